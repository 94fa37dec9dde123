"""Command line (docs/formats.md "Command line"): :func:`main` parses the arguments
(:mod:`.parser`), runs the sub-command and prints its JSON to stdout or ``--json FILE``.

Bad input exits with status 2 and one line on stderr naming the file, row and column;
so does a usage error (``error: ...; see ... --help``). Outputs never destroy inputs:
before any work, an output that is one of the command's inputs, a folder, or the same file
as another output is refused; every file is written to a temporary file in its folder and
renamed into place (``io.atomic_write_text``), so a failed run leaves an old file intact.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from .options import msl_metadata_beside
from .parser import _SIM_FILES, MAX_MESSAGE, build_parser


def _jsonable(o):
    """A command's result as plain JSON values (arrays as lists, NaN and inf as null)."""
    # lazy: a result is printed after its command ran, which loaded numpy (--help: never)
    import numpy as np

    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, (np.floating, float)):
        return None if not np.isfinite(o) else float(o)
    if isinstance(o, np.integer):
        return int(o)
    return o


_DATA_FILES = ("meas", "setup", "certificate", "mapping", "msl", "msl_metadata", "msl_bar",
               "laser", "step_gauge", "ball_bar")
"""The options of the fitting commands that name files they read."""


def _files(args):
    """``(outputs, folders, inputs)`` of a parsed command, for ``io.check_outputs``:
    option -> file(s) written, option -> folder created, every file read."""
    outs, folders, ins = {}, {}, []
    for attr in _DATA_FILES:
        v = getattr(args, attr, None)
        ins += v if isinstance(v, list) else [v]
    ins += msl_metadata_beside(args)  # the default of --msl-metadata reads them
    cmd = args.command
    if cmd == "simulate":
        ins.append(args.config)
        folders["--out"] = args.out
        outs["--out"] = [Path(args.out) / f for f in _SIM_FILES]
    elif cmd == "fit":
        outs["--save"] = args.save
    elif cmd == "compensate":
        ins += [args.model, args.points]
        outs["--out"] = args.out
    elif cmd == "budget":
        ins.append(args.budget)
    elif cmd == "report":
        ins.append(args.analysis)
        # lazy: report alone reads a file (its record) before the outputs are checked
        from ..analysis import read_record, record_files

        record = read_record(Path(args.analysis), confine=not args.any_path)
        # the files the record reads, its stored calibrations too
        ins += [f.path for _, f in record_files(record)]
        outs["--out"] = args.out
    elif cmd == "plan":
        ins.append(args.plan)
    elif cmd == "task":
        ins += [args.model, args.task]
    elif cmd == "check":
        ins.append(args.model)
        outs["--report"] = args.report
        outs["--results-json"] = args.results_json
    elif cmd == "compare":
        ins += args.models
        outs["--results-json"] = args.results_json
    elif cmd == "next":
        outs["--plan-out"] = args.plan_out
    elif cmd == "export":
        ins.append(args.model)
        # lazy: export's files are its module's to say (the module it runs next)
        from .export import output_files

        o, f = output_files(args)
        outs.update(o)
        folders.update(f)
    outs["--json"] = args.json
    return outs, folders, ins


def _input_name(args):
    """The one input file of commands that read one (None for several or none): named in
    messages that do not name a file themselves (simulation config, budget)."""
    for attr in ("config", "budget"):
        if isinstance(getattr(args, attr, None), str):
            return Path(getattr(args, attr)).name
    return None


def _one_line(exc, name) -> str:
    """An exception as one line of at most :data:`MAX_MESSAGE` characters, naming ``name``
    when the message does not name a file."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, KeyError):
        text = f"missing key {text}"
    if isinstance(exc, OSError) and exc.filename:
        text = f"{Path(str(exc.filename)).name}: {exc.strerror or text}"
    if name and name not in text:
        text = f"{name}: {text}"
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 1] + "…"


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status (a usage error exits 2 from argparse)."""
    args = build_parser().parse_args(argv)
    if args.func.serves:  # the app's server: its exit status, no JSON, none of the core
        return args.func(args)
    # after parsing, so that --help and a usage error load none of the core; the command's
    # own module loads in args.func (parser.Subcommand), the wings it uses with it
    # lazy: the io wing brings numpy and pandas, which neither --help nor a usage error needs
    from ..io import forget_outputs

    try:
        return _run(args)
    finally:  # the outputs' states at the start belong to this command alone
        forget_outputs()


def _run(args) -> int:
    """The parsed command, its outputs checked first (``io.check_outputs``), its result
    printed or written: the exit status."""
    # lazy: as in main
    from ..io import DataError, atomic_write_text, check_outputs
    from .records import provenance_of  # lazy: the io wing's, as the line above

    try:  # before any work: outputs that would destroy an input or each other
        outs, folders, ins = _files(args)
        check_outputs(outs, ins, folders=folders)
        args.input_files = [p for p in ins if p]  # their digests go into every record
    except (DataError, ValueError, KeyError, OSError) as exc:
        print(f"error: {_one_line(exc, None)}", file=sys.stderr)
        return 2
    try:
        out = args.func(args)
    except (DataError, ValueError, KeyError, OSError) as exc:
        print(f"error: {_one_line(exc, _input_name(args))}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - a bug must still end in one line, not a traceback
        print(f"error: internal error ({_one_line(exc, None)}); please report it with the "
              "input files.", file=sys.stderr)
        return 3
    for note in out.get("notes", []) if isinstance(out, dict) else []:
        print(f"note: {_one_line(note, None)}", file=sys.stderr)
    if isinstance(out, dict) and "provenance" not in out:  # what made this result
        out["provenance"] = provenance_of(args).to_dict()
    text = json.dumps(_jsonable(out), indent=1)
    if args.json:
        try:
            atomic_write_text(args.json, text)
        except (DataError, OSError) as exc:
            print(f"error: {_one_line(exc, None)}", file=sys.stderr)
            return 2
    else:
        try:
            print(text)
            sys.stdout.flush()
        except BrokenPipeError:
            # the reader stopped early (``| head``): not an error of this command; stdout
            # is pointed at devnull so that the interpreter's own flush at exit is quiet
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0

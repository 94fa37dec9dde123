"""``python -m cmm_core export``: compensation tables and results files from a saved model.

Formats in docs/compensation.md. :func:`add_parser` adds the sub-command to a parser (its
options are in :mod:`.parser`; its ``func`` runs :func:`command`, which returns the JSON
summary ``cli.main`` prints); :func:`run` runs it on its own: the summary on stdout, exit
status 0; bad input exits with status 2 and one line on stderr naming the file, row and
column. No output may be the model file or another output (:func:`output_files`,
``io.check_outputs``); each file is written whole or not at all, and the files of one run
all or none (``io.atomic_write_all``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..export import comp_tables as ct
from ..export import load_model
from ..export import results as rx
from ..io import DataError, atomic_write_all, check_outputs
from ..machine import AXES
from .parser import add_command


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``export`` sub-command to ``subparsers`` (as ``cli.build_parser`` does; its
    options: ``parser.add_export_arguments``)."""
    return add_command(subparsers, "export")


AXIS_TABLE_FILES = (*(f"axis_{a}.csv" for a in AXES), "squareness.csv")
"""The files ``--axis-tables DIR`` writes into its folder."""


def output_files(args: argparse.Namespace) -> tuple[dict, dict]:
    """``(outputs, folders)`` of ``export`` for ``io.check_outputs``: option -> file(s)
    written, option -> folder created."""
    outs = {"--grid": args.grid, "--results-json": args.results_json,
            "--results-xml": args.results_xml}
    folders = {}
    if args.axis_tables:
        folders["--axis-tables"] = args.axis_tables
        outs["--axis-tables"] = [Path(args.axis_tables) / f for f in AXIS_TABLE_FILES]
    return outs, folders


def command(args: argparse.Namespace) -> dict:
    """Write the files asked for; the JSON summary (what was written where).

    Raises DataError / OSError on bad input (one line each): an output that is the model
    file, a folder or another output is refused before any work. Every file is computed
    before the first is written, so a refusal leaves none behind, and each is written
    whole or not at all.
    """

    source = Path(args.model).name
    outs = (args.grid, args.axis_tables, args.results_json, args.results_xml)
    if not any(outs):
        raise DataError("nothing to write: give --grid, --axis-tables, --results-json "
                        "and/or --results-xml.", file=source)
    files, folders = output_files(args)
    check_outputs(files, [args.model], folders=folders)
    model = load_model(args.model)
    try:
        return _write(args, model, source)
    except DataError:
        raise
    except ValueError as exc:  # a step or coverage the model's strokes cannot take
        raise DataError(str(exc), file=source) from None


def _write(args, model, source) -> dict:
    """Compute the files of ``args`` from ``model``, then write them; the summary."""

    step = args.grid_step_mm
    axis_step = args.axis_step_mm if args.axis_step_mm is not None else step
    if isinstance(axis_step, tuple):
        axis_step = axis_step[0]
    out = {"model": source, "spec": model.spec, "layout": model.terms.layout,
           "fails_chi2_test": model.summary.get("fails_chi2_test")}
    texts = {}  # path -> text
    if args.grid:
        g = ct.compensation_grid(model, step, probe=args.probe,
                                 allow_undetermined=args.allow_undetermined)
        texts[Path(args.grid)] = ct.grid_csv(model, g, args.probe, source)
        out["grid"] = {"file": str(args.grid), "nodes": len(g),
                       "max_correction_um": float(g[["cx_um", "cy_um", "cz_um"]].abs()
                                                  .max().max())}
    if args.axis_tables:
        d = Path(args.axis_tables)
        files = ct.axis_tables_csv(model, axis_step, source,
                                   allow_undetermined=args.allow_undetermined)
        texts.update({d / name: text for name, text in files.items()})
        out["axis_tables"] = {"dir": str(d), "files": sorted(files)}
    kw = {"coverage_factor": args.coverage_factor, "source": source}
    if args.results_json:
        texts[Path(args.results_json)] = rx.results_json(model, **kw)
        out["results_json"] = str(args.results_json)
    if args.results_xml:
        texts[Path(args.results_xml)] = rx.results_xml(model, **kw)
        out["results_xml"] = str(args.results_xml)
    if args.axis_tables:
        Path(args.axis_tables).mkdir(parents=True, exist_ok=True)
    atomic_write_all(texts)  # all or nothing: never a grid beside another model's tables
    return out


def run(args: argparse.Namespace) -> int:
    """Run ``export`` on parsed arguments: summary JSON on stdout and 0, or one line on
    stderr naming the file, row and column and 2."""
    try:
        out = command(args)
    except (DataError, ValueError, KeyError, OSError) as exc:
        text = " ".join(str(exc).split()) or type(exc).__name__
        if isinstance(exc, OSError) and exc.filename:
            text = f"{Path(str(exc.filename)).name}: {exc.strerror or text}"
        name = Path(args.model).name
        if name not in text and not isinstance(exc, OSError):
            text = f"{name}: {text}"
        print(f"error: {text[:400]}", file=sys.stderr)
        return 2
    print(json.dumps(out, indent=1))
    return 0

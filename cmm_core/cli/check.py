"""``python -m cmm_core check`` and ``compare``: interim checks against a stored
calibration, and a machine's calibration history (docs/monitoring.md).

:func:`add_parser` adds both sub-commands to a parser (their options are in
:mod:`.parser`; their ``func`` runs :func:`_command_check` or :func:`_command_compare`,
which return the JSON summary ``cli.main`` prints; bad input raises ``DataError``, which
``cli.main`` prints as one line on stderr naming the file, row and column, exit status 2).
"""

from __future__ import annotations

import argparse
import datetime as dt
from pathlib import Path

from ..analysis import (
    AnalysisRecord,
    CheckChoices,
    DataFile,
    DataSources,
    InstrumentFile,
    render,
    run,
)
from ..export import load_model, results_json
from ..io import DataError, atomic_write_all, atomic_write_text, check_outputs, load_dataset
from ..monitor import check_sigma_um, compare_calibrations, run_check, version_notes
from .inputs import instruments_of
from .parser import add_command
from .records import command_inputs


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``check`` and ``compare`` to ``subparsers`` (as ``cli.build_parser`` does; their
    options are in :mod:`.parser`)."""
    add_command(subparsers, "check")
    add_command(subparsers, "compare")


def _command_check(args) -> dict:
    """The interim check, what changed, the new effect and (with ``--mpe``) conformity,
    as a JSON dict; with ``--report`` / ``--results-json`` those files too."""
    inputs = [args.model, *args.meas, args.setup, args.certificate, *args.laser,
              *args.step_gauge, *args.ball_bar]
    check_outputs({"--report": args.report, "--results-json": args.results_json}, inputs)
    if not args.meas and (args.setup or args.certificate):
        raise DataError("--setup and --certificate describe plate measurements; none was "
                        "given.", file="command line", column="MEAS.csv",
                        hint="give the measurements, or check with instruments alone.")
    if args.meas and args.setup is None:
        raise DataError("the measurements need their setup (--setup SETUP.json).",
                        file="command line", column="--setup")
    if args.report and not args.meas:
        raise DataError("--report needs plate measurements (the report is that of an "
                        "analysis of them); use --results-json for instruments alone.",
                        file="command line", column="--report")
    model = load_model(args.model)
    instruments = instruments_of(args)
    if not args.meas and not instruments:
        raise DataError("nothing to check: give measurements (MEAS.csv --setup ...) or "
                        "instrument files (--laser, --step-gauge, --ball-bar).",
                        file="command line", column="MEAS.csv")
    data = None
    if args.meas:
        data = load_dataset(args.meas, args.setup, args.certificate,
                            name=", ".join(Path(m).name for m in args.meas))
    positions = None if args.positions is None else \
        [p.strip() for p in args.positions.split(",") if p.strip()]
    if positions is not None:
        known = [] if data is None else list(map(str, data.positions))
        unknown = [p for p in positions if p not in set(known)]
        if unknown:
            raise DataError(f"placement {unknown[0]!r} is not in the data (known: "
                            f"{', '.join(known) or 'none'}).",
                            file="command line" if data is None else data.name,
                            column="position")
    texts: dict[Path, str] = {}  # written together, all or none, when all are made
    if args.report:
        record = AnalysisRecord(
            DataSources(", ".join(Path(m).name for m in args.meas),
                        tuple(DataFile(Path(m).name, str(m)) for m in args.meas),
                        DataFile(Path(args.setup).name, str(args.setup)),
                        None if args.certificate is None else
                        DataFile(Path(args.certificate).name, str(args.certificate)),
                        tuple(InstrumentFile(k, DataFile(Path(f).name, str(f)))
                              for k, fs in (("laser", args.laser),
                                            ("step_gauge", args.step_gauge),
                                            ("ball_bar", args.ball_bar)) for f in fs)),
            spec=model.spec, sigma_um=check_sigma_um(model, args.sigma_um),
            positions=None if positions is None else tuple(positions),
            interim_check=CheckChoices(DataFile(Path(args.model).name, str(args.model)),
                                       args.alpha, args.family_alpha, args.sigma_um,
                                       args.mpe))
        # the report's analysis and its check: the check printed and written is that
        # one (the record's selection and exclusions), not a second computation
        res = run(record)
        texts[Path(args.report)] = render(res)
        if res.interim is None:  # the record asks for it: run() always makes it
            raise RuntimeError("the analysis record's interim check is missing")
        outcome = res.interim
    else:
        outcome = run_check(model, data, instruments=instruments, sigma_um=args.sigma_um,
                            alpha=args.alpha, family_alpha=args.family_alpha,
                            positions=positions, mpe=args.mpe)
    out: dict[str, object] = {"model": Path(args.model).name, **outcome.to_dict(),
                              "notes": version_notes([model])}
    if args.results_json:
        made = model.derived_provenance(command_inputs(args, leave_out=[model.source]))
        texts[Path(args.results_json)] = results_json(
            model, source=Path(args.model).name, interim_check=outcome.results_section(),
            provenance=made)
        out["results_json"] = str(args.results_json)
    if args.report:
        out["report"] = str(args.report)
    atomic_write_all(texts)
    return out


def _command_compare(args) -> dict:
    """The calibration history of the models, as a JSON dict."""
    if len(args.dates) != len(args.models):
        raise DataError(f"{len(args.models)} model(s) but {len(args.dates)} date(s); give "
                        "one date per model, in the same order.", file="command line",
                        column="--dates")
    check_outputs({"--results-json": args.results_json}, args.models)
    models = [load_model(m) for m in args.models]
    h = compare_calibrations(list(zip(models, args.dates, strict=True)),
                             family_alpha=args.family_alpha, nodes_per_axis=args.nodes)
    out = {**h.to_dict(), "notes": version_notes(models)}
    if args.results_json:
        # the latest by the history's own date order (parsed dates, not strings: the
        # history refuses two models of one date, so it is one model)
        last = next(i for i, d in enumerate(args.dates)
                    if dt.date.fromisoformat(d.strip()).isoformat() == h.dates[-1])
        made = models[last].derived_provenance(
            command_inputs(args, leave_out=[models[last].source]))
        atomic_write_text(args.results_json, results_json(
            models[last], source=Path(args.models[last]).name,
            history=h.results_section(), provenance=made))
        out["results_json"] = str(args.results_json)
    return out

"""``python -m cmm_core check`` and ``compare``: interim checks against a stored
calibration, and a machine's calibration history (docs/monitoring.md).

:func:`add_parser` adds both sub-commands to the main parser (their ``func`` returns the
JSON summary ``cli.main`` prints); :func:`run` runs one on its own: the summary on stdout
(or ``--json FILE`` when the parser has that option), exit status 0; bad input exits
with status 2 and one line on stderr naming the file, row and column.
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
from ..monitor import (
    MAX_MAP_NODES_PER_AXIS,
    check_sigma_um,
    compare_calibrations,
    parse_mpe,
    run_check,
)
from .inputs import add_instrument_args, instruments_of, number_arg

_MODEL_HELP = ("the stored calibration: a model file written by 'fit --save' (kinematic "
               "coefficients with their covariance, σ, layout, strokes and styli)")
_MEAS_HELP = ("the new measurements (long CSV, docs/formats.md): one placement of the plate "
              "is enough; several files are read as one; none when instruments alone "
              "(--laser, --step-gauge, --ball-bar) are the check")
_SETUP_HELP = ("setup JSON of the new measurements (layout, strokes, placements, styli; "
               "required with measurements; default: none, for instruments alone): the "
               "machine must be the model's")
_REPORT_HELP = ("write the HTML report of the check (an analysis record of the new data "
                "with its section 'Interim check', docs/report.md); needs plate "
                "measurements (default: no report)")
_RESULTS_HELP = ("write the results document (JSON, docs/compensation.md) with its section "
                 "'%s': the numbers with their uncertainties and decision rules (default: "
                 "none)")
_CERT_HELP = ("certificate CSV of the plate (calibrated ball centres with their "
              "uncertainties): the check predicts the balls from it (default: the one the "
              "setup names; one of the two is required)")
_SIGMA_HELP = ("repeatability of one probed coordinate of the new data, µm, 0.001 to 1000 "
               "(default: the stored model's σ)")
_ALPHA_HELP = ("false-alarm level of the χ² test, 0.001 to 0.2 (default: %(default)s): the "
               "fraction of checks of an unchanged machine that fail")
_FAMILY_HELP = ("family-wise false-alarm level of the parameter changes (Holm over the "
                "parameters tested), 0.001 to 0.2 (default: %(default)s)")
_POS_HELP = ("placements of the new data to check, comma-separated (default: all)")
_MPE_HELP = ("the machine's MPE for lengths as 'A,D': MPE = A µm + L/D with L in mm, e.g. "
             "0.6,600 (the thesis machine). With it the check states conformity by the "
             "ISO 14253-1 rule (conforms, does not conform, cannot say); default: no "
             "statement")
_MODELS_HELP = "two or more model files of one machine, written by 'fit --save'"
_DATES_HELP = ("the calibration date of each model, ISO 8601 (YYYY-MM-DD), in the order of "
               "the models (required)")
_NODES_HELP = (f"grid nodes per axis of the error map's change, 2 to {MAX_MAP_NODES_PER_AXIS} "
               "(default: %(default)s)")


_LEVEL = number_arg(float, 0.001, 0.2)
"""A false-alarm level: 0.1 % to 20 %."""


def _mpe(text: str) -> tuple[float, float]:
    """``--mpe``: ``monitor.parse_mpe`` (the app's field reads it there too)."""
    try:
        return parse_mpe(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``check`` and ``compare`` to the sub-parsers of ``cli.build_parser``."""
    p = subparsers.add_parser(
        "check", help="interim check of new measurements against a stored calibration: χ² "
                      "test, E_n per ball, what changed, conformity to the MPE")
    p.add_argument("model", metavar="MODEL.json", help=_MODEL_HELP)
    p.add_argument("meas", nargs="*", metavar="MEAS.csv", help=_MEAS_HELP)
    p.add_argument("--setup", metavar="SETUP.json", default=None, help=_SETUP_HELP)
    p.add_argument("--certificate", metavar="CERT.csv", help=_CERT_HELP)
    p.add_argument("--sigma-um", type=number_arg(float, 1e-3, 999.999, "µm"), default=None, metavar="UM", help=_SIGMA_HELP)
    p.add_argument("--alpha", type=_LEVEL, default=0.05, metavar="LEVEL", help=_ALPHA_HELP)
    p.add_argument("--family-alpha", type=_LEVEL, default=0.05, metavar="LEVEL",
                   help=_FAMILY_HELP)
    p.add_argument("--positions", default=None, metavar="P1,P2", help=_POS_HELP)
    p.add_argument("--mpe", type=_mpe, default=None, metavar="A,D", help=_MPE_HELP)
    add_instrument_args(p)
    p.add_argument("--report", metavar="OUT.html", default=None, help=_REPORT_HELP)
    p.add_argument("--results-json", metavar="OUT.json", default=None,
                   help=_RESULTS_HELP % "interim_check")
    p.set_defaults(func=_command_check)
    p = subparsers.add_parser(
        "compare", help="a machine's calibration history: every shared parameter's change "
                        "with u and E_n, significant changes, the error map's change")
    p.add_argument("models", nargs="+", metavar="MODEL.json", help=_MODELS_HELP)
    p.add_argument("--dates", nargs="+", required=True, metavar="YYYY-MM-DD",
                   help=_DATES_HELP)
    p.add_argument("--family-alpha", type=_LEVEL, default=0.05, metavar="LEVEL",
                   help=_FAMILY_HELP)
    p.add_argument("--nodes", type=number_arg(int, 2, MAX_MAP_NODES_PER_AXIS), default=5, metavar="N", help=_NODES_HELP)
    p.add_argument("--results-json", metavar="OUT.json", default=None,
                   help=(_RESULTS_HELP % "history").replace(" (default", ", beside the "
                                                             "latest calibration's parameters "
                                                             "(default"))
    p.set_defaults(func=_command_compare)


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
    out: dict[str, object] = {"model": Path(args.model).name, **outcome.to_dict()}
    if args.results_json:
        texts[Path(args.results_json)] = results_json(
            model, source=Path(args.model).name, interim_check=outcome.results_section())
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
    out = h.to_dict()
    if args.results_json:
        # the latest by the history's own date order (parsed dates, not strings: the
        # history refuses two models of one date, so it is one model)
        last = next(i for i, d in enumerate(args.dates)
                    if dt.date.fromisoformat(d.strip()).isoformat() == h.dates[-1])
        atomic_write_text(args.results_json, results_json(
            models[last], source=Path(args.models[last]).name,
            history=h.results_section()))
        out["results_json"] = str(args.results_json)
    return out

"""Command line (docs/formats.md "Command line"): JSON to stdout or ``--json FILE``.

Bad input exits with status 2 and one line on stderr naming the file, row and column;
so does a usage error (``error: ...; see ... --help``). Outputs never destroy inputs:
before any work, an output that is one of the command's inputs, a folder, or the same file
as another output is refused; every file is written to a temporary file in its folder and
renamed into place (``io.atomic_write_text``), so a failed run leaves an old file intact.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..analysis import measured_error_from_residuals_um, read_record, write_report
from ..diagnosis import diagnose, kinematic_basis
from ..export import compensate, load_model, save_model
from ..gp import gp_components
from ..gum import air_from_args, read_budget
from ..io import (
    DataError,
    atomic_write_all,
    atomic_write_text,
    check_outputs,
    read_json,
)
from ..model import MAX_ORDER, Observations, fit, select, simulate, summary
from .check import add_parser as add_check_parser
from .export import add_parser as add_export_parser
from .export import output_files as export_output_files
from .inputs import (
    PLATE_HELP,
    add_data_args,
    add_fit_args,
    add_instrument_args,
    add_outlier_args,
    data_of,
    dataset_of,
    exclusions_of,
    fit_args_of,
    instruments_of,
    number_arg,
    sigma_of,
)
from .plan import add_plan_arguments, add_task_arguments, run_plan, run_task
from .proposals import add_parser as add_next_parser


def _jsonable(o):
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


_SIM_FILES = ("measurements.csv", "setup.json", "certificate.csv", "truth.json")


def cmd_simulate(args: argparse.Namespace) -> dict:
    # read like every JSON input (a byte-order mark tolerated), refusals name the file
    cfg, name = read_json(Path(args.config))
    sim = simulate(cfg, name=name)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:  # all four made, then written all or none
        sim.write(tmp)
        atomic_write_all({out / f: (Path(tmp) / f).read_bytes() for f in _SIM_FILES})
    return {"out": str(args.out), "n_obs": len(sim.dataset.meas), "files": list(_SIM_FILES)}


def cmd_fit(args: argparse.Namespace) -> dict:
    instruments = instruments_of(args)
    data = data_of(args, instruments)
    outliers, exclude = exclusions_of(data, args.exclude_outliers)
    sigma_um, sigma = sigma_of(args, data, exclude, args.model)
    r = fit(data, args.model, instruments=instruments or None,
            **fit_args_of(args, args.model, exclude, sigma_um=sigma_um))
    if args.save:
        save_model(r, args.save)
    return {**r.summary(), "sigma": sigma,
            "parameters": {lab: {"value": v, "u": u, "u_inflated": ui, "unit": un}
                           for lab, v, u, ui, un in zip(r.labels, r.values, r.u, r.u_inflated,
                                                        r.units, strict=True)},
            "unidentifiable": r.unidentifiable, "null_combinations": r.null_combinations,
            "instruments": summary(r),
            "outliers": outliers, "excluded": [list(e) for e in exclude]}


def cmd_diagnose(args: argparse.Namespace) -> dict:
    instruments = instruments_of(args)
    data = data_of(args, instruments)
    outliers, exclude = exclusions_of(data, args.exclude_outliers)
    sigma_um, sigma = sigma_of(args, data, exclude, args.baseline)
    if instruments and not isinstance(data, Observations):  # they ride on the observations into every model the diagnosis fits
        data = replace(select(data, exclude=exclude), instruments=tuple(instruments))
    d = diagnose(data, args.baseline,
                 **fit_args_of(args, args.baseline, exclude, sigma_um=sigma_um))
    out = d.to_dict()
    out["certificate_u_source"] = d.baseline.certificate_u_source
    out["sigma"] = sigma
    out["outliers"] = outliers
    return out


def cmd_compensate(args: argparse.Namespace) -> dict:
    # streamed a chunk at a time: the memory does not grow with the number of points
    return compensate(load_model(args.model), args.points, out=args.out,
                      allow_extrapolation=args.allow_extrapolation)


def cmd_gp(args: argparse.Namespace) -> dict:
    data = dataset_of(args)
    _, exclude = exclusions_of(data, args.exclude_outliers)
    spec = "kinematic21" if args.mean == "kinematic" else "rigid"
    r = fit(data, spec, **fit_args_of(args, spec, exclude))
    obs = r.problem.obs
    basis = None
    if args.mean == "kinematic":

        basis = kinematic_basis(r)
    comps = gp_components(obs.r_mm, measured_error_from_residuals_um(r.residuals_um),
                          mean="zero" if basis is not None
                          else args.mean, kernel=args.kernel, basis=basis,
                          probe_mm=obs.p_mm if args.inputs == "probe" else None)
    return {"mean": args.mean, "kernel": args.kernel,
            "inputs": "ram position and probe offset" if comps.probe_input else "tip",
            "loo_coverage_95": comps.loo_coverage(0.95), "components": comps.summary()}


def cmd_budget(args: argparse.Namespace) -> dict:
    return read_budget(Path(args.budget))


def cmd_report(args: argparse.Namespace) -> dict:
    return write_report(args.analysis, args.out)


def cmd_air(args: argparse.Namespace) -> dict:
    return air_from_args(args.t_C, args.p_Pa, args.rh_percent, args.wavelength_nm)


def cmd_plan(args: argparse.Namespace) -> dict:
    return run_plan(args)


def cmd_task(args: argparse.Namespace) -> dict:
    return run_task(args)


MAX_MESSAGE = 400
"""Longest error line (characters): a 1 MB cell must not become a 1 MB line."""


class _Parser(argparse.ArgumentParser):
    """A usage error is one line, ``error: ...; see PROG --help``, and exit status 2 (not
    argparse's whole usage); the sub-command parsers are of this class too."""

    def error(self, message):
        text = " ".join(str(message).split())
        if len(text) > MAX_MESSAGE:
            text = text[:MAX_MESSAGE - 1] + "…"
        self.exit(2, f"error: {text}; see {self.prog} --help\n")


_JSON_HELP = ("write the JSON result to FILE instead of stdout, whole or not at all (never "
              "one of the command's inputs or another output; accepted before or after "
              "the command; default: stdout)")


def program_name() -> str:
    """How the user called the command line, for usage lines and hints: ``cmm-error-lab``
    (the installed console script) or ``python -m cmm_core``."""
    called = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    return "cmm-error-lab" if called.startswith("cmm-error-lab") else "python -m cmm_core"


def build_parser() -> argparse.ArgumentParser:
    """Argument parser with one sub-command per command of docs/formats.md."""
    ap = _Parser(prog=program_name(), description="CMM error lab")
    ap.add_argument("--json", metavar="FILE", help=_JSON_HELP)
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("simulate", help="simulate a virtual CMM")
    p.add_argument("config", metavar="CONFIG.json",
                   help="simulation config: seed, noise_um (µm), measurement order, plate "
                        "form, true kinematic errors and hidden effects "
                        "(docs/formats.md#simulation-config; example: "
                        "sample_data/simulated/config.json)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="directory to write measurements.csv, setup.json, certificate.csv "
                        "and truth.json into (created if missing; required)")
    p.set_defaults(func=cmd_simulate)
    p = sub.add_parser("fit", help="fit the kinematic model")
    add_fit_args(p)
    add_instrument_args(p)
    p.add_argument("--save", metavar="MODEL.json",
                   help="write the fitted model to this JSON file, for 'compensate' "
                        "(default: not saved)")
    p.set_defaults(func=cmd_fit)
    p = sub.add_parser("diagnose", help="rank the effects missing from a baseline model")
    add_fit_args(p, baseline=True)
    add_instrument_args(p)
    p.set_defaults(func=cmd_diagnose)
    p = sub.add_parser("compensate", help="correct points with a saved model")
    p.add_argument("model", metavar="MODEL.json",
                   help="fitted model written by 'fit --save'")
    p.add_argument("points", metavar="POINTS.csv",
                   help="points to correct: x_mm,y_mm,z_mm (reported tip centres, mm, "
                        "machine frame) and probe (the stylus name, needed unless the "
                        "model has one stylus); other columns are kept")
    p.add_argument("--out", required=True, metavar="CORRECTED.csv",
                   help="output CSV: the input columns plus corrected coordinates "
                        "xc_mm,yc_mm,zc_mm (mm) and the corrections and their standard "
                        "uncertainties (µm); required")
    p.add_argument("--allow-extrapolation", action="store_true",
                   help="accept points outside the machine's range (their corrections "
                        "extrapolate the model and are flagged in the 'extrapolated' "
                        "column); without it such points make the command fail (exit 2), "
                        "the flagged output still written")
    p.set_defaults(func=cmd_compensate)
    p = sub.add_parser("gp", help="Gaussian-process model of the errors")
    add_data_args(p)
    p.add_argument("--mean", choices=("zero", "quadratic", "kinematic"), default="zero",
                   help="GP mean: 'zero' (the GP models the rigid-aligned errors), "
                        "'quadratic' (full quadratic in the ram position, coefficients "
                        "marginalised) or 'kinematic' (the GP models what the fitted "
                        "kinematic model leaves; default: %(default)s)")
    p.add_argument("--kernel", choices=("se_iso", "se_ard"), default="se_iso",
                   help="squared-exponential covariance with one length scale (se_iso) or "
                        "one per machine axis (se_ard); length scales in mm "
                        "(default: %(default)s)")
    p.add_argument("--inputs", choices=("probe", "tip"), default="probe",
                   help="GP inputs: 'probe' = the ram position and the stylus offset (mm), "
                        "one noise level per stylus, when the data carry several styli; "
                        "'tip' = the tip coordinates only (default: %(default)s)")
    add_outlier_args(p)
    p.add_argument("--order", type=number_arg(int, 1, MAX_ORDER), default=2, metavar="N",
                   help=f"polynomial order of the kinematic model for --mean kinematic, 1 "
                        f"to {MAX_ORDER} (default: %(default)s)")
    p.add_argument("--plate", choices=("fixed", "prior", "free"), help=PLATE_HELP)
    p.set_defaults(func=cmd_gp)
    p = sub.add_parser("budget", help="GUM uncertainty budget")
    p.add_argument("budget", metavar="BUDGET.json",
                   help="uncertainty budget: contributions, each with a standard "
                        "uncertainty u or a half_width, a distribution, a sensitivity c and "
                        "optional degrees of freedom; coverage probability and Monte Carlo "
                        "trials (docs/formats.md#uncertainty-budget; example: "
                        "sample_data/budget/ballplate_budget.json)")
    p.set_defaults(func=cmd_budget)
    p = sub.add_parser("report", help="self-contained HTML report of an analysis record")
    p.add_argument("analysis", metavar="ANALYSIS.json",
                   help="analysis record: data files (paths relative to the record), model "
                        "spec, order, plate mode, σ in µm, exclusions, exclude_outliers "
                        "(default false: flagged outliers stay in the fit), diagnosis, GP, "
                        "MPE and magnification choices (docs/report.md; example: "
                        "sample_data/analysis/thesis.json)")
    p.add_argument("--out", required=True, metavar="REPORT.html",
                   help="HTML file to write (plotly inline, opens offline; about 2 MB); "
                        "required. The χ² test of the fit is printed as JSON")
    p.set_defaults(func=cmd_report)
    p = sub.add_parser("air", help="refractive index of air (modified Edlén)")
    # the ranges of the modified Edlén equation (gum.refractive_index_edlen checks them too)
    p.add_argument("--t-C", type=number_arg(float, 0, 40, "°C"), required=True, dest="t_C",
                   metavar="DEG_C", help="air temperature in °C, 0 to 40 (required)")
    p.add_argument("--p-Pa", type=number_arg(float, 60_000, 120_000, "Pa"), required=True,
                   dest="p_Pa", metavar="PA",
                   help="air pressure in Pa, 60000 to 120000, e.g. 101325 (required)")
    p.add_argument("--rh-percent", type=number_arg(float, 0, 100, "%"), required=True,
                   dest="rh_percent", metavar="PERCENT",
                   help="relative humidity in %%, 0 to 100 (required)")
    p.add_argument("--wavelength-nm", type=number_arg(float, 350, 1100, "nm"), required=True,
                   dest="wavelength_nm", metavar="NM",
                   help="vacuum wavelength of the laser in nm, 350 to 1100, e.g. 632.99 "
                        "for a HeNe laser (required)")
    p.set_defaults(func=cmd_air)

    p = sub.add_parser("plan", help="evaluate, compare and design measurement plans "
                                    "before measuring")
    add_plan_arguments(p)
    p.set_defaults(func=cmd_plan)
    p = sub.add_parser("task", help="task-specific uncertainty of a distance, circle or "
                                    "plane measured with a fitted machine")
    add_task_arguments(p)
    p.set_defaults(func=cmd_task)

    add_export_parser(sub)
    add_check_parser(sub)
    add_next_parser(sub)
    for p in sub.choices.values():  # --json after the command too (SUPPRESS: no override)
        p.add_argument("--json", metavar="FILE", default=argparse.SUPPRESS, help=_JSON_HELP)
    return ap


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
        data = read_record(Path(args.analysis)).data  # the files the record reads
        ins += [f.path for f in (*data.measurements, data.setup, data.certificate) if f]
        ins += [i.file.path for i in data.instruments]
        outs["--out"] = args.out
    elif cmd == "plan":
        ins.append(args.plan)
    elif cmd == "task":
        ins += [args.model, args.task]
    elif cmd == "check":
        ins.append(args.model)
    elif cmd == "compare":
        ins += args.models
    elif cmd == "next":
        outs["--plan-out"] = args.plan_out
    elif cmd == "export":
        ins.append(args.model)
        o, f = export_output_files(args)
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
    try:  # before any work: outputs that would destroy an input or each other
        outs, folders, ins = _files(args)
        check_outputs(outs, ins, folders=folders)
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

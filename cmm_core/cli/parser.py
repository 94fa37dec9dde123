"""The command line's grammar: every sub-command with its options and help texts, and the
table that names the function each one runs (``docs/formats.md`` "Command line").

Standard library only, as :mod:`.options`: building the parser (``--help``, ``COMMAND
--help``, a usage error) imports no command module and so none of numpy, scipy, pandas or
plotly (``tests/test_cli_start.py``). A sub-command's function is named ``"module:function"``
of this wing in :data:`COMMANDS` and imported when the command runs (:class:`Subcommand`),
so that each command loads only the wings it uses. A new sub-command is one entry of
:data:`COMMANDS`: its help line, the function adding its options, the function it runs.
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .app import add_app_arguments
from .options import (
    _MAX_MAP_NODES_PER_AXIS,
    _MAX_ORDER,
    _TARGET_POWER,
    DEFAULT_ORDER,
    DEFAULT_SIGMA_UM,
    PLATE_HELP,
    _order_arg,
    _sigma_arg,
    _spec_arg,
    add_data_args,
    add_fit_args,
    add_foreign_args,
    add_instrument_args,
    add_outlier_args,
    number_arg,
)

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


# --- simulate, fit, diagnose, compensate, gp, budget, report, air

_SIM_FILES = ("measurements.csv", "setup.json", "certificate.csv", "truth.json")
"""The files ``simulate --out DIR`` writes into its folder."""


def _simulate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG.json",
                   help="simulation config: seed, noise_um (µm), measurement order, plate "
                        "form, true kinematic errors and hidden effects "
                        "(docs/formats.md#simulation-config; example: "
                        "sample_data/simulated/config.json)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="directory to write measurements.csv, setup.json, certificate.csv "
                        "and truth.json into (created if missing; required)")


def _fit_arguments(p: argparse.ArgumentParser) -> None:
    add_fit_args(p)
    add_instrument_args(p)
    p.add_argument("--save", metavar="MODEL.json",
                   help="write the fitted model to this JSON file, for 'compensate' "
                        "(default: not saved)")


def _diagnose_arguments(p: argparse.ArgumentParser) -> None:
    add_fit_args(p, baseline=True)
    add_instrument_args(p)


def _compensate_arguments(p: argparse.ArgumentParser) -> None:
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


def _gp_arguments(p: argparse.ArgumentParser) -> None:
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
    p.add_argument("--order", type=number_arg(int, 1, _MAX_ORDER), default=None, metavar="N",
                   help=f"polynomial order of the kinematic model for --mean kinematic, 1 "
                        f"to {_MAX_ORDER} (default: {DEFAULT_ORDER}; with MSL files the "
                        "degree of the model parameters their metadata lists)")
    p.add_argument("--plate", choices=("fixed", "prior", "free"), help=PLATE_HELP)


def _budget_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("budget", metavar="BUDGET.json",
                   help="uncertainty budget: contributions, each with a standard "
                        "uncertainty u or a half_width, a distribution, a sensitivity c and "
                        "optional degrees of freedom; coverage probability and Monte Carlo "
                        "trials (docs/formats.md#uncertainty-budget; example: "
                        "sample_data/budget/ballplate_budget.json)")


def _report_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("analysis", metavar="ANALYSIS.json",
                   help="analysis record: data files (paths relative to the record), model "
                        "spec, order, plate mode, σ in µm, exclusions, exclude_outliers "
                        "(default false: flagged outliers stay in the fit), diagnosis, GP, "
                        "MPE and magnification choices (docs/report.md; example: "
                        "sample_data/thesis/analysis.json)")
    p.add_argument("--any-path", action="store_true",
                   help="read the files the record names wherever they are; by default "
                        "every one must lie in the record's folder or below it, so that a "
                        "record from elsewhere cannot make the program read other files "
                        "on this computer")
    p.add_argument("--out", required=True, metavar="REPORT.html",
                   help="HTML file to write (plotly inline, opens offline; about 2 MB); "
                        "required. The χ² test of the fit is printed as JSON")


def _air_arguments(p: argparse.ArgumentParser) -> None:
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


# --- plan, task

MAX_TRIALS = 10**7
"""Most Monte Carlo trials of ``task --trials`` (the task file's ``trials`` has the same
range, from :data:`MIN_TRIALS`)."""
MIN_TRIALS = 100
MAX_CHECK_TRIALS = 10**5
"""Most simulated data sets per strategy of ``plan --check-trials``."""
MAX_WORKERS = 1024
"""Most local Dask workers of ``plan --workers``."""


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``plan``."""
    p.add_argument("plan", metavar="PLAN.json",
                   help="measurement plan: setup (machine, placements, styli offsets in mm), "
                        "plate (rows, cols, pitch_mm, certificate_u_um in µm), model, "
                        "noise_um (µm), measurement order and timing (minutes), strategies "
                        "to compare and an optional design section (docs/planning.md; "
                        "example: sample_data/plans/thesis_plan.json); required")
    p.add_argument("--no-detection", action="store_true",
                   help="skip the detection limits of the catalogue effects (default: "
                        "computed for every effect the diagnosis would try)")
    p.add_argument("--check-trials", type=number_arg(int, 0, MAX_CHECK_TRIALS), default=0,
                   metavar="N",
                   help="Monte Carlo check of each strategy (and of the designed plan): "
                        "simulate N data sets with noise and the prior errors, run the real "
                        "fit and the diagnosis's tests, and compare the observed U2/U3 and "
                        "detection rates with the predictions; runs on Dask; 0 to "
                        f"{MAX_CHECK_TRIALS} (default: %(default)s, no check)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="Dask scheduler address for the Monte Carlo check, e.g. "
                        "tcp://10.0.0.5:8786 (default: a local cluster of --workers "
                        "processes on this machine)")
    p.add_argument("--workers", type=number_arg(int, 1, MAX_WORKERS), default=2, metavar="N",
                   help="workers of the local Dask cluster when no --scheduler is given, "
                        f"1 to {MAX_WORKERS} (default: %(default)s)")


def add_task_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``task``."""
    p.add_argument("model", metavar="MODEL.json",
                   help="fitted model written by 'fit --save' (kinematic coefficients and "
                        "their covariance, styli offsets in mm); required")
    p.add_argument("task", metavar="TASK.json",
                   help="measurement task: 'distance', 'circle' or 'plane', its points "
                        "(reported tip centres x_mm, y_mm, z_mm in mm, machine frame, with "
                        "the stylus) and the influences (probing noise in µm, workpiece "
                        "temperature in °C, optional discrepancy); docs/planning.md, "
                        "example: sample_data/plans/task_distance.json; required")
    p.add_argument("--trials", type=number_arg(int, MIN_TRIALS, MAX_TRIALS), default=None,
                   metavar="N",
                   help=f"Monte Carlo trials (JCGM 101), {MIN_TRIALS} to {MAX_TRIALS}, "
                        "overriding the task file's 'trials' (default: the task file's "
                        "value, else 20000)")


# --- export (docs/compensation.md)

_MODEL_HELP = ("fitted model written by 'fit --save' (its kinematic coefficients, their "
               "covariance, the layout, strokes and probe offsets). At least one of --grid, "
               "--axis-tables, --results-json, --results-xml, --qif, --msl-parameters is "
               "required; formats in docs/compensation.md (MSL's: docs/msl-format.md)")
_EXPORT_MEAS_HELP = ("for --qif only: the measurement file(s) the model was fitted to, as "
                     "'fit' read them (long or thesis-form CSV, a mapped table, a DMIS or "
                     "QIF file), unchanged: each must be one of the inputs the model file "
                     "records (its SHA-256), so that the document's measured centres are "
                     "those of its parameters")
_EXPORT_SETUP_HELP = ("for --qif only: the setup JSON the model was fitted with (machine, "
                      "placements, styli, calibration date); required with MEAS files (default: "
                      "none)")
_EXPORT_CERT_HELP = ("for --qif only: the plate certificate CSV the model was fitted with "
                     "(the nominal ball centres and their uncertainties); a QIF calibration "
                     "document needs one (default: none)")
_QIF_HELP = ("write the calibration as an ANSI/DMSC QIF 3.0 document (QIFDocument, "
             "schema-valid): the CMM, each placement's measured ball centres (mm, "
             "labelled position/probe/ball) with the fit's repeatability as their "
             "standard uncertainty, and in its extension the fitted parameters with "
             "standard and expanded uncertainties (k = --coverage-factor), the χ² test and "
             "the certificate; provenance in its header (docs/formats.md, \"QIF 3.0\"). "
             "Needs the data the model was fitted to: MEAS files, --setup and "
             "--certificate (or --msl snapshots). Default: not written")
_MSL_PARAMETERS_HELP = ("write the fitted machine as an MSL cmm-error-map metadata file "
                        "(docs/msl-format.md, \"Writing MSL's form\"): the layout flags, "
                        "the strokes, the probe (--probe, default the ram reference point) "
                        "and the 21 model parameters as power series in mm and rad, in "
                        "MSL's sign; what the MSL reader here reads back to the same "
                        "coefficients. No provenance line (MSL's files start with 'save "
                        "time'): the title names the model file and its SHA-256. A model "
                        "with undetermined combinations is refused unless "
                        "--allow-undetermined. Default: not written")
_GRID_STEP_HELP = ("spacing of the 3-D compensation grid along each axis, mm, 0.1 to 10000; "
                   "one number for all axes or three (x,y,z), e.g. 100 or 100,100,50. Each "
                   "axis runs "
                   "from 0 to its stroke, the last interval shorter when the stroke is not "
                   "a multiple (default: %(default)s mm)")
_AXIS_STEP_HELP = ("spacing of the rows of the per-axis tables, mm, 0.1 to 10000 (default: "
                   "the grid step; the first of three)")
_PROBE_HELP = ("stylus of the model whose tip the grid corrects; default: none, the ram "
               "reference point (offset 0 0 0 mm), as a controller's table; also the "
               "probe --msl-parameters writes. The per-axis tables do not depend on the "
               "stylus")
_GRID_HELP = ("write the 3-D grid compensation table to this CSV: at each node the "
              "correction (true minus indicated, µm, added to the reading) in x, y, z and "
              "its standard uncertainty (k = 1), with a header block (units, sign, layout, "
              "probe, grid, model and its χ² test). Default: not written")
_AXES_HELP = ("write the per-axis tables to this directory (created if missing): "
              "axis_x.csv, axis_y.csv, axis_z.csv (positioning, two straightness, three "
              "rotations along each axis, µm and µrad, with standard uncertainties) and "
              "squareness.csv (µrad). Default: not written")
_RESULTS_JSON_HELP = ("write the fitted parameters with standard and expanded uncertainties "
                      "and the χ² test outcome as a results JSON document (schema version "
                      "1). Default: not written")
_XML_HELP = ("write the same results as QIF-like XML (MeasurementResults: machine, "
             "artefact, one characteristic per parameter with value, unit, standard "
             "uncertainty, coverage factor, expanded uncertainty; the χ² test). Default: "
             "not written")
_K_HELP = ("coverage factor k of the expanded uncertainties U = k·u in the results files, "
           "1 to 10 (default: %(default)s, about 95 %% for a normal distribution)")
_UNDET_HELP = ("write the tables (and --msl-parameters) even when the model has parameter "
               "combinations the data "
               "do not determine (their corrections are then an arbitrary choice and the "
               "uncertainties empty); without it such a model is refused (exit 2)")


def _step(text: str):
    """A positive step in mm, or three comma-separated ones."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a step in mm (e.g. 100) or three (100,100,50), found {text[:40]!r}"
        ) from None
    if len(vals) not in (1, 3) or not all(math.isfinite(v) and 0.1 <= v <= 1e4 for v in vals):
        raise argparse.ArgumentTypeError(
            f"expected one or three steps from 0.1 to 10000 mm, found {text[:40]!r}")
    return vals[0] if len(vals) == 1 else tuple(vals)


def _coverage(text: str) -> float:
    try:
        k = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a coverage factor (e.g. 2), found {text[:40]!r}") from None
    if not (math.isfinite(k) and 1.0 <= k <= 10.0):
        raise argparse.ArgumentTypeError(f"expected a coverage factor from 1 to 10, found {k:g}")
    return k


def add_export_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``export`` (every one with the help text a metrologist reads)."""
    p.add_argument("model", metavar="MODEL.json", help=_MODEL_HELP)
    p.add_argument("--grid-step-mm", type=_step, default=100.0, metavar="MM",
                   help=_GRID_STEP_HELP)
    p.add_argument("--axis-step-mm", type=_step, default=None, metavar="MM",
                   help=_AXIS_STEP_HELP)
    p.add_argument("--probe", default=None, metavar="NAME", help=_PROBE_HELP)
    p.add_argument("--grid", metavar="OUT.csv", help=_GRID_HELP)
    p.add_argument("--axis-tables", metavar="DIR", help=_AXES_HELP)
    p.add_argument("--results-json", metavar="OUT.json", help=_RESULTS_JSON_HELP)
    p.add_argument("--results-xml", metavar="OUT.xml", help=_XML_HELP)
    p.add_argument("--qif", metavar="OUT.qif", help=_QIF_HELP)
    p.add_argument("--msl-parameters", metavar="OUT.csv", help=_MSL_PARAMETERS_HELP)
    p.add_argument("--coverage-factor", type=_coverage, default=2.0, metavar="K",
                   help=_K_HELP)
    p.add_argument("--allow-undetermined", action="store_true", help=_UNDET_HELP)
    # the data of --qif, read as the fitting commands read them (cli.inputs.dataset_of)
    p.add_argument("meas", nargs="*", metavar="MEAS.csv", help=_EXPORT_MEAS_HELP)
    p.add_argument("--setup", metavar="SETUP.json", help=_EXPORT_SETUP_HELP)
    p.add_argument("--certificate", metavar="CERT.csv", help=_EXPORT_CERT_HELP)
    add_foreign_args(p)


# --- check, compare (docs/monitoring.md)

_CALIBRATION_HELP = ("the stored calibration: a model file written by 'fit --save' (kinematic "
                     "coefficients with their covariance, σ, layout, strokes and styli)")
_NEW_MEAS_HELP = ("the new measurements (long CSV, docs/formats.md): one placement of the "
                  "plate is enough; several files are read as one; none when instruments "
                  "alone (--laser, --step-gauge, --ball-bar) are the check")
_NEW_SETUP_HELP = ("setup JSON of the new measurements (layout, strokes, placements, styli; "
                   "required with measurements; default: none, for instruments alone): the "
                   "machine must be the model's")
_REPORT_HELP = ("write the HTML report of the check (an analysis record of the new data "
                "with its section 'Interim check', docs/report.md); needs plate "
                "measurements (default: no report)")
_RESULTS_HELP = ("write the results document (JSON, docs/compensation.md) with its section "
                 "'%s': the numbers with their uncertainties and decision rules (default: "
                 "none)")
_CHECK_CERT_HELP = ("certificate CSV of the plate (calibrated ball centres with their "
                    "uncertainties): the check predicts the balls from it (default: the one "
                    "the setup names; one of the two is required)")
_CHECK_SIGMA_HELP = ("repeatability of one probed coordinate of the new data, µm, 0.001 to "
                     "1000 (default: the stored model's σ)")
_ALPHA_HELP = ("false-alarm level of the check, 0.001 to 0.2 (default: %(default)s): at most "
               "the fraction of checks of an unchanged machine that say 'changed'; half of "
               "it goes to the χ² test of all the new data, half to the test of the fewest "
               "physical changes (a scale, a squareness, an error function, a stylus), "
               "Bonferroni")
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
_NODES_HELP = (f"grid nodes per axis of the error map's change, 2 to {_MAX_MAP_NODES_PER_AXIS} "
               "(default: %(default)s)")


_LEVEL = number_arg(float, 0.001, 0.2)
"""A false-alarm level: 0.1 % to 20 %."""


def _mpe(text: str) -> tuple[float, float]:
    """``--mpe``: ``monitor.parse_mpe`` (the app's field reads it there too)."""
    # lazy: only a given --mpe is read, by the monitor wing (numpy): --help loads none
    from ..monitor import parse_mpe

    try:
        return parse_mpe(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _check_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL.json", help=_CALIBRATION_HELP)
    p.add_argument("meas", nargs="*", metavar="MEAS.csv", help=_NEW_MEAS_HELP)
    p.add_argument("--setup", metavar="SETUP.json", default=None, help=_NEW_SETUP_HELP)
    p.add_argument("--certificate", metavar="CERT.csv", help=_CHECK_CERT_HELP)
    p.add_argument("--sigma-um", type=number_arg(float, 1e-3, 999.999, "µm"), default=None,
                   metavar="UM", help=_CHECK_SIGMA_HELP)
    p.add_argument("--alpha", type=_LEVEL, default=0.05, metavar="LEVEL", help=_ALPHA_HELP)
    p.add_argument("--family-alpha", type=_LEVEL, default=0.05, metavar="LEVEL",
                   help=_FAMILY_HELP)
    p.add_argument("--positions", default=None, metavar="P1,P2", help=_POS_HELP)
    p.add_argument("--mpe", type=_mpe, default=None, metavar="A,D", help=_MPE_HELP)
    add_instrument_args(p)
    p.add_argument("--report", metavar="OUT.html", default=None, help=_REPORT_HELP)
    p.add_argument("--results-json", metavar="OUT.json", default=None,
                   help=_RESULTS_HELP % "interim_check")


def _compare_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("models", nargs="+", metavar="MODEL.json", help=_MODELS_HELP)
    p.add_argument("--dates", nargs="+", required=True, metavar="YYYY-MM-DD",
                   help=_DATES_HELP)
    p.add_argument("--family-alpha", type=_LEVEL, default=0.05, metavar="LEVEL",
                   help=_FAMILY_HELP)
    p.add_argument("--nodes", type=number_arg(int, 2, _MAX_MAP_NODES_PER_AXIS), default=5,
                   metavar="N", help=_NODES_HELP)
    p.add_argument("--results-json", metavar="OUT.json", default=None,
                   help=(_RESULTS_HELP % "history").replace(" (default", ", beside the "
                                                             "latest calibration's parameters "
                                                             "(default"))


# --- next (issue 29, docs/proposals.md)

_MAX_TOP = 100
"""Most proposals ``--top`` lists."""


def _rivals_arg(text):
    """Two or more different model tokens separated by commas (``sxy,rxz:4``; an alias
    set: ``dzz:4,probe_offset,drift``)."""
    parts = [t.strip() for t in str(text).split(",")]
    if len(parts) < 2 or not all(parts) or len(set(parts)) != len(parts):
        raise argparse.ArgumentTypeError(
            f"expected two or more different effect tokens separated by commas (e.g. "
            f"'probe_offset,drift'), found {text[:60]!r}")
    return tuple(parts)


def _next_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``next``."""
    add_data_args(p)
    p.add_argument("--baseline", default="kinematic21", metavar="SPEC", type=_spec_arg,
                   help="model the diagnosis starts from, as a model spec "
                        "(docs/formats.md#model-specs), e.g. 'kinematic21,-sxy' "
                        "(default: %(default)s)")
    p.add_argument("--order", type=_order_arg, default=None, metavar="N",
                   help=f"default polynomial order of the error functions (default: "
                        f"{DEFAULT_ORDER}; with MSL files the degree of the model "
                        "parameters their metadata lists)")
    p.add_argument("--plate", choices=("fixed", "prior", "free"),
                   help="plate geometry in the fits: certificate fixed, as a prior, or free "
                        "(default: fixed with a certificate)")
    p.add_argument("--sigma-um", type=_sigma_arg, default=None, metavar="UM|auto",
                   help="repeatability of one probed coordinate in µm (0.001 to 1000), or "
                        f"'auto' to estimate it from the data (default: {DEFAULT_SIGMA_UM} "
                        "µm; with MSL simulated files the rounding of their decimals)")
    p.add_argument("--rivals", type=_rivals_arg, metavar="A,B[,C]", default=None,
                   help="the effects to tell apart, as model tokens separated by commas, "
                        "e.g. 'probe_offset,drift' or an alias set 'dzz:4,probe_offset,"
                        "drift' (each of another function: not 'rxz:3,rxz:4'); the second "
                        "of two may be 'placement_scale' (each placement's own scale) or "
                        "'baseline' (the model as it is: for an effect the data cannot "
                        "determine in full) (default: the diagnosis's first candidate with "
                        "all its aliases, or its runner-up)")
    p.add_argument("--top", type=number_arg(int, 1, _MAX_TOP), default=5, metavar="N",
                   help=f"how many proposals to list, best first, 1 to {_MAX_TOP} (default: "
                        "%(default)s)")
    p.add_argument("--reference", metavar="PLACEMENT", default=None,
                   help="placement the candidates are derived from (default: the first "
                        "horizontal one)")
    p.add_argument("--target-power", type=number_arg(float, 0.01, 0.999),
                   default=_TARGET_POWER, metavar="P",
                   help="power at which a proposal counts as deciding the pair (default: "
                        "%(default)s)")
    p.add_argument("--instruments", action="store_true",
                   help="also score instrument candidates: laser positioning runs along X, "
                        "Y, Z, step gauges along X and Y, a ball bar in XY (default: plate "
                        "placements and styli only; --plan-out takes plate proposals only)")
    p.add_argument("--simulate", action="store_true",
                   help="also simulate the top proposal (a placement, stylus, repeat or "
                        "instrument run) with each rival as the truth, append it to the data "
                        "and run the diagnosis (adds a few seconds)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the noise of --simulate (default: %(default)s)")
    p.add_argument("--plan-out", metavar="PLAN.json", default=None,
                   help="write the top placement, stylus or repeat proposal as a plan file "
                        "for 'plan' (docs/planning.md: a repeat is the strategy's "
                        "repeat_at_end; an instrument run cannot be a plan: the next one "
                        "down is written; default: not written)")


# --- the table of sub-commands


@dataclass(frozen=True)
class Subcommand:
    """One sub-command: its line in ``--help``, the function adding its options, and the
    function it runs, named ``"module:function"`` of this wing (``args -> JSON-ready
    dict``). Set as the parsed arguments' ``func``, it imports that module when called:
    not before the command runs, and only the one it needs."""

    help: str
    arguments: Callable[[argparse.ArgumentParser], None]
    run: str
    serves: bool = False
    """A server (``app``): it runs until stopped and returns its exit status, not a JSON
    document; it has no ``--json``."""

    def __call__(self, args: argparse.Namespace) -> Any:
        module, name = self.run.split(":")
        # imported when the command runs, not when the parser is built (--help, usage errors)
        # lazy: a command's module brings the wings it uses (numpy, scipy, pandas, plotly)
        return getattr(importlib.import_module(f"{__package__}.{module}"), name)(args)


COMMANDS: dict[str, Subcommand] = {
    "simulate": Subcommand("simulate a virtual CMM", _simulate_arguments,
                           "simulate:cmd_simulate"),
    "fit": Subcommand("fit the kinematic model", _fit_arguments, "fitting:cmd_fit"),
    "diagnose": Subcommand("rank the effects missing from a baseline model",
                           _diagnose_arguments, "fitting:cmd_diagnose"),
    "compensate": Subcommand("correct points with a saved model", _compensate_arguments,
                             "compensate:cmd_compensate"),
    "gp": Subcommand("Gaussian-process model of the errors", _gp_arguments,
                     "fitting:cmd_gp"),
    "budget": Subcommand("GUM uncertainty budget", _budget_arguments, "budget:cmd_budget"),
    "report": Subcommand("self-contained HTML report of an analysis record",
                         _report_arguments, "report:cmd_report"),
    "air": Subcommand("refractive index of air (modified Edlén)", _air_arguments,
                      "budget:cmd_air"),
    "plan": Subcommand("evaluate, compare and design measurement plans before measuring",
                       add_plan_arguments, "plan:cmd_plan"),
    "task": Subcommand("task-specific uncertainty of a distance, circle or plane measured "
                       "with a fitted machine", add_task_arguments, "plan:cmd_task"),
    "export": Subcommand("compensation tables (3-D grid, per-axis) and results files (JSON, "
                         "QIF-like XML) from a saved model", add_export_arguments,
                         "export:command"),
    "check": Subcommand("interim check of new measurements against a stored calibration: χ² "
                        "test, E_n per ball, what changed, conformity to the MPE",
                        _check_arguments, "check:_command_check"),
    "compare": Subcommand("a machine's calibration history: every shared parameter's change "
                          "with u and E_n, significant changes, the error map's change",
                          _compare_arguments, "check:_command_compare"),
    "next": Subcommand("propose the measurement that tells two rival effects apart",
                       _next_arguments, "proposals:run"),
    "app": Subcommand("start the app in the browser (on this computer only unless --host "
                      "says otherwise); Ctrl+C stops it", add_app_arguments, "app:serve_app",
                      serves=True),
}
"""Every sub-command, in the order ``--help`` lists them (docs/formats.md)."""


def add_command(subparsers: argparse._SubParsersAction, name: str
                ) -> argparse.ArgumentParser:
    """Add the sub-command ``name`` of :data:`COMMANDS` to ``subparsers``: its options, and
    ``func`` (its :class:`Subcommand`) that ``cli.main`` calls with the parsed arguments."""
    command = COMMANDS[name]
    p = subparsers.add_parser(name, help=command.help)
    command.arguments(p)
    p.set_defaults(func=command)
    return p


def build_parser() -> argparse.ArgumentParser:
    """Argument parser with one sub-command per command of docs/formats.md."""
    ap = _Parser(prog=program_name(), description="CMM error lab")
    ap.add_argument("--json", metavar="FILE", help=_JSON_HELP)
    sub = ap.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        add_command(sub, name)
    for name, p in sub.choices.items():  # --json after the command too (SUPPRESS: no override)
        if not COMMANDS[name].serves:
            p.add_argument("--json", metavar="FILE", default=argparse.SUPPRESS,
                           help=_JSON_HELP)
    return ap

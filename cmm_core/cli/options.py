"""The options that several sub-commands of the command line share (the data files, the
instruments, the model options, σ and the outlier rule), their argparse types and the help
texts a metrologist reads in ``--help``.

Standard library only, as :mod:`.parser`: ``--help`` and a usage error build the whole
parser without loading numpy, scipy, pandas or plotly. The limits the help texts state are
therefore copies of the core's (a wing's face loads its whole wing), each pinned equal to
the one it copies by ``tests/test_cli_start.py``.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

_MAX_ORDER = 5
"""``model.MAX_ORDER``, the highest polynomial order of an error function (a copy: see
the module's docstring)."""
_TARGET_POWER = 0.9
"""``plan.TARGET_POWER``, the default of ``next --target-power`` (a copy)."""
_MAX_MAP_NODES_PER_AXIS = 21
"""``monitor.MAX_MAP_NODES_PER_AXIS``, the largest ``compare --nodes`` (a copy)."""
_QIF_LABEL_PATTERN = r"(?P<position>.+)/(?P<probe>[^/]+)/(?P<ball>\d+)"
"""``io.QIF_LABEL_PATTERN``, the default of ``--qif-pattern`` (a copy)."""
DEFAULT_ORDER = 2
"""``--order`` when neither the command line nor an MSL metadata file states it."""
DEFAULT_SIGMA_UM = 0.5
"""``--sigma-um`` when neither the command line nor an MSL simulation states it."""
_MSL_ROUNDING_UM = 0.0029
"""``io.MSL_ROUNDING_U_UM`` to two digits, for the help texts (a copy)."""
_MSL_CERTIFICATE_A_UM = (0.0, 100.0)
_MSL_CERTIFICATE_B_UM_PER_MM = (0.0, 1.0)
"""The ranges ``io`` accepts for a certificate's ``U_um`` (a copy: ``--msl-certificate-u``
is checked at parsing, naming the flag, not later in a setup the user never wrote)."""

MEAS_HELP = ("measurement CSV file(s), coordinates in mm: one long-form file "
              "(position,probe,ball,x_mm,y_mm,z_mm[,time_min,temp_C,repeat,temp_x_C,temp_y_C,temp_z_C]) or one "
              "thesis-form file per position (ball,x_mm,y_mm,z_mm, named after the position); "
              "see docs/formats.md")
SETUP_HELP = ("setup JSON: machine layout and range, each position's placement (mm) and "
               "stylus, the probe offsets (mm), the certificate's uncertainty statement; "
               "default: none, and then required with MEAS files (MSL snapshots bring "
               "their own) (docs/formats.md#setup)")
CERT_HELP = ("plate certificate CSV (ball,x_mm,y_mm,z_mm[,u_x_um,u_y_um,u_z_um]), mm and "
              "µm; without the u columns the setup must state its uncertainty "
              "(\"certificate\": {\"U_um\": [a, b], \"k\": 2}) or that it is exact; "
              "default: none, the plate geometry is then fitted (self-calibration)")
ORDER_HELP = (f"polynomial order of each error function along its axis, 1 (linear) to "
              f"{_MAX_ORDER} (default: {DEFAULT_ORDER}; with MSL files the degree of the "
              "model parameters their metadata lists, 1 in MSL's own files; a note says "
              "which)")
PLATE_HELP = ("plate geometry: 'fixed' to the certificate, the certificate as a 'prior' "
               "with its uncertainties, or 'free' (self-calibrated). Default: fixed with a "
               "certificate, free without")


_LASER_HELP = ("laser interferometer run CSV, machine axes: [run,]axis[,component],x_mm,y_mm,"
               "z_mm,error_um,u_um[,offset_x_mm,offset_y_mm,offset_z_mm]: the indicated "
               "point (mm), the error reading, indicated minus true, relative to the run's "
               "zero (µm) and its standard uncertainty (µm); component = axis is "
               "positioning, another straightness. Fitted jointly with the plate; "
               "repeatable (docs/instruments.md). Default: none")
_STEP_GAUGE_HELP = ("step gauge / gauge block CSV, machine axes: [gauge,]x1_mm,y1_mm,z1_mm,"
                    "x2_mm,y2_mm,z2_mm,measured_mm,certified_mm,u_um[,offset_x_mm,"
                    "offset_y_mm,offset_z_mm][,temp_C,cte_per_K]: the indicated tip centres "
                    "of the two probings and the lengths (mm), the standard uncertainty of "
                    "measured minus certified length (µm). Fitted jointly with the plate; "
                    "repeatable (docs/instruments.md). Default: none")
_BALL_BAR_HELP = ("ball bar CSV, machine axes: [bar,]x1_mm,y1_mm,z1_mm,x2_mm,y2_mm,z2_mm,"
                  "certified_mm,u_um[,offset_x_mm,offset_y_mm,offset_z_mm][,temp_C,"
                  "cte_per_K]: the indicated centres of the bar's two balls and its "
                  "certified length (mm), the standard uncertainty of indicated minus "
                  "certified length (µm); one row per placement of the bar. Fitted jointly "
                  "with the plate; repeatable (docs/instruments.md). Default: none")


def add_instrument_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--laser", action="append", default=[], metavar="RUN.csv",
                   help=_LASER_HELP)
    p.add_argument("--step-gauge", action="append", default=[], metavar="SG.csv",
                   help=_STEP_GAUGE_HELP)
    p.add_argument("--ball-bar", action="append", default=[], metavar="BB.csv",
                   help=_BALL_BAR_HELP)


def add_foreign_args(p: argparse.ArgumentParser) -> None:
    """Files other tools write (docs/foreign-formats.md, docs/msl-format.md)."""
    p.add_argument("--mapping", metavar="MAPPING.json",
                   help="column mapping JSON: read every MEAS file as a table from other "
                        "software (which column is position, probe, ball, x, y, z; the unit "
                        "mm/um/inch; the decimal separator), see docs/foreign-formats.md. "
                        "Default: none, MEAS files are in this project's long or thesis form")
    p.add_argument("--dmis-pattern", metavar="REGEX",
                   help="regular expression every sphere label of a DMIS output file (.dmo) "
                        "must match, with named groups ball and optionally position and "
                        "probe, e.g. 'BP(?P<position>\\w+)_(?P<ball>\\d+)'; default: none, "
                        "required for .dmo files")
    p.add_argument("--qif-pattern", metavar="REGEX",
                   help="regular expression every measured sphere's label "
                        "(SphereFeatureMeasurement FeatureName) of a QIF 3.0 results "
                        "document (.qif, or .xml that is a QIFDocument) must match, with "
                        "named groups ball and optionally position and probe; default: "
                        f"'{_QIF_LABEL_PATTERN}', the position/probe/ball labels of "
                        "'export --qif' (docs/formats.md, "
                        "\"QIF 3.0\")")
    p.add_argument("--default-probe", default="1", metavar="NAME",
                   help="probe of DMIS or QIF spheres whose label has no probe group "
                        "(default: %(default)s)")
    p.add_argument("--msl", action="append", default=[], metavar="SNAPSHOT.csv",
                   help="MSL cmm-error-map plate snapshot, read with its conventions "
                        "(ball numbering, origin = location + probe, angles, layout flags, "
                        "sign; docs/msl-format.md) instead of MEAS files; repeatable, one "
                        "placement each (a placement given twice is refused), with "
                        "--msl-bar too (default: none)")
    p.add_argument("--msl-metadata", action="append", default=[], metavar="METADATA.csv",
                   help="MSL metadata file (layout flags, probe, machine size, model "
                        "parameters) of an --msl or --msl-bar snapshot: each is paired with "
                        "the snapshot whose header it repeats (name, artefact, location, "
                        "rotation), in any order; repeatable. Default: the metadata.csv "
                        "saved beside each snapshot (MSL saves the two together), said in a "
                        "note; a snapshot with neither is refused, since it does not say "
                        "the machine")
    p.add_argument("--msl-bar", action="append", default=[], metavar="SNAPSHOT.csv",
                   help="MSL bar (step gauge) snapshot, fitted as a step gauge with the "
                        "--msl plates, or alone; repeatable (default: none)")
    p.add_argument("--msl-kind", choices=("simulated", "measured"),
                   help="what the MSL files hold, required with --msl and --msl-bar (the "
                        "files do not say): 'simulated' deviations (nominal + deviation, "
                        "certificate exact, σ the rounding of their decimals, "
                        f"{_MSL_ROUNDING_UM} µm for 5) or 'measured' coordinates "
                        "(default: none)")
    p.add_argument("--msl-certificate-u", metavar="A_UM,B_UM_PER_MM",
                   type=_msl_certificate_arg,
                   help="the artefact's certificate U(k=2) = sqrt(A² + (B·L)²) µm, L mm from "
                        "ball 1, A 0 to 100 µm and B 0 to 1 µm/mm, not both 0, for "
                        "--msl-kind measured (default: none; required then)")


def msl_metadata_beside(args: argparse.Namespace) -> list[str]:
    """The ``metadata.csv`` beside each ``--msl`` / ``--msl-bar`` snapshot that exists and
    is not given with ``--msl-metadata``: the files the default of ``--msl-metadata`` may
    read, so that no output overwrites them and a record names them (``cli.commands``)."""
    given = {str(m) for m in getattr(args, "msl_metadata", None) or []}
    out = []
    for snap in [*(getattr(args, "msl", None) or []), *(getattr(args, "msl_bar", None) or [])]:
        beside = str(Path(snap).with_name("metadata.csv"))
        if beside not in given and beside not in out and Path(beside).is_file():
            out.append(beside)
    return out


def add_data_args(p: argparse.ArgumentParser) -> None:
    """The data files of every fitting command: this project's, or other tools'."""
    p.add_argument("meas", nargs="*", metavar="MEAS.csv", help=MEAS_HELP)
    p.add_argument("--setup", metavar="SETUP.json", help=SETUP_HELP)
    p.add_argument("--certificate", metavar="CERT.csv", help=CERT_HELP)
    add_foreign_args(p)


def add_fit_args(p: argparse.ArgumentParser, *, baseline: bool = False) -> None:
    add_data_args(p)
    if baseline:
        p.add_argument("--baseline", default="kinematic21", metavar="SPEC", type=_spec_arg,
                       help="model the diagnosis starts from, as a model spec "
                            "(docs/formats.md#model-specs), e.g. 'kinematic21,-sxy' "
                            "(default: %(default)s, the 21 errors)")
    else:
        p.add_argument("--model", default="kinematic21", metavar="SPEC", type=_spec_arg,
                       help="model to fit, as a model spec (docs/formats.md#model-specs), "
                            "e.g. 'kinematic21,plate_sag' or 'translational,squareness' "
                            "(default: %(default)s, the 21 errors)")
    p.add_argument("--order", type=_order_arg, default=None, metavar="N", help=ORDER_HELP)
    p.add_argument("--plate", choices=("fixed", "prior", "free"), help=PLATE_HELP)
    p.add_argument("--sigma-um", type=_sigma_arg, default=None, metavar="UM|auto",
                   help="repeatability of one probed coordinate, standard deviation in µm "
                        "(0.001 to 1000): "
                        f"weights the fit and scales every uncertainty (default: "
                        f"{DEFAULT_SIGMA_UM} µm; with MSL simulated files the rounding of "
                        f"their decimals, {_MSL_ROUNDING_UM} µm for 5; a note says which). "
                        "'auto' estimates it from the data (repeated "
                        "balls where the file has a repeat column, else the residuals of "
                        "the most flexible model the data determine) and reports the "
                        "estimate with its uncertainty under \"sigma\"")
    add_outlier_args(p)


def add_outlier_args(p: argparse.ArgumentParser) -> None:
    """The outlier rule of the app and the analysis record (``analysis.
    DEFAULT_EXCLUDE_OUTLIERS``): flagged observations are listed, and kept unless asked."""
    p.add_argument("--exclude-outliers", action="store_true",
                   help="leave out every observation the robust median/MAD check across "
                        "the placements flags (default: they are fitted, and listed under "
                        "\"outliers\" in the JSON with their deviation in µm so that you "
                        "can decide; the app and an analysis record keep them too)")
    p.add_argument("--keep-outliers", action="store_true",
                   help="fit the flagged observations: what happens without "
                        "--exclude-outliers (accepted for scripts written when exclusion "
                        "was the command line's default)")


def _spec_arg(text):
    """A model spec that names something: an empty one would silently fit the rigid
    alignment alone."""
    if not any(t.strip() for t in str(text).split(",")):
        raise argparse.ArgumentTypeError(
            "the model spec is empty; give one such as 'kinematic21' "
            "(docs/formats.md#model-specs)")
    return text


def _order_arg(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a polynomial order 1 to {_MAX_ORDER}, found {text[:40]!r}") from None
    if not 1 <= value <= _MAX_ORDER:
        raise argparse.ArgumentTypeError(
            f"expected a polynomial order 1 to {_MAX_ORDER}, found {value}")
    return value


def _msl_certificate_arg(text):
    """``A,B`` of ``--msl-certificate-u``: two numbers in the certificate ranges, not both
    zero (an exact certificate is a simulation's: ``--msl-kind simulated``)."""
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected A_UM,B_UM_PER_MM (two numbers, e.g. 0.26,0.0019), found "
            f"{text[:40]!r}") from None
    (alo, ahi), (blo, bhi) = _MSL_CERTIFICATE_A_UM, _MSL_CERTIFICATE_B_UM_PER_MM
    if not (math.isfinite(a) and math.isfinite(b) and alo <= a <= ahi and blo <= b <= bhi):
        raise argparse.ArgumentTypeError(
            f"expected A from {alo:g} to {ahi:g} µm and B from {blo:g} to {bhi:g} µm/mm, "
            f"found {text[:40]!r}")
    if a == 0 and b == 0:
        raise argparse.ArgumentTypeError(
            "A and B are both 0: a measured artefact's certificate has an uncertainty "
            "(a noise-free simulation's grid is exact: --msl-kind simulated, without "
            "--msl-certificate-u)")
    return a, b


def _sigma_arg(text):
    if text.strip().lower() == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a repeatability in µm (e.g. 0.5) or 'auto', found {text[:40]!r}") from None
    if not 1e-3 <= value < 1e3:
        # below a nanometre no CMM repeats: a value in mm or m typed as µm
        raise argparse.ArgumentTypeError(
            f"expected a repeatability in µm from 0.001 to 1000, found {value:g}")
    return value


def number_arg(kind: type, lo: float, hi: float, unit: str = "") -> Callable[[str], float]:
    """An argparse type: a ``kind`` (int or float) from ``lo`` to ``hi``, refused in one
    line with the range otherwise."""
    what = "a whole number" if kind is int else "a number"
    unit = f" {unit}" if unit else ""
    # whole numbers written out in full (10000000, not 1e+07)
    span = f"{int(lo)} to {int(hi)}" if kind is int else f"{lo:g} to {hi:g}"

    def parse(text):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {what} from {span}{unit}, found {text[:40]!r}") from None
        if not (math.isfinite(v) and lo <= v <= hi):
            raise argparse.ArgumentTypeError(
                f"expected {what} from {span}{unit}, found {v:g}")
        return v

    parse.__name__ = kind.__name__  # argparse names the type in its own messages
    return parse

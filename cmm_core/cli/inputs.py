"""What the fitting commands read (``fit``, ``diagnose``, ``gp``): the data files, the
instruments fitted with the plate, the model options, σ and the outlier rule, with the
help texts a metrologist reads in ``--help``."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..diagnosis import detect_outliers, estimate_sigma
from ..io import load_dataset
from ..model import read_instrument


def dataset_of(args):

    return load_dataset(args.meas, args.setup, args.certificate,
                        name=", ".join(Path(m).name for m in args.meas))


MEAS_HELP = ("measurement CSV file(s), coordinates in mm: one long-form file "
              "(position,probe,ball,x_mm,y_mm,z_mm[,time_min,temp_C,repeat,temp_x_C,temp_y_C,temp_z_C]) or one "
              "thesis-form file per position (ball,x_mm,y_mm,z_mm, named after the position); "
              "see docs/formats.md")
SETUP_HELP = ("setup JSON: machine layout and range, each position's placement (mm) and "
               "stylus, the probe offsets (mm); required (docs/formats.md#setup)")
CERT_HELP = ("plate certificate CSV (ball,x_mm,y_mm,z_mm[,u_x_um,u_y_um,u_z_um]), mm and "
              "µm; default: none, the plate geometry is then fitted (self-calibration)")
ORDER_HELP = ("polynomial order of each error function along its axis (1 = linear; "
               "default: %(default)s)")
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


def add_instrument_args(p):
    p.add_argument("--laser", action="append", default=[], metavar="RUN.csv",
                   help=_LASER_HELP)
    p.add_argument("--step-gauge", action="append", default=[], metavar="SG.csv",
                   help=_STEP_GAUGE_HELP)
    p.add_argument("--ball-bar", action="append", default=[], metavar="BB.csv",
                   help=_BALL_BAR_HELP)


def instruments_of(args):
    """The instrument files of ``--laser``, ``--step-gauge`` and ``--ball-bar``, read
    (DataError if bad)."""

    return [read_instrument(f, kind) for kind, files in
            (("laser", args.laser), ("step_gauge", args.step_gauge),
             ("ball_bar", args.ball_bar)) for f in files]


def add_fit_args(p, *, baseline=False):
    p.add_argument("meas", nargs="+", metavar="MEAS.csv", help=MEAS_HELP)
    p.add_argument("--setup", required=True, metavar="SETUP.json", help=SETUP_HELP)
    p.add_argument("--certificate", metavar="CERT.csv", help=CERT_HELP)
    if baseline:
        p.add_argument("--baseline", default="kinematic21", metavar="SPEC",
                       help="model the diagnosis starts from, as a model spec "
                            "(docs/formats.md#model-specs), e.g. 'kinematic21,-sxy' "
                            "(default: %(default)s, the 21 errors)")
    else:
        p.add_argument("--model", default="kinematic21", metavar="SPEC",
                       help="model to fit, as a model spec (docs/formats.md#model-specs), "
                            "e.g. 'kinematic21,plate_sag' or 'translational,squareness' "
                            "(default: %(default)s, the 21 errors)")
    p.add_argument("--order", type=int, default=2, metavar="N", help=ORDER_HELP)
    p.add_argument("--plate", choices=("fixed", "prior", "free"), help=PLATE_HELP)
    p.add_argument("--sigma-um", type=_sigma_arg, default=0.5, metavar="UM|auto",
                   help="repeatability of one probed coordinate, standard deviation in µm: "
                        "weights the fit and scales every uncertainty (default: "
                        "%(default)s µm). 'auto' estimates it from the data (repeated "
                        "balls where the file has a repeat column, else the residuals of "
                        "the most flexible model the data determine) and reports the "
                        "estimate with its uncertainty under \"sigma\"")
    add_outlier_args(p)


def add_outlier_args(p):
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


def sigma_of(args, data, exclude, spec):
    """``(σ µm, JSON record)``: the stated value, or the estimate for ``--sigma-um auto``."""
    if args.sigma_um != "auto":
        return args.sigma_um, {"value_um": args.sigma_um, "auto": False}

    est = estimate_sigma(data, spec, order=args.order, plate=args.plate, exclude=exclude)
    return est.value_um, {**est.to_dict(), "auto": True}


def exclusions_of(data, exclude_flagged):

    rep = detect_outliers(data)
    out = [{k: o[k] for k in ("position", "probe", "ball", "axis", "deviation_um")}
           for o in rep.outliers]
    return out, (rep.exclusions if exclude_flagged else [])

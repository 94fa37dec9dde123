"""What the fitting commands read (``fit``, ``diagnose``, ``gp``): the data files, the
instruments fitted with the plate, the model options, σ and the outlier rule, with the
help texts a metrologist reads in ``--help``."""

from __future__ import annotations

import argparse
import io
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..analysis import fit_kwargs
from ..diagnosis import detect_outliers, estimate_sigma
from ..io import (
    DMIS_SUFFIXES,
    DataError,
    Dataset,
    combine_plates,
    load_dataset,
    read_foreign,
    read_machine,
    read_mapping,
    read_msl_bar,
    read_msl_plate,
    sniff,
)
from ..model import (
    MAX_ORDER,
    Observations,
    instrument_observations,
    read_instrument,
    refuse_repeated,
)


def dataset_of(args: argparse.Namespace) -> Dataset:
    """The dataset the fitting commands read: this project's files, tables from other
    software through ``--mapping`` or a DMIS pattern, or MSL cmm-error-map snapshots."""
    if args.msl:
        if args.meas:
            raise DataError("give measurement files or --msl snapshots, not both.",
                            file=str(args.meas[0]))
        metas = args.msl_metadata or [None] * len(args.msl)
        if len(metas) != len(args.msl):
            raise DataError(f"{len(args.msl)} --msl snapshot(s) but {len(metas)} "
                            "--msl-metadata file(s); give one metadata file per snapshot, "
                            "in the same order.", file=str(args.msl[0]))
        cu = _certificate_u_arg(args.msl_certificate_u)
        return combine_plates([read_msl_plate(s, m, kind=args.msl_kind, certificate_u=cu)
                               for s, m in zip(args.msl, metas, strict=True)]).to_dataset()
    if not args.meas:
        raise DataError("no measurement file given.", file="command line",
                        hint="name MEAS.csv file(s), or --msl SNAPSHOT.csv for MSL files.")
    if args.setup is None:
        raise DataError("--setup is required with measurement files.", file="command line",
                        hint="the setup JSON gives the layout, placements and styli "
                             "(docs/formats.md#setup).")
    mapping = read_mapping(args.mapping) if args.mapping else None
    meas = [read_foreign(m, mapping=mapping, pattern=args.dmis_pattern,
                         default_probe=args.default_probe).as_source()
            if mapping is not None or str(m).lower().endswith(DMIS_SUFFIXES) else m
            for m in args.meas]
    try:
        return load_dataset(meas, args.setup, args.certificate,
                            name=", ".join(Path(m).name for m in args.meas))
    except DataError:
        for m in args.meas:  # another tool's file given as ours: name the reader that takes it
            foreign = sniff(m) if isinstance(m, str | Path) else None
            if foreign:
                raise DataError(foreign, file=Path(m).name) from None
        raise


def data_of(args: argparse.Namespace, instruments: list) -> Dataset | Observations:
    """The fitting commands' data: the dataset of :func:`dataset_of`, or, with instrument
    files and no measurement file, an instrument-only fit's observations (the machine
    from ``--setup``, which then needs no positions, or from an ``--msl-bar``'s
    metadata)."""
    if args.meas or args.msl or not instruments:
        return dataset_of(args)
    if args.setup is not None:
        machine = read_machine(args.setup)
    elif args.msl_bar and args.msl_metadata:
        machine = read_machine(read_msl_bar(
            args.msl_bar[0], args.msl_metadata[0], kind=args.msl_kind,
            certificate_u=_certificate_u_arg(args.msl_certificate_u)).setup)
    else:
        raise DataError("an instrument-only fit needs the machine: give --setup (its "
                        "machine.layout and range_mm; no positions needed).",
                        file="command line")
    return instrument_observations(instruments, *machine)


def _certificate_u_arg(text):
    """``--msl-certificate-u A,B`` as the setup's certificate statement (k = 2)."""
    if not text:
        return None
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise DataError(f"--msl-certificate-u expects A_UM,B_UM_PER_MM, found {text[:40]!r}.",
                        file="command line") from None
    return {"U_um": [a, b], "k": 2, "combine": "quadrature"}


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
              f"{MAX_ORDER} (default: %(default)s)")
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


def instruments_of(args: argparse.Namespace) -> list:
    """The instrument files of ``--laser``, ``--step-gauge`` and ``--ball-bar``, read
    (DataError if bad)."""

    given = [(kind, f) for kind, files in (("laser", args.laser),
                                           ("step_gauge", args.step_gauge),
                                           ("ball_bar", args.ball_bar)) for f in files]
    out = [read_instrument(f, kind) for kind, f in given]  # each reader bounds the size
    bars = getattr(args, "msl_bar", [])
    # the metadata files pair with the bars when no plate snapshot (--msl) takes them
    metas = (getattr(args, "msl_metadata", []) if not getattr(args, "msl", []) else []) \
        or [None] * len(bars)
    for snapshot, meta in zip(bars, metas, strict=False):
        bar = read_msl_bar(snapshot, meta, kind=args.msl_kind,
                           certificate_u=_certificate_u_arg(args.msl_certificate_u))
        out.append(read_instrument(io.BytesIO(bar.step_gauge_csv.encode()), "step_gauge",
                                   name=f"{bar.name} (as a step gauge)"))
    refuse_repeated(out)  # before any work, as the fit itself would
    return out


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
    p.add_argument("--default-probe", default="1", metavar="NAME",
                   help="probe of DMIS spheres whose label has no probe group (default: "
                        "%(default)s)")
    p.add_argument("--msl", action="append", default=[], metavar="SNAPSHOT.csv",
                   help="MSL cmm-error-map plate snapshot, read with its conventions "
                        "(ball numbering, origin = location + probe, angles, layout flags, "
                        "sign; docs/msl-format.md) instead of MEAS files; repeatable, one "
                        "placement each, with --msl-metadata in the same order (default: none)")
    p.add_argument("--msl-metadata", action="append", default=[], metavar="METADATA.csv",
                   help="MSL metadata file of each --msl/--msl-bar snapshot (layout flags, "
                        "probe, machine size); default: none (then the snapshot alone)")
    p.add_argument("--msl-bar", action="append", default=[], metavar="SNAPSHOT.csv",
                   help="MSL bar (step gauge) snapshot, fitted as a step gauge; repeatable "
                        "(default: none)")
    p.add_argument("--msl-kind", choices=("simulated", "measured"),
                   help="what the MSL files hold, required with --msl and --msl-bar (the "
                        "files do not say): 'simulated' deviations (nominal + deviation, "
                        "certificate exact) or 'measured' coordinates (default: none)")
    p.add_argument("--msl-certificate-u", metavar="A_UM,B_UM_PER_MM",
                   help="the artefact's certificate U(k=2) = sqrt(A² + (B·L)²) µm, L mm from "
                        "ball 1, A 0 to 100 µm and B 0 to 1 µm/mm, not both 0, for "
                        "--msl-kind measured (default: none; required then)")


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
    p.add_argument("--order", type=_order_arg, default=2, metavar="N", help=ORDER_HELP)
    p.add_argument("--plate", choices=("fixed", "prior", "free"), help=PLATE_HELP)
    p.add_argument("--sigma-um", type=_sigma_arg, default=0.5, metavar="UM|auto",
                   help="repeatability of one probed coordinate, standard deviation in µm "
                        "(0.001 to 1000): "
                        "weights the fit and scales every uncertainty (default: "
                        "%(default)s µm). 'auto' estimates it from the data (repeated "
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
            f"expected a polynomial order 1 to {MAX_ORDER}, found {text[:40]!r}") from None
    if not 1 <= value <= MAX_ORDER:
        raise argparse.ArgumentTypeError(
            f"expected a polynomial order 1 to {MAX_ORDER}, found {value}")
    return value


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


@dataclass(frozen=True)
class CommandChoices:
    """The fit choices of a command line (``analysis.FitChoices``): the fitting commands
    turn them into a fit's keyword arguments by ``analysis.fit_kwargs``, as the analysis
    record and the app do, so that one translation serves all three."""

    spec: str
    """The model spec (``--model``, ``--baseline``)."""
    order: int
    """The default Chebyshev order (``--order``)."""
    plate: str
    """``--plate``, or ``"auto"`` when not given (the fit's default for the data)."""
    sigma_um: float | str
    """``--sigma-um``: µm, or ``"auto"``."""
    exclusions: Sequence[Sequence] = ()
    """``(position, probe, ball)`` left out (the flagged outliers with
    ``--exclude-outliers``)."""
    positions: Sequence[str] | None = None
    """Every position: the command line has no selection."""
    probes: Sequence[str] | None = None
    """Every probe."""


def fit_args_of(args: argparse.Namespace, spec: str, exclude: Sequence[Sequence] = (),
                **more: float) -> dict:
    """Keyword arguments of ``fit`` / ``diagnose`` from the command line's options
    (:class:`CommandChoices` through ``analysis.fit_kwargs``); ``more``: ``sigma_um``."""
    choices = CommandChoices(spec, args.order, args.plate or "auto",
                             getattr(args, "sigma_um", 0.5), tuple(map(tuple, exclude)))
    return fit_kwargs(choices, None, **more)


def sigma_of(args: argparse.Namespace, data: Dataset | Observations, exclude: list,
             spec: str) -> tuple[float, dict]:
    """``(σ µm, JSON record)``: the stated value, or the estimate for ``--sigma-um auto``."""
    if args.sigma_um != "auto":
        return args.sigma_um, {"value_um": args.sigma_um, "auto": False}
    if isinstance(data, Observations):
        raise DataError("--sigma-um auto estimates the plate's repeatability, and an "
                        "instrument-only fit has no plate; give a number (it weighs no "
                        "instrument row: each reading has its own u_um).",
                        file="command line")

    est = estimate_sigma(data, spec, **fit_args_of(args, spec, exclude))
    return est.value_um, {**est.to_dict(), "auto": True}


def exclusions_of(data: Dataset | Observations, exclude_flagged: bool
                  ) -> tuple[list, list]:
    if isinstance(data, Observations):  # instruments only: no plate, no plate outlier
        return [], []
    rep = detect_outliers(data)
    out = [{k: o[k] for k in ("position", "probe", "ball", "axis", "deviation_um")}
           for o in rep.outliers]
    return out, (rep.exclusions if exclude_flagged else [])


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

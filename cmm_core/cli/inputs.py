"""What the fitting commands read (``fit``, ``diagnose``, ``gp``, ``next``, ``check``): the
data files, the instruments fitted with the plate, the model options, σ and the outlier
rule, from the parsed options (their definitions and help texts: :mod:`.options`)."""

from __future__ import annotations

import argparse
import io
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from ..analysis import fit_kwargs
from ..diagnosis import detect_outliers, estimate_sigma
from ..io import (
    DMIS_SUFFIXES,
    DataError,
    Dataset,
    combine_plates,
    is_qif,
    load_dataset,
    read_foreign,
    read_machine,
    read_mapping,
    read_msl_bar,
    read_msl_plate,
    sniff,
)
from ..model import (
    Observations,
    instrument_observations,
    read_instrument,
    refuse_repeated,
)


def dataset_of(args: argparse.Namespace) -> Dataset:
    """The dataset the fitting commands read: this project's files, tables from other
    software through ``--mapping``, DMIS files through ``--dmis-pattern``, QIF documents
    (``.qif``, or XML that is a ``QIFDocument``) through ``--qif-pattern``, or MSL
    cmm-error-map snapshots."""
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
    meas, notes = [], []
    for m in args.meas:
        if mapping is not None or str(m).lower().endswith(DMIS_SUFFIXES) or is_qif(m):
            table = read_foreign(m, mapping=mapping, pattern=args.dmis_pattern,
                                 default_probe=args.default_probe,
                                 qif_pattern=getattr(args, "qif_pattern", None))
            notes += [f"{Path(m).name}: {n}" for n in table.notes]
            meas.append(table.as_source())
        else:
            meas.append(m)
    try:
        ds = load_dataset(meas, args.setup, args.certificate,
                          name=", ".join(Path(m).name for m in args.meas))
        return replace(ds, notes=tuple(notes))
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

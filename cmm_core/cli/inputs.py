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
    MslFiles,
    MslNames,
    is_qif,
    load_dataset,
    msl_degree,
    read_foreign,
    read_machine,
    read_mapping,
    read_msl_files,
    rounding_u_um,
    sniff,
)
from ..model import (
    Observations,
    instrument_observations,
    read_instrument,
    refuse_repeated,
)
from .options import DEFAULT_ORDER, DEFAULT_SIGMA_UM

MSL_CLI_NAMES = MslNames(
    kind="--msl-kind simulated or --msl-kind measured", measured="--msl-kind measured",
    simulated="--msl-kind simulated", certificate_u="--msl-certificate-u A_UM,B_UM_PER_MM",
    certificate_example="--msl-certificate-u 0.26,0.0019", metadata="--msl-metadata "
    "METADATA.csv (the metadata.csv saved with the snapshot, which repeats its header), or "
    "put that file beside the snapshot", machine="",
    plate="give it with --msl", bar="give it with --msl-bar",
    pairing="give the metadata.csv saved with it (--msl-metadata pairs each file with the "
            "snapshot whose header it repeats)",
    files="give MSL snapshots with --msl or --msl-bar and their metadata with "
          "--msl-metadata", metadata_flag="--msl-metadata", lead_plate="--msl",
    lead_bar="--msl-bar", lead_metadata="--msl-metadata")
"""The MSL readers' refusals in the command line's words: its flags, not the keywords of
``io.read_msl_plate``."""


MslInputs = MslFiles
"""The MSL files of a command line, read once (:func:`msl_inputs`): ``io.MslFiles``."""


def msl_inputs(args: argparse.Namespace) -> MslFiles:
    """The ``--msl`` and ``--msl-bar`` snapshots read with their metadata
    (``io.read_msl_files``, as the app reads them; memoised on ``args``: the data, the
    instruments and the defaults all need them).

    Each ``--msl-metadata`` file is paired with the snapshot whose header it repeats
    (:func:`io.msl_header`), in any order; a snapshot without one takes the
    ``metadata.csv`` beside it when that file repeats its header (MSL saves the two
    together), and says so in a note.

    Raises
    ------
    DataError
        In the flags' words (:data:`MSL_CLI_NAMES`), naming the flag and the file: a
        snapshot without metadata, a metadata file no snapshot pairs with, a placement
        given twice, a bad file.
    """
    done = getattr(args, "msl_read", None)
    if isinstance(done, MslFiles):
        return done

    def beside(snap: str):
        near = Path(snap).with_name("metadata.csv")
        if near.is_file() and not near.samefile(snap):
            return str(near), near
        return None

    out = read_msl_files([(str(s), s) for s in args.msl],
                         [(str(s), s) for s in args.msl_bar],
                         [(str(m), m) for m in args.msl_metadata], kind=args.msl_kind,
                         certificate_u=_certificate_u(args.msl_certificate_u),
                         beside=beside, names=MSL_CLI_NAMES)
    args.msl_read = out
    return out


def _certificate_u(ab: tuple[float, float] | None) -> dict | None:
    """``--msl-certificate-u A,B`` (parsed by its argparse type) as the setup's
    certificate statement (k = 2, in quadrature)."""
    if ab is None:
        return None
    return {"U_um": [float(ab[0]), float(ab[1])], "k": 2, "combine": "quadrature",
            "source": "--msl-certificate-u"}


def dataset_of(args: argparse.Namespace) -> Dataset:
    """The dataset the fitting commands read: this project's files, tables from other
    software through ``--mapping``, DMIS files through ``--dmis-pattern``, QIF documents
    (``.qif``, or XML that is a ``QIFDocument``) through ``--qif-pattern``, or MSL
    cmm-error-map snapshots (:func:`msl_inputs`)."""
    if args.msl:
        if args.meas:
            raise DataError("give measurement files or --msl snapshots, not both.",
                            file=str(args.meas[0]))
        return msl_inputs(args).dataset()
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
            foreign = sniff(m, MSL_CLI_NAMES) if isinstance(m, str | Path) else None
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
    elif getattr(args, "msl_bar", None):
        machine = read_machine(msl_inputs(args).bars[0].setup)
    else:
        raise DataError("an instrument-only fit needs the machine: give --setup (its "
                        "machine.layout and range_mm; no positions needed).",
                        file="command line")
    return instrument_observations(instruments, *machine)


def settle_defaults(args: argparse.Namespace) -> list[str]:
    """Set ``--order`` and ``--sigma-um`` where the command line left them out, from what
    MSL files state, else :data:`.options.DEFAULT_ORDER` and ``DEFAULT_SIGMA_UM``; the
    notes saying what was taken, one line each, for MSL input (this project's own files
    keep the documented defaults without a word, as before).

    - order: the degree of the model parameters the metadata lists (MSL's own: 1).
    - σ: for a simulation, the rounding of the files' decimals, its only scatter; for a
      measurement, which states no repeatability, the default, said as assumed.
    - plate: fixed to MSL's nominal grid, the certificate the kind implies.
    """
    done = getattr(args, "settled_notes", None)
    if isinstance(done, list):  # settled already: the notes of the first call
        return done
    msl = msl_inputs(args) if (args.msl or getattr(args, "msl_bar", None)) else None
    notes: list[str] = []
    if getattr(args, "order", DEFAULT_ORDER) is None:
        degrees = [d for d in (msl_degree(p.parameters) for p in msl.parts)
                   if d is not None] if msl else []
        args.order = max(degrees) if degrees else DEFAULT_ORDER
        if degrees:
            notes.append(f"order: {args.order}, the degree of the model parameters the MSL "
                         "metadata lists (MSL's polynomials; --order N overrides).")
        elif msl:
            notes.append(f"order: {DEFAULT_ORDER}, assumed: the MSL metadata lists no model "
                         "parameters to take the degree from (--order N sets it).")
    if getattr(args, "sigma_um", DEFAULT_SIGMA_UM) is None:
        args.sigma_um = DEFAULT_SIGMA_UM
        if msl and msl.plates and args.msl_kind == "simulated":
            decimals = max(p.decimals for p in msl.plates)
            args.sigma_um = rounding_u_um(decimals)
            notes.append(f"sigma: {args.sigma_um:.3g} µm, the rounding of the MSL files' "
                         f"{decimals} decimals (step/√12), a noise-free simulation's only "
                         "scatter (--sigma-um overrides: a simulation with added noise "
                         "needs it).")
        elif msl and msl.plates:
            notes.append(f"sigma: {DEFAULT_SIGMA_UM} µm, assumed: an MSL measured file does "
                         "not state the repeatability (give --sigma-um UM, or --sigma-um "
                         "auto to estimate it from the data).")
    if msl and msl.plates and getattr(args, "plate", "") is None:
        notes.append("plate: fixed to MSL's nominal grid, "
                     + ("exact for a simulation" if args.msl_kind == "simulated" else
                        "with the --msl-certificate-u uncertainty")
                     + " (--plate prior or free overrides).")
    args.settled_notes = notes
    return notes


def notes_of(args: argparse.Namespace, data: Dataset | Observations) -> list[str]:
    """The notes a fitting command prints on stderr: how the data were read (for MSL
    input every convention once, bars too, :func:`msl_inputs`), then the defaults
    :func:`settle_defaults` took (call it first)."""
    if args.msl or getattr(args, "msl_bar", None):
        read = msl_inputs(args).notes
    else:
        read = list(getattr(data, "notes", ()))
    return [*read, *getattr(args, "settled_notes", [])]


def instruments_of(args: argparse.Namespace) -> list:
    """The instrument files of ``--laser``, ``--step-gauge`` and ``--ball-bar``, read
    (DataError if bad)."""

    given = [(kind, f) for kind, files in (("laser", args.laser),
                                           ("step_gauge", args.step_gauge),
                                           ("ball_bar", args.ball_bar)) for f in files]
    out = [read_instrument(f, kind) for kind, f in given]  # each reader bounds the size
    if getattr(args, "msl_bar", None):
        for name, text in msl_inputs(args).step_gauges():
            out.append(read_instrument(io.BytesIO(text.encode()), "step_gauge", name=name))
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
    order = getattr(args, "order", None)
    sigma = getattr(args, "sigma_um", None)
    # None: settle_defaults did not run (a caller of this function alone)
    choices = CommandChoices(spec, DEFAULT_ORDER if order is None else order,
                             args.plate or "auto",
                             DEFAULT_SIGMA_UM if sigma is None else sigma,
                             tuple(map(tuple, exclude)))
    return fit_kwargs(choices, None, **more)


def sigma_of(args: argparse.Namespace, data: Dataset | Observations, exclude: list,
             spec: str) -> tuple[float, dict]:
    """``(σ µm, JSON record)``: the stated value, or the estimate for ``--sigma-um auto``."""
    if args.sigma_um != "auto":
        value = DEFAULT_SIGMA_UM if args.sigma_um is None else args.sigma_um
        return value, {"value_um": value, "auto": False}
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

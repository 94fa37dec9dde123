"""The analysis record's types and conventions (``analysis``): the files of an analysis,
the record itself, the sign of the measured error and the outlier default, each defined
once for the app, the command line and the report."""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..io import (
    DataError,
    InputFile,
    Provenance,
    apply_mapping,
    input_file,
    provenance,
    read_bytes,
)
from ..model import INSTRUMENT_KINDS, read_instrument

__all__ = ["FORMAT", "VERSION", "DEFAULT_EXCLUDE_OUTLIERS", "ERROR_CONVENTION",
           "PLATE_CHOICES", "GP_MEANS", "GP_KERNELS", "MPE_U_SOURCES", "measured_error_um",
           "measured_error_from_residuals_um", "DataFile", "instrument_kinds",
           "InstrumentFile", "DataSources", "CheckChoices", "HistoryChoices",
           "AnalysisRecord"]

FORMAT = "cmm-error-lab-analysis"
"""Value of the ``format`` key of an analysis record file."""
VERSION = 1
"""Version of the record format written by this code."""
DEFAULT_EXCLUDE_OUTLIERS = False
"""Flagged outliers stay in the fit unless excluded by name or by ``exclude_outliers``:
excluding silently what a robust check flags hides a real effect as easily as a gross
error, so the app and the CLI both show the flags and exclude only what the record says."""
ERROR_CONVENTION = ("measured error = true − reported (µm): the true point is the reported "
                    "point plus the error, which is what compensation adds")
"""The sign of every error shown by the app, the CLI and the report."""
PLATE_CHOICES = ("auto", "fixed", "prior", "free")
GP_MEANS = ("zero", "quadratic", "thesis_quadratic", "kinematic")
GP_KERNELS, MPE_U_SOURCES = ("se_iso", "se_ard"), ("test", "cmm_spec")


def measured_error_um(reported_mm: ArrayLike, true_mm: ArrayLike) -> np.ndarray:
    """Measured error (µm, :data:`ERROR_CONVENTION`) of points as the CMM reports them
    (``reported_mm``, (n, 3)) given their true or corrected positions (``true_mm``)."""
    return (np.asarray(true_mm, float) - np.asarray(reported_mm, float)) * 1e3


def measured_error_from_residuals_um(residuals_um: ArrayLike) -> np.ndarray:
    """Measured error (µm) from the residuals of a fit with no error model (``rigid``):
    the residual is reported minus placed ball, so the error is its negative."""
    return -np.asarray(residuals_um, float)


@dataclass(frozen=True)
class DataFile:
    """One input file, by path or by content (exactly one of the two)."""

    name: str
    """File name used in messages; thesis-form measurement files name their position."""
    path: str | None = None
    """Path of the file (relative paths are resolved against the record's folder)."""
    content: str | None = None
    """The file's text, when the record carries it (the app's downloads do)."""
    mapping: dict | None = None
    """For a measurement table from other software: the column mapping it is read through
    (``TableMapping.to_dict()``, docs/foreign-formats.md), the file then being that
    table; None: the file is in this project's own format."""

    def text(self) -> str:
        """The file's text as this project reads it: the file itself, or with a
        :attr:`mapping` the long form the mapping converts it to (DataError when bad)."""
        raw = self.source_text()
        if self.mapping is None:
            return raw
        return apply_mapping(raw.encode(), self.mapping, name=self.name).csv_text

    def digest(self) -> InputFile | None:
        """The file with its SHA-256: of the bytes on disk for a path, of the UTF-8 text
        for content the record carries; None when the path cannot be read."""
        if self.content is not None:
            return input_file(self.name, self.content)
        try:
            return input_file(self.name, read_bytes(Path(str(self.path)), self.name)[0])
        except DataError:
            return None

    def source_text(self) -> str:
        """The file's own text (read from ``path`` when the record does not carry it)."""
        if self.content is not None:
            return self.content
        if self.path is None:
            raise DataError("names neither a path nor its content.", file=self.name)
        raw, _ = read_bytes(Path(self.path), Path(self.path).name)  # capped, files only
        try:
            return raw.decode("utf-8-sig")
        except UnicodeDecodeError:
            raise DataError("cannot be read (not UTF-8 text).",
                            file=Path(self.path).name) from None


def instrument_kinds() -> tuple:
    """The instrument kinds a record may name (``model.instrument_files.INSTRUMENT_KINDS``)."""
    return tuple(INSTRUMENT_KINDS)


@dataclass(frozen=True)
class InstrumentFile:
    """One instrument file of an analysis (docs/instruments.md)."""

    kind: str
    """Instrument kind, one of :func:`instrument_kinds` (``laser``, ``step_gauge``)."""
    file: DataFile
    """The file, by path or by content."""

    def read(self) -> Any:
        """The instrument's readings (``model.instrument_files``); DataError when bad."""
        return read_instrument(io.StringIO(self.file.text()), self.kind, name=self.file.name)


@dataclass(frozen=True)
class DataSources:
    """The data of an analysis: measurements, setup, an optional certificate and
    instrument files."""

    name: str
    """Dataset label shown in the app and the report."""
    measurements: tuple
    """:class:`DataFile` per measurement file (one long-form or one per position)."""
    setup: DataFile
    """The setup JSON."""
    certificate: DataFile | None = None
    """The plate certificate CSV; None: the plate is self-calibrated."""
    instruments: tuple = ()
    """:class:`InstrumentFile` per laser run or step-gauge file, fitted with the plate."""

    @property
    def files(self) -> tuple[DataFile, ...]:
        """Every file: measurements, setup, certificate, instruments."""
        return (*self.measurements, self.setup,
                *(() if self.certificate is None else (self.certificate,)),
                *(i.file for i in self.instruments))

    def provenance(self, **extra: Any) -> Provenance:
        """The provenance of a record made now from these data: each file's SHA-256 and
        the machine and calibration date the setup names (none when it cannot be read:
        the record's own check reports that)."""
        digests = [f.digest() for f in self.files]
        try:
            setup = json.loads(self.setup.source_text())
        except (DataError, ValueError):
            setup = None
        machine = setup.get("machine") if isinstance(setup, dict) else None
        mid = machine.get("id") if isinstance(machine, dict) else None
        day = setup.get("calibration_date") if isinstance(setup, dict) else None
        return provenance([d for d in digests if d is not None],
                          machine=mid if isinstance(mid, str) else None,
                          calibration_date=day if isinstance(day, str) else None,
                          extra=extra)


@dataclass(frozen=True)
class CheckChoices:
    """An interim check of the record's data against a stored calibration
    (docs/monitoring.md): the record's measurements and instruments are the new data."""

    model: DataFile
    """The stored calibration: a model file written by ``fit --save``."""
    alpha: float = 0.05
    """False-alarm level of the χ² test."""
    family_alpha: float = 0.05
    """Family-wise level of the parameter changes (Holm)."""
    sigma_um: float | None = None
    """Repeatability of the new data, µm; None: the stored model's σ."""
    mpe: tuple | None = None
    """``(A µm, D)``: MPE = A + L/D for the conformity statement; None: no statement."""


@dataclass(frozen=True)
class HistoryChoices:
    """The machine's calibration history beside the record's analysis
    (docs/monitoring.md)."""

    models: tuple
    """``(DataFile, date)`` per earlier calibration (model files, ISO 8601 dates)."""
    family_alpha: float = 0.05
    """Family-wise level of the changes (Holm over pairs and parameters)."""
    nodes: int = 5
    """Grid nodes per axis of the error map's change."""
    date: str | None = None
    """This analysis's calibration date: its own fit joins the history as the latest
    calibration; None: the model files alone."""


@dataclass(frozen=True)
class AnalysisRecord:
    """Everything that decides the numbers of an analysis (docs/report.md)."""

    data: DataSources
    """Input files."""
    spec: str = "kinematic21"
    """Model spec (docs/formats.md#model-specs)."""
    order: int = 2
    """Default polynomial order of the error functions, 1-5."""
    plate: str = "auto"
    """Plate geometry: auto (fixed with a certificate, else free), fixed, prior, free."""
    sigma_um: float | str = 0.5
    """Repeatability of one probed coordinate, µm, or "auto" (estimated from the data)."""
    positions: tuple | None = None
    """Positions fitted (None: all)."""
    probes: tuple | None = None
    """Probes fitted (None: all)."""
    exclusions: tuple = ()
    """``(position, probe, ball)`` observations the user excluded."""
    exclude_outliers: bool = DEFAULT_EXCLUDE_OUTLIERS
    """Also exclude every observation the robust outlier check flags."""
    history: tuple = ()
    """``(spec, change)`` steps of the diagnosis history, first the baseline; a step
    written with the exclusions in force when it was made is ``(spec, change,
    exclusions)`` (a tuple of ``(position, probe, ball)``), so that excluding outliers is
    a step of its own; a step without them is fitted with the record's exclusions."""
    diagnose: bool = False
    """Run the diagnosis (ranked missing effects) and report it."""
    uncertainty_points: int = 200
    """Random points of U2/U3 (thesis §4.5.3)."""
    uncertainty_seed: int = 0
    """Seed of those points."""
    gp_mean: str | None = None
    """GP of the measured errors with this mean (:data:`GP_MEANS`); None: no GP."""
    gp_kernel: str = "se_iso"
    """GP covariance: se_iso or se_ard."""
    mpe_u_source: str = "test"
    """U of the MPE decision: "test" (certificate and σ) or "cmm_spec"."""
    magnification: float = 2000.0
    """Magnification of the deviation plots."""
    interim_check: CheckChoices | None = None
    """Check the record's data against a stored calibration (report section "Interim
    check"); None: no check."""
    calibration_history: HistoryChoices | None = None
    """Compare the machine's calibrations (report section "History"); None: none."""

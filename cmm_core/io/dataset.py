"""A dataset: resolved measurements with their setup and certificate, ready to fit."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .certificate import Certificate, read_certificate
from .delimited import FileSource, read_bytes, read_json
from .errors import DataError, _check_keys
from .matching import resolve
from .measurements import _named, read_measurement_files
from .provenance import InputFile, Provenance, input_file, provenance
from .setup import LAYOUTS, SETUP_KEYS, Setup, _json_object, _machine_range, read_setup


def _sample_dir() -> Path:
    """The sample data: installed as ``cmm_core/sample_data`` by a wheel, or the
    checkout's ``sample_data/`` folder (a checkout run in place, an editable install)."""
    installed = Path(__file__).resolve().parents[1] / "sample_data"
    return installed if installed.is_dir() else Path(__file__).resolve().parents[2] / "sample_data"


SAMPLE_DIR = _sample_dir()
"""The folder of sample data (thesis tables, simulated runs, plans, histories)."""
THESIS_DIR = SAMPLE_DIR / "thesis"
THESIS_POSITIONS = ("BP111", "BP112", "BP211", "BP212", "BP311", "BP312")


@dataclass(frozen=True)
class Dataset:
    """Measurements resolved against a setup (and certificate).

    Attributes
    ----------
    meas : DataFrame
        One row per probed ball centre: ``position, probe, ball, x_mm, y_mm, z_mm``, the
        machine-frame tip centres ``mx_mm, my_mm, mz_mm``, optional ``time_min, temp_C``,
        and the ``source`` file and ``row`` each came from.
    setup : Setup
    certificate : Certificate or None
    name : str
        Label shown in the app and reports.
    inputs : tuple of InputFile
        The files it was read from, each with its SHA-256 (measurements, then the setup
        and the certificate when they were files); empty for data built in memory.
    notes : tuple of str
        What the readers of other tools' files left out or assumed (rows not read, units
        converted, a default stylus): said by every command and page that uses the data.
    """

    meas: pd.DataFrame
    setup: Setup
    certificate: Certificate | None
    name: str = "dataset"
    inputs: tuple[InputFile, ...] = field(default=(), compare=False)
    notes: tuple[str, ...] = field(default=(), compare=False)

    def provenance(self, inputs: Iterable[InputFile] = (), **extra: Any) -> Provenance:
        """The provenance of a record made now from this dataset (and ``inputs`` more):
        its files' digests, the setup's machine and calibration date."""
        return provenance((*self.inputs, *inputs), machine=self.setup.machine_id,
                          calibration_date=self.setup.calibration_date, extra=extra)

    @property
    def positions(self) -> list:
        """Position names in order of first appearance."""
        return list(dict.fromkeys(self.meas["position"]))

    @property
    def probes(self) -> list:
        """Probe names in order of first appearance."""
        return list(dict.fromkeys(self.meas["probe"]))

    def plate_frame_table(self, position: str, probe: str | None = None) -> np.ndarray:
        """Ball centres (balls in certificate order) of one position in the plate frame, mm.

        Machine-frame data are mapped back through the nominal placement; balls that were
        not measured are NaN.
        """
        g = self.meas[self.meas["position"] == position]
        if probe is not None:
            g = g[g["probe"] == probe]
        pl = self.setup.positions[position]
        xyz = g[["mx_mm", "my_mm", "mz_mm"]].to_numpy() - pl.origin_mm
        plate = xyz @ pl.rotation
        balls = self.certificate.balls if self.certificate is not None else np.unique(
            self.meas["ball"])
        out = np.full((len(balls), 3), np.nan)
        idx = {b: i for i, b in enumerate(balls)}
        for b, row in zip(g["ball"], plate, strict=True):
            out[idx[b]] = row
        return out


def load_dataset(meas_sources: Iterable[FileSource | tuple[FileSource, str | None]],
             setup_source: FileSource | dict,
             certificate_source: FileSource | tuple[FileSource, str | None] | Certificate
             | None = None, *, name: str | None = None) -> Dataset:
    """Read and resolve measurement files, a setup and an optional certificate.

    ``meas_sources`` is a list of paths or ``(file-like, name)`` pairs (one long-form file or
    thesis-form files, one per position).
    """
    # each file read once, as bytes: what is parsed is what is hashed
    files = [read_bytes(s, n) for s, n in _named(meas_sources)]
    meas = read_measurement_files(files)
    setup_file = None
    if isinstance(setup_source, dict) or (isinstance(setup_source, str)
                                         and setup_source.lstrip()[:1] == "{"):
        setup = read_setup(setup_source)  # a document in memory, not a file
    else:
        setup_file = read_bytes(setup_source, None if isinstance(setup_source, (str, Path))
                                else "setup.json")
        setup = read_setup(setup_file[0], name=setup_file[1])
    cert = certificate_source
    cert_file = None
    if cert is not None and not isinstance(cert, Certificate):
        cert_file = read_bytes(*(cert if isinstance(cert, tuple) else (cert, None)))
        cert = read_certificate(cert_file[0], name=cert_file[1])
    resolved = resolve(meas, setup, cert)  # the data's own problems are reported first
    cert = stated_certificate(cert, setup)
    inputs = tuple(input_file(n, b) for b, n in
                   [*files, *(f for f in (setup_file, cert_file) if f is not None)])
    return Dataset(resolved, setup, cert, name or "dataset", inputs)


def stated_certificate(cert: Certificate | None, setup: Setup) -> Certificate | None:
    """The certificate with the uncertainty its user stated, never an assumed one.

    From the file's ``u_x_um, u_y_um, u_z_um`` columns, else from the setup's
    ``certificate`` statement (``U(k) = a ⊕ b·L``, or exact for a noise-free simulation);
    a certificate with neither is refused in one line with the fix. Every χ² test and
    propagated uncertainty uses what is returned here, and ``u_source`` says where it came
    from (the app, the CLI JSON, the report and exported results print it).
    """
    if cert is None:
        return None
    stated = setup.certificate_u
    if cert.u_um is not None:
        source = cert.u_source
        if stated is not None:
            source += "; the setup's certificate statement is not used (the file's columns are)"
        return replace(cert, u_source=source)
    if stated is None:
        raise DataError(
            "the certificate gives no uncertainty and the setup states none; no fit may "
            "assume one.", file=cert.name or "certificate.csv", column="u_x_um",
            hint="add columns u_x_um,u_y_um,u_z_um (standard uncertainties, µm), or state it "
                 'in the setup: "certificate": {"U_um": [a, b_per_mm], "k": 2} (U = '
                 'sqrt(a² + (b·L)²), L mm from ball 1), or "certificate": {"exact": true} '
                 "for a noise-free simulation.")
    return replace(cert, u_um=stated.u_um(cert.xyz_mm), u_source=stated.describe())


def read_machine(source: FileSource | dict, *, name: str | None = "setup.json"
                 ) -> tuple[np.ndarray, str]:
    """The machine of a setup JSON, ``(range_mm, layout)``, for a fit without a plate.

    An instrument-only fit (laser runs, step gauges, ball bars: ``cmm_core.model.
    instrument_observations``) needs the machine's strokes and kinematic chain only, so a
    setup with no ``positions`` is accepted here (``read_setup`` requires them); the keys
    and the ``machine`` section are checked as ``read_setup`` checks them.
    """
    if isinstance(source, dict):
        raw = source
    else:
        raw, name = read_json(source, None if isinstance(source, str | Path) else name)
    if not isinstance(raw, dict):
        raise DataError("expected a JSON object.", file=name)
    _check_keys(raw, SETUP_KEYS[""], name, "")
    machine = _json_object(raw, "machine", name)
    _check_keys(machine, SETUP_KEYS["machine"], name, "machine")
    return _machine_range(machine, name), str(machine.get("layout", LAYOUTS[0]))


def thesis_dataset() -> Dataset:
    """The six ball-plate tables of thesis chapter 6 with the appendix 5 certificate."""
    files = [THESIS_DIR / f"{p}.csv" for p in THESIS_POSITIONS]
    return load_dataset(files, THESIS_DIR / "setup.json", THESIS_DIR / "certificate.csv",
                        name="thesis tables 6.1-6.6")

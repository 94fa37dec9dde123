"""Exports: spreadsheet-safe CSV, the error-map grid, corrected points, project files.

Everything here is plain Python over the core (no UI). Lengths are mm in files; errors
and uncertainties are µm.

- :func:`safe_csv` writes a DataFrame as CSV that is safe to open in a spreadsheet: text
  cells starting with ``= + - @``, tab or carriage return that are not plain numbers get a
  leading apostrophe (CSV formula injection).
- :func:`error_map_grid` tabulates the fitted error and its standard uncertainty on a
  regular grid of machine coordinates, the layout of an ISG-style compensation table
  (``comp_tables.compensation_grid``, the one grid, under this table's column names).
- :func:`compensate_points` corrects reported tip centres
  (``cmm_core.export.correction.compensate``).
- :func:`project_to_json` / :func:`project_from_json` save and restore a session: the
  dataset files' content, setup, certificate, model, exclusions and history.
- :func:`download_name` prefixes a download's file name with its dataset's name, so the
  downloads of two datasets never overwrite each other in one folder.
"""

from __future__ import annotations

import io
import json
import math
import re
from collections.abc import Iterable
from datetime import datetime
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from .. import __version__
from ..io import DataError, Provenance, read_json, read_measurement_files, read_setup
from ..io import provenance as make_provenance
from ..model import MAX_ORDER, PLATE_MODES, FitResult, parse_spec
from .comp_tables import as_model, compensation_grid
from .correction import compensate
from .model_file import Model
from .safe import safe_csv

_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def download_name(dataset_name: str, file_name: str, date: str | None = None,
                  max_stem: int = 40) -> str:
    """``file_name`` prefixed with a file-system-safe form of ``dataset_name`` and the date:
    ``download_name("thesis tables 6.1-6.6", "cmm_model.json", "2026-11-26")`` is
    ``"thesis_tables_6.1-6.6_2026-11-26_cmm_model.json"``. Characters other than letters,
    digits, ``. _ -`` become ``_`` (no path separators, no spaces a shell must quote); the
    name part is cut to ``max_stem`` characters so that names stay within any file
    system's limit. ``date`` defaults to today (local time, ISO 8601): downloads of two
    datasets, or of one dataset on two days, never overwrite each other."""
    stem = _UNSAFE.sub("_", str(dataset_name)).strip("._-")[:max_stem].rstrip("._-")
    day = _UNSAFE.sub("_", date if date is not None else datetime.now().strftime("%Y-%m-%d"))
    return "_".join(p for p in (stem, day, file_name) if p)


PROJECT_FORMAT = "cmm-error-lab-project"
PROJECT_VERSION = 1
def parameters_csv(result: FitResult, provenance: Provenance | None = None) -> str:
    """Fitted parameters with standard uncertainties (µm, µrad), one row per parameter,
    below ``#`` lines of the provenance (the fitted data's,
    :meth:`cmm_core.io.Dataset.provenance`; default this process with no inputs), the
    model and its fit."""
    df = result.parameters_frame().rename(columns={"u": "u_standard"})
    df["identifiable"] = ~df["parameter"].isin(result.unidentifiable)
    head = [*(provenance or make_provenance()).lines(),
            f"model {result.spec}; order per spec; plate {result.plate}; "
            f"sigma {result.sigma_um} um; RMS {result.rms_um:.4f} um; "
            f"chi2/dof {result.chi2_dof:.3f}; status {result.status}",
            f"certificate uncertainty: {result.certificate_u_source}"]
    return safe_csv(df, float_format="%.6g", header_lines=head)


def residuals_csv(result: FitResult, provenance: Provenance | None = None) -> str:
    """Residuals per observation (µm) with position, probe, ball, source file and row,
    below ``#`` lines of the provenance (as :func:`parameters_csv`)."""
    return safe_csv(result.residuals_frame(), float_format="%.4f",
                    header_lines=[*(provenance or make_provenance()).lines(),
                                  f"model {result.spec}; residuals = measured - fitted, um"])


def error_map_grid(result: Model | FitResult, *,
               step_mm: float | tuple[float, float, float] = (100.0, 100.0, 100.0),
               lower_mm: ArrayLike | None = None, upper_mm: ArrayLike | None = None,
               probe: str | None = None) -> pd.DataFrame:
    """Error map on a regular grid of scale readings: an ISG-style compensation table.

    :func:`comp_tables.compensation_grid` (the one grid: same nodes, each axis ending at
    its stroke or ``upper_mm``, same region test) under this table's column names, for a
    probe tip, and for a model whose data leave combinations undetermined too (its
    uncertainties are then NaN).

    Parameters
    ----------
    result : FitResult or model_file.Model
    step_mm : float or 3 floats
        Grid spacing per axis (mm).
    lower_mm, upper_mm : 3 floats, optional
        Grid corners (default: the machine's working volume, 0 .. range).
    probe : str, optional
        Probe whose offset the tip has (default the first probe of the fit).

    Returns
    -------
    DataFrame with ``x_mm, y_mm, z_mm`` (grid, x fastest), ``ex_um, ey_um, ez_um`` (error:
    true minus reported, add it to correct; the grid's ``cx_um`` ...), ``u_ex_um, u_ey_um,
    u_ez_um`` (standard uncertainty, k = 1; NaN when the data do not determine the model)
    and ``extrapolated`` (1 where the node lies outside the region the fit measured).
    """

    m = as_model(result)
    probe = next(iter(m.probes_mm)) if probe is None else probe
    g = compensation_grid(m, step_mm, probe=probe, allow_undetermined=True,
                          lower_mm=lower_mm, upper_mm=upper_mm)
    names = {f"{p}c{a}_um": f"{p}e{a}_um" for p in ("", "u_") for a in "xyz"}
    return g[["x_mm", "y_mm", "z_mm", *names, "extrapolated"]].rename(columns=names)


def error_map_csv(result: FitResult, grid: pd.DataFrame, probe: str | None = None,
                  provenance: Provenance | None = None) -> str:
    """The error-map grid as CSV with a comment header stating its provenance (the
    fitted data's, :meth:`cmm_core.io.Dataset.provenance`), model, probe and units."""
    obs = result.problem.obs
    head = ["CMM error map (ISG-style compensation table)",
            *(provenance or make_provenance()).lines(),
            f"model {result.spec}; plate {result.plate}; RMS {result.rms_um:.4f} um",
            f"probe {probe or obs.probes[0]}; grid: scale readings in mm, x fastest",
            "ex,ey,ez: error in um (true minus reported; add to correct); u_*: standard "
            "uncertainty in um (k=1)",
            "extrapolated: 1 where the node lies outside the region the fit measured"]
    lab, val, u = result.block("backlash")
    if len(lab):
        # a position-only table cannot hold a direction-dependent error: say so
        head.append("NOT in this table: backlash (reversal span, um, depends on the direction "
                    "each axis last moved): " + "; ".join(
                        f"{a} {v:.3f} +- {ui:.3f}" for a, v, ui in
                        zip("xyz", val, u, strict=True)))
    lab, val, u = result.block("machine_thermal")
    if len(lab):
        head.append("NOT in this table: machine_thermal (scale expansion, depends on each "
                    "scale's temperature; the table is for the scales at 20 C): " + "; ".join(
                        f"{a} {v:.4g} +- {ui:.2g} ppm/K" for a, v, ui in zip(lab, val, u, strict=True)))
    return safe_csv(grid, float_format="%.5f", header_lines=head)


# ---------------------------------------------------------------------------------------
# Compensation (cmm_core.export.correction.compensate)
# ---------------------------------------------------------------------------------------

def compensate_points(result: Model | FitResult, points: pd.DataFrame) -> pd.DataFrame:
    """Corrected tip centres ``xc_mm, yc_mm, zc_mm``, errors and ``u_x_um, u_y_um,
    u_z_um`` (``correction.compensate``), with an ``extrapolated`` note per point."""

    return compensate(result, points)


def corrected_csv(corrected: pd.DataFrame, provenance: Provenance) -> str:
    """The corrected points (:func:`compensate_points`) as spreadsheet-safe CSV below
    ``#`` lines of ``provenance`` (the model's and the points file's), as the command
    line's ``compensate --out`` writes them."""
    return safe_csv(corrected, float_format="%.6f", header_lines=provenance.lines())


# ---------------------------------------------------------------------------------------
# Project files
# ---------------------------------------------------------------------------------------

def _clean(obj):
    """JSON-safe copy (numpy scalars and arrays to Python, NaN to None)."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, np.generic):
        return _clean(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def project_to_json(*, dataset_name: str, measurements: list, setup: str,
                certificate: tuple[str, str] | None = None, model: dict,
                exclusions: Iterable[tuple[str, str, int]] = (), history: Iterable[dict] = (),
                extra: dict | None = None, provenance: Provenance | None = None) -> str:
    """Serialise a session to a project file (JSON text).

    Parameters
    ----------
    dataset_name : str
    measurements : list of (file name, CSV text)
    setup : str
        Setup JSON text.
    certificate : (file name, CSV text) or None
    model : dict
        ``spec, order, plate, sigma_um, positions, probes``.
    exclusions : iterable of (position, probe, ball)
    history : iterable of dict
        Diagnosis history rows.
    provenance : Provenance, optional
        What made it (:meth:`cmm_core.analysis.DataSources.provenance`); default this
        software's identity and the time, without inputs.
    """
    prov = provenance or make_provenance()
    doc = {"format": PROJECT_FORMAT, "version": PROJECT_VERSION,
           "created": prov.created,
           "cmm_core": __version__, "provenance": prov.to_dict(),
           "dataset": {"name": dataset_name,
                       "measurements": [{"name": n, "content": c} for n, c in measurements],
                       "setup": setup,
                       "certificate": (None if certificate is None else
                                       {"name": certificate[0], "content": certificate[1]})},
           "model": model,
           "exclusions": [[str(p), str(q), int(b)] for p, q, b in exclusions],
           "history": list(history),
           "extra": extra or {}}
    return json.dumps(_clean(doc), indent=1, allow_nan=False)


def _checked_model(model, name) -> dict:
    """The project's model block with every field checked against what the app accepts
    (a bad field would otherwise break every page of the restored session)."""
    if not isinstance(model, dict):
        raise DataError("model must be an object.", file=name, column="model")
    out: dict[str, Any] = {}

    def bad(key, expected):
        return DataError(f"{key} must be {expected}, found {model[key]!r}.", file=name,
                         column=f"model.{key}")

    if "order" in model:
        o = model["order"]
        if isinstance(o, bool) or not isinstance(o, int) or not 1 <= o <= MAX_ORDER:
            raise bad("order", f"a whole number 1-{MAX_ORDER}")
        out["order"] = o
    if "spec" in model:
        if not isinstance(model["spec"], str):
            raise bad("spec", "a model spec string such as \"kinematic21,plate_sag\"")
        try:
            parse_spec(model["spec"], default_order=out.get("order", 2))
        except ValueError as exc:
            raise DataError(str(exc), file=name, column="model.spec") from exc
        out["spec"] = model["spec"]
    if "plate" in model:
        if model["plate"] not in ("auto", *PLATE_MODES):
            raise bad("plate", f"one of auto, {', '.join(PLATE_MODES)}")
        out["plate"] = model["plate"]
    if "sigma_um" in model:
        v = model["sigma_um"]
        if v != "auto" and (isinstance(v, bool) or not isinstance(v, int | float)
                            or not 0 < v < 1e4):
            raise bad("sigma_um", 'a positive repeatability in µm or "auto"')
        out["sigma_um"] = v if v == "auto" else float(v)
    for key in ("positions", "probes"):
        if key in model:
            v = model[key]
            if v is not None and (not isinstance(v, list) or not v
                                  or not all(isinstance(x, str | int) for x in v)):
                raise bad(key, "null (all) or a non-empty list of names")
            out[key] = None if v is None else [str(x) for x in v]
    return out


def _check_model_names(model, meas, setup, name):
    """Positions and probes the project's model names must exist in its own data: a
    missing one would restore to an empty fit with no reason given."""

    try:
        st = read_setup(io.BytesIO(setup.encode()), name="setup")
        data = read_measurement_files([(io.BytesIO(c.encode()), n) for n, c in meas])
    except DataError as exc:
        raise DataError(f"its dataset cannot be read ({exc})", file=name,
                        column="dataset") from None
    positions = list(dict.fromkeys(data["position"]))
    probes = set(data["probe"].dropna()) | {st.positions[p].probe for p in positions
                                            if p in st.positions and st.positions[p].probe}
    for key, have in (("positions", positions), ("probes", sorted(probes))):
        for x in model.get(key) or []:
            if x not in have:
                raise DataError(f"model.{key} names {x!r}, which the project's data do not "
                                f"have (they have {', '.join(map(str, have))}).", file=name,
                                column=f"model.{key}",
                                hint=f"remove it from model.{key}, or use null for all.")


def project_from_json(text: str | bytes, name: str = "project.json") -> dict:
    """Parse and check a project file; returns the document with tuples restored.

    Raises :class:`DataError` naming the field that is wrong.
    """
    # the same reader as every JSON input: BOM tolerated, binary and bad JSON refused
    doc, _ = read_json(text.encode() if isinstance(text, str) else text, name)
    if not isinstance(doc, dict) or doc.get("format") != PROJECT_FORMAT:
        raise DataError(f"is not a CMM error lab project (expected \"format\": "
                        f"\"{PROJECT_FORMAT}\").", file=name)
    version = doc.get("version", 0)
    if isinstance(version, bool) or not isinstance(version, int | float):
        raise DataError(f"version must be a number, found {version!r}.", file=name,
                        column="version")
    if version > PROJECT_VERSION:
        raise DataError(f"was written by a newer version (project version "
                        f"{doc.get('version')}).", file=name)
    ds = doc.get("dataset")
    if not isinstance(ds, dict) or not ds.get("measurements") or not ds.get("setup"):
        raise DataError("has no dataset (measurements and setup).", file=name,
                        column="dataset")
    meas = []
    for i, m in enumerate(ds["measurements"]):
        if not isinstance(m, dict) or not isinstance(m.get("content"), str):
            raise DataError("measurement entry needs name and content.", file=name,
                            column=f"dataset.measurements[{i}]")
        meas.append((str(m.get("name") or f"file{i + 1}.csv"), m["content"]))
    cert = ds.get("certificate")
    if cert is not None:
        if not isinstance(cert, dict) or not isinstance(cert.get("content"), str):
            raise DataError("certificate needs name and content.", file=name,
                            column="dataset.certificate")
        cert = (str(cert.get("name") or "certificate.csv"), cert["content"])
    setup = ds["setup"]
    if isinstance(setup, dict):
        setup = json.dumps(setup)
    if not isinstance(setup, str):
        raise DataError(f"dataset.setup must be the setup (an object or its JSON text), "
                        f"found {type(setup).__name__}.", file=name, column="dataset.setup")
    model = _checked_model(doc.get("model") or {}, name)
    _check_model_names(model, meas, setup, name)
    try:
        excl = [(str(p), str(q), int(b)) for p, q, b in doc.get("exclusions", [])]
    except (TypeError, ValueError, OverflowError) as exc:
        raise DataError("exclusions must be [position, probe, ball] triples.", file=name,
                        column="exclusions") from exc
    return {"dataset_name": str(ds.get("name") or "project"), "measurements": meas,
            "setup": setup, "certificate": cert, "model": model, "exclusions": excl,
            "history": list(doc.get("history") or []), "extra": doc.get("extra") or {}}

"""Compensation: correct measured points with a fitted model, with uncertainties.

The true tip centre of a reported point ``r`` measured with probe offset ``p`` is
``r + e(r - p, p)`` (SPEC conventions). A saved model holds what that needs: the
kinematic terms and coefficients with their covariance, and the probe offsets (nominal plus
any fitted offset error). A model fitted with ``backlash`` also holds the reversal spans:
each new point is then corrected for the direction from which its axes last moved (its
file order, or ``time_min``), and an axis whose direction is unknown (before it first
moves) carries half the span as standard uncertainty instead.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from . import kinematics as kin
from .fit import FitResult, approach_directions
from .io import DataError, _file_rows, _numeric, _read_csv, _require
from .uncertainty import propagate_error


@dataclass(frozen=True)
class Model:
    """A fitted kinematic model detached from its data (what ``fit --save`` writes).

    Attributes
    ----------
    spec : str
    terms : KinematicTerms
    coef : ndarray
        Kinematic coefficients (µm, µrad).
    cov : ndarray
        Their covariance.
    probes_mm : dict
        Probe name -> effective offset (nominal plus fitted error) in mm.
    undetermined : bool
        True when some kinematic combination was not determined by the data; corrected
        points then carry NaN uncertainties.
    summary : dict
        RMS, χ²/dof and provenance for the record.
    backlash_um : ndarray (3,) or None
        Reversal span of each axis (µm) when the model was fitted with ``backlash``.
    cov_with_backlash : ndarray or None
        Joint covariance of the kinematic coefficients followed by the three spans.
    """

    spec: str
    terms: kin.KinematicTerms
    coef: np.ndarray
    cov: np.ndarray
    probes_mm: dict
    undetermined: bool
    summary: dict
    backlash_um: np.ndarray | None = None
    cov_with_backlash: np.ndarray | None = None


def model_from_result(result: FitResult) -> Model:
    """Detach the model from a fit result."""
    obs = result.problem.obs
    probes = {}
    lab, val, _ = result.block("probe_offset")
    for i, q in enumerate(obs.probes):
        p = obs.p_mm[obs.probe == i][0].copy()
        if len(lab):
            p = p + val.reshape(-1, 3)[i] * 1e-3
        probes[q] = p
    kin_labels = set(result.terms.labels)
    blk = result.problem.layout.blocks
    backlash = joint = None
    if "backlash" in blk:
        idx = np.r_[np.arange(blk["kinematic"].start, blk["kinematic"].stop),
                    np.arange(blk["backlash"].start, blk["backlash"].stop)]
        backlash = result.values[blk["backlash"]].copy()
        joint = result.covariance[np.ix_(idx, idx)].copy()
    # an undetermined span would be applied as if known: it makes the model undetermined
    used = kin_labels | {f"backlash.{a}" for a in "xyz"}
    return Model(result.spec, result.terms, result.kinematic_coef.copy(),
                 result.kinematic_cov.copy(), probes,
                 any(lab in used for lab in result.unidentifiable),
                 {"rms_um": result.rms_um, "chi2_dof": result.chi2_dof, "n_obs": result.n_obs,
                  "plate": result.plate, "sigma_um": result.sigma_um,
                  "region_mm": [np.min(obs.r_mm - obs.p_mm, axis=0).tolist(),
                                np.max(obs.r_mm - obs.p_mm, axis=0).tolist()]},
                 backlash, joint)


def model_to_dict(model: Model | FitResult) -> dict:
    """JSON-ready dict of a model (or of a fit result's model)."""
    m = model_from_result(model) if isinstance(model, FitResult) else model
    return {"format": "cmm-error-lab model 1", "spec": m.spec,
            "orders": [list(o) for o in m.terms.orders], "range_mm": list(m.terms.range_mm),
            "periods": [list(o) for o in m.terms.periods],
            "labels": m.terms.labels, "coef": m.coef.tolist(), "cov": m.cov.tolist(),
            "probes_mm": {k: list(map(float, v)) for k, v in m.probes_mm.items()},
            "undetermined": m.undetermined, "summary": m.summary,
            **({} if m.backlash_um is None else {
                "backlash_um": m.backlash_um.tolist(),
                "cov_with_backlash": m.cov_with_backlash.tolist()})}


def model_from_dict(d: dict, *, name: str = "model") -> Model:
    """Rebuild a model from :func:`model_to_dict` output, checking its shape."""
    try:
        terms = kin.KinematicTerms(tuple((str(n), int(o)) for n, o in d["orders"]),
                                   tuple(float(x) for x in d["range_mm"]),
                                   tuple((str(n), float(p)) for n, p in d.get("periods", [])))
        coef = np.asarray(d["coef"], float)
        cov = np.asarray(d["cov"], float)
        probes = {str(k): np.asarray(v, float) for k, v in d["probes_mm"].items()}
        backlash = joint = None
        if "backlash_um" in d:
            backlash = np.asarray(d["backlash_um"], float)
            joint = np.asarray(d["cov_with_backlash"], float)
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"is not a model file written by 'fit --save' ({exc}).",
                        file=name) from exc
    if coef.shape != (terms.n,) or cov.shape != (terms.n, terms.n):
        raise DataError(f"expected {terms.n} coefficients and a {terms.n}x{terms.n} "
                        f"covariance, found {coef.shape} and {cov.shape}.", file=name)
    if backlash is None and "backlash" in str(d.get("spec", "")).split(","):
        raise DataError("the model's spec has backlash but the file holds no backlash spans "
                        "(written by an older version).", file=name,
                        hint="refit and save the model again.")
    if backlash is not None and (backlash.shape != (3,)
                                 or joint.shape != (terms.n + 3, terms.n + 3)):
        raise DataError(f"expected 3 backlash spans and a {terms.n + 3}x{terms.n + 3} joint "
                        f"covariance, found {backlash.shape} and {joint.shape}.", file=name)
    return Model(d.get("spec", ""), terms, coef, cov, probes, bool(d.get("undetermined")),
                 d.get("summary", {}), backlash, joint)


def _extrapolation_note(m: Model, x_mm: np.ndarray) -> np.ndarray:
    """Per point: "" inside the region the fit measured (box of its scale readings),
    else why the correction is an extrapolation. A polynomial fitted over part of a
    stroke is not evidence about the rest, and outside the machine's range it is not even
    defined; the uncertainty, propagated from the coefficients, does not show that."""
    rng = np.asarray(m.terms.range_mm, float)
    note = np.full(len(x_mm), "", dtype=object)
    region = m.summary.get("region_mm") if isinstance(m.summary, dict) else None
    if region is not None:
        lo, hi = np.asarray(region[0], float), np.asarray(region[1], float)
        outside = ((x_mm < lo - 1.0) | (x_mm > hi + 1.0)).any(axis=1)
        note[outside] = "outside the measured region"
    # styli put scale readings a little beyond the strokes (the thesis layout: z = -50 mm),
    # so only an excursion of more than a stylus length (100 mm, or 5 % of a longer stroke)
    # says the point is off the machine, or units or frame are wrong
    tol = np.maximum(0.05 * rng, 100.0)
    beyond = ((x_mm < -tol) | (x_mm > rng + tol)).any(axis=1)
    note[beyond] = "outside the machine's range"
    return note


def save_model(model: Model | FitResult, path) -> None:
    """Write a model JSON file."""
    Path(path).write_text(json.dumps(model_to_dict(model), indent=1))


def load_model(path) -> Model:
    """Read a model JSON file."""
    p = Path(path)
    try:
        d = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(f"cannot read a model ({exc}).", file=p.name) from exc
    return model_from_dict(d, name=p.name)


def read_points(source, *, name=None) -> pd.DataFrame:
    """Read points to correct: ``x_mm,y_mm,z_mm`` and ``probe`` (plus any other columns)."""
    df, name = _read_csv(source, name)
    _require(df, ("x_mm", "y_mm", "z_mm"), name, "points")
    out = df.copy()
    for c in ("x_mm", "y_mm", "z_mm"):
        out[c] = _numeric(df, c, name)
    out.attrs["source"] = name
    return out


def compensate(model: Model | FitResult, points: pd.DataFrame) -> pd.DataFrame:
    """Corrected points ``xc_mm, yc_mm, zc_mm`` with standard uncertainties in µm.

    ``points`` needs ``x_mm, y_mm, z_mm`` (reported tip centres, machine frame) and a
    ``probe`` column unless the model has a single probe. With a backlash model the
    points' order (``time_min``, else the rows) is their measurement order, and the
    output gets the approach direction of each axis (``approach_x`` ...: +1, -1, 0 unknown).
    """
    m = model_from_result(model) if isinstance(model, FitResult) else model
    name = points.attrs.get("source", "points")
    if "probe" in points:
        probes = points["probe"].astype(str).str.strip().to_numpy()
    elif len(m.probes_mm) == 1:
        probes = np.full(len(points), next(iter(m.probes_mm)))
    else:
        raise DataError(f"missing column 'probe'; the model has probes "
                        f"{', '.join(m.probes_mm)}.", file=name, column="probe")
    file_rows = _file_rows(points)
    for i, q in enumerate(probes):
        if q not in m.probes_mm:
            raise DataError(f"probe {q!r} is not in the model (known: "
                            f"{', '.join(m.probes_mm)}).", file=name, row=int(file_rows[i]),
                            column="probe")
    r = points[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    rng = np.asarray(m.terms.range_mm, float)
    if len(r) and rng.max() >= 100 and np.nanmax(np.abs(r)) <= 2.0:
        raise DataError(f"every coordinate is within 2 mm of the origin of a "
                        f"{rng.max():.0f} mm machine: the points look like metres.",
                        file=name, column="x_mm", hint="write the points in mm.")
    p = np.array([m.probes_mm[q] for q in probes]).reshape(-1, 3)
    x = r - p
    d = None  # approach directions, with a backlash model
    if m.backlash_um is None:
        e_um, u = propagate_error(m.terms, m.coef, m.cov, x, p)
    else:
        t = points["time_min"].to_numpy(float) if "time_min" in points and \
            points["time_min"].notna().all() else None
        d = approach_directions(x, t)
        # the reversal enters each axis linearly: extra Jacobian columns diag(d/2)
        e_um, u = propagate_error(m.terms, m.coef, m.cov_with_backlash, x, p,
                                  extra_jac=np.eye(3)[None] * (d / 2)[:, None, :])
        e_um = e_um + m.backlash_um * d / 2
        # direction unknown: the correction is ±span/2 with equal odds, σ = |span|/2
        u = np.sqrt(u**2 + (d == 0) * (m.backlash_um / 2) ** 2)
    if m.undetermined:
        u[:] = np.nan
    out = points.copy()
    out["xc_mm"], out["yc_mm"], out["zc_mm"] = (r + e_um * kin.UM).T
    out["ex_um"], out["ey_um"], out["ez_um"] = e_um.T
    out["u_x_um"], out["u_y_um"], out["u_z_um"] = u.T
    out["extrapolated"] = _extrapolation_note(m, x)
    if d is not None:
        for a, col in enumerate(("approach_x", "approach_y", "approach_z")):
            out[col] = d[:, a].astype(int)
    return out

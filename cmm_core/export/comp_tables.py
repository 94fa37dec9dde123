"""Vendor-neutral compensation tables of a fitted kinematic model (docs/compensation.md).

Two forms, both from the 21-error kinematic model (thesis eq. 4.13 and its other machine
layouts, ``docs/layouts.md``):

- :func:`compensation_grid`: a regular 3-D grid over the machine's strokes. At each node
  (scale readings of the ram reference point) the correction of the indicated tip centre
  ``tip = node + probe offset`` in x, y, z (µm) and its standard uncertainty (k = 1). The
  correction is ``e = x* - (x + p)``, true minus indicated, *added* to the reading: it is
  what :func:`cmm_core.export.correction.compensate` adds to that tip reading.
- :func:`axis_tables`: what a controller that evaluates the kinematic model itself needs:
  for each axis its six error functions (positioning, two straightness, three rotations)
  tabulated along the axis, and the three squareness angles, each with its standard
  uncertainty. Fed to eq. (L1)-(L2) of ``docs/layouts.md`` at a node they give the grid's
  correction (to round-off, ``tests/test_comp_export.py``).

Neither holds backlash (a direction-dependent error) nor effects of the plate or the
temperature: the headers say so.
"""

from __future__ import annotations

import io
import math
import zipfile

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from ..io import DataError, Provenance
from ..machine import AXES, split_chain
from ..model import BY_TOKEN, CHI2_ALPHA, FitResult, covariance_factor
from .correction import _propagated, _refuse_non_finite, extrapolation_note
from .model_file import Model, model_from_result
from .safe import MAX_GRID_NODES, safe_csv

GRID_FORMAT = "cmm-error-lab compensation grid 1"
AXIS_FORMAT = "cmm-error-lab axis table 1"
MAX_AXIS_NODES = 10_001
"""Most rows of one per-axis table (a 0.1 mm step over a 1 m stroke)."""

SIGN_GRID = ("correction = true - indicated, added to the reading: true tip centre = "
             "(tip_x_mm, tip_y_mm, tip_z_mm) + (cx_um, cy_um, cz_um) / 1000")
_ROLE = {0: "positioning", 1: "straightness", 2: "straightness"}
_ROTATION = {"x": ("roll", "pitch", "yaw"), "y": ("pitch", "roll", "yaw"),
             "z": ("tilt about x", "tilt about y", "roll")}
_ISO = "XYZ"
_ISO_ROT = "ABC"


def as_model(obj: Model | FitResult) -> Model:
    """The model of a fit result, or the model itself."""
    return model_from_result(obj) if isinstance(obj, FitResult) else obj


def chi2_status(obj: Model | FitResult) -> dict:
    """The χ² test of the fit behind a model (``FitResult.fails_chi2_test``).

    Returns
    -------
    dict
        ``chi2_dof`` (the fit's χ²/dof), ``chi2_test_dof``, ``dof`` and ``p_value`` of the
        tested statistic (of a saved model: its summary's ``chi2_test_dof``, ``dof_test``
        and ``chi2_p_value``, None in model files written before they were kept),
        ``alpha`` (the test's level), ``fails`` (True, False, or None when unknown) and
        ``birge_ratio``.
    """
    if isinstance(obj, FitResult):
        return {"chi2_dof": float(obj.chi2_dof), "chi2_test_dof": float(obj.chi2_test_dof),
                "dof": int(obj.test_statistic[1]), "p_value": float(obj.chi2_p_value),
                "alpha": CHI2_ALPHA, "fails": bool(obj.fails_chi2_test),
                "birge_ratio": float(obj.birge_ratio)}
    s = obj.summary if isinstance(obj.summary, dict) else {}

    def num(key):
        v = s.get(key)
        return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None

    fails = s.get("fails_chi2_test")
    dof = num("dof_test")
    return {"chi2_dof": num("chi2_dof"), "chi2_test_dof": num("chi2_test_dof"),
            "dof": None if dof is None else int(dof), "p_value": num("chi2_p_value"),
            "alpha": CHI2_ALPHA,
            "fails": fails if isinstance(fails, bool) else None,
            "birge_ratio": num("birge_ratio")}


def axis_nodes(stroke_mm: float, step_mm: float, *, limit: int = MAX_AXIS_NODES,
               axis: str = "") -> np.ndarray:
    """Nodes ``0, step, 2·step, ...`` along one stroke (mm), ending at the stroke's end
    (the last interval is shorter when the stroke is not a multiple of the step)."""
    if not (math.isfinite(step_mm) and step_mm > 0):
        raise ValueError(f"the step must be a positive length in mm, found {step_mm!r}.")
    n = int(math.floor(stroke_mm / step_mm + 1e-9)) + 1
    if n > limit:
        raise ValueError(f"a step of {step_mm:g} mm gives {n:,} nodes over the "
                         f"{stroke_mm:g} mm stroke{' of ' + axis if axis else ''} (limit "
                         f"{limit:,}); use a coarser step.")
    u = step_mm * np.arange(n)
    return np.append(u, stroke_mm) if stroke_mm - u[-1] > 1e-6 else u


def probe_offset(model: Model, probe: str | None) -> np.ndarray:
    """Offset (mm) of a probe of the model; None is the ram reference point (0, 0, 0)."""
    if probe is None:
        return np.zeros(3)
    if str(probe) not in model.probes_mm:
        raise DataError(f"probe {str(probe)[:40]!r} is not in the model (known: "
                        f"{', '.join(model.probes_mm)}).", file=model.name,
                        column="probes_mm", hint="name one of them, or none for the ram "
                                                 "reference point.")
    return np.asarray(model.probes_mm[str(probe)], float)


def _refuse_undetermined(model: Model) -> None:
    if model.undetermined:
        raise DataError("the model has parameter combinations the data do not determine: "
                        "its corrections there are an arbitrary (minimum-norm) choice, not "
                        "fit for a compensation table.", file=model.name,
                        column="undetermined", hint="measure more placements and refit.")


def compensation_grid(obj: Model | FitResult, step_mm: float | ArrayLike = 100.0, *,
                      probe: str | None = None, allow_undetermined: bool = False,
                      lower_mm: ArrayLike | None = None,
                      upper_mm: ArrayLike | None = None) -> pd.DataFrame:
    """Correction and its standard uncertainty on a regular grid over the strokes.

    The one grid of the package: the app's error map (``export.error_map_grid``) is this
    table under its older column names.

    Parameters
    ----------
    obj : Model or FitResult
    step_mm : float or 3 floats
        Grid step per axis (mm); each axis ends at its stroke (:func:`axis_nodes`), or at
        ``upper_mm``.
    probe : str, optional
        Probe of the model whose tip is corrected; default the ram reference point
        (offset 0), the probe of a controller's table.
    allow_undetermined : bool
        Tabulate a model with undetermined combinations (uncertainties NaN); refused by
        default.
    lower_mm, upper_mm : 3 floats, optional
        Corners of the box tabulated (scale readings, mm); default the strokes, 0 to range.

    Returns
    -------
    DataFrame
        ``x_mm, y_mm, z_mm`` (node: scale readings), ``tip_x_mm, tip_y_mm, tip_z_mm``
        (indicated tip centre, node + offset), ``cx_um, cy_um, cz_um`` (correction,
        ``e = x* - (x + p)`` of ``kinematics.error``), ``u_cx_um, u_cy_um, u_cz_um``
        (standard uncertainty by the law of propagation, ``correction._propagated``)
        and ``extrapolated`` (1 where the node is outside the region the fit measured).
        Rows run x fastest, then y, then z.
    """
    m = as_model(obj)
    if not allow_undetermined:
        _refuse_undetermined(m)
    p = probe_offset(m, probe)
    step = np.broadcast_to(np.asarray(step_mm, float), (3,))
    lo = np.zeros(3) if lower_mm is None else np.asarray(lower_mm, float)
    hi = np.asarray(m.terms.range_mm, float) if upper_mm is None else np.asarray(upper_mm,
                                                                                  float)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (hi >= lo).all()):
        raise ValueError(f"the grid's corners must be finite with upper >= lower, found "
                         f"{lo.tolist()} to {hi.tolist()} mm.")
    axes = [a0 + axis_nodes(b - a0, st, limit=201, axis=a)
            for a0, b, st, a in zip(lo, hi, step, AXES, strict=True)]
    n = math.prod(len(a) for a in axes)
    if n > MAX_GRID_NODES:
        # the uncertainty at every node costs a Jacobian row: keep it to seconds
        hint = (float(np.prod(np.maximum(hi - lo, 1e-9))) / MAX_GRID_NODES) ** (1 / 3)
        raise ValueError(f"the grid would have {n:,} nodes (limit {MAX_GRID_NODES:,}); use a "
                         f"step of about {math.ceil(hint):d} mm or more, or a smaller box.")
    Z, Y, X = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    x = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    e, u = _propagated(m, covariance_factor(m.cov), x, np.broadcast_to(p, x.shape))
    _refuse_non_finite(m, None, e, u, m.name)
    if m.undetermined:
        u[:] = np.nan
    out = pd.DataFrame(x, columns=["x_mm", "y_mm", "z_mm"])
    out[["tip_x_mm", "tip_y_mm", "tip_z_mm"]] = x + p
    out[["cx_um", "cy_um", "cz_um"]] = e
    out[["u_cx_um", "u_cy_um", "u_cz_um"]] = u
    # the region test of compensate itself: a node is flagged exactly when a point there
    # would be
    out["extrapolated"] = (extrapolation_note(m, x) != "").astype(int)
    return out


def function_values(m: Model, name: str, u_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One error function at axis coordinates ``u_mm`` (µm or µrad) and its standard
    uncertainty (the function's own coefficients, their covariance); zeros for a function
    the model does not have (held at zero by assumption)."""
    sl = m.terms.slices.get(name)
    u_mm = np.asarray(u_mm, float)
    if sl is None:
        return np.zeros(len(u_mm)), np.zeros(len(u_mm))
    D = m.terms.design(name, u_mm)
    cov = m.cov[sl, sl]
    u = np.sqrt(np.clip(np.einsum("nk,kl,nl->n", D, cov, D), 0, None))
    return D @ m.coef[sl], (np.full_like(u, np.nan) if m.undetermined else u)


def axis_functions(axis: str) -> list[tuple[str, str]]:
    """``(function, what it is)`` of the six error functions of one axis, in the order
    positioning, straightness, straightness, rotation about x, y, z."""
    out = []
    for c in AXES:
        name = f"d{axis}{c}"
        what = "positioning" if c == axis else f"straightness in {c}"
        out.append((name, f"{what} (ISO 230-1 E{_ISO[AXES.index(c)]}{axis.upper()})"))
    for i, c in enumerate(AXES):
        out.append((f"r{axis}{c}", f"{_ROTATION[axis][i]}, rotation about {c} "
                                   f"(ISO 230-1 E{_ISO_ROT[i]}{axis.upper()})"))
    out.sort(key=lambda f: (f[0][0] == "r", f[0][0] == "d" and f[0][2] != axis))
    return out


def axis_table(obj: Model | FitResult, axis: str, step_mm: float) -> pd.DataFrame:
    """The six error functions of one axis tabulated along it, with uncertainties.

    Columns ``<axis>_mm`` (scale reading of that axis), then per function ``<name>_um`` or
    ``<name>_urad`` and ``u_<name>_um`` / ``u_<name>_urad`` (standard uncertainty, k = 1),
    in the order of :func:`axis_functions`. Values are the model's functions as defined in
    ``kinematics.basis`` (zero at the axis origin; sign conventions in docs/layouts.md).
    """
    m = as_model(obj)
    a = AXES.index(axis)
    u_mm = axis_nodes(m.terms.range_mm[a], float(step_mm), axis=axis)
    out = {f"{axis}_mm": u_mm}
    for name, _ in axis_functions(axis):
        unit = "um" if name[0] == "d" else "urad"
        v, u = function_values(m, name, u_mm)
        out[f"{name}_{unit}"], out[f"u_{name}_{unit}"] = v, u
    return pd.DataFrame(out)


def squareness_table(obj: Model | FitResult) -> pd.DataFrame:
    """The three squareness angles (µrad) with standard uncertainties and meaning."""
    m = as_model(obj)
    rows = []
    for name, what in (("sxy", "adds sxy*y to x (y carriage)"),
                       ("sxz", "adds sxz*z to x (z carriage)"),
                       ("syz", "adds syz*z to y (z carriage)")):
        v, u = function_values(m, name, np.ones(1))  # basis: the coordinate itself
        rows.append({"name": name, "value_urad": float(v[0]), "u_urad": float(u[0]),
                     "in_model": name in m.terms.slices, "meaning": what})
    return pd.DataFrame(rows)


def axis_roles(m: Model) -> dict:
    """Per axis, ``(role, sign)``: ``("carries the probe", +1)`` or ``("moves the table",
    -1)``: the sign with which its translations enter the correction (docs/layouts.md)."""
    table, _ = split_chain(m.terms.chain)
    return {a: (("moves the table", -1) if a in table else ("carries the probe", +1))
            for a in AXES}


def model_lines(obj: Model | FitResult, source: str | None = None,
                provenance: Provenance | None = None) -> list[str]:
    """Header lines naming the table's provenance (``provenance``, default
    :meth:`Model.derived_provenance`: software, time, machine, input digests), the model
    and the outcome of its χ² test."""
    m = as_model(obj)
    s = m.summary if isinstance(m.summary, dict) else {}
    t = chi2_status(obj)
    head = [*(provenance or m.derived_provenance()).lines(),
            f"model: {source or m.name}; spec {m.spec}; fitted "
            f"{s.get('created', 'on a date the model file does not record')}; "
            f"sigma {s.get('sigma_um', 'unknown')} um; RMS {_g(s.get('rms_um'))} um; "
            f"chi2/dof {_g(t['chi2_dof'])}; plate {s.get('plate', 'unknown')}"]
    if t["fails"] is None:
        head.append("chi2 test: outcome not recorded in the model file")
    else:
        p = "" if t["p_value"] is None else f", p = {t['p_value']:.3g}"
        head.append(f"chi2 test at {t['alpha']:g}: {'FAILS' if t['fails'] else 'passes'}{p}"
                    + (f"; the uncertainties' noise part is too small by the Birge "
                       f"ratio {_g(t['birge_ratio'])}" if t["fails"] else ""))
    head.append(f"layout: {m.terms.layout} (chain {m.terms.chain}; docs/layouts.md)")
    if m.undetermined:
        head.append("WARNING: the model has undetermined combinations; uncertainties empty")
    return head


def _g(v) -> str:
    return "unknown" if v is None else f"{float(v):.4g}"


_EXTRA_UNITS = {t: b.comp_units for t, b in BY_TOKEN.items() if b.model_keys}
"""Unit of the parameters each compensating block applies to new points (its
``comp_units``)."""


def model_extras(m: Model) -> list[tuple[str, str, float, float]]:
    """``(label, unit, value, standard uncertainty)`` of the parameters a model applies to
    new points besides the kinematic map (backlash spans, scale expansion coefficients):
    the model's ``parts``, or the ``backlash_um`` of model objects that predate them."""
    out = []
    parts = getattr(m, "parts", None)
    if parts:
        for token, part in parts.items():
            k = len(part.labels)
            u = np.sqrt(np.clip(np.diag(part.cov)[-k:], 0, None))
            out += [(str(lab), _EXTRA_UNITS.get(token, ""), float(v),
                     float(s)) for lab, v, s in zip(part.labels, part.values, u, strict=True)]
    return out


def _not_in_table(m: Model) -> str:
    extra = "".join(f"; {lab} {v:.4g} {unit}" for lab, unit, v, _ in model_extras(m))
    return ("NOT in this table: plate effects, backlash (direction-dependent) and the scales' "
            "thermal expansion (temperature-dependent)"
            + (f"; this model has{extra[1:]}" if extra else ""))


def grid_csv(obj: Model | FitResult, grid: pd.DataFrame, probe: str | None = None,
             source: str | None = None, provenance: Provenance | None = None) -> str:
    """The grid of :func:`compensation_grid` as CSV with its documented header block
    (``provenance``: :func:`model_lines`)."""
    m = as_model(obj)
    p = probe_offset(m, probe)
    axes = []
    for c in AXES:
        v = np.unique(grid[f"{c}_mm"].to_numpy())
        axes.append(f"{c} {v[0]:g} to {v[-1]:g} mm, {len(v)} nodes"
                    + (f", step {v[1] - v[0]:g}" if len(v) > 1 else ""))
    head = [f"format: {GRID_FORMAT}", *model_lines(obj, source, provenance),
            f"probe: {probe or 'none, the ram reference point'}; offset "
            f"{' '.join(f'{v:g}' for v in p)} mm (tip = node + offset)",
            "units: coordinates mm; corrections and their uncertainties um (micrometres); "
            "standard uncertainty k = 1",
            f"sign: {SIGN_GRID}",
            "a controller that subtracts an error (indicated - true) uses -cx, -cy, -cz",
            f"grid: {'; '.join(axes)}; rows x fastest, then y, then z",
            "extrapolated: 1 where the node lies outside the region the fit measured",
            _not_in_table(m)]
    return safe_csv(grid, float_format="%.6f", header_lines=head)


def axis_tables(obj: Model | FitResult, step_mm: float, *,
                allow_undetermined: bool = False) -> dict[str, pd.DataFrame]:
    """``{"x": ..., "y": ..., "z": ..., "squareness": ...}``: the per-axis tables of
    :func:`axis_table` and :func:`squareness_table` (a model with undetermined
    combinations refused unless ``allow_undetermined``)."""
    m = as_model(obj)
    if not allow_undetermined:
        _refuse_undetermined(m)
    return {**{a: axis_table(m, a, step_mm) for a in AXES},
            "squareness": squareness_table(m)}


def axis_tables_csv(obj: Model | FitResult, step_mm: float, source: str | None = None, *,
                    allow_undetermined: bool = False,
                    provenance: Provenance | None = None) -> dict[str, str]:
    """File name -> CSV text of the per-axis tables (``axis_x.csv`` ...,
    ``squareness.csv``), each with a header stating units, sign convention and
    provenance (:func:`model_lines`)."""
    m = as_model(obj)
    tables = axis_tables(m, step_mm, allow_undetermined=allow_undetermined)
    roles = axis_roles(m)
    common = model_lines(obj, source, provenance)
    out = {}
    for a in AXES:
        role, sign = roles[a]
        lines = [f"format: {AXIS_FORMAT}", *common,
                 f"axis {a}: this carriage {role}; rows: {a}_mm, its scale reading",
                 "units: translations um, rotations urad, standard uncertainties k = 1 "
                 "(marginal: a correction's uncertainty needs their correlations, see the grid)",
                 "sign: the model's error functions (docs/layouts.md): "
                 + ("translations are true - indicated of this carriage's reference point and "
                    "enter the correction with +" if sign > 0 else
                    "translations are the table's own motion error in the foundation frame "
                    "and enter the correction with -")
                 + "; rotations right-handed, R = Rz Ry Rx; a controller that subtracts "
                 "an error uses every value negated",
                 *(f"{n}: {w}" for n, w in axis_functions(a)),
                 "functions not in the model are 0 with u 0: "
                 + (", ".join(n for n, _ in axis_functions(a) if n not in m.terms.slices)
                    or "none"),
                 _not_in_table(m)]
        out[f"axis_{a}.csv"] = safe_csv(tables[a], float_format="%.6f", header_lines=lines)
    out["squareness.csv"] = safe_csv(
        tables["squareness"], float_format="%.6f",
        header_lines=[f"format: {AXIS_FORMAT}", *common,
                      "units: urad (angles; value times the coordinate in mm gives nm)",
                      "sign: true - indicated, entering the correction with + in every "
                      "layout; a controller that subtracts an error uses them negated"])
    return out


def axis_tables_zip(obj: Model | FitResult, step_mm: float, source: str | None = None, *,
                    provenance: Provenance | None = None) -> bytes:
    """The per-axis tables of :func:`axis_tables_csv` in one zip archive (in memory)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, text in axis_tables_csv(obj, step_mm, source,
                                          provenance=provenance).items():
            z.writestr(name, text)
    return buf.getvalue()

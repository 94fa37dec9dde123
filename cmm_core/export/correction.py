"""Compensation: correct measured points with a fitted model, with uncertainties.

The true tip centre of a reported point ``r`` measured with probe offset ``p`` is
``r + e(r - p, p)`` (SPEC conventions). A saved model holds what that needs: the
kinematic terms and coefficients with their covariance, and the probe offsets (nominal plus
any fitted offset error). The effect blocks that act on new points add their parts
(``Block.compensation``; the model file's keys are each block's, ``Block.part_to_file``)
and correct the points in turn (``Block.correct``): ``backlash`` for the direction from
which each axis last moved, ``machine_thermal`` for the scales' expansion at the points'
scale temperatures. The uncertainty propagates the kinematic coefficients and every
part's parameters through their joint covariance (JCGM 100 eq. 13):
``u² = diag(J V Jᵀ)`` with ``J = [∂e/∂coef, ∂δ_block/∂values ...]``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..io import (
    MAX_PROBE_MM,
    MAX_STROKE_MM,
    MIN_STROKE_MM,
    DataError,
    atomic_write_text,
    read_json,
)
from ..io.delimited import file_rows, numeric_column, read_csv_text, require_columns, require_rows
from ..io.errors import cut_repr
from ..machine import kinematics as kin
from ..model import MAX_ORDER, REGISTRY, FitResult, checked_cov, parse_spec, propagate_error

COMPENSATING = tuple(b for b in REGISTRY if b.model_keys)
"""Blocks that act on new points, in the order of their parameters in the joint
covariance (after the kinematic coefficients)."""


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
    parts : dict
        Block token -> :class:`blocks.base.ModelPart` of each block that acts on new
        points (backlash spans, scale expansion coefficients), in :data:`COMPENSATING`
        order; each holds the joint covariance up to its own parameters.
    name : str
        File the model was read from (for messages).
    """

    spec: str
    terms: kin.KinematicTerms
    coef: np.ndarray
    cov: np.ndarray
    probes_mm: dict
    undetermined: bool
    summary: dict
    parts: dict = field(default_factory=dict)
    name: str = "model"

    @property
    def joint_cov(self) -> np.ndarray:
        """Covariance of the kinematic coefficients followed by every part's parameters
        (the last part's: each part holds the covariance up to its own)."""
        return next(reversed(self.parts.values())).cov if self.parts else self.cov


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
    blk = result.problem.layout.blocks
    before = np.arange(blk["kinematic"].start, blk["kinematic"].stop)
    parts = {}
    for b in COMPENSATING:
        part = b.compensation(result, before)
        if part is not None:
            parts[b.token] = part
            before = np.r_[before, np.arange(blk[b.token].start, blk[b.token].stop)]
    # an undetermined span or coefficient would be applied as if known: it makes the
    # model undetermined
    used = set(result.terms.labels).union(*(p.labels for p in parts.values()))
    return Model(result.spec, result.terms, result.kinematic_coef.copy(),
                 result.kinematic_cov.copy(), probes,
                 any(lab in used for lab in result.unidentifiable),
                 {"rms_um": result.rms_um, "chi2_dof": result.chi2_dof, "n_obs": result.n_obs,
                  "fails_chi2_test": bool(result.fails_chi2_test),
                  "birge_ratio": float(result.birge_ratio),
                  # the χ² test's statistic, so that results exported from the model file
                  # state the test as those of the fit (results_export); absent in files
                  # written before them, which then report these as unknown
                  "chi2_test_dof": float(result.chi2_test_dof),
                  "dof_test": int(result.test_statistic[1]),
                  "chi2_p_value": float(result.chi2_p_value),
                  "artefact": getattr(obs, "artefact", "ball_plate"),
                  "placements": [str(p) for p in obs.positions],
                  "plate": result.plate, "sigma_um": result.sigma_um,
                  "certificate_u_source": result.certificate_u_source,
                  "region_mm": [np.min(obs.r_mm - obs.p_mm, axis=0).tolist(),
                                np.max(obs.r_mm - obs.p_mm, axis=0).tolist()]},
                 parts)


def model_to_dict(model: Model | FitResult) -> dict:
    """JSON-ready dict of a model (or of a fit result's model)."""
    m = model_from_result(model) if isinstance(model, FitResult) else model
    return {"format": "cmm-error-lab model 1", "spec": m.spec,
            "orders": [list(o) for o in m.terms.orders], "range_mm": list(m.terms.range_mm),
            "periods": [list(o) for o in m.terms.periods],
            # the default layout is left out: model files of the moving bridge stay
            # readable by releases before layouts existed
            **({} if m.terms.layout == kin.DEFAULT_LAYOUT else {"layout": m.terms.layout}),
            "labels": m.terms.labels, "coef": m.coef.tolist(), "cov": m.cov.tolist(),
            "probes_mm": {k: list(map(float, v)) for k, v in m.probes_mm.items()},
            "undetermined": m.undetermined, "summary": m.summary,
            # each block's own keys; none for a model without such blocks (the format of
            # releases before them)
            **{k: v for b in COMPENSATING if b.token in m.parts
               for k, v in b.part_to_file(m.parts[b.token]).items()}}


MODEL_FORMAT = "cmm-error-lab model 1"
_MODEL_REQUIRED = ("format", "spec", "orders", "range_mm", "periods", "labels", "coef",
                   "cov", "probes_mm", "undetermined", "summary")
_MODEL_OPTIONAL = ("layout", *(k for b in COMPENSATING for k in b.model_keys))


_checked_cov = checked_cov  # the name this module used before the blocks shared it


def model_from_dict(d: dict, *, name: str = "model") -> Model:
    """Rebuild a model from :func:`model_to_dict` output, checking every field.

    Refused with a :class:`DataError` naming the field: another format, labels that do not
    follow from the orders (reordered or edited), non-finite coefficients, a covariance
    that is not a finite positive semi-definite matrix, strokes that are not mm, probe
    offsets that are not 3-vectors in mm.
    """
    layout = _checked_model_header(d, name)
    terms, coef, cov, probes = _parsed_model(d, name, layout)
    spec = _checked_model_terms(d, terms, name)
    _checked_model_values(d, terms, coef, cov, probes, name)
    parts = _model_parts(d, spec, terms.n, name)
    summary = d.get("summary", {})
    if not isinstance(summary, dict):
        raise DataError("summary must be an object.", file=name, column="summary")
    region = summary.get("region_mm")
    if region is not None:
        reg = np.asarray(region, float) if isinstance(region, list) else None
        if reg is None or reg.shape != (2, 3) or not np.isfinite(reg).all():
            raise DataError(f"summary.region_mm must be [[3 numbers], [3 numbers]] (mm), "
                            f"found {cut_repr(region)}.", file=name, column="summary.region_mm")
    if not isinstance(d.get("undetermined", False), bool):
        raise DataError("undetermined must be true or false.", file=name,
                        column="undetermined")
    return Model(spec, terms, coef, cov, probes, bool(d.get("undetermined")), summary,
                 parts, name)


def _model_parts(d, spec, n_kin, name):
    """The parts of the compensating blocks the file holds, each read and checked by its
    block; a spec naming such a block without its part (or the reverse) is refused."""
    effects = parse_spec(spec).effects
    parts, n_before = {}, n_kin
    for b in COMPENSATING:
        part = b.part_from_file(d, n_before, name)
        if part is None and b.token in effects and not b.model_keys_optional:
            raise DataError(f"the model's spec has {b.token} but the file holds no "
                            f"{b.model_what} (written by an older version).", file=name,
                            hint="refit and save the model again.")
        if part is not None and b.token not in effects:
            raise DataError(f"the file holds {b.model_what} but the model's spec has no "
                            f"{b.token}.", file=name, column=b.model_keys[0],
                            hint="refit and save the model again (fit --save); do not "
                                 "edit it.")
        if part is not None:
            parts[b.token] = part
            n_before += len(part.values)
    return parts


def _checked_model_header(d, name):
    """A dict of this program's model format, with its machine layout."""
    if not isinstance(d, dict):
        raise DataError(f"is not a model file written by 'fit --save' (expected a JSON object, "
                        f"found {type(d).__name__}).", file=name)
    missing = [k for k in _MODEL_REQUIRED if k not in d]
    extra = sorted(set(map(str, d)) - set(_MODEL_REQUIRED) - set(_MODEL_OPTIONAL))
    if d.get("format") == MODEL_FORMAT and (missing or extra):
        # written by the program: a missing or renamed key ("undeterminedx") would
        # silently take a default (an undetermined model passing as determined)
        raise DataError(f"{'missing key ' + repr(missing[0]) if missing else ''}"
                        f"{'; ' if missing and extra else ''}"
                        f"{'unknown key ' + cut_repr(extra[0]) if extra else ''}; expected the "
                        f"keys {', '.join(_MODEL_REQUIRED)}.", file=name,
                        column=missing[0] if missing else extra[0],
                        hint="refit and save the model again (fit --save); do not edit it.")
    if d.get("format") != MODEL_FORMAT:
        raise DataError(f"is not a model file written by 'fit --save' (expected \"format\": "
                        f"\"{MODEL_FORMAT}\", found {cut_repr(d.get('format'))}).", file=name)
    layout = d.get("layout", kin.DEFAULT_LAYOUT)  # files written before layouts existed
    if not isinstance(layout, str) or layout not in kin.LAYOUTS:
        raise DataError(f"layout {cut_repr(layout)} is not a known machine layout; expected one "
                        f"of: {', '.join(kin.LAYOUTS)}.", file=name, column="layout",
                        hint="refit and save the model again (fit --save); do not edit it.")
    return layout


def _parsed_model(d, name, layout):
    """The model's terms and arrays, or a DataError when the file's structure is wrong."""
    try:
        terms = kin.KinematicTerms(tuple((str(n), int(o)) for n, o in d["orders"]),
                                   tuple(float(x) for x in d["range_mm"]),
                                   tuple((str(n), float(p)) for n, p in d.get("periods", [])),
                                   layout)
        coef = np.asarray(d["coef"], float)
        cov = np.asarray(d["cov"], float)
        probes = {str(k): np.asarray(v, float) for k, v in d["probes_mm"].items()}
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise DataError(f"is not a model file written by 'fit --save' ({cut_repr(str(exc), 80)}).",
                        file=name) from None
    return terms, coef, cov, probes


def _checked_model_terms(d, terms, name):
    """Spec, strokes, orders, periods and labels consistent with each other; the spec."""
    if not isinstance(d["periods"], list) or not isinstance(d["orders"], list):
        raise DataError("orders and periods must be lists of [function, value] pairs.",
                        file=name, column="orders" if not isinstance(d["orders"], list)
                        else "periods")
    spec = d["spec"]
    try:
        if not isinstance(spec, str):
            raise ValueError(f"expected a model spec string, found {cut_repr(spec)}")
        parse_spec(spec)
    except ValueError as exc:
        raise DataError(f"spec: {cut_repr(str(exc), 120)}.", file=name, column="spec",
                        hint="refit and save the model again (fit --save).") from None
    rng = np.asarray(terms.range_mm, float)
    if rng.shape != (3,) or not np.isfinite(rng).all() or rng.min() < MIN_STROKE_MM \
            or rng.max() > MAX_STROKE_MM:
        raise DataError(f"range_mm {cut_repr(d['range_mm'])} is not three strokes in mm "
                        f"({MIN_STROKE_MM:g} to {MAX_STROKE_MM:g}).", file=name,
                        column="range_mm")
    if any(o < 1 or o > MAX_ORDER for _, o in terms.orders):
        raise DataError(f"orders must be 1 to {MAX_ORDER}, found {cut_repr(d['orders'])}.",
                        file=name, column="orders")
    if any(not (np.isfinite(p) and p > 0) for _, p in terms.periods):
        raise DataError(f"periods must be positive lengths (mm), found "
                        f"{cut_repr(d.get('periods'))}.", file=name, column="periods")
    if d.get("labels") != terms.labels:
        raise DataError(f"labels {cut_repr(d.get('labels'), 80)} do not match the orders (expected "
                        f"{cut_repr(terms.labels, 80)}); the coefficients cannot be assigned.",
                        file=name, column="labels",
                        hint="refit and save the model again (fit --save); do not edit it.")
    return spec


def _checked_model_values(d, terms, coef, cov, probes, name):
    """Finite coefficients, a positive semi-definite covariance and probe offsets in mm."""
    if coef.shape != (terms.n,) or cov.shape != (terms.n, terms.n):
        raise DataError(f"expected {terms.n} coefficients and a {terms.n}x{terms.n} "
                        f"covariance, found {coef.shape} and {cov.shape}.", file=name)
    if not np.isfinite(coef).all():
        k = int(np.flatnonzero(~np.isfinite(coef))[0])
        raise DataError(f"coefficient {terms.labels[k]} is {coef[k]}; expected a finite "
                        "number.", file=name, column="coef",
                        hint="refit and save the model again (fit --save).")
    _checked_cov(cov, terms.n, name, "cov")
    if not probes:
        raise DataError("the model has no probes; expected probes_mm with one offset per "
                        "stylus.", file=name, column="probes_mm")
    for q, p in probes.items():
        if p.shape != (3,) or not np.isfinite(p).all() or np.linalg.norm(p) > MAX_PROBE_MM:
            raise DataError(f"expected 3 finite numbers (mm), found {cut_repr(d['probes_mm'][q])}.",
                            file=name, column=f"probes_mm.{q}")


OFF_MACHINE = "outside the machine's range"


def refuse_off_machine(corrected: pd.DataFrame, name: str = "points") -> None:
    """Raise a :class:`DataError` when :func:`compensate` flagged points outside the
    machine's range: their "correction" extrapolates a polynomial far beyond the data
    (a point 400 m away got a 352 m correction), so a batch run must not pass it on as a
    result. The CLI calls this unless ``--allow-extrapolation`` is given."""
    off = (corrected["extrapolated"] == OFF_MACHINE).to_numpy()
    if off.any():
        rows = file_rows(corrected)
        i = int(np.flatnonzero(off)[0])
        n = int(off.sum())
        raise DataError(f"{n} point{'s' * (n > 1)} lie outside the machine's range, where "
                        "the model is not defined (this one at "
                        f"{corrected[['x_mm', 'y_mm', 'z_mm']].to_numpy(float)[i].round(1).tolist()}"
                        " mm); expected points in mm, machine frame.", file=name,
                        row=int(rows[i]), column="x_mm",
                        hint="check units and frame; to keep such points anyway, use "
                             "--allow-extrapolation (they are flagged in the 'extrapolated' "
                             "column).")


def extrapolation_note(m: Model, x_mm: np.ndarray) -> np.ndarray:
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
    note[beyond] = OFF_MACHINE
    return note


def save_model(model: Model | FitResult, path) -> None:
    """Write a model JSON file (atomically: a reader never sees half of it, a failed
    write leaves an existing file as it was)."""
    atomic_write_text(path, json.dumps(model_to_dict(model), indent=1))


def load_model(path) -> Model:
    """Read a model JSON file (a path, or bytes / file-like as uploaded), every field
    checked (:func:`model_from_dict`)."""
    d, name = read_json(Path(path) if isinstance(path, str) else path)
    return model_from_dict(d, name=name)


def read_points(source, *, name=None) -> pd.DataFrame:
    """Read points to correct: ``x_mm,y_mm,z_mm`` and ``probe`` (plus any other columns)."""
    df, name = read_csv_text(source, name)
    require_columns(df, ("x_mm", "y_mm", "z_mm"), name, "points")
    require_rows(df, name, "point to correct")
    out = df.copy()
    for c in ("x_mm", "y_mm", "z_mm"):
        out[c] = numeric_column(df, c, name)
    out.attrs["source"] = name
    return out


def compensate(model: Model | FitResult, points: pd.DataFrame) -> pd.DataFrame:
    """Corrected points ``xc_mm, yc_mm, zc_mm`` with standard uncertainties in µm.

    ``points`` needs ``x_mm, y_mm, z_mm`` (reported tip centres, machine frame) and a
    ``probe`` column unless the model has a single probe. With a backlash model the
    points' order (``time_min``, else the rows) is their measurement order, and the
    output gets the approach direction of each axis (``approach_x`` ...: +1, -1, 0 unknown).
    With a machine_thermal model the points need the scale temperature of every fitted
    axis (``temp_x_C``, ``temp_y_C``, ``temp_z_C``, °C).

    The correction is ``e + Σ δ_block`` (kinematic error, thesis eq. 4.13, plus each
    part's :meth:`blocks.base.Block.correct`), its uncertainty the propagation of the
    joint covariance (module docstring) plus any variance a part adds.
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
    rows_in_file = file_rows(points)
    for i, q in enumerate(probes):
        if q not in m.probes_mm:
            raise DataError(f"probe {cut_repr(q)} is not in the model {m.name} (known: "
                            f"{', '.join(m.probes_mm)}).", file=name, row=int(rows_in_file[i]),
                            column="probe")
    r = points[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    if not np.isfinite(r).all():
        i = int(np.flatnonzero(~np.isfinite(r).all(axis=1))[0])
        raise DataError("expected finite coordinates (mm), found "
                        f"{r[i].tolist()}.", file=name, row=int(rows_in_file[i]), column="x_mm")
    rng = np.asarray(m.terms.range_mm, float)
    if len(r) and rng.max() >= 100 and np.nanmax(np.abs(r)) <= 2.0:
        raise DataError(f"every coordinate is within 2 mm of the origin of a "
                        f"{rng.max():.0f} mm machine: the points look like metres.",
                        file=name, column="x_mm", hint="write the points in mm.")
    p = np.array([m.probes_mm[q] for q in probes]).reshape(-1, 3)
    x = r - p
    fixes = [b.correct(part, points, x, name) for b in COMPENSATING
             if (part := m.parts.get(b.token)) is not None]
    if not fixes:
        e_um, u = propagate_error(m.terms, m.coef, m.cov, x, p)
    else:
        # each part enters linearly: its Jacobian columns follow the kinematic ones
        e_um, u = propagate_error(m.terms, m.coef, m.joint_cov, x, p,
                                  extra_jac=np.concatenate([f.jac for f in fixes], axis=2))
        for f in fixes:
            e_um = e_um + f.delta_um
        extra = [f.var_um2 for f in fixes if f.var_um2 is not None]
        if extra:
            u = np.sqrt(u**2 + sum(extra))
    if m.undetermined:
        u[:] = np.nan
    out = points.copy()
    out["xc_mm"], out["yc_mm"], out["zc_mm"] = (r + e_um * kin.UM).T
    out["ex_um"], out["ey_um"], out["ez_um"] = e_um.T
    out["u_x_um"], out["u_y_um"], out["u_z_um"] = u.T
    out["extrapolated"] = extrapolation_note(m, x)
    for f in fixes:
        for col, v in f.columns.items():
            out[col] = v
    return out

"""Task-specific uncertainty of a measurement made with the fitted machine (ISO/TS 15530-4).

A task is a set of probed points (reported tip centres, machine frame, with their
styli) and a feature evaluated from them: the ``distance`` between two points, a
``circle`` (diameter and centre, least-squares circle in the least-squares plane) or a
``plane`` (least-squares flatness: the range of the distances to the least-squares
plane, which is at least the minimum-zone flatness). The points are corrected with the
fitted kinematic model (``compensate``: true point = ``r + e(r − p, p)``) and the result
is reported at 20 °C.

Its uncertainty is evaluated by Monte Carlo (JCGM 101, propagation of distributions;
ISO/TS 15530-4 simulation): each trial draws

- the kinematic coefficients from N(estimate, covariance) of the saved model (the
  correction's uncertainty, correlated over the points: the error map's shape);
- the probing noise of every point, N(0, σ²) per coordinate;
- optionally a discrepancy field the kinematic model does not describe, a Gaussian
  process with squared-exponential covariance ``sd² exp(−d²/2ℓ²)`` per component (the
  GP page's fitted amplitude and length scale);
- the workpiece temperature and expansion coefficient, and an unmodelled scale error of
  the machine (the reference's length uncertainty), as a scaling about the points'
  centroid,

and evaluates the feature. The law of propagation of uncertainty (JCGM 100 eq. 10, with
the points' joint covariance and a central-difference gradient of the feature) is given
beside it, with each influence's share; for a linear task the two agree (the check).

Each point's true position is thus N(measured, σ²) (JCGM 101 §6.4.7: the measured value
is its best estimate). For a nonlinear feature the distribution of the result is then not
centred on the value: the flatness, a range, is raised by noise twice, once in the value
(the range of noisy points exceeds the surface's) and once more in the trials, so their
mean (``mc_mean``) lies above the value by about that excess and the interval is that of
the flatness of point sets scattered about the measured ones (as a repeat measurement of
a surface shaped like the measured points would give). It is not a coverage interval for
the surface's flatness when the form is within a few σ (``_FLATNESS_NOTE``; the four-point
plane, whose flatness is 2|w| with a twist w known as N(ŵ, σ²/4), has a closed form:
``tests/test_task.py``). Points outside the machine's range are refused (``compensate``'s
test), and so are the two points of a distance closer than :data:`MIN_LENGTH_MM`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._blas import single_blas_thread
from ..export import OFF_MACHINE, Model, extrapolation_note
from ..gum import coverage_intervals
from ..io import DataError, read_json, refuse_unknown_keys
from ..io.errors import cut_repr
from ..machine import kinematics as kin
from ..units import UM

TASKS = ("distance", "circle", "plane")
TASK_KEYS = ("task", "points", "probing_sigma_um", "temperature", "scale_u_ppm",
             "discrepancy", "include_model", "trials", "seed", "coverage_probability")
MIN_LENGTH_MM = 1e-3
"""Shortest distance task (mm): two points closer than 1 µm are one point probed twice;
their length has no direction, and its gradient (the law of propagation's) is zero."""
_FLATNESS_NOTE = (
    "Flatness is the range of the corrected points, probing noise included (a range of "
    "noisy points exceeds the surface's); the Monte Carlo draws each point about its "
    "measured position (JCGM 101), which adds that excess again: its mean (mc_mean) lies "
    "above the value by about the excess, and its interval is that of the flatness of "
    "points scattered like these about the measured ones, as a repeat measurement would "
    "give, not a coverage interval for the surface's flatness when the form is within a "
    "few σ.")


@dataclass(frozen=True)
class Task:
    """A measurement task (``TASK.json``, docs/planning.md).

    Attributes
    ----------
    kind : str
        ``distance``, ``circle`` or ``plane``.
    points_mm : ndarray (n, 3)
        Reported tip centres, machine frame, mm.
    probes : list of str
        Stylus of each point.
    sigma_um : float or None
        Probing repeatability (µm); None: the model's σ.
    temp_C, u_temp_C, cte_per_K, u_cte_per_K : float
        Workpiece temperature and its standard uncertainty (°C), expansion coefficient
        and its standard uncertainty (1/K).
    scale_u_ppm : float
        Standard uncertainty of an unmodelled scale error of the machine, µm/m.
    discrepancy_sd_um, discrepancy_length_mm : float
        Discrepancy GP amplitude (µm; 0: none) and length scale (mm).
    include_model : bool
        Propagate the model's covariance (False: only the other influences).
    trials, seed : int
    coverage_probability : float
    name : str
    """

    kind: str
    points_mm: np.ndarray
    probes: list
    sigma_um: float | None = None
    temp_C: float = 20.0
    u_temp_C: float = 0.0
    cte_per_K: float = 11.5e-6
    u_cte_per_K: float = 0.0
    scale_u_ppm: float = 0.0
    discrepancy_sd_um: float = 0.0
    discrepancy_length_mm: float = 200.0
    include_model: bool = True
    trials: int = 20000
    seed: int = 1
    coverage_probability: float = 0.95
    name: str = "task"


def _num(name, column, value, lo, hi, integer=False):
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(
        value) and lo <= value <= hi and (not integer or float(value).is_integer())
    if not ok:
        raise DataError(f"expected {'a whole number' if integer else 'a number'} from "
                        f"{lo:g} to {hi:g}, found {cut_repr(value)}.", file=name, column=column)
    return int(value) if integer else float(value)


def read_task(source: str | Path | bytes | dict, *, name: str | None = None) -> Task:
    """Read and check a task file (path, JSON text, bytes or a parsed dict); refusals
    name the file and the key (``points[2].probe``)."""
    if isinstance(source, dict):
        raw, name = source, name or "task"
    else:
        raw, name = read_json(source, name)
    if not isinstance(raw, dict):
        raise DataError(f"expected a JSON object with {list(TASK_KEYS)}, found "
                        f"{type(raw).__name__}.", file=name)
    refuse_unknown_keys(raw, TASK_KEYS, name)
    kind = raw.get("task")
    if kind not in TASKS:
        raise DataError(f"expected one of {list(TASKS)}, found {cut_repr(kind)}.", file=name,
                        column="task")
    pts = raw.get("points")
    need = {"distance": 2, "circle": 3, "plane": 3}[kind]
    if not isinstance(pts, list) or len(pts) < need or (kind == "distance" and len(pts) != 2):
        raise DataError(f"a {kind} needs {'exactly 2' if kind == 'distance' else f'at least {need}'} "
                        f"points, found {cut_repr(pts)}.", file=name, column="points")
    rows: list[list[float]] = []
    probes: list[str | None] = []
    for i, p in enumerate(pts):
        col = f"points[{i}]"
        if not isinstance(p, dict) or not {"x_mm", "y_mm", "z_mm"} <= set(p):
            raise DataError(f"expected {{\"x_mm\", \"y_mm\", \"z_mm\", \"probe\"}}, found "
                            f"{cut_repr(p)}.", file=name, column=col)
        rows.append([_num(name, f"{col}.{c}", p[c], -1e5, 1e5) for c in ("x_mm", "y_mm",
                                                                         "z_mm")])
        probes.append(None if p.get("probe") is None else str(p["probe"]))
    xyz = np.array(rows)
    if kind == "distance" and np.linalg.norm(xyz[1] - xyz[0]) < MIN_LENGTH_MM:
        raise DataError(f"points[0] and points[1] are {np.linalg.norm(xyz[1] - xyz[0]):.2g} "
                        f"mm apart; a distance needs two distinct points (at least "
                        f"{MIN_LENGTH_MM:g} mm apart).", file=name, column="points[1]",
                        hint="probe the two ends of the length.")
    if kind != "distance" and np.linalg.matrix_rank(xyz - xyz.mean(0), tol=1e-6) < 2:
        raise DataError("the points lie on one line; a circle or plane needs points "
                        "spanning a plane.", file=name, column="points")
    t = raw.get("temperature", {})
    if not isinstance(t, dict) or set(t) - {"temp_C", "u_temp_C", "cte_per_K", "u_cte_per_K"}:
        raise DataError("expected an object with temp_C, u_temp_C (°C), cte_per_K, "
                        f"u_cte_per_K (1/K), found {cut_repr(t)}.", file=name,
                        column="temperature")
    d = raw.get("discrepancy", {})
    if not isinstance(d, dict) or set(d) - {"sd_um", "length_mm"}:
        raise DataError(f"expected an object with sd_um (µm) and length_mm (mm), found "
                        f"{cut_repr(d)}.", file=name, column="discrepancy")
    sigma = raw.get("probing_sigma_um")
    inc = raw.get("include_model", True)
    if not isinstance(inc, bool):
        raise DataError(f"expected true or false, found {cut_repr(inc)}.", file=name,
                        column="include_model")
    task = Task(kind, xyz, probes,
                None if sigma is None else _num(name, "probing_sigma_um", sigma, 0, 1000),
                _num(name, "temperature.temp_C", t.get("temp_C", 20.0), 0, 50),
                _num(name, "temperature.u_temp_C", t.get("u_temp_C", 0.0), 0, 10),
                _num(name, "temperature.cte_per_K", t.get("cte_per_K", 11.5e-6), -1e-6, 3e-5),
                _num(name, "temperature.u_cte_per_K", t.get("u_cte_per_K", 0.0), 0, 1e-5),
                _num(name, "scale_u_ppm", raw.get("scale_u_ppm", 0.0), 0, 1000),
                _num(name, "discrepancy.sd_um", d.get("sd_um", 0.0), 0, 1000),
                _num(name, "discrepancy.length_mm", d.get("length_mm", 200.0), 1, 1e5),
                inc, _num(name, "trials", raw.get("trials", 20000), 100, 10**7, True),
                _num(name, "seed", raw.get("seed", 1), 0, 2**32 - 1, True),
                _num(name, "coverage_probability", raw.get("coverage_probability", 0.95),
                     0.5, 0.999), name)
    if not inc and not any((task.sigma_um is None, task.sigma_um,
                            task.u_temp_C, task.u_cte_per_K, task.scale_u_ppm,
                            task.discrepancy_sd_um)):
        raise DataError("include_model is false and every other influence is zero, so "
                        "U = 0; expected at least one uncertainty above zero.", file=name,
                        column="include_model",
                        hint="keep include_model true, or state the probing noise.")
    return task


def feature(kind: str, P: np.ndarray) -> np.ndarray:
    """Feature values of point sets ``P`` (T, n, 3) mm: distance (mm); circle
    (diameter, centre x, y, z, mm); plane (flatness, µm). Returns (T, k)."""
    P = np.asarray(P, float)
    if kind == "distance":
        return np.linalg.norm(P[:, 1] - P[:, 0], axis=1)[:, None]
    c = P.mean(1, keepdims=True)
    _, _, Vt = np.linalg.svd(P - c, full_matrices=False)
    if kind == "plane":
        h = np.einsum("tnk,tk->tn", P - c, Vt[:, 2])
        return (np.ptp(h, axis=1) * 1e3)[:, None]
    # circle: in-plane coordinates, algebraic (Kasa) start, Gauss-Newton on the
    # geometric residuals |q - m| - R (the least-squares circle)
    q = np.stack([np.einsum("tnk,tk->tn", P - c, Vt[:, j]) for j in (0, 1)], axis=2)
    A = np.concatenate([2 * q, np.ones(q.shape[:2] + (1,))], axis=2)
    b = (q ** 2).sum(2)
    sol = np.linalg.solve(np.einsum("tni,tnj->tij", A, A),
                          np.einsum("tni,tn->ti", A, b)[..., None])[..., 0]
    m = sol[:, :2]
    R = np.sqrt(sol[:, 2] + (m ** 2).sum(1))
    for _ in range(5):
        d = q - m[:, None, :]
        rho = np.linalg.norm(d, axis=2)
        r = rho - R[:, None]
        J = np.concatenate([-d / rho[..., None], -np.ones(r.shape + (1,))], axis=2)
        step = np.linalg.solve(np.einsum("tni,tnj->tij", J, J),
                               -np.einsum("tni,tn->ti", J, r)[..., None])[..., 0]
        m, R = m + step[:, :2], R + step[:, 2]
    centre = c[:, 0] + m[:, :1] * Vt[:, 0] + m[:, 1:] * Vt[:, 1]
    return np.column_stack([2 * R, centre])


def _names(kind):
    return {"distance": [("length_mm", "mm")], "plane": [("flatness_um", "um")],
            "circle": [("diameter_mm", "mm"), ("centre_x_mm", "mm"), ("centre_y_mm", "mm"),
                       ("centre_z_mm", "mm")]}[kind]


@dataclass(frozen=True)
class TaskResult:
    """A task's result with its uncertainty.

    Attributes
    ----------
    kind : str
    values : dict
        Quantity -> ``{"value", "unit", "mc_mean", "u_mc_um", "u_lpu_um", "interval",
        "contributions_um"}``: the estimate (from the corrected points, at 20 °C), the
        mean of the Monte Carlo results (the quantity's unit; above the value for a
        flatness, module docstring), their standard deviation (µm), the law of
        propagation's standard uncertainty (µm), the shortest coverage interval of the
        Monte Carlo results (in the quantity's unit) and each influence's standard
        uncertainty by the law of propagation (µm).
    trials : int
    coverage_probability : float
    sigma_um : float
        Probing repeatability used.
    message : str
    """

    kind: str
    values: dict
    trials: int
    coverage_probability: float
    sigma_um: float
    message: str

    def to_dict(self) -> dict:
        """JSON-ready record (``task``'s output)."""
        return {"task": self.kind, "results": self.values, "trials": self.trials,
                "coverage_probability": self.coverage_probability,
                "probing_sigma_um": self.sigma_um, "message": self.message}


def _probe_offsets(model, task):
    names = list(model.probes_mm)
    out = []
    for i, q in enumerate(task.probes):
        if q is None and len(names) == 1:
            q = names[0]
        if q not in model.probes_mm:
            raise DataError(f"stylus {cut_repr(q)} is not in the model (known: "
                            f"{', '.join(names)}).", file=task.name, column=f"points[{i}].probe")
        out.append(model.probes_mm[q])
    return np.array(out)


def _check_on_machine(model, task, x):
    """Refuse points off the machine (compensate's test: beyond the strokes by more than
    a stylus length), where the model is not defined; the indices of points outside the
    region the fit measured (their correction extrapolates)."""
    note = extrapolation_note(model, x)
    off = np.flatnonzero(note == OFF_MACHINE)
    if off.size:
        i = int(off[0])
        raise DataError(f"points[{i}] at {np.round(task.points_mm[i], 1).tolist()} mm lies "
                        f"outside the machine's range {list(model.terms.range_mm)} mm, where "
                        "the model is not defined; expected points in mm, machine frame.",
                        file=task.name, column=f"points[{i}]",
                        hint="check the units and the frame of the points.")
    return np.flatnonzero(note != "")


def _influences(model, task, x, p, sigma):
    """Covariance (3n × 3n, mm²) of the corrected points per influence, and the
    sensitivity of the points to a relative scale δ (3n,)."""
    n = len(x)
    _, Jk = kin.jacobian(model.terms, model.coef, x, p)
    Je = Jk.reshape(3 * n, -1)  # mm per coefficient unit
    out = {"model": Je @ model.cov @ Je.T if task.include_model else np.zeros((3 * n,) * 2),
           "probing": np.eye(3 * n) * (sigma * 1e-3) ** 2}
    r = x + p
    if task.discrepancy_sd_um > 0:
        d2 = ((r[:, None, :] - r[None, :, :]) ** 2).sum(2)
        K = (task.discrepancy_sd_um * 1e-3) ** 2 * np.exp(-d2 / (2 * task.discrepancy_length_mm ** 2))
        out["discrepancy"] = np.kron(K, np.eye(3))
    g = (r - r.mean(0)).ravel()
    u_rel_T = math.hypot(task.cte_per_K * task.u_temp_C, (task.temp_C - 20) * task.u_cte_per_K)
    out["temperature"] = np.outer(g, g) * u_rel_T ** 2
    out["scale"] = np.outer(g, g) * (task.scale_u_ppm * 1e-6) ** 2
    return out


@single_blas_thread
def task_uncertainty(model: Model, task: Task, *, trials: int | None = None,
                     progress: Callable[[float, str], None] | None = None,
                     chunk: int = 5000) -> TaskResult:
    """Task-specific uncertainty (module docstring).

    Parameters
    ----------
    model : export.Model
        A saved model (``fit --save``; ``export.load_model``).
    task : Task
    trials : int, optional
        Monte Carlo trials (default: the task's).
    progress : callable, optional
        ``progress(fraction, text)`` after each chunk of trials.
    """
    if model.undetermined and task.include_model:
        raise ValueError(f"{model.name}: the model leaves some parameter combination "
                         "undetermined, so the correction's uncertainty is unbounded; fit a "
                         "model the data determine.")
    M = int(trials or task.trials)
    sigma = task.sigma_um if task.sigma_um is not None else float(
        model.summary.get("sigma_um", 0.5))
    p = _probe_offsets(model, task)
    x = task.points_mm - p
    n = len(x)
    outside = _check_on_machine(model, task, x)
    e = kin.error(model.terms, model.coef, x, p) * UM  # µm -> mm
    alpha, dT = task.cte_per_K, task.temp_C - 20.0
    corr = task.points_mm + e
    c0 = corr.mean(0)
    est_pts = c0 + (corr - c0) / (1 + alpha * dT)  # at 20 °C
    est = feature(task.kind, est_pts[None])[0]
    # law of propagation: central-difference gradient of the feature wrt the points
    h = 1e-4
    grad = np.empty((len(est), 3 * n))
    flat = est_pts.ravel()
    steps = np.vstack([flat + h * np.eye(3 * n)[i] for i in range(3 * n)]
                      + [flat - h * np.eye(3 * n)[i] for i in range(3 * n)])
    f = feature(task.kind, steps.reshape(-1, n, 3))
    grad = ((f[:3 * n] - f[3 * n:]) / (2 * h)).T
    infl = _influences(model, task, x, p, sigma)
    unit_um = np.array([1e3 if u == "mm" else 1.0 for _, u in _names(task.kind)])
    contrib = {k: np.sqrt(np.clip(np.einsum("ki,ij,kj->k", grad, V, grad), 0, None))
               * unit_um for k, V in infl.items()}
    u_lpu = np.sqrt(sum(c ** 2 for c in contrib.values()))
    # Monte Carlo
    rng = np.random.default_rng(task.seed)
    w, Q = np.linalg.eigh((model.cov + model.cov.T) / 2)
    L = Q * np.sqrt(np.clip(w, 0, None))
    Kd = infl.get("discrepancy")
    Ld = None
    if Kd is not None:
        wd, Qd = np.linalg.eigh(Kd)
        Ld = Qd * np.sqrt(np.clip(wd, 0, None))
    ys, done = [], 0
    while done < M:
        t = min(chunk, M - done)
        pts = np.broadcast_to(task.points_mm, (t, n, 3)).copy()
        if task.include_model:
            draws = model.coef + rng.standard_normal((t, len(model.coef))) @ L.T
            xs = np.tile(x, (t, 1))
            pts += kin.error(model.terms, np.repeat(draws, n, axis=0), xs,
                             np.tile(p, (t, 1))).reshape(t, n, 3) * UM
        else:
            pts += e
        pts += rng.normal(0.0, sigma * 1e-3, pts.shape)
        if Ld is not None:
            pts += (rng.standard_normal((t, 3 * n)) @ Ld.T).reshape(t, n, 3)
        a_t = alpha + task.u_cte_per_K * rng.standard_normal(t)
        dT_t = dT + task.u_temp_C * rng.standard_normal(t)
        s_t = 1 + task.scale_u_ppm * 1e-6 * rng.standard_normal(t)
        # the true part at 20 °C: what was measured, less the expansion at the true
        # temperature and coefficient, and the machine's unmodelled scale
        cen = pts.mean(1, keepdims=True)
        pts = cen + (pts - cen) / ((1 + a_t * dT_t) * s_t)[:, None, None]
        ys.append(feature(task.kind, pts))
        done += t
        if progress is not None:
            progress(done / M, f"Monte Carlo: {done}/{M} trials")
    Y = np.vstack(ys)
    values = {}
    for j, (qname, unit) in enumerate(_names(task.kind)):
        col = np.sort(Y[:, j])
        _, short = coverage_intervals(col, task.coverage_probability)
        values[qname] = {"value": float(est[j]), "unit": unit,
                         "mc_mean": float(np.mean(Y[:, j])),
                         "u_mc_um": float(np.std(Y[:, j], ddof=1) * unit_um[j]),
                         "u_lpu_um": float(u_lpu[j]), "interval": list(short),
                         "contributions_um": {k: float(v[j]) for k, v in contrib.items()
                                              if v[j] > 0}}
    msg = (f"{task.kind} from {n} points, corrected with the model {model.spec!r} and "
           f"reported at 20 °C; {M} Monte Carlo trials (JCGM 101) beside the law of "
           f"propagation (JCGM 100); probing σ = {sigma:g} µm.")
    if outside.size:
        msg += (f" Points {', '.join(f'points[{i}]' for i in outside)} lie outside the "
                "region the fit measured: their correction extrapolates the model.")
    parts = list(getattr(model, "parts", {}))
    if parts:
        # a task point has no measurement order or scale temperatures to apply them with
        msg += (f" The model's {' and '.join(parts)} corrections are not applied to task "
                "points (compensate applies them from the points' order and scale "
                "temperatures); neither they nor their uncertainty are in these results.")
    if task.kind == "plane":
        msg += " " + _FLATNESS_NOTE
    if model.summary.get("fails_chi2_test"):
        # the model's noise part is σ-based: under misfit its share is too small
        msg += (f" The model failed its χ² test (scatter {model.summary['birge_ratio']:.2f} "
                "times what σ allows): its share of these uncertainties is too small by up "
                "to that factor; diagnose and refit before relying on them.")
    return TaskResult(task.kind, values, M, task.coverage_probability, sigma, msg)

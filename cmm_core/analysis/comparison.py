"""Thesis chapter 7 done honestly: the kinematic model, the Gaussian process and the
measurement side by side at the measured balls, and the surfaces of one placement's plane.

The thesis compares the models by a "percentage error" (eq. 7.1), a micrometre difference
divided by the ball's coordinate in metres, so any model scores a few thousandths of a
percent. Here each difference is divided by its own standard uncertainty: the kinematic
model's difference at a ball it was fitted to is the fit's residual, whose sd is
σ√(1 − h_ii) (:func:`cmm_core.model.residual_u`); the GP's is taken leave-one-out (each
ball predicted from all the others, Rasmussen & Williams eq. 5.12), noise included. Eq. 7.1
is kept as a column only for comparison with the thesis. The app's GP page, and anything
else that shows this comparison, reads :class:`ModelComparison` rather than recomputing it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from ..model import error_at
from ..units import UM

__all__ = ["ComparisonFigure", "ModelComparison", "PlaneGrid", "compare_models",
           "coverage_reasons", "placement_plane_grid", "plate_coordinates_mm"]

_COORD_FLOOR_MM = 1.0
"""Eq. 7.1 divides by the ball's plate coordinate: below 1 mm the ratio means nothing and
is left blank rather than shown as a huge percentage."""


@dataclass(frozen=True)
class ComparisonFigure:
    """One summary figure of the comparison (a card on the GP page)."""

    label: str
    """Short label with its unit, e.g. ``"kin. RMS Δ (µm)"``."""
    value: float
    """The figure (µm for a difference, dimensionless for a z)."""
    meaning: str
    """What it is, in one sentence (the card's help text)."""


@dataclass(frozen=True)
class ModelComparison:
    """Kinematic model vs GP vs measurement at every measured ball, one error component."""

    component: str
    """Error component compared: ``"x"``, ``"y"`` or ``"z"``."""
    sigma_um: float
    """Measurement σ (µm) the kinematic z-scores are based on."""
    table: pd.DataFrame
    """One row per observation: ``position``, ``probe``, ``ball``, ``measured_um``,
    ``kinematic_um``, ``kin_minus_meas_um``, ``kin_z`` (over σ√(1 − h_ii)),
    ``thesis_pct_kin`` (eq. 7.1) and, with a GP, ``gp_um``, ``gp_minus_meas_um``,
    ``gp_loo_minus_meas_um``, ``gp_loo_z`` (leave-one-out, noise included) and
    ``thesis_pct_gp``."""
    summary: tuple[ComparisonFigure, ...]
    """RMS figures over every ball: the kinematic difference and z, and with a GP its
    in-sample and leave-one-out differences and leave-one-out z."""
    has_gp: bool
    """Whether the GP columns are present."""

    def summary_dict(self) -> dict[str, float]:
        """``{label: value}`` of the summary figures."""
        return {f.label: f.value for f in self.summary}


@dataclass(frozen=True)
class PlaneGrid:
    """A grid over the plate plane of one placement, with the kinematic error on it."""

    position: str
    """The placement whose plane is drawn."""
    probe: str
    """The stylus of that placement (the surfaces are for its offset)."""
    probe_mm: np.ndarray
    """Its offset (mm, machine axes)."""
    u_mm: np.ndarray
    """Grid axis along the plate's u (mm, plate frame), ``n`` values."""
    v_mm: np.ndarray
    """Grid axis along the plate's v (mm, plate frame), ``n`` values."""
    machine_mm: np.ndarray
    """The ``n × n`` grid points as tip positions in machine coordinates (mm), v-major."""
    kinematic_um: np.ndarray
    """Kinematic error at the grid points (µm, (n², 3)), aligned like the measured errors
    (the mean difference at the placement's balls, which its rigid placement absorbs,
    added back)."""
    kinematic_sd_um: np.ndarray
    """Standard uncertainty of ``kinematic_um`` (µm, (n², 3))."""
    selected: np.ndarray
    """Boolean mask of the observations that belong to this placement."""
    balls_plate_mm: np.ndarray
    """The placement's measured balls in the plate frame (mm, (m, 3))."""


def plate_coordinates_mm(result: Any, points_mm: ArrayLike) -> np.ndarray:
    """Points of every observation (mm, machine axes) in their own placement's plate
    frame, ``Rₖᵀ (x − tₖ)`` with the fitted placement k of each row.

    ``result`` is a :class:`~cmm_core.model.FitResult`."""
    obs, st = result.problem.obs, result.state
    return np.einsum("nji,nj->ni", st.R[obs.pos], np.asarray(points_mm, float) - st.t[obs.pos])


def _rms(values: ArrayLike) -> float:
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")


def _thesis_pct(diff_um: np.ndarray, coord_mm: np.ndarray) -> np.ndarray:
    """Thesis eq. 7.1: |model − measurement| / measurement × 100 %, the measurement
    being the ball's plate coordinate."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(coord_mm > _COORD_FLOOR_MM, np.abs(diff_um) * UM / coord_mm * 100,
                        np.nan)


def compare_models(result: Any, measured_um: ArrayLike, kinematic_um: ArrayLike,
                   residual_u_um: ArrayLike, component: str, *, points_mm: ArrayLike,
                   meta: pd.DataFrame, gp_mean_um: ArrayLike | None = None,
                   gp_loo_mean_um: ArrayLike | None = None,
                   gp_loo_sd_um: ArrayLike | None = None) -> ModelComparison:
    """The chapter-7 comparison at the measured balls for one error component.

    Parameters
    ----------
    result : FitResult
        The kinematic fit (its placements give the plate coordinates of eq. 7.1, its σ the
        z-scores' scale).
    measured_um, kinematic_um : array (n, 3)
        Measured error (minus the residual of a rigid-only fit) and the kinematic model's
        rigid-aligned prediction at every observation (µm).
    residual_u_um : array (n, 3)
        Standard uncertainty of kinematic minus measured, σ√(1 − h_ii)
        (:func:`cmm_core.model.residual_u`).
    component : {"x", "y", "z"}
    points_mm : array (n, 3)
        Tip positions of the observations (mm, machine axes).
    meta : DataFrame
        ``position``, ``probe``, ``ball`` of every observation, in the same order.
    gp_mean_um, gp_loo_mean_um, gp_loo_sd_um : array (n, 3), optional
        The GP's posterior mean at the observations and its leave-one-out mean and sd
        (R&W eq. 5.12), already on the measured-error scale.

    Returns
    -------
    ModelComparison
    """
    if component not in ("x", "y", "z"):
        raise ValueError(f"component: expected 'x', 'y' or 'z', found {component!r}.")
    a = "xyz".index(component)
    meas = np.asarray(measured_um, float)[:, a]
    kin = np.asarray(kinematic_um, float)[:, a]
    u_res = np.asarray(residual_u_um, float)[:, a]
    coord = np.abs(plate_coordinates_mm(result, points_mm)[:, a])
    rows = pd.DataFrame({c: meta[c].to_numpy() for c in ("position", "probe", "ball")})
    rows["measured_um"] = meas
    rows["kinematic_um"] = kin
    rows["kin_minus_meas_um"] = kin - meas
    with np.errstate(divide="ignore", invalid="ignore"):
        rows["kin_z"] = (kin - meas) / np.where(u_res > 0, u_res, np.nan)
    rows["thesis_pct_kin"] = _thesis_pct(kin - meas, coord)
    summary = [
        ComparisonFigure("kin. RMS Δ (µm)", _rms(rows["kin_minus_meas_um"]),
                         "kinematic model − measured, RMS over every ball"),
        ComparisonFigure("kin. RMS z", _rms(rows["kin_z"]),
                         "RMS of (kinematic − measured) / σ√(1 − h_ii), the residual's sd")]
    has_gp = gp_mean_um is not None
    if has_gp:
        gp = np.asarray(gp_mean_um, float)[:, a]
        loo = np.asarray(gp_loo_mean_um, float)[:, a]
        loo_sd = np.asarray(gp_loo_sd_um, float)[:, a]
        rows["gp_um"] = gp
        rows["gp_minus_meas_um"] = gp - meas
        rows["gp_loo_minus_meas_um"] = loo - meas
        with np.errstate(divide="ignore", invalid="ignore"):
            rows["gp_loo_z"] = (loo - meas) / loo_sd
        rows["thesis_pct_gp"] = _thesis_pct(gp - meas, coord)
        summary += [
            ComparisonFigure("GP RMS Δ (µm)", _rms(rows["gp_minus_meas_um"]),
                             "GP posterior mean − measured, RMS over every ball"),
            ComparisonFigure("GP LOO RMS Δ (µm)", _rms(rows["gp_loo_minus_meas_um"]),
                             "each ball predicted by the GP from all the others, RMS"),
            ComparisonFigure("GP LOO RMS z", _rms(rows["gp_loo_z"]),
                             "RMS of the leave-one-out difference / its sd (noise "
                             "included)")]
    return ModelComparison(component=component, sigma_um=float(result.sigma_um), table=rows,
                           summary=tuple(summary), has_gp=has_gp)


def placement_plane_grid(result: Any, position: str, kinematic_um: ArrayLike,
                         n: int = 21) -> PlaneGrid:
    """An ``n × n`` grid over the plate plane of ``position`` with the kinematic error on it.

    The kinematic error at the grid (:func:`cmm_core.model.error_at`, for the placement's
    stylus) is shifted by the mean of ``kinematic_um − error_at`` over the placement's
    balls: the rigid placement absorbs a constant, and the surfaces are compared with the
    rigid-aligned measured errors.

    Parameters
    ----------
    result : FitResult
    position : str
        One of the fit's placements.
    kinematic_um : array (n_obs, 3)
        The model's rigid-aligned prediction at every observation (µm).
    n : int
        Grid points per side.
    """
    obs, st = result.problem.obs, result.state
    if position not in obs.positions:
        raise ValueError(f"position: expected one of {list(obs.positions)}, found "
                         f"{position!r}.")
    k = obs.positions.index(position)
    R, t, plate = st.R[k], st.t[k], st.c
    u = np.linspace(plate[:, 0].min(), plate[:, 0].max(), n)
    v = np.linspace(plate[:, 1].min(), plate[:, 1].max(), n)
    U, V = np.meshgrid(u, v)
    grid = np.column_stack([U.ravel(), V.ravel(), np.zeros(U.size)]) @ R.T + t
    sel = np.asarray(obs.pos) == k
    probe = str(obs.probes[int(obs.probe[sel][0])])
    pk = obs.p_mm[sel][0]
    e_grid, u_grid = error_at(result, grid - pk, probe)
    e_obs, _ = error_at(result, obs.r_mm[sel] - pk, probe)
    offset = np.mean(np.asarray(kinematic_um, float)[sel] - e_obs, axis=0)
    return PlaneGrid(position=position, probe=probe, probe_mm=pk, u_mm=u, v_mm=v,
                     machine_mm=grid, kinematic_um=e_grid + offset, kinematic_sd_um=u_grid,
                     selected=sel, balls_plate_mm=(obs.r_mm[sel] - t) @ R)


def coverage_reasons(coverage_pct: float, z_loo: ArrayLike, meta: pd.DataFrame,
                     noise_by_probe: ArrayLike | None = None, probe_names: Sequence[str] = (),
                     several_probes: bool = False, degenerate: bool = False) -> list[str]:
    """Why a GP's leave-one-out 95 % coverage is off 95 %, in sentences driven by the
    numbers: the standardised leave-one-out errors ``z_loo`` (one per point, rows of
    ``meta``: position, probe, ball), the noise level per stylus and the point count.

    Checks, each reported only when it applies: the count alone (one point is 100/n %);
    points far outside their interval (|z| > 4: blunders or local errors); a misfit that is
    not stationary (the RMS z of the worst placement against the best: one signal and
    noise level do not fit every placement); noise levels that differ between styli (or
    one level shared by several); an RMS z far from 1 (intervals too narrow or too wide
    overall); a degenerate optimum.
    """
    z = np.asarray(z_loo, float)
    ok = np.isfinite(z)
    n = int(ok.sum())
    out = []
    if n == 0:
        return ["no finite leave-one-out prediction to judge it by."]
    z, m = z[ok], meta.reset_index(drop=True)[ok]
    one = 100.0 / n
    rms = float(np.sqrt(np.mean(z**2)))
    low = coverage_pct < 95
    miss = abs(coverage_pct - 95) - 2
    if miss <= one:
        out.append(f"it is {miss:.1f} % outside the band with one point worth {one:.1f} % "
                   f"({n} points): a single point decides it, chance alone can explain it.")
    big = np.flatnonzero(np.abs(z) > 4)
    if big.size:
        w = big[np.argmax(np.abs(z[big]))]
        out.append(f"{big.size} point(s) lie more than 4 leave-one-out sd from their "
                   f"prediction (worst |z| = {abs(z[w]):.1f} at {m['position'].iloc[w]} probe "
                   f"{m['probe'].iloc[w]} ball {m['ball'].iloc[w]}): blunders or a local "
                   "error the GP cannot follow (see the outliers on the Data page).")
    by = pd.Series(z**2).groupby(m["position"].to_numpy()).mean() ** 0.5
    if len(by) > 1 and by.max() > 2 * max(by.min(), 1e-9) and by.max() > 1.3:
        out.append(f"the misfit is not stationary: the RMS z of the leave-one-out errors is "
                   f"{by.max():.2f} at {by.idxmax()} but {by.min():.2f} at {by.idxmin()}, "
                   "so one signal amplitude and noise level cannot fit every placement "
                   "(an error tied to a placement or stylus that the GP's inputs do not "
                   "carry).")
    if noise_by_probe is not None and len(np.atleast_1d(noise_by_probe)) > 1:
        nb = np.asarray(noise_by_probe, float)
        if nb.max() > 3 * max(nb.min(), 1e-3):
            names = list(probe_names) or [str(i) for i in range(len(nb))]
            out.append(f"the noise level differs between styli ({nb.min():.2f} µm for "
                       f"{names[int(nb.argmin())]} to {nb.max():.2f} µm for "
                       f"{names[int(nb.argmax())]}): with so few points per stylus the "
                       "levels are poorly determined.")
    elif several_probes:
        out.append("one noise level is shared by several styli (tick 'Probe offset as "
                   "input' to give each its own).")
    if low and rms > 1.2:
        out.append(f"the RMS z is {rms:.2f}: overall the GP's intervals are narrower than "
                   "the errors it makes on points it has not seen.")
    elif not low and rms < 0.8:
        out.append(f"the RMS z is {rms:.2f}: overall the intervals are wider than the "
                   "errors need (a noise level inflated by a few large points).")
    if degenerate:
        out.append("the optimum is degenerate (see the warning above).")
    if not out:
        out.append(f"no single cause stands out (RMS z {rms:.2f}, {n} points, one point = "
                   f"{one:.1f} %).")
    return out

"""Uncertainty of the fitted model and of the CMM error it predicts (thesis §4.5.3).

The parameter covariance comes from the fit (law of propagation of uncertainty,
``V = σ² (JᵀJ)⁺`` on the constrained, full-rank problem). The error ``e(x, p)`` at any
point is propagated through its analytic Jacobian. Thesis tables 4.1-4.3 define:

- U1: the average standard uncertainty of the ball-centre coordinates,
- U2: the average standard uncertainty of the CMM error at 200 random points in the
  evaluated region (the box spanned by the measurements),
- U3: the same over the whole working volume,

each per axis, after removing the six rigid-body freedoms from the covariance (the
thesis's ``xux2uzsp``): a rigid motion of the whole point set is not an error of the CMM,
because the frame of the workpiece is always re-established.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..machine import KinematicTerms
from ..machine import kinematics as kin
from ..units import UM
from .certificate_prior import residual_u_um
from .result import FitResult


def rigid_body_projector(points_mm: np.ndarray) -> np.ndarray:
    """Projector removing translations and small rotations of a point set (3m × 3m).

    ``P = I - G G⁺`` with G the 6 rigid-body motion fields at the points (rotations about
    the centroid); ``P V Pᵀ`` is the covariance the thesis's ``xux2uzsp`` returns.
    """
    Q = _rigid_basis(points_mm)
    return np.eye(Q.shape[0]) - Q @ Q.T


def _rigid_basis(points_mm: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3m × 6) of the rigid-body motion fields at the points."""
    c = np.asarray(points_mm, float) - np.mean(points_mm, 0)
    m = len(c)
    G = np.zeros((3 * m, 6))
    for a in range(3):
        G[a::3, a] = 1.0
    # rotation about axis a moves point c by e_a x c
    G[0::3, 3], G[1::3, 3], G[2::3, 3] = 0, -c[:, 2], c[:, 1]
    G[0::3, 4], G[1::3, 4], G[2::3, 4] = c[:, 2], 0, -c[:, 0]
    G[0::3, 5], G[1::3, 5], G[2::3, 5] = -c[:, 1], c[:, 0], 0
    Q, _ = np.linalg.qr(G)
    return Q


def _probe_vector(result: FitResult, probe):
    obs = result.problem.obs
    name = obs.probes[0] if probe is None else str(probe)
    if name not in obs.probes:
        raise ValueError(f"probe {name!r} was not in the fit (known: {', '.join(obs.probes)}).")
    i = obs.probes.index(name)
    p = obs.p_mm[obs.probe == i][0].copy()
    lab, val, _ = result.block("probe_offset")
    if len(lab):
        p = p + val.reshape(-1, 3)[i] * 1e-3
    return p


def covariance_factor(cov: np.ndarray) -> np.ndarray:
    """A factor ``L`` of a covariance, ``V = L Lᵀ`` (eigen-decomposition, so that a
    semi-definite V has one too): :func:`propagate_error` takes it to propagate many
    points without factoring V again."""
    w, Q = np.linalg.eigh((cov + cov.T) / 2)
    return Q * np.sqrt(np.clip(w, 0, None))


def propagate_error(terms: KinematicTerms, coef: np.ndarray, cov: np.ndarray | None,
                    x_mm: np.ndarray, p_mm: np.ndarray, extra_jac: np.ndarray | None = None,
                    *, factor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Error ``e(x, p)`` (µm, thesis eq. 4.13) and its standard uncertainty
    ``sqrt(diag(J V Jᵀ))`` per component (JCGM 100 eq. 13), J the analytic Jacobian of
    the error with respect to the coefficients, computed as the row norms of ``J L``
    (``V = L Lᵀ``, :func:`covariance_factor`; ``factor`` when the caller has it, else
    from ``cov``): one matrix product, where ``diag(J V Jᵀ)`` term by term costs k² per
    coordinate.

    ``extra_jac`` (m, 3, k) appends the sensitivities of further linear terms (the
    compensation parts of effect blocks: backlash spans, scale expansion coefficients)
    whose coefficients follow the kinematic ones in the covariance; their contribution to
    ``e`` is the caller's.
    """
    xs, J = kin.jacobian(terms, coef, x_mm, p_mm)
    e = (xs - x_mm - p_mm) / UM
    Je = J / UM
    if extra_jac is not None:
        Je = np.concatenate([Je, extra_jac], axis=2)
    L = covariance_factor(np.asarray(cov, float)) if factor is None else factor
    JL = Je.reshape(-1, Je.shape[2]) @ L
    u = np.sqrt(np.einsum("ij,ij->i", JL, JL)).reshape(-1, 3)
    return e, u


def error_at(result: FitResult, x_mm: ArrayLike, probe: str | None = None
         ) -> tuple[np.ndarray, np.ndarray]:
    """Kinematic error and its standard uncertainty at scale readings ``x_mm``.

    Parameters
    ----------
    result : FitResult
    x_mm : array (m, 3)
        Scale readings (ram reference point) in mm.
    probe : str, optional
        Probe whose offset the tip has (default the first probe of the fit).

    Returns
    -------
    e_um, u_um : arrays (m, 3)
        Error (true minus reported tip) and its standard uncertainty; u is NaN when the
        model has parameters the data cannot determine.
    """
    x = np.atleast_2d(np.asarray(x_mm, float))
    p = np.broadcast_to(_probe_vector(result, probe), x.shape)
    e, u = propagate_error(result.terms, result.kinematic_coef, result.kinematic_cov, x, p)
    if _undetermined(result, "kinematic") or _undetermined(result, "probe_offset"):
        u[:] = np.nan
    return e, u


def monte_carlo_error(result: FitResult, x_mm: ArrayLike, probe: str | None = None, *,
                  trials: int = 1000, seed: int = 1, chunk: int = 2000,
                  progress: Callable[[float, str], object] | None = None
                  ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Monte Carlo check of :func:`error_at` (JCGM 101 §7: propagation of distributions).

    Draws the kinematic coefficients from N(estimate, covariance), evaluates the error
    with the exact (nonlinear) model at every point for every draw, and returns the mean
    and standard deviation over the draws beside the linearised standard uncertainty.
    Vectorised over draws and points (``chunk`` draws at a time).

    Returns
    -------
    mean_um, u_mc_um, u_lin_um : arrays (m, 3)
        ``None``s when the model has undetermined parameters (nothing to sample).
    progress : callable, optional
        ``progress(fraction, text)`` after each chunk; an exception it raises (a changed
        input in the app) stops the run.
    """
    x = np.atleast_2d(np.asarray(x_mm, float))
    _, u_lin = error_at(result, x, probe)
    if np.isnan(u_lin).any():
        return None, None, None
    p = _probe_vector(result, probe)
    cov = result.kinematic_cov
    w, Q = np.linalg.eigh((cov + cov.T) / 2)
    L = Q * np.sqrt(np.clip(w, 0, None))
    coef0 = result.kinematic_coef
    rng = np.random.default_rng(seed)
    m = len(x)
    acc, acc2, done = np.zeros((m, 3)), np.zeros((m, 3)), 0
    while done < trials:
        t = min(chunk, trials - done)
        draws = coef0 + rng.standard_normal((t, len(coef0))) @ L.T
        xs = np.tile(x, (t, 1))
        e = kin.error(result.terms, np.repeat(draws, m, axis=0), xs,
                      np.broadcast_to(p, xs.shape)).reshape(t, m, 3)
        acc += e.sum(0)
        acc2 += (e ** 2).sum(0)
        done += t
        if progress is not None:
            progress(done / trials, f"Monte Carlo: {done}/{trials} trials")
    mean = acc / done
    return mean, np.sqrt(np.clip(acc2 / done - mean ** 2, 0, None)), u_lin


def _undetermined(result: FitResult, block: str) -> bool:
    bad = set(result.unidentifiable)
    return any(g == block and lab in bad
               for g, lab in zip(result.groups, result.labels, strict=True))


def error_covariance(result: FitResult, x_mm: ArrayLike, probe: str | None = None,
                 kinematic_cov: np.ndarray | None = None) -> np.ndarray:
    """Full covariance (3m × 3m, µm²) of the error at the points, for maps and U2/U3
    (``kinematic_cov``: another covariance of the kinematic coefficients, e.g. the noise
    part alone)."""
    x = np.atleast_2d(np.asarray(x_mm, float))
    p = np.broadcast_to(_probe_vector(result, probe), x.shape)
    Je = _error_jacobian(result, x, p)
    cov = result.kinematic_cov if kinematic_cov is None else kinematic_cov
    return Je @ cov @ Je.T


def _error_jacobian(result: FitResult, x, p) -> np.ndarray:
    """(3m, k) derivative of the error (µm) at the points wrt the kinematic coefficients."""
    _, J = kin.jacobian(result.terms, result.kinematic_coef, x, p)
    return (J / UM).reshape(-1, J.shape[2])


def aligned_error_u(result: FitResult) -> np.ndarray:
    """Standard uncertainty (µm, (n, 3)) of the kinematic error at each observation with
    each position's rigid-body part removed: the uncertainty of the error as the plate
    sees it after its placement is fitted (as U1-U3 remove it), the one to compare a
    rigid-aligned measured error with. NaN when the model is undetermined."""
    obs = result.problem.obs
    u = np.full(obs.r_mm.shape, np.nan)
    if _undetermined(result, "kinematic") or _undetermined(result, "probe_offset"):
        return u
    for k in range(len(obs.positions)):
        idx = np.flatnonzero(obs.pos == k)
        u[idx] = _rigid_removed_u(result, obs.r_mm[idx] - obs.p_mm[idx], obs.p_mm[idx],
                                  obs.r_mm[idx])
    return u


def residual_u(result: FitResult, *, chunk: int = 30000) -> np.ndarray:
    """Standard uncertainty (µm, (n, 3)) of the model's prediction minus the measurement at
    each fitted observation: the residual's ``σ √(1 − h_ii)``.

    The model's rigid-aligned prediction minus the rigid-aligned measured error at a ball
    the model was fitted to *is* the fit's residual (the placements of the rigid fit are
    a subset of the full model's parameters). Prediction and measurement share that
    ball's noise, so the difference varies less than either: its variance is
    ``σ² − var(fit)``, ``var(fit) = J_i V J_iᵀ`` with the full Jacobian row (placements,
    plate and effects included) and the full covariance. Combining them as
    ``√(u_model² + σ²)`` treats them as independent, which holds only for a measurement
    the fit did not use, and made nominal 95 % intervals cover about 97 % (96.3 % with
    the plate fixed, 97.1 % with it free, over simulated data sets). With the certificate
    fixed its errors add their own part (``certificate_prior.residual_u_um``). With this, they
    cover 95 % (``tests/test_coverage.py``).

    Parameters
    ----------
    result : FitResult
    chunk : int
        Jacobian rows made dense at a time (memory).

    Returns
    -------
    ndarray (n, 3)
        ``σ √(1 − h_ii)`` per residual component, in the fit's observation order.
    """
    _, J = result.problem.residual(result.state, True)
    # the noise's part: σ²(1 - h_ii) needs the covariance of the noise alone; the
    # certificate's errors (certificate fixed) add their own part to each residual
    cov = np.nan_to_num(result.covariance if result.covariance_noise is None
                        else result.covariance_noise)
    var_fit = np.empty(J.shape[0])
    for i in range(0, J.shape[0], chunk):
        A = J[i:i + chunk]
        A = A.toarray() if hasattr(A, "toarray") else np.asarray(A)
        var_fit[i:i + chunk] = np.einsum("ik,ik->i", A @ cov, A)
    u2 = np.clip(result.sigma_um**2 - var_fit, 0, None)
    if result.covariance_noise is not None:

        u2 = u2 + residual_u_um(result, chunk).ravel() ** 2
    return np.sqrt(u2).reshape(-1, 3)


def rigid_removed_error_u(result: FitResult, x_mm: ArrayLike, probe: str | None = None
                      ) -> np.ndarray:
    """Standard uncertainty (µm) of the error at scale readings ``x_mm`` (one probe) with
    the rigid-body part of the whole point set removed: the uncertainty of the error's
    shape over those points (lengths, flatness), for maps. NaN when undetermined."""
    x = np.atleast_2d(np.asarray(x_mm, float))
    if _undetermined(result, "kinematic") or _undetermined(result, "probe_offset"):
        return np.full(x.shape, np.nan)
    p = np.broadcast_to(_probe_vector(result, probe), x.shape)
    return _rigid_removed_u(result, x, p, x + p)


def _rigid_removed_u(result, x, p, points):
    """sqrt(diag(P J V Jᵀ Pᵀ)) without forming the 3m × 3m projector P = I − Q Qᵀ."""
    Je = _error_jacobian(result, x, p)
    Q = _rigid_basis(points)
    PJ = Je - Q @ (Q.T @ Je)
    V = np.einsum("ik,kl,il->i", PJ, result.kinematic_cov, PJ)
    return np.sqrt(np.clip(V, 0, None)).reshape(-1, 3)


@dataclass(frozen=True)
class UncertaintySummary:
    """U1, U2, U3 of thesis tables 4.1-4.3 (average standard uncertainties per axis, µm).

    Attributes
    ----------
    U1_um : dict or None
        Ball-centre coordinates (``None`` when the plate is fixed to the certificate).
    U2_um : dict or None
        CMM error at random points in the evaluated region.
    U3_um : dict or None
        CMM error at random points in the whole working volume.
    region_mm : ndarray (2, 3)
        Lower and upper corners of the evaluated region (scale readings).
    message : str
        What was computed, and why something was not.
    """

    U1_um: dict | None
    U2_um: dict | None
    U3_um: dict | None
    region_mm: np.ndarray
    message: str
    inflated: dict = field(default_factory=dict)
    """``{"U1_um": ..., "U2_um": ..., "U3_um": ...}`` with the noise part of every point's
    variance scaled by the squared Birge ratio (when above 1) and the certificate's part
    (certificate fixed) as it is; equal to the plain values when the fit passes."""


def _avg(V, m, Vn=None, b2=1.0):
    """Mean over points of each axis's u: plain, and with the noise part ``Vn`` of the
    variance (all of it when None) scaled by ``b2``."""
    d = np.clip(np.diag(V), 0, None)
    dn = d if Vn is None else np.clip(np.diag(Vn), 0, None)
    out = []
    for var in (d, b2 * dn + np.clip(d - dn, 0, None)):
        u = np.sqrt(var).reshape(m, 3)
        out.append({a: float(u[:, i].mean()) for i, a in enumerate("xyz")})
    return out


def evaluate(result: FitResult, *, n_random: int = 200, seed: int = 0,
         probe: str | None = None) -> UncertaintySummary:
    """U1, U2 and U3 as thesis §4.5.3 defines them, rigid-body freedoms removed.

    A model whose parameters the data do not all determine gets no numbers: the message
    names the undetermined combinations instead (thesis: "location 0 alone will lead to
    the rank deficiency of the Jacobian matrix").
    """
    obs = result.problem.obs
    x_meas = obs.r_mm - obs.p_mm
    region = np.array([x_meas.min(0), x_meas.max(0)])
    if _undetermined(result, "kinematic"):
        return UncertaintySummary(None, None, None, region,
                                  "Not evaluated: the data cannot determine "
                                  f"{len(result.null_combinations)} parameter combination(s) "
                                  f"({' '.join(dict.fromkeys(result.null_words[:3]))}) Uncertainties "
                                  "would be unbounded; add positions or probes, or remove "
                                  "those functions from the model.")
    rng = np.random.default_rng(seed)
    msgs = []
    U1 = None
    b2 = max(1.0, result.birge_ratio) ** 2
    cn = result.covariance_noise
    inflated = {}
    labels, _, _ = result.block("plate")
    if len(labels) and _undetermined(result, "plate"):
        msgs.append("U1 not evaluated: the data cannot determine the plate")
    elif len(labels):
        s = result.problem.layout.blocks["plate"]
        Vc = result.covariance[s, s]
        P = rigid_body_projector(obs.plate0_mm)
        U1, inflated["U1_um"] = _avg(P @ Vc @ P.T, len(obs.plate0_mm),
                                     None if cn is None else P @ cn[s, s] @ P.T, b2)
        msgs.append(f"U1 over {len(obs.plate0_mm)} balls ({result.plate} plate)")
    else:
        msgs.append("U1 not evaluated: the plate is fixed to the certificate")
    out = []
    rng_mm = np.asarray(obs.range_mm, float)
    kin = result.problem.layout.blocks["kinematic"]
    for lo, hi in ((region[0], region[1]), (np.zeros(3), rng_mm)):
        pts = lo + (hi - lo) * rng.random((n_random, 3))
        V = error_covariance(result, pts, probe)
        P = rigid_body_projector(pts)
        Vn = None if cn is None else P @ error_covariance(result, pts, probe,
                                                          cn[kin, kin]) @ P.T
        out.append(_avg(P @ V @ P.T, n_random, Vn, b2))
    msgs.append(f"U2 and U3 at {n_random} random points (seed {seed})")
    inflated.update(U2_um=out[0][1], U3_um=out[1][1])
    return UncertaintySummary(U1, out[0][0], out[1][0], region, "; ".join(msgs) + ".",
                              inflated)

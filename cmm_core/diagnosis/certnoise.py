"""The certificate's own errors in the diagnosis's F-test (issue 26).

With the plate fixed to a certificate, the certificate's errors are a second noise beside
σ, common to every placement's image of a ball. In the weighted residual they are
``G c`` with ``c`` standard normal, ``G`` the plate coordinates' weighted columns times
the certificate's standard uncertainties (:func:`cert_columns`); what the baseline
cannot absorb of them is ``M G`` (``M = I − U Uᵀ``, U the baseline's column space), with
covariance ``D = M G Gᵀ M``.

A candidate effect spans k directions ``Q`` beyond the baseline. Its χ² reduction is then
the quadratic form ``Σ_i w_i (z_i + δ_i)²`` in k standard normals, ``w_i`` the
eigenvalues of ``I + Qᵀ D Q`` (:func:`cert_noise`; their mean ``c1`` is the Δχ²'s
inflation per dof), and the residual χ² is about ``c2`` times a central χ²(ν),
``c2 = 1 + tr((M − P_Q) D)/ν`` (Satterthwaite 1946; :func:`cert_scales`). A plain F-test
takes σ as white; on the scenario layouts the certificate loads some candidates'
directions up to 16 % more than the residual (``dzz:3``, ``plate_sag``, ``backlash``), so
their false-alarm rate was up to 2.6 times their level and the family's about 0.95 % at a
stated 0.8 % (1189 null verdicts of 1200 clean seeds). The diagnosis's p-value is
therefore the exact tail of the statistic under this null (:func:`null_p_value`):

    p = P(Σ_i w_i z_i² − F (k/ν) c2 χ²_ν > 0),

a probability of a quadratic form in normal variables (Imhof 1961,
:func:`quadratic_form_sf`); with no certificate (``w_i = c2 = 1``) it is the F-test's own
``f.sf(F, k, ν)``. ``plan.detect`` states detection limits for this same test.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize, stats

from ..model import FitResult, ModelSpec, Problem, augmented_state, weighted_residual

__all__ = ["MIN_FORM_DOF", "CertNoise", "cert_columns", "cert_noise", "cert_scales",
           "critical_ratio", "null_p_value", "quadratic_form_sf", "rejection_probability",
           "size_for_power"]

MIN_FORM_DOF = 20
"""Fewest dof in all that :func:`quadratic_form_sf` integrates (its tail then decays at
least like u^-10); fewer: the Satterthwaite shortcut (one scale ``c1`` for all k)."""


def quadratic_form_sf(weights: np.ndarray, dofs: np.ndarray, noncentralities: np.ndarray
                      ) -> float:
    """``P(Σ_j w_j χ²(h_j, δ_j²) > 0)`` for independent non-central χ² terms of weights
    ``w_j`` (either sign), dof ``h_j`` and non-centralities ``δ_j²``: Imhof (1961), eq. 3.2,

        P = 1/2 + (1/π) ∫_0^∞ sin θ(u) / (u ρ(u)) du,
        θ(u) = ½ Σ [h_j atan(w_j u) + δ_j² w_j u / (1 + w_j² u²)],
        ρ(u) = Π (1 + w_j² u²)^{h_j/4} exp(½ Σ δ_j² w_j² u² / (1 + w_j² u²)),

    integrated by Simpson's rule on a grid of three points per radian of θ's fastest turn
    (at least 801 points) up to where ``ρ`` exceeds e^40. Meant for forms holding a
    residual χ² of many dof (at least :data:`MIN_FORM_DOF` in all), whose ρ grows fast,
    so that the integral is short: against scipy's non-central F the error is below 1e-13
    (``tests/test_detect_certnoise.py``). Fewer dof are refused (the grid would not reach the
    slowly decaying tail).
    """
    w = np.asarray(weights, float)
    h = np.asarray(dofs, float)
    d2 = np.asarray(noncentralities, float)
    if float(h.sum()) < MIN_FORM_DOF:
        raise ValueError(f"quadratic_form_sf: {float(h.sum()):g} dof in all, fewer than "
                         f"{MIN_FORM_DOF} (the integral's tail would be cut).")

    def log_rho(u):
        x = (w * u[:, None]) ** 2
        return (0.25 * h * np.log1p(x) + 0.5 * d2 * x / (1 + x)).sum(axis=1)

    # the first of u = 2^j / max|w| (j = 0 .. 79) where ρ exceeds e^40, in one evaluation
    tops = 2.0 ** np.arange(80) / np.abs(w).max()
    top = float(tops[min(int(np.argmax(log_rho(tops) >= 40.0)), tops.size - 1)])
    rate = 0.5 * float(np.sum(np.abs(w) * (h + d2)))
    n = int(min(max(3 * rate * top, 800), 400_000)) // 2 * 2 + 1
    u = np.linspace(0.0, top, n)[1:]
    wu = w * u[:, None]
    theta = 0.5 * (h * np.arctan(wu) + d2 * wu / (1 + wu**2)).sum(axis=1)
    f = np.empty(n)
    f[0] = 0.5 * float(np.sum(w * (h + d2)))  # lim sin θ(u)/u at 0
    f[1:] = np.sin(theta) / u * np.exp(-log_rho(u))
    step = top / (n - 1)
    integral = step / 3 * (f[0] + f[-1] + 4 * f[1:-1:2].sum() + 2 * f[2:-1:2].sum())
    return float(np.clip(0.5 + integral / np.pi, 0.0, 1.0))


def _even(w: np.ndarray) -> bool:
    return w.size <= 1 or float(w.max() - w.min()) <= 1e-6 * float(w.max())


def null_p_value(F: float, weights: np.ndarray, c2: float, nu: int) -> float:
    """p-value of the diagnosis's statistic ``F = (Δχ²/k)/(χ²_res/ν)`` when the Δχ²'s
    noise has the eigenvalues ``weights`` (k of them) and the residual χ² is ``c2`` times
    a central χ²(ν) (module docstring). Equal weights (k = 1, or no certificate): the
    F distribution scaled by ``c1/c2``, exactly; unequal: Imhof's integral."""
    w = np.asarray(weights, float)
    k = w.size
    if _even(w) or nu + k < MIN_FORM_DOF:
        return float(stats.f.sf(F * c2 / float(w.mean()), k, nu))
    return quadratic_form_sf(np.r_[w, -F * k / nu * c2], np.r_[np.ones(k), nu],
                             np.zeros(k + 1))


def critical_ratio(weights: np.ndarray, c2: float, nu: int, level: float) -> float:
    """``a = F* k/ν``, ``F*`` the statistic at which :func:`null_p_value` is ``level``:
    the test rejects when ``Δχ² − a χ²_res > 0`` (``plan.detect``'s power of it)."""
    w = np.asarray(weights, float)
    k = w.size
    if _even(w) or nu + k < MIN_FORM_DOF:
        return float(stats.f.isf(level, k, nu)) * float(w.mean()) / c2 * k / nu
    lo = float(stats.f.isf(level, k, nu)) * float(w.min()) / c2
    hi = float(stats.f.isf(level, k, nu)) * float(w.max()) / c2 * 1.01
    F = optimize.brentq(lambda F: null_p_value(F, w, c2, nu) - level, lo, hi,
                        xtol=1e-7 * lo, rtol=1e-7)
    return float(F) * k / nu


def rejection_probability(weights: np.ndarray, signal: np.ndarray, nu: int, level: float,
                          c2: float = 1.0) -> float:
    """Probability that the diagnosis's test at ``level`` rejects when its Δχ² is
    ``Σ_i w_i (z_i + δ_i)²`` (``signal`` the ``δ_i²``) and its residual χ² is ``c2``
    times a central χ²(ν): ``P(Δχ² − a c2 χ²_ν > 0)``, ``a`` the test's critical
    ``Δχ²/χ²_res`` under the same noise (:func:`critical_ratio`; ``plan.detect``'s
    detection limits)."""
    return _form(weights, nu, level, c2)(np.asarray(signal, float))


def _form(weights, nu, level, c2):
    """``δ² -> rejection probability`` for fixed noise weights, ν, level and ``c2``."""
    w = np.asarray(weights, float)
    k = w.size
    a = critical_ratio(w, c2, nu, level)
    ws, hs = np.r_[w, -a * c2], np.r_[np.ones(k), nu]
    return lambda d2: quadratic_form_sf(ws, hs, np.r_[d2, 0.0])


def size_for_power(weights: np.ndarray, signal_per_unit2: np.ndarray, nu: int, level: float,
                   c2: float, power: float, guess: float) -> float:
    """Size along a shape at which :func:`rejection_probability` is ``power`` (brentq in
    the size², to 1e-4 relative, on a bracket around ``guess`` that widens until it
    holds the root)."""
    d = np.asarray(signal_per_unit2, float)
    prob = _form(weights, nu, level, c2)

    def gap(t):
        return prob(t * d) - power

    lo, hi = 0.9 * guess**2, 1.15 * guess**2
    while gap(lo) > 0 and lo > 1e-12 * guess**2:
        lo *= 0.5
    while gap(hi) < 0:
        hi *= 2.0
    return float(np.sqrt(optimize.brentq(gap, lo, hi, xtol=1e-4 * lo, rtol=1e-4)))


def cert_columns(base: FitResult, spec: ModelSpec | None = None) -> np.ndarray | None:
    """The certificate's own errors in the weighted residual: the plate coordinates'
    weighted columns (the plate block of the same model with the certificate as a prior)
    times the certificate's standard uncertainties, observation rows only; their Gram
    matrix is the errors' covariance. None when the plate is not fixed to a certificate
    with uncertainties, or for a hole plate."""
    o = base.problem.obs
    if base.plate != "fixed" or o.cert_u_um is None or o.artefact == "hole_plate":
        return None
    pp = Problem(o, base.problem.spec if spec is None else spec, "prior")
    Jp = weighted_residual(pp, augmented_state(base, pp), base.sigma_um, True)[2]
    blk = pp.layout.blocks["plate"]
    Jc = Jp.toarray()[: 3 * pp.n_obs, blk.start:blk.stop]
    return Jc * np.nan_to_num(np.asarray(o.cert_u_um, float).ravel(), posinf=0.0)


def cert_noise(MG: np.ndarray | None, R: np.ndarray, k: int) -> tuple:
    """``(w, V, Q)``: the eigenvalues ``w`` (ascending) and eigenvectors ``V`` of the
    Δχ²'s noise covariance ``I + Qᵀ D Q`` in the effect's k directions ``Q`` (the
    leading left singular vectors of ``R``, its columns beyond the baseline), ``D`` the
    certificate's errors' covariance ``MG MGᵀ`` (module docstring)."""
    Q = np.linalg.svd(R, full_matrices=False)[0][:, :k]
    if MG is None:
        return np.ones(k), np.eye(k), Q
    C = Q.T @ MG
    w, V = np.linalg.eigh(np.eye(k) + C @ C.T)
    return w, V, Q


def cert_scales(MG: np.ndarray | None, R: np.ndarray, k: int, nu: int
                ) -> tuple[float, float]:
    """``(c1, c2)``: how much a fixed certificate's errors inflate the test's Δχ² per
    degree of freedom (their share in the effect's columns, ``1 + tr(P_R D)/k``) and its
    residual χ²/ν (``1 + tr((M − P_R) D)/ν``), ``D = M G Gᵀ M`` their covariance."""
    if MG is None or k <= 0:
        return 1.0, 1.0
    Q = np.linalg.svd(R, full_matrices=False)[0][:, :k]
    on = float(np.sum((Q.T @ MG) ** 2))
    return 1.0 + on / k, 1.0 + (float(np.sum(MG**2)) - on) / max(nu, 1)


class CertNoise:
    """A baseline's certificate errors beyond its own column space, for the noise of each
    candidate's test (module docstring).

    Parameters
    ----------
    base : FitResult
    U : ndarray
        Orthonormal basis of the baseline's column space (weighted Jacobian rows).
    n_rows : int
        Rows of the candidates' weighted Jacobian (observations, then priors).
    """

    def __init__(self, base: FitResult, U: np.ndarray, n_rows: int) -> None:
        G = cert_columns(base)
        self.MG: np.ndarray | None = None
        if G is not None:
            G = np.vstack([G, np.zeros((n_rows - G.shape[0], G.shape[1]))])
            self.MG = G - U @ (U.T @ G)
        self.U = U

    def of(self, JE: np.ndarray, k: int, nu: int) -> tuple[np.ndarray, float]:
        """``(w, c2)`` of a candidate whose added weighted columns are ``JE`` (k the rank
        it adds, ν the residual dof): all ones and 1 without a certificate."""
        if self.MG is None or k <= 0:
            return np.ones(max(k, 0)), 1.0
        R = JE - self.U @ (self.U.T @ JE)
        w = cert_noise(self.MG, R, k)[0]
        return w, cert_scales(self.MG, R, k, nu)[1]

    def each(self, JE: np.ndarray) -> np.ndarray:
        """Each added column's own inflation ``1 + |MGᵀ q_j|²``, ``q_j`` the unit part of
        column j beyond the baseline and the other added columns (the direction its
        parameter's uncertainty belongs to); 1 without a certificate, and for a column
        with no part of its own."""
        out = np.ones(JE.shape[1])
        if self.MG is None:
            return out
        R = JE - self.U @ (self.U.T @ JE)
        for j in range(R.shape[1]):
            others = np.delete(R, j, axis=1)
            r = R[:, j]
            if others.size:
                r = r - others @ np.linalg.lstsq(others, r, rcond=None)[0]
            n = float(np.linalg.norm(r))
            if n > 1e-9 * max(float(np.linalg.norm(R[:, j])), 1e-300):
                out[j] = 1.0 + float(np.sum((self.MG.T @ (r / n)) ** 2))
        return out

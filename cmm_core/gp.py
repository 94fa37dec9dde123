"""Gaussian-process regression with explicit basis functions (thesis chapter 5, appendix 3).

The model is the one of Rasmussen & Williams (2006), *Gaussian Processes for Machine
Learning* (R&W), §2.7::

    y = f(x) + h(x)ᵀβ + ε,   f ~ GP(0, k),   ε ~ N(0, σ_n²),   β ~ N(b, B), B → ∞

with ``k`` the squared-exponential covariance (thesis eq. 5.1, R&W eq. 2.31 isotropic or
eq. 5.1 with automatic relevance determination) and ``h`` a set of explicit basis functions
(the parametric mean: nothing, a constant, a linear or quadratic polynomial, thesis eq. 5.11
``meanMylinear_2D``, or any design matrix such as a kinematic model's). The coefficients β
are marginalised analytically under a vague prior rather than optimised as hyperparameters
as the thesis's GPML script does; this gives the extra predictive variance term of
R&W eq. 2.42 and the adjusted marginal likelihood of R&W eq. 2.45.

Hyperparameters (length scale(s), signal and noise standard deviations) are chosen by
maximising the log marginal likelihood with L-BFGS-B in log space, with analytic gradients
(R&W eq. 5.9, using the projected matrix ``P`` for a basis mean; one Cholesky
factorisation per evaluation), from a default start and ``restarts`` further starts, a
seeded Latin hypercube over the whole bounds; above 600 points the starts run on a
300-point subset first and the distinct optima are polished on all the points. Inputs are centred and scaled by one common
factor, outputs by their RMS, for conditioning; everything is reported in data units
(X in mm, y in µm for the CMM use).

Leave-one-out predictions are in closed form (R&W §5.4.2, eq. 5.12), with ``P`` in place
of ``K⁻¹`` when a basis is marginalised.

Only numpy and scipy are used.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from itertools import combinations_with_replacement

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack
from scipy.optimize import OptimizeResult, minimize
from scipy.spatial.distance import cdist
from scipy.stats import norm, qmc

from ._blas import single_blas_thread

__all__ = ["GPResult", "fit_gp", "log_marginal_likelihood", "polynomial_basis", "MEANS", "KERNELS"]

MEANS = ("zero", "constant", "linear", "quadratic", "thesis_quadratic")
"""Built-in parametric means (explicit basis functions marginalised analytically)."""
KERNELS = ("se_iso", "se_ard")
"""Squared-exponential covariance, isotropic (one length scale) or ARD (one per input)."""

_LOG2PI = np.log(2 * np.pi)
_JITTER_START = 1e-10  # relative to the mean diagonal of K
_JITTER_MAX = 1e-4
_RANK_RTOL = 1e-9  # basis columns with pivoted-QR |R_jj| below this times |R_00| are dropped
_CHUNK = 4096  # prediction points per block
_MAX_INPUTS = 6  # ram position and probe offset
_SAME_POINT = 1e-3  # inputs closer than this times the input extent are one location
_ALT_MAX_LENGTH = 10.0  # next-best optimum: length scales up to this times the extent
# collapsed: the closest distinct points are more than this many length scales apart
# (correlation below exp(-2) = 0.14). Not 1: the thesis appendix 3 plate (pitch 100 mm)
# has its optimum at 87 mm, neighbours correlated by 0.52, a working GP.
_COLLAPSE_SPACINGS = 2.0
_PREFIT_POINTS = 300  # subset the restarts run on first when n > 2 × this (``_optimise``)
_SAME_OPTIMUM = 0.05  # subset optima closer than this in every log hyperparameter are one
# L-BFGS-B's relative-reduction stop: scipy's default 2.2e-9 leaves the log ML 1e-7 below
# the optimum at n = 1000 (its gradient test then stops it first); the subset runs only
# find the basins and keep the default
_FTOL = 1e-12
# BFGS polish: ∞-norm of the gradient at which it stops. The log ML is then within
# |g|²/(2 λ_min) ~ 1e-10 of the optimum (λ_min ~ 10 at n = 1000); 1e-5 is below what its
# round-off (~1e-10) lets the line search see, which then spent 24 evaluations in place
_GTOL = 1e-4
_GTOL_STALLED = 1e-3  # a BFGS polish stalled by round-off below this gradient converged
# a BFGS polish is a few steps from a good start; more means it is lost (L-BFGS-B then)
_BFGS_MAXITER = 15
_PRUNE_NATS = 10.0  # subset optima this far below the best are not polished (_optimise)
_INTERIOR = 2.0  # a subset optimum this far (log) from every bound gets the BFGS polish
_FTOL_PREFIT = 2.2e-9


# --------------------------------------------------------------------------- basis

def polynomial_basis(X, kind: str):
    """Design matrix of a built-in polynomial mean, in the units of ``X``.

    Parameters
    ----------
    X : array_like (n, d)
    kind : {"zero", "constant", "linear", "quadratic", "thesis_quadratic"}
        ``quadratic`` is the full quadratic in all inputs (1, x_i, x_i x_j for i <= j);
        ``thesis_quadratic`` is thesis eq. 5.11 exactly (``meanMylinear_2D``:
        a1 + a2 x1 + a3 x1², first input only).

    Returns
    -------
    H : ndarray (n, m)
    names : tuple of str
        Column names, e.g. ``("1", "x1", "x1*x2")``.
    """
    X = np.atleast_2d(np.asarray(X, dtype=float))
    n, d = X.shape
    lab = [f"x{i + 1}" for i in range(d)]
    if kind == "zero":
        return np.zeros((n, 0)), ()
    cols, names = [np.ones(n)], ["1"]
    if kind == "thesis_quadratic":
        return np.column_stack([np.ones(n), X[:, 0], X[:, 0] ** 2]), ("1", "x1", "x1^2")
    if kind in ("linear", "quadratic"):
        cols += [X[:, i] for i in range(d)]
        names += lab
    if kind == "quadratic":
        for i, j in combinations_with_replacement(range(d), 2):
            cols.append(X[:, i] * X[:, j])
            names.append(f"{lab[i]}^2" if i == j else f"{lab[i]}*{lab[j]}")
    if kind not in ("constant", "linear", "quadratic"):
        raise ValueError(f"mean {kind!r} is not a built-in mean: expected one of {MEANS}, a "
                         "callable h(X) -> (n, m) or an (n, m) design matrix")
    return np.column_stack(cols), tuple(names)


# --------------------------------------------------------------------------- core

class _Problem:
    """Standardised data and the negative log marginal likelihood with its gradient.

    Internal units: ``Xs = (X - centre)/x_scale``, ``ys = y/y_scale``; the basis is the
    orthonormal ``Q`` of a pivoted QR of the column-normalised user basis.
    """

    def __init__(self, Xs, ys, Q, groups, noise_groups=None):
        self.Xs, self.ys, self.Q = Xs, ys, Q
        # noise group of each point (one noise variance per group)
        self.noise_groups = (np.zeros(len(ys), dtype=int) if noise_groups is None
                             else np.asarray(noise_groups, dtype=int))
        self.n_noise = int(self.noise_groups.max()) + 1
        self.groups = np.asarray(groups, dtype=int)
        self.n, self.d = Xs.shape
        self.m = Q.shape[1]
        self.n_groups = int(self.groups.max()) + 1
        # squared distances per length-scale group (G, n, n)
        self.D2 = np.stack([cdist(Xs[:, self.groups == g], Xs[:, self.groups == g],
                                  "sqeuclidean") for g in range(self.n_groups)])
        self.n_jitter = 0
        self.n_eval = 0

    def n_length(self):
        return self.n_groups

    def kernel(self, log_l, sf2):
        if self.n_groups > 1:
            K = np.tensordot(0.5 / np.exp(2 * log_l), self.D2, axes=1)
        else:
            K = self.D2[0] * (0.5 / np.exp(2 * log_l[0]))
        np.negative(K, out=K)
        np.exp(K, out=K)
        K *= sf2
        return K

    def scaled_d2(self, log_l):
        """Σ_g D2_g / l_g²: squared distances in units of the length scales."""
        return np.tensordot(1.0 / np.exp(2 * np.asarray(log_l)), self.D2, axes=1)

    def factor(self, theta):
        """Cholesky factor of K_y (jitter only if it fails) and the basis quantities.

        ``L`` is LAPACK potrf's lower factor with the upper triangle zeroed, so that potri
        on it gives K⁻¹'s lower triangle and zeros (see ``_kinv_lower``).
        """
        nl = self.n_length()
        log_l, sf2, sn2 = theta[:nl], np.exp(2 * theta[nl]), np.exp(2 * theta[nl + 1:])
        Kf = self.kernel(log_l, sf2)
        noise = sn2[self.noise_groups]
        jitter = 0.0
        scale = sf2 + sn2.max()
        while True:
            Ky = Kf.copy()
            Ky.flat[:: self.n + 1] += noise + jitter
            L, info = lapack.dpotrf(Ky, lower=1, clean=1, overwrite_a=1)
            if info == 0:
                break
            new = _JITTER_START * scale if jitter == 0 else 10 * jitter
            if new > _JITTER_MAX * scale:
                return None
            jitter = new
        if jitter:
            self.n_jitter += 1
        a0 = sla.cho_solve((L, True), self.ys, check_finite=False)
        st = {"L": L, "Kf": Kf, "sf2": sf2, "sn2": sn2, "log_l": log_l, "jitter": jitter}
        if self.m:
            KiQ = sla.cho_solve((L, True), self.Q, check_finite=False)
            A = self.Q.T @ KiQ
            try:
                LA, _ = sla.cho_factor(A, lower=True, check_finite=False)
            except sla.LinAlgError:
                return None
            beta = sla.cho_solve((LA, True), self.Q.T @ a0, check_finite=False)
            alpha = a0 - KiQ @ beta
            logdetA = 2 * np.log(np.diag(LA)).sum()
            # P = K⁻¹ - WᵀW (R&W §2.7): the basis part of the projected matrix, never formed
            W = sla.solve_triangular(LA, KiQ.T, lower=True, check_finite=False)
            st.update(KiQ=KiQ, LA=LA, beta=beta, logdetA=logdetA, W=W)
        else:
            alpha, logdetA = a0, 0.0
            st.update(beta=np.zeros(0), logdetA=0.0, W=None)
        st["alpha"] = alpha
        st["lml"] = (-0.5 * self.ys @ alpha - np.log(np.diag(L)).sum() - 0.5 * logdetA
                     - 0.5 * (self.n - self.m) * _LOG2PI)
        return st

    def p_diag(self, st, T):
        """diag(P) from K⁻¹'s lower triangle ``T``."""
        d = np.diag(T).copy()
        if st["W"] is not None:
            d -= np.einsum("ki,ki->i", st["W"], st["W"])
        return d

    def trace_p(self, st, T, G):
        """tr(P G) for a symmetric G, from K⁻¹'s lower triangle ``T`` (upper zero)."""
        t = 2 * np.vdot(T, G) - np.dot(np.diag(T), np.diag(G))
        if st["W"] is not None:
            t -= np.vdot(st["W"] @ G, st["W"])
        return t

    def objective(self, theta):
        """Negative log marginal likelihood and its gradient in log hyperparameters.

        ∂ log p/∂θ_j = ½ αᵀ ∂K_j α - ½ tr(P ∂K_j), α = P y (R&W eq. 5.9 with P). One
        Cholesky factorisation serves both; K⁻¹ for the traces is LAPACK potri on the
        factor in place (its lower triangle only: a third of cho_solve's flops with the
        identity, and no n×n symmetrisation).
        """
        self.n_eval += 1
        st = self.factor(theta)
        if st is None:
            return 1e25, np.zeros_like(theta)
        alpha, Kf = st["alpha"], st["Kf"]
        T = _kinv_lower(st.pop("L"), overwrite=True)
        if T is None:
            return 1e25, np.zeros_like(theta)
        nl = self.n_length()
        g = np.empty_like(theta)
        for i in range(nl):
            G = self.D2[i] * Kf  # ∂K/∂log l_i times l_i²
            g[i] = 0.5 * (alpha @ (G @ alpha) - self.trace_p(st, T, G)) / np.exp(
                2 * st["log_l"][i])
        g[nl] = alpha @ (Kf @ alpha) - self.trace_p(st, T, Kf)  # ∂K/∂log σ_f = 2 K_f
        g[nl + 1:] = st["sn2"] * np.bincount(self.noise_groups,
                                             weights=alpha**2 - self.p_diag(st, T),
                                             minlength=self.n_noise)
        return -st["lml"], -g

    def subset(self, idx):
        """The same problem on the points ``idx`` (same standardisation), or None when the
        subset does not determine the basis or misses a noise group."""
        groups = self.noise_groups[idx]
        if np.unique(groups).size != self.n_noise:
            return None
        Q = self.Q[idx]
        if self.m:
            Q, R = np.linalg.qr(Q)
            dg = np.abs(np.diag(R))
            if dg.min() <= _RANK_RTOL * dg.max():
                return None
        sub = object.__new__(_Problem)
        sub.__dict__.update(self.__dict__)
        sub.Xs, sub.ys, sub.Q, sub.noise_groups = self.Xs[idx], self.ys[idx], Q, groups
        sub.n = len(idx)
        sub.D2 = self.D2[:, idx][:, :, idx]
        sub.n_jitter = sub.n_eval = 0
        return sub


def _kinv_lower(L, overwrite=False):
    """Lower triangle of K⁻¹ (upper triangle zero) from the clean lower factor ``L``, by
    LAPACK potri; None if it fails (a zero on the factor's diagonal)."""
    T, info = lapack.dpotri(L, lower=1, overwrite_c=overwrite)
    return T if info == 0 else None


# --------------------------------------------------------------------------- result

@dataclass(frozen=True, eq=False)
class GPResult:
    """A fitted Gaussian process (hyperparameters in data units).

    Attributes
    ----------
    mean : str
        The mean: a built-in name (see ``MEANS``), ``"callable"`` or ``"matrix"``.
    kernel : str
        ``"se_iso"`` or ``"se_ard"``.
    n : int
        Number of training points.
    input_dim : int
        Number of input coordinates (1, 2 or 3).
    length_scale_mm : tuple of float
        SE length scale(s) in the units of X (one for ``se_iso``, one per input for
        ``se_ard``).
    signal_sd_um : float
        Signal standard deviation σ_f (units of y): k(x, x) = σ_f².
    noise_sd_um : float
        Noise standard deviation σ_n of the Gaussian likelihood (units of y); with noise
        groups, the RMS over the points of their groups' values. Predictive variances from
        ``predict`` are of the latent function and exclude it.
    noise_sd_by_group_um : tuple of float
        σ_n of each noise group (one value without ``noise_groups``).
    log_marginal_likelihood : float
        log p(y | X, θ) at the reported hyperparameters. With a basis it is R&W eq. 2.45
        without the terms that diverge with the vague prior (the log|B| term), for the basis
        as defined in data units (``mean_terms``); comparable between hyperparameters, not
        between different bases.
    mean_terms : tuple of str
        Names of the basis columns used.
    basis_dropped : tuple of str
        Basis columns dropped because the data do not determine them (linearly dependent on
        the others at the training inputs, pivoted QR with relative tolerance 1e-9).
    mean_coefficients : ndarray (m,)
        β̄ = A⁻¹ Hᵀ K_y⁻¹ y (R&W eq. 2.42), coefficients of ``mean_terms`` in data units.
    mean_coefficients_cov : ndarray (m, m)
        Their posterior covariance A⁻¹ = (Hᵀ K_y⁻¹ H)⁻¹.
    loo_mean_um : ndarray (n,)
        Leave-one-out predictive mean of each y_i (R&W eq. 5.12), hyperparameters fixed.
    loo_sd_um : ndarray (n,)
        Leave-one-out predictive standard deviation of each y_i, noise included
        (``inf`` where leaving the point out leaves a basis coefficient undetermined).
    loo_rms_um : float
        RMS of y - loo_mean over the points with a finite LOO prediction.
    loo_log_predictive : float
        Leave-one-out log predictive probability Σ log p(y_i | X, y_-i, θ) (R&W eq. 5.11).
    loo_z : ndarray (n,)
        Standardised leave-one-out residual (y_i - loo_mean_i) / loo_sd_i (``nan`` where
        there is no LOO prediction); N(0, 1) when the GP's uncertainty is right.
    status : str
        ``"converged"``, ``"not_converged"`` (best start did not satisfy L-BFGS-B's
        convergence test; the best point found is reported), ``"degenerate"`` (the best
        optimum is a collapsed or bounded length scale, see ``degenerate_reason`` and
        ``alternative``) or ``"fixed"`` (no optimisation asked for).
    success : bool
        ``status`` is ``"converged"`` or ``"fixed"``.
    message : str
        Optimiser message, hyperparameters at their bounds and any jitter, in words.
    n_evaluations : int
        Likelihood evaluations on all the training points over all starts (for
        n > 600 the starts first run on a 300-point subset, whose evaluations cost 1/30
        as much and are not counted; see ``fit_gp``, Notes).
    start_log_ml : tuple of float
        Final log marginal likelihood of each start (default start first; for n > 600,
        of the optimum its subset run led to, polished on all points, or unpolished when
        it was 10 nats or more below the best on the subset); ``nan`` for a
        start where the likelihood could not be evaluated.
    jitter_um2 : float
        Variance added to the diagonal of K_y at the reported hyperparameters because its
        Cholesky factorisation failed (units of y²); 0 when none was needed.
    n_jitter_events : int
        Number of factorisations during the fit that needed jitter.
    bounds : dict
        Bounds on the hyperparameters, data units: ``{name: (low, high)}``.
    groups : tuple of int
        Length-scale group of each input (``length_scale_mm`` has one value per group).
    degenerate : bool
        The hyperparameters are degenerate (see ``fit_gp``, Notes); also set for fixed
        hyperparameters, whose status stays ``"fixed"``.
    degenerate_reason : str
        Why, in words ("" when not degenerate).
    smallest_spacing_mm : float
        Smallest distance between distinct training inputs (points closer than 1e-3 of
        the input extent count as one location), units of X.
    alternative : GPResult or None
        For a degenerate fit, the next-best optimum that is not degenerate (or the optimum
        with the length scales kept above the smallest spacing); None otherwise.
    """

    mean: str
    kernel: str
    n: int
    input_dim: int
    length_scale_mm: tuple
    signal_sd_um: float
    noise_sd_um: float
    noise_sd_by_group_um: tuple
    log_marginal_likelihood: float
    mean_terms: tuple
    basis_dropped: tuple
    mean_coefficients: np.ndarray
    mean_coefficients_cov: np.ndarray
    loo_mean_um: np.ndarray
    loo_sd_um: np.ndarray
    loo_rms_um: float
    loo_log_predictive: float
    status: str
    success: bool
    message: str
    n_evaluations: int
    start_log_ml: tuple
    jitter_um2: float
    n_jitter_events: int
    bounds: dict
    loo_z: np.ndarray
    groups: tuple
    _state: dict = field(repr=False)
    degenerate: bool = False
    degenerate_reason: str = ""
    smallest_spacing_mm: float = float("nan")
    alternative: GPResult | None = None

    @property
    def hyperparameters(self) -> dict:
        """Readable hyperparameters: ``length_scale_mm``, ``signal_sd_um``, ``noise_sd_um``."""
        ls = self.length_scale_mm
        return {"length_scale_mm": ls[0] if len(ls) == 1 else list(ls),
                "signal_sd_um": self.signal_sd_um,
                "noise_sd_um": (self.noise_sd_um if len(self.noise_sd_by_group_um) == 1
                                else list(self.noise_sd_by_group_um))}

    def summary(self) -> dict:
        """JSON-ready summary: hyperparameters, log marginal likelihood, LOO RMS, status."""
        return {**self.hyperparameters,
                "log_marginal_likelihood": float(self.log_marginal_likelihood),
                "loo_rms_um": float(self.loo_rms_um),
                "n": self.n, "mean": self.mean, "n_mean_terms": len(self.mean_terms),
                # coefficients by name for the named (built-in) means only; a design
                # matrix's coefficients are in GPResult.mean_coefficients
                "mean_coefficients": ({t: float(b) for t, b in
                                       zip(self.mean_terms, self.mean_coefficients, strict=True)}
                                      if self.mean in MEANS else None),
                "basis_dropped": list(self.basis_dropped), "kernel": self.kernel,
                "status": self.status, "message": self.message,
                "jitter_um2": float(self.jitter_um2),
                "loo_coverage_95": float(self.loo_coverage(0.95)),
                "degenerate": bool(self.degenerate),
                "degenerate_reason": self.degenerate_reason,
                "smallest_spacing_mm": float(self.smallest_spacing_mm),
                "alternative": (None if self.alternative is None
                                else self.alternative.summary())}

    def loo_coverage(self, level: float = 0.95) -> float:
        """Fraction of the points inside their leave-one-out central ``level`` interval.

        Parameters
        ----------
        level : float
            Probability content of the interval, e.g. 0.95 for loo_mean ± 1.96 loo_sd.

        Returns
        -------
        float
            Covered fraction over the points with a LOO prediction (``nan`` if none):
            close to ``level`` when the GP's predictive uncertainty is right.
        """
        z = np.asarray(self.loo_z, float)
        z = z[np.isfinite(z)]
        if not z.size:
            return float("nan")
        return float(np.mean(np.abs(z) <= norm.ppf(0.5 + level / 2)))

    def predict(self, X_new, H_new=None, *, include_mean: bool = True):
        """Predictive mean and variance of the latent function at ``X_new``.

        f̄* = k*ᵀ K_y⁻¹ (y - Hβ̄) + h*ᵀβ̄ and
        V[f*] = k** - k*ᵀ K_y⁻¹ k* + Rᵀ A⁻¹ R, R = h* - Hᵀ K_y⁻¹ k* (R&W eq. 2.41-2.42;
        eq. 2.23-2.24 without a basis). The noise variance is not included: add
        ``noise_sd_um**2`` for the variance of a new observation.

        Parameters
        ----------
        X_new : array_like (m, d) (or (m,) when d = 1)
        H_new : array_like (m, p), optional
            Basis at ``X_new``; required when the mean was given as a design matrix
            (the basis is otherwise evaluated from the mean's definition).
        include_mean : bool
            With ``False``, return only the GP part conditional on β = β̄:
            mean k*ᵀ K_y⁻¹ (y - Hβ̄), variance k** - k*ᵀ K_y⁻¹ k* (the discrepancy from the
            parametric mean, e.g. of a kinematic model, at points where its basis is unknown).

        Returns
        -------
        mean : ndarray (m,)
        var : ndarray (m,)
        """
        s = self._state
        Xn = _as_inputs(X_new, "X_new")
        if Xn.shape[1] != self.input_dim:
            raise ValueError(f"X_new has {Xn.shape[1]} columns, expected {self.input_dim} "
                             "(the number of input coordinates the GP was fitted on)")
        use_basis = include_mean and s["m"] > 0
        if use_basis:
            Hn = self._basis_at(Xn, H_new)
            # internal basis q* = (h*_kept / d) R⁻¹
            Qn = sla.solve_triangular(s["R"], (Hn[:, s["keep"]] / s["col_norm"]).T,
                                      trans="T", lower=False, check_finite=False).T
        Xs = (Xn - s["centre"]) / s["x_scale"]
        mean = np.empty(len(Xn))
        var = np.empty(len(Xn))
        for lo in range(0, len(Xn), _CHUNK):
            sl = slice(lo, lo + _CHUNK)
            Ks = _cross_kernel(Xs[sl], s["Xs"], s["length_s"], s["sf2"])
            mu = Ks @ s["alpha"]
            v = sla.solve_triangular(s["L"], Ks.T, lower=True, check_finite=False)
            vv = s["sf2"] - np.einsum("ij,ij->j", v, v)
            if use_basis:
                mu += Qn[sl] @ s["beta"]
                Rm = Qn[sl].T - s["KiQ"].T @ Ks.T
                w = sla.solve_triangular(s["LA"], Rm, lower=True, check_finite=False)
                vv += np.einsum("ij,ij->j", w, w)
            mean[sl] = mu
            var[sl] = np.maximum(vv, 0.0)
        return mean * s["y_scale"], var * s["y_scale"] ** 2

    def _basis_at(self, Xn, H_new):
        s = self._state
        if H_new is not None:
            Hn = np.asarray(H_new, dtype=float)
            if Hn.ndim == 1 and s["m_user"] == 1:
                Hn = Hn[:, None]
            if Hn.shape != (len(Xn), s["m_user"]):
                raise ValueError(f"H_new has shape {Hn.shape}, expected {(len(Xn), s['m_user'])}"
                                 " (the basis at X_new, same columns as the training basis)")
            return Hn
        if s["basis_fn"] is None:
            raise ValueError("the mean was given as a design matrix at the training points: "
                             "pass H_new (the basis at X_new), or include_mean=False for the "
                             "GP part alone")
        return _eval_basis(s["basis_fn"], Xn, s["m_user"])


def _cross_kernel(A, B, length, sf2):
    return sf2 * np.exp(-0.5 * cdist(A / length, B / length, "sqeuclidean"))


def _as_inputs(X, name):
    X = np.asarray(X, dtype=float)
    if X.ndim == 1:
        X = X[:, None]
    if X.ndim != 2 or not 1 <= X.shape[1] <= _MAX_INPUTS:
        raise ValueError(f"{name} has shape {np.shape(X)}, expected (n,) or (n, d) with "
                         f"d = 1 to {_MAX_INPUTS} input coordinates (3 machine coordinates, "
                         "3 more for the probe offset)")
    if not np.all(np.isfinite(X)):
        raise ValueError(f"{name} contains NaN or inf values: expected finite coordinates")
    return X


def _eval_basis(fn, X, m=None):
    H = np.asarray(fn(X), dtype=float)
    if H.ndim == 1:
        H = H[:, None]
    if H.ndim != 2 or H.shape[0] != len(X) or (m is not None and H.shape[1] != m):
        raise ValueError(f"the basis function returned shape {H.shape}, expected "
                         f"({len(X)}, {m if m is not None else 'm'})")
    return H


def _resolve_mean(mean, X):
    """(label, H in data units, names, callable or None)."""
    if isinstance(mean, str):
        H, names = polynomial_basis(X, mean)
        return mean, H, names, (lambda Z, _k=mean: polynomial_basis(Z, _k)[0])
    if callable(mean):
        H = _eval_basis(mean, X)
        return "callable", H, tuple(f"h{j + 1}" for j in range(H.shape[1])), mean
    H = np.asarray(mean, dtype=float)
    if H.ndim == 1:
        H = H[:, None]
    if H.ndim != 2 or H.shape[0] != len(X):
        raise ValueError(f"the mean design matrix has shape {np.shape(mean)}, expected "
                         f"({len(X)}, m): one row per training point")
    return "matrix", H, tuple(f"h{j + 1}" for j in range(H.shape[1])), None


class _Context:
    """Standardised data and basis shared by ``fit_gp`` and ``log_marginal_likelihood``."""


def _resolve_groups(groups, kernel, d):
    """Length-scale group of each input: one group (se_iso), one per input (se_ard), or
    as given (labels 0..G-1, every label used)."""
    if groups is None:
        return np.zeros(d, dtype=int) if kernel == "se_iso" else np.arange(d)
    g = np.asarray(groups)
    if g.shape != (d,) or not np.issubdtype(g.dtype, np.integer) or g.min() != 0 \
            or set(g.tolist()) != set(range(int(g.max()) + 1)):
        raise ValueError(f"groups = {list(np.atleast_1d(groups))}: expected one integer "
                         f"label per input ({d}), labels 0, 1, ... each used at least once")
    return g.astype(int)


def _resolve_noise_groups(noise_groups, n):
    g = np.asarray(noise_groups)
    if g.shape != (n,) or not np.issubdtype(g.dtype, np.integer) or g.min() != 0 \
            or set(g.tolist()) != set(range(int(g.max()) + 1)):
        raise ValueError(f"noise_groups has shape {g.shape} and labels "
                         f"{sorted(set(np.ravel(g).tolist()))[:8]}: expected one integer label "
                         f"per point ({n}), labels 0, 1, ... each used at least once")
    return g.astype(int)


def _prepare(X, y, mean, kernel, groups=None, noise_groups=None):
    X = _as_inputs(X, "X")
    y = np.asarray(y, dtype=float)
    if y.ndim == 2 and y.shape[1] == 1:
        y = y[:, 0]
    if y.ndim != 1 or len(y) != len(X):
        raise ValueError(f"y has shape {y.shape}, expected ({len(X)},): one value per row of X")
    if not np.all(np.isfinite(y)):
        raise ValueError("y contains NaN or inf values: expected finite observations "
                         "(drop or impute them before fitting)")
    if kernel not in KERNELS:
        raise ValueError(f"kernel {kernel!r} is unknown: expected one of {KERNELS}")
    n, d = X.shape
    groups = _resolve_groups(groups, kernel, d)
    label, H, names, basis_fn = _resolve_mean(mean, X)
    if not np.all(np.isfinite(H)):
        raise ValueError("the mean's basis contains NaN or inf values at the training points")
    m_user = H.shape[1]

    # basis: column-normalise, pivoted QR, drop what the data cannot determine
    if m_user:
        col = np.linalg.norm(H, axis=0)
        zero = col == 0
        col[zero] = 1.0
        Qf, Rf, piv = sla.qr(H / col, mode="economic", pivoting=True, check_finite=False)
        diag = np.abs(np.diag(Rf))
        r = int(np.sum(diag > _RANK_RTOL * diag[0])) if diag.size and diag[0] > 0 else 0
        keep = np.sort(piv[:r])
        # QR again on the kept columns in their original order (R upper triangular for them)
        Q, R = sla.qr(H[:, keep] / col[keep], mode="economic", check_finite=False)
        col_keep = col[keep]
        dropped = tuple(names[j] for j in range(m_user) if j not in set(keep.tolist()))
    else:
        keep = np.zeros(0, dtype=int)
        Q, R, col_keep, dropped = np.zeros((n, 0)), np.zeros((0, 0)), np.zeros(0), ()
    m = Q.shape[1]
    if n < m + 2:
        raise ValueError(f"{n} points for a mean with {m} determinable basis functions: "
                         f"expected at least {m + 2} (use a simpler mean or more points)")

    centre = X.mean(axis=0)
    extent = float(np.ptp(X, axis=0).max())
    if extent == 0:
        raise ValueError("all input points coincide: expected at least two distinct points")
    x_scale = extent
    Xs = (X - centre) / x_scale
    resid = y - Q @ (Q.T @ y) if m else y
    y_scale = float(np.sqrt(np.mean(resid**2)))
    y_rms = float(np.sqrt(np.mean(y**2)))
    if y_scale <= 1e-12 * y_rms or y_scale == 0:
        y_scale = y_rms or 1.0

    ctx = _Context()
    ctx.__dict__.update(n=n, d=d, m=m, m_user=m_user, label=label, names=names,
                        basis_fn=basis_fn, keep=keep, Q=Q, R=R, col_keep=col_keep,
                        dropped=dropped, extent=extent, x_scale=x_scale, y_scale=y_scale,
                        centre=centre, Xs=Xs, X=X, y=y, groups=groups, kernel=kernel)
    if noise_groups is not None:
        noise_groups = _resolve_noise_groups(noise_groups, n)
    ctx.prob = _Problem(Xs, y / y_scale, Q, groups, noise_groups)
    # log ML in data units = standardised value + offset (undo y scaling and basis scaling)
    logdetR = float(np.log(np.abs(np.diag(R))).sum()) if m else 0.0
    ctx.lml_offset = -(n - m) * np.log(y_scale) - logdetR - float(np.log(col_keep).sum())
    return ctx


_HYPER = ("length_scale_mm", "signal_sd_um", "noise_sd_um")


def _theta_from(hyper: dict, ctx, nl, theta):
    """Standardised log hyperparameters from readable ones (data units)."""
    theta = np.array(theta, dtype=float)
    nn = ctx.prob.n_noise
    units = {"signal_sd_um": ctx.y_scale, "noise_sd_um": ctx.y_scale}
    for k, v in hyper.items():
        if k not in _HYPER:
            raise ValueError(f"hyperparameter {k!r} is unknown: expected one of {_HYPER}")
        v = np.atleast_1d(np.asarray(v, dtype=float))
        if np.any(~np.isfinite(v)) or np.any(v <= 0):
            raise ValueError(f"{k} = {v}: expected positive finite values")
        if k == "length_scale_mm":
            if v.size not in (1, nl):
                raise ValueError(f"length_scale_mm has {v.size} values, expected 1 or {nl}")
            theta[:nl] = np.log(v / ctx.x_scale)
        elif k == "noise_sd_um":
            if v.size not in (1, nn):
                raise ValueError(f"noise_sd_um has {v.size} values, expected 1 or {nn} (one "
                                 "per noise group)")
            theta[nl + 1:] = np.log(v / units[k])
        else:
            if v.size != 1:
                raise ValueError(f"{k} has {v.size} values, expected 1")
            theta[nl] = np.log(v[0] / units[k])
    return theta


@single_blas_thread
def log_marginal_likelihood(X, y, hyperparameters: dict, *, mean="zero",
                            kernel: str = "se_iso", groups=None, noise_groups=None):
    """Log marginal likelihood and its gradient at given hyperparameters.

    Parameters
    ----------
    X, y, mean, kernel, groups, noise_groups
        As for ``fit_gp``.
    hyperparameters : dict
        ``length_scale_mm`` (one value, or one per length-scale group: per input for
        ``se_ard``), ``signal_sd_um``, ``noise_sd_um`` (one value, or one per noise group),
        ``noise_sd_um``, all required.

    Returns
    -------
    lml : float
        As ``GPResult.log_marginal_likelihood`` (R&W eq. 2.30, or eq. 2.45 without the
        divergent terms with a basis).
    grad : ndarray (p,)
        ∂ lml / ∂ log θ for θ = (length scale(s), σ_f, σ_n), analytic (R&W eq. 5.9 with the
        projected matrix P of §2.7). The same in any units, since it is per log unit.
    """
    missing = [k for k in _HYPER if k not in hyperparameters]
    if missing:
        raise ValueError(f"hyperparameters lack {missing}: expected all of {_HYPER}")
    ctx = _prepare(X, y, mean, kernel, groups, noise_groups)
    nl = ctx.prob.n_length()
    theta = _theta_from(hyperparameters, ctx, nl, np.zeros(nl + 1 + ctx.prob.n_noise))
    val, grad = ctx.prob.objective(theta)
    if val >= 1e24:
        raise ValueError("the covariance matrix is not positive definite even with jitter at "
                         "these hyperparameters (increase noise_sd_um)")
    return float(-val + ctx.lml_offset), -grad


_BOUND_FACTORS = {"length": (1e-3, 1e3), "signal": (1e-3, 1e2), "noise": (1e-4, 1e1)}


@single_blas_thread
def fit_gp(X, y, *, mean="zero", kernel: str = "se_iso", restarts: int = 3, seed=0,
           bounds: dict | None = None, initial: dict | None = None,
           optimize: bool = True, groups=None, discrete_groups=(),
           noise_groups=None) -> GPResult:
    """Fit a GP regression model by maximising the marginal likelihood.

    Parameters
    ----------
    X : array_like (n,) or (n, d), d = 1 to 6
        Inputs (mm for CMM coordinates; 3 machine coordinates and, optionally, the 3
        components of the probe offset).
    y : array_like (n,)
        Observations (µm for CMM errors).
    mean : str, callable or array_like (n, m)
        Parametric mean as explicit basis functions whose coefficients are marginalised under
        a vague prior (R&W §2.7): ``"zero"`` (thesis appendix 3 part T2), ``"constant"``,
        ``"linear"``, ``"quadratic"`` (full quadratic in all inputs), ``"thesis_quadratic"``
        (thesis eq. 5.11, ``meanMylinear_2D``: 1, x1, x1²), a callable ``h(X) -> (n, m)``, or
        the design matrix at the training points (e.g. a kinematic model's Jacobian; then
        ``predict`` needs ``H_new``). Polynomials are evaluated in the units of X.
    kernel : {"se_iso", "se_ard"}
        Squared-exponential covariance (thesis eq. 5.1, covSEiso; or covSEard).
    restarts : int
        Random starts in addition to the default start (as scikit-learn's
        ``n_restarts_optimizer``), a Latin hypercube over the whole bounds in log
        hyperparameters (``scipy.stats.qmc.LatinHypercube`` with
        ``np.random.default_rng(seed)``), so that each hyperparameter's whole range is
        searched evenly.
    seed : int or numpy Generator
    bounds : dict, optional
        Override bounds in data units, keys ``length_scale_mm``, ``signal_sd_um``,
        ``noise_sd_um``, values ``(low, high)``. Defaults: length scale 1e-3..1e3 × the
        input extent (largest coordinate range), σ_f 1e-3..1e2 × and σ_n 1e-4..10 × the
        RMS of y after removing the least-squares basis fit.
    initial : dict, optional
        Starting hyperparameters in data units (same keys); with ``optimize=False`` they
        are used as they are.
    optimize : bool
        ``False`` evaluates the model at ``initial`` (status ``"fixed"``).
    groups : sequence of int, optional
        Length-scale group of each input column: the inputs of one group share a length
        scale, k = σ_f² exp(-½ Σ_g |x_g - x'_g|² / l_g²) (a product of SE kernels, one per
        group). Default: one group (``se_iso``) or one per input (``se_ard``); given, it
        overrides ``kernel``'s. ``(0, 0, 0, 1, 1, 1)`` gives the ram position and the probe
        offset one length scale each.
    discrete_groups : sequence of int
        Groups whose inputs take a few discrete values (the probe offset). A length scale
        of such a group at either bound is a legitimate limit (short: the values are
        independent; long: the input does not matter), not a degenerate fit.
    noise_groups : array_like of int (n,), optional
        Noise group of each point (labels 0, 1, ...): one noise standard deviation per
        group, e.g. per stylus, whose repeatabilities differ (K_y = K + diag(σ_n,g(i)²)).
        Default: one noise level for all points.

    Returns
    -------
    GPResult
        Never raises on non-convergence or a degenerate optimum: see ``status``,
        ``degenerate_reason`` and ``alternative``.

    Raises
    ------
    ValueError
        Bad shapes, non-finite values, unknown mean or kernel, or too few points.

    Notes
    -----
    A fit is *degenerate* (status ``"degenerate"``) when the likelihood's best optimum is
    (a) collapsed: no two distinct training points (farther apart than 1e-3 of the input
    extent) lie within two length scales of each other, so neighbours are correlated by
    less than exp(-2) = 0.14 and the GP is close to white noise (for ``se_iso``: the
    length scale is below half the data's smallest spacing; the spacing itself would
    flag working fits such as thesis appendix 3's, 87 mm on a 100 mm pitch), (b) a length
    scale of a continuous group at its lower bound, or every continuous length scale at its
    upper bound (the data show no correlation length; one ARD input at its upper bound
    only says that input does not matter), or (c) σ_f at its lower bound (no signal). The
    next-best optimum is then offered as ``alternative``: the best start that is not
    degenerate, or else the optimum with the continuous length scales between half the
    smallest spacing and 10 × the input extent (itself flagged if still degenerate).

    For n > 600 the starts run first on a random subset of 300 points (same
    standardisation, drawn with the same generator), and each distinct optimum reached
    there is polished on all the points (BFGS from the subset's Hessian, L-BFGS-B at a
    bound): the optimisation then costs a few evaluations on all the points instead of
    about twenty per start, and every basin the starts found is still polished.
    """
    ctx = _prepare(X, y, mean, kernel, groups, noise_groups)
    prob = ctx.prob
    nl, nn = prob.n_length(), prob.n_noise
    discrete = {int(g) for g in np.atleast_1d(discrete_groups)}
    if not discrete <= set(range(nl)):
        raise ValueError(f"discrete_groups = {sorted(discrete)}: expected labels among the "
                         f"length-scale groups 0..{nl - 1}")
    x_scale, y_scale, extent = ctx.x_scale, ctx.y_scale, ctx.extent
    bnd = {"length_scale_mm": tuple(f * extent for f in _BOUND_FACTORS["length"]),
           "signal_sd_um": tuple(f * y_scale for f in _BOUND_FACTORS["signal"]),
           "noise_sd_um": tuple(f * y_scale for f in _BOUND_FACTORS["noise"])}
    for k, v in (bounds or {}).items():
        if k not in bnd:
            raise ValueError(f"bounds key {k!r} is unknown: expected one of {tuple(bnd)}")
        lo, hi = (float(t) for t in v)
        if not 0 < lo <= hi:
            raise ValueError(f"bounds[{k!r}] = {v}: expected 0 < low <= high")
        bnd[k] = (lo, hi)
    lb = np.array([np.log(bnd["length_scale_mm"][0] / x_scale)] * nl
                  + [np.log(bnd["signal_sd_um"][0] / y_scale)]
                  + [np.log(bnd["noise_sd_um"][0] / y_scale)] * nn)
    ub = np.array([np.log(bnd["length_scale_mm"][1] / x_scale)] * nl
                  + [np.log(bnd["signal_sd_um"][1] / y_scale)]
                  + [np.log(bnd["noise_sd_um"][1] / y_scale)] * nn)

    # default start: length 0.3 extent, σ_f = RMS, σ_n = 0.3 RMS (standardised units)
    theta0 = _theta_from(initial or {}, ctx, nl,
                         np.array([np.log(0.3)] * nl + [0.0] + [np.log(0.3)] * nn))
    if optimize:
        theta0 = np.clip(theta0, lb, ub)

    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    starts = [theta0]
    k = max(int(restarts), 0) if optimize else 0
    if k:
        # a Latin hypercube over the whole (log) bounds: every hyperparameter's range is
        # covered evenly by the starts, the short and long length scales included (a box
        # around the default start missed scikit-learn's optimum in 1 of 9 bench fits)
        u = qmc.LatinHypercube(d=len(lb), rng=rng).random(k)
        starts += list(lb + u * (ub - lb))
    # large n: the starts first run on a random subset of the points, and only the
    # distinct optima found there are polished on all of them (``_optimise``)
    sub = None
    if optimize and prob.n > 2 * _PREFIT_POINTS:
        sub = prob.subset(np.sort(rng.choice(prob.n, _PREFIT_POINTS, replace=False)))

    spacing_s, far = _spacing(prob)
    cont = [g for g in range(nl) if g not in discrete]

    def degeneracy(theta, lo, hi):
        return _degeneracy(prob, theta, lo, hi, far, spacing_s, x_scale, cont)

    def optimise(lo, hi, points):
        return _optimise(prob, sub, lo, hi, points)

    def outcome(runs):
        ok = [r for r in runs if float(r.fun) < 1e24]
        if not ok:
            return theta0, "not_converged", ["the likelihood could not be evaluated at any "
                                             "start"]
        b = min(ok, key=lambda r: float(r.fun))
        m0 = b.message.decode() if isinstance(b.message, bytes) else str(b.message)
        return b.x, "converged" if b.success else "not_converged", [m0]

    if not optimize:
        res = _result(ctx, theta0, "fixed", ["hyperparameters fixed at the values given"],
                      lb, ub, bnd, (), optimized=False)
        return replace(res, **degeneracy(theta0, lb, ub))
    runs = optimise(lb, ub, starts)
    start_lml = tuple(-float(r.fun) if float(r.fun) < 1e24 else np.nan for r in runs)
    best, status, msg = outcome(runs)
    deg = degeneracy(best, lb, ub)
    if not deg["degenerate"]:
        return replace(_result(ctx, best, status, msg, lb, ub, bnd, start_lml), **deg)

    # degenerate: the next-best optimum, among the starts or with the length scales kept
    # between the smallest spacing and _ALT_MAX_LENGTH × the extent
    order = sorted((r for r in runs if float(r.fun) < 1e24), key=lambda r: float(r.fun))
    alt_runs = [r for r in order if not degeneracy(r.x, lb, ub)["degenerate"]][:1]
    if alt_runs and not alt_runs[0].get("polished", True):
        alt_runs = [_minimize(prob, lb, ub, alt_runs[0].x)]
    alt_lb, alt_ub, how = lb, ub, "the best start that is not degenerate"
    if not alt_runs and np.isfinite(spacing_s):
        alt_lb, alt_ub = lb.copy(), ub.copy()
        for g in cont:
            alt_lb[g] = max(lb[g], np.log(spacing_s / _COLLAPSE_SPACINGS * (1 + 1e-6)))
            alt_ub[g] = max(alt_lb[g], min(ub[g], np.log(_ALT_MAX_LENGTH)))
        alt_runs = optimise(alt_lb, alt_ub, starts)
        how = (f"length scale(s) kept between half the smallest spacing "
               f"{spacing_s * x_scale / _COLLAPSE_SPACINGS:.3g} mm and {_ALT_MAX_LENGTH:g} × the input extent "
               f"({np.exp(alt_ub[cont[0]]) * x_scale:.3g} mm)" if cont else "")
    alternative = None
    if alt_runs:
        a_theta, a_status, a_msg = outcome(alt_runs)
        alternative = _result(ctx, a_theta, a_status, [f"next-best optimum ({how})"] + a_msg,
                              alt_lb, alt_ub, bnd, ())
        alternative = replace(alternative, **degeneracy(a_theta, lb, ub))
    res = _result(ctx, best, "degenerate", [f"degenerate fit: {deg['degenerate_reason']}"]
                  + msg, lb, ub, bnd, start_lml)
    return replace(res, alternative=alternative, **deg)


def _minimize(prob, lo, hi, t0, ftol=_FTOL):
    return minimize(prob.objective, np.clip(t0, lo, hi), jac=True, method="L-BFGS-B",
                    bounds=list(zip(lo, hi, strict=True)), options={"ftol": ftol})


def _optimise(prob, sub, lo, hi, points):
    """One optimisation per start; the result of each, in the order of ``points``.

    Without a subset problem ``sub``: L-BFGS-B from each start on all the points.

    With one, every start runs on the subset first (a likelihood evaluation on 300 points
    costs 1/30 of one on 1000), the optima it reaches are grouped (log hyperparameters
    within ``_SAME_OPTIMUM`` of each other are one optimum), and each distinct optimum is
    polished on all the points; a start's result is the polished optimum of its group, so
    every basin the starts found is still searched on all the data. An optimum inside the
    bounds is polished by BFGS started with the inverse of the subset's Hessian there
    (finite differences of its analytic gradient, × √(n/m)): its first step is then close
    to Newton's, where L-BFGS-B's identity start spent most of its 12 to 27 evaluations in
    line searches (8 with BFGS on the bench data). The factor: the noise curvature grows
    like n/m but the length scale's and σ_f's more slowly (a fixed domain filled in);
    n/m overshot them and made BFGS's line search fail. An optimum at a bound, or a BFGS
    polish that leaves the bounds or fails, gets L-BFGS-B from where it stands.

    Optima more than ``_PRUNE_NATS`` below the best on the subset (a likelihood ratio
    e^-10: collapsed or signal-free optima the whole-bounds starts fall into) are not
    polished; their result is the log ML on all points at the subset optimum, marked
    ``polished=False`` (``fit_gp`` polishes one if it is needed as the alternative).
    """
    if sub is None:
        return [_minimize(prob, lo, hi, t0) for t0 in points]
    pre = [_minimize(sub, lo, hi, t0, _FTOL_PREFIT) for t0 in points]
    reps, group = [], []
    for r in pre:
        ok = float(r.fun) < 1e24
        j = next((i for i, q in enumerate(reps) if ok
                  and np.max(np.abs(q.x - r.x)) < _SAME_OPTIMUM), None)
        if j is None:
            reps.append(r)
            j = len(reps) - 1
        group.append(j)
    best = min(float(q.fun) for q in reps)
    polished = [_polish(prob, sub, lo, hi, q) if float(q.fun) <= best + _PRUNE_NATS
                else _unpolished(prob, q) for q in reps]
    return [polished[j] for j in group]


def _unpolished(prob, pre):
    """A subset optimum far below the best one, evaluated on all points, not optimised."""
    f, g = prob.objective(pre.x)
    return OptimizeResult(x=pre.x, fun=f, jac=g, success=False, status=-1, polished=False,
                          message=f"not polished: {_PRUNE_NATS:g} nats or more below the "
                                  "best optimum on the subset")


def _polish(prob, sub, lo, hi, pre):
    """The optimum on all the points near the subset optimum ``pre`` (see ``_optimise``)."""
    t = pre.x
    inside = float(pre.fun) < 1e24 and np.all(t - lo > _INTERIOR) and np.all(hi - t > _INTERIOR)
    H = _fd_hessian(sub, t) * np.sqrt(prob.n / sub.n) if inside else None
    if H is not None:
        lam, V = np.linalg.eigh(H)
        if lam.min() > 1e-6 * lam.max():  # a clear minimum on the subset
            Hinv = (V / lam) @ V.T
            res = minimize(prob.objective, t, jac=True, method="BFGS",
                           options={"hess_inv0": (Hinv + Hinv.T) / 2, "gtol": _GTOL,
                                    "maxiter": _BFGS_MAXITER})
            # BFGS's "precision loss": the line search found no decrease along the
            # quasi-Newton direction, i.e. the optimum to round-off (at n = 1000 the
            # log ML's round-off, ~1e-10, stalls gradients of ~1e-5 on the way down)
            stalled = res.status == 2 and np.max(np.abs(res.jac)) < _GTOL_STALLED
            if (res.success or stalled) and np.all(res.x >= lo) and np.all(res.x <= hi):
                if stalled:
                    res.success = True
                    res.message = ("BFGS: no further increase of the log ML in floating "
                                   f"point (gradient {np.max(np.abs(res.jac)):.1e})")
                return res
            if float(res.fun) < 1e24:
                t = res.x  # L-BFGS-B carries on from where BFGS stopped (clipped)
    return _minimize(prob, lo, hi, t)


def _fd_hessian(prob, theta, h=1e-4):
    """Hessian of ``prob.objective`` at ``theta``: central differences of its gradient."""
    p = len(theta)
    H = np.empty((p, p))
    for j in range(p):
        e = np.zeros(p)
        e[j] = h
        H[:, j] = (prob.objective(theta + e)[1] - prob.objective(theta - e)[1]) / (2 * h)
    return (H + H.T) / 2


def _spacing(prob):
    """Smallest distance between distinct training locations (standardised units; points
    closer than ``_SAME_POINT`` are one location) and the mask of distinct pairs."""
    d2 = prob.D2.sum(axis=0)
    far = d2 > _SAME_POINT**2
    return (float(np.sqrt(d2[far].min())) if far.any() else float("nan")), far


def _degeneracy(prob, theta, lb, ub, far, spacing_s, x_scale, cont) -> dict:
    """``degenerate``, ``degenerate_reason`` and ``smallest_spacing_mm`` at ``theta``."""
    nl = prob.n_length()
    reasons = []
    lengths = np.exp(theta[:nl]) * x_scale
    spacing_mm = spacing_s * x_scale
    if far.any():
        nearest = float(np.sqrt(prob.scaled_d2(theta[:nl])[far].min()))
        if nearest > _COLLAPSE_SPACINGS * (1 + 1e-6):
            if nl == 1:
                reasons.append(f"the length scale {lengths[0]:.3g} mm is below half the "
                               f"smallest spacing {spacing_mm:.3g} mm between distinct points")
            else:
                reasons.append(f"the length scales {', '.join(f'{v:.3g}' for v in lengths)} "
                               "mm leave no two distinct points within two length scales of "
                               f"each other (smallest spacing {spacing_mm:.3g} mm)")
            reasons[-1] += (f": neighbouring points are correlated by less than "
                            f"{np.exp(-0.5 * _COLLAPSE_SPACINGS**2):.2f}, the GP is (close "
                            "to) white noise and predicts nothing between them")
    low = [g for g in cont if ub[g] > lb[g] and theta[g] - lb[g] < 1e-6]
    high = [g for g in cont if ub[g] > lb[g] and ub[g] - theta[g] < 1e-6]
    if low:
        reasons.append("length scale " + ", ".join(f"{lengths[g]:.3g}" for g in low)
                       + " mm at its lower bound")
    if cont and len(high) == len(cont):
        reasons.append("length scale " + ", ".join(f"{lengths[g]:.3g}" for g in high)
                       + " mm at its upper bound: the data show no correlation length")
    if ub[nl] > lb[nl] and theta[nl] - lb[nl] < 1e-6:
        reasons.append("signal sd at its lower bound: the GP carries no signal")
    return {"degenerate": bool(reasons), "degenerate_reason": "; ".join(reasons),
            "smallest_spacing_mm": float(spacing_mm)}


def _result(ctx, best, status, msg, lb, ub, bnd, start_lml, *, optimized=True) -> GPResult:
    """The GPResult at the log hyperparameters ``best`` (standardised units)."""
    prob = ctx.prob
    n, d, m, m_user, nl = ctx.n, ctx.d, ctx.m, ctx.m_user, prob.n_length()
    x_scale, y_scale, y = ctx.x_scale, ctx.y_scale, ctx.y
    R, col_keep = ctx.R, ctx.col_keep
    units = {"length_scale_mm": x_scale, "signal_sd_um": y_scale, "noise_sd_um": y_scale}
    nn = prob.n_noise
    st = prob.factor(best)
    if st is None:
        raise ValueError("the covariance matrix is not positive definite even with jitter at "
                         "the given hyperparameters (increase noise_sd_um)")
    msg = list(msg)

    # readable hyperparameters and bound notes
    length = np.exp(best[:nl]) * x_scale
    sf, sn = np.exp(best[nl]) * y_scale, np.exp(best[nl + 1:]) * y_scale
    # one noise level: that; several: the RMS over the points
    sn_all = float(sn[0]) if nn == 1 else float(np.sqrt(np.mean(sn[prob.noise_groups] ** 2)))
    if optimized:
        for name, i in [("length_scale_mm", j) for j in range(nl)] + [
                ("signal_sd_um", nl)] + [("noise_sd_um", nl + 1 + j) for j in range(nn)]:
            if ub[i] - lb[i] > 0 and (best[i] - lb[i] < 1e-6 or ub[i] - best[i] < 1e-6):
                side = "lower" if best[i] - lb[i] < 1e-6 else "upper"
                msg.append(f"{name} at its {side} bound {np.exp((lb if side == 'lower' else ub)[i]) * units[name]:.3g}")
    if st["jitter"]:
        msg.append(f"jitter {st['jitter'] * y_scale**2:.3g} added to the diagonal of K_y "
                   "(Cholesky factorisation failed without it)")

    lml = st["lml"] + ctx.lml_offset

    # coefficients in data units: h_keptᵀβ = qᵀβ_Q with q = (h/col) R⁻¹
    if m:
        Rinv = sla.solve_triangular(R, np.eye(m), check_finite=False)
        T = Rinv / col_keep[:, None]  # β_user = T β_Q
        Ainv_Q = sla.cho_solve((st["LA"], True), np.eye(m), check_finite=False)
        coef = T @ st["beta"] * y_scale
        coef_cov = T @ Ainv_Q @ T.T * y_scale**2
    else:
        coef, coef_cov = np.zeros(0), np.zeros((0, 0))

    # LOO in closed form (R&W eq. 5.12 with P): μ_i = y_i - [Py]_i/P_ii, σ_i² = 1/P_ii
    T = _kinv_lower(st["L"])
    if T is None:
        raise ValueError("the covariance matrix is singular at the given hyperparameters "
                         "(increase noise_sd_um)")
    pdiag = prob.p_diag(st, T)
    ok = pdiag > 1e-10 * np.max(np.abs(pdiag))
    with np.errstate(divide="ignore", invalid="ignore"):
        loo_mu = np.where(ok, prob.ys - st["alpha"] / pdiag, np.nan)
        loo_var = np.where(ok, 1.0 / pdiag, np.inf)
    loo_mu_u = loo_mu * y_scale
    loo_sd_u = np.sqrt(loo_var) * y_scale
    loo_res = (y - loo_mu_u)[ok]
    loo_rms = float(np.sqrt(np.mean(loo_res**2))) if ok.any() else float("nan")
    loo_lp = float(np.sum(-0.5 * np.log(loo_var[ok] * y_scale**2)
                          - loo_res**2 / (2 * loo_var[ok] * y_scale**2) - 0.5 * _LOG2PI))
    with np.errstate(divide="ignore", invalid="ignore"):
        loo_z = np.where(ok, (y - loo_mu_u) / loo_sd_u, np.nan)
    if not ok.all():
        msg.append(f"{int((~ok).sum())} point(s) without a leave-one-out prediction "
                   "(a basis coefficient rests on them alone)")

    state = {"Xs": ctx.Xs, "centre": ctx.centre, "x_scale": x_scale, "y_scale": y_scale,
             "length_s": np.exp(best[:nl])[prob.groups],
             "sf2": st["sf2"], "L": st["L"], "alpha": st["alpha"], "beta": st["beta"],
             "m": m, "m_user": m_user, "keep": ctx.keep, "col_norm": col_keep, "R": R,
             "KiQ": st.get("KiQ"), "LA": st.get("LA"), "basis_fn": ctx.basis_fn}
    return GPResult(
        mean=ctx.label, kernel=ctx.kernel, n=n, input_dim=d,
        length_scale_mm=tuple(float(v) for v in length),
        signal_sd_um=float(sf), noise_sd_um=sn_all, log_marginal_likelihood=float(lml),
        noise_sd_by_group_um=tuple(float(v) for v in sn),
        mean_terms=tuple(ctx.names[j] for j in ctx.keep), basis_dropped=ctx.dropped,
        mean_coefficients=coef, mean_coefficients_cov=coef_cov,
        loo_mean_um=loo_mu_u, loo_sd_um=loo_sd_u, loo_rms_um=loo_rms,
        loo_log_predictive=loo_lp, loo_z=loo_z, status=status,
        success=status in ("converged", "fixed"),
        message="; ".join(msg), n_evaluations=prob.n_eval,
        start_log_ml=tuple(float(v + ctx.lml_offset) for v in start_lml),
        jitter_um2=float(st["jitter"] * y_scale**2), n_jitter_events=prob.n_jitter,
        bounds=bnd, groups=tuple(int(g) for g in prob.groups), _state=state)

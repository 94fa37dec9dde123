"""A fitted GP: :class:`GPResult`, its predictions and leave-one-out diagnostics.

:class:`GPResult` holds the hyperparameters in data units, the marginal likelihood, the
posterior of the basis coefficients (R&W eq. 2.42), the closed-form leave-one-out
predictions (R&W §5.4.2, eq. 5.11-5.12, with ``P`` in place of ``K⁻¹`` when a basis is
marginalised) and the fit's status; :meth:`GPResult.predict` gives the predictive mean
and variance of the latent function (R&W eq. 2.23-2.24, 2.41-2.42). :func:`_result`
builds it from the optimiser's log hyperparameters. References: Rasmussen & Williams
(2006), *Gaussian Processes for Machine Learning* (R&W); thesis chapter 5 and appendix 3.

See Also
--------
cmm_core.gp : ``fit_gp`` (re-exports :class:`GPResult`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
from numpy.typing import ArrayLike
from scipy.spatial.distance import cdist
from scipy.stats import norm

from .basis import MEANS, _as_inputs, _eval_basis
from .likelihood import _LOG2PI, _kinv_lower

_CHUNK = 4096  # prediction points per block


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

    def predict(self, X_new: ArrayLike, H_new: ArrayLike | None = None, *,
                include_mean: bool = True) -> tuple[np.ndarray, np.ndarray]:
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

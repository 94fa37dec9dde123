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

The code is split by concept; this module holds the two entry points, :func:`fit_gp` and
:func:`log_marginal_likelihood`, and re-exports the public names of the others:

- ``cmm_core.gp.basis``: inputs and the mean's basis functions (``polynomial_basis``,
  ``MEANS``; thesis eq. 5.11, R&W §2.7);
- ``cmm_core.gp.likelihood``: covariance, log marginal likelihood and gradient (``KERNELS``;
  thesis eq. 5.1, R&W eq. 2.30, 2.45, 5.9);
- ``cmm_core.gp.prepare``: checks, standardisation, basis reduction, hyperparameters in
  standardised units;
- ``cmm_core.gp.optimise``: L-BFGS-B over the starts, subset prefit and polish;
- ``cmm_core.gp.degeneracy``: collapsed or bounded optima (see :func:`fit_gp`, Notes);
- ``cmm_core.gp.result``: ``GPResult``, prediction (R&W eq. 2.41-2.42) and closed-form
  leave-one-out (R&W eq. 5.12).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import qmc

from .._blas import single_blas_thread
from .degeneracy import _COLLAPSE_SPACINGS, _degeneracy, _spacing
from .optimise import _minimize, _optimise
from .prepare import _HYPER, _prepare, _theta_from
from .result import GPResult, _result

__all__ = ["fit_gp", "log_marginal_likelihood"]

_ALT_MAX_LENGTH = 10.0  # next-best optimum: length scales up to this times the extent
# fit_gp draws the subset (with the starts' generator); gp.optimise only runs on it
_PREFIT_POINTS = 300  # subset the restarts run on first when n > 2 × this (``_optimise``)


@single_blas_thread
def log_marginal_likelihood(X: ArrayLike, y: ArrayLike, hyperparameters: dict, *,
                            mean: str | ArrayLike = "zero", kernel: str = "se_iso",
                            groups: ArrayLike | None = None,
                            noise_groups: ArrayLike | None = None
                            ) -> tuple[float, dict]:
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
def fit_gp(X: ArrayLike, y: ArrayLike, *, mean: str | ArrayLike = "zero",
           kernel: str = "se_iso", restarts: int = 3, seed: int | None = 0,
           bounds: dict | None = None, initial: dict | None = None,
           optimize: bool = True, groups: ArrayLike | None = None,
           discrete_groups: tuple = (), noise_groups: ArrayLike | None = None) -> GPResult:
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

"""How well a candidate measurement separates rival models (issue 29): two, or the
three or more effects of an alias set.

How a candidate is scored. Each rival in turn is the truth at the size it is fitted to on
the current data (``θ_A``, the parameters A has and B has not). The noise-free augmented
design (``J``, the weighted Jacobian at the nominal linearisation of the model holding both
rivals; the current readings and the candidate's simulated ones) gives the mean misfit the
other rival leaves:

    λ_A = ‖(I − P_B) J_A θ_A‖²,

``P_B`` the projector on B's columns (baseline, B, the new placement's pose), ``J_A`` A's
own columns, weighted by 1/σ. That is the χ² the fit of B leaves on noise-free data from A
(Δχ² of the noise-free augmented design), and the non-centrality of the diagnosis's nested
F-test "A is still needed once B is in" (``verdict._encompassing``): F(k_A, ν, λ_A) with k_A
the rank A adds to B, ν the residual dof of the model with both (Scheffé 1959, §2.8; the
linear-model power of ``detect.py``). The power to separate is

    power_A = P(F(k_A, ν, λ_A) > F⁻¹(1 − α; k_A, ν)),

α the level the diagnosis judges the pair at: its nested tests judge both directions at
the level of the candidate it ranks first (``verdict._encompassing``), so both powers of
two model tokens are taken at the first rival's level (its share of the family-wise rate,
weighted Bonferroni), which is that candidate's when the rivals are the diagnosis's
(:func:`rivals_of`, :func:`open_pairs`; for rivals given in the other order, an
approximation); a placement-scale rival at the placement-scale test's level.

The fitted ``θ̂_A`` carries noise, and the more so the worse the current data separate the
rivals (that is why a proposal is asked for): ``E‖M θ̂‖² = ‖M θ‖² + tr(M C Mᵀ)`` for an
unbiased ``θ̂`` of covariance ``C`` (``M = (I − P_B) J_A``), so λ_A is taken as
``‖M θ̂_A‖² − tr(M C_A Mᵀ)`` (at least 0): at exactly the fitted size it would overstate
the separation (by Δχ² ≈ 15 of 45 for a probe offset against drift on the 80 mm layout,
bench/proposals.py); the size itself is kept as ``delta_chi2_fitted``.

The predicted power is an expectation over the size's uncertainty, not the power at one
size (:func:`_expected_power`). The noise-corrected λ is unbiased, but the power at it is
not the expected power: when the current data fit the size within its noise, λ is often
clipped at 0 and the power there is the level, although the truth's λ is, as often, well
above it (drift rates fitted within ±1.3-3.5 µm/h against a 1 µm/h spread: 65 % predicted
against 93 % measured, docs/proposals.md "Validation"). So ``power_A`` is the assurance
of the nested test (O'Hagan & Stevens 2001; Spiegelhalter, Abrams & Myles 2004 §6.5):
``E[P(F(k_A, ν, λ_A(θ)) > F⁻¹(1 − α))]`` over the current data's posterior of A's size,
with ``λ_A(θ) = θᵀ Mᵀ M θ``. The posterior is that of a stated prior
(:func:`_hierarchical_assurance`): A's own parameters drawn of mean 0 from one spread
``τ`` of A's, ``θ ~ N(0, τ² I)``, ``τ`` uniform (the normal/normal hierarchical model,
Efron & Morris 1973, Carlin & Louis 2000 §3.3-3.4; Gelman 2006), so that a size the
current data hardly see is shrunk towards 0 instead of taken at the noise's size (the
flat prior's ``N(θ̂_A, C_A)``, :func:`_expected_power`, used before and still for a
rival of one free parameter). Where the data determine the size well it is the flat
prior's result; with ``C_A → 0`` the power at the fitted size.

Three rivals or more (an alias set of the diagnosis, ``rivals.rival_pairs``): deciding
means separating each pair. With ``A`` true its power is the smallest, over the other
rivals ``O``, of the power of "A still needed once O is in" (the hardest pairwise
separation; its λ, dof and size are that test's), and the candidate decides the set with
the smallest of these over the truths: the minimum pairwise power (:func:`_score_on`).
That is the chance of the hardest of the tests the diagnosis runs, an upper bound of the
chance that all of them single out the true one at once (Bonferroni's lower bound of that
is ``1 − Σ_O (1 − power_{A|O})``); for two rivals it is the pair's power.

A repeat (:func:`repeat_candidates`: a stylus measured again on a placement already
measured, appended to the current placement or in the next session) adds rows to that
placement, not a new one: it is scored on the design of the whole augmented data set
(:func:`_score_repeats`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy import integrate, stats
from scipy.stats import qmc

from ...io import Dataset
from ...model import Problem, select, weighted_residual
from .append import append_measurement
from .candidates import NextMeasurement
from .rivals import PLACEMENT_SCALE, PSEUDO, RivalFits, _basis, scale_columns

_ASSURANCE_DRAWS = 256
"""Points of the quasi-Monte Carlo of the expected power (:func:`_expected_power`), each
taken with its mirror image: scrambled Sobol' normals (a power of two, as Sobol' points
balance best). On the tests' tiny case the expectation is within 0.2 points of a
400 000-draw reference (0.19 and 0.08); 200 pseudo-random mirrored pairs missed it by up
to 2.4 points."""

_NULL_RTOL = 1e-9
"""Eigenvalue of a fitted size's covariance, relative to its largest, below which the
direction is taken as having no spread (:func:`_hierarchical_assurance`)."""

_TAU2_GRID = 400
"""Log-spaced points of the grid of the posterior of τ² (:func:`_tau2_quantiles`)."""

_ASSURANCE_SEED = 2001
"""Seed of the Sobol' scrambling (fixed: the same design gives the same score)."""


@dataclass(frozen=True)
class _Design:
    """Weighted Jacobian at the nominal linearisation of the model holding every rival,
    its column labels, and which labels each rival's own model has."""

    J: np.ndarray
    labels: list
    has: dict


def _both(rf: RivalFits):
    """The model holding every rival (the first's with each other token added; a
    pseudo-rival adds no token)."""
    spec = rf.specs[rf.rivals[0]]
    for r in rf.rivals[1:]:
        if r not in PSEUDO:
            spec = spec.with_token(r)
    return spec


def _design(obs, rf: RivalFits) -> _Design:
    f = rf.fits[rf.rivals[0]]
    prob = Problem(obs, _both(rf), f.plate)
    J = weighted_residual(prob, prob.initial_state(), f.sigma_um, True)[2].toarray()
    labels = list(prob.layout.labels)
    has = {r: set(Problem(obs, rf.specs[r], f.plate).layout.labels) for r in rf.rivals}
    if PLACEMENT_SCALE in rf.rivals:
        S, lab_s = scale_columns(obs, f.sigma_um, J.shape[0])
        J = np.hstack([J, S])
        labels += lab_s
        has[PLACEMENT_SCALE] |= set(lab_s)
    return _Design(J, labels, has)


def _stack(d1: _Design, d2: _Design) -> _Design:
    """The design of both observation sets: rows stacked, columns matched by label (a
    parameter one set does not have has zero columns there)."""
    labels = list(dict.fromkeys(d1.labels + d2.labels))
    col = {lab: i for i, lab in enumerate(labels)}
    J = np.zeros((d1.J.shape[0] + d2.J.shape[0], len(labels)))
    J[:d1.J.shape[0], [col[lab] for lab in d1.labels]] = d1.J
    J[d1.J.shape[0]:, [col[lab] for lab in d2.labels]] = d2.J
    return _Design(J, labels, {r: d1.has[r] | d2.has[r] for r in d1.has})


def _rows(des: _Design, keep: np.ndarray) -> _Design:
    """The design of some observations only (``keep``: one flag per observation; three
    weighted rows each, first), without the columns that are empty there. Rows after the
    observations' (a plate prior's, three per certificate ball) are left out: the current
    data's design holds them once."""
    J = des.J[:3 * len(keep)][np.repeat(keep, 3)]
    used = np.abs(J).sum(axis=0) > 0
    return _Design(J[:, used], [lab for lab, u in zip(des.labels, used, strict=True) if u],
                   des.has)


def _instrument_design(obs, now: _Design, rf: RivalFits, inst) -> _Design:
    """The design rows of one instrument: the rows it appends to the current data's."""
    f = rf.fits[rf.rivals[0]]
    prob = Problem(replace(obs, instruments=(inst,)), _both(rf), f.plate)
    J = weighted_residual(prob, prob.initial_state(), f.sigma_um, True)[2].toarray()
    return _Design(J[now.J.shape[0]:], list(prob.layout.labels), now.has)


def _separation(des: _Design, truth: str, other: str, theta: dict, *, rank_rtol: float,
                level: float, spread: tuple | None = None) -> tuple:
    """(λ, k, ν, power, λ at the fitted size, parameter count, power at λ) of the nested
    test "``truth`` is needed once ``other`` is in" on the noise-free design with ``truth``
    true at ``theta`` (module docstring). ``spread``: ``(labels, covariance)`` of
    ``theta``'s fit; λ is then the expected-size estimate ``‖M θ‖² − tr(M C Mᵀ)`` (at
    least 0), which takes out what the fitted size owes to noise, and the power is the
    expected power over the size's uncertainty (:func:`_expected_power`); the last item
    is the power at λ itself (what the ranking reads, :mod:`.ranking`'s docstring)."""
    lab_b = des.has[other]
    own = [i for i, lab in enumerate(des.labels) if lab in des.has[truth] and lab not in lab_b]
    JB = des.J[:, [i for i, lab in enumerate(des.labels) if lab in lab_b]]
    JA = des.J[:, own]
    U, sv_max = _basis(JB, rank_rtol)
    mu = JA @ np.array([theta.get(des.labels[i], 0.0) for i in own])
    lam_fit = float(np.sum((mu - U @ (U.T @ mu)) ** 2))
    M = JA - U @ (U.T @ JA)
    k = _basis(M, rank_rtol, sv_max)[0].shape[1] if own else 0
    nu = max(des.J.shape[0] - U.shape[1] - k, 1)
    if k == 0:
        return 0.0, 0, nu, 0.0, 0.0, len(own), 0.0
    lam = lam_fit
    if spread is not None:
        at = {lab: i for i, lab in enumerate(spread[0])}
        ix = [at.get(des.labels[i], -1) for i in own]
        C = np.zeros((len(own), len(own)))
        got = [j for j, i in enumerate(ix) if i >= 0]
        C[np.ix_(got, got)] = np.asarray(spread[1])[np.ix_([ix[j] for j in got],
                                                          [ix[j] for j in got])]
        lam = max(lam_fit - float(np.sum((M @ C) * M)), 0.0)
        theta_own = np.array([theta.get(des.labels[i], 0.0) for i in own])
        # the design prior: the posterior of the current data's own parameters under
        # the hierarchical normal prior (:func:`_hierarchical_assurance`); those the
        # current data do not have (a new placement's) are 0, as before
        G = M.T @ M
        power = _hierarchical_assurance(G[np.ix_(got, got)], theta_own[got],
                                           C[np.ix_(got, got)], k, nu, level)[0]
        return lam, k, nu, power, lam_fit, len(own), _power(lam, k, nu, level)
    point = _power(lam, k, nu, level)
    return lam, k, nu, point, lam_fit, len(own), point


def _expected_power(G: np.ndarray, theta: np.ndarray, cov: np.ndarray, k: int, nu: int,
                   level: float, draws: int = _ASSURANCE_DRAWS) -> float:
    """Expected power ``E[P(F(k, ν, λ(θ)) > F⁻¹(1 − α))]`` over ``θ ~ N(θ̂, C)``, with
    ``λ(θ) = θᵀ G θ`` (``G = MᵀM``, module docstring): the assurance of the nested test
    (O'Hagan & Stevens 2001, "Bayesian assessment of sample size for clinical trials of
    cost-effectiveness", Med. Decis. Making 21: the power averaged over a design prior;
    Spiegelhalter, Abrams & Myles 2004, §6.5), the design prior being the current data's
    posterior of the rival's own parameters under a flat prior, ``N(θ̂, C)``, ``C`` the
    fit's covariance (σ known; the linear model's posterior, Box & Tiao 1973 §2.7).

    Why not the power at one size: λ is a quadratic form in θ, and the fitted θ̂ may be
    hardly more than its noise along ``M`` (a proposal is asked for because the current
    data do not separate the rivals). The unbiased ``‖M θ̂‖² − tr(M C Mᵀ)`` is then often
    clipped at 0, where the power is the level, although the truth's λ is, as often, well
    above it (a drift rate of 1 µm/h spread fitted within ±1.3-3.5 µm/h,
    docs/proposals.md "Validation"). Averaging the power over the sizes the data allow
    weighs the large λ the data cannot exclude as well as the small. ``λ(θ)`` under
    ``θ ~ N(θ̂, C)`` is a weighted sum of non-central χ² variables (with ``C = L Lᵀ``
    and ``Lᵀ G L = V diag(w) Vᵀ``: ``Σ w_j χ²₁(δ_j²)``, ``δ = Vᵀ L⁻¹ θ̂``), and ``P`` is
    a non-central F tail: the expectation is taken by quasi-Monte Carlo, ``draws``
    scrambled Sobol' normal points ``z`` each with its mirror, ``θ̂ ± L z`` (Owen 1997,
    randomised QMC; fixed seed: the same number for the same design; the two of a pair
    have the same mean, so E[θ] is exact and the odd part of λ in ``z`` cancels), every
    power at once (vectorised ``ncf.sf``). With ``C → 0`` it is the power at ``λ(θ̂)``.

    Parameters
    ----------
    G : ndarray (p, p)
        ``MᵀM``: λ of a size θ is ``θᵀ G θ``.
    theta : ndarray (p,)
        The fitted size ``θ̂``.
    cov : ndarray (p, p)
        Its covariance ``C`` (positive semi-definite; negative eigenvalues from rounding
        are taken as 0).
    k, nu : int
        Numerator and denominator dof of the nested F-test.
    level : float
        Its level α.
    draws : int
        Antithetic pairs of the Monte Carlo.

    Returns
    -------
    float
        The expected power, in ``[level, 1]``.
    """
    theta = np.asarray(theta, float)
    cov = np.asarray(cov, float)
    w, V = np.linalg.eigh(0.5 * (cov + cov.T)) if theta.size else (np.zeros(0), cov)
    L = V * np.sqrt(np.clip(w, 0.0, None))
    if not theta.size or not np.any(L):
        return _power(float(theta @ G @ theta), k, nu, level)
    d = L @ _normal_points(theta.size, int(draws))
    return _mirrored_power(G, theta[:, None], d, k, nu, level)


def _mirrored_power(G: np.ndarray, mean: np.ndarray, d: np.ndarray, k: int, nu: int,
                    level: float) -> float:
    """Mean power over the mirrored pairs of sizes ``mean ± d`` (columns; ``mean`` one
    column for all, or one per pair): ``λ(m ± d) = mᵀGm ± 2 mᵀG d + dᵀG d``."""
    base = np.sum(mean * (G @ mean), axis=0)
    cross = 2.0 * np.sum(mean * (G @ d), axis=0)
    quad = np.sum(d * (G @ d), axis=0)
    lam = np.concatenate([base + cross + quad, base - cross + quad])
    return float(np.mean(_powers(np.clip(lam, 0.0, None), k, nu, level)))


def _hierarchical_assurance(G: np.ndarray, theta: np.ndarray, cov: np.ndarray, k: int,
                               nu: int, level: float,
                               draws: int = _ASSURANCE_DRAWS) -> tuple:
    """Expected power of the nested test over the posterior of the rival's own parameters
    under a hierarchical normal prior: ``(expected power, posterior median of τ²)``.

    The model (the normal/normal hierarchical model: Efron & Morris 1973, "Stein's
    estimation rule and its competitors: an empirical Bayes approach", JASA 68; Carlin &
    Louis 2000, "Bayes and Empirical Bayes Methods for Data Analysis", 2nd ed., §3.3-3.4):

        θ̂ | θ ~ N(θ, C),    θ | τ ~ N(0, τ² I),    τ ~ uniform on [0, ∞),

    the fit of the current data (the linear model with σ known); each of the rival's own
    parameters (each placement's drift rate along an axis, each stylus's offset, each
    coefficient of one error function: one unit within a rival) a draw of mean 0 from one
    spread ``τ`` of the rival's; and the uniform prior on ``τ`` (Gelman 2006, "Prior
    distributions for variance parameters in hierarchical models", Bayesian Analysis 1:
    the noninformative choice for a group-level spread, which leaves ``τ`` to the data).
    With ``C = V diag(c) Vᵀ`` and ``z = Vᵀ θ̂`` the ``z_j ~ N(0, τ² + c_j)`` are
    independent given ``τ``, whose posterior is ``∝ Π_j (τ² + c_j)^(-1/2)
    exp(−z_j²/(2(τ² + c_j)))`` (:func:`_tau2_quantiles`), and ``θ | θ̂, τ ~
    N(V diag(b) z, V diag(b c) Vᵀ)`` with the shrinkage ``b_j = τ²/(τ² + c_j)``. The
    expectation over both is a quasi-Monte Carlo of ``draws`` scrambled Sobol' points in
    ``p + 1`` dimensions (the first through the quantiles of ``τ²``, the others normal),
    each with its mirror in ``θ`` (:func:`_expected_power`'s scheme).

    Why a prior (the flat prior's ``N(θ̂, C)``, :func:`_expected_power`, before): where
    the current data hardly see the rival (``C`` large against ``θ̂θ̂ᵀ``), ``θ̂`` is mostly
    noise and the flat prior credits a measurement with the noise's size
    (docs/proposals.md, "On four machine layouts": drift rates fitted at ±7-21 µm/h
    against a 1 µm/h truth on the horizontal arm, predicted 91.8 % against 38 %
    separated). The posterior of ``τ`` then stays near the noise or below, and the sizes
    are shrunk towards 0. Where the data determine the size well (``c_j ≪ θ̂ᵀθ̂/p``) the
    posterior of ``τ²`` sits far above every ``c_j``, ``b_j → 1``, and this is the flat
    prior's expected power (today's result; the flat prior is the limit ``τ → ∞``).

    Choices tried on bench/next_layouts.py (gantry and horizontal arm, 20 seeds, the same
    tops, docs/proposals.md): the plug-in empirical Bayes (the marginal maximum-likelihood
    ``τ̂²`` and the posterior at it, Carlin & Louis §3.3) is often ``τ̂² = 0`` with the few
    parameters of one rival (two for ``rxz:4``) where ``τ`` is not, the point mass at 0
    (the expected power the level: 47 % predicted against 75 % separated for the weak yaw
    on the gantry) and understates the uncertainty of ``τ`` (Morris 1983, "Parametric
    empirical Bayes inference: theory and applications", JASA 78); the uniform shrinkage
    prior ``c₀/(c₀ + τ²)²`` (Daniels 1999, Can. J. Statist. 27), whose median is the noise
    level, and even ``τ`` fixed at the simulation's own spread (1) shrank as much (44 %
    and 54 % there); the uniform prior on ``τ`` is within ±5 points on both layouts'
    four pairs together, 56 % there.

    One free direction (a single parameter): the posterior of ``τ`` under the uniform
    prior is improper (its tail falls as ``τ⁻¹``; Gelman 2006 §4), its mass at ``τ → ∞``,
    which is the flat prior: :func:`_expected_power` as before. Directions of no spread
    (``c_j`` at rounding level, :data:`_NULL_RTOL`: a constraint of the parameters, e.g.
    stylus offsets of zero sum, whose ``z_j`` is 0 by construction) say nothing of
    ``τ``: they are left out of its likelihood and kept as fitted (``b_j = 1``).

    Parameters
    ----------
    G : ndarray (p, p)
        ``MᵀM``: λ of a size θ is ``θᵀ G θ``.
    theta : ndarray (p,)
        The fitted size ``θ̂``.
    cov : ndarray (p, p)
        Its covariance ``C`` (negative eigenvalues from rounding taken as 0).
    k, nu : int
        Numerator and denominator dof of the nested F-test.
    level : float
        Its level α.
    draws : int
        Mirrored pairs of the quasi-Monte Carlo.

    Returns
    -------
    tuple
        ``(expected power in [level, 1], posterior median of τ²; inf for one free
        direction)``.
    """
    theta = np.asarray(theta, float)
    cov = np.asarray(cov, float)
    if not theta.size:
        return _power(0.0, k, nu, level), 0.0
    c, V = np.linalg.eigh(0.5 * (cov + cov.T))
    c = np.clip(c, 0.0, None)
    z = V.T @ theta
    free = c > _NULL_RTOL * float(c.max())
    if free.sum() < 2:  # one free direction: no spread to estimate (the flat prior)
        return _expected_power(G, theta, cov, k, nu, level, draws), float("inf")
    u = _normal_points(theta.size + 1, int(draws))
    t2 = _tau2_quantiles(z[free] ** 2, c[free], stats.norm.cdf(u[0]))
    b = np.ones((c.size, t2.size))
    b[free] = t2[None, :] / (t2[None, :] + c[free, None])
    mean = V @ (b * z[:, None])
    d = V @ (np.sqrt(b * c[:, None]) * u[1:])
    return _mirrored_power(G, mean, d, k, nu, level), float(np.median(t2))


def _tau2_quantiles(z2: np.ndarray, c: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Quantiles ``q`` of the posterior of ``τ²`` given ``z_j²`` and noise variances
    ``c_j`` (``z_j ~ N(0, τ² + c_j)``) under the uniform prior on ``τ``
    (:func:`_hierarchical_assurance`): the density ``Π_j (τ² + c_j)^(-1/2)
    exp(−z_j²/(2(τ² + c_j)))`` on ``τ = 0`` and :data:`_TAU2_GRID` log-spaced ``τ`` from
    ``10⁻² √min c`` to ``10² √max(c, z²)`` (for two parameters, whose tail falls as
    ``τ⁻²``, the cut leaves out about 1 % of the mass), its cumulative integral in ``τ`` by
    the trapezoid rule, inverted linearly."""
    hi = 1e2 * np.sqrt(max(float(c.max()), float(z2.max())))
    tau = np.concatenate([[0.0], np.geomspace(1e-2 * np.sqrt(float(c.min())), hi, _TAU2_GRID)])
    v = tau[:, None] ** 2 + c[None, :]
    logp = -0.5 * np.sum(np.log(v) + z2 / v, axis=1)
    dens = np.exp(logp - logp.max())
    cdf = integrate.cumulative_trapezoid(dens, tau, initial=0.0)
    return np.interp(np.asarray(q, float) * cdf[-1], cdf, tau) ** 2


def _power(lam: float, k: int, nu: int, level: float) -> float:
    """P(F(k, ν, λ) > F⁻¹(1 − level; k, ν)) at one λ (:func:`_powers`)."""
    return float(_powers(np.array([lam], float), k, nu, level)[0])


@lru_cache(maxsize=64)
def _normal_points(dim: int, n: int) -> np.ndarray:
    """``(dim, n)`` standard normal points: scrambled Sobol' (``_ASSURANCE_SEED``) through
    the normal quantile; cached (read-only), as every candidate of a rival asks for the
    same."""
    u = qmc.Sobol(dim, scramble=True, seed=_ASSURANCE_SEED).random(n)
    z = stats.norm.ppf(np.clip(u, 1e-12, 1.0 - 1e-12)).T
    z.flags.writeable = False
    return z


def _powers(lam: np.ndarray, k: int, nu: int, level: float) -> np.ndarray:
    """P(F(k, ν, λ) > F⁻¹(1 − level; k, ν)) for each λ: the level itself at λ = 0
    (scipy's ``ncf`` returns nonsense there, e.g. -0.99), the χ² limit (ν → ∞) where
    ``ncf`` fails."""
    lam = np.asarray(lam, float)
    crit = stats.f.isf(level, k, nu)
    with np.errstate(all="ignore"):
        p = np.array(np.broadcast_to(stats.ncf.sf(crit, k, nu, lam), lam.shape), float)
    bad = ~((p >= 0.0) & (p <= 1.0))
    if bad.any():
        p[bad] = stats.ncx2.sf(k * crit, k, lam[bad])
    p = np.minimum(np.maximum(p, float(level)), 1.0)
    p[lam <= 0.0] = float(level)
    return p


def _score_on(des: _Design, rf: RivalFits) -> dict:
    """Rival taken as the truth -> :func:`_separation`'s tuple against the other rival
    it is hardest to tell from (module docstring): of the tests "truth still needed once
    ``o`` is in", the one of the smallest power at the corrected size (then expected
    power, then λ). For two rivals the one test each way."""
    out = {}
    for t in rf.rivals:
        f = rf.fits[t]
        theta = dict(zip(f.labels, f.values, strict=True))
        tests = [_separation(des, t, o, theta, rank_rtol=f.rank_rtol, level=rf.levels[t],
                             spread=(f.labels, f.covariance))
                 for o in rf.rivals if o != t]
        out[t] = min(tests, key=lambda v: (v[6], v[3], v[0]))
    return out


def _score_candidates(now: _Design, obs, ok: list, rf: RivalFits):
    """``(candidate, {rival: (λ, k, ν, power)})`` for each candidate, from one design of
    all their observations (rows of each placement stacked onto the current data's)."""
    if obs is None:
        return
    extra = _design(obs, rf)
    for cand in ok:
        keep = obs.pos == obs.positions.index(next(iter(cand.positions)))
        yield cand, _score_on(_stack(now, _rows(extra, keep)), rf)


def _union(reps: list) -> NextMeasurement | None:
    """One repeat holding every candidate's rows, or None when two candidates repeat one
    placement with different styli (its rows are one stylus's). A ball repeated at two
    times (a placement's repeat alone in the next session, and later in ``repeat_all``
    after another's) is two rows of the union, each candidate keeping its own."""
    rows: dict = {}
    for c in reps:
        for p, r in c.repeat.items():
            for b, t in zip(r["balls"], r["time_min"], strict=True):
                rows.setdefault((p, r["probe"], int(b), round(float(t), 6)), float(t))
    each: dict = {}
    for (p, q, b, _), t in rows.items():
        if p in each and each[p]["probe"] != q:
            return None
        r = each.setdefault(p, {"probe": q, "balls": [], "time_min": []})
        r["balls"].append(b)
        r["time_min"].append(t)
    return NextMeasurement("repeats", "every repeat", {}, {}, {}, 0.0, repeat=each)


def _score_repeats(data: Dataset, reps: list, rf: RivalFits):
    """``(candidate, {rival: (λ, k, ν, power, ...)})`` for each repeat. A repeat adds rows
    to placements already measured (at its own times, after the data's last reading: a
    drift is seen over all the time elapsed), so its design is that of the whole
    augmented data set, its hours counted from the mean time of the placement's readings
    before (moving
    that centre changes a drift column by a multiple of the placement's translation
    columns, which every rival holds: the projections and λ do not change; the fit of the
    augmented data centres anew). One design of all the repeats' rows together serves
    each: its rows are the current data's and that candidate's."""
    if not reps:
        return
    union = _union(reps)
    if union is None:
        for c in reps:
            yield c, _score_on(_design(select(append_measurement(data, c)), rf), rf)
        return
    obs = select(append_measurement(data, union))
    t = obs.table
    new = (t["source"] == f"proposal {union.name}").to_numpy()
    # each placement's hours from the mean time of its readings before (the current
    # data's own centring): the current rows' design is then the same whichever
    # repeats the union holds (the same numbers however the candidates are split)
    tm = t["time_min"].to_numpy(float)
    hours = obs.hours.copy()
    for i in range(len(obs.positions)):
        at = obs.pos == i
        if (at & new).any():
            hours[at] = (tm[at] - tm[at & ~new].mean()) / 60.0
    obs = replace(obs, hours=hours)
    des = _design(obs, rf)
    # a row is the candidate's by its placement, stylus, ball and time (the union may
    # hold a ball at two times)
    key = list(zip(t["position"].astype(str), t["probe"].astype(str), t["ball"].astype(int),
                   np.round(tm, 6), strict=True))
    n3 = 3 * len(t)
    for c in reps:
        mine = {(p, r["probe"], int(b), round(float(u), 6)) for p, r in c.repeat.items()
                for b, u in zip(r["balls"], r["time_min"], strict=True)}
        keep = np.repeat(~new | np.array([k in mine for k in key]), 3)
        J = np.vstack([des.J[:n3][keep], des.J[n3:]])
        yield c, _score_on(_Design(J, des.labels, des.has), rf)

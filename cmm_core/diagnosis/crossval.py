"""Leave-one-placement-out check: does an effect predict placements it was not fitted to?

An F-test or ΔBIC rewards whatever lowers χ² on the data it was fitted to. A flexible
alias (a periodic error whose period the ball spacing aliases, a higher order that
follows one placement's oddity) lowers it too. A physical effect of the machine or the
plate, fitted on the other placements, *predicts* the held-out one; an alias does not.

The check works on the part of the residual the baseline leaves (Frisch-Waugh-Lovell):
with ``r`` the baseline's weighted residual and ``X`` the effect's columns with the
baseline's columns projected out, the in-sample gain of adding the effect is
``|P_X r|²``. For each placement ``p`` the effect's coefficients are estimated from the
other placements' rows only, and its held-out gain is how much that prediction lowers
``p``'s residual: ``|r_p|² - |r_p - X_p β_(-p)|²``. The baseline itself is common to both
sides of the comparison and stays fitted to all data; what is cross-validated is the
effect. Linearised at the baseline's solution, as ``scoring.score``.

**The decision is a test with a stated error rate.** Under the hypothesis that the effect
is real, ``r = X β + ε`` with ``ε ~ N(0, s² M)`` (``M = I - H`` the baseline's
residual projector, ``s²`` the scatter left once the effect is added, ``χ²/ν`` as in the
diagnosis's F-test), and the total held-out gain ``T = rᵀ Q r`` is a Gaussian quadratic
form. Its deviation from what the in-sample fit ``μ̂ = P r`` (``P`` the projector on
``X``) implies, ``D = rᵀ K r - s² tr(K M)`` with ``K = Q - P Q P``, has expectation
exactly zero for *every* β (``P μ = μ``), variance ``2 s⁴ tr(KMKM) + 4 s² μᵀKMKμ`` and
third cumulant ``8 s⁶ tr((KM)³) + 24 s⁴ μᵀ(KM)²Kμ`` (``μ`` estimated by ``μ̂`` with its
noise term removed). ``z`` is the normal score of ``D`` under the shifted gamma (Pearson
type III) with those three cumulants: about standard normal for a real effect whatever
its size, large and negative for an alias, whose in-sample pattern the held-out
placements do not share. The check
fails when ``z`` is below the lower :data:`ALPHA` quantile of the normal and the shortfall
is material (:data:`MATERIAL`): a real effect is
declared an alias in about ``ALPHA`` of data sets at any size, and an alias no larger
than its own noise passes (the data cannot tell it from a real effect).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg as sla
from scipy import stats

from ..model import (
    FitResult,
    Normal,
    Observations,
    Problem,
    augmented_state,
    weighted_residual,
)

if TYPE_CHECKING:
    from .scoring import ScoreCache

ALPHA = 0.01
"""Rate at which a real effect fails the check (one-sided level of the ``z`` test in the
module docstring), checked by simulation in ``tests/test_honesty.py``."""

MATERIAL = 0.2
"""Shortfall, as a share of the expected held-out gain, below which a significant one is
not held against the effect. A large real effect predicts so precisely that the
linearisation or a residual that is not quite white can push ``z`` below the level while
it keeps nearly all its held-out gain; an alias loses most of it. Only relaxes the test:
a real effect still fails at most at the rate :data:`ALPHA`."""

SCALE_ALPHA = ALPHA
"""Level of the placement-scale test (:func:`placement_scale_test`): a real catalogue
effect, with no placement-dependent scale in the data, fails it at most at this rate
(the F-test of the scales given the effect is then a null test)."""

SCALE_ALONE_ALPHA = 0.002
"""Level of the placement-scale test on the baseline alone (:func:`scales_alone_p`), run
when no catalogue candidate is significant: clean data fail it at this rate, on top of
the diagnosis's own false alarms, so it is a fifth of :data:`SCALE_ALPHA` to keep the
clean-data null verdicts at 99 % (0 of 300 clean data sets on three layouts fail it, 3 at
0.01; a 5 ppm spread of Z scales over five placements of a 150 mm plate is found in 26 of
30 seeds, 28 at 0.01)."""

MIN_PLACEMENTS = 3
"""With two placements, one placement alone rarely determines an effect's coefficients."""


@dataclass(frozen=True)
class HoldoutCheck:
    """Outcome of the leave-one-placement-out check of one candidate effect.

    Attributes
    ----------
    effect : str
        Model token checked.
    applicable : bool
        False when the check cannot judge the effect (``reason`` says why): fewer than
        three placements, or every parameter it adds belongs to a single placement
        (drift of each position), so no other placement can predict it.
    passed : bool
        False when the held-out gain falls short of what the effect, were it real, would
        give by more than chance allows (``z`` below the :data:`ALPHA` quantile) and by
        more than :data:`MATERIAL` of it; True when not applicable (the check then has no evidence against the effect).
    gain_in_sample : float
        χ² the effect removes on all data (linearised).
    gain_held_out : float
        Sum over placements of the held-out χ² reduction.
    per_placement : dict
        ``{position: held-out χ² reduction}``.
    reason : str
        Plain-language reading of the numbers.
    expected_held_out : float
        Held-out gain a real effect of the fitted size would give on average.
    sd_held_out : float
        Its standard deviation under that hypothesis (noise and estimation).
    z : float
        ``(gain_held_out - expected_held_out) / sd_held_out`` (NaN when not applicable).
    scale_p : float
        p-value of each placement's own scale (three per placement, along the machine
        axes) added once the effect is in the model (:func:`placement_scale_test`; NaN
        when not run: a hole plate, or one placement).
    effect_given_scale_p : float
        p-value of the effect added once the placements' own scales are in the model.
    effect_level : float
        The effect's own level in the diagnosis, at which ``effect_given_scale_p`` is
        judged (NaN when not given).
    """

    effect: str
    applicable: bool
    passed: bool
    gain_in_sample: float
    gain_held_out: float
    per_placement: dict = field(default_factory=dict)
    reason: str = ""
    expected_held_out: float = float("nan")
    sd_held_out: float = float("nan")
    z: float = float("nan")
    scale_p: float = float("nan")
    effect_given_scale_p: float = float("nan")
    effect_level: float = float("nan")

    @property
    def stands_in_for_scale(self) -> bool:
        """The effect stands in for each placement's own scale: the scales are still
        needed with it in (``scale_p < SCALE_ALPHA``) while it adds nothing once they are
        in (``effect_given_scale_p ≥ effect_level``). False when the test was not run."""
        return bool(self.scale_p < SCALE_ALPHA
                    and self.effect_given_scale_p >= self.effect_level)

    @property
    def share(self) -> float:
        """Held-out gain as a share of the in-sample gain (0 when nothing is gained)."""
        if not self.applicable or self.gain_in_sample <= 0:
            return 0.0
        return self.gain_held_out / self.gain_in_sample

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"effect": self.effect, "applicable": self.applicable, "passed": self.passed,
                "gain_in_sample": self.gain_in_sample,
                "gain_held_out": self.gain_held_out if self.applicable else None,
                "share": self.share if self.applicable else None,
                "expected_held_out": self.expected_held_out if self.applicable else None,
                "sd_held_out": self.sd_held_out if self.applicable else None,
                "z": self.z if self.applicable else None, "level": ALPHA,
                "per_placement": self.per_placement, "reason": self.reason,
                "stands_in_for_scale": self.stands_in_for_scale,
                "placement_scale": {"scale_given_effect_p": _nan_none(self.scale_p),
                                    "effect_given_scale_p":
                                        _nan_none(self.effect_given_scale_p),
                                    "level": SCALE_ALPHA}}


def _nan_none(x: float):
    return None if not np.isfinite(x) else float(x)


def scale_columns(obs: Observations, sigma_um: float, n_rows: int
                  ) -> tuple[np.ndarray, list[tuple[str, str]]]:
    """Weighted columns of each placement's own scale along each machine axis it spans
    (at least a quarter of its longest extent; 1 ppm: the reading of axis ``a`` moves by
    1e-3 µm per mm from the placement's mean ``a``), rows as the weighted residual's
    (three per observation first; further rows zero), at the nominal placement. Returns
    ``(S, labels)``, labels ``(position, axis)``; ``S`` is ``(n_rows, 0)`` when no
    placement spans anything."""
    cols, labels = [], []
    # nominal coordinates: the readings' own µm errors (the residual itself) must not
    # enter the columns, or once the plate is projected out they fit the residual
    xyz = np.einsum("nac,nc->na", obs.R0[obs.pos], obs.plate0_mm[obs.ball]) + obs.t0_mm[obs.pos]
    for k, name in enumerate(obs.positions):
        sel = np.flatnonzero(obs.pos == k)
        if not sel.size:
            continue
        span = np.ptp(xyz[sel], axis=0)
        for a in range(3):
            # an axis the placement hardly spans (a horizontal plate's z) has no scale
            # the data can see; its near-empty column would only fit rounding
            if span[a] < 0.25 * span.max():
                continue
            c = np.zeros(n_rows)
            x = xyz[sel, a]
            c[3 * sel + a] = (x - x.mean()) * 1e-3 / sigma_um
            cols.append(c)
            labels.append((str(name), "xyz"[a]))
    return (np.column_stack(cols) if cols else np.zeros((n_rows, 0))), labels


def placement_scale_columns(base: FitResult, n_rows: int) -> tuple[np.ndarray, list]:
    """:func:`scale_columns` of a fit's observations at its σ; an empty ``S`` for a hole
    plate, whose residuals live in its plane (the test is not run there), and for a
    single placement."""
    o = base.problem.obs
    if o.artefact == "hole_plate" or len(o.positions) < 2:
        return np.zeros((n_rows, 0)), []
    return scale_columns(o, base.sigma_um, n_rows)


_RANK_TOL = 1e-3
"""Relative size, against a column's norm before projection, below which what is left of
it after projecting out other columns is rounding, not a direction of its own."""


def _basis(A, norms):
    """Orthonormal basis of the columns of ``A`` that keep more than :data:`_RANK_TOL`
    of their norm ``norms`` (before projection)."""
    keep = np.linalg.norm(A, axis=0) > _RANK_TOL * np.maximum(norms, 1e-300)
    if not keep.any():
        return np.zeros((A.shape[0], 0))
    B = A[:, keep] / norms[keep]
    Q, R, _ = sla.qr(B, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    return Q[:, : int(np.sum(d > _RANK_TOL))]


def _rss(r, A, norms):
    """Residual sum of squares of ``r`` on the columns ``A`` and their rank."""
    if A.shape[1] == 0:
        return float(r @ r), 0
    Q = _basis(A, norms)
    e = r - Q @ (Q.T @ r)
    return float(e @ e), Q.shape[1]


def scales_alone_p(base: FitResult, cache: ScoreCache | None = None) -> float:
    """p-value of each placement's own scale added to the baseline alone: the nested
    F-test of :func:`placement_scale_test` without an effect (the baseline's columns and
    a free plate's projected out, Frisch-Waugh-Lovell; Scheffé 1959, §2.3). NaN when no
    placement spans an axis (one placement, a hole plate). Under no placement scale its
    p-value is uniform (an exact F-test when the noise is normal: the plate is free, so
    the certificate's errors are projected out with it). ``cache``: the diagnosis's
    ``scoring.ScoreCache``, whose dense Jacobian holds the baseline's columns already."""
    idx = None if cache is None else cache.columns(base.problem)
    if cache is not None and idx is not None:
        r, J = cache.r, cache.J[:, idx]
    else:
        _, r, Js = weighted_residual(base.problem, base.state, base.sigma_um, True)
        J = Js.toarray()
    S, _ = placement_scale_columns(base, r.size)
    if not S.shape[1]:
        return float("nan")
    B = np.hstack([J, plate_columns(base, r.size)])
    Q = _basis(B, np.linalg.norm(B, axis=0))
    ns = np.linalg.norm(S, axis=0)
    r, S = (A - Q @ (Q.T @ A) for A in (r, S))
    rss1, ks = _rss(r, S, ns)
    if ks == 0:
        return float("nan")
    nu = max(base.dof + base.rank - Q.shape[1] - ks, 1)
    f = max(float(r @ r) - rss1, 0.0) / ks / max(rss1 / nu, 1e-300)
    return float(stats.f.sf(f, ks, nu))


def plate_columns(base: FitResult, n_rows: int) -> np.ndarray:
    """Weighted columns of a free plate (each ball's three plate coordinates, through each
    placement's nominal rotation), rows as the weighted residual's. The placement-scale
    test is made with the plate free: a certificate's own errors are common to every
    placement in the plate frame but differ per placement in the machine frame, and
    placement scales would otherwise fit them (a test that fails clean data)."""
    o = base.problem.obs
    n = o.pos.size
    P = np.zeros((n_rows, 3 * len(o.balls)))
    R = o.R0[o.pos] / base.sigma_um  # (n, 3, 3): machine axis a, plate axis c
    for a in range(3):
        for c in range(3):
            P[3 * np.arange(n) + a, 3 * o.ball + c] = R[:, a, c]
    return P


def placement_scale_test(r: np.ndarray, X: np.ndarray, S: np.ndarray, n_rows: int,
                         B: np.ndarray) -> tuple[float, float]:
    """Does the effect stand in for each placement's own scale? ``(p_S|E, p_E|S)``.

    ``r``, ``X``, ``S``: the baseline's weighted residual, the effect's columns and the
    placement-scale columns (:func:`placement_scale_columns`); ``B``: the baseline's
    columns beside the free plate's (:func:`plate_columns`), projected out of all three
    first through an orthonormal basis (Frisch-Waugh-Lovell); ``n_rows``: the number of
    residuals that count (the baseline's degrees of freedom plus its rank). Two nested
    F-tests (linearised at the baseline, as the diagnosis's score):
    of the scales once the effect is in, and of the effect once the scales are in. The
    effect is an alias of placement scales when the scales are still needed with it
    (``p_S|E`` below :data:`SCALE_ALPHA`) while it adds nothing once they are in. Under a
    real effect with no placement scale in the data the first test is a null F-test, so a
    real effect fails at most at the rate :data:`SCALE_ALPHA` (Scheffé 1959, §2.3)."""
    nx, ns = np.linalg.norm(X, axis=0), np.linalg.norm(S, axis=0)
    Q = _basis(B, np.linalg.norm(B, axis=0))
    r, X, S = (A - Q @ (Q.T @ A) for A in (r, X, S))
    dof = n_rows - Q.shape[1]
    rss_e, ke = _rss(r, X, nx)
    rss_s, ks = _rss(r, S, ns)
    rss_es, kes = _rss(r, np.hstack([X, S]), np.concatenate([nx, ns]))
    nu = max(dof - kes, 1)
    s2 = max(rss_es / nu, 1e-300)

    def p_of(rss_small, k_small):
        dk = kes - k_small
        if dk <= 0:
            return 1.0
        return float(stats.f.sf(max(rss_small - rss_es, 0.0) / dk / s2, dk, nu))

    return p_of(rss_e, ke), p_of(rss_s, ks)


def _effect_columns(base: FitResult, prob: Problem, cache=None):
    """Baseline residual and the effect's columns with the baseline's projected out.

    Returns ``(r, X, pos_of_row, Jb, cov)``: weighted residual (m,), effect columns (m, k)
    in the effect's own gauge, the placement index of every row (-1: certificate prior,
    -2: instrument rows, laser runs and step gauges, the last rows), and the baseline's
    weighted Jacobian and constrained covariance (its hat matrix is ``Jb cov Jbᵀ``).
    ``prob`` is the baseline's problem with the effect added; ``cache``, the diagnosis's
    ``scoring.ScoreCache``, holds its columns already.
    """
    idx = None if cache is None else cache.columns(prob)
    if idx is None:
        _, r, J = weighted_residual(prob, augmented_state(base, prob), base.sigma_um, True)
        J = J.toarray()
    else:
        r, J = cache.r, cache.J[:, idx]
    old = set(base.labels)
    is_new = np.array([lab not in old for lab in prob.layout.labels])
    C = prob.constraints()
    Cb = C[:, ~is_new][np.abs(C[:, is_new]).sum(axis=1) == 0]
    if base.design_null.size:
        Cb = np.vstack([Cb, base.design_null])
    Jb, X = J[:, ~is_new], J[:, is_new]
    # the effect's own gauge (probe offsets summing to zero): its constraint null space
    Cn = C[:, is_new][np.abs(C[:, ~is_new]).sum(axis=1) == 0]
    if Cn.shape[0]:
        X = X @ sla.null_space(Cn)
    # project out what the baseline explains (its constrained least-squares hat matrix)
    cov = Normal(Jb, r, Cb, base.rank_rtol).cov()
    X = X - Jb @ (cov @ (Jb.T @ X))
    r = r - Jb @ (cov @ (Jb.T @ r))
    o = prob.obs
    pos_of_row = np.full(r.size, -1)
    pos_of_row[: 3 * prob.n_obs] = np.repeat(o.pos, 3)
    pos_of_row[r.size - prob.instruments.n_rows:] = -2
    return r, X, pos_of_row, Jb, cov


def _falls_short(gain, expected, z) -> bool:
    """The decision: the held-out gain falls short of a real effect's, significantly
    (``z`` below the :data:`ALPHA` quantile) and materially (:data:`MATERIAL`)."""
    return bool(z < stats.norm.ppf(ALPHA) and gain < (1.0 - MATERIAL) * expected)


def _pinv(A):
    return np.linalg.pinv(A, rcond=1e-10)


def _fold_maps(X, folds):
    """Per held-out placement, the least-squares map from the other rows to the effect's
    coefficients: ``β(-p) = pinv(X[~held]) r[~held]``."""
    return [_pinv(X[~held]) for held in folds]


def _real_effect_test(r, X, folds, maps, Jb, cov, gain, s2=1.0):
    """``(expected, sd, z)`` of the held-out ``gain`` under "the effect is real" (module
    docstring). ``folds``: boolean row masks of the held-out placements, ``maps`` their
    :func:`_fold_maps`; ``s2``: the noise variance in units of the weights (the scatter
    left, as in the F-test).

    Everything is kept in the basis ``Z`` of the columns the quadratic forms live in (each
    fold's effect columns and its prediction map), so that no n × n matrix is formed:
    ``K = Z W Zᵀ`` and ``Zᵀ M Z = ZᵀZ - (ZᵀJb) cov (JbᵀZ)``.
    """
    n, k = X.shape
    F, B, XtX = [], [], []  # per fold: effect rows, prediction map, XpᵀXp
    for held, A in zip(folds, maps, strict=True):
        Fp = np.where(held[:, None], X, 0.0)
        Bp = np.zeros((n, k))
        Bp[~held] = A.T  # β(-p) = Bpᵀ r
        F.append(Fp)
        B.append(Bp)
        XtX.append(Fp.T @ Fp)
    nf = len(folds)
    Z = np.hstack(F + B)
    m = Z.shape[1]
    W = np.zeros((m, m))
    for i in range(nf):  # gain_p = 2 r_pᵀ X_p β(-p) - |X_p β(-p)|²
        f, b = slice(i * k, (i + 1) * k), slice((nf + i) * k, (nf + i + 1) * k)
        W[f, b] += np.eye(k)
        W[b, f] += np.eye(k)
        W[b, b] -= XtX[i]
    S = np.vstack([np.eye(k)] * nf + [np.zeros((k, k))] * nf)  # X = Z S
    G = _pinv(X.T @ X)
    ZtZ = Z.T @ Z
    SGS = S @ G @ S.T  # P = Z SGS Zᵀ
    Wk = W - SGS @ ZtZ @ W @ ZtZ @ SGS  # K = Q - PQP
    ZJ = Z.T @ Jb
    Y = ZtZ - ZJ @ cov @ ZJ.T  # Zᵀ M Z
    zr = Z.T @ r
    zmu = ZtZ @ SGS @ zr  # Zᵀ μ̂
    WY = Wk @ Y
    D = float(zr @ Wk @ zr - s2 * np.trace(WY))
    # μᵀ(KM)ʲK μ from μ̂, less its noise part: E[μ̂ᵀAμ̂] - μᵀAμ = tr(A PMP)
    PMP = ZtZ @ SGS @ Y @ SGS @ ZtZ

    def signal(A):
        return max(float(zmu @ A @ zmu - s2 * np.trace(A @ PMP)), 0.0)

    var = 2.0 * s2**2 * float(np.trace(WY @ WY)) + 4.0 * s2 * signal(WY @ Wk)
    k3 = (8.0 * s2**3 * float(np.trace(WY @ WY @ WY))
          + 24.0 * s2**2 * signal(WY @ WY @ Wk))
    sd = float(np.sqrt(max(var, 1e-300)))
    # the form is skewed (few fold predictions dominate): the lower tail of a Pearson
    # type III (shifted gamma) with the form's mean, variance and third cumulant
    skew = k3 / sd**3
    if abs(skew) < 1e-3:
        z = D / sd
    else:
        shape, scale = 4.0 / skew**2, sd * abs(skew) / 2.0
        # D = sign(skew) (G - shape scale), G ~ Gamma(shape, scale)
        g = shape * scale + np.sign(skew) * D
        cdf = (stats.gamma.cdf(g, shape, scale=scale) if skew > 0
               else stats.gamma.sf(g, shape, scale=scale))
        z = float(stats.norm.ppf(np.clip(cdf, 1e-300, 1.0 - 1e-16)))
    return gain - D, sd, z


def check(base: FitResult, token: str, cache: ScoreCache | None = None,
          level: float = ALPHA) -> HoldoutCheck:
    """Leave-one-placement-out check of adding ``token`` to ``base`` (module docstring),
    and whether it stands in for each placement's own scale (:func:`placement_scale_test`;
    ``level``: the effect's own level in the diagnosis, at which "adds nothing once the
    scales are in" is judged). ``cache``: the diagnosis's ``scoring.ScoreCache``."""
    o = base.problem.obs
    prob = Problem(o, base.problem.spec.with_token(token), base.plate)
    added = {g for g, lab in zip(prob.layout.groups, prob.layout.labels, strict=True)
             if lab not in set(base.labels)}
    r, X, pos_of_row, Jb, cov = _effect_columns(base, prob, cache)
    S, _ = placement_scale_columns(base, r.size)
    p_s = p_e = float("nan")
    if S.shape[1]:
        p_s, p_e = placement_scale_test(r, X, S, base.dof + base.rank,
                                        np.hstack([Jb, plate_columns(base, r.size)]))
    h = _held_out(base, token, added, r, X, pos_of_row, Jb, cov)
    h = replace(h, scale_p=p_s, effect_given_scale_p=p_e, effect_level=level)
    if h.stands_in_for_scale:
        h = replace(h, passed=False, reason=(
            f"it stands in for each placement's own scale: once the placements' own "
            f"scales are in the model it adds nothing (p = {p_e:.2g} against its level "
            f"{level:.2g}), while the scales are still needed with it in (p = {p_s:.2g} < "
            f"{SCALE_ALPHA:g}; a real effect fails this at most {100 * SCALE_ALPHA:g} % of "
            f"the time). Leave-one-placement-out: {h.reason}"))
    return h


def _held_out(base, token, added, r, X, pos_of_row, Jb, cov) -> HoldoutCheck:
    """The leave-one-placement-out part of :func:`check` (module docstring)."""
    o = base.problem.obs
    if len(o.positions) < MIN_PLACEMENTS:
        return HoldoutCheck(token, False, True, float("nan"), float("nan"), {},
                            f"needs at least {MIN_PLACEMENTS} placements")
    if added <= {"drift"}:
        return HoldoutCheck(token, False, True, float("nan"), float("nan"), {},
                            "its parameters belong to single placements (the drift of each "
                            "position), so no other placement can predict them")
    # instrument rows (laser, step gauge) train every fold and are held out in none: the
    # in-sample gain compared is that on the rows that are held out
    on = pos_of_row != -2
    left = r - X @ (_pinv(X) @ r)
    gain_in = float(r[on] @ r[on] - np.sum(left[on] ** 2))
    # the noise scale is the scatter the effect leaves, as in the diagnosis's F-test: a
    # misfit elsewhere (or a misstated σ) is noise to this check, not evidence
    s2 = float(left @ left) / max(base.dof - np.linalg.matrix_rank(X), 1)
    folds = [pos_of_row == k for k in range(len(o.positions))]
    maps = _fold_maps(X, folds)
    per = {}
    for name, held, A in zip(o.positions, folds, maps, strict=True):
        rp, e = r[held], r[held] - X[held] @ (A @ r[~held])
        per[name] = float(rp @ rp - e @ e)
    gain = float(sum(per.values()))
    expected, sd, z = _real_effect_test(r, X, folds, maps, Jb, cov, gain, s2)
    passed = bool(gain_in > 0 and not _falls_short(gain, expected, z))
    if passed and z < stats.norm.ppf(ALPHA):
        why = (f"fitted on the other placements, it predicts {100 * gain / expected:.0f} % "
               f"of what a real effect of the fitted size would on the held-out ones (the "
               f"held-out χ² falls by {gain:.1f} against {expected:.1f} ± {sd:.1f}, z = "
               f"{z:.1f}): short of it beyond chance but by less than {100 * MATERIAL:.0f} "
               "%, a real effect whose shape or size differs a little between placements, "
               "not an alias")
    elif passed:
        why = (f"fitted on the other placements, its predictions of the held-out ones are "
               f"consistent with a real effect: the held-out χ² falls by {gain:.1f} where a "
               f"real effect of the fitted size gives {expected:.1f} ± {sd:.1f} (z = {z:.1f}; "
               f"in sample it falls by {gain_in:.1f})")
    else:
        worst = min(per, key=lambda k: per[k])
        why = (f"fitted on the other placements it does not predict the held-out ones: the "
               f"held-out χ² changes by {-gain:+.1f} where a real effect of the fitted size "
               f"would lower it by {expected:.1f} ± {sd:.1f} (z = {z:.1f}; in sample it "
               f"falls by {gain_in:.1f}; worst at {worst}: {-per[worst]:+.1f}). It follows "
               "what differs between placements, not a property of the machine or the plate")
    return HoldoutCheck(token, True, passed, gain_in, gain, per, why, expected, sd, z)

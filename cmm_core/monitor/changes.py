"""What changed: the stored model refitted on the new data with itself as the prior.

The interim check's linear system (``check``) is ``d = -J δ + A β + ε`` with ``δ`` the
change of the kinematic coefficients, the stored model as the prior ``δ ~ N(0, V)``, the
poses ``β`` free and ``ε ~ N(0, Σ_n)`` (noise and certificate). With
``Σ = Σ_n + J V Jᵀ`` and the pose-projected precision
``Π = Σ⁻¹ - Σ⁻¹ A M⁻¹ Aᵀ Σ⁻¹`` (``M = Aᵀ Σ⁻¹ A``), the posterior (Gaussian linear model,
Gelman et al. 2013 §14.8; Rao 1973 §4a.3 for the pose profile) is::

 s = E[δ | d] = -V Jᵀ Π d             (the change the new data show)
    cov(δ | d) = V - V Jᵀ Π J V

and if nothing changed ``s ~ N(0, V Jᵀ Π J V)``: each parameter's ``z_j = s_j / u(s_j)``
is standard normal, and it is tested by its two-sided p-value. Its normalised error is
stated as laboratories read one, at the check's coverage factor ``k`` (default 2: the
expanded uncertainties of EA-4/02; ISO/IEC 17043:2010 Annex B):
``E_n = s_j / (k u(s_j))``, ``|E_n| <= 1`` the usual acceptance (``|z| <= 2`` at k = 2);
the tests do not depend on ``k``. A single parameter that moved alone (the others as
stored) is tested by its score, ``z_j = -(Jᵀ Π d)_j / sqrt((Jᵀ Π J)_jj)``, standard
normal if nothing changed (its ``E_n`` is ``z_j / k``): the sharper test when one effect
appeared (a crash). It is made only where the data resolve the parameter moving alone,
``(Jᵀ Π J)_jj V_jj >=`` :data:`MIN_RESOLVED`
(elsewhere the estimate ``-(Jᵀ Π d)_j / (Jᵀ Π J)_jj`` is an extrapolation: a ball bar
of five lengths gave ``ryz[2]`` a "significant" 4.6·10⁵ µrad). ``s`` is the posterior
mean, shrunk toward 0 by about the resolved fraction; its uncertainty is the posterior
sd ``u_updated``, not ``u(s)`` (the sd of ``s`` if nothing changed, ``u_null``: the
E_n denominator is ``k u_null``); the alone estimate is unshrunk. Parameters are tested at a
family-wise level by Holm's step-down procedure (Holm 1979) over those the new data
resolve (at least :data:`MIN_RESOLVED` of their prior variance), the joint and the
alone tests each over their own count. In the prior's whitened coordinates
(``V = L Lᵀ``) the eigenvalues of ``Lᵀ Jᵀ Π J L`` are the fractions of the prior
variance the new data resolve along each combination; combinations below
:data:`MIN_RESOLVED` are those the new data cannot determine (a change there is unseen).
Any unit vector of their span is resolved below :data:`MIN_RESOLVED` too (a weighted mean
of their eigenvalues), so their basis is rotated by varimax (Kaiser 1958) to few
parameters per direction before it is said in words (:func:`.unseen.unseen_words`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import linalg, stats

from .._blas import single_blas_thread
from ..export import Model
from .check import InterimCheck
from .numbers import json_num
from .unseen import CARRIER_WEIGHT, combination_text, unseen_example, unseen_words

MIN_RESOLVED = 0.1
"""A parameter (or combination) is tested (seen) when the new data resolve at least this
fraction of its prior variance."""


@dataclass(frozen=True)
class Changes:
    """Outcome of :func:`what_changed`.

    Attributes
    ----------
    message : str
        What moved, at which family-wise level (E_n at ``coverage_factor``), and what
        the new data cannot see, in words.
    family_alpha : float
        Family-wise false-alarm level of the Holm procedure over the tested parameters.
    table : DataFrame
        One row per kinematic parameter: ``label``, ``unit``, ``stored`` (value),
        ``change`` (the posterior mean s of the change: shrunk toward 0 by about
        ``resolved``), ``u_null`` (sd of s if nothing changed: ``k u_null`` is the E_n
        denominator; not the change's uncertainty), ``En`` (``change / (k u_null)``, k the
        ``coverage_factor``), ``p_value`` (two-sided, of ``change / u_null``), ``resolved``
        (fraction of the prior variance the new data resolve), ``tested``,
        ``significant``, ``updated`` (stored + change) and ``u_updated`` (posterior sd:
        the standard uncertainty of the change and of the updated value).
        ``change_alone``, ``u_change_alone``, ``En_alone``, ``p_value_alone`` and
        ``significant_alone``: the same parameter's change if it alone had moved (the
        others as stored; the unshrunk estimate of the score test of ``δ = t e_j``, Holm
        at ``family_alpha``; ``En_alone`` the score over k), the test that names a single
        new effect (a squareness after a crash) with its size; ``resolved_alone``
        (``h_jj V_jj``, its information relative to the prior) and ``tested_alone``
        (``resolved_alone >=`` :data:`MIN_RESOLVED`): untested rows carry NaN.
    significant : list of str
        Parameters that moved beyond their joint uncertainty (Holm, ``family_alpha``).
    significant_alone : list of str
        Parameters whose change alone is significant (Holm, ``family_alpha``), strongest
        first.
    unseen : list of str
        The combinations the new data cannot determine, in words, one per direction
        (:func:`.unseen.unseen_words`), e.g. ``"the z scale and its curvature (dzz linear,
        dzz[2])"``: a basis of the unseen subspace, whose count is a property of the
        design but whose vectors are not unique (any rotation within the subspace is as
        good; this one is varimax-rotated to few parameters each), least resolved first.
    n_tested : int
        Parameters tested jointly.
    posterior_coef : ndarray (k,)
        Stored coefficients plus the change.
    posterior_cov : ndarray (k, k)
        Their posterior covariance.
    n_tested_alone : int
        Parameters tested alone (Holm's m of the one-parameter tests).
    unseen_combinations : list of str
        The same directions as their largest prior-scaled weights, e.g. ``"1.00 sxz -
        0.24 dzx[2]"`` (for experts; the results' ``unseen_combinations``).
    unseen_directions : ndarray (m, k)
        The same directions, one row each over the parameters, in units of each
        parameter's prior standard uncertainty (the largest weight +1).
    coverage_factor : float
        The k of the E_n stated (the check's).
    """

    message: str
    family_alpha: float
    table: pd.DataFrame
    significant: list
    significant_alone: list
    unseen: list
    n_tested: int
    posterior_coef: np.ndarray
    posterior_cov: np.ndarray
    n_tested_alone: int = 0
    unseen_combinations: list = field(default_factory=list)
    unseen_directions: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    coverage_factor: float = 2.0

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        rows = self.table[self.table["significant"]]
        return {"message": self.message, "family_alpha": self.family_alpha,
                "method": "Holm", "coverage_factor": self.coverage_factor,
                "n_tested": self.n_tested,
                "n_tested_alone": self.n_tested_alone,
                "significant": [{k: (json_num(v) if isinstance(v, float | np.floating) else v)
                                 for k, v in r.items()}
                                for r in rows.to_dict("records")],
                "significant_alone": list(self.significant_alone),
                "unseen": list(self.unseen),
                "unseen_combinations": list(self.unseen_combinations)}


@single_blas_thread
def what_changed(model: Model, check: InterimCheck, *, family_alpha: float = 0.05,
                 coverage_factor: float | None = None) -> Changes:
    """The stored model refitted on the check's data with itself as the prior.

    Parameters
    ----------
    model : Model
        The stored calibration the check was made against.
    check : InterimCheck
        :func:`interim_check` of the new data against ``model``.
    family_alpha : float
        Family-wise false-alarm level (Holm over the tested parameters).
    coverage_factor : float, optional
        The k of the E_n stated (ISO/IEC 17043:2010 Annex B: ``E_n = change / (k u)``);
        default the check's (``InterimCheck.coverage_factor``, 2). The tests do not
        depend on it.

    Returns
    -------
    Changes
    """
    if not 0 < family_alpha < 0.5:
        raise ValueError(f"family_alpha must be in (0, 0.5), got {family_alpha}.")
    k = check.coverage_factor if coverage_factor is None else float(coverage_factor)
    if not (np.isfinite(k) and k > 0):
        raise ValueError(f"coverage_factor must be a positive number, got {coverage_factor}.")
    sys = check.system
    V = model.cov
    PiJ = projected(check, sys.J)
    H = sys.J.T @ PiJ  # Jᵀ Π J
    H = (H + H.T) / 2
    # the stored model corrects with c; the machine now has c + δ: d = -J δ + A β + ε
    s = -V @ (PiJ.T @ sys.d_um)
    cov_s = V @ H @ V
    post = V - cov_s
    u_s = np.sqrt(np.clip(np.diag(cov_s), 0, None))
    prior_var = np.clip(np.diag(V), 1e-300, None)
    resolved = np.clip(np.diag(cov_s) / prior_var, 0, 1)
    tested = resolved >= MIN_RESOLVED
    z_joint = np.where(u_s > 0, s / np.where(u_s > 0, u_s, 1), 0.0)  # N(0, 1) if unchanged
    p = 2 * stats.norm.sf(np.abs(z_joint))
    significant = holm(np.where(tested, p, 1.0), int(tested.sum()), family_alpha) & tested
    # one parameter moved alone, the others as stored: the score test of δ = t e_j, only
    # where the data resolve the parameter moving alone (h V_jj >= MIN_RESOLVED: its
    # alone estimate's variance 1/h at most 10 × its prior variance); elsewhere the
    # estimate g/h is an extrapolation of a whisper (a ball bar gave ryz[2] 4.6e5 µrad)
    g_alone = -(PiJ.T @ sys.d_um)
    h = np.clip(np.diag(H), 0, None)
    resolved_alone = h * np.diag(V)
    seen = resolved_alone >= MIN_RESOLVED
    hs = np.where(seen, h, 1.0)
    z = np.where(seen, g_alone / np.sqrt(hs), np.nan)
    p_alone = np.where(seen, 2 * stats.norm.sf(np.abs(np.nan_to_num(z))), np.nan)
    alone = holm(p_alone, int(seen.sum()), family_alpha) & seen
    labels = model.terms.labels
    u_post = np.sqrt(np.clip(np.diag(post), 0, None))
    table = pd.DataFrame({"label": labels, "unit": [model.terms.unit(lab) for lab in labels],
                          "stored": model.coef, "change": s, "u_null": u_s,
                          "En": z_joint / k,
                          "p_value": p, "resolved": resolved, "tested": tested,
                          "significant": significant,
                          "change_alone": np.where(seen, g_alone / hs, np.nan),
                          "u_change_alone": np.where(seen, 1 / np.sqrt(hs), np.nan),
                          "En_alone": z / k, "p_value_alone": p_alone,
                          "resolved_alone": resolved_alone, "tested_alone": seen,
                          "significant_alone": alone,
                          "updated": model.coef + s, "u_updated": u_post})
    directions = _unseen_directions(V, H)
    unseen = unseen_words(directions, labels)
    combinations = [combination_text(v, labels) for v in directions]
    sig = [labels[j] for j in np.flatnonzero(significant)]
    en = f"E_n (k = {k:g})"
    msg = (f"Refit of {model.name} on the new data with the stored model as the prior: "
           f"{int(tested.sum())} of {len(labels)} parameters resolved well enough to test "
           f"(at least {100 * MIN_RESOLVED:g} % of their prior variance); "
           + (f"{len(sig)} moved beyond their joint uncertainty ("
              + ", ".join(f"{lab} by {table.change[j]:+.3g} ± {table.u_updated[j]:.2g} "
                          f"({en} = {table.En[j]:+.1f})"
                          for lab, j in zip(sig, np.flatnonzero(significant), strict=True))
              + ")" if sig else "none moved beyond its joint uncertainty")
           + f" (Holm, family-wise false-alarm level {100 * family_alpha:g} %).")
    best = int(np.argmax(np.where(alone, np.abs(np.nan_to_num(z)), -1)))
    if alone.any():
        msg += (f" Taken alone (the others as stored; {int(seen.sum())} parameter(s) resolved "
                f"enough to test so), {int(alone.sum())} would "
                f"explain a significant part of the change; the strongest: "
                f"{labels[best]} {table.change_alone[best]:+.3g} ± "
                f"{table.u_change_alone[best]:.2g} ({en} = {z[best] / k:+.1f}).")
    if unseen:
        msg += (f" The new data cannot determine {len(unseen)} combination(s) of the "
                f"parameters (a change there is not seen), e.g. {unseen_example(unseen)}.")
    strongest = [labels[j] for j in np.argsort(-np.abs(np.nan_to_num(z))) if alone[j]]
    return Changes(msg, float(family_alpha), table, sig, strongest, unseen, int(tested.sum()),
                   model.coef + s, post, int(seen.sum()), combinations, directions, k)



def projected(check: InterimCheck, X: np.ndarray) -> np.ndarray:
    """``Π X``: the check's pose-projected precision (module docstring) applied to the
    columns ``X`` (rows of the check's system)."""
    g = check.gls
    SiX = linalg.cho_solve(g.factor, X)
    A = check.system.A
    if not A.size:
        return SiX
    SiA = linalg.cho_solve(g.factor, A)
    return SiX - SiA @ np.linalg.solve(A.T @ SiA, A.T @ SiX)


def holm(p: np.ndarray, m: int, alpha: float) -> np.ndarray:
    """Holm's step-down rejections at family-wise level ``alpha`` (Holm 1979): the p-values
    in ascending order are rejected while ``p_(i) <= alpha / (m - i)``; ``m`` is the number
    tested (the others carry p = 1; a NaN or infinite p-value counts as 1, never rejected)."""
    p = np.asarray(p, float)
    p = np.where(np.isfinite(p), p, 1.0)  # NaN (not tested, 0/0) is never a rejection
    order = np.argsort(p)
    reject = np.zeros(p.size, bool)
    for i, j in enumerate(order[:m]):
        if p[j] > alpha / (m - i):
            break
        reject[j] = True
    return reject


def _unseen_directions(V: np.ndarray, H: np.ndarray) -> np.ndarray:
    """The combinations whose prior variance the new data resolve less than
    :data:`MIN_RESOLVED` of (module docstring), one row each over the parameters in units
    of each parameter's prior u, the largest weight +1: the eigenvectors of
    ``Lᵀ H L`` below it (``V = L Lᵀ``), their basis rotated by varimax to few parameters
    each, least resolved first (then fewest parameters carrying it)."""
    w, Q = linalg.eigh((V + V.T) / 2)
    pos = w > w.max() * 1e-12  # directions the prior leaves free (gauge) are no change
    L = Q[:, pos] * np.sqrt(w[pos])
    G = L.T @ H @ L
    mu, U = linalg.eigh((G + G.T) / 2)
    Uk = U[:, mu < MIN_RESOLVED]
    if not Uk.shape[1]:
        return np.zeros((0, len(V)))
    sd = np.sqrt(np.clip(np.diag(V), 0, None))
    # in units of each parameter's prior u; a parameter held fixed (u = 0) carries none
    scale = np.where(sd > sd.max() * 1e-9, 1 / np.where(sd > 0, sd, 1), 0.0)
    B = (L @ Uk) * scale[:, None]
    R = _varimax(B)
    Uk, B = Uk @ R, B @ R
    resolved = np.einsum("ij,ij->j", Uk, G @ Uk)  # each below MIN_RESOLVED (their mean)
    D = B.T
    top = D[np.arange(len(D)), np.argmax(np.abs(D), axis=1)]
    D = D / np.where(top != 0, top, 1)[:, None]
    carriers = (np.abs(D) >= CARRIER_WEIGHT).sum(axis=1)
    return D[np.lexsort((carriers, np.round(resolved, 6)))]


def _varimax(B: np.ndarray, *, iterations: int = 500, tol: float = 1e-10) -> np.ndarray:
    """The orthogonal rotation ``R`` of the columns of ``B`` (parameters × directions)
    that maximises the varimax criterion, the variance of the squared weights of each
    column (Kaiser 1958, Psychometrika 23, 187-200; the SVD iteration): few large weights
    per direction."""
    p, m = B.shape
    R = np.eye(m)
    if m < 2:
        return R
    d = 0.0
    for _ in range(iterations):
        Lam = B @ R
        u, sv, vt = np.linalg.svd(B.T @ (Lam ** 3 - Lam * (np.sum(Lam ** 2, axis=0) / p)))
        R = u @ vt
        if sv.sum() <= d * (1 + tol):
            break
        d = float(sv.sum())
    return R

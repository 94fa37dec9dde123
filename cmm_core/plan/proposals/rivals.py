"""The rivals a measurement should tell apart, and their fits to the current data.

Every set of rivals a diagnosis leaves open (:func:`rival_pairs`, :func:`open_pairs`,
:func:`rivals_of`): its first candidate with all its aliases (two, three or more effects:
the whole alias set, not two of it), its runner-up, an effect standing in for each
placement's own scale against :data:`PLACEMENT_SCALE`, an effect whose addition would
leave combinations undetermined against the :data:`BASELINE`. One error function at two
orders (``rxz:3`` and ``rxz:4``) is one physical function, never two rivals
(:func:`function_of`, :func:`check_rivals`). Each rival fitted to the current data
(:func:`fit_rivals`: its size and the level its nested test is judged at; the placement
scales fitted to the baseline's residual, :class:`ScaleFit`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...diagnosis import FAMILY_ALPHA, SCALE_ALPHA, Diagnosis
from ...diagnosis import scale_columns as placement_scales
from ...io import Dataset
from ...machine import ERROR_NAMES
from ...model import FitResult, Observations, Problem, fit, weighted_residual
from ..detect import candidate_tokens

BASELINE = "baseline"
"""A rival that adds nothing: the model as it is. The rival of an effect whose addition
would leave parameter combinations undetermined (``Candidate.would_leave_undetermined``):
a proposal is scored by the rank the effect then adds (``Proposal.dof``, against the
current data's in the outcome) and its power to be seen; with the baseline true there is
nothing to see, so only the effect's power counts."""

PSEUDO = frozenset({"placement_scale", "baseline"})
"""Rivals that are not model tokens (:data:`PLACEMENT_SCALE`, :data:`BASELINE`): given
second."""

PLACEMENT_SCALE = "placement_scale"
"""A rival that is not a model token: each placement's own scale along each machine axis
it spans (outside the catalogue; the diagnosis's placement-scale test,
``diagnosis.placement_scale_columns``). A new placement brings its own scales."""

SCALE_RTOL = 1e-3
"""Part of a placement-scale column (its norm) that must be left once the baseline's
columns are projected out for that scale to be fitted (``diagnosis.crossval``'s rank
rule)."""


def function_of(token: str) -> str:
    """The physical function a rival token stands for: a kinematic error function without
    its order (``rxz:4`` -> ``rxz``: the same carriage rotation at any order), any other
    token itself (``periodic_x:40`` names a period, another function than
    ``periodic_x:20``; ``probe_offset``, ``drift``)."""
    name, _, _ = str(token).partition(":")
    return name if name in ERROR_NAMES else str(token)


def check_rivals(rivals: Sequence[str]) -> tuple[str, ...]:
    """The rivals as a tuple, checked: two or more, different, each of its own function
    (:func:`function_of`: one function at two orders is not a question between two
    effects), a pseudo-rival (:data:`PSEUDO`) only as the second of two.

    Raises
    ------
    ValueError
        When they are not.
    """
    out = tuple(str(r) for r in rivals)
    if len(out) < 2 or len(set(out)) != len(out):
        raise ValueError(f"expected two or more different rival tokens, got {list(out)}.")
    seen: dict = {}
    for r in out:
        f = function_of(r)
        if f in seen:
            raise ValueError(f"{seen[f]} and {r} are one function ({f}) at two orders: the "
                             "same physical function, not rivals; give rivals of different "
                             "effects or functions (e.g. the verdict's aliases).")
        seen[f] = r
    if out[0] in PSEUDO:
        raise ValueError(f"give {out[0]} as the second rival (after the effect it is "
                         "told apart from).")
    if len(out) > 2 and set(out) & PSEUDO:
        raise ValueError(f"{', '.join(sorted(set(out) & PSEUDO))} is the rival of one "
                         "effect: give it as the second of two rivals.")
    return out


def rival_pairs(candidates: Sequence[Mapping[str, Any]], *, top: int = 3
                ) -> list[tuple[str, ...]]:
    """Every set of rivals a diagnosis leaves open, most pressing first: the first
    candidate with all its aliases (one set: a three-way alias set is one question of
    three rivals, not two pairs of it); its runner-up (the next significant candidate of
    another function); then the alias set of each of the next ``top - 1`` significant
    candidates. Within a set one token per function (:func:`function_of`: an alias that
    is the candidate's own function at another order is the same physical function, left
    out; a set left with one function is no question). Each set once, whichever its
    order, and none that an earlier set holds.

    Parameters
    ----------
    candidates : sequence of mappings
        The diagnosis's ranked candidates as ``Candidate.to_dict`` gives them (at least
        ``effect``, ``aliases`` (list of tokens) and ``significant``); optional
        ``stands_in_for_scale``: true when the placement-scale test found the candidate
        standing in for each placement's own scale (then it and :data:`PLACEMENT_SCALE`
        are a pair, after the aliases); optional ``would_leave_undetermined`` (list):
        the parameter combinations its addition leaves undetermined (then it and
        :data:`BASELINE` are a pair, last).
    top : int
        How many of the first candidates' aliases count.

    Returns
    -------
    list of tuple of str
        Each set, the candidate first (two rivals for a pair, more for a larger alias
        set).
    """
    out: list[tuple[str, ...]] = []

    def add(*names: str) -> None:
        kept: list[str] = []
        for n in map(str, names):
            if all(function_of(n) != function_of(k) for k in kept):
                kept.append(n)
        if len(kept) > 1 and not any(set(kept) <= set(o) for o in out):
            out.append(tuple(kept))

    if not candidates:
        return out
    first = candidates[0]
    add(first["effect"], *first["aliases"])
    name = function_of(first["effect"])
    other = next((c for c in candidates[1:] if c["significant"]
                  and function_of(c["effect"]) != name), None)
    if other is not None:
        add(first["effect"], other["effect"])
    for c in [c for c in candidates[1:] if c["significant"]][:max(top - 1, 0)]:
        add(c["effect"], *c["aliases"])
    for c in candidates[:max(top, 1)]:
        if c.get("stands_in_for_scale"):
            add(c["effect"], PLACEMENT_SCALE)
    for c in candidates[:max(top, 1)]:
        if c.get("would_leave_undetermined"):
            add(c["effect"], BASELINE)
    return out


def open_pairs(diagnosis: Diagnosis | Mapping[str, Any], *, top: int = 3
               ) -> list[tuple[str, ...]]:
    """Every set of rivals a diagnosis leaves open (:func:`rival_pairs`), read from the
    diagnosis itself: each candidate's aliases and significance, whether it stands in
    for each placement's own scale (``HoldoutCheck.stands_in_for_scale``, the rule
    ``diagnosis.crossval.check`` judges by; not merely a failed check), and the combinations its addition would leave
    undetermined (then it and :data:`BASELINE` are a pair). The one rule of the ``next``
    command's default rivals (:func:`rivals_of`) and the app's "Measure next".

    Parameters
    ----------
    diagnosis : Diagnosis or mapping
        A :class:`~cmm_core.diagnosis.Diagnosis`, or its JSON document
        (``Diagnosis.to_dict``, the ``diagnose`` command's output): ``candidates`` as
        ``Candidate.to_dict`` gives them (aliases as a list), ``holdout`` as
        ``HoldoutCheck.to_dict`` (absent: no placement-scale pair).
    top : int
        How many of the first candidates count (:func:`rival_pairs`).
    """
    if isinstance(diagnosis, Diagnosis):
        cands = [{"effect": c.effect, "aliases": list(c.aliases),
                  "significant": bool(c.significant), "level": float(c.level),
                  "would_leave_undetermined": list(c.would_leave_undetermined)}
                 for c in diagnosis.candidates]
        scale = {h.effect: h.stands_in_for_scale for h in diagnosis.holdout}
    else:
        cands = [dict(c) for c in diagnosis.get("candidates") or []]
        scale = {h["effect"]: bool(h.get("stands_in_for_scale"))
                 for h in diagnosis.get("holdout") or []}
    return rival_pairs([{"effect": c["effect"], "aliases": list(c["aliases"]),
                         "significant": bool(c["significant"]),
                         "stands_in_for_scale": scale.get(c["effect"], False),
                         "would_leave_undetermined": list(
                             c.get("would_leave_undetermined") or [])}
                        for c in cands], top=top)


def rivals_of(diagnosis: Diagnosis) -> tuple[str, ...]:
    """The open question of the diagnosis: the first of :func:`open_pairs` for its first
    candidate (``top=1``): it with all its aliases of other functions (two rivals, or
    three or more for a larger alias set), or else the next significant candidate of
    another function (a runner-up), or else :data:`PLACEMENT_SCALE` when it stands in
    for each placement's own scale, or else :data:`BASELINE` when its addition would
    leave combinations undetermined.

    Raises
    ------
    ValueError
        When the diagnosis ranked no candidate or leaves no pair open.
    """
    cands = diagnosis.candidates
    if not cands:
        raise ValueError("the diagnosis ranked no candidate: there is nothing to decide.")
    pairs = open_pairs(diagnosis, top=1)
    if not pairs:
        raise ValueError(f"the diagnosis names {cands[0].effect} with no alias, no "
                         "significant runner-up, no stand-in for the placements' scales "
                         "and nothing left undetermined: there is nothing to decide; give "
                         "the rivals.")
    return pairs[0]


@dataclass(frozen=True)
class RivalFits:
    """The rivals fitted to the current data.

    Attributes
    ----------
    rivals : tuple of str
        The rival tokens (A, B, ...: two, or more for an alias set).
    specs : dict
        Rival -> the baseline with it added (``ModelSpec``).
    fits : dict
        Rival -> its ``FitResult`` on the current data.
    levels : dict
        Rival -> the level its nested tests are judged at: for model tokens the first
        rival's level, every direction (:func:`fit_rivals`).
    """

    rivals: tuple
    specs: dict
    fits: dict
    levels: dict


def fit_rivals(data: Dataset, rivals: Sequence[str], *, baseline: str = "kinematic21", order: int = 2,
               plate: str | None = None, sigma_um: float = 0.5,
               alpha: float = FAMILY_ALPHA) -> RivalFits:
    """Fit the baseline with each rival added to the current data (their fitted sizes),
    and the level each direction is judged at (:func:`_levels`: for two model tokens the
    first rival's, ``detect.candidate_tokens``).

    Raises
    ------
    ValueError
        When the rivals are not different effects (:func:`check_rivals`: a pseudo-rival
        given first, one function at two orders), or a rival token the baseline already
        holds (adding it changes nothing: there would be nothing to tell apart).
    """
    rivals = check_rivals(rivals)
    base = fit(data, baseline, order=order, plate=plate, sigma_um=sigma_um, max_iter=2000)
    spec0 = base.problem.spec
    specs = {r: spec0 if r in PSEUDO else spec0.with_token(r) for r in rivals}
    for r in rivals:
        if r not in PSEUDO and specs[r] == spec0:
            b0 = spec0.to_string()
            raise ValueError(f"{r} is already in the baseline {b0}; give a baseline without "
                             f"it (e.g. '{b0},-{r.partition(':')[0]}').")
    fits = {r: _scale_fit(base) if r == PLACEMENT_SCALE else base if r == BASELINE else
            fit(data, specs[r], plate=base.plate, sigma_um=sigma_um, max_iter=2000,
                certificate_test=False) for r in rivals}
    return RivalFits(tuple(rivals), specs, fits, _levels(base, rivals, alpha))


def _levels(base: FitResult, rivals: Sequence[str], alpha: float) -> dict:
    """Rival -> the level its nested test is judged at (:mod:`.separation`'s docstring): both
    directions of two model tokens at the first rival's own level (its share of
    ``alpha``, ``detect.candidate_tokens``), as the diagnosis's nested tests judge both
    at the level of the candidate it ranks first (``verdict._encompassing``), which is
    the first rival when the rivals are the diagnosis's (:func:`rivals_of`,
    :func:`open_pairs`); :data:`PLACEMENT_SCALE` at the placement-scale test's level
    (``SCALE_ALPHA``, as ``crossval.check`` judges it) and the effect against it at its
    own; :data:`BASELINE` at ``alpha`` (it has nothing to see: not scored)."""
    own = {**candidate_tokens(base, alpha)[2], PLACEMENT_SCALE: SCALE_ALPHA, BASELINE: alpha}
    fallback = alpha / max(len(own), 1)
    a = rivals[0]
    first = float(own.get(a, own.get(a.partition(":")[0], fallback)))
    return {r: float(own[r]) if r in PSEUDO else first for r in rivals}


@dataclass(frozen=True)
class ScaleFit:
    """Each placement's own scale fitted to the baseline's residual (the rival
    :data:`PLACEMENT_SCALE`, linearised at the baseline's fit as the diagnosis's
    placement-scale test): what :class:`RivalFits` reads of a fit.

    Attributes
    ----------
    labels : list of str
        ``<placement>.scale_<axis>`` (:func:`scale_columns`).
    values : ndarray
        Fitted scales (ppm).
    covariance : ndarray
        Their covariance (ppm²) from σ.
    rank_rtol : float
        The baseline fit's rank rule.
    problem : Problem
        The baseline's problem.
    sigma_um : float
        σ of the fit (µm).
    plate : str
        The baseline's plate geometry.
    """

    labels: list
    values: np.ndarray
    covariance: np.ndarray
    rank_rtol: float
    problem: Problem
    sigma_um: float
    plate: str


def _scale_fit(base: FitResult) -> ScaleFit:
    """The placement scales fitted to the baseline's weighted residual with the
    baseline's columns projected out (Frisch-Waugh-Lovell)."""
    r, J = weighted_residual(base.problem, base.state, base.sigma_um, True)[1:]
    J = J.toarray()
    S, labels = scale_columns(base.problem.obs, base.sigma_um, r.size)
    Q, _ = _basis(J, base.rank_rtol)
    norms = np.linalg.norm(S, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    Sp = (S - Q @ (Q.T @ S)) / norms
    # the scales the baseline leaves undetermined (what is left of a column after the
    # baseline is projected out is below SCALE_RTOL of it) are not fitted: zero, zero
    # variance (as the placement-scale test's rank rule)
    U, sv, Vt = np.linalg.svd(Sp, full_matrices=False)
    keep = sv > SCALE_RTOL
    V, inv = Vt[keep].T, 1.0 / sv[keep]
    # r is readings minus model: a placement's scale moves its readings by s (x - x̄)
    values = (V * inv) @ (U[:, keep].T @ r) / norms
    cov = ((V * inv**2) @ V.T) / np.outer(norms, norms)
    return ScaleFit(labels, values, cov, base.rank_rtol, base.problem, base.sigma_um,
                    base.plate)


def scale_columns(obs: Observations, sigma_um: float, n_rows: int
                  ) -> tuple[np.ndarray, list[str]]:
    """Weighted columns of each placement's own scale (1 ppm) along each machine axis it
    spans, rows as the weighted residual's (``diagnosis.scale_columns``, the columns of
    the diagnosis's placement-scale test, for any observations). Labels
    ``<placement>.scale_<axis>``."""
    S, labels = placement_scales(obs, sigma_um, n_rows)
    return S, [f"{name}.scale_{axis}" for name, axis in labels]


def _basis(A: np.ndarray, rtol: float, sv_ref: float | None = None) -> tuple:
    """Orthonormal basis of the column space of ``A`` (columns scaled to unit norm, the
    fit's rank rule: singular values above ``rtol`` times the largest, or ``sv_ref``)."""
    norms = np.linalg.norm(A, axis=0)
    S = A / np.where(norms > 0, norms, 1.0)
    if not S.size:
        return np.zeros((A.shape[0], 0)), 0.0
    U, sv, _ = np.linalg.svd(S, full_matrices=False)
    ref = sv.max() if sv_ref is None else sv_ref
    return U[:, sv > rtol * ref], float(sv.max())

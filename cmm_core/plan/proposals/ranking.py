"""The proposals: each candidate scored by its separation of the rivals
(:mod:`.separation`) and ranked (:func:`propose`; :func:`propose_many` in chunks on Dask).

A candidate decides the pair with power ``min(power_A, power_B)``; an alias set of three
rivals or more with the minimum pairwise power (each rival's power against the rival it
is hardest to tell from, :mod:`.separation`'s docstring), the smallest over the truths. Proposals are ranked
on the powers at the noise-corrected sizes (``Proposal.power_at_size``): those reaching
``target`` power first, by machine time; then the others by power. Not on the assurance:
under the flat prior it credits a candidate for seeing directions the current data leave
loose (the ranking under the hierarchical prior the assurance now takes, :mod:`.separation`,
is not examined) (large sizes there are as likely as small ones), so a rival fitted to nothing but
noise gets a power above :data:`NO_POWER` from a candidate that sees little of it, and
that candidate would outrank one that shows the other rival with certainty (the weak
``rxz:4`` case of bench/proposals.py, seed 9: ``low_x`` at 0.33/0.15 against ``high_x``
at 0.95/0.002; ``high_x`` separates the rivals, ``low_x`` does not).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ..._blas import single_blas_thread
from ...diagnosis import FAMILY_ALPHA, Diagnosis, diagnose
from ...io import DataError, Dataset
from ...model import select
from ..study import dask_client
from .append import _in_machine, _machine, instrument_of, instrument_out_of_reach
from .candidates import FAMILIES, WIDER, NextMeasurement, measurement_candidates
from .rivals import BASELINE, RivalFits, check_rivals, fit_rivals, rivals_of
from .separation import (
    _design,
    _instrument_design,
    _score_candidates,
    _score_on,
    _score_repeats,
    _stack,
)

TARGET_POWER = 0.9
"""Power at which a proposal counts as deciding the pair of rivals."""

NO_POWER = 0.05
"""A power below this (one chance in twenty) decides nothing: the ranking does not tell
such powers apart (:func:`_rank_key`)."""

DECIDE_POWER = 0.8
"""Expected power below which a candidate is not said to decide the pair, whatever the
target (the conventional least power of a study design, Cohen 1988 §2.4): below both it
and the target, a ranking says that nothing decides (``Proposals.decided``) instead of
naming a best next measurement (:func:`decide_bar`)."""

CHUNK = 16
"""Candidates per Dask task of :func:`propose_many`."""


def decide_bar(target: float) -> float:
    """The expected power a proposal needs to be called deciding: the ``target``, or
    :data:`DECIDE_POWER` when the target is above it (a proposal between the two decides,
    short of the target, and is named with its power)."""
    return min(float(target), DECIDE_POWER)


@dataclass(frozen=True)
class Skipped:
    """A candidate not scored, and why.

    Attributes
    ----------
    name : str
        The candidate's name (``NextMeasurement.name``).
    description : str
        The measurement in words.
    family : str
        Its family (``NextMeasurement.family``).
    reason : str
        Why it was not scored: the ball, stylus and scale reading outside the machine's
        stroke (``append.out_of_reach``), the instrument point outside it, or the error
        its simulation raised.
    """

    name: str
    description: str
    family: str
    reason: str

    def to_dict(self) -> dict:
        """JSON-ready record."""
        return {"name": self.name, "description": self.description, "family": self.family,
                "reason": self.reason}

    def line(self) -> str:
        """One line: ``skipped: <name> (<description>): <reason>``."""
        return f"skipped: {self.name} ({self.description}): {self.reason}"


@dataclass(frozen=True)
class Proposal:
    """A candidate measurement scored by how well it separates two rival models.

    Attributes
    ----------
    candidate : NextMeasurement
        The measurement.
    rivals : tuple of str
        The rival tokens (A, B, ...: two, or three or more for an alias set).
    delta_chi2 : dict
        Rival taken as the truth -> expected Δχ² (non-centrality λ) the other rival (of
        three or more: the one it is hardest to tell from) leaves on the noise-free
        augmented data, its size's noise taken out: ``‖M θ̂‖² −
        tr(M C Mᵀ)`` (at least 0), ``C`` the covariance of the fitted ``θ̂``
        (:mod:`.separation`'s docstring).
    dof : dict
        Rival taken as the truth -> (k, ν): numerator and denominator dof of its nested
        F-test.
    level : dict
        Rival taken as the truth -> the level its nested test is judged at (two model
        tokens: both at the first rival's level, as the diagnosis's nested tests).
    power : dict
        Rival taken as the truth -> probability that its nested test rejects the other:
        the expected power over the uncertainty of the rival's fitted size under the
        hierarchical prior of :func:`~.separation._hierarchical_assurance` (the
        "assurance").
    power_min : float
        The smallest of the powers: the probability the pair is decided (of three rivals
        or more: the minimum pairwise power, :mod:`.separation`'s docstring).
    per_minute : float
        The smaller expected Δχ² per minute of machine time.
    outcome : str
        The predicted outcome in words.
    delta_chi2_fitted : dict
        Rival taken as the truth -> Δχ² at exactly its fitted size (``‖M θ̂‖²``): the χ²
        the other rival leaves on noise-free data simulated from the fit.
    own : dict
        Rival -> how many parameters it has that the other has not (on the augmented
        data; a gauge, such as a probe offset's reference, counts too): the rank it adds,
        ``dof[rival][0]``, is what the data determine of them.
    power_at_size : dict
        Rival taken as the truth -> the power at exactly ``delta_chi2`` (the noise-corrected
        size, no spread): what the ranking reads (module docstring); ``power`` is its
        expectation over the size's uncertainty.
    """

    candidate: NextMeasurement
    rivals: tuple
    delta_chi2: dict
    dof: dict
    level: dict
    power: dict
    power_min: float
    per_minute: float
    outcome: str
    delta_chi2_fitted: dict = field(default_factory=dict)
    own: dict = field(default_factory=dict)
    power_at_size: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready record."""
        c = self.candidate
        return {"name": c.name, "description": c.description, "time_min": c.time_min,
                "positions": c.positions, "probes": c.probes, "probes_of": c.probes_of,
                "instrument": c.instrument, "repeat": c.repeat,
                "rivals": list(self.rivals), "delta_chi2": self.delta_chi2,
                "delta_chi2_fitted": self.delta_chi2_fitted, "own_parameters": self.own,
                "dof": {k: list(v) for k, v in self.dof.items()}, "level": self.level,
                "power": self.power, "power_min": self.power_min,
                "power_at_size": self.power_at_size,
                "delta_chi2_per_min": self.per_minute, "outcome": self.outcome}


@dataclass(frozen=True)
class Proposals:
    """Ranked proposals for the next measurement.

    Attributes
    ----------
    rivals : tuple of str
        The rival tokens scored (two, or three or more for an alias set).
    baseline : str
        The baseline the rivals are added to, exactly as given (``"kinematic21,-sxy"``
        stays so, whichever the rivals).
    current : dict
        Rival taken as the truth -> power of its nested test with the current data alone
        (the same formula without a candidate): what the data already decide (not for
        :data:`BASELINE`, which has nothing to see).
    ranked : list of Proposal
        Best first: those reaching ``target`` power by machine time (at equal time by
        power, then Δχ² per minute), then the rest by power. The first need not decide
        (``decided``).
    infeasible : list of Skipped
        The candidates not scored, each with why: outside the machine's strokes (every
        probed ball of every stylus, every instrument point, without slack:
        ``append.out_of_reach``), or failing in the simulation; in candidate order.
    target : float
        Power at which a pair counts as decided.
    message : str
        The conclusion in words: the best next measurement when one decides, else first
        that none does, the best power reached, and the wider families not searched
        (:func:`conclusion`).
    decided : bool
        Whether some proposal reaches the power to decide (:func:`decide_bar`: the
        target, at most :data:`DECIDE_POWER`); when False no proposal is a "best next
        measurement".
    families : tuple of str
        The candidate families scored (``NextMeasurement.family``), in first-seen order.
    """

    rivals: tuple
    baseline: str
    current: dict
    ranked: list
    infeasible: list
    target: float
    message: str = ""
    decided: bool = False
    families: tuple = ()

    @property
    def skipped(self) -> dict:
        """Candidate name -> why it was not scored (``infeasible`` as a mapping)."""
        return {s.name: s.reason for s in self.infeasible}

    def to_dict(self) -> dict:
        """JSON-ready record (``next`` command's output): the conclusion first."""
        return {"message": self.message, "decided": self.decided,
                "rivals": list(self.rivals), "baseline": self.baseline,
                "current_power": self.current, "target_power": self.target,
                "decide_power": decide_bar(self.target),
                "proposals": [p.to_dict() for p in self.ranked],
                "skipped": [s.to_dict() for s in self.infeasible],
                "families": list(self.families)}


def _verdict(cand: NextMeasurement, power_min: float, bar: float) -> str:
    """The end of an outcome: decided with its power, or its power too little (below
    ``bar``: "decided with 0 % power" would call a useless measurement a decision)."""
    if power_min >= bar:
        return f"decided with {100 * power_min:.0f} % power in {cand.time_min:.0f} min"
    return (f"only {100 * power_min:.0f} % power in {cand.time_min:.0f} min, too little to "
            f"decide ({100 * bar:.0f} % needed)")


def _names(rivals: Sequence[str]) -> str:
    """The rivals in words: "A and B", "A, B and C"."""
    rivals = [str(r) for r in rivals]
    return rivals[0] if len(rivals) == 1 else f"{', '.join(rivals[:-1])} and {rivals[-1]}"


def _outcome(cand: NextMeasurement, rivals, lam: dict, power_min: float,
             rank: tuple | None = None, bar: float = DECIDE_POWER) -> str:
    a = rivals[0]
    if rivals[-1] == BASELINE:
        k, k_now = rank or (0, 0)
        return (f"with {cand.description}, the data determine {k} parameter "
                f"combination(s) of {a} ({k_now} now) and it stands out by Δχ² ≈ "
                f"{lam[a]:.0f}: {_verdict(cand, power_min, bar)}")
    each = ", ".join(f"{r} true: {lam[r]:.0f}" for r in rivals)
    # three or more: each pair must differ, and the figure is the hardest pair's
    differ = "differ by" if len(rivals) == 2 else "differ pairwise by at least"
    return (f"with {cand.description}, {_names(rivals)} {differ} Δχ² ≈ "
            f"{min(lam.values()):.0f} ({each}): {_verdict(cand, power_min, bar)}")


def conclusion(rivals: Sequence[str], current: dict, ranked: list, infeasible: list,
               families: Sequence[str], target: float) -> tuple[str, bool]:
    """The conclusion of a ranking in words, and whether a proposal decides.

    When one reaches :func:`decide_bar`'s power: the current data's power and the best
    next measurement (the first in rank order that decides). Else, first, that none
    decides, with the best power reached and by what, then the current data's power, and
    the wider families (:data:`~.candidates.WIDER`: instrument runs, another stylus
    length, a second plate orientation) that were not searched (none of their candidates
    given) or that were out of the machine's reach (all skipped): those might.

    Parameters
    ----------
    rivals : sequence of str
        Two, or three or more for an alias set.
    current : dict
        Rival -> the current data's power (``Proposals.current``).
    ranked : list of Proposal
        Best first.
    infeasible : list of Skipped
    families : sequence of str
        The families scored.
    target : float

    Returns
    -------
    (str, bool)
    """
    a, others = rivals[0], _names(rivals[1:])
    now = (f"the current data decide with {100 * min(current.values()):.0f} % power"
           if current else "the current data decide nothing")
    bar = decide_bar(target)
    deciding = [p for p in ranked if p.power_min >= bar]
    if deciding:
        return (f"{a} against {others}: {now}. Best next measurement: "
                f"{deciding[0].outcome}."), True
    if ranked:
        best = max(ranked, key=lambda p: p.power_min)  # the first of the most powerful
        head = (f"No candidate decides between {_names(rivals)}: the best reaches "
                f"{100 * best.power_min:.0f} % power ({best.candidate.description}, "
                f"{best.candidate.time_min:.0f} min; {100 * bar:.0f} % needed); {now}.")
    else:
        head = (f"No candidate decides between {_names(rivals)}: no candidate measurement "
                f"fits in the machine; {now}.")
    out_of_reach = {s.family for s in infeasible} - set(families)
    unsearched = [f for f in WIDER if f not in families and f not in out_of_reach]
    unreached = [f for f in WIDER if f in out_of_reach]
    if unsearched:
        head += (" Not searched, and might decide: "
                 + "; ".join(FAMILIES[f] for f in unsearched) + ".")
    if unreached:
        head += (" Out of the machine's reach here: "
                 + "; ".join(FAMILIES[f] for f in unreached) + ".")
    return head, False


def _families(cands) -> tuple:
    """The families of ``cands`` in first-seen order."""
    return tuple(dict.fromkeys(c.family for c in cands))


def _proposals(results, rivals, rf: RivalFits, rank_now: int = 0,
               bar: float = DECIDE_POWER) -> list:
    """Proposals from ``(candidate, {rival: (λ, k, ν, power, λ fitted, parameters,
    power at λ)})`` pairs; ``bar``: the power that decides (:func:`decide_bar`)."""
    out = []
    for cand, res in results:
        lam = {t: v[0] for t, v in res.items()}
        power = {t: v[3] for t, v in res.items()}
        # with the baseline true there is nothing to see: the effect's power decides
        pmin = min(v for t, v in power.items() if t != BASELINE)
        lmin = min(v for t, v in lam.items() if t != BASELINE)
        a = rivals[0]
        out.append(Proposal(cand, rivals, lam, {t: (v[1], v[2]) for t, v in res.items()},
                            dict(rf.levels), power, pmin, lmin / cand.time_min,
                            _outcome(cand, rivals, lam, pmin, (res[a][1], rank_now), bar),
                            {t: v[4] for t, v in res.items()},
                            {t: v[5] for t, v in res.items()},
                            {t: v[6] for t, v in res.items()}))
    return out


def _power_max(p: Proposal) -> float:
    """The larger of the two powers at the noise-corrected sizes (the effect's alone
    against :data:`BASELINE`)."""
    return max(v for t, v in _ranked_power(p).items() if t != BASELINE)


def _power_min(p: Proposal) -> float:
    """The smaller of the two powers at the noise-corrected sizes (the effect's alone
    against :data:`BASELINE`)."""
    return min(v for t, v in _ranked_power(p).items() if t != BASELINE)


def _ranked_power(p: Proposal) -> dict:
    """The powers the ranking reads: at the noise-corrected sizes (module docstring)."""
    return p.power_at_size or p.power


def _delta_chi2_max(p: Proposal) -> float:
    """The larger expected Δχ² (of the augmented data: the current data's share too)."""
    return max(v for t, v in p.delta_chi2.items() if t != BASELINE)


def _rank_key(target: float):
    """Ranking: proposals reaching ``target`` power first, by machine time; then the
    others by power; at equal time by power, then by the other direction's power, then
    by the smaller Δχ² per minute, then by the larger Δχ² (when the smaller power is
    below :data:`NO_POWER`: the larger Δχ² first, the smaller being noise), then by
    name (the same order however the candidates were split). Powers are compared in whole percent (as they
    are shown): a smaller difference is none, and powers below :data:`NO_POWER` are all
    alike. The other direction decides when one rival cannot be seen whatever is
    measured (its size fitted to hardly more than noise: its power near the level for
    every candidate, 0.013 against 0.001 being no difference): the pair is then decided,
    if at all, by the other rival standing out, and the candidate that shows it best
    comes first. The powers read are those at the noise-corrected sizes
    (``Proposal.power_at_size``, module docstring)."""
    def pct(x: float) -> float:
        # rounded twice: the same candidate scored in another chunk differs by 1e-15;
        # below NO_POWER nothing is decided: no difference
        x = round(round(x, 9), 2)
        return 0.0 if x < NO_POWER else x

    def key(p: Proposal) -> tuple:
        pmin = _power_min(p)
        seen = pct(pmin) > 0.0
        # the smaller Δχ² per minute while both rivals can be seen; else the other's Δχ²
        size = (-round(p.per_minute, 6), -round(_delta_chi2_max(p), 6)) if seen else \
            (-round(_delta_chi2_max(p), 6), -round(p.per_minute, 6))
        return (pmin < target, p.candidate.time_min if pmin >= target
                else -pct(pmin), -pct(pmin), -pct(_power_max(p)), *size,
                p.candidate.name)

    return key


@single_blas_thread
def propose(data: Dataset, rivals: Sequence[str] | None = None, *, baseline: str = "kinematic21", order: int = 2,
            plate: str | None = None, sigma_um: float = 0.5, alpha: float = FAMILY_ALPHA,
            cands: list | None = None, target: float = TARGET_POWER,
            diagnosis: Diagnosis | None = None) -> Proposals:
    """Rank candidate measurements by how well they decide between rivals.

    Parameters
    ----------
    data : Dataset
        The current measurements (with a certificate of a regular-grid plate).
    rivals : sequence of str, optional
        The rival tokens, two or more (:func:`~.rivals.check_rivals`: each of its own
        function); default the diagnosis's open question, its first candidate with all
        its aliases or its runner-up (:func:`rivals_of`), running ``diagnose`` when
        ``diagnosis`` is None. Three or more are decided with the minimum pairwise power
        (:mod:`.separation`'s docstring).
    baseline, order, plate, sigma_um, alpha
        The diagnosis's settings; ``baseline`` is kept as given in
        ``Proposals.baseline``.
    cands : list of NextMeasurement, optional
        Default :func:`measurement_candidates` of the data.
    target : float
        Power at which a proposal decides the pair.

    Returns
    -------
    Proposals
    """
    if rivals is None:
        diagnosis = diagnosis or diagnose(data, baseline, order=order, plate=plate,
                                          sigma_um=sigma_um, alpha=alpha)
        rivals = rivals_of(diagnosis)
    rivals = check_rivals(rivals)
    rf = fit_rivals(data, rivals, baseline=baseline, order=order, plate=plate,
                    sigma_um=sigma_um, alpha=alpha)
    now = _design(select(data), rf)
    scores_now = _score_on(now, rf)
    current = {t: v[3] for t, v in scores_now.items() if t != BASELINE}
    rank_now = scores_now[rivals[0]][1]
    cands = list(cands if cands is not None else measurement_candidates(data))
    bar = decide_bar(target)
    plates = [c for c in cands if not c.instrument and not c.repeat]
    scored, skipped = [], {}
    for i in range(0, len(plates), CHUNK):  # one simulation and design per chunk
        obs, ok, out = _in_machine(data, plates[i:i + CHUNK])
        skipped.update(out)
        scored += _proposals(_score_candidates(now, obs, ok, rf), rivals, rf, rank_now, bar)
    scored += _proposals(_score_repeats(data, [c for c in cands if c.repeat], rf), rivals,
                         rf, rank_now, bar)
    tools = [c for c in cands if c.instrument]
    if tools:
        sim0, obs_now = _machine(data), select(data)
        scored += _proposals(((c, _score_on(_stack(now, _instrument_design(
            obs_now, now, rf, inst)), rf)) for c, inst in _instruments(data, tools, sim0,
                                                                       skipped)),
            rivals, rf, rank_now, bar)
    scored.sort(key=_rank_key(target))
    infeasible = [Skipped(c.name, c.description, c.family, skipped[c.name]) for c in cands
                  if c.name in skipped]
    families = _families(p.candidate for p in scored)
    msg, decided = conclusion(rivals, current, scored, infeasible, families, target)
    # the baseline as the user gave it: the fitted spec holds the first rival, and a
    # rival the baseline took out ("-sxy") would be lost in it
    given = baseline if isinstance(baseline, str) else baseline.to_string()
    return Proposals(rivals, given, current, scored, infeasible, target, msg, decided,
                     families)


def _instruments(data: Dataset, tools: list, sim0, skipped: dict):
    """``(candidate, instrument)`` of each instrument candidate the machine can read
    (:func:`~.append.instrument_out_of_reach`); the others, and any its simulation
    refuses, are recorded in ``skipped`` with the reason (one never stops the rest)."""
    for c in tools:
        try:
            inst = instrument_of(c, sim0)
        except DataError as exc:
            skipped[c.name] = str(exc)
            continue
        why = instrument_out_of_reach(inst, data.setup.range_mm)
        if why:
            skipped[c.name] = why
            continue
        yield c, inst


def _score_chunk(cands: list, data: Dataset, rivals, settings: dict) -> Proposals:
    """One Dask task of :func:`propose_many` (BLAS single-threaded: ``propose``)."""
    return propose(data, rivals, cands=cands, **settings)


def propose_many(data: Dataset, rivals: Sequence[str], cands: list, *,
                 client: Any = None, scheduler: str | None = None, workers: int = 2,
                 chunk: int = CHUNK, **settings: Any) -> Proposals:
    """:func:`propose` for a large candidate set (e.g. :func:`wide_candidates`), scored
    in chunks of ``chunk`` candidates on Dask: ``client``, else a scheduler address, else
    a ``LocalCluster`` of ``workers`` processes (``study.dask_client``, as the plan
    studies run). ``settings``: :func:`propose`'s keywords. The rivals must be given."""
    if rivals is None:
        raise ValueError("propose_many needs the two rivals (run propose once, or "
                         "rivals_of(diagnosis)).")
    chunks = [cands[i:i + chunk] for i in range(0, len(cands), max(int(chunk), 1))]
    if len(chunks) <= 1:
        return propose(data, rivals, cands=cands, **settings)

    def go(c):
        return c.gather(c.map(_score_chunk, chunks, data=data, rivals=tuple(rivals),
                              settings=settings, pure=False))

    if client is not None:
        parts = go(client)
    else:
        with dask_client(scheduler, workers) as c:
            parts = go(c)
    target = settings.get("target", TARGET_POWER)
    ranked = sorted((p for part in parts for p in part.ranked), key=_rank_key(target))
    infeasible = [s for part in parts for s in part.infeasible]
    first = parts[0]
    families = tuple(dict.fromkeys(f for part in parts for f in part.families))
    msg, decided = conclusion(first.rivals, first.current, ranked, infeasible, families,
                              target)
    return Proposals(first.rivals, first.baseline, first.current, ranked, infeasible,
                     target, msg, decided, families)

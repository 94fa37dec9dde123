"""One headline per verdict: the sentence a person reads first, the same in the app's
Diagnose page, the HTML report and the CLI's ``diagnose --json`` (``"headline"``).

:func:`headline_of` derives it from a :class:`~cmm_core.diagnosis.Diagnosis` (also
``Diagnosis.headline()``), one branch per verdict, tried in this order:

1. ``no_candidates``: no candidate effect left to try;
2. ``flagged_outliers``: flagged outliers hold most of the misfit (``blunders``);
3. ``outside_catalogue``: the misfit is significant and no catalogue effect explains it;
4. ``not_converged``: the best candidate is significant but the baseline fit did not
   converge, so no effect is named;
5. ``named``: the verdict, an effect (with ``alias_of`` when this data cannot tell it
   from others: the headline names the set);
6. ``explained_to_noise``: nothing significant and the baseline passes its χ² test (the
   text lists the baseline's significant terms, squareness first);
7. ``sigma_too_small``: nothing significant and the misfit is spread evenly: the stated
   σ looks too small (with the estimate);
8. ``unexplained``: otherwise.

The numbers are written by :mod:`cmm_core.units` (:func:`~cmm_core.units.number`,
:func:`~cmm_core.units.p_text`, :func:`~cmm_core.units.value_u`): sizes with their u and
unit, no ``-0.0``, no ``p = 0``, no ``± nan``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..machine import SQUARENESS
from ..model import FitResult, catalogue_entry
from ..units import number, p_text, value_u
from .blunders import ACTION, BLUNDERS, BlunderCheck
from .replicates import SigmaEstimate, Uniformity
from .verdict import OUTSIDE, _where_text, fitted_parameters, stylus_text
from .verdict import _Named as _Fitted

HEADLINE_LEVELS = ("success", "info", "warning", "error")
"""The headline's levels, as the app draws them (``st.success`` ... ``st.error``)."""

HEADLINE_VERDICTS = {"no_candidates": "info", "flagged_outliers": "error",
                     "outside_catalogue": "warning", "not_converged": "warning",
                     "named": "success", "explained_to_noise": "info",
                     "sigma_too_small": "warning", "unexplained": "warning"}
"""Each headline verdict code (:attr:`Headline.verdict`) and its level, in the order the
branches are tried (module docstring)."""

SIGNIFICANT_Z = 3.0
"""A fitted term of the baseline is listed as significant when ``|value| / u`` reaches
this (about 0.3 % two-sided for one term alone)."""

MAX_TERMS = 4
"""At most this many significant terms are listed in the explained-to-noise headline."""

SETUP_GROUPS = frozenset({"plate", "rotation", "translation"})
"""Parameter blocks that are the plate's geometry and the placements, not the machine's
errors: never listed among the significant terms."""


class _Named(_Fitted, Protocol):
    """What the headline reads of a candidate (``search.Candidate``)."""

    @property
    def title(self) -> str: ...
    @property
    def separate_by(self) -> str: ...
    @property
    def delta_chi2(self) -> float: ...
    @property
    def n_params(self) -> int: ...
    @property
    def delta_bic(self) -> float: ...
    @property
    def p_value(self) -> float: ...
    @property
    def chi2_dof(self) -> float: ...
    @property
    def significant(self) -> bool: ...


class _Diagnosed(Protocol):
    """What the headline reads of a diagnosis (``search.Diagnosis``)."""

    @property
    def baseline(self) -> FitResult: ...
    @property
    def candidates(self) -> list: ...
    @property
    def verdict(self) -> str | None: ...
    @property
    def sigma(self) -> SigmaEstimate | None: ...
    @property
    def uniformity(self) -> Uniformity | None: ...
    @property
    def where(self) -> dict: ...
    @property
    def blunders(self) -> BlunderCheck | None: ...


@dataclass(frozen=True)
class Headline:
    """The diagnosis's verdict in one message: what the app draws first, the report
    shows above the candidates and ``diagnose --json`` carries as ``"headline"``.

    Attributes
    ----------
    verdict : str
        A short code, one per branch (:data:`HEADLINE_VERDICTS`): ``no_candidates``,
        ``flagged_outliers``, ``outside_catalogue``, ``not_converged``, ``named``,
        ``explained_to_noise``, ``sigma_too_small``, ``unexplained``.
    level : str
        ``"success"``, ``"info"``, ``"warning"`` or ``"error"``
        (:data:`HEADLINE_LEVELS`): how the app draws it.
    title : str
        One line, e.g. ``"Most likely missing: probe offset error"``; with aliases the
        set, ``"Most likely missing: probe offset error or drift with time: this data
        cannot decide — see Measure next"``.
    text : str
        Plain sentence(s): the size with its u and unit, the evidence (ΔBIC and p), or
        what the verdict rests on.
    action : str
        The one next step, in plain words.
    alias_of : tuple of str
        Effects (model tokens) this data cannot tell apart from the named one; empty
        when there are none or no effect is named.
    """

    verdict: str
    level: str
    title: str
    text: str
    action: str
    alias_of: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        """JSON-ready: ``verdict``, ``level``, ``title``, ``text``, ``action``,
        ``alias_of`` (a list)."""
        return {"verdict": self.verdict, "level": self.level, "title": self.title,
                "text": self.text, "action": self.action, "alias_of": list(self.alias_of)}


def headline_of(d: _Diagnosed) -> Headline:
    """The headline of a diagnosis: the first branch of the module docstring whose
    condition holds.

    Parameters
    ----------
    d : Diagnosis
        What :func:`~cmm_core.diagnosis.diagnose` returned.

    Returns
    -------
    Headline
    """
    base, cands = d.baseline, d.candidates
    if not cands:
        return _no_candidates(base)
    best = cands[0]
    named = best.effect == d.verdict
    if d.verdict == BLUNDERS:
        return _blunders(d.blunders)
    if d.verdict == OUTSIDE:
        return _outside(base, cands, d.where)
    if best.significant and not named and d.verdict is None:
        return _not_converged(base)
    if named:
        return _named(best)
    if not base.fails_chi2_test:
        return _explained(base)
    if d.sigma is not None and d.uniformity is not None and d.uniformity.uniform:
        return _sigma(base, d.sigma)
    return _make("unexplained", "No catalogue effect explains the misfit",
                 f"No candidate is significant, yet χ²/dof is {number(base.chi2_dof, '.1f')} "
                 f"({p_text(base.chi2_p_value)})"
                 + ("" if base.status == "converged" else
                    f"; the baseline fit did not converge ({base.status})") + ".",
                 "Read the diagnosis's conclusion for what to try next.")


def _make(verdict: str, title: str, text: str, action: str,
          alias_of: Sequence[str] = ()) -> Headline:
    return Headline(verdict, HEADLINE_VERDICTS[verdict], title, text, action, tuple(alias_of))


def _test_words(base: FitResult) -> str:
    """``χ²/dof 1.02, p = 0.41``: the statistic the χ² test decides on."""
    return f"χ²/dof {number(base.chi2_test_dof, '.2f')}, {p_text(base.chi2_p_value)}"


def _title_of(token: str) -> str:
    """The catalogue's title of an effect token; the token itself if it has none."""
    try:
        return catalogue_entry(token).title
    except (KeyError, ValueError):
        return token


def _either(names: Sequence[str]) -> str:
    """``a``, ``a or b``, ``a, b or c``."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]


def _no_candidates(base: FitResult) -> Headline:
    passes = not base.fails_chi2_test
    return _make("no_candidates", "No candidate effect left to try",
                 "Every catalogue effect this data can see is in the model already or was "
                 f"skipped; the baseline {'passes' if passes else 'fails'} its χ² test "
                 f"({_test_words(base)}).",
                 "Nothing to add from the catalogue: use this model." if passes else
                 "Look at the residual maps and check σ: the catalogue has nothing left to "
                 "add.")


def _blunders(b: BlunderCheck | None) -> Headline:
    text = ("Flagged outliers hold most of the misfit." if b is None else
            f"{len(b.exclusions)} observation(s) flagged as gross errors hold "
            f"{100 * b.chi2_share:.0f} % of the baseline's χ² ({100 * b.excess_share:.0f} % "
            f"of its misfit above noise): {b.text()}.")
    return _make("flagged_outliers", "Flagged outlier(s) first",
                 text + " No effect is named and σ is not estimated from these residuals, "
                 "which the outliers dominate.",
                 ACTION[:1].upper() + ACTION[1:] + ".")


def _outside(base: FitResult, cands: list, where: dict) -> Headline:
    if base.fails_chi2_test:
        text = (f"The misfit is significant ({_test_words(base)}) and no catalogue effect "
                "explains it")
        failed = [c.effect for c in cands if c.significant]
        if failed:
            text += (f": {', '.join(failed[:3])} fail the leave-one-placement-out check "
                     "(fitted on the other placements they do not predict the held-out one)")
        text += "."
    else:
        text = ("The χ² test passes, but each placement's own scale is significant with no "
                "effect added: the placements read lengths with different scales.")
    loc = _where_text(where or {})
    if loc:
        text += f" Where the residual lives: {loc}."
    return _make("outside_catalogue", "Outside the catalogue", text,
                 "Look at the residual maps and the evidence tables: a blunder, a "
                 "certificate entry, or an effect the catalogue does not hold (a local error "
                 "of one axis, a placement's own scale or temperature).")


def _not_converged(base: FitResult) -> Headline:
    return _make("not_converged", "No effect is named: the baseline fit did not converge",
                 f"The baseline fit stopped ({base.status}, {base.iterations} iterations): "
                 "the candidates' χ² reductions include its unfinished improvement, so none "
                 "is credited.",
                 "Simplify the baseline (lower order, fewer functions) or add placements, "
                 "and diagnose again.")


def _size_text(c: _Named) -> str:
    """`` Size: plate_sag.uu = -2.01 ± 0.05 µm, plate_sag.vv = -1.5 ± 0.05 µm.``: the
    added parameters largest against their u (``verdict.fitted_parameters``); a probe
    offset's stylus furthest off (``verdict.stylus_text``); a u not determinable says
    why."""
    if not c.fitted:
        return " Its size is not estimated (no full refit of it)."
    if c.effect == "probe_offset":
        return " " + stylus_text(c, "each stylus relative to the mean of all") + "."
    n = len(c.fitted)
    return (" Size: " + ", ".join(fitted_parameters(c, 2))
            + (f" (2 of its {n} parameters)" if n > 2 else "") + ".")


def _named(best: _Named) -> Headline:
    tok = best.effect
    evidence = (f"adding {tok} lowers χ² by {number(best.delta_chi2, '.1f')} for "
                f"{best.n_params} parameter(s): ΔBIC {number(best.delta_bic, '.1f')}, "
                f"{p_text(best.p_value)}.")
    aliases = list(best.aliases)
    if aliases:
        names = [best.title, *(_title_of(a) for a in aliases)]
        title = (f"Most likely missing: {_either(names)}: this data cannot decide — see "
                 "Measure next")
        text = (f"{best.title[:1].upper() + best.title[1:]} ({tok}) cannot be told apart "
                f"from {_either(aliases)} with this data; {evidence}{_size_text(best)}")
        why = best.separate_by.rstrip(". ")
        action = ("Before adding either, measure what tells them apart"
                  + (f": {why[:1].lower() + why[1:]};" if why else "")
                  + " see Measure next.")
        return _make("named", title, text, action, aliases)
    text = evidence[:1].upper() + evidence[1:] + _size_text(best)
    if best.chi2_dof > 1.3:
        action = (f"Add {tok} to the model and run the diagnosis again: with it χ²/dof is "
                  f"still {number(best.chi2_dof, '.2f')}, so more is missing.")
    else:
        action = f"Add {tok} to the model (with it χ²/dof is {number(best.chi2_dof, '.2f')})."
    return _make("named", f"Most likely missing: {best.title}", text, action)


def significant_terms(base: FitResult, z: float = SIGNIFICANT_Z) -> list:
    """The baseline's fitted terms at least ``z`` standard uncertainties from zero, as
    ``(name, unit, value, u)``: squareness first, then largest ``|value| / u`` first. The
    plate's geometry and the placements (:data:`SETUP_GROUPS`) are not machine terms and
    are left out, as are terms whose u is not determinable.

    Parameters
    ----------
    base : FitResult
    z : float
        The threshold on ``|value| / u`` (default :data:`SIGNIFICANT_Z`).

    Returns
    -------
    list of tuple
        ``(name, unit, value, u)``; ``name`` is the catalogue's title of a squareness
        (``squareness XY``) and the parameter's label otherwise (``dxx[1]``,
        ``plate_sag.uu``).
    """
    out = []
    for lab, unit, group, v, u in zip(base.labels, base.units, base.groups, base.values,
                                      base.u, strict=True):
        if group in SETUP_GROUPS or not (np.isfinite(u) and u > 0) or abs(v) < z * u:
            continue
        square = group == "kinematic" and lab in SQUARENESS
        out.append((not square, -abs(v) / u,
                    (_title_of(lab) if square else lab, unit, float(v), float(u))))
    return [t for *_, t in sorted(out, key=lambda e: (e[0], e[1]))]


def _explained(base: FitResult) -> Headline:
    text = (f"No candidate is significant and the fit passes its χ² test "
            f"({_test_words(base)}): the data are explained to noise by this model.")
    terms = significant_terms(base)
    if terms:
        more = len(terms) - MAX_TERMS
        text += (" Significant in the model: "
                 + ", ".join(f"{name} {value_u(v, u, unit)}"
                             for name, unit, v, u in terms[:MAX_TERMS])
                 + (f" and {more} more" if more > 0 else "") + ".")
    return _make("explained_to_noise", "Explained to noise", text,
                 "Nothing to add: use this model (its uncertainties, compensation and "
                 "export).")


def _sigma(base: FitResult, s: SigmaEstimate) -> Headline:
    return _make("sigma_too_small", "σ looks too small",
                 "No candidate is significant and the misfit is spread evenly: the stated "
                 f"σ = {number(base.sigma_um)} µm looks too small. Estimated from the data: "
                 f"σ = {value_u(s.value_um, s.u_um, 'um')} ({s.detail}).",
                 f"Refit with σ = {number(s.value_um)} µm, or find why the machine repeats "
                 "worse than stated.")

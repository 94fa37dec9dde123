"""An interim check's full outcome: the test, what changed, the new effect named by the
diagnosis, what the check cannot see, and conformity (issue 28, docs/monitoring.md).

The new effect. The new data are corrected by the stored model (each probed tip replaced
by the model's true tip ``x*(r − p, p')``, thesis eq. 4.13), so what is left is what the
stored model does not explain; the diagnosis (``diagnosis.diagnose``) then runs on them
against the rigid baseline (each placement's pose only, the plate fixed to its
certificate) and names the missing effect as it names effects in a calibration: a new
squareness after a crash as ``sxy``, a drift as ``drift``, with its fitted size. The
diagnosis counts σ and the certificate but not the stored model's own uncertainty
(``J V Jᵀ``): a kinematic parameter of the stored model it names is confirmed only when
the V-aware test of that parameter alone (``changes.what_changed``, Holm) is significant
too; an effect outside the stored model (a drift) has no stored uncertainty to count.

The verdict in one word (:data:`VERDICTS`): ``"no change seen"`` when the χ² test passes
and the check sees every combination of the stored model's parameters; ``"partial: no
change seen in what was measured"`` when it passes but some combinations are unseen (a
change there would pass unnoticed: never "conforms"); ``"changed"`` when the test fails.

The test is two, at one stated level (:data:`TEST_RULE`): the χ² test of all the new data
(an omnibus test, right for a change of no particular form) at ``alpha (1 -``
:data:`TARGETED_SHARE` ``)``, and the fewest physical changes (``explain.explain_change``:
a scale, a squareness, an error function, a stylus, each a test of a few degrees of
freedom) at ``alpha`` :data:`TARGETED_SHARE` (Bonferroni over the hypotheses at its first
step). The machine changed when either rejects; by Bonferroni the false-alarm rate on an
unchanged machine is at most ``alpha``. The χ² test alone spread a single parameter's
change over the check's 23-32 degrees of freedom: a 3 u yaw was seen in 78-84 % of checks
and a stylus bent by 7-10 u in 38-83 %; the targeted test sees both in every seed tried
(``bench/explain.py``, docs/validation.md).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..diagnosis import Diagnosis, diagnose
from ..export import Model
from ..io import Dataset
from ..machine import kinematics as kin
from ..units import p_text
from .blunder import Blunder, find_blunders
from .changes import MIN_RESOLVED, Changes, what_changed
from .check import InterimCheck, en_definition, interim_check
from .conformity import RULE, Conformity, conformity
from .explain import ChangeExplanation, explain_change
from .numbers import json_num
from .unseen import unseen_example

TARGETED_SHARE = 0.5
"""Share of the check's level ``alpha`` given to the fewest-changes test (module
docstring); the χ² test has the rest."""
TEST_RULE = ("the machine no longer behaves as the stored model predicts when P(χ²_dof > χ²) "
             "< alpha (1 − targeted_share), χ² the generalised least-squares residual of the "
             "new data with the covariance σ² I + J V Jᵀ + K U_cert Kᵀ (each placement's pose "
             "fitted; dof = rows − 6 per placement), or when the fewest physical changes "
             "(forward nested tests of a scale, a squareness, an error function, a stylus; "
             "Bonferroni over the hypotheses tried) name a change at alpha targeted_share: "
             "family-wise at most alpha on an unchanged machine (Bonferroni)")
"""The interim check's decision rule, as the results document states it."""
CHANGE_RULE = ("a parameter moved when the two-sided p-value of its standard score "
               "z = s / u_null (s the posterior mean of the change, shrunk toward 0, of the "
               "stored model refitted on the new data with itself as the prior; u_null the "
               "sd of s if nothing changed; z standard normal then) is rejected by Holm's "
               "step-down procedure at family_alpha over the parameters the new data "
               f"resolve (at least {100 * MIN_RESOLVED:g} % of their prior variance); En is "
               "stated at the coverage factor k, E_n = z / k (ISO/IEC 17043 Annex B, "
               "expanded uncertainties at k); standard_uncertainty is the posterior sd; "
               "*_alone: the same parameter's unshrunk change had it alone moved (score "
               "test, Holm at family_alpha over the parameters resolved alone, at least "
               f"{100 * MIN_RESOLVED:g} % of their prior variance)")
"""The parameter changes' decision rule, as the results document states it."""
VERDICTS = ("no change seen", "partial: no change seen in what was measured", "changed")
"""The one-line verdicts of :class:`CheckOutcome`."""


@dataclass(frozen=True)
class NewEffects:
    """The diagnosis of the new data against the stored model (module docstring).

    Attributes
    ----------
    message : str
        The effects named, with their sizes, or why none is.
    named : list of dict
        One per significant effect the diagnosis names, best first: ``effect`` (the
        diagnosis's token, e.g. ``sxy``, ``drift``), ``title``, ``fitted`` (label ->
        ``{unit, value, u}``), ``p_value``, ``in_stored_model`` (its parameters are the
        stored model's) and ``confirmed`` (the V-aware test agrees; always True for an
        effect outside the stored model).
    verdict : str or None
        The diagnosis's verdict token (``Diagnosis.verdict``).
    cannot_see : dict
        Effects the check's design cannot see (``Diagnosis.unseen``), with the reason.
    diagnosis : Diagnosis or None
        The diagnosis itself; None when the check has no plate data.
    """

    message: str
    named: list
    verdict: str | None
    cannot_see: dict
    diagnosis: Diagnosis | None

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"message": self.message, "named": list(self.named), "verdict": self.verdict,
                "cannot_see": dict(self.cannot_see),
                "baseline": "the stored model (its residuals: the rigid poses only)"}


def name_new_effects(model: Model, check: InterimCheck, changes: Changes, *,
                     alpha: float | None = None) -> NewEffects:
    """The diagnosis of ``check``'s plate data against ``model`` as the baseline.

    Parameters
    ----------
    model : Model
        The stored calibration of the check.
    check : InterimCheck
        :func:`interim_check` of the new data against ``model``.
    changes : Changes
        :func:`what_changed` of the same check (its V-aware tests confirm the effects of
        the stored model's parameters).
    alpha : float, optional
        The diagnosis's family-wise level (default its own, ``diagnosis.FAMILY_ALPHA``).

    Returns
    -------
    NewEffects
    """
    obs = check.system.obs
    if not len(obs.r_mm):
        return NewEffects("The diagnosis names effects from ball-plate data; this check has "
                          "instruments only (what changed is told by the parameters above).",
                          [], None, {}, None)
    p = np.array([model.probes_mm[q] for q in obs.probes], float)[obs.probe]
    true_tip = kin.model_point(model.terms, model.coef, obs.r_mm - obs.p_mm, p)
    corrected = replace(obs, r_mm=true_tip + (obs.p_mm - p), instruments=())
    kw: dict[str, Any] = {} if alpha is None else {"alpha": alpha}
    diag = diagnose(corrected, "rigid", plate="fixed", sigma_um=check.sigma_um, **kw)
    labels = set(model.terms.labels)
    alone = changes.table.set_index("label")["significant_alone"]
    named = []
    for c in diag.candidates:
        if not c.significant:
            continue
        fitted = {lab: {"unit": unit, "value": float(v), "u": float(u)}
                  for lab, (unit, v, u) in c.fitted.items()}
        own = bool(fitted) and all(lab in labels for lab in fitted)
        confirmed = (not own) or any(bool(alone.get(lab, False)) for lab in fitted)
        named.append({"effect": c.effect, "title": c.title, "fitted": fitted,
                      "p_value": float(c.p_value), "in_stored_model": own,
                      "confirmed": confirmed})
    named.sort(key=lambda e: (not e["confirmed"]))
    shown = [e for e in named if e["confirmed"]]
    if diag.verdict is not None and shown and shown[0]["effect"] != diag.verdict:
        shown.sort(key=lambda e: e["effect"] != diag.verdict)
    if shown:
        best = shown[0]
        size = ", ".join(f"{lab} {f['value']:+.3g} ± {f['u']:.2g} {_unit(f['unit'])}"
                         for lab, f in best["fitted"].items())
        msg = (f"The diagnosis of the new data against the stored model names "
               f"{best['title']} ({best['effect']}{': ' + size if size else ''})"
               + (f"; other candidates explain part of the same pattern: "
                  f"{', '.join(e['effect'] for e in shown[1:4])}" if len(shown) > 1 else "")
               + ".")
    else:
        msg = ("The diagnosis of the new data against the stored model names no new "
               "effect" + (" (the effects of the stored model's parameters it found are "
                           "within the stored model's own uncertainty)" if named else "")
               + ".")
    if diag.unseen:
        msg += (f" This check cannot see {len(diag.unseen)} candidate effect(s) at all (e.g. "
                f"{next(iter(diag.unseen))}: {next(iter(diag.unseen.values()))}).")
    return NewEffects(msg, shown + [e for e in named if not e["confirmed"]], diag.verdict,
                      dict(diag.unseen), diag)


def _unit(code: str) -> str:
    """A unit code as printed (``urad`` -> ``µrad``)."""
    return {"urad": "µrad", "um": "µm"}.get(code, code)


@dataclass(frozen=True)
class CheckOutcome:
    """Everything an interim check reports (:func:`run_check`).

    Attributes
    ----------
    verdict : str
        One of :data:`VERDICTS`.
    message : str
        The verdict in one paragraph, with what the check could not see.
    check : InterimCheck
        The χ² test and the E_n table.
    changes : Changes
        The stored model refitted on the new data with itself as the prior.
    effects : NewEffects or None
        The diagnosis of the new data against the stored model (None when not asked).
    conformity : Conformity or None
        The ISO 14253-1 statement (None without an MPE or without a plate).
    explanation : ChangeExplanation or None
        The fewest physical changes that explain the new data (None when the check
        passes): what the message names first.
    blunders : tuple of Blunder
        Ball centres left out as probable blunders (:mod:`.blunder`): the check, the
        changes and the verdict are of the data without them.
    """

    verdict: str
    message: str
    check: InterimCheck
    changes: Changes
    effects: NewEffects | None
    conformity: Conformity | None
    explanation: ChangeExplanation | None = None
    blunders: tuple = ()

    def results_section(self) -> dict:
        """The "interim_check" section of the results document (``export.results_dict``):
        the test with the largest E_n at the check's coverage factor, each tested
        parameter's change with its standard uncertainty (the posterior sd) and its
        ``u_null`` (the sd of the change if nothing changed: ``E_n = change / (k
        u_null)``), what the check cannot see in words (``unseen``) and as prior-scaled
        weights (``unseen_combinations``), the new effect, conformity, each with its
        decision rule; numbers JSON-safe (NaN: null)."""
        c, ch = self.check, self.changes
        tested = ch.table[ch.table["tested"]]
        return {
            "model": c.model_name, "verdict": self.verdict, "message": self.message,
            "coverage_factor": c.coverage_factor,
            "test": {"statistic": "chi2", "chi2": json_num(c.chi2), "dof": c.dof,
                     "p_value": json_num(c.p_value), "alpha": c.alpha,
                     "passes": c.passes, "decision_rule": TEST_RULE,
                     "targeted_share": TARGETED_SHARE,
                     "level": json_num(c.alpha / (1.0 - TARGETED_SHARE)),
                     "changed": self.verdict == VERDICTS[2],
                     "coverage_factor": c.coverage_factor,
                     "En_definition": en_definition(c.coverage_factor),
                     "largest_En": [{"position": str(r.position), "probe": str(r.probe),
                                     "ball": int(r.ball), "En": json_num(r.En)}
                                    for r in c.largest_En(10).itertuples()],
                     "sigma_um": json_num(c.sigma_um), "n_ball_centres": len(c.table),
                     "positions": list(c.positions),
                     "coverage_95": json_num(c.coverage_95),
                     "instruments": [{k: (json_num(v) if isinstance(v, float) else v)
                                      for k, v in r.items()}
                                     for r in c.instruments.to_dict("records")]},
            "changes": {"family_alpha": ch.family_alpha, "method": "Holm",
                        "decision_rule": CHANGE_RULE, "coverage_factor": ch.coverage_factor,
                        "n_tested": ch.n_tested,
                        "n_tested_alone": ch.n_tested_alone,
                        "parameters": [
                            {"name": r.label, "unit": r.unit, "stored": json_num(r.stored),
                             "change": json_num(r.change),
                             "standard_uncertainty": json_num(r.u_updated),
                             "u_null": json_num(r.u_null),
                             "En": json_num(r.En), "significant": bool(r.significant),
                             "change_alone": json_num(r.change_alone),
                             "standard_uncertainty_alone": json_num(r.u_change_alone),
                             "significant_alone": bool(r.significant_alone),
                             "resolved": json_num(r.resolved)}
                            for r in tested.itertuples()],
                        "unseen": list(ch.unseen),
                        "unseen_combinations": list(ch.unseen_combinations)},
            "explanation": None if self.explanation is None else self.explanation.to_dict(),
            "blunders": [b.to_dict() for b in self.blunders],
            "new_effects": None if self.effects is None else self.effects.to_dict(),
            "conformity": None if self.conformity is None else self.conformity.to_dict()}

    def to_dict(self) -> dict:
        """JSON-ready summary (the ``check`` command's output)."""
        return {"verdict": self.verdict, "message": self.message,
                "check": self.check.to_dict(), "changes": self.changes.to_dict(),
                "explanation": None if self.explanation is None
                else self.explanation.to_dict(),
                "blunders": [b.to_dict() for b in self.blunders],
                "new_effects": None if self.effects is None else self.effects.to_dict(),
                "conformity": None if self.conformity is None else self.conformity.to_dict()}


def scale_temperatures(dataset: Dataset | None, positions: Sequence[str]) -> dict:
    """Axis -> mean recorded temperature of its scale (°C) over the readings of
    ``positions``: the ``temp_x_C``, ``temp_y_C``, ``temp_z_C`` columns the data have
    (none: an empty dict)."""
    if dataset is None:
        return {}
    m = dataset.meas
    rows = m[m["position"].astype(str).isin([str(p) for p in positions])]
    out = {}
    for a in "xyz":
        col = f"temp_{a}_C"
        if col in rows and rows[col].notna().all() and len(rows):
            out[a] = float(rows[col].astype(float).mean())
    return out


def run_check(model: Model, dataset: Dataset | None, *, instruments: Sequence = (),
              sigma_um: float | None = None, alpha: float = 0.05,
              family_alpha: float = 0.05, positions: Sequence[str] | None = None,
              mpe: tuple[float, float] | None = None, name_effects: bool = True,
              probes: Sequence[str] | None = None, exclude: Iterable[Sequence] = (),
              coverage_factor: float = 2.0) -> CheckOutcome:
    """The interim check, what changed, the new effect and (with ``mpe``) conformity.

    Parameters
    ----------
    model : Model
        The stored calibration.
    dataset : Dataset or None
        The new ball-plate data (None: instruments only).
    instruments : sequence
        Laser runs, step gauges, ball bars of the check (``interim_check``).
    sigma_um, alpha, positions, probes, exclude
        As :func:`interim_check`: the selection of the new data and the observations
        left out (an analysis's exclusions), so the check tests the data its fit used.
    coverage_factor : float
        k of the E_n stated by the check and the changes (``E_n = residual / (k u)``,
        ISO/IEC 17043:2010 Annex B; default 2 as EA-4/02 states expanded
        uncertainties). The tests do not depend on it.
    family_alpha : float
        Family-wise level of :func:`what_changed`.
    mpe : (float, float), optional
        ``(A µm, D)``: MPE = A + L/D, the conformity statement's limit.
    name_effects : bool
        Run the diagnosis of the new data against the stored model when the test fails.

    Returns
    -------
    CheckOutcome
    """
    exclude = list(exclude)
    chi2_alpha = alpha * (1.0 - TARGETED_SHARE)

    def checked(more: list) -> InterimCheck:
        return interim_check(model, dataset, sigma_um=sigma_um, alpha=chi2_alpha,
                             positions=positions, probes=probes, instruments=instruments,
                             exclude=exclude + more, coverage_factor=coverage_factor)

    check = checked([])
    blunders: list[Blunder] = []
    if not check.passes and dataset is not None:
        # a misprobe before the machine is blamed: named only when the check without
        # it passes (.blunder)
        blunders, check = find_blunders(check, checked, chi2_alpha)
    changes = what_changed(model, check, family_alpha=family_alpha)
    temps = scale_temperatures(dataset, check.positions)
    explanation: ChangeExplanation | None
    if check.passes:
        # the targeted half of the test: a change of a few parameters the χ² test's
        # many degrees of freedom dilute
        targeted = explain_change(model, check, alpha=alpha * TARGETED_SHARE,
                                  scale_temps_C=temps)
        explanation = targeted if targeted.first is not None else None
    else:
        explanation = explain_change(model, check, alpha=family_alpha, scale_temps_C=temps)
    changed = not check.passes or explanation is not None
    effects = None
    if name_effects and changed:
        effects = name_new_effects(model, check, changes)
    conf = None
    if mpe is not None:
        if dataset is None:
            conf = Conformity("cannot say", f"Cannot say whether the machine conforms to "
                              f"MPE = {mpe[0]:g} µm + L/{mpe[1]:g} (L in mm): the check has no plate "
                              "lengths to decide on, and it cannot see "
                              f"{len(changes.unseen)} combination(s) of the machine's errors."
                              , {}, None, RULE, list(changes.unseen))
        else:
            conf = conformity(model, check, dataset, mpe_a_um=mpe[0], mpe_per_mm=1 / mpe[1],
                              changes=changes)
    said = ""
    if blunders:
        said = (f"Probable blunder{'s' if len(blunders) > 1 else ''}: "
                + "; ".join(b.text() for b in blunders)
                + f" (beyond the single-outlier bound of the check's coordinates at "
                f"{100 * alpha:g} %); without {'them' if len(blunders) > 1 else 'it'} the "
                f"check passes (χ² = {check.chi2:.1f} for {check.dof} degrees of freedom, "
                f"{p_text(check.p_value)}). Re-measure "
                f"{'them' if len(blunders) > 1 else 'it'}; what follows is of the data "
                f"without {'them' if len(blunders) > 1 else 'it'}. ")
    if changed:
        verdict = VERDICTS[2]
        seen_by = "" if not check.passes else (
            f"The χ² test of all the new data passes at its share of the level "
            f"(χ² = {check.chi2:.1f} for {check.dof} degrees of freedom, "
            f"{p_text(check.p_value)} ≥ {chi2_alpha:g}), but the test of the fewest "
            f"physical changes names one at its share ({alpha * TARGETED_SHARE:g}). ")
        # the fewest changes first, in physical terms; the parameter-by-parameter
        # refit after it, for the expert
        msg = ("The machine changed. " + seen_by
               + (explanation.message if explanation else "")
               + " Parameter by parameter: " + changes.message)
        if effects is not None:
            msg += " " + effects.message
    elif changes.unseen:
        verdict = VERDICTS[1]
        msg = (f"No change seen in what this check measures, but it cannot see "
               f"{len(changes.unseen)} combination(s) of the stored model's parameters (e.g. "
               f"{unseen_example(changes.unseen)}): a change there would pass unnoticed. "
               "This partial check does not say that the machine is unchanged.")
    else:
        verdict = VERDICTS[0]
        msg = ("No change seen: the check sees every combination of the stored model's "
               "parameters and the machine behaves as the stored model predicts.")
    return CheckOutcome(verdict, said + msg, check, changes, effects, conf, explanation,
                        tuple(blunders))

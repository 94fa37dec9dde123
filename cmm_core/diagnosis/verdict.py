"""From scored candidates to a verdict, and the words that explain it.

The best significant candidate is checked against its rivals by nested F-tests on full
refits (:func:`_encompassing`), a periodic error yields to a physical candidate that
reproduces its signature (:func:`_physical_before_periodic`), and the verdict must pass
the leave-one-placement-out check (:func:`_checked_verdict`, ``holdout``); otherwise it
is :data:`OUTSIDE` the catalogue, with where the residual lives
(:func:`misfit_location`). :func:`_conclusion` writes the message.
"""

from __future__ import annotations

import inspect
from dataclasses import replace
from typing import Protocol

import numpy as np
from scipy import stats

from ..model import PERIODIC, FitResult, fit
from ..units import number, p_text, value_u
from . import crossval as holdout
from .blunders import BLUNDERS
from .replicates import axis_weights


class _Named(Protocol):
    """What :func:`fitted_text` reads of a candidate (``search.Candidate``, frozen: read
    only)."""

    @property
    def effect(self) -> str: ...
    @property
    def fitted(self) -> dict: ...
    @property
    def aliases(self) -> list: ...
    @property
    def would_leave_undetermined(self) -> list: ...
    @property
    def undetermined_carriers(self) -> list: ...

OUTSIDE = "outside_catalogue"
"""Verdict when the misfit is significant and no catalogue effect passes the checks."""


def _flexible_tokens(tokens):
    """One order up per function and every effect scored: the most flexible model."""
    lowest = {}
    for t in tokens:
        name, _, k = t.partition(":")
        if name in PERIODIC or name.startswith("periodic"):
            continue
        if k.isdigit():
            lowest[name] = min(int(k), lowest.get(name, 99))
        else:
            lowest[name] = None
    return [n if k is None else f"{n}:{k}" for n, k in lowest.items()]


def _physical_before_periodic(cands):
    """A periodic error whose pattern a significant physical candidate reproduces (an
    alias by signature) is not named ahead of it: the physical effect has the story."""
    if not cands or not cands[0].effect.startswith("periodic"):
        return cands
    top = cands[0]
    rival = next((c for c in cands[1:] if c.significant and c.effect in top.aliases
                  and not c.effect.startswith("periodic")), None)
    if rival is None:
        return cands
    rest = [c for c in cands if c is not rival]
    return [replace(rival, aliases=list(dict.fromkeys([*rival.aliases, top.effect]))),
            *rest]


def _checked_verdict(base: FitResult, cands, max_checks: int = 3, cache=None):
    """Walk the significant candidates best first; the first that passes the
    leave-one-placement-out check (or that the check cannot judge) is the verdict.
    Returns ``(verdict, checks, candidates, note)``; ``verdict`` is ``OUTSIDE`` when the
    significant ones all fail and None when none is significant."""
    sig = [c for c in cands if c.significant][:max_checks]
    if not sig:
        # nothing of the catalogue, yet each placement may read with its own scale (a
        # placement's thermal state): the placement-scale test on the baseline alone
        p = holdout.scales_alone_p(base, cache)
        if np.isfinite(p) and p < holdout.SCALE_ALONE_ALPHA:
            return OUTSIDE, [], cands, (
                f" Each placement's own scale added to the baseline alone: p = {p:.2g} < "
                f"{holdout.SCALE_ALONE_ALPHA:g} (clean data fail this at that rate).")
        return None, [], cands, ""
    checks: list = []
    failed: list = []
    for c in sig:
        h = holdout.check(base, c.effect, cache, c.level)
        checks.append(h)
        if h.passed:
            if failed:
                cands = [c, *[x for x in cands if x is not c]]
                return c.effect, checks, cands, (
                    f" {', '.join(failed)} ranked higher but failed the "
                    f"leave-one-placement-out check; {c.effect} passes it ({h.reason}).")
            return c.effect, checks, cands, ""
        failed.append(c.effect)
    return OUTSIDE, checks, cands, ""


def misfit_location(base: FitResult) -> dict:
    """Where the residual lives: the placement, probe, axis and ball carrying the largest
    share of χ², with their shares (what the user should look at in the residual maps).
    The numbers of ``residuals.breakdown``, counted with ``bincount``. The expected
    shares are those of an evenly spread misfit: each observation's components
    (``repeatability.axis_weights``: three for a ball plate, the two in its plane for a
    hole plate), and the axis named is the one most above its expected share."""

    out: dict = {}
    if base.n_obs == 0:  # instruments alone: no plate residual to place
        return out
    z2 = (base.residuals_um / base.sigma_um) ** 2
    chi = z2.sum(axis=1)
    total = max(chi.sum(), 1e-300)
    o = base.problem.obs
    w = axis_weights(base)
    comps = w.sum(axis=1)
    for by, idx, names in (("position", o.pos, o.positions), ("probe", o.probe, o.probes),
                           ("ball", o.ball, o.balls)):
        n = np.bincount(idx, minlength=len(names))
        if np.count_nonzero(n) > 1:
            c = np.bincount(idx, weights=chi, minlength=len(names))
            k = int(np.argmax(np.where(n > 0, c, -np.inf)))
            # sums of integers for a ball plate: n[k] / n.sum() exactly
            e = np.bincount(idx, weights=comps, minlength=len(names))
            out[by] = {"name": str(int(names[k])) if by == "ball" else str(names[k]),
                       "chi2_share": float(c[k] / total),
                       "expected_share": float(e[k] / e.sum())}
    shares = z2.sum(axis=0) / max(z2.sum(), 1e-300)
    expected = w.sum(axis=0) / w.sum()  # 1/3 each for a ball plate
    if np.all(expected == expected[0]):
        a = int(np.argmax(shares))
    else:  # an axis with no expected share (a hole plate's normal) is never named
        a = int(np.argmax(np.where(expected > 0, shares / np.maximum(expected, 1e-300),
                                   -np.inf)))
    out["axis"] = {"name": "xyz"[a], "chi2_share": float(shares[a]),
                   "expected_share": float(expected[a])}
    return out


def _refit(base: FitResult, spec, max_iter: int, cache=None) -> FitResult:
    """Full fit of another model on the baseline's observations, plate and settings. The
    nested tests read its χ² and rank only: no χ² test with the certificate's uncertainty
    (``fit``'s ``certificate_test``), and no BLAS thread limit of its own (the diagnosis
    holds one). ``cache``: the diagnosis's ``scoring.ScoreCache``, whose normal equations
    at the initial state start the fit."""
    return inspect.unwrap(fit)(base.problem.obs, spec, plate=base.plate, sigma_um=base.sigma_um,
                           rank_rtol=base.rank_rtol, max_iter=max_iter, certificate_test=False,
                           nominal=None if cache is None else cache.nominal)


def _nested_p(small: FitResult, big: FitResult) -> float:
    """F-test p-value of the parameters ``big`` adds to ``small`` (both full fits)."""
    dk, dchi2 = big.rank - small.rank, small.chi2 - big.chi2
    if dk <= 0 or dchi2 <= 0:
        return 1.0
    return float(stats.f.sf((dchi2 / dk) / max(big.chi2 / max(big.dof, 1), 1e-300),
                            dk, max(big.dof, 1)))


def _encompassing(base: FitResult, cands, level, refits, alpha=0.01, max_rivals=3,
                  max_iter=500, cache=None):
    """Nested F-tests between the best candidate A and the next significant ones B.

    Fits base+A, base+B and base+A+B. If A adds nothing at ``alpha`` once B is in while B
    still adds something once A is in (at ``level``), B explains A's evidence and more: B
    goes first (the message says why). If neither adds anything given the other at
    ``level``, they are aliases.
    Returns the reordered candidates and a sentence for the message.
    """
    def refit(spec):
        return _refit(base, spec, max_iter, cache)

    out, note = list(cands), ""
    a = out[0]
    # Occam for orders: "dzz:4" must beat "dzz:3" by a significant nested test, or the
    # lower order (a near tie on ΔBIC) is the better-founded name
    name, _, k = a.effect.partition(":")
    if k.isdigit():
        lower = next((c for c in out if c.effect == f"{name}:{int(k) - 1}" and c.significant),
                     None)
        if lower is not None:
            fa = refits.get(a.effect) or refit(base.problem.spec.with_token(a.effect))
            fl = refits.get(lower.effect) or refit(base.problem.spec.with_token(lower.effect))
            refits = {**refits, a.effect: fa, lower.effect: fl}
            p_extra = _nested_p(fl, fa)
            if p_extra >= level:
                out.remove(lower)
                out.insert(0, lower)
                note = (f" Order {k} adds nothing significant to order {int(k) - 1} "
                        f"(p = {p_extra:.2g}): {lower.effect} is named.")
                a = lower
    spec_a = base.problem.spec.with_token(a.effect)
    fa = refits.get(a.effect) or refit(spec_a)
    # another order of the same function is not a rival: with_token replaces the order
    # (the Occam rule above compares orders)
    rivals = sorted((c for c in out[1:] if c.significant and c.n_params > 0
                     and c.effect.partition(":")[0] != name),
                    key=lambda c: c.p_value)[:max_rivals]
    promoted, mutual = None, []
    for b in rivals:
        fb = refits.get(b.effect) or refit(base.problem.spec.with_token(b.effect))
        fab = refit(spec_a.with_token(b.effect))
        p_a_given_b, p_b_given_a = _nested_p(fb, fab), _nested_p(fa, fab)
        # "A adds nothing given B" at the plain level: promoting B on weak evidence
        # against A would trade a well-supported name for a bigger model
        if p_a_given_b >= alpha and p_b_given_a < level and promoted is None:
            promoted = (b, p_a_given_b, p_b_given_a)
        elif p_a_given_b >= level and p_b_given_a >= level:
            mutual.append(b.effect)
    if promoted is not None:
        b, pab, pba = promoted
        out.remove(b)
        out = [b, *out]
        note += (f" Nested tests: {a.effect} adds nothing once {b.effect} is in the model "
                f"(p = {pab:.2g}), while {b.effect} is still needed with {a.effect} in "
                f"(p = {pba:.2g}): {b.effect} explains the same misfit and more, although "
                f"its ΔBIC ({b.delta_bic:.1f}, for {b.n_params} parameters) is weaker than "
                f"{a.effect}'s ({a.delta_bic:.1f}).")
    elif mutual:
        # The data cannot tell them apart: name the one the testing procedure supports
        # best, the smallest p relative to its share of the false-alarm rate (the order
        # of a weighted Holm procedure, whose weights are the prior plausibility of each
        # kind of effect), not the one a ΔBIC that charges unused parameters prefers.
        group = [a, *(c for c in out if c.effect in mutual)]
        # ... among those with a physical story when there are any (a periodic error
        # yields to them, :func:`_physical_before_periodic`)
        story = [c for c in group if not c.effect.startswith("periodic")] or group
        log_p = _log_p(group, base)
        best = min(story, key=lambda c: log_p[c.effect] - np.log(c.level))
        tied = [c.effect for c in group if c is not best]
        if best is not a:
            out.remove(best)
            out = [best, *out]
            why = ("as the better supported at its level" if best is min(
                group, key=lambda c: log_p[c.effect] - np.log(c.level)) else
                "as the one with a physical story (a periodic error yields to it)")
            note += (f" {best.effect} is named ahead of {a.effect}, which neither adds "
                     f"anything to nor needs once the other is in the model, {why} "
                     f"(p = {_p_text(log_p[best.effect])} against {best.level:.2g}; "
                     f"{a.effect}: p = {_p_text(log_p[a.effect])} against {a.level:.2g}).")
        out[0] = replace(best, aliases=list(dict.fromkeys([*best.aliases, *tied])))
    return out, note


_P_FLOOR = 1e-12
"""Below this a candidate's p-value is not compared with another's as it stands: the exact
tail with a fixed certificate's noise (``certnoise``, Imhof's integral) is accurate to
about 1e-15 absolute and returns 0 beneath, so two aliases both far beyond their levels
(a squareness and a fourth-order yaw, p = 3e-21 against "0") would be ordered by the
integral's rounding. :func:`_log_p` then compares the F-test's log-tail of each."""


def _log_p(group, base: FitResult) -> dict:
    """``{effect: ln p}`` for the alias tie-break of :func:`_encompassing` (the order of a
    weighted Holm procedure, p against each level). The candidates' own p-values unless
    all are below :data:`_P_FLOOR`; then, for all of them alike, the log-tail of the plain
    F-test of their Δχ² against the scatter they leave (``stats.f.logsf``, no underflow;
    the certificate's share of the noise is the same order for rivals on the same data)."""
    if not all(c.p_value < _P_FLOOR for c in group):
        # one of them resolved: the others' p, resolved or below it, order as they stand
        return {c.effect: float(np.log(c.p_value)) if c.p_value > 0 else -np.inf
                for c in group}
    out = {}
    for c in group:
        k = max(int(c.n_params), 1)
        nu = max(base.dof - k, 1)
        F = (max(c.delta_chi2, 0.0) / k) / max(c.chi2_dof, 1e-300)
        out[c.effect] = float(stats.f.logsf(F, k, nu))
    return out


def _p_text(log_p: float) -> str:
    """``2.7e-21``; below the double range ``1e-350`` style from the log."""
    if not np.isfinite(log_p):
        return "< 1e-308"
    if log_p > -700:
        return f"{np.exp(log_p):.2g}"
    return f"1e{log_p / np.log(10):.0f}"


def _with_aliases(cands, threshold, extra=None):
    sigs = [c.signature_um.ravel() for c in cands]
    norms = [np.linalg.norm(s) for s in sigs]
    res = []
    for i, c in enumerate(cands):
        al = []
        if norms[i] > 0 and c.n_params > 0:
            for j, o in enumerate(cands):
                if j != i and norms[j] > 0 and o.n_params > 0:
                    corr = abs(sigs[i] @ sigs[j]) / (norms[i] * norms[j])
                    if corr > threshold:
                        al.append(o.effect)
        al += (extra or {}).get(c.effect, [])
        res.append(replace(c, aliases=al))
    return res


def stylus_offsets(fitted: dict) -> dict:
    """``{stylus: (vector µm (3,), u µm (3,))}`` from a probe offset's fitted
    parameters (labels ``probe<name>.<axis>``)."""
    out: dict = {}
    for lab, (_, v, u) in fitted.items():
        q, _, a = lab[len("probe"):].rpartition(".")
        vec = out.setdefault(q, (np.zeros(3), np.zeros(3)))
        vec[0]["xyz".index(a)], vec[1]["xyz".index(a)] = v, u
    return out


def _u_why(c: _Named, labels) -> str:
    """Why the fitted parameters ``labels`` of candidate ``c`` have no determinable u:
    the sentence of the undetermined combination of the model with it that names one of
    them, else that the model leaves some undetermined, else its aliases ("" when none of
    these says why)."""
    # the sentence that names one of them (its carriers are the labels it names)
    for words, carriers in zip(c.would_leave_undetermined, c.undetermined_carriers,
                               strict=False):
        if any(lab in carriers for lab in labels):
            return f"in this design {words[:1].lower()}{words[1:].rstrip('.')}"
    if c.would_leave_undetermined:
        return (f"the model with {c.effect} leaves {len(c.would_leave_undetermined)} "
                "parameter combination(s) undetermined")
    if c.aliases:
        return "aliased with " + ", ".join(c.aliases)
    return ""


def stylus_text(c: _Named, note: str = "") -> str:
    """``Stylus 2 is the furthest off: its offset error is (x +1.18 ± 0.05, ...) µm (|e|
    = 5.02 µm; note)`` of a probe offset candidate: the stylus whose fitted offset vector
    is largest, each component with its u, or the components alone and why their u is
    not determinable (never ``± nan``)."""
    off = stylus_offsets(c.fitted)
    q = max(off, key=lambda k: float(np.linalg.norm(off[k][0])))
    v, u = off[q]
    if np.all(np.isfinite(u) & (u > 0)):
        vec = ", ".join(f"{a} {number(x, '+.2f')} ± {number(s, '.2f')}"
                        for a, x, s in zip("xyz", v, u, strict=True))
        tail = ""
    else:
        vec = ", ".join(f"{a} {number(x, '+.2f')}" for a, x in zip("xyz", v, strict=True))
        why = _u_why(c, [f"probe{q}.{a}" for a in "xyz"])
        tail = f"; u not determinable: {why or 'the data do not determine it'}"
    return (f"Stylus {q} is the furthest off: its offset error is ({vec}) µm (|e| = "
            f"{number(float(np.linalg.norm(v)), '.2f')} µm{'; ' + note if note else ''}"
            f"{tail})")


def fitted_parameters(c: _Named, limit: int = 3) -> list:
    """The named effect's added parameters largest against their u first (those without
    a determinable u after them, largest first), at most ``limit``, as text:
    ``dxx[1] = -1.85 ± 0.45 µm`` (``value_u``: a u not determinable says why)."""
    def key(item):
        _, v, u = item[1]
        has_u = bool(np.isfinite(u) and u > 0)
        return (not has_u, -abs(v) / u if has_u else -abs(v))

    top = sorted(c.fitted.items(), key=key)[:limit]
    return [f"{lab} = {value_u(v, u, unit, _u_why(c, [lab]))}"
            for lab, (unit, v, u) in top]


def fitted_text(c: _Named) -> str:
    """The named effect's numbers: a probe offset names the stylus furthest off (the
    largest offset vector, with u), other effects their parameters largest against u."""
    if not c.fitted:
        return ""
    if c.effect == "probe_offset":
        return (" " + stylus_text(c, "u standard uncertainties, each stylus relative to the "
                                     "mean of all, since the fit only sees their differences")
                + "; requalify it. Every stylus's vector is in the candidate's fitted "
                "parameters.")
    return " Fitted: " + ", ".join(fitted_parameters(c)) + "."


def evidence(base: FitResult) -> dict:
    """What an outside-catalogue misfit is, in the tables a person reads: each
    placement's own scale along each machine axis (the slope of the baseline's residual
    of that axis against the coordinate within the placement, ppm, with u from σ) and each
    stylus's mean residual vector (µm, with u = σ/√n), each largest against its u first.
    Axes a placement spans less than a quarter of its longest extent are left out. A hole
    plate's residuals live in its plane: its table has the styli only."""
    o, res, sig = base.problem.obs, base.residuals_um, base.sigma_um
    scales = []
    if o.artefact != "hole_plate":
        for k, name in enumerate(o.positions):
            sel = o.pos == k
            span = np.ptp(o.r_mm[sel], axis=0)
            for a in range(3):
                # an axis the placement hardly spans (a horizontal plate's z) has no
                # scale worth the name: its slope is the residual over a few mm
                if span[a] < 0.25 * span.max():
                    continue
                dx = (o.r_mm[sel, a] - o.r_mm[sel, a].mean()) * 1e-3  # µm per ppm
                sxx = float(dx @ dx)
                v = float(dx @ res[sel, a]) / sxx
                scales.append({"position": str(name), "axis": "xyz"[a], "scale_ppm": v,
                               "u_ppm": sig / np.sqrt(sxx)})
    styli = []
    for k, name in enumerate(o.probes):
        sel = o.probe == k
        n = int(sel.sum())
        if n:
            m = res[sel].mean(axis=0)
            styli.append({"probe": str(name), "mean_um": [float(x) for x in m],
                          "u_um": sig / np.sqrt(n)})
    scales.sort(key=lambda e: -abs(e["scale_ppm"]) / e["u_ppm"])
    styli.sort(key=lambda e: -float(np.linalg.norm(e["mean_um"])) / e["u_um"])
    return {"placement_scales_ppm": scales, "stylus_mean_residual_um": styli}


def _evidence_text(ev: dict) -> str:
    """The evidence tables named, with their largest entries."""
    parts = []
    if ev.get("placement_scales_ppm"):
        top = ev["placement_scales_ppm"][:3]
        parts.append("each placement's own scale along the machine axes (largest: "
                     + ", ".join(f"{e['position']} {e['axis']} {e['scale_ppm']:+.1f} ± "
                                 f"{e['u_ppm']:.1f} ppm" for e in top) + ")")
    if ev.get("stylus_mean_residual_um"):
        e = ev["stylus_mean_residual_um"][0]
        vec = ", ".join(f"{x:+.2f}" for x in e["mean_um"])
        parts.append(f"each stylus's mean residual (largest: stylus {e['probe']} "
                     f"({vec}) ± {e['u_um']:.2f} µm)")
    if not parts:
        return ""
    return (" Evidence of what it is (the diagnosis's evidence tables, JSON 'evidence'; in "
            "the app the 'Per position and probe' tab): " + "; ".join(parts) + ".")


def _where_text(where: dict) -> str:
    """``BP112 carries 30 % of χ² (17 % of the observations); ...``"""
    parts = []
    for by, label in (("position", "placement"), ("probe", "stylus"), ("ball", "ball"),
                      ("axis", "axis")):
        w = where.get(by)
        if w and w["chi2_share"] > 1.5 * w["expected_share"]:
            parts.append(f"{label} {w['name']} carries {100 * w['chi2_share']:.0f} % of χ² "
                         f"({100 * w['expected_share']:.0f} % of the data)")
    return "; ".join(parts)


def _test_text(base) -> str:
    """The baseline's χ² test in words, quoting the statistic the test uses (with the
    certificate fixed, its uncertainty counted) beside the fit's own χ²/dof."""
    verdict = "fails" if base.fails_chi2_test else "passes"
    val, dof = base.chi2_test_dof, base.test_statistic[1]
    own = (f" with the certificate's uncertainty counted (this is the value the test "
           f"decides on; the fit's own χ²/dof, {base.chi2_dof:.2f}, leaves that uncertainty "
           "out)" if base.test_counts_certificate else "")
    return (f"χ²/dof {val:.2f} at {dof} degrees of freedom against σ = "
            f"{base.sigma_um:.3g} µm{own} {verdict} the χ² test ({p_text(base.chi2_p_value)})")


def _conclusion(base, cands, verdict, sigma=None, uniform=None, where=None):
    # instruments alone have no plate residual: their own fit is the χ² test's
    rms = (f"RMS {base.rms_um:.2f} µm" if base.n_obs else
           "instruments only (no plate residuals)")
    head = f"Baseline {base.spec}: {rms}; {_test_text(base)}."
    if base.null_combinations:
        head += (f" This design leaves {len(base.null_combinations)} combination(s) of the "
                 "baseline undetermined; candidates are judged only on what it can see, "
                 "and more placements would change the picture.")
    if base.status != "converged" or verdict == BLUNDERS:
        return head
    sig_text = "" if sigma is None else (
        f" Estimated from the data, σ = {sigma.value_um:.3g} ± {sigma.u_um:.2g} µm "
        f"({sigma.detail}); at that σ the baseline's χ²/dof would be "
        f"{base.chi2_dof * (base.sigma_um / sigma.value_um) ** 2:.2f}.")
    if verdict is None and not base.fails_chi2_test:
        return head + (" No candidate effect explains a significant part of the remaining "
                       "misfit: the data are explained to noise by this model.")
    if verdict is None:
        return head + (" No candidate effect is significant and the misfit is spread evenly "
                       "over placements, styli and axes: the stated repeatability looks too "
                       "small, not a missing effect." + sig_text + " Refit with the estimated "
                       "σ (its uncertainties then reflect the observed scatter) or find why "
                       "the machine repeats worse than stated.")
    if verdict == OUTSIDE:
        failed = [c for c in cands if c.significant]
        text = " No effect of the catalogue explains the misfit."
        if failed:
            text += (f" The significant candidates ({', '.join(c.effect for c in failed[:3])})"
                     " fail the leave-one-placement-out check: fitted on the other placements "
                     "they do not predict the held-out one, so they follow what differs "
                     "between placements (an alias), not a property of the machine or plate.")
        elif not base.fails_chi2_test:
            # the only way here: each placement's own scale, tested on the baseline alone
            # (_checked_verdict), while the χ² test passes and no candidate is significant
            text += (" Nothing in the catalogue is significant and the χ² test passes, but "
                     "each placement's own scale is significant with no effect added (the "
                     "test below): the placements read lengths with different scales.")
            text += _evidence_text(evidence(base))
            return head + text + (" Look at the table of each placement's own scale: a "
                                  "placement's own temperature or scale is outside the "
                                  "catalogue; correct the data for it or measure the "
                                  "placements at one thermal state." + sig_text)
        else:
            text += " Nothing in the catalogue is significant, yet the misfit is concentrated"
            if uniform is not None:
                text += f" (largest: {uniform.worst})"
            text += "."
        loc = _where_text(where or {})
        if loc:
            text += f" Where the residual lives: {loc}."
        text += _evidence_text(evidence(base))
        text += (" Look at the residual maps there: a blunder, a certificate entry, or an "
                 "effect the catalogue does not hold (a local error of one axis, a placement's "
                 "own scale or temperature)." + sig_text)
        return head + text
    best = cands[0]
    name = best.title if best.title.startswith(best.effect) else (
        f"{best.title} ({best.effect})")
    expl = best.explanation[:1].upper() + best.explanation[1:]
    text = (f" Most likely missing: {name}: adding it lowers χ² by "
            f"{best.delta_chi2:.1f} for {best.n_params} parameter(s), ΔBIC "
            f"{number(best.delta_bic, '.1f')}, {p_text(best.p_value)}. {expl}{fitted_text(best)}")
    if best.delta_bic > 0:
        text += (f" Its ΔBIC is positive: BIC charges ln N = "
                 f"{np.log(base.dof + base.rank):.1f} per parameter and would rather not add "
                 f"{best.n_params}, while the F-test finds the χ² they remove too large for "
                 "noise (the verdict follows the test). Expect BIC to rise a little when it "
                 f"is added while RMS and χ²/dof fall; to confirm it: {best.separate_by}")
    if best.aliases:
        text += (f" With this data it cannot be told apart from {', '.join(best.aliases)}; "
                 f"to separate them: {best.separate_by}")
    if best.would_leave_undetermined:
        text += (f" Adding it as is would leave {len(best.would_leave_undetermined)} "
                 "parameter combination(s) undetermined ("
                 + "; ".join(best.would_leave_undetermined[:2])
                 + "): remove one of the functions named there, add a placement or stylus "
                 "that exercises them, or use a lower order.")
    if best.chi2_dof > 1.3:
        text += (f" With it the fit still has χ²/dof = {best.chi2_dof:.2f}: more is missing. "
                 "Add it and run the diagnosis again (effects are found one at a time); if "
                 "nothing significant is left, the diagnosis says whether σ or an effect "
                 "outside the catalogue is the cause.")
    return head + text

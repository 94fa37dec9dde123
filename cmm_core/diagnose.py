"""Which physical effect is missing? Rank candidates by the misfit they explain.

For a baseline fit, every catalogue token not yet in the model (``effects.ModelSpec.
candidates``) is scored by the χ² reduction of one Gauss-Newton step of the augmented
model from the baseline solution (a score test; the model is nearly linear, so this is the
refit's reduction to high accuracy), and the best few are confirmed by a full refit. Each
candidate gets:

- ``delta_bic = -Δχ² + Δk ln N`` (Δk the rank it adds, N the number of residuals);
- an F-test p-value ``F = (Δχ²/Δk) / (χ²_new/ν_new)``, robust to a misstated σ;
- its signature: the residual pattern its refit removes, to draw beside the residuals;
- aliases: other candidates whose signatures are nearly the same pattern with this data.

A candidate is significant when ``p`` is below its share of ``alpha`` (weighted
Bonferroni, :data:`PHYSICAL_SHARE`: half for the physical effects and absent functions,
half for the higher orders and periodic errors; the false-alarm rate of the verdict stays
at most ``alpha``). Significant candidates are ranked by ΔBIC, then the best is checked
against the other significant ones by nested F-tests on full refits (an encompassing
test): when the best is no longer needed once another is in the model, but the other is
still needed with the best in, the other is the better explanation and is promoted. Pairs
where neither is needed once the other is in are reported as aliases; a periodic error
whose signature a significant physical candidate reproduces yields to it.

The verdict must then pass a leave-one-placement-out check (``holdout``): fitted on the
other placements, the effect predicts the held-out one. The first significant candidate
that passes (or that the check cannot judge) is the verdict; when all fail, or when none
is significant while the baseline fails its χ² test with the misfit concentrated in some
placements, styli, balls or regions, the verdict is ``"outside_catalogue"`` with where the
residual lives. With nothing significant and the misfit spread evenly, the verdict is None
and σ is the suspect (``repeatability``: estimated from repeats or the most flexible
model). When the baseline uses a certificate and fails its χ² test, the certificate is
checked against the self-calibrated plate (``certificate_check``).

Guards: no period shorter than ``blocks.periodic.NYQUIST_FACTOR`` ball spacings is scanned; which
parameters a candidate adds is decided at the nominal linearisation, as its refit decides
it (``fit``'s frozen design null space); whatever ranks first is confirmed
by a refit; a higher order must beat the next lower one by a nested F-test (Occam); and a
baseline that does not converge names no effect, since its own unfinished descent would
be credited to every candidate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats

from . import holdout, repeatability
from . import kinematics as kin
from ._blas import single_blas_thread
from .blocks import needs
from .blocks.periodic import PERIOD_SCAN, shortest_resolvable_period
from .certificate_check import CertificateCheck, check_certificate
from .effects import PERIODIC, PHYSICAL, catalogue_entry
from .fit import FitResult, Problem, augmented_state, fit, held_constraints, weighted_residual
from .solver import Normal, describe_null, solve

PHYSICAL_SHARE = 0.5
"""Share of the family-wise false-alarm rate ``alpha`` given to the physical effects and
absent error functions (weighted Bonferroni: each of them is tested at
``alpha * PHYSICAL_SHARE / n_physical``, every higher order and periodic error at
``alpha * (1 - PHYSICAL_SHARE) / n_other``; the weights sum to one, so the family-wise
rate stays at most ``alpha``). A handful of physical effects would otherwise pay for the
~40 order increases tried beside them."""


@dataclass(frozen=True)
class Candidate:
    """One candidate effect scored against the baseline.

    Attributes
    ----------
    effect : str
        Model token (``plate_sag``, ``dyz:3``, ``sxy``).
    title, explanation, needs, separate_by : str
        From the effect catalogue.
    rms_um, chi2_dof : float
        Of the model with the effect added.
    delta_chi2 : float
        χ² reduction (baseline minus augmented).
    n_params : int
        Rank the effect adds (0: the data cannot determine it on top of the baseline).
    delta_bic : float
        BIC change; negative favours adding the effect.
    p_value : float
        F-test p-value of the χ² reduction.
    significant : bool
    confirmed : bool
        True when the numbers come from a full refit, not only the one-step score.
    signature_um : ndarray (n, 3)
        Residual pattern the effect removes, aligned with the baseline's observations.
    aliases : list of str
        Candidates producing nearly the same pattern with this data.
    detectable : dict
        ``{label: (unit, size)}``: the size of each added parameter (µm, µrad, ...) above
        which this data set finds it with 80 % probability at the test's level, from its
        standard uncertainty in the augmented fit scaled by the residual scatter left
        (``inf``: not determined). Tells what the
        design can and cannot see, e.g. rotations of the ram with short styli.
    level : float
        The significance level this candidate was tested at (its share of the family-wise
        false-alarm rate, weighted Bonferroni).
    would_leave_undetermined : list of str
        Parameter combinations the model with this effect added could not determine
        (beyond the baseline's own): adding it as is leaves them unidentified. Fix by a
        constraint (remove one of the named functions), another placement or stylus, or a
        lower order.
    """

    effect: str
    title: str
    explanation: str
    needs: str
    separate_by: str
    rms_um: float
    chi2_dof: float
    delta_chi2: float
    n_params: int
    delta_bic: float
    p_value: float
    significant: bool
    confirmed: bool
    signature_um: np.ndarray = field(repr=False)
    aliases: list = field(default_factory=list)
    detectable: dict = field(default_factory=dict)
    level: float = 0.01
    would_leave_undetermined: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-ready summary (no arrays)."""
        return {"effect": self.effect, "title": self.title, "rms_um": self.rms_um,
                "chi2_dof": self.chi2_dof, "delta_chi2": self.delta_chi2,
                "n_params": self.n_params, "delta_bic": self.delta_bic,
                "p_value": self.p_value, "significant": self.significant,
                "confirmed": self.confirmed, "aliases": self.aliases,
                "explanation": self.explanation, "separate_by": self.separate_by,
                "detectable": {k: {"unit": u, "size": v}
                               for k, (u, v) in self.detectable.items()},
                "level": self.level,
                "would_leave_undetermined": self.would_leave_undetermined}

    def detectable_text(self) -> str:
        """``dxz[1] > 1.9 µm, dxz[2] > 2.3 µm`` (the first few parameters)."""
        items = [f"{k} > {v:.3g} {u.replace('um', 'µm').replace('urad', 'µrad')}"
                 for k, (u, v) in list(self.detectable.items())[:4]]
        more = len(self.detectable) - 4
        return ", ".join(items) + (f" (+{more} more)" if more > 0 else "")


@dataclass(frozen=True)
class Diagnosis:
    """Ranked candidates and the verdict.

    Attributes
    ----------
    baseline : FitResult
    candidates : list of Candidate
        Best first: significant ones by ΔBIC (after the nested-test check of the best),
        then the rest by ΔBIC.
    verdict : str or None
        Best significant effect that passes the leave-one-placement-out check;
        ``"outside_catalogue"`` when the misfit is significant and no catalogue effect
        explains it (the significant ones fail the check, or none is significant while the
        misfit is concentrated in some placements, probes or axes); None when nothing is
        significant (explained to noise, or a stated σ that looks too small: ``sigma``).
    skipped : dict
        Tokens not tried, with the reason (data they need are absent).
    message : str
        Plain-language conclusion.
    holdout : list of holdout.HoldoutCheck
        Leave-one-placement-out checks of the significant candidates tried, best first.
    sigma : repeatability.SigmaEstimate or None
        σ estimated from the data when the baseline fails its χ² test and no effect is
        named.
    uniformity : repeatability.Uniformity or None
        Whether that misfit is spread evenly (σ) or concentrated (a missing effect).
    where : dict
        Where the baseline's residual lives (``misfit_location``).
    certificate : certificate_check.CertificateCheck or None
        The certificate compared with the self-calibrated plate, when the baseline uses a
        certificate (fixed or prior) and the design can self-calibrate.
    """

    baseline: FitResult
    candidates: list
    verdict: str | None
    skipped: dict
    message: str
    holdout: list = field(default_factory=list)
    sigma: repeatability.SigmaEstimate | None = None
    uniformity: repeatability.Uniformity | None = None
    where: dict = field(default_factory=dict)
    certificate: CertificateCheck | None = None

    def to_dict(self) -> dict:
        """JSON-ready result in the ``diagnose`` shape (docs/formats.md)."""
        b = self.baseline
        return {"baseline": {"model": b.spec, "rms_um": b.rms_um, "chi2_dof": b.chi2_dof,
                             "bic": b.bic, "dof": b.dof, "chi2_p_value": b.chi2_p_value,
                             "fails_chi2_test": b.fails_chi2_test},
                "candidates": [c.to_dict() for c in self.candidates],
                "verdict": self.verdict, "skipped": self.skipped, "message": self.message,
                "holdout": [h.to_dict() for h in self.holdout],
                "sigma_check": None if self.sigma is None else {
                    **self.sigma.to_dict(),
                    "uniform": None if self.uniformity is None else self.uniformity.uniform,
                    "uniformity": None if self.uniformity is None else self.uniformity.to_dict()},
                "where": self.where,
                "certificate": None if self.certificate is None else self.certificate.to_dict()}


def _needs_met(token, base: FitResult):
    """Why the baseline's data cannot see ``token`` (None: they can); the block says."""
    return needs(token, base.problem.obs)


def score(base: FitResult, token: str):
    """One-step score of adding ``token``.

    Returns (Δχ², Δrank, signature µm (n, 3), χ² new, u_new, combos) where ``u_new`` maps
    each added parameter label to ``(unit, standard uncertainty)`` in the augmented model:
    how well this data set determines the effect on top of the baseline; ``combos`` are
    the parameter combinations the augmented model would leave undetermined (beyond the
    baseline's own), written out as the fit writes them.
    """
    spec = base.problem.spec.with_token(token)
    prob = Problem(base.problem.obs, spec, base.plate)
    st = augmented_state(base, prob)
    d, r, J = weighted_residual(prob, st, base.sigma_um, True)
    # what the baseline's design could not determine stays held, or the candidate would
    # be credited with (and counted for) those directions too
    C = prob.constraints()
    if base.design_null.size:
        C = np.vstack([C, held_constraints(base.labels, base.design_null, prob)])
    # ... and what the candidate adds is decided at the nominal linearisation, as its
    # refit decides it (fit's frozen design null): at the baseline's solution the
    # nonlinearity of fitted rotations lends weakly coupled columns a small, spurious rank
    _, r0, J0 = weighted_residual(prob, prob.initial_state(), base.sigma_um, True)
    ne0 = Normal(J0, r0, C, base.rank_rtol)
    combos = describe_null(ne0.null, prob.layout.labels)[0] if ne0.null.shape[1] else []
    step, cov, rank, null = solve(J, r, ne0.freeze_null(C), base.rank_rtol)
    r_new = r + J @ step
    chi2_new = float(r_new @ r_new)
    n = prob.n_obs
    sig = -(J @ step)[: 3 * n].reshape(n, 3) * base.sigma_um
    old = set(base.labels)
    u = np.sqrt(np.clip(np.diag(cov), 0, None))
    # a parameter with a component in the null space is not determined at all
    # (the same 5 % share rule as fit's unidentifiable parameters)
    undetermined = ((np.abs(null) >= 0.05 * np.abs(null).max(axis=0)).any(axis=1)
                    if null.size else np.zeros(len(u), bool))
    u_new = {lab: (unit, float("inf") if und else float(ui))
             for lab, unit, ui, und in zip(prob.layout.labels, prob.layout.units, u,
                                           undetermined, strict=True) if lab not in old}
    return base.chi2 - chi2_new, rank - base.rank, sig, chi2_new, u_new, combos


def scan_period(base: FitResult, token: str):
    """Best period of a periodic scale error (``periodic_x`` ...) for this residual.

    Score test for every period of the scan: the χ² reduction of adding the two periodic
    columns (sine, cosine) after projecting out the baseline's Jacobian, so that only what
    the baseline cannot already explain counts. Returns ``(token with period, periods mm,
    Δχ² per period, alias tokens)``: the best period is refined between its grid
    neighbours; aliases are other local maxima within 80 % of the best (periods the ball
    spacing cannot tell apart from it).
    """
    a = "xyz".index(token[-1])
    _, r, J = weighted_residual(base.problem, base.state, base.sigma_um, True)
    U, sv, _ = np.linalg.svd(J.toarray(), full_matrices=False)
    U = U[:, sv > base.rank_rtol * sv.max()]
    u = (base.problem.obs.r_mm - base.problem.obs.p_mm)[:, a]
    n = u.size
    shortest = shortest_resolvable_period(base.problem.obs, a)[0]
    periods = np.geomspace(shortest, max(np.ptp(u), 2 * shortest), PERIOD_SCAN[1])

    def gain(lam):
        X = np.zeros((r.size, 2))
        X[a: 3 * n: 3] = kin.periodic_basis(u, lam) / base.sigma_um
        X -= U @ (U.T @ X)
        q, rr = np.linalg.qr(X)
        if abs(rr[-1, -1]) <= 1e-9 * abs(rr[0, 0]):
            return 0.0  # this period is indistinguishable from the baseline
        return float(np.sum((q.T @ r) ** 2))

    gains = np.array([gain(lam) for lam in periods])
    i = int(np.argmax(gains))
    lo, hi = periods[max(i - 1, 0)], periods[min(i + 1, periods.size - 1)]
    best = optimize.minimize_scalar(lambda lam: -gain(lam), bounds=(lo, hi),
                                    method="bounded", options={"xatol": 0.5}).x
    # other periods that explain nearly as much: aliases of the ball spacing
    peaks = [j for j in range(periods.size) if gains[j] >= 0.8 * gains[i]
             and gains[j] >= gains[max(j - 1, 0)] and gains[j] >= gains[min(j + 1, periods.size - 1)]
             and abs(np.log(periods[j] / best)) > 0.1]
    aliases = [f"{token}:{periods[j]:.0f}" for j in peaks]
    return f"{token}:{best:.0f}", periods, gains, aliases


def _stats(base: FitResult, dchi2, dk, chi2_new, n_scan=1):
    """ΔBIC, F-test p-value and residual dof of adding ``dk`` parameters. A candidate
    chosen as the best of ``n_scan`` (a scanned period) pays for the choice: one more
    parameter in the BIC and a Bonferroni factor ``n_scan`` on p (conservative: the
    scanned periods are correlated)."""
    n_rows = base.dof + base.rank
    dof_new = max(n_rows - base.rank - dk, 1)
    dbic = -dchi2 + (dk + (n_scan > 1)) * np.log(n_rows)
    if dk <= 0 or dchi2 <= 0:
        return dbic, 1.0, dof_new
    F = (dchi2 / dk) / max(chi2_new / dof_new, 1e-300)
    return dbic, min(1.0, n_scan * float(stats.f.sf(F, dk, dof_new))), dof_new


@dataclass
class _Scored:
    """Working record of one candidate while the diagnosis ranks it."""

    token: str
    dchi2: float
    dk: int
    signature: np.ndarray
    chi2_new: float
    u_new: dict
    combos: list
    n_scan: int = 1
    period_aliases: list = field(default_factory=list)
    refit: FitResult | None = None
    family: str = ""


def _levels(tokens, alpha):
    """Weighted Bonferroni levels (:data:`PHYSICAL_SHARE`): ``{token: level}``."""
    def physical(t):
        return t in PHYSICAL or ":" not in t and t not in PERIODIC

    phys = [t for t in tokens if physical(t)]
    other = [t for t in tokens if not physical(t)]
    share = PHYSICAL_SHARE if phys and other else float(bool(phys))
    lv = {t: alpha * share / len(phys) for t in phys}
    lv.update({t: alpha * (1 - share) / len(other) for t in other})
    return lv


@single_blas_thread
def diagnose(data, baseline: str = "kinematic21", *, order: int = 2, plate=None,
             sigma_um: float = 0.5, exclude=(), positions=None, probes=None,
             candidates=None, alpha: float = 0.01, confirm: int = 3,
             alias_corr: float = 0.9, progress=None) -> Diagnosis:
    """Rank the catalogue effects missing from ``baseline`` (see module docstring).

    Parameters
    ----------
    data : Dataset
    baseline : str
        Model spec of the baseline.
    candidates : list of str, optional
        Tokens to try (default: every catalogue token not in the baseline).
    alpha : float
        Family-wise false-alarm rate, shared over the candidates by weighted Bonferroni
        (:data:`PHYSICAL_SHARE`).
    confirm : int
        How many of the best scored candidates are confirmed by a full refit.
    alias_corr : float
        Signature correlation above which two candidates are reported as aliases.
    progress : callable, optional
        ``progress(fraction, text)`` is called as candidates are scored and confirmed
        (for a progress bar); exceptions it raises propagate.
    """
    def report(frac, text):
        if progress is not None:
            progress(float(min(max(frac, 0.0), 1.0)), text)

    # weakly determined directions (one placement, high orders) can need many steps: the
    # baseline gets a large budget (a converged fit stops early), and the candidates'
    # refits the same one when the baseline needed more than fit's default
    base = fit(data, baseline, order=order, plate=plate, sigma_um=sigma_um, exclude=exclude,
               positions=positions, probes=probes, max_iter=2000)
    max_iter = 500 if base.iterations <= 500 else 2000
    tokens = candidates if candidates is not None else base.problem.spec.candidates()
    skipped, scored = {}, []
    n_steps = len(tokens) + confirm
    for i, tok in enumerate(tokens):
        report(i / n_steps, f"scoring {tok} ({i + 1}/{len(tokens)})")
        why = _needs_met(tok, base)
        if why:
            skipped[tok] = why
            continue
        n_scan, period_aliases, family = 1, [], tok
        if tok in PERIODIC:
            tok, periods, _, period_aliases = scan_period(base, tok)
            n_scan = periods.size
        scored.append(_Scored(tok, *score(base, tok), n_scan=n_scan,
                              period_aliases=period_aliases, family=family))
    levels = _levels([sc.family for sc in scored], alpha)
    def stats_of(sc):
        return _stats(base, sc.dchi2, sc.dk, sc.chi2_new, sc.n_scan)

    def significant(sc):
        return sc.dk > 0 and stats_of(sc)[1] < levels[sc.family]

    def refit_candidate(sc, j):
        report((len(tokens) + j) / n_steps, f"confirming {sc.token} by a full refit")
        ref = _refit(base, base.problem.spec.with_token(sc.token), max_iter)
        sc.dchi2, sc.dk, sc.chi2_new, sc.refit = base.chi2 - ref.chi2, ref.rank - base.rank, \
            ref.chi2, ref

    scored.sort(key=lambda sc: stats_of(sc)[0])
    for j, sc in enumerate(scored[:confirm]):
        if sc.dk > 0:
            refit_candidate(sc, j)
    # A refit can still change a candidate's Δχ² and rank (nonlinearity, iterations), and
    # so the order: whatever ends up first is confirmed too.
    for j in range(confirm, confirm + 10):
        scored.sort(key=lambda sc: (not significant(sc), stats_of(sc)[0]))
        top = next((sc for sc in scored if sc.dk > 0), None)
        if top is None or top.refit is not None or confirm == 0:
            break
        refit_candidate(top, j)
    n_rows = base.dof + base.rank
    out = []
    for sc in scored:
        dbic, p, dof_new = stats_of(sc)
        # Size at which a parameter alone is found with 80 % probability at its level:
        # |θ| = u s (z_{1-level/2} + z_{0.8}), s² = χ²/ν left (normal approximation of the
        # F-test, which measures the reduction against the residual scatter left)
        k_detect = float(stats.norm.isf(levels[sc.family] / 2) + stats.norm.isf(0.2))
        scale = float(np.sqrt(sc.chi2_new / dof_new))
        e = catalogue_entry(sc.token)
        # Unconfirmed candidates: RMS from the one-step χ² (prior rows are few).
        rms = sc.refit.rms_um if sc.refit is not None else float(
            np.sqrt(max(sc.chi2_new, 0) / n_rows) * sigma_um)
        out.append(Candidate(
            sc.token, e.title, e.explanation, e.needs, e.separate_by, rms,
            sc.chi2_new / dof_new, float(sc.dchi2), int(sc.dk), float(dbic), p,
            significant(sc), sc.refit is not None, sc.signature,
            detectable={lab: (unit, k_detect * scale * ui)
                        for lab, (unit, ui) in sc.u_new.items()},
            level=levels[sc.family],
            would_leave_undetermined=list(sc.combos)))
    out.sort(key=lambda c: (not c.significant, c.delta_bic))
    out = _with_aliases(out, alias_corr, {sc.token: sc.period_aliases for sc in scored})
    note = ""
    refits = {sc.token: sc.refit for sc in scored}
    if out and out[0].significant:
        report(0.99, "nested tests of the best candidates")
        out, note = _encompassing(base, out, out[0].level, refits, alpha, max_iter=max_iter)
        out = _physical_before_periodic(out)
    report(0.995, "leave-one-placement-out checks")
    verdict, checks, out, note2 = _checked_verdict(base, out)
    note += note2
    sigma = uniform = None
    if base.status == "converged" and base.fails_chi2_test and verdict in (None, OUTSIDE):
        # nothing catalogued explains the misfit: σ, or something outside the catalogue?
        # An understated σ spreads the misfit evenly; a missing effect concentrates it.
        uniform = repeatability.uniformity(base)
        sigma = repeatability.estimate(base, _flexible_tokens([sc.token for sc in scored]))
        if verdict is None and not uniform.uniform:
            verdict = OUTSIDE
    if base.status != "converged":
        # the baseline's own unfinished improvement would be credited to every candidate
        verdict = None
        note = (f" The baseline fit did not converge ({base.status}, {base.iterations} "
                 "iterations): the χ² reductions above include its unfinished improvement, "
                 "so no effect is named. Simplify the baseline (lower order, fewer functions) "
                 "or add placements, and diagnose again.")
    where = misfit_location(base)
    cert = None
    if base.plate in ("fixed", "prior") and base.fails_chi2_test:
        report(0.997, "the certificate against the self-calibrated plate")
        cert = check_certificate(base.problem.obs, base.spec, sigma_um=base.sigma_um,
                                 fitted=base)
    msg = _conclusion(base, out, verdict, sigma, uniform, where) + note
    top = next((h for h in checks if h.effect == verdict), None)
    if top is not None and not top.applicable:
        msg += (f" The leave-one-placement-out check cannot judge {verdict} ({top.reason}): "
                "an effect that differs from placement to placement, such as each placement's "
                "own scale or temperature, can look the same; measuring the balls in another "
                "order tells them apart.")
    if cert is not None and cert.suspect:
        msg = cert.message + " " + msg
    report(1.0, "done")
    return Diagnosis(base, out, verdict, skipped, msg, checks, sigma, uniform, where, cert)


def estimate_sigma(data, baseline: str = "kinematic21", *, order: int = 2, plate=None,
                   exclude=(), positions=None, probes=None) -> repeatability.SigmaEstimate:
    """Repeatability estimated from the data (``--sigma-um auto``): from repeated balls
    when the data have them, else from the residuals of the most flexible model the
    diagnosis would try from ``baseline`` (every function one order up, every physical
    effect whose data are present). The estimate does not depend on the σ assumed for
    the fit it starts from."""
    base = fit(data, baseline, order=order, plate=plate, exclude=exclude,
               positions=positions, probes=probes)
    tokens = [t for t in base.problem.spec.candidates()
              if t not in PERIODIC and not _needs_met(t, base)]
    return repeatability.estimate(base, _flexible_tokens(tokens))


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
    return [Candidate(**{**rival.__dict__, "aliases": list(dict.fromkeys(
        [*rival.aliases, top.effect]))}), *rest]


def _checked_verdict(base: FitResult, cands, max_checks: int = 3):
    """Walk the significant candidates best first; the first that passes the
    leave-one-placement-out check (or that the check cannot judge) is the verdict.
    Returns ``(verdict, checks, candidates, note)``; ``verdict`` is ``OUTSIDE`` when the
    significant ones all fail and None when none is significant."""
    sig = [c for c in cands if c.significant][:max_checks]
    if not sig:
        return None, [], cands, ""
    checks, failed = [], []
    for c in sig:
        h = holdout.check(base, c.effect)
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
    share of χ², with their shares (what the user should look at in the residual maps)."""
    from .residuals import breakdown

    out = {}
    for by in ("position", "probe", "ball"):
        b = breakdown(base, by)
        if len(b) > 1:
            v = b.iloc[0][by]
            out[by] = {"name": str(int(v)) if by == "ball" else str(v),
                       "chi2_share": float(b.iloc[0]["chi2_share"]),
                       "expected_share": float(b.iloc[0]["n"] / b["n"].sum())}
    z2 = (base.residuals_um / base.sigma_um) ** 2
    shares = z2.sum(axis=0) / max(z2.sum(), 1e-300)
    a = int(np.argmax(shares))
    out["axis"] = {"name": "xyz"[a], "chi2_share": float(shares[a]), "expected_share": 1 / 3}
    return out


def _refit(base: FitResult, spec, max_iter: int) -> FitResult:
    """Full fit of another model on the baseline's observations, plate and settings."""
    return fit(base.problem.obs, spec, plate=base.plate, sigma_um=base.sigma_um,
               rank_rtol=base.rank_rtol, max_iter=max_iter)


def _nested_p(small: FitResult, big: FitResult) -> float:
    """F-test p-value of the parameters ``big`` adds to ``small`` (both full fits)."""
    dk, dchi2 = big.rank - small.rank, small.chi2 - big.chi2
    if dk <= 0 or dchi2 <= 0:
        return 1.0
    return float(stats.f.sf((dchi2 / dk) / max(big.chi2 / max(big.dof, 1), 1e-300),
                            dk, max(big.dof, 1)))


def _encompassing(base: FitResult, cands, level, refits, alpha=0.01, max_rivals=3,
                  max_iter=500):
    """Nested F-tests between the best candidate A and the next significant ones B.

    Fits base+A, base+B and base+A+B. If A adds nothing at ``alpha`` once B is in while B
    still adds something once A is in (at ``level``), B explains A's evidence and more: B
    goes first (the message says why). If neither adds anything given the other at
    ``level``, they are aliases.
    Returns the reordered candidates and a sentence for the message.
    """
    def refit(spec):
        return _refit(base, spec, max_iter)

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
        out[0] = Candidate(**{**a.__dict__, "aliases": list(dict.fromkeys(
            [*a.aliases, *mutual]))})
    return out, note


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
        res.append(Candidate(**{**c.__dict__, "aliases": al}))
    return res


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
    verdict = "fails" if base.fails_chi2_test else "passes"
    return (f"χ²/dof {base.chi2_dof:.2f} at {base.dof} degrees of freedom against σ = "
            f"{base.sigma_um:.3g} µm {verdict} the χ² test (p = {base.chi2_p_value:.2g})")


def _conclusion(base, cands, verdict, sigma=None, uniform=None, where=None):
    head = f"Baseline {base.spec}: RMS {base.rms_um:.2f} µm; {_test_text(base)}."
    if base.null_combinations:
        head += (f" This design leaves {len(base.null_combinations)} combination(s) of the "
                 "baseline undetermined; candidates are judged only on what it can see, "
                 "and more placements would change the picture.")
    if base.status != "converged":
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
        else:
            text += " Nothing in the catalogue is significant, yet the misfit is concentrated"
            if uniform is not None:
                text += f" (largest: {uniform.worst})"
            text += "."
        loc = _where_text(where or {})
        if loc:
            text += f" Where the residual lives: {loc}."
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
            f"{best.delta_bic:.1f}, p = {best.p_value:.2g}. {expl}")
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


def kinematic_basis(result: FitResult):
    """Per-component design matrices of a fit at its observations, for a GP mean.

    Returns a list of three arrays (n, m_c): an orthonormal basis of the columns of the
    model's Jacobian restricted to the x, y and z residual rows, so that a GP over the
    residuals with this explicit basis cannot absorb what the model already explains.
    """
    _, J = result.problem.residual(result.state, True)
    J = J.toarray()
    out = []
    for c in range(3):
        Jc = J[c::3]
        Jc = Jc[:, np.linalg.norm(Jc, axis=0) > 0]
        U, s, _ = np.linalg.svd(Jc, full_matrices=False)
        keep = s > 1e-8 * s.max() if s.size else s.astype(bool)
        k = min(int(keep.sum()), Jc.shape[0] - 3)
        out.append(U[:, :k])
    return out


@dataclass(frozen=True)
class Discrepancy:
    """GP over a fit's residuals with the model's own design matrix as explicit basis.

    Attributes
    ----------
    amplitude_um : dict
        Signal standard deviation (hyperparameter) of each component's GP (x, y, z), µm.
        Poorly determined when the length scale runs to the size of the machine; use
        ``structure_um`` to compare models.
    length_scale_mm : dict
        Length scale(s) of each component's GP, mm.
    noise_sd_um : dict
        Fitted noise standard deviation per component, µm.
    structure_um : dict
        RMS over the observations of the GP's posterior mean of the discrepancy (the
        part of the residual the GP attributes to smooth structure rather than noise), µm.
    rms_amplitude_um : float
        sqrt(mean over components of ``structure_um`` squared): the one number of the
        add-and-watch history; it falls towards zero when the missing effect is added.
    components : object
        The fitted ``gp_cmm.GPComponents`` (for surfaces).
    """

    amplitude_um: dict
    length_scale_mm: dict
    noise_sd_um: dict
    structure_um: dict
    rms_amplitude_um: float
    components: object = field(repr=False)


@single_blas_thread
def discrepancy_gp(result: FitResult, *, kernel: str = "se_iso", restarts: int = 2,
                   seed: int = 0) -> Discrepancy:
    """Structure left in the residuals: one GP per component over the machine
    coordinates of the observations, with :func:`kinematic_basis` as explicit basis
    (marginalised, R&W §2.7) so the GP cannot absorb what the model already explains. Its
    amplitude shrinks towards zero (the noise takes over) when the missing effect is added.
    """
    from .gp_cmm import gp_components

    o = result.problem.obs
    comps = gp_components(o.r_mm - o.p_mm, result.residuals_um, kernel=kernel,
                          basis=kinematic_basis(result), restarts=restarts, seed=seed)
    amp = {c: float(comps[c].signal_sd_um) for c in comps.names}
    ls = {c: [float(v) for v in comps[c].length_scale_mm] for c in comps.names}
    noise = {c: float(comps[c].noise_sd_um) for c in comps.names}
    X = o.r_mm - o.p_mm
    struct = {c: float(np.sqrt(np.mean(comps[c].predict(X, include_mean=False)[0] ** 2)))
              for c in comps.names}
    return Discrepancy(amp, ls, noise, struct,
                       float(np.sqrt(np.mean(np.square(list(struct.values()))))), comps)


def history_entry(result: FitResult, gp_amplitude_um=None) -> dict:
    """One row of the add-and-watch history."""
    return {"model": result.spec, "rms_um": result.rms_um, "chi2_dof": result.chi2_dof,
            "bic": result.bic, "n_params": result.rank, "gp_amplitude_um": gp_amplitude_um}

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

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, fields, is_dataclass

import numpy as np
import pandas as pd
from scipy import optimize, stats

from .._blas import single_blas_thread
from ..io import DataError, Dataset
from ..model import (
    PERIODIC,
    FitResult,
    Observations,
    catalogue_entry,
    fit,
    has_plate,
    parse_spec,
    select,
    selected_rows,
)
from ..units import label as unit_label
from . import replicates as repeatability
from .blunders import BLUNDERS, BlunderCheck, blunder_check
from .certificate_check import CertificateCheck, check_certificate
from .headline import Headline, headline_of
from .scoring import (
    FAMILY_ALPHA,
    ScoreCache,
    _Scored,
    baseline_basis,
    candidate_noise,
    candidate_stats,
    certificate_noise,
    family_levels,
    needs_met,
    scan_period,
    score,
)
from .verdict import (
    OUTSIDE,
    _checked_verdict,
    _conclusion,
    _encompassing,
    _flexible_tokens,
    _physical_before_periodic,
    _refit,
    _with_aliases,
    evidence,
    misfit_location,
)

__all__ = ["BASE_MAX_ITER", "Candidate", "Diagnosis", "MAX_READINGS", "diagnose",
           "estimate_sigma"]

BASE_MAX_ITER = 2000
"""Gauss-Newton budget of the diagnosis's baseline fit (``model.fit``'s default is 500):
weakly determined directions (one placement, high orders) can need many steps. A given
fit that stopped at a smaller budget without converging is refitted with this one."""

MAX_READINGS = 20_000
"""Probed ball centres one diagnosis takes. Its scores, hold-out checks and placement-scale
tests work on the weighted Jacobian of every candidate at once, dense: about 26 kB per
reading (0.5 GB above the program's own 0.2 GB at 20 000 readings, measured on a simulated
plate with repeats; 5 GB at 200 000). A ball-plate calibration has a few hundred to a few
thousand; beyond this, a diagnosis is refused before any fit rather than exhausting the
machine's memory."""


def _refuse_beyond_limit(data: Dataset | Observations, positions, probes) -> None:
    """A one-line DataError when the selected data hold more than :data:`MAX_READINGS`."""
    if isinstance(data, Observations):
        n, name = int(data.pos.size), "the data"
    else:
        n, name = int(selected_rows(data.meas, positions, probes).sum()), data.name
    if n > MAX_READINGS:
        raise DataError(f"{n} probed ball centres; a diagnosis takes at most {MAX_READINGS} "
                        "(it holds every candidate's Jacobian in memory, about 26 kB a "
                        "reading).", file=name,
                        hint="diagnose fewer placements or styli (positions=, probes=), or "
                             "average repeated readings of a ball.")


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
        and the power of the candidate's test of all its ``n_params`` parameters (a
        parameter correlated with the candidate's others is found alone at that size more
        often: at least 80 %) (``inf``: not determined). Tells what the
        design can and cannot see, e.g. rotations of the ram with short styli.
    level : float
        The significance level this candidate was tested at (its share of the family-wise
        false-alarm rate, weighted Bonferroni).
    fitted : dict
        ``{label: (unit, value, u)}``: the added parameters as the full refit of the
        baseline with this effect estimates them (empty when not confirmed by a refit).
        The verdict quotes them (a probe offset names its stylus and vector).
    would_leave_undetermined : list of str
        Parameter combinations the model with this effect added could not determine
        (beyond the baseline's own), in words: adding it as is leaves them unidentified.
        Fix by a constraint (remove one of the named functions), another placement or
        stylus, or a lower order.
    undetermined_carriers : list of tuple of str
        The parameter labels each of those sentences names (``model.null_carriers``),
        in the same order.
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
    fitted: dict = field(default_factory=dict)
    undetermined_carriers: list = field(default_factory=list, repr=False)

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
                "would_leave_undetermined": self.would_leave_undetermined,
                "fitted": {k: {"unit": unit, "value": v, "u": u}
                           for k, (unit, v, u) in self.fitted.items()}}

    def detectable_text(self) -> str:
        """``dxz[1] > 1.9 µm, dxz[2] > 2.3 µm`` (the first few parameters)."""
        items = [f"{k} > {v:.3g} {unit_label(u)}"
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
    unseen : dict
        Candidates this design cannot see (no parameter determinable on top of the
        baseline), with the reason: listed, never ranked, given no detection limit.
    blunders : blunders.BlunderCheck or None
        Flagged outliers still in the fit and their share of its misfit; when they
        dominate it (``dominant``) the verdict is ``"flagged_outliers"`` and no effect is
        named nor σ estimated.
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
    blunders: BlunderCheck | None = None
    unseen: dict = field(default_factory=dict)

    def headline(self) -> Headline:
        """The verdict in one message (:func:`headline.headline_of`): what the app's
        Diagnose page draws first, the report shows and ``to_dict`` carries."""
        return headline_of(self)

    def to_dict(self) -> dict:
        """JSON-ready result in the ``diagnose`` shape (docs/formats.md), with the
        ``headline`` (:meth:`headline`)."""
        b = self.baseline
        return {"baseline": b.summary(), "headline": self.headline().to_dict(),
                "candidates": [c.to_dict() for c in self.candidates],
                "verdict": self.verdict, "skipped": self.skipped, "message": self.message,
                "holdout": [h.to_dict() for h in self.holdout],
                "sigma_check": None if self.sigma is None else {
                    **self.sigma.to_dict(),
                    "uniform": None if self.uniformity is None else self.uniformity.uniform,
                    "uniformity": None if self.uniformity is None else self.uniformity.to_dict()},
                "where": self.where,
                "certificate": None if self.certificate is None else self.certificate.to_dict(),
                "blunders": None if self.blunders is None else self.blunders.to_dict(),
                "cannot_see": self.unseen,
                "evidence": evidence(b) if self.verdict == OUTSIDE else None}


@single_blas_thread
def diagnose(data: Dataset | Observations, baseline: str = "kinematic21", *, order: int = 2,
         plate: str | None = None, sigma_um: float = 0.5,
         exclude: Iterable[tuple[str, str, int]] = (), positions: Sequence[str] | None = None,
         probes: Sequence[str] | None = None, candidates: Sequence[str] | None = None,
         alpha: float = FAMILY_ALPHA, confirm: int = 3, alias_corr: float = 0.9,
         progress: Callable[[float, str], object] | None = None,
         baseline_fit: FitResult | None = None) -> Diagnosis:
    """Rank the catalogue effects missing from ``baseline`` (see module docstring).

    Parameters
    ----------
    data : Dataset
    baseline : str
        Model spec of the baseline.
    order, plate, sigma_um, exclude, positions, probes
        The baseline fit's settings (``model.fit``'s).
    candidates : list of str, optional
        Tokens to try (default: every catalogue token not in the baseline).
    alpha : float
        Family-wise false-alarm rate, shared over the candidates by weighted Bonferroni
        (:data:`PHYSICAL_SHARE`); default :data:`scoring.FAMILY_ALPHA`.
    confirm : int
        How many of the best scored candidates are confirmed by a full refit.
    alias_corr : float
        Signature correlation above which two candidates are reported as aliases.
    progress : callable, optional
        ``progress(fraction, text)`` is called as candidates are scored and confirmed
        (for a progress bar); exceptions it raises propagate.
    baseline_fit : FitResult, optional
        The baseline fit the caller already holds (``model.fit`` of ``data`` with
        ``baseline`` and the settings above): used as it is, so a diagnosis fits the
        baseline once. Refitted only when it stopped at its iteration budget below the
        diagnosis's own (a converged fit is the same at any budget). Default: fitted here.

    Raises
    ------
    ValueError
        ``baseline_fit`` is not of ``data`` as selected, ``baseline`` or these settings (the
        message names what differs, expected against given).
    DataError
        More than :data:`MAX_READINGS` probed ball centres selected.
    """
    _refuse_beyond_limit(data if baseline_fit is None else baseline_fit.problem.obs,
                         positions, probes)

    def report(frac, text):
        if progress is not None:
            progress(float(min(max(frac, 0.0), 1.0)), text)

    # weakly determined directions (one placement, high orders) can need many steps: the
    # baseline gets a large budget (a converged fit stops early), and the candidates'
    # refits the same one when the baseline needed more than fit's default
    if baseline_fit is not None:
        _check_given_fit(baseline_fit, data, baseline, order=order, plate=plate,
                         sigma_um=sigma_um, exclude=exclude, positions=positions,
                         probes=probes)
    base = baseline_fit
    if base is None or (base.status == "max_iterations" and base.iterations < BASE_MAX_ITER):
        base = fit(data, baseline, order=order, plate=plate, sigma_um=sigma_um,
                   exclude=exclude, positions=positions, probes=probes,
                   max_iter=BASE_MAX_ITER)
    max_iter = 500 if base.iterations <= 500 else 2000
    tokens = candidates if candidates is not None else base.problem.spec.candidates()
    n_steps = len(tokens) + confirm
    skipped, todo = _to_score(base, tokens, report)
    # every candidate's columns from one evaluation of the model with all of them added
    try:
        cache = ScoreCache(base, [t[0] for t in todo]) if todo else None
    except ValueError:  # a superset the spec grammar refuses: each candidate on its own
        cache = None
    scored = []
    for i, (tok, n_scan, period_aliases, family) in enumerate(todo):
        report(i / n_steps, f"scoring {tok} ({i + 1}/{len(todo)})")
        scored.append(_Scored(tok, *score(base, tok, cache), n_scan=n_scan,
                              period_aliases=period_aliases, family=family))
    levels = family_levels([sc.family for sc in scored], alpha)
    noise_of, stats_of = _tests(base, cache)

    def significant(sc):
        return sc.dk > 0 and stats_of(sc)[1] < levels[sc.family]

    def refit_candidate(sc, j):
        report((len(tokens) + j) / n_steps, f"confirming {sc.token} by a full refit")
        ref = _refit(base, base.problem.spec.with_token(sc.token), max_iter, cache)
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
    out, k_of_level = [], {}
    for sc in scored:
        dbic, p, dof_new = stats_of(sc)
        # Size at which a parameter alone is found with 80 % probability at its level by
        # the candidate's test of its n_params = k parameters: |θ| = u s √λ_k, λ_k the
        # non-central χ²_k's parameter of that power, s² = χ²/ν left (the χ² approximation
        # of the F-test, which measures the reduction against the residual scatter left;
        # k = 1: √λ = z_{1-level/2} + z_{0.8}). Conservative for a parameter correlated
        # with the candidate's others: alone it is seen better than its u says.
        # the test's own level: the family's share, divided by the periods a scanned
        # candidate was chosen among (its p carries that Bonferroni factor, as
        # plan.detect's limits do)
        lv = levels[sc.family] / max(int(sc.n_scan), 1)
        if (lv, sc.dk) not in k_of_level:
            k_of_level[lv, sc.dk] = _k_detect(lv, int(sc.dk))
        k_detect = k_of_level[lv, sc.dk]
        scale = float(np.sqrt(sc.chi2_new / dof_new))
        # with a fixed certificate its errors add to each parameter's own direction (c1)
        # and to the residual scatter (c2): the test counts both (certnoise), so does the
        # size it sees (plan.detect's limits, for one parameter alone)
        inflate = _inflation(noise_of(sc), list(sc.u_new))
        e = catalogue_entry(sc.token)
        # Unconfirmed candidates: RMS from the one-step χ² (prior rows are few).
        rms = sc.refit.rms_um if sc.refit is not None else float(
            np.sqrt(max(sc.chi2_new, 0) / n_rows) * sigma_um)
        out.append(Candidate(
            effect=sc.token, title=e.title, explanation=e.explanation, needs=e.needs,
            separate_by=e.separate_by, rms_um=rms, chi2_dof=sc.chi2_new / dof_new,
            delta_chi2=float(sc.dchi2), n_params=int(sc.dk), delta_bic=float(dbic),
            p_value=p, significant=significant(sc), confirmed=sc.refit is not None,
            signature_um=sc.signature,
            # an undetermined parameter has no limit (u reported as 0): inf, never 0
            detectable={lab: (unit, k_detect * scale * ui * inflate.get(lab, 1.0)
                              if ui > 0 else np.inf)
                        for lab, (unit, ui) in sc.u_new.items()},
            level=levels[sc.family],
            would_leave_undetermined=[w for w, _ in sc.combos], fitted=_fitted(sc),
            undetermined_carriers=[c for _, c in sc.combos]))
    out, unseen = _seen(base, out)
    out.sort(key=lambda c: (not c.significant, c.delta_bic))
    out = _with_aliases(out, alias_corr, {sc.token: sc.period_aliases for sc in scored})
    note = ""
    refits = {sc.token: sc.refit for sc in scored}
    if out and out[0].significant:
        report(0.99, "nested tests of the best candidates")
        out, note = _encompassing(base, out, out[0].level, refits, alpha, max_iter=max_iter,
                                  cache=cache)
        out = _physical_before_periodic(out)
    blunders, verdict, checks, out, note = _first_verdict(data, base, out, exclude, note,
                                                          cache, report)
    sigma = uniform = None
    if base.status == "converged" and base.fails_chi2_test and verdict in (None, OUTSIDE):
        # nothing catalogued explains the misfit: σ, or something outside the catalogue?
        # An understated σ spreads the misfit evenly; a missing effect concentrates it.
        uniform = repeatability.uniformity(base)
        sigma = repeatability.estimate(base, _flexible_tokens([sc.token for sc in scored]),
                                       None if cache is None else cache.nominal)
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
    msg = _message(base, out, verdict, sigma, uniform, where, note, checks, cert,
                   blunders) + _unseen_text(unseen)
    report(1.0, "done")
    return Diagnosis(baseline=base, candidates=out, verdict=verdict, skipped=skipped,
                     message=msg, holdout=checks, sigma=sigma, uniformity=uniform,
                     where=where, certificate=cert, blunders=blunders, unseen=unseen)


def _same(a, b) -> bool:
    """Equal values, arrays, frames and (nested) dataclasses, NaN equal to NaN: whether a
    given fit's observations are the ones the diagnosis would select."""
    if a is b:
        return True
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return a.shape == b.shape and bool(np.array_equal(
            a, b, equal_nan=a.dtype.kind in "fc"))
    if isinstance(a, pd.DataFrame):
        return a.equals(b)
    if is_dataclass(a):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return bool(a == b)


def _check_given_fit(given: FitResult, data, baseline, *, order, plate, sigma_um,
                     exclude, positions, probes) -> None:
    """Refuse a baseline fit that is not the one :func:`diagnose` would make: another
    model, plate mode, σ or selection of the data (``ValueError``, expected against
    given)."""
    spec = parse_spec(baseline, default_order=order).to_string(explicit=True)
    obs = data if isinstance(data, Observations) else select(
        data, positions=positions, probes=probes, exclude=exclude)
    mode = plate if plate is not None else (
        "none" if not has_plate(obs) else "fixed" if obs.has_certificate else "free")
    for what, expected, actual in (("model", spec, given.spec), ("plate mode", mode, given.plate),
                                   ("sigma_um", float(sigma_um), float(given.sigma_um))):
        if expected != actual:
            raise ValueError(f"the given baseline fit is of another {what}: the diagnosis "
                             f"expects {expected!r}, the fit has {actual!r}.")
    if not _same(obs, given.problem.obs):
        raise ValueError("the given baseline fit is of other observations: the diagnosis "
                         f"expects {len(obs.table)} observation(s) of positions "
                         f"{list(obs.positions)} and probes {list(obs.probes)} (after the "
                         f"exclusions), the fit has {len(given.problem.obs.table)} of "
                         f"{list(given.problem.obs.positions)} and "
                         f"{list(given.problem.obs.probes)}, or other values.")


def _k_detect(level: float, k: int, power: float = 0.8) -> float:
    """``√λ`` of the non-central χ² with ``k`` degrees of freedom that exceeds the central
    one's ``1 − level`` quantile with probability ``power`` (the power of a k-parameter
    test against a shift of ``√λ`` standard uncertainties; Johnson, Kotz & Balakrishnan,
    *Continuous Univariate Distributions* vol. 2, ch. 29; the large-ν limit of the
    F-test, which plan.detect evaluates exactly). ``k <= 1``: the normal approximation
    ``z_{1-level/2} + z_{power}`` (the two-sided test's far tail dropped)."""
    z = float(stats.norm.isf(level / 2) + stats.norm.isf(1 - power))
    if k <= 1:
        return z
    crit = stats.chi2.isf(level, k)
    lam = optimize.brentq(lambda x: stats.ncx2.sf(crit, k, x) - power, z * z,
                          z * z + 20.0 * k + 50.0)
    return float(np.sqrt(lam))


def _inflation(noise, labels) -> dict:
    """``{label: sqrt(c1_j / c2)}``: how much a fixed certificate's errors scale the size
    at which each added parameter is seen (empty: no certificate)."""
    if noise is None:
        return {}
    return dict(zip(labels, np.sqrt(noise[2] / noise[1]), strict=False))


def _tests(base, cache):
    """``(noise_of, stats_of)``: a candidate's certificate noise (``candidate_noise``: a
    fixed certificate's own errors in its test) and its ΔBIC, p-value and dof
    (``candidate_stats`` with that noise), each computed once (the candidates are sorted
    on them several times)."""
    cert = certificate_noise(base, cache)
    noises: dict = {}
    memo: dict = {}

    def noise_of(sc):
        if (sc.token, sc.dk) not in noises:
            noises[sc.token, sc.dk] = candidate_noise(cert, base, sc.token, sc.dk, cache)
        return noises[sc.token, sc.dk]

    def stats_of(sc):
        key = (sc.dchi2, sc.dk, sc.chi2_new, sc.n_scan)
        if (sc.token, key) not in memo:
            nz = noise_of(sc)
            memo[sc.token, key] = candidate_stats(base, *key,
                                                  noise=None if nz is None else nz[:2])
        return memo[sc.token, key]

    return noise_of, stats_of


def _fitted(sc) -> dict:
    """``{label: (unit, value, u)}`` of a candidate's added parameters from its refit."""
    if sc.refit is None:
        return {}
    idx = {lab: i for i, lab in enumerate(sc.refit.labels)}
    return {lab: (unit, float(sc.refit.values[idx[lab]]), float(sc.refit.u[idx[lab]]))
            for lab, (unit, _) in sc.u_new.items() if lab in idx}


def _seen(base, cands):
    """``(ranked, unseen)``: a candidate that adds no determinable parameter to the
    baseline on this design is not ranked (its ΔBIC of 0 and detection limits of 0 would
    read as "seen, and absent"); it is listed with the reason instead."""
    ranked, unseen = [], {}
    for c in cands:
        if c.n_params > 0:
            ranked.append(c)
            continue
        why = ("none of its parameters is determined by this design on top of the "
               "baseline: the design does not measure what it changes, or the baseline's "
               "own terms absorb it")
        if c.would_leave_undetermined:
            why += ("; adding it as is would leave combinations undetermined: "
                    + " ".join(dict.fromkeys(c.would_leave_undetermined[:2])))
        if base.problem.obs.artefact == "hole_plate":
            why += ("; a hole plate gives only the two coordinates in its plane, so an "
                    "effect normal to the plate (a sag) is invisible to it")
        unseen[c.effect] = why
    return ranked, unseen


def _unseen_text(unseen: dict) -> str:
    """`` Cannot be seen with this design: plate_sag (why).`` or nothing."""
    if not unseen:
        return ""
    return (" Cannot be seen with this design: "
            + "; ".join(f"{k} ({v})" for k, v in unseen.items()) + ".")


def _first_verdict(data, base, out, exclude, note, cache, report):
    """Dominant flagged outliers (``blunders``) before anything else, else the first
    significant candidate passing the leave-one-placement-out check.
    Returns ``(blunders, verdict, checks, candidates, note)``."""
    blunders = (blunder_check(data, base, exclude)
                if base.status == "converged" and base.fails_chi2_test else None)
    if blunders is not None and blunders.dominant:
        # neither a holdout check nor a σ estimate on residuals the outliers dominate
        return blunders, BLUNDERS, [], out, ""
    report(0.995, "leave-one-placement-out checks")
    verdict, checks, out, note2 = _checked_verdict(base, out, cache=cache)
    return blunders, verdict, checks, out, note + note2


def _to_score(base, tokens, report):
    """``(skipped, todo)``: why the data cannot see some tokens, and for the others
    ``(token, n_scan, period_aliases, family)`` with periodic errors' periods scanned."""
    skipped, todo, U = {}, [], None
    for tok in tokens:
        why = needs_met(tok, base)
        if why:
            skipped[tok] = why
            continue
        n_scan, period_aliases, family = 1, [], tok
        if tok in PERIODIC:
            report(0.0, f"scanning the period of {tok}")
            U = baseline_basis(base) if U is None else U
            tok, periods, _, period_aliases = scan_period(base, tok, U)
            n_scan = periods.size
        todo.append((tok, n_scan, period_aliases, family))
    return skipped, todo


def _message(base, out, verdict, sigma, uniform, where, note, checks, cert,
             blunders=None) -> str:
    """The diagnosis in words: the conclusion, what the holdout check could not judge,
    the certificate's suspect entries before it, and dominant flagged outliers first of
    all (a blunder also makes the certificate look wrong)."""
    if verdict == BLUNDERS:
        return blunders.message() + " " + _conclusion(base, out, verdict)
    msg = _conclusion(base, out, verdict, sigma, uniform, where) + note
    if blunders is not None:
        msg += (f" {len(blunders.exclusions)} flagged outlier(s) are still in the fit "
                f"({blunders.text()}), holding {100 * blunders.chi2_share:.0f} % of the "
                "baseline's χ², too little to be the misfit; excluding them is still "
                "advised.")
    top = next((h for h in checks if h.effect == verdict), None)
    if top is not None and not top.applicable:
        msg += (f" The leave-one-placement-out check cannot judge {verdict} ({top.reason}): "
                "an effect that differs from placement to placement, such as each placement's "
                "own scale or temperature, can look the same; measuring the balls in another "
                "order tells them apart.")
    if cert is not None and cert.suspect:
        msg = cert.message + " " + msg
    return msg


def estimate_sigma(data: Dataset | Observations, baseline: str = "kinematic21", *,
               order: int = 2, plate: str | None = None,
               exclude: Iterable[tuple[str, str, int]] = (),
               positions: Sequence[str] | None = None, probes: Sequence[str] | None = None
               ) -> repeatability.SigmaEstimate:
    """Repeatability estimated from the data (``--sigma-um auto``): from repeated balls
    when the data have them, else from the residuals of the most flexible model the
    diagnosis would try from ``baseline`` (every function one order up, every physical
    effect whose data are present). The estimate does not depend on the σ assumed for
    the fit it starts from."""
    base = fit(data, baseline, order=order, plate=plate, exclude=exclude,
               positions=positions, probes=probes)
    tokens = [t for t in base.problem.spec.candidates()
              if t not in PERIODIC and not needs_met(t, base)]
    return repeatability.estimate(base, _flexible_tokens(tokens))

"""Detection limits of the catalogue effects for a measurement plan, from its design.

The diagnosis (``diagnose``) tests each candidate effect E missing from the baseline by
an F-test of the χ² its columns remove, at its own level α_E (weighted Bonferroni over
the candidates it tries; a scanned period pays a further factor for the scan). For data
of a plan with the effect present at size ``s`` along a shape ``e`` of its parameters,
the χ² reduction is non-central χ² with ``k`` degrees of freedom (the rank E adds) and
non-centrality

    λ(s) = s² ‖(I − P_base) J_E e‖² / σ²,

``P_base`` the projector on the baseline's columns (the part of E's pattern the
baseline cannot absorb), ``J_E`` E's columns of the weighted Jacobian. The residual χ²
is central with ν degrees of freedom, so the test statistic is non-central F(k, ν, λ)
(Scheffé 1959, §2.8; non-central χ²(k, λ) as ν → ∞). The detection limit is the size
at which the test rejects with 80 % probability:

    ncf.sf(f.isf(α_E, k, ν), k, ν, λ(s)) = 0.8.

With the plate fixed to a certificate, the certificate's own errors are a second noise,
common to every placement's image of a ball (``diagnosis.certnoise``): within the k
directions the effect's columns span, the Δχ² is the quadratic form
``Σ_i w_i (z_i + δ_i)²`` of k standard normals, ``w_i`` the eigenvalues of its noise
covariance there (their mean ``c1``, :func:`cert_scales`) and ``δ_i`` the effect's
pattern in the eigenvectors over ``√w_i`` (a generalised non-central χ²); the residual χ²
is about ``c2`` times a central χ²(ν) (Satterthwaite 1946). The diagnosis's p-value is
the tail of its statistic under that null (``certnoise.null_p_value``), so the test
rejects when ``Δχ² − a c2 χ²_ν > 0``, ``a`` its critical ``Δχ²/χ²_res``
(``certnoise.critical_ratio``), and the probability of that at size s is Imhof's (1961,
eq. 3.2) integral (:func:`rejection_probability`). The limit is the size at which it is
0.8. With equal ``w_i`` (k = 1) it is exactly ``ncf.sf(f.isf(α_E, k, ν), k, ν,
λ(s)/c1) = 0.8`` (:func:`noncentrality_for_power`). ``bench/plan.py`` found the former
shortcut (one scale ``c1`` for all k directions, the plain F-test) 1-2 points optimistic
for backlash and plate sag, whose directions the certificate's errors load unevenly
(eigenvalues 1.06-1.29 and 1.00-1.20 on the thesis plan).

Sizes are in the effect's parameter units along its shape ``e`` (largest weight 1):
``docs/planning.md`` lists the shapes. An effect with several shapes (a probe offset
error along x, y or z) reports the worst one.

The diagnosis's private helpers used here (which tokens it tries, their levels, the test
statistics) are wrapped in one place, :func:`_diagnosis_rules`, to be easy to repoint.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize, stats

from .._blas import single_blas_thread
from ..diagnosis import (
    MIN_FORM_DOF,
    cert_columns,
    cert_noise,
    cert_scales,
    rejection_probability,
    scan_period,
    score,
    size_for_power,
)
from ..diagnosis import scoring as sc
from ..model import (
    BY_TOKEN,
    PERIODIC,
    FitResult,
    Observations,
    Problem,
    augmented_state,
    parse_spec,
    weighted_residual,
)
from .plans import Plan, fit_plan_data, simulate_plan

POWER = 0.8
"""Probability of detection that defines the detection limit."""


def _diagnosis_rules():
    """The diagnosis's own rules (``scoring``): skip reason, levels, F-test statistics,
    scan size, shortest resolvable period."""

    return sc.needs_met, sc.family_levels, sc.candidate_stats, sc.PERIOD_SCAN[1], \
        sc.shortest_resolvable_period


@dataclass(frozen=True)
class DetectionLimit:
    """Smallest size of one catalogue effect that the diagnosis names with 80 % power.

    Attributes
    ----------
    effect : str
        Model token as the diagnosis tries it (``plate_sag``, ``dyz:3``,
        ``periodic_x:420``).
    size : float
        Detection limit along ``shape`` in ``unit`` (``inf``: the design cannot see it).
    unit : str
        Unit of the size (``um``, ``urad``, ``um/h``, ``1e-6/K``).
    shape : dict
        Parameter label -> weight of the effect's shape (largest weight 1).
    n_params : int
        Rank the effect adds: the numerator degrees of freedom k of the test.
    dof : int
        Residual degrees of freedom ν of the test.
    level : float
        False-alarm level of the test (α_E, divided by the periods scanned).
    noncentrality_per_unit2 : float
        λ for a unit size: λ(s) = s² × this.
    note : str
        How the shape was chosen, or why the effect cannot be seen.
    family : str
        The diagnosis's candidate token (``periodic_x`` for ``periodic_x:420``).
    numerator_scale, denominator_scale : float
        Noise scales ``c1``, ``c2`` of the test's Δχ² per degree of freedom and of its
        residual χ²/ν (1 for white noise at σ; above 1 with a fixed certificate, whose own
        errors add to both: :func:`cert_scales`). λ is divided by the first; the test
        itself counts both (``diagnosis.certnoise``).
    noise_weights : tuple of float
        Eigenvalues ``w_i`` of the Δχ²'s noise covariance in the effect's k directions
        (empty: all equal to ``numerator_scale``).
    signal_per_unit2 : tuple of float
        ``δ_i²`` per unit size² along ``shape`` in those eigen-directions (with
        ``noise_weights``; their ``w``-weighted sum is ``noncentrality_per_unit2``).
    """

    effect: str
    size: float
    unit: str
    shape: dict
    n_params: int
    dof: int
    level: float
    noncentrality_per_unit2: float
    note: str = ""
    family: str = field(default="", repr=False)
    numerator_scale: float = 1.0
    denominator_scale: float = 1.0
    noise_weights: tuple = field(default=(), repr=False)
    signal_per_unit2: tuple = field(default=(), repr=False)

    def to_dict(self) -> dict:
        """JSON record ``{"size", "unit", ...}`` (an infinite size is null)."""
        return {"size": self.size if np.isfinite(self.size) else None, "unit": self.unit,
                "shape": self.shape, "n_params": self.n_params, "level": self.level,
                "dof": self.dof, "note": self.note}

    def power(self, size: float) -> float:
        """Probability that the diagnosis's test names an effect of ``size``."""
        if self.n_params <= 0:
            return self.level
        c1, c2 = self.numerator_scale, self.denominator_scale
        if self.noise_weights:
            return rejection_probability(np.asarray(self.noise_weights),
                                         size ** 2 * np.asarray(self.signal_per_unit2),
                                         self.dof, self.level, c2)
        # the test divides F by c1/c2 (certnoise.null_p_value): the plain critical value
        lam = size ** 2 * self.noncentrality_per_unit2 / c1
        crit = stats.f.isf(self.level, self.n_params, self.dof)
        return float(stats.ncf.sf(crit, self.n_params, self.dof, lam))


@functools.lru_cache(maxsize=512)
def noncentrality_for_power(k: int, nu: int, level: float, power: float = POWER,
                            ratio: float = 1.0) -> float:
    """λ at which the F-test of k numerator and ν denominator dof at ``level`` rejects
    with probability ``power`` (scipy ``ncf``; brentq on a bracket that doubles).
    ``ratio``: the denominator's over the numerator's noise scale (:func:`cert_scales`),
    which moves the critical value of the unscaled statistic by that factor."""
    crit = stats.f.isf(level, k, nu) * ratio

    def gap(lam):
        return float(stats.ncf.sf(crit, k, nu, lam)) - power

    hi = 1.0
    while gap(hi) < 0:
        hi *= 2.0
    return float(optimize.brentq(gap, 0.0, hi, xtol=1e-10, rtol=1e-10))


def baseline_basis(base: FitResult) -> tuple:
    """Orthonormal basis U of what the baseline can explain (its weighted, constrained
    Jacobian's column space, numerical rank by the fit's rule: singular values of the
    column-scaled reduced matrix above ``rank_rtol`` times the largest) and that largest
    singular value."""
    _, _, J = weighted_residual(base.problem, base.state, base.sigma_um, True)
    A = J.toarray()
    norms = np.linalg.norm(A, axis=0)
    S = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
    C = base.problem.constraints()
    Z = linalg.null_space(C * S) if C.shape[0] else np.eye(A.shape[1])
    U, sv, _ = np.linalg.svd((A * S) @ Z, full_matrices=False)
    keep = sv > base.rank_rtol * sv.max()
    return U[:, keep], float(sv.max())


def _shapes(token: str, labels: list, base_spec, positions, probes) -> list:
    """Candidate shapes ``(name, {label: weight})`` of an effect (see docs/planning.md):
    a physical effect's are its block's (``Block.detection_shapes``; by default each of
    its parameters alone, the worst reported)."""
    name = token.partition(":")[0]
    if name in BY_TOKEN:
        return BY_TOKEN[name].detection_shapes(labels, positions, probes)
    if name in PERIODIC:
        return [("sine term", {labels[0]: 1.0})]
    if name not in dict(base_spec.orders):
        return [(f"{lab} alone", {lab: 1.0}) for lab in labels]
    present = base_spec.order(name) > 0
    lab = labels[-1] if present else labels[0]
    return [("highest new degree" if present else "lowest degree", {lab: 1.0})]


def default_period(obs: Observations, axis: int) -> float:
    """Period (mm) at which a periodic error along ``axis`` is judged when the plan does
    not give one: the geometric mean of the scanned range (shortest resolvable period to
    the span of the balls)."""
    shortest = _diagnosis_rules()[4](obs, axis)[0]
    span = float(np.ptp((obs.r_mm - obs.p_mm)[:, axis]))
    return float(np.sqrt(shortest * max(span, 2 * shortest)))


def candidate_tokens(base: FitResult, alpha: float) -> tuple[list, dict, dict]:
    """The tokens the diagnosis would try on this design, the reasons for those it would
    skip, and each tried family's level ``{family: α_E}``."""
    needs_met, levels, _, _, _ = _diagnosis_rules()
    tried, skipped = [], {}
    for tok in base.problem.spec.candidates():
        why = needs_met(tok, base)
        if why:
            skipped[tok] = why
        else:
            tried.append(tok)
    return tried, skipped, levels(tried, alpha)


def _all_candidates_spec(base: FitResult, tokens):
    """One model holding every candidate's columns at once: each function at the highest
    order tried, the absent functions, the physical effects and periods. A candidate's
    columns are the same in it as in its own augmented model (Chebyshev columns do not
    depend on the highest order; every new parameter is zero), so one Jacobian serves
    all candidates."""
    spec = base.problem.spec
    for tok in tokens:
        spec = spec.with_token(tok) if ":" not in tok or tok.partition(":")[0] in PERIODIC \
            or int(tok.partition(":")[2]) > spec.order(tok.partition(":")[0]) else spec
    return spec


def detection_limits(base: FitResult, plan: Plan, *, power: float = POWER
                     ) -> tuple:
    """Detection limit of every catalogue effect the diagnosis would try on the plan's
    data (module docstring). Returns ``({token: DetectionLimit}, {token: skip reason})``.
    """
    tried, skipped, levels = candidate_tokens(base, plan.model["alpha"])
    n_scan = _diagnosis_rules()[3]
    obs = base.problem.obs
    tokens = {}
    for fam in tried:
        if fam in PERIODIC:
            a = "xyz".index(fam[-1])
            period = plan.model["periods_mm"].get(fam[-1]) or default_period(obs, a)
            tokens[fam] = (f"{fam}:{period:.0f}", n_scan)
        else:
            tokens[fam] = (fam, 1)
    U, sv_max = baseline_basis(base)
    big = Problem(obs, _all_candidates_spec(base, [t for t, _ in tokens.values()]),
                  base.plate)
    _, _, J = weighted_residual(big, augmented_state(base, big), base.sigma_um, True)
    J = J.toarray()
    col = {lab: i for i, lab in enumerate(big.layout.labels)}
    units = dict(zip(big.layout.labels, big.layout.units, strict=True))
    have = set(base.labels)
    n_rows = base.dof + base.rank
    G = cert_columns(base)
    MG = None
    if G is not None:  # rows beyond the observations' (instruments) carry no plate
        G = np.vstack([G, np.zeros((J.shape[0] - G.shape[0], G.shape[1]))])
        MG = G - U @ (U.T @ G)
    out = {}
    for fam, (token, scan) in tokens.items():
        own = Problem(obs, base.problem.spec.with_token(token), base.plate).layout.labels
        labels = [lab for lab in own if lab not in have]
        JE = J[:, [col[lab] for lab in labels]]
        R = JE - U @ (U.T @ JE)
        norms = np.linalg.norm(JE, axis=0)
        scaled = R / np.where(norms > 0, norms, 1.0)
        k = int((np.linalg.svd(scaled, compute_uv=False) > base.rank_rtol * sv_max).sum()) \
            if scaled.size else 0
        nu = max(n_rows - base.rank - k, 1)
        level = levels[fam] / scan
        c1, c2 = cert_scales(MG, R, k, nu)
        lam = c1 * noncentrality_for_power(k, nu, level, power) if k > 0 else np.inf
        w, V, Q = cert_noise(MG, R, k) if k > 0 else (np.ones(0), None, None)
        # unequal noise in the k directions: the generalised non-central χ² (docstring)
        uneven = k > 1 and nu + k >= MIN_FORM_DOF and float(w.max() - w.min()) > 1e-6 * float(w.max())
        sizes = {}
        for sname, shape in _shapes(fam, labels, base.problem.spec, obs.positions,
                                    obs.probes):
            e = np.array([shape.get(lab, 0.0) for lab in labels])
            pattern = float(np.linalg.norm(JE @ e))
            q = float(np.sum((R @ e) ** 2))
            # the fit's rank rule: a pattern the baseline absorbs but for a relative
            # remainder below rank_rtol (scaled) is not seen at all
            seen = k > 0 and pattern > 0 and np.sqrt(q) > base.rank_rtol * sv_max * pattern
            d2: tuple = ()
            size = float(np.sqrt(lam / q)) if seen else np.inf
            if seen and uneven:
                d2 = tuple((V.T @ (Q.T @ (R @ e))) ** 2 / w)
                size = size_for_power(w, np.array(d2), int(nu), level, c2, power, size)
            sizes[sname] = (size, shape, q, d2)
        sname = max(sizes, key=lambda n: sizes[n][0])
        size, shape, q, d2 = sizes[sname]
        unit = units[max(shape, key=lambda lab: abs(shape[lab]))]
        note = f"shape: {sname}"
        if len(sizes) > 1:
            note += " (the worst of: " + ", ".join(
                f"{n} {v[0]:.3g}" for n, v in sizes.items()) + f" {unit})"
        if scan > 1:
            note += (f"; period {token.partition(':')[2]} mm, level divided by the {scan} "
                     "periods scanned")
        if not np.isfinite(size):
            note = ("the baseline absorbs this pattern (or the design cannot determine it): "
                    "no size is detectable. " + note)
        out[token] = DetectionLimit(token, size, unit, shape, k, int(nu), float(level), q,
                                    note, fam, c1, c2,
                                    tuple(map(float, w)) if d2 else (), d2)
    return out, skipped


def injection(limit: DetectionLimit, plan: Plan, size: float) -> dict:
    """``simulation_config`` keywords that hide the effect at ``size`` along its shape in
    simulated data of ``plan`` (the kinematic coefficients otherwise drawn from the
    plan's prior sizes)."""

    fam, token = limit.family or limit.effect, limit.effect
    vals = {lab: size * w for lab, w in limit.shape.items()}
    if fam in BY_TOKEN:  # a physical effect: its block's simulator keys
        body = BY_TOKEN[fam].injection(vals)
        if body is None:
            raise ValueError(f"the effect {fam!r} cannot be hidden in simulated data (its "
                             "block has no injection).")
        return {"effects": {fam: body}}
    spec = parse_spec(plan.model["spec"], default_order=plan.model["order"]).with_token(token)
    return {"spec": spec.to_string(), "coefficients": vals}


def diagnosis_detects(base: FitResult, limit: DetectionLimit) -> tuple:
    """Run the diagnosis's test of ``limit``'s effect on a fit of (simulated) data:
    its one-step score, the F-test p-value (a scanned period pays for the scan) against
    the effect's level. Returns ``(detected, p_value, Δχ²)``."""

    _, _, stats_of, _, _ = _diagnosis_rules()
    token, scan = limit.effect, 1
    if limit.family in PERIODIC:
        token, periods, _, _ = scan_period(base, limit.family)
        scan = periods.size
    dchi2, dk, _, chi2_new, _, _ = score(base, token)
    if dk <= 0:
        return False, 1.0, 0.0
    # the fixed certificate's own errors in the test, as the diagnosis counts them
    nz = sc.candidate_noise(sc.certificate_noise(base), base, token, dk)
    p = stats_of(base, dchi2, dk, chi2_new, scan, None if nz is None else nz[:2])[1]
    # the level already carries the scan factor; stats_of multiplies p by it instead
    level = limit.level * (scan if limit.family in PERIODIC else 1)
    return bool(p < level), float(p), float(dchi2)


@single_blas_thread
def detection_trial(plan: Plan, limit: DetectionLimit, size: float, seed: int) -> tuple:
    """One Monte Carlo trial of a detection limit: simulate the plan's data with noise,
    the prior kinematic errors and the effect at ``size``, fit the plan's model and run
    the diagnosis's test of the effect. Returns ``(detected, p_value, Δχ²)``."""

    data = simulate_plan(plan, seed=seed, noise_um=plan.noise_um, prior=True,
                         **injection(limit, plan, size))
    return diagnosis_detects(fit_plan_data(plan, data), limit)

"""Design a measurement plan: the cheapest plan of a pool that meets a target.

The pool is a set of *units*: one stylus measuring the plate in one placement (all balls,
the plan's repeats). A plan is a subset of units; its cost is its measuring time
(``Plan.time_min``). The target may ask for

- ``determined``: every parameter of the model determined (no undetermined combination);
- ``U3_um``: the thesis U3 (working volume, rigid-body freedoms removed) at most this,
  on every axis;
- ``detect``: ``{effect: size}``, each effect's detection limit at most that size.

Every unit's rows of the weighted Jacobian are computed once, from noise-free data of
the whole pool; a plan's information matrix is the sum of its units' Gram matrices
``N_S = Σ J_uᵀ J_u`` (Fisher information of the linearised model). On it:

- the rank and the covariance follow the fit's rule (column-scaled, gauge constraints by
  null-space projection, relative singular-value tolerance ``rank_rtol``);
- a detection limit uses the Schur complement of the effect's columns,
  ``N_EE − N_EB N_BB⁺ N_BE = ‖(I − P_base) J_E‖²`` (``detect``'s non-centrality);
- the search criterion is Bayesian D- or A-optimality of the kinematic coefficients
  (Chaloner & Verdinelli 1995): the posterior precision ``N_S + Π`` with the plan's
  prior sizes in Π, so that plans with undetermined parameters still compare.

Search: greedy forward selection by criterion gain per minute until the target is met,
then backward elimination and 1-exchange (swap a unit for a cheaper one) while the
target still holds (Fedorov's exchange idea, with cost). The result is evaluated exactly
(``plan.evaluate``) and the target checked on those numbers; the targets that fail when
any one unit is removed are the binding ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg

from .._blas import single_blas_thread
from ..diagnosis import MIN_FORM_DOF, size_for_power
from ..machine import kinematics as kin
from ..model import Problem, augmented_state, rigid_body_projector, select, weighted_residual
from ..units import UM
from .detect import POWER, detection_limits, noncentrality_for_power
from .evaluation import PlanEvaluation, evaluate
from .plans import Plan, fit_plan_data, simulate_plan

WEAK_PRIOR = 1e4
"""Prior standard deviation (µm, µrad) of the nuisance parameters (placements, plate) in
the Bayesian search criterion: weak enough to leave the data in charge."""


class PoolModel:
    """Information of every unit of a pool, for fast evaluation of subsets."""

    def __init__(self, plan: Plan, pool: dict, detect: dict | None = None):
        self.plan = plan.with_units(pool, "pool")
        self.units = [(p, q) for p, qs in pool.items() for q in qs]
        data = simulate_plan(self.plan, seed=plan.seed)
        base = fit_plan_data(self.plan, data)
        self.base, self.detect = base, dict(detect or {})
        spec = base.problem.spec
        for tok in self.detect:
            spec = spec.with_token(tok)
        obs = select(data)
        prob = Problem(obs, spec, base.plate)
        _, _, J = weighted_residual(prob, augmented_state(base, prob), base.sigma_um, True)
        J = J.toarray()
        L = prob.layout
        n_obs_rows = 3 * prob.n_obs
        unit_of_obs = {(p, q): i for i, (p, q) in enumerate(self.units)}
        rows = np.array([unit_of_obs[(obs.positions[k], obs.probes[j])]
                         for k, j in zip(obs.pos, obs.probe, strict=True)]).repeat(3)
        self.gram = np.array([J[:n_obs_rows][rows == u].T @ J[:n_obs_rows][rows == u]
                              for u in range(len(self.units))])
        self.rows_per_unit = np.bincount(rows, minlength=len(self.units))
        self.prior_gram = J[n_obs_rows:].T @ J[n_obs_rows:]
        # with the certificate fixed its uncertainty propagates into every parameter
        # (model.certificate_prior): per unit, the cross information of the parameters and the
        # plate coordinates, to be summed over a subset like the Gram matrices
        self.cert_cross, self.cert_u2, self.cert_sq = None, None, None
        if base.plate == "fixed" and obs.cert_u_um is not None:
            pp = Problem(obs, spec, "prior")
            Jp = weighted_residual(pp, augmented_state(base, pp), base.sigma_um,
                                   True)[2].toarray()[:n_obs_rows]
            blk = pp.layout.blocks["plate"]
            Jc = Jp[:, blk.start:blk.stop]
            self.cert_cross = np.array([J[:n_obs_rows][rows == u].T @ Jc[rows == u]
                                        for u in range(len(self.units))])
            self.cert_u2 = np.nan_to_num(obs.cert_u_um.ravel() ** 2, posinf=0.0)
            # the certificate's errors as a noise of the detection test (detect.
            # cert_scales): per unit, the squared norms of their weighted columns
            self.cert_sq = np.array([np.sum(Jc[rows == u] ** 2, axis=0)
                                     for u in range(len(self.units))]) * self.cert_u2
        self.n_prior_rows = J.shape[0] - n_obs_rows
        self.C = prob.constraints()
        self.labels = L.labels
        # columns that belong to one placement or stylus (inactive when it is not measured)
        owner: list[tuple[str, str] | None] = [None] * L.n
        for i, lab in enumerate(L.labels):
            head = lab.split(".")[0]
            if L.groups[i] in ("rotation", "translation", "drift"):
                owner[i] = ("pos", head)
            elif L.groups[i] == "probe_offset":
                owner[i] = ("probe", head[len("probe"):])
        self.owner = owner
        base_labels = set(base.labels)
        self.effect_cols = {tok: [i for i, lab in enumerate(L.labels) if lab not in base_labels
                                  and lab in Problem(obs, base.problem.spec.with_token(tok),
                                                     base.plate).layout.labels]
                            for tok in self.detect}
        self.base_cols = np.array([lab in base_labels for lab in L.labels])
        self.kin = np.array([g == "kinematic" for g in L.groups]) & self.base_cols
        self.prior_sd = np.array([
            (plan.model["prior_um"] if u == "um" else plan.model["prior_urad"]) or 1.0
            if g == "kinematic" else WEAK_PRIOR for g, u in zip(L.groups, L.units, strict=True)])
        # U3's points and their rigid-removed error Jacobians, per stylus
        rng = np.random.default_rng(plan.seed)
        rng.random((200, 3))  # uncertainty.evaluate draws U2's points first
        pts = np.asarray(obs.range_mm, float) * rng.random((200, 3))

        self.Eu = {}
        kin_cols = np.flatnonzero(self.kin)
        for q in obs.probes:
            p = np.broadcast_to(obs.p_mm[obs.probe == obs.probes.index(q)][0], pts.shape)
            _, Jk = kin.jacobian(base.terms, base.kinematic_coef, pts, p)
            Je = (Jk / UM).reshape(-1, Jk.shape[2])
            self.Eu[q] = (rigid_body_projector(pts) @ Je, kin_cols)
        self.rank_rtol = base.rank_rtol
        # each detection target's level and shape: the diagnosis's, on the whole pool

        limits, skipped = detection_limits(base, self.plan) if self.detect else ({}, {})
        self.levels, self.shapes = {}, {}
        for tok in self.detect:
            lim = limits.get(tok)
            if lim is None:
                why = skipped.get(tok, "not a catalogue effect missing from the model "
                                       f"(the diagnosis tries: {', '.join(limits)})")
                raise ValueError(f"{tok!r} cannot be a detection target on this pool: "
                                 f"{why}.")
            self.levels[tok] = lim.level
            self.shapes[tok] = np.array([lim.shape.get(L.labels[c], 0.0)
                                         for c in self.effect_cols[tok]])

    def cost(self, sel: Sequence[int]) -> float:
        """Measuring time (minutes) of a subset of units (indices)."""
        m = self.plan.measurement
        balls = self.plan.plate["rows"] * self.plan.plate["cols"]
        places = {self.units[u][0] for u in sel}
        return float(len(sel) * balls * m["repeats"] * m["minutes_per_ball"]
                     + len(places) * m["minutes_per_placement"])

    def _active(self, sel):
        places = {self.units[u][0] for u in sel}
        probes = {self.units[u][1] for u in sel}
        return np.array([o is None or (o[0] == "pos" and o[1] in places)
                         or (o[0] == "probe" and o[1] in probes) for o in self.owner])

    def _normal(self, sel):
        N = self.gram[list(sel)].sum(0) + self.prior_gram
        return N

    def check(self, sel: Sequence[int]) -> dict:
        """Fast figures of a subset: determined, U3 (max over axes, µm; inf when
        undetermined) and each detection target's limit."""
        if not sel:
            return {"determined": False, "U3_um": np.inf,
                    "detect": dict.fromkeys(self.detect, np.inf)}
        act = self._active(sel) & self.base_cols
        N = self._normal(sel)
        idx = np.flatnonzero(act)
        Nb = N[np.ix_(idx, idx)]
        d = np.sqrt(np.clip(np.diag(Nb), 0, None))
        S = np.where(d > 0, 1 / np.where(d > 0, d, 1), 1.0)
        C = self.C[:, idx]
        C = C[np.abs(C).sum(1) > 0]
        Z = linalg.null_space(C * S) if C.shape[0] else np.eye(len(idx))
        Nr = Z.T @ (S[:, None] * Nb * S[None, :]) @ Z
        lam, V = np.linalg.eigh((Nr + Nr.T) / 2)
        sv = np.sqrt(np.clip(lam, 0, None))
        keep = sv > self.rank_rtol * sv.max()
        determined = bool(keep.all())
        ZV = Z @ V[:, keep]
        cov = (S[:, None] * ((ZV / lam[keep]) @ ZV.T)) * S[None, :]
        cov_u = cov
        if self.cert_cross is not None:  # the certificate's uncertainty, as the fit has it
            CG = cov @ self.cert_cross[list(sel)].sum(0)[idx]
            cov_u = cov + (CG * self.cert_u2) @ CG.T
        u3 = np.inf
        if determined:
            first = self.units[min(sel)][1]
            E, kin_cols = self.Eu[first]
            pos = {c: i for i, c in enumerate(idx)}
            kk = [pos[c] for c in kin_cols]
            Vk = cov_u[np.ix_(kk, kk)]
            u = np.sqrt(np.clip(np.einsum("ik,kl,il->i", E, Vk, E), 0, None)).reshape(-1, 3)
            u3 = float(u.mean(0).max())
        det = {}
        rank = int(keep.sum())
        n_rows = int(self.rows_per_unit[list(sel)].sum()) + self.n_prior_rows
        XG = None
        if (self.cert_cross is not None and self.cert_u2 is not None
                and self.cert_sq is not None):  # Jᵀ G, tr(Gᵀ M G): the certificate's errors
            XG = self.cert_cross[list(sel)].sum(0) * np.sqrt(self.cert_u2)
            XB = XG[idx]
            tr_mg = float(self.cert_sq[list(sel)].sum() - np.sum(XB * (cov @ XB)))
        for tok, cols in self.effect_cols.items():
            e_idx = np.array(cols)
            NEE = N[np.ix_(e_idx, e_idx)]
            NEB = N[np.ix_(e_idx, idx)]
            schur = NEE - NEB @ cov @ NEB.T
            dE = np.sqrt(np.clip(np.diag(NEE), 1e-300, None))
            w = np.linalg.eigvalsh((schur + schur.T) / 2 / np.outer(dE, dE))
            k = int((np.sqrt(np.clip(w, 0, None)) > self.rank_rtol * sv.max()).sum())
            shape = self.shapes[tok]
            q = float(shape @ schur @ shape)
            nu = max(n_rows - rank - k, 1)
            ok = k > 0 and q > (self.rank_rtol * sv.max()) ** 2 * float(shape @ NEE @ shape)
            c1 = c2 = 1.0
            noise: tuple | None = None
            if XG is not None and ok:  # detect.cert_scales from the Gram matrices
                XE = XG[e_idx] - NEB @ cov @ XB  # Rᵀ M G
                ws, vs = np.linalg.eigh((schur + schur.T) / 2)
                top = np.argsort(ws)[::-1][:k]
                C = (vs[:, top].T @ XE) / np.sqrt(ws[top])[:, None]  # Qᵀ M G
                on = float(np.sum(C ** 2))
                c1, c2 = 1.0 + on / k, 1.0 + (tr_mg - on) / nu
                # detect.cert_noise: the Δχ²'s noise in the k directions, and the shape's
                # pattern there (Qᵀ R e = S Vᵀ e)
                w, V2 = np.linalg.eigh(np.eye(k) + C @ C.T)
                noise = (w, V2.T @ (np.sqrt(ws[top]) * (vs[:, top].T @ shape)))
            # the diagnosis's test divides F by c1/c2 (diagnosis.certnoise): the plain F's
            # critical value; uneven noise in k > 1 directions: Imhof's integral, as
            # detect.detection_limits
            size = (float(np.sqrt(c1 * noncentrality_for_power(
                k, nu, self.levels[tok], POWER) / q)) if ok else np.inf)
            if ok and noise is not None and k > 1 and nu + k >= MIN_FORM_DOF:
                w, mu = noise
                if float(w.max() - w.min()) > 1e-6 * float(w.max()):
                    size = size_for_power(w, mu ** 2 / w, int(nu), self.levels[tok], c2,
                                          POWER, size)
            det[tok] = size
        return {"determined": determined, "U3_um": u3, "detect": det}

    def criterion(self, sel: Sequence[int], kind: str) -> float:
        """Bayesian D (log det of the kinematic posterior precision) or A (minus the sum
        of kinematic posterior variances in units of their prior variances); larger is
        better."""
        act = self._active(sel) & self.base_cols
        idx = np.flatnonzero(act)
        M = (self._normal(sel) if sel else self.prior_gram)[np.ix_(idx, idx)] + np.diag(
            1 / self.prior_sd[idx] ** 2)
        cov = np.linalg.inv(M)
        kk = self.kin[idx]
        Vk = cov[np.ix_(kk, kk)]
        if kind == "D":
            return float(-np.linalg.slogdet(Vk)[1])
        return float(-np.sum(np.diag(Vk) * self.prior_sd[idx][kk] ** -2))


def meets(fig: dict, target: dict) -> bool:
    """True when the figures of a plan meet every target."""
    return not failing(fig, target)


def failing(fig: dict, target: dict) -> list:
    """Names of the targets a plan's figures fail (``determined``, ``U3_um``,
    ``detect.EFFECT``)."""
    out = []
    if target.get("determined") and not fig["determined"]:
        out.append("determined")
    if "U3_um" in target and not fig["U3_um"] <= target["U3_um"]:
        out.append("U3_um")
    for tok, size in target.get("detect", {}).items():
        if not fig["detect"].get(tok, np.inf) <= size:
            out.append(f"detect.{tok}")
    return out


@dataclass(frozen=True)
class DesignResult:
    """The cheapest plan of the pool found to meet the target.

    Attributes
    ----------
    plan : Plan
        The designed plan.
    evaluation : PlanEvaluation
        Its exact evaluation (``plan.evaluate``).
    units : list of str
        Its units, ``placement/stylus``.
    time_min : float
        Its measuring time, minutes.
    criterion : str
        ``D`` or ``A`` (Bayesian optimality of the kinematic coefficients).
    target : dict
        The target as given.
    achieved : dict
        The exact figures the target is judged on: ``determined``, ``U3_um`` (largest
        axis, µm), ``detect`` sizes.
    binding : list of str
        Targets that fail when any one unit is removed: what makes the plan this large.
    steps : list of dict
        The search: each unit added, removed or exchanged, with the time after it.
    random_best_time_min : float or None
        Shortest measuring time among ``n_random`` random plans of the pool that meet
        the target (units added in random order until it is met); None when none did.
    n_random : int
        Random plans drawn for that comparison.
    message : str
        Plain-language summary.
    """

    plan: Plan
    evaluation: PlanEvaluation = field(repr=False)
    units: list
    time_min: float
    criterion: str
    target: dict
    achieved: dict
    binding: list
    steps: list
    random_best_time_min: float | None
    n_random: int
    message: str

    def to_dict(self) -> dict:
        """JSON-ready record (``plan``'s ``design`` entry)."""
        return {"name": self.plan.name, "units": self.units, "time_min": self.time_min,
                "criterion": self.criterion, "target": self.target,
                "achieved": _finite(self.achieved), "binding": self.binding,
                "steps": self.steps, "random_best_time_min": self.random_best_time_min,
                "n_random": self.n_random, "message": self.message,
                "evaluation": self.evaluation.to_dict()}


def _finite(d):
    if isinstance(d, dict):
        return {k: _finite(v) for k, v in d.items()}
    return None if isinstance(d, float) and not np.isfinite(d) else d


def figures(ev: PlanEvaluation, target: dict) -> dict:
    """The figures a target is judged on, from an exact evaluation."""
    det = {}
    for tok in target.get("detect", {}):
        lim = next((v for v in ev.detection_limits.values()
                    if v.effect == tok or v.family == tok), None)
        det[tok] = np.inf if lim is None else lim.size
    return {"determined": ev.determined,
            "U3_um": max(ev.U3_um.values()) if ev.U3_um else np.inf, "detect": det}


def random_plans(pm: PoolModel, target: dict, n: int,
                 rng: np.random.Generator) -> list:
    """``n`` random plans of the pool meeting the target: units in random order, added
    until the target is met (the fast figures)."""
    out: list[list[int]] = []
    for _ in range(50 * n):
        if len(out) == n:
            break
        sel: list[int] = []
        for u in rng.permutation(len(pm.units)):
            sel = sorted([*sel, int(u)])
            if meets(pm.check(sel), target):
                out.append(sel)
                break
    return out


def _label(pm, sel):
    return [f"{pm.units[u][0]}/{pm.units[u][1]}" for u in sel]


def _as_plan(pm: PoolModel, sel, name) -> Plan:
    probes_of: dict[str, list[str]] = {}
    for u in sel:
        p, q = pm.units[u]
        probes_of.setdefault(p, []).append(q)
    return pm.plan.with_units({p: tuple(q) for p, q in probes_of.items()}, name)


@single_blas_thread
def design(plan: Plan, pool: dict, target: dict, *, criterion: str = "D",
           n_random: int = 20, restarts: int = 20, seed: int = 0,
           name: str = "designed") -> DesignResult:
    """Cheapest plan of ``pool`` (placement -> styli) meeting ``target`` (module
    docstring). Raises ValueError when the whole pool does not meet it."""
    if criterion not in ("D", "A"):
        raise ValueError(f"criterion must be 'D' or 'A', found {criterion!r}.")
    pm = PoolModel(plan, pool, target.get("detect"))
    everything = list(range(len(pm.units)))
    short = failing(pm.check(everything), target)
    if short:
        raise ValueError(f"even the whole pool ({len(everything)} units, "
                         f"{pm.cost(everything):.0f} min) fails the target: "
                         f"{', '.join(short)}; add placements or styli to the pool, or relax "
                         "the target.")
    steps: list = []

    def add_best(sel):
        rest = [u for u in everything if u not in sel]
        c0, t0 = pm.criterion(sel, criterion), pm.cost(sel)
        gain = [(pm.criterion(sorted([*sel, u]), criterion) - c0)
                / max(pm.cost(sorted([*sel, u])) - t0, 1e-9) for u in rest]
        return sorted([*sel, rest[int(np.argmax(gain))]])

    def local_search(sel, log):
        """Backward elimination (whole placements first, then units) and 1-exchange to a
        cheaper unit, while the target holds."""
        while True:
            moves = [[v for v in sel if pm.units[v][0] != p]
                     for p in dict.fromkeys(pm.units[u][0] for u in sel)]
            moves += [[v for v in sel if v != u] for u in sel]
            moves += [sorted([w for w in sel if w != u] + [v]) for u in sel
                      for v in everything if v not in sel]
            cheaper = sorted((m for m in moves if pm.cost(m) < pm.cost(sel) - 1e-9),
                             key=pm.cost)
            nxt = next((m for m in cheaper if meets(pm.check(m), target)), None)
            if nxt is None:
                return sel
            log.append({"remove": _label(pm, sorted(set(sel) - set(nxt))),
                        "add": _label(pm, sorted(set(nxt) - set(sel))),
                        "time_min": pm.cost(nxt)})
            sel = nxt

    # greedy by criterion gain per minute, then randomised restarts (units in random
    # order until the target is met), each improved by the local search; the cheapest
    # wins, the criterion breaking ties
    starts = []
    sel: list[int] = []
    log: list = []
    while not meets(pm.check(sel), target):
        nxt = add_best(sel)
        log.append({"add": _label(pm, sorted(set(nxt) - set(sel))), "time_min": pm.cost(nxt)})
        sel = nxt
    starts.append(("greedy", sel, log))
    rng = np.random.default_rng(seed + 7919)
    for i, r in enumerate(random_plans(pm, target, restarts, rng)):
        starts.append((f"random start {i + 1}", r, [{"start": _label(pm, r),
                                                      "time_min": pm.cost(r)}]))
    results = []
    for how, s0, log in starts:
        s1 = local_search(s0, log)
        results.append((pm.cost(s1), -pm.criterion(s1, criterion), how, s1, log))
    cost, _, how, sel, steps = min(results, key=lambda r: (r[0], r[1]))
    steps = [{"search": how}, *steps]
    chosen = _as_plan(pm, sel, name)
    ev = evaluate(chosen)
    while not meets(figures(ev, target), target) and len(sel) < len(everything):
        sel = add_best(sel)  # the fast figures were optimistic: the exact check decides
        steps.append({"add": _label(pm, sorted(sel)), "time_min": pm.cost(sel),
                      "why": "the exact evaluation missed the target"})
        chosen = _as_plan(pm, sel, name)
        ev = evaluate(chosen)
    binding = sorted({f for u in sel for f in failing(pm.check([v for v in sel if v != u]),
                                                     target)})
    # an independent comparison: random plans of other draws than the restarts
    rand = random_plans(pm, target, n_random, np.random.default_rng(seed))
    best_rand = min((pm.cost(r) for r in rand), default=None)
    t = pm.cost(sel)
    msg = (f"{len(sel)} unit(s) in {len({pm.units[u][0] for u in sel})} placement(s), "
           f"{t:.0f} min, meet the target ({criterion}-optimal greedy search and "
           f"{restarts} random restarts, each improved by elimination and exchange, over "
           f"{len(everything)} units; best from the {how}). Binding: "
           f"{', '.join(binding) or 'none'}.")
    if best_rand is not None:
        msg += (f" The best of {len(rand)} random plans of the pool that meet it takes "
                f"{best_rand:.0f} min.")
    return DesignResult(chosen, ev, _label(pm, sel), t, criterion, target,
                        figures(ev, target), binding, steps, best_rand, len(rand), msg)

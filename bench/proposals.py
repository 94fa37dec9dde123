"""Benchmark and Monte Carlo check of "measure next" (issue 29, ``cmm_core.plan.proposals``).

Prints, in one run:

1. the median wall time of ``propose`` for the default candidate set, beside the median
   time of one ``diagnose`` of the same data (its peer in the interactive flow), and their
   ratio (``--no-timing`` skips it);
2. for each alias case (a true effect and its rival on a simulated layout of
   ``tests/scenarios.py``, other than the sample data's: a high-order rotation against
   squareness on two plates and a weak one; a probe offset against drift with styli
   measured in blocks, both ways; each placement's own Z scale against ``dzz:4``): over N
   seeds, the share of seeds where the diagnosis names the true effect (a) on the data
   alone, (b) with the top proposal measured (simulated from the true machine, with noise)
   and appended, (c) with a random other candidate of the same machine time appended
   instead (for a repeat, which no other candidate is as short as: a random other plate
   candidate cut to the repeat's machine time, ``random_candidate``: under 10 min, the
   set-up of a new placement or stylus, that is nothing measured; and, on the seeds whose
   top proposal is a repeat, a random repeat of the same readings, ``random_repeat``);
   each with its binomial standard error. "Names" is counted strictly (the verdict is the true token), by function (``rxz:3`` for a true ``rxz:4``: the Occam rule
   names the lower order when the higher does not beat it), and "decided" (named, the
   rival no longer among its aliases). The placement scales are named by the
   outside-catalogue verdict with them as its evidence;
3. the predicted power of the top proposal (mean over seeds of its power with the truth
   as the truth: the expected power over the uncertainty of the size fitted on that
   seed's data, ``proposals.separation._expected_power``) against the Monte Carlo
   separation rate: the share of seeds where the nested F-test "the truth is still needed
   once the rival is in" rejects at the diagnosis's level on the augmented noisy data. The
   issue asks for agreement within ±8 points.

Run: ``.venv/bin/python bench/proposals.py [--seeds N] [--cases WORDS]`` (default 50
seeds; 10-20 s a seed on the shared two-core machine; docs/proposals.md has 30).
"""

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "tests"))

from _timing import median_time  # noqa: E402
from scenarios import perturb, placement_scale, simulated  # noqa: E402

from cmm_core.diagnosis import OUTSIDE, diagnose  # noqa: E402
from cmm_core.model import BY_TOKEN, fit, weighted_residual  # noqa: E402
from cmm_core.plan import (  # noqa: E402
    MEASUREMENT_DEFAULTS,
    PLACEMENT_SCALE,
    append_measurement,
    fit_rivals,
    propose,
    scale_columns,
)

NOISE_UM = 0.5

# name: (layout, simulator keys of the truth, baseline, truth token, rival token)
CASES = {
    "high-order rotation vs squareness, 80 mm plate": (
        "pitch80_3pos", {"kinematic": {"spec": "kinematic21,rxz:4",
                                       "coefficients": {"rxz[4]": 3.0}}},
        "kinematic21,-sxy", "rxz:4", "sxy"),
    "high-order rotation vs squareness, 150 mm plate": (
        "pitch150_5pos", {"kinematic": {"spec": "kinematic21,rxz:4",
                                        "coefficients": {"rxz[4]": 3.0}}},
        "kinematic21,-sxy", "rxz:4", "sxy"),
    # a third of the size: the proposals' power is no longer near 1 (calibration)
    "weak high-order rotation vs squareness, 80 mm plate": (
        "pitch80_3pos", {"kinematic": {"spec": "kinematic21,rxz:4",
                                       "coefficients": {"rxz[4]": 1.0}}},
        "kinematic21,-sxy", "rxz:4", "sxy"),
    # styli measured in blocks (the simulator's default order): each placement's second
    # stylus comes later, so a stylus's offset and the placement's drift look alike
    "probe offset vs drift, styli in blocks, 80 mm plate": (
        "pitch80_3pos", {"effects": {"probe_offset": {"sd_um": 1.0}}},
        "kinematic21", "probe_offset", "drift"),
    # the other way round: each placement drifts (a new placement drifts anew, drawn
    # from the same spread)
    "drift vs probe offset, styli in blocks, 80 mm plate": (
        "pitch80_3pos", {"effects": {"drift": {"sd_um_per_h": 1.0}}},
        "kinematic21", "drift", "probe_offset"),
    # outside the catalogue: each placement reads Z lengths with its own scale (5 ppm
    # spread, balls in random order; tests/scenarios.py placement_scale), which a
    # high-order Z positioning term dzz:4 can stand in for; a new placement has its own
    # scale, drawn from the same spread ("_placement_scale": spread in ppm, axis)
    "per-placement scale vs high-order dzz:4, 150 mm plate": (
        "pitch150_5pos", {"order": "random", "_placement_scale": (5.0, 2)},
        "kinematic21", PLACEMENT_SCALE, "dzz:4"),
}


# effects whose parameters belong to the machine or the styli, not to one placement
# (a new placement has its own drift, unknown): carried into an appended measurement
_CARRIED = {"probe_offset": lambda lab: lab.startswith("probe")}
# effects of each placement, drawn as a spread: drawn anew for the appended placement
_REDRAWN = ("drift",)


def true_machine(sim, cand=None) -> dict:
    """Simulator keys that reproduce the simulation's own machine (every kinematic
    coefficient drawn, by label; the styli's offsets) for a measurement appended to its
    data. A repeat (``cand.repeat``) continues its placements: their own drift, not a
    new one."""
    km = sim.config["kinematic"]
    effects = {}
    for tok, own in _CARRIED.items():
        vals = {k: v for k, v in sim.truth.items() if own(k)}
        if tok in sim.config.get("effects", {}) and vals:
            effects[tok] = BY_TOKEN[tok].injection(vals)
    for tok in _REDRAWN:
        if tok in sim.config.get("effects", {}):
            effects[tok] = sim.config["effects"][tok]
            if cand is not None and cand.repeat:
                effects[tok] = BY_TOKEN[tok].injection(
                    {k: v for k, v in sim.truth.items()
                     if k.partition(".")[0] in cand.repeat and f".{tok}_" in k})
    return {"kinematic": {"spec": km["spec"], "order": km["order"],
                          "coefficients": {k: v for k, v in sim.truth.items()
                                           if "." not in k and not k.startswith("probe")}},
            "effects": effects, "noise_um": NOISE_UM}


def nested_rejects(data, rf, truth, rival) -> bool:
    """The nested F-test of the parameters ``truth`` adds to ``rival`` (both full fits,
    as the diagnosis's ``verdict._nested_p``) rejects at ``truth``'s level; for the
    placement scales, the F-test of their columns added to the rival's fit (linearised
    there, as the diagnosis's placement-scale test)."""
    if truth == PLACEMENT_SCALE:
        small = fit(data, rf.specs[rival], sigma_um=NOISE_UM, max_iter=2000,
                    certificate_test=False)
        r, J = weighted_residual(small.problem, small.state, small.sigma_um, True)[1:]
        J = J.toarray()
        S = scale_columns(small.problem.obs, small.sigma_um, r.size)[0]
        U, sv, _ = np.linalg.svd(J, full_matrices=False)
        Q = U[:, sv > small.rank_rtol * sv.max()]
        Sp = S - Q @ (Q.T @ S)
        Us, ss, _ = np.linalg.svd(Sp / np.linalg.norm(S, axis=0), full_matrices=False)
        Qs = Us[:, ss > 1e-3]
        dk = Qs.shape[1]
        dchi2 = float(np.sum((Qs.T @ r) ** 2))
        nu = max(small.dof - dk, 1)
        p = stats.f.sf((dchi2 / dk) / ((small.chi2 - dchi2) / nu), dk, nu)
        return bool(p < rf.levels[truth])
    small = fit(data, rf.specs[rival], sigma_um=NOISE_UM, max_iter=2000, certificate_test=False)
    big = fit(data, rf.specs[truth].with_token(rival), sigma_um=NOISE_UM, max_iter=2000,
              certificate_test=False)
    dk, dchi2 = big.rank - small.rank, small.chi2 - big.chi2
    if dk <= 0 or dchi2 <= 0:
        return False
    p = stats.f.sf((dchi2 / dk) / (big.chi2 / max(big.dof, 1)), dk, max(big.dof, 1))
    return bool(p < rf.levels[truth])


def random_candidate(data, top, others, rng):
    """A random extra measurement of the top proposal's machine time, and the number of
    its readings that fit in that time (None: all of them).

    Another default candidate of the same time, drawn at random, whole. A repeat at the
    end of placements (2-18 min) shares its time with no placement or stylus candidate
    (28-46 min): the random measurement is then any other plate candidate of at least
    that time, drawn at random, cut to the same machine time (its first readings, after
    its set-up: a new placement's 10 min, none for a repeat), as a metrologist who spends
    the same minutes on the machine without the proposer would."""
    if not top.repeat:
        same = [p.candidate for p in others if p.candidate.time_min == top.time_min]
        return same[rng.integers(len(same))], None
    pool = [p.candidate for p in others
            if not p.candidate.instrument and p.candidate.time_min >= top.time_min]
    cand = pool[rng.integers(len(pool))]
    setup = 0.0 if cand.repeat else MEASUREMENT_DEFAULTS["minutes_per_placement"]
    keep = int(np.floor((top.time_min - setup) / MEASUREMENT_DEFAULTS["minutes_per_ball"]
                        + 1e-9))
    return cand, max(keep, 0)


def random_repeat(data, top, rng):
    """For a repeat top: a repeat of the same readings at the end of the same placements,
    with a stylus of each drawn at random among those it measured with, on balls drawn at
    random: does the proposer's choice among repeats matter, or only that it is one?"""
    each = {}
    m = data.meas
    for p, r in top.repeat.items():
        at = m["position"] == p
        styli = list(dict.fromkeys(m.loc[at, "probe"].astype(str)))
        q = styli[rng.integers(len(styli))]
        balls = sorted(set(m.loc[at & (m["probe"].astype(str) == q), "ball"].astype(int)))
        pick = rng.choice(balls, size=len(r["balls"]), replace=False)
        each[p] = {"probe": q, "balls": [int(b) for b in pick],
                   "time_min": list(r["time_min"])}
    return replace(top, name=f"random_{top.name}", description="random repeat",
                   repeat=each)


def first_readings(aug, n_before: int, keep: int | None):
    """``aug`` with only the first ``keep`` of the readings appended after row
    ``n_before`` (in time order); ``keep`` None: unchanged."""
    if keep is None:
        return aug
    new = aug.meas.iloc[n_before:].sort_values("time_min", kind="stable")
    rows = np.r_[np.arange(n_before), new.index[:keep].to_numpy()]
    return replace(aug, meas=aug.meas.loc[np.sort(rows)].reset_index(drop=True))


def _named(d, truth, rival):
    """(strict, by function, decided): the verdict is the truth; is of its function; is
    the truth and the rival is no longer its alias (``Outcome.separated``). The placement
    scales are named by the outside-catalogue verdict with them as its evidence."""
    if truth == PLACEMENT_SCALE:
        hit = d.verdict == OUTSIDE and "each placement's own scale" in d.message
        return hit, hit, hit
    al = list(d.candidates[0].aliases) if d.candidates else []
    return (d.verdict == truth,
            (d.verdict or "").partition(":")[0] == truth.partition(":")[0],
            d.verdict == truth and rival not in al)


def run_case(name, seeds):
    layout, extra, base, truth, rival = CASES[name]
    scale = extra.get("_placement_scale")
    sim_keys = {k: v for k, v in extra.items() if not k.startswith("_")}
    rows = []
    for seed in range(seeds):
        sim = simulated(layout, 1000 + seed, noise_um=NOISE_UM, **sim_keys)
        data = sim.dataset
        if scale:
            data = placement_scale(data, np.random.default_rng(2000 + seed), *scale)
        before = _named(diagnose(data, base), truth, rival)
        # a placement-scale rival comes second (plan.fit_rivals)
        pr = propose(data, (rival, truth) if truth == PLACEMENT_SCALE else (truth, rival),
                     baseline=base)
        top = pr.ranked[0]

        def appended(cand, data=data, sim=sim, seed=seed):
            aug = append_measurement(data, cand, config=true_machine(sim, cand),
                                     seed=5000 + seed)
            if scale and cand.repeat:  # the repeated placements' own scales, as drawn
                drawn = np.random.default_rng(2000 + seed)
                own = {p: drawn.normal(0, scale[0]) * 1e-6 for p in data.positions}
                n0 = len(data.meas)
                xyz = aug.meas[["mx_mm", "my_mm", "mz_mm"]].to_numpy()
                delta = np.zeros_like(xyz)
                for p in cand.repeat:
                    at = (aug.meas["position"] == p).to_numpy()
                    mean = xyz[:n0][at[:n0], scale[1]].mean()
                    new = at.copy()
                    new[:n0] = False
                    delta[new, scale[1]] = own[p] * (xyz[new, scale[1]] - mean)
                aug = perturb(aug, delta)
            elif scale:  # the new placement's own scale, drawn from the same spread
                new = aug.meas["position"].isin(list(cand.positions)).to_numpy()
                xyz = aug.meas[["mx_mm", "my_mm", "mz_mm"]].to_numpy()
                s = np.random.default_rng(7000 + seed).normal(0, scale[0]) * 1e-6
                delta = np.zeros_like(xyz)
                delta[new, scale[1]] = s * (xyz[new, scale[1]] - xyz[new, scale[1]].mean())
                aug = perturb(aug, delta)
            return aug

        aug = appended(top.candidate)
        after = _named(diagnose(aug, base), truth, rival)
        rng = np.random.default_rng(seed)
        other, keep = random_candidate(data, top.candidate, pr.ranked[1:], rng)
        aug_r = first_readings(appended(other), len(data.meas), keep)
        random_ = _named(diagnose(aug_r, base), truth, rival)
        rep = (_named(diagnose(appended(random_repeat(data, top.candidate, rng)), base),
                      truth, rival) if top.candidate.repeat else None)
        rf = fit_rivals(data, pr.rivals, baseline=base)
        sep = nested_rejects(aug, rf, truth, rival)
        rows.append((before, after, random_, top.power[truth], sep, top.candidate.name, rep))
        print(f"  seed {seed}: top {top.candidate.name} (power {top.power[truth]:.2f}), "
              f"named before/after/random: {before[0]}/{after[0]}/{random_[0]}, decided "
              f"{before[2]}/{after[2]}/{random_[2]} "
              f"({other.name}{'' if keep is None else f', first {keep} readings'})"
              + ("" if rep is None else f", random repeat named/decided {rep[0]}/{rep[2]}")
              + f", separated {sep}", flush=True)
    return rows


def _share(x):
    x = np.asarray(x, float)
    p = float(x.mean())
    return f"{100 * p:5.1f} % ± {100 * np.sqrt(p * (1 - p) / len(x)):.1f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50, help="seeds per alias case")
    ap.add_argument("--repeats", type=int, default=5, help="timing repeats (medians)")
    ap.add_argument("--cases", default="",
                    help="run only the cases whose name contains one of these comma-"
                         "separated words (default: all)")
    ap.add_argument("--no-timing", action="store_true", help="skip the timing")
    args = ap.parse_args()
    words = [w.strip() for w in args.cases.split(",") if w.strip()]
    names = [n for n in CASES if not words or any(w in n for w in words)]

    layout, extra, base, truth, rival = CASES[next(iter(CASES))]
    data = simulated(layout, 7, noise_um=NOISE_UM, **extra).dataset
    if not args.no_timing:
        t_prop, pr = median_time(lambda: propose(data, (truth, rival), baseline=base),
                                 args.repeats)
        t_diag, _ = median_time(lambda: diagnose(data, base), args.repeats)
        print(f"propose, {len(pr.ranked)} candidates ({layout}): {t_prop:.2f} s; one "
              f"diagnose of the same data {t_diag:.2f} s; ratio {t_prop / t_diag:.2f}")

    for name in names:
        print(f"\n{name} ({args.seeds} seeds; truth {CASES[name][3]}, rival {CASES[name][4]})")
        rows = run_case(name, args.seeds)
        for label, i in (("data alone", 0), ("top proposal appended", 1),
                         ("random candidate, same time", 2)):
            print(f"  {label:30s} names the truth: strict {_share([r[i][0] for r in rows])},"
                  f" by function {_share([r[i][1] for r in rows])}, decided "
                  f"{_share([r[i][2] for r in rows])}")
        reps = [r for r in rows if r[6] is not None]
        if reps:  # on the same seeds: those whose top proposal is a repeat
            print(f"  on the {len(reps)} seeds whose top proposal is a repeat: top proposal "
                  f"names {_share([r[1][0] for r in reps])}, decides "
                  f"{_share([r[1][2] for r in reps])}; a random repeat of the same "
                  f"readings names {_share([r[6][0] for r in reps])}, decides "
                  f"{_share([r[6][2] for r in reps])}")
        pred = float(np.mean([r[3] for r in rows]))
        print(f"  predicted power {100 * pred:.1f} %, Monte Carlo separation "
              f"{_share([r[4] for r in rows])}, difference "
              f"{100 * (np.mean([r[4] for r in rows]) - pred):+.1f} points")
        tops = {}
        for r in rows:
            tops[r[5]] = tops.get(r[5], 0) + 1
        print(f"  top proposals: {tops}")


if __name__ == "__main__":
    main()

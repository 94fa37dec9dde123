"""Monte Carlo check of "measure next" on four machine layouts (issue 40, item 5).

``bench/proposals.py`` checks the proposals on moving bridges only (the layouts of
``tests/scenarios.py``). Here the same kind of alias pair is simulated on a moving bridge,
a fixed bridge (the table moves along X), a gantry and a horizontal arm, several seeds
each, and for each case and seed:

1. data are simulated with a hidden effect whose rival is its alias (``PAIRS``, the kinds
   of ``bench/proposals.py`` and ``tests/test_next_reach.py``): a high-order yaw of the X
   carriage (``rxz:4``) hidden from a baseline without squareness, rivals ``rxz:4`` and
   ``sxy``, at a strong size (3 µrad) and a weak one (1 µrad: the powers spread below 1,
   which is what calibrates the prediction); random stylus offsets (1 µm) against drift
   with the styli measured in blocks, and the other way round (drift of 1 µm/h spread, a
   new placement drifting anew);
2. ``propose`` ranks the default candidates; the top proposal's predicted power is its
   expected power with the truth as the truth (``Proposal.power[truth]``, as
   ``bench/proposals.py``);
3. the top proposal is measured on the true machine (every coefficient drawn, with
   noise; ``append_measurement`` with ``proposals.true_machine``) and appended, and the
   nested F-test "the truth is still needed once the rival is in" is run on the
   augmented data at the diagnosis's level (``proposals.nested_rejects``): separated or
   not;
4. every ranked proposal is checked against the machine: the scale reading (tip minus
   stylus offset) of every ball of the plate with every stylus of every new placement,
   computed here from the setup's geometry (independently of the core), and of every
   reading a repeat measures again, against the strokes ``[0, range_mm]`` and against
   the strokes widened to the readings the data already made (the core's rule,
   ``proposals.reached_range``: what the machine measured, it can measure again); the
   core's own ``out_of_reach`` must say "" too. A proposal beyond the widened strokes is
   out of the machine's reach (must be none); one outside the strokes but within what
   the data measured is counted apart.

Printed per layout and pair: the share of seeds whose top proposal has a predicted power
≥ 80 % and, among those, the observed separation rate (target ≥ 90 %); the mean predicted
power against the separation rate over all seeds (target: within ±10 points); the count
of proposals out of the reach (must be 0) and of those outside the strokes only; the
prediction against the separation apart for the seeds whose top proposal's
noise-corrected Δχ² is 0 (the current data fit the truth's size within its noise); binomial standard errors throughout. Then the
same pooled over layouts.

Run: ``.venv/bin/python bench/next_layouts.py [--seeds N] [--layouts WORDS]
[--pairs WORDS] [--instruments]`` (``--instruments``: the instrument candidates searched
too, a top instrument measured on the true machine with its own noise) (default 5 seeds per layout and pair, seeds 3000 on; about 0.6 s a seed
on the shared two-core machine).
"""

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "tests"))

from proposals import NOISE_UM, nested_rejects, true_machine  # noqa: E402
from scenarios import (  # noqa: E402
    arm_config,
    gantry_config,
    layout_on,
    proposal_scale_readings,
)

from cmm_core.model import select, simulate  # noqa: E402
from cmm_core.plan import append_measurement, fit_rivals, propose  # noqa: E402
from cmm_core.plan.proposals import (  # noqa: E402
    instrument_candidates,
    instrument_of,
    measurement_candidates,
    out_of_reach,
    reached_range,
)

BASE = "kinematic21,-sxy"
POWER_BAR = 0.8
"""Predicted power from which a proposal is expected to separate (the issue's 80 %)."""



def _hidden(size_urad: float) -> dict:
    """Simulator keys: ``rxz:4`` of ``size_urad`` on top of the drawn kinematic21."""
    return {"kinematic": {"spec": "kinematic21,rxz:4",
                          "coefficients": {"rxz[4]": float(size_urad)}}}


PAIRS = {
    "rxz:4 3 urad / sxy": (_hidden(3.0), BASE, "rxz:4", "sxy"),
    # a third of the size: the powers spread below 1 (what calibrates the prediction)
    "rxz:4 1 urad / sxy": (_hidden(1.0), BASE, "rxz:4", "sxy"),
    # styli measured in blocks (the simulator's default order): a placement's second
    # stylus comes later, so its offset and the placement's drift look alike
    "probe offset / drift": ({"effects": {"probe_offset": {"sd_um": 1.0}}}, "kinematic21",
                             "probe_offset", "drift"),
    "drift / probe offset": ({"effects": {"drift": {"sd_um_per_h": 1.0}}}, "kinematic21",
                             "drift", "probe_offset"),
}
"""Pair -> (simulator keys of the truth, baseline, truth, rival), as ``bench/proposals.py``'s
cases; the layout's own keys are merged under them."""


LAYOUTS = {
    "moving bridge": lambda s, a: layout_on("pitch80_3pos", "moving_bridge_fxyz", s,
                                            noise_um=NOISE_UM, **a),
    "fixed bridge": lambda s, a: layout_on("pitch150_5pos", "fixed_bridge_xfyz", s,
                                           noise_um=NOISE_UM, **a),
    "gantry": lambda s, a: gantry_config(s, NOISE_UM, **a),
    "horizontal arm": lambda s, a: arm_config(s, NOISE_UM, **a),
}
"""Layout -> simulator configuration of (seed, the pair's simulator keys)."""


def outside(data, cand) -> tuple[str, str]:
    """Why the candidate leaves the strokes ``[0, range_mm]`` (first), and why it leaves
    the strokes widened to the readings the data already made (second: the core's rule,
    ``reached_range``; or the core's own ``out_of_reach`` reason), each "" when it does
    not."""
    if cand.instrument:
        return "", ""  # not searched here (``propose``'s default candidates)
    rng = np.asarray(data.setup.range_mm, float)
    lo, hi = reached_range(data)
    x = proposal_scale_readings(data, cand)
    why = []
    for low, high in ((np.zeros(3), rng), (lo, hi)):
        bad = (x < low - 1e-9) | (x > high + 1e-9)
        if bad.any():
            i, a = np.argwhere(bad)[0]
            why.append(f"scale reading {x[i, a]:.1f} mm of axis {'xyz'[a]}")
        else:
            why.append("")
    return why[0], why[1] or out_of_reach(data, cand)


def measured(sim, cand, seed: int):
    """The data with the candidate measured on the true machine: a plate placement,
    stylus or repeat appended (``append_measurement``), an instrument run simulated on the
    simulation's own machine with the instrument's noise and fitted jointly (as
    ``simulate_outcomes`` does on each rival's machine)."""
    if cand.instrument:
        obs = select(sim.dataset)
        return replace(obs, instruments=(*obs.instruments,
                                         instrument_of(cand, sim, seed=seed)))
    return append_measurement(sim.dataset, cand, config=true_machine(sim, cand), seed=seed)


def run(layout: str, pair: str, seeds: int, instruments: bool = False) -> list:
    """One row per seed: (predicted power, separated, proposals beyond what the machine
    reaches, top name, proposals checked, seconds, proposals outside the strokes, the top
    proposal's noise-corrected Δχ² with the truth true). ``instruments``: the
    instrument candidates are searched too (``next --instruments``)."""
    extra, base, truth, rival = PAIRS[pair]
    rows = []
    for seed in range(seeds):
        t0 = time.perf_counter()
        sim = simulate(LAYOUTS[layout](3000 + seed, extra), name=layout)
        data = sim.dataset
        cands = measurement_candidates(data) + (instrument_candidates(data) if instruments
                                                else [])
        pr = propose(data, (truth, rival), baseline=base, cands=cands)
        top = pr.ranked[0]
        why = {p.candidate.name: outside(data, p.candidate) for p in pr.ranked}
        strokes = [(n, w[0]) for n, w in why.items() if w[0]]
        far = [(n, w[1]) for n, w in why.items() if w[1]]
        aug = measured(sim, top.candidate, 5000 + seed)
        rf = fit_rivals(data, pr.rivals, baseline=base)
        sep = nested_rejects(aug, rf, truth, rival)
        dt = time.perf_counter() - t0
        rows.append((top.power[truth], sep, len(far), top.candidate.name, len(pr.ranked), dt,
                     len(strokes), top.delta_chi2[truth]))
        print(f"  seed {seed}: top {top.candidate.name} (predicted {top.power[truth]:.2f}, "
              f"Δχ² {top.delta_chi2[truth]:.1f}), "
              f"separated {sep}, {len(pr.ranked)} proposals, {len(pr.infeasible)} skipped, "
              f"beyond the reach {far or 0}, outside the strokes {strokes or 0}, {dt:.1f} s",
              flush=True)
    return rows


def _share(x) -> str:
    """Share of True in ``x`` in percent with its binomial standard error."""
    x = np.asarray(x, float)
    if not x.size:
        return "  n/a"
    p = float(x.mean())
    return f"{100 * p:5.1f} % ± {100 * np.sqrt(p * (1 - p) / x.size):.1f}"


def summary(label: str, rows: list) -> str:
    """The figures of one set of rows in one line."""
    pred = np.array([r[0] for r in rows])
    sep = np.array([r[1] for r in rows], bool)
    hi = pred >= POWER_BAR
    diff = 100 * (sep.mean() - pred.mean())
    se = 100 * np.sqrt(sep.mean() * (1 - sep.mean()) / sep.size)
    tops: dict = {}
    for r in rows:
        tops[r[3]] = tops.get(r[3], 0) + 1
    return (f"{label}: {len(rows)} seeds; predicted ≥ {100 * POWER_BAR:.0f} %: "
            f"{_share(hi)} ({int(hi.sum())}), separated among them {_share(sep[hi])} "
            f"(predicted {100 * pred[hi].mean() if hi.any() else float('nan'):.1f} %); "
            f"predicted {100 * pred.mean():.1f} % vs separated {_share(sep)} "
            f"(observed minus predicted {diff:+.1f} points, ± {se:.1f}); of "
            f"{sum(r[4] for r in rows)} proposals {sum(r[2] for r in rows)} beyond the "
            f"reach, {sum(r[6] for r in rows)} outside the strokes; "
            f"tops {tops}; {np.mean([r[5] for r in rows]):.1f} s a seed")


def by_size(label: str, rows: list) -> str:
    """Predicted against separated, apart for the seeds whose top proposal's
    noise-corrected Δχ² is 0 (the current data fit the truth's size within its noise: the
    expected power then rests on the size's uncertainty alone) and the others."""
    out = []
    for name, keep in (("Δχ² = 0", lambda r: r[7] <= 0.0), ("Δχ² > 0", lambda r: r[7] > 0.0)):
        part = [r for r in rows if keep(r)]
        if part:
            out.append(f"{name}: {len(part)} seeds, predicted "
                       f"{100 * np.mean([r[0] for r in part]):.1f} % vs separated "
                       f"{_share([r[1] for r in part])}")
    return f"{label}: " + "; ".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds per layout and pair")
    ap.add_argument("--layouts", default="",
                    help="only the layouts whose name contains one of these comma-separated "
                         "words (default: all four)")
    ap.add_argument("--instruments", action="store_true",
                    help="search the instrument candidates too (laser runs, step gauges, "
                         "ball bars: next --instruments); a top instrument is measured on "
                         "the true machine with its own noise")
    ap.add_argument("--pairs", default="",
                    help="only the pairs whose name contains one of these comma-separated "
                         "words (default: all)")
    args = ap.parse_args()

    def chosen(names, text):
        words = [w.strip() for w in text.split(",") if w.strip()]
        return [n for n in names if not words or any(w in n for w in words)]

    by_layout: dict = {}
    lines = []
    for pair in chosen(PAIRS, args.pairs):
        for name in chosen(LAYOUTS, args.layouts):
            print(f"\n{name}, {pair} ({args.seeds} seeds)", flush=True)
            rows = run(name, pair, args.seeds, args.instruments)
            by_layout.setdefault(name, []).extend(rows)
            lines += [summary(f"{name}, {pair}", rows), by_size(f"  {name}, {pair}", rows)]
            print(lines[-2], lines[-1], sep="\n", flush=True)
    print("\nSummary")
    for ln in lines:
        print(ln)
    for name, rows in by_layout.items():
        print(summary(f"{name}, all pairs", rows))
        print(by_size(f"  {name}, all pairs", rows))
    every = [r for rows in by_layout.values() for r in rows]
    print(summary("all layouts and pairs", every))
    print(by_size("  all layouts and pairs", every))


if __name__ == "__main__":
    main()

"""Monte Carlo of the non-rigid blocks (``python bench/nonrigid.py [--seeds N] [--twist-seeds M]
[--rigid-seeds K] [--arm-seeds A] [--arm-limit-seeds B]``), on scenario layouts (not the
thesis). Items 1-4 are ``bridge_twist`` on bridges and gantries:

1. coverage of bridge_twist's fitted parameters (z = (v - truth)/u), the roll about the
   machine's z = 0 and about a line 900 mm up (a gantry's rails);
2. the clean-data false-alarm rate of naming bridge_twist;
3. twists whose shape is not exactly the block's (``scenarios.bridge_roll``, evaluated at
   the tips, not the carriage: g(s) = s², s³, sin(πs/2) or s, and here also (1 − s²)², a
   rail between pillars, and tanh(3s), a stiffness step, which no cubic holds; about
   z = 0 or 900 mm up, 15 and 30 µrad at the corners) on three scenario layouts and four
   bridge and gantry layouts: the loop's path (diagnose, add the verdict, again), counting
   how often a rigid function's higher order (``rxx:3`` ...) or the plate's sag is named
   before the twist;
4. the converse: real rigid higher orders of the bridge's and the carriage's rotations
   (``rxx:3``, ``rzy:3`` ...) at their detection limit on the same layouts, how often the
   diagnosis names the twist first instead of the rigid term (the cost of the block's
   cubic shape family), with the rate at which the rigid term is named.

Items 5-8 are ``column_bend`` on the horizontal-arm layouts (``horizontal_arm_fxzy``,
``horizontal_arm_fyzx``), each with the 100, 150 and 80 mm plate scenarios:

5. coverage of column_bend's three fitted parameters (z = (v - truth)/u; expect RMS ~1
   and ~95 % within ±2);
6. the clean-data false-alarm rate of naming column_bend (and any verdict, against the
   diagnosis's family-wise level);
7. detection: each of the three shapes alone injected at its detection limit (the
   ``detectable`` of the column_bend candidate of a clean diagnosis of the same layout:
   the size found with 80 % probability by a one-parameter test) and at twice it, the
   share of seeds where the diagnosis names column_bend (with its binomial standard
   error), beside the power the block's three-parameter test has at that size alone
   (below 80 % for a shape uncorrelated with the others, above for correlated ones);
8. the converse: real rigid third orders of the arm's and the vertical carriage's
   functions (the rigid neighbours of the block's shapes: the carriage's rotation about
   the column's travel axis on the arm's lever, the arm's straightness in z and its
   scale ...) at their detection limit, how often column_bend is named first instead.
"""
import argparse
import sys
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]

import scenarios as sc  # noqa: E402
from honesty import loop  # noqa: E402

from cmm_core.diagnosis import diagnose  # noqa: E402
from cmm_core.model import fit  # noqa: E402
from cmm_core.model.blocks.bridge_twist import BRIDGES  # noqa: E402
from cmm_core.model.blocks.column_bend import ARMS  # noqa: E402
from cmm_core.model.blocks.column_bend import SHAPES as BEND_SHAPES  # noqa: E402

LAYOUTS = (("pitch150_5pos", "gantry_fxyz"), ("pitch100_4pos", "moving_bridge_fxyz"),
           ("pitch100_4pos", "gantry_fyxz"), ("pitch80_3pos", "moving_bridge_fyxz"))
SHAPES = (("s2", 0.0), ("s3", 0.0), ("sin", 900.0), ("s2", 900.0), ("lin", 900.0),
          ("mid", 0.0), ("tanh", 900.0))


def coverage(seeds: int) -> None:
    z = []
    for name in ("pitch100_4pos", "pitch150_5pos"):
        for layout in ("gantry_fxyz", "moving_bridge_fyxz"):
            for seed in range(seeds):
                h = 900.0 if seed % 2 else 0.0
                sim = sc.layout_data(name, layout, 100 + seed, effects={"bridge_twist": {
                    "lin_urad": 5.0, "quad_urad": 3.0, "cub_urad": -3.0,
                    "axis_height_mm": h}})
                r = fit(sim.dataset, "kinematic21,bridge_twist")
                lab, v, u = r.block("bridge_twist")
                z += list((v - np.array([sim.truth[k] for k in lab])) / u)
    za = np.array(z)
    print(f"1. bridge_twist z: n={za.size} rms={np.sqrt(np.mean(za**2)):.3f} "
          f"|z|<2: {np.mean(np.abs(za) < 2):.3f}", flush=True)


def clean(seeds: int) -> None:
    named = n = 0
    for name in ("pitch100_4pos", "pitch150_5pos"):
        for layout in ("gantry_fxyz", "moving_bridge_fyxz"):
            for seed in range(seeds):
                d = diagnose(sc.layout_data(name, layout, 500 + seed).dataset, "kinematic21")
                n += 1
                named += d.verdict == "bridge_twist"
    print(f"2. clean data: bridge_twist named {named} of {n}", flush=True)


def other_shapes(seeds: int, at_reading: bool = False) -> None:
    rigid = sag = twist = total = 0
    for name, layout in LAYOUTS:
        rng = sc.LAYOUTS[name]["range_mm"]
        for shape, h in SHAPES:
            for amp in (15.0, 30.0):
                for seed in range(seeds):
                    sim = sc.layout_data(name, layout, 700 + seed)
                    data = sc.bridge_roll(sim.dataset, layout, rng, amp, shape, h, at_reading)
                    path, chi2_dof, last = loop(data, "kinematic21", max_steps=3)
                    first = path[0] if path else last
                    before = path[:path.index("bridge_twist")] if "bridge_twist" in path \
                        else path
                    bad = any(":" in t for t in before)
                    rigid += bad
                    sag += "plate_sag" in before
                    twist += "bridge_twist" in path
                    total += 1
                    print(f"   {layout:19s} {name:14s} g={shape:4s} h={h:4.0f} {amp:4.0f} µrad "
                          f"seed {seed}: {' -> '.join(path) or '-':36s} ends {last} "
                          f"χ²/dof {chi2_dof:.2f} (first {first}){' RIGID' if bad else ''}",
                          flush=True)
    print(f"3. twists of other shapes (g at the {'readings' if at_reading else 'tips'}): "
          f"bridge_twist named {twist}/{total}; a rigid "
          f"function's higher order named before it {rigid}/{total}; plate sag before it "
          f"{sag}/{total}", flush=True)


def _rigid_tokens(layout):
    """Third orders of the rotations of the bridge's travel axis and the carriage's axis
    (the rigid terms a twist was named as, and their neighbours)."""
    a, b = BRIDGES[layout][1], BRIDGES[layout][2]
    return [f"r{c}{a}:3" for c in "xyz"] + [f"r{c}{b}:3" for c in "xyz"] + ["dyz:3"]


def _third_orders_at_limit(name: str, layout: str, tokens: list[str]):
    """``(token, function, label, size)`` of each third order among ``tokens`` that a
    clean diagnosis of the layout (seed 999) states a finite detection limit for, at that
    limit; the others are said in a line and skipped."""
    d0 = diagnose(sc.layout_data(name, layout, 999).dataset, "kinematic21")
    lim = {c.effect: c.detectable for c in d0.candidates}
    for tok in tokens:
        fn = tok.partition(":")[0]
        lab = f"{fn}[3]"
        if tok not in lim or lab not in lim[tok] or not np.isfinite(lim[tok][lab][1]):
            print(f"   {layout:19s} {name:14s} {tok}: no limit (not a candidate or "
                  "undetermined), skipped", flush=True)
            continue
        yield tok, fn, lab, lim[tok][lab][1]


def rigid_at_limit(seeds: int) -> None:
    """Real rigid third orders at their detection limit (read from a clean diagnosis of the
    same layout): named first as themselves (or their next order), as the twist, else."""
    named = twist = total = 0
    for name, layout in LAYOUTS:
        for tok, fn, lab, size in _third_orders_at_limit(name, layout, _rigid_tokens(layout)):
            n_tok = n_tw = 0
            for seed in range(seeds):
                sim = sc.layout_data(name, layout, 3000 + seed, kinematic={
                    "spec": f"kinematic21,{tok}", "coefficients": {lab: size}})
                v = diagnose(sim.dataset, "kinematic21").verdict
                n_tok += v is not None and v.partition(":")[0] == fn
                n_tw += v == "bridge_twist"
            named, twist, total = named + n_tok, twist + n_tw, total + seeds
            print(f"   {layout:19s} {name:14s} {tok} at its limit {size:.3g}: named "
                  f"{n_tok}/{seeds}, bridge_twist first {n_tw}/{seeds}", flush=True)
    print(f"4. rigid third orders at their detection limit: named {named}/{total} "
          f"({100 * named / max(total, 1):.1f} %), bridge_twist named first instead "
          f"{twist}/{total} ({100 * twist / max(total, 1):.2f} %)", flush=True)

ARM_CASES = tuple((name, layout) for layout in ARMS
                  for name in ("pitch100_4pos", "pitch150_5pos", "pitch80_3pos"))
"""Every horizontal-arm layout with three plate scenarios."""
CASE_STRIDE = 10000
"""Items 5-8 draw case i's seeds from ``base + seed + CASE_STRIDE·i``: the two arm
layouts (and the plates) with one seed would share the noise draw, and a false alarm of a
candidate both layouts have (``backlash``, ``dzz:3``) would be counted twice."""


def _seed(base: int, case: tuple, seed: int) -> int:
    return base + seed + CASE_STRIDE * ARM_CASES.index(case)
BEND = {"drop_um": 4.0, "shear_um": -3.0, "bend_um": 2.5}
"""Item 5's bending (µm at the strokes' corners; tests/test_column_bend.py's)."""


def _rate(k: int, n: int) -> str:
    """``k/n (p ± se %)``: a share with its binomial standard error."""
    p = k / max(n, 1)
    return f"{k}/{n} ({100 * p:.1f} ± {100 * np.sqrt(p * (1 - p) / max(n, 1)):.1f} %)"


def _bend_limits(name: str, layout: str) -> dict:
    """``{label: (size, power)}`` of column_bend's parameters: ``size`` the candidate's
    ``detectable`` in a clean diagnosis of the layout (seed 999, as item 4 reads the rigid
    limits), ``power`` what the candidate's own test (χ² with its ``n_params`` degrees of
    freedom at its level) finds at that size of this one parameter alone: noncentrality
    ``(size/u_j)² · u_j² (Σ⁻¹)_jj`` (Σ the block's covariance in the augmented fit, u_j²
    its diagonal: a parameter correlated with the others is seen better alone than its
    u_j says); 80 % only for an uncorrelated one-parameter test."""
    data = sc.layout_data(name, layout, 999).dataset
    d0 = diagnose(data, "kinematic21")
    c = next((c for c in d0.candidates if c.effect == "column_bend"), None)
    if c is None:
        return {}
    r = fit(data, "kinematic21,column_bend")
    sl = r.problem.layout.blocks["column_bend"]
    cov = r.covariance[sl, sl]
    gain = np.diag(cov) * np.diag(np.linalg.inv(cov))  # 1/(1 - R_j²) >= 1
    crit = stats.chi2.isf(c.level, c.n_params)
    return {lab: (size, float(stats.ncx2.sf(crit, c.n_params, (size / u) ** 2 * g)))
            for g, u, (lab, (_, size)) in zip(gain, np.sqrt(np.diag(cov)),
                                               c.detectable.items(), strict=True)
            if np.isfinite(size)}


def arm_coverage(seeds: int) -> None:
    z = []
    for name, layout in ARM_CASES:
        for seed in range(seeds):
            sim = sc.layout_data(name, layout, _seed(1100, (name, layout), seed),
                                 effects={"column_bend": BEND})
            lab, v, u = fit(sim.dataset, "kinematic21,column_bend").block("column_bend")
            z += list((v - np.array([sim.truth[k] for k in lab])) / u)
    za = np.array(z)
    print(f"5. column_bend z (seeds 1100-{1099 + seeds} + {CASE_STRIDE}·case, "
          f"{len(ARM_CASES)} arm cases, "
          f"{len(BEND_SHAPES)} per fit): n={za.size} rms={np.sqrt(np.mean(za**2)):.3f} "
          f"|z|<2: {np.mean(np.abs(za) < 2):.3f}", flush=True)


def arm_clean(seeds: int) -> None:
    named = n = 0
    other: dict = {}
    for name, layout in ARM_CASES:
        for seed in range(seeds):
            sd = _seed(1500, (name, layout), seed)
            v = diagnose(sc.layout_data(name, layout, sd).dataset, "kinematic21").verdict
            n += 1
            named += v == "column_bend"
            if v is not None:
                print(f"   {layout:19s} {name:14s} seed {sd}: {v}", flush=True)
            if v is not None and v != "column_bend":
                other[v] = other.get(v, 0) + 1
    alarms = named + sum(other.values())
    print(f"6. clean arm data (seeds 1500-{1499 + seeds} + {CASE_STRIDE}·case): column_bend "
          f"named {_rate(named, n)}; "
          f"any verdict {_rate(alarms, n)} {other or ''}", flush=True)


def arm_detection(seeds: int) -> None:
    """Each shape alone at its limit and twice it: the share of seeds naming column_bend
    (verdict), per shape and in all, against the power its test predicts (``_bend_limits``)
    and what else is named."""
    limits = {case: _bend_limits(*case) for case in ARM_CASES}
    for scale in (1.0, 2.0):
        hit = total = 0
        pred = 0.0
        by_shape: dict = {}
        other: dict = {}
        for (name, layout), lim in limits.items():
            for lab, (size, power) in lim.items():
                key = f"{lab.partition('.')[2]}_um"
                n_hit = 0
                for seed in range(seeds):
                    sim = sc.layout_data(name, layout, _seed(2000, (name, layout), seed),
                                         effects={"column_bend": {key: scale * size}})
                    v = diagnose(sim.dataset, "kinematic21").verdict
                    n_hit += v == "column_bend"
                    if v != "column_bend":
                        other[v] = other.get(v, 0) + 1
                hit, total = hit + n_hit, total + seeds
                h0, t0, p0 = by_shape.get(lab, (0, 0, 0.0))
                by_shape[lab] = (h0 + n_hit, t0 + seeds, p0 + seeds * power)
                pred += seeds * power
                print(f"   {layout:19s} {name:14s} {lab:18s} {scale:g}x limit "
                      f"{scale * size:.3g} µm: named {n_hit}/{seeds}"
                      + (f" (its test at 1x: {100 * power:.0f} %)" if scale == 1 else ""),
                      flush=True)
        for lab, (h0, t0, p0) in by_shape.items():
            print(f"   {lab:18s} at {scale:g}x: named {_rate(h0, t0)}"
                  + (f", predicted {100 * p0 / t0:.0f} %" if scale == 1 else ""), flush=True)
        print(f"7. column_bend at {scale:g}x its limit (seeds 2000-{1999 + seeds} + "
              f"{CASE_STRIDE}·case): named "
              f"{_rate(hit, total)}"
              + (f" (its 3-parameter test predicts {100 * pred / total:.0f} %)"
                 if scale == 1 else "") + f"; otherwise {other}", flush=True)


def _arm_tokens(layout: str) -> list[str]:
    """Third orders of the rigid neighbours of column_bend's shapes (module docstring of
    ``blocks.column_bend``): the rotations of the arm (axis a) and of the vertical
    carriage on the column (z; ``rz`` about the column's travel axis c acts on the arm's
    lever: the vertical ``f(h)·u``), the arm's scale and straightness in z, and the
    carriage's straightness along the arm."""
    a = ARMS[layout][3]
    return ([f"r{a}{k}:3" for k in "xyz"] + [f"rz{k}:3" for k in "xyz"]
            + [f"d{a}{a}:3", f"d{a}z:3", f"dz{a}:3"])


def arm_rigid(seeds: int) -> None:
    """Real rigid third orders at their detection limit on the arm layouts: how often the
    term's own test is significant (the 80 % of its limit), the verdict names it (or its
    next order), names another rigid term the diagnosis lists as its alias (it says the
    two cannot be told apart on this design), column_bend, or else."""
    named = alias = sig = bend = total = 0
    other: dict = {}
    for name, layout in ARM_CASES:
        for tok, fn, lab, size in _third_orders_at_limit(name, layout, _arm_tokens(layout)):
            n_tok = n_alias = n_sig = n_bend = 0
            for seed in range(seeds):
                sim = sc.layout_data(name, layout, _seed(4000, (name, layout), seed),
                                     kinematic={"spec": f"kinematic21,{tok}",
                                                "coefficients": {lab: size}})
                d = diagnose(sim.dataset, "kinematic21")
                v = d.verdict
                own = next((c for c in d.candidates if c.effect == tok), None)
                n_sig += own is not None and own.significant
                if v is not None and v.partition(":")[0] == fn:
                    n_tok += 1
                elif own is not None and v in own.aliases:
                    n_alias += 1
                else:
                    n_bend += v == "column_bend"
                    other[v] = other.get(v, 0) + 1
            named, alias, sig = named + n_tok, alias + n_alias, sig + n_sig
            bend, total = bend + n_bend, total + seeds
            print(f"   {layout:19s} {name:14s} {tok} at its limit {size:.3g}: own test "
                  f"{n_sig}/{seeds}, named {n_tok}/{seeds}, an alias {n_alias}/{seeds}, "
                  f"column_bend first {n_bend}/{seeds}", flush=True)
    print(f"8. rigid third orders on the arm layouts at their detection limit (seeds "
          f"4000-{3999 + seeds} + {CASE_STRIDE}·case): own test significant "
          f"{_rate(sig, total)}; named {_rate(named, total)}, an alias of it "
          f"{_rate(alias, total)}, column_bend named first instead {_rate(bend, total)}; "
          f"otherwise {other}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=12, help="seeds of items 1 and 2 (12)")
    ap.add_argument("--twist-seeds", type=int, default=2, help="seeds of item 3 (2)")
    ap.add_argument("--rigid-seeds", type=int, default=10,
                    help="seeds per rigid term and layout of item 4 (10; 0: skip)")
    ap.add_argument("--at-reading", action="store_true",
                    help="item 3: the twist's s and v at the carriage's readings, not the "
                         "tips (scenarios.bridge_roll evaluates at the tips)")
    ap.add_argument("--arm-seeds", type=int, default=6,
                    help="seeds per arm layout and plate of items 5 and 6 (6; item 6 runs "
                         "4x as many; 0: skip)")
    ap.add_argument("--arm-limit-seeds", type=int, default=4,
                    help="seeds per case of items 7 and 8 (4; 0: skip)")
    ap.add_argument("--only", choices=tuple("12345678"), default=None,
                    help="run one item only")
    args = ap.parse_args(argv)
    if args.only in (None, "1"):
        coverage(args.seeds)
    if args.only in (None, "2"):
        clean(2 * args.seeds)
    if args.only in (None, "3"):
        other_shapes(args.twist_seeds, args.at_reading)
    if args.only in (None, "4") and args.rigid_seeds:
        rigid_at_limit(args.rigid_seeds)
    if args.only in (None, "5") and args.arm_seeds:
        arm_coverage(args.arm_seeds)
    if args.only in (None, "6") and args.arm_seeds:
        arm_clean(4 * args.arm_seeds)
    if args.only in (None, "7") and args.arm_limit_seeds:
        arm_detection(args.arm_limit_seeds)
    if args.only in (None, "8") and args.arm_limit_seeds:
        arm_rigid(args.arm_limit_seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())

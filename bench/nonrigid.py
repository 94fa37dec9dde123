"""Monte Carlo of the non-rigid block (``python bench/nonrigid.py [--seeds N] [--twist-seeds M]``),
on scenario layouts (not the thesis):

1. coverage of bridge_twist's fitted parameters (z = (v - truth)/u), the roll about the
   machine's z = 0 and about a line 900 mm up (a gantry's rails);
2. the clean-data false-alarm rate of naming bridge_twist;
3. twists whose shape is none of the block's (``scenarios.bridge_roll``: g(s) = s², s³,
   sin(πs/2) or s at the tips, about z = 0 or 900 mm up, 15 and 30 µrad at the corners):
   the loop's path (diagnose, add the verdict, again), counting how often a rigid
   function's higher order (``ryy:3`` ...) or the plate's sag is named before the twist.
"""
import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]

import scenarios as sc  # noqa: E402
from honesty import loop  # noqa: E402

from cmm_core.diagnosis import diagnose  # noqa: E402
from cmm_core.model import fit  # noqa: E402

LAYOUTS = (("pitch150_5pos", "gantry_fxyz"), ("pitch100_4pos", "moving_bridge_fxyz"),
           ("pitch100_4pos", "gantry_fyxz"), ("pitch80_3pos", "moving_bridge_fyxz"))
SHAPES = (("s2", 0.0), ("s3", 0.0), ("sin", 900.0), ("s2", 900.0), ("lin", 900.0))


def coverage(seeds: int) -> None:
    z = []
    for name in ("pitch100_4pos", "pitch150_5pos"):
        for layout in ("gantry_fxyz", "moving_bridge_fyxz"):
            for seed in range(seeds):
                h = 900.0 if seed % 2 else 0.0
                sim = sc.layout_data(name, layout, 100 + seed, effects={"bridge_twist": {
                    "lin_urad": 5.0, "mid_urad": 3.0, "axis_height_mm": h}})
                r = fit(sim.dataset, "kinematic21,bridge_twist")
                lab, v, u = r.block("bridge_twist")
                z += list((v - np.array([sim.truth[k] for k in lab])) / u)
    za = np.array(z)
    print(f"1. bridge_twist z: n={za.size} rms={np.sqrt(np.mean(za**2)):.3f} "
          f"|z|<2: {np.mean(np.abs(za) < 2):.3f}")


def clean(seeds: int) -> None:
    named = n = 0
    for name in ("pitch100_4pos", "pitch150_5pos"):
        for layout in ("gantry_fxyz", "moving_bridge_fyxz"):
            for seed in range(seeds):
                d = diagnose(sc.layout_data(name, layout, 500 + seed).dataset, "kinematic21")
                n += 1
                named += d.verdict == "bridge_twist"
    print(f"2. clean data: bridge_twist named {named} of {n}")


def other_shapes(seeds: int) -> None:
    rigid = sag = twist = total = 0
    for name, layout in LAYOUTS:
        rng = sc.LAYOUTS[name]["range_mm"]
        for shape, h in SHAPES:
            for amp in (15.0, 30.0):
                for seed in range(seeds):
                    sim = sc.layout_data(name, layout, 700 + seed)
                    data = sc.bridge_roll(sim.dataset, layout, rng, amp, shape, h)
                    path, chi2_dof, last = loop(data, "kinematic21", max_steps=3)
                    first = path[0] if path else last
                    before = path[:path.index("bridge_twist")] if "bridge_twist" in path \
                        else path
                    rigid += any(":" in t for t in before)
                    sag += "plate_sag" in before
                    twist += "bridge_twist" in path
                    total += 1
                    print(f"   {layout:19s} {name:14s} g={shape:3s} h={h:4.0f} {amp:4.0f} µrad "
                          f"seed {seed}: {' -> '.join(path) or '-':36s} ends {last} "
                          f"χ²/dof {chi2_dof:.2f} (first {first})", flush=True)
    print(f"3. twists of other shapes: bridge_twist named {twist}/{total}; a rigid "
          f"function's higher order named before it {rigid}/{total}; plate sag before it "
          f"{sag}/{total}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=12, help="seeds of items 1 and 2 (12)")
    ap.add_argument("--twist-seeds", type=int, default=2, help="seeds of item 3 (2)")
    args = ap.parse_args(argv)
    coverage(args.seeds)
    clean(2 * args.seeds)
    other_shapes(args.twist_seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())

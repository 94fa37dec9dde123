"""Monte Carlo (``python bench/nonrigid.py``): coverage of bridge_twist's fitted parameters (z = (v - truth)/u) and the
clean-data false-alarm rate of naming bridge_twist, on scenario layouts (not the thesis)."""
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import scenarios as sc  # noqa: E402

from cmm_core.diagnosis import diagnose  # noqa: E402
from cmm_core.model import fit, simulate  # noqa: E402

z = []
for name in ("pitch100_4pos", "pitch150_5pos"):
    for layout in ("gantry_fxyz", "moving_bridge_fyxz"):
        for seed in range(12):
            cfg = sc.layout_config(name, seed=100 + seed,
                                   effects={"bridge_twist": {"lin_urad": 5.0, "mid_urad": 3.0}})
            cfg["setup"]["machine"]["layout"] = layout
            sim = simulate(cfg)
            r = fit(sim.dataset, "kinematic21,bridge_twist")
            lab, v, u = r.block("bridge_twist")
            z += list((v - np.array([sim.truth[k] for k in lab])) / u)
z = np.array(z)
print(f"bridge_twist z: n={z.size} rms={np.sqrt(np.mean(z**2)):.3f} "
      f"|z|<2: {np.mean(np.abs(z) < 2):.3f}")
named = n = 0
for name in ("pitch100_4pos", "pitch150_5pos"):
    for layout in ("gantry_fxyz", "moving_bridge_fyxz"):
        for seed in range(25):
            cfg = sc.layout_config(name, seed=500 + seed, effects={})
            cfg["setup"]["machine"]["layout"] = layout
            d = diagnose(simulate(cfg).dataset, "kinematic21")
            n += 1
            named += d.verdict == "bridge_twist"
print(f"clean data: bridge_twist named {named} of {n}")

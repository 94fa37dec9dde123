"""Regenerate the example instrument files from the simulated sample's true machine.

    python sample_data/instruments/make_samples.py

The machine is ``sample_data/simulated`` (``config.json``, seed 42): the same truth as its
measurements, so the files fit jointly with them.
"""

import json
from pathlib import Path

import numpy as np

from cmm_core.model import instruments as ins
from cmm_core.model import simulate, simulate_ball_bar
from cmm_core.model.instrument_files import write_ball_bar, write_laser, write_step_gauge

HERE = Path(__file__).resolve().parent
SIM = HERE.parent / "simulated"

sim = simulate(json.loads((SIM / "config.json").read_text()))
xs = np.linspace(0.0, 1200.0, 25)
pos = ins.simulate_laser(sim, "x", [0, 100, 50], xs, u_um=0.2, seed=1, run="x_pos_y100_z50")
straight = ins.simulate_laser(sim, "x", [0, 100, 50], xs, component="y", u_um=0.3, seed=2,
                              run="x_straight_y_y100_z50")
laser = ins.LaserRun(
    "laser_x.csv", np.arange(2, 2 + 2 * xs.size), np.repeat([0, 1], xs.size),
    (pos.runs[0], straight.runs[0]), np.concatenate([pos.axis, straight.axis]),
    np.concatenate([pos.component, straight.component]),
    np.vstack([pos.r_mm, straight.r_mm]), np.vstack([pos.p_mm, straight.p_mm]),
    np.concatenate([pos.error_um, straight.error_um]),
    np.concatenate([pos.u_um, straight.u_um]))
write_laser(laser, HERE / "laser_x.csv")
sg = ins.simulate_step_gauge(sim, [100, 150, 100], [1100, 850, 400],
                             np.arange(1, 12) * 100.0, offset_mm=(0, 0, -150), u_um=0.3,
                             seed=4)
write_step_gauge(sg, HERE / "step_gauge.csv")

# A 400 mm ball bar in the six directions of ISO 10360-2 (three axes, three face
# diagonals) about the middle of the volume, each placement measured once.
centre = np.array([600.0, 500.0, 300.0])
dirs = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 0, 1], [0, 1, 1]], float)
dirs /= np.linalg.norm(dirs, axis=1)[:, None]
bb = simulate_ball_bar(sim, centre - 200 * dirs, centre + 200 * dirs, offset_mm=(0, 0, -150),
                       u_um=0.3, seed=5, labels=["x", "y", "z", "xy", "xz", "yz"],
                       source="ball_bar.csv")
write_ball_bar(bb, HERE / "ball_bar.csv")

"""Writes model files in the format of before the compensation hooks of the blocks, and
the corrections that release gave for a fixed set of points (``tests/test_compensate.py``
checks they are reproduced bit for bit).

Run once, from the repository root, with the release that wrote them (commit eddf597):
``PYTHONPATH=. .venv/bin/python tests/corpus/legacy_models/make_legacy_models.py``.
Rerunning it with a later release overwrites the pinned corrections with that release's;
do not, unless the format is meant to change.
"""
import pathlib

import numpy as np
import pandas as pd

from cmm_core.export import compensate, load_model, save_model
from cmm_core.model import fit, simulate

HERE = pathlib.Path(__file__).resolve().parent

rng = np.random.default_rng(12)
# 40 points inside the machine, in a random (file) order, probes 1 and 3
pts = pd.DataFrame({"probe": rng.choice(["1", "3"], 40),
                    "x_mm": rng.uniform(300, 900, 40).round(3),
                    "y_mm": rng.uniform(200, 800, 40).round(3),
                    "z_mm": rng.uniform(-40, 600, 40).round(3)})
pts.to_csv(HERE / "points.csv", index=False)

for tag, spec, effects in (
        ("kinematic", "kinematic21", {}),
        ("backlash", "kinematic21,backlash",
         {"backlash": {"x_um": 2.0, "y_um": -1.5, "z_um": 1.0}}),
        # that release saved no scale coefficients: it corrected as at 20 °C scales
        ("machine_thermal", "kinematic21,machine_thermal",
         {"machine_thermal": {"x_cte_per_K": 3e-6, "z_cte_per_K": -2e-6}})):
    sim = simulate({"seed": 8, "order": "serpentine", "effects": effects})
    save_model(fit(sim.dataset, spec), HERE / f"model_{tag}.json")
    out = compensate(load_model(HERE / f"model_{tag}.json"), pts)
    # repr of a float reads back to the same double: the pinned values are exact
    out.to_csv(HERE / f"corrected_{tag}.csv", index=False, float_format="%.17g")

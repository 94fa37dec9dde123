"""Make the sample calibration history of one simulated CMM (sample_data/history/README.md).

Three yearly calibrations (four placements of a 5 x 5 plate at 100 mm pitch, five
styli, kinematic21 fitted with the plate fixed to its certificate) saved as model files,
and two interim checks: a quiet one (one placement, 2024-06) and one after a simulated
crash (2025-02: the xy squareness moved by 12 µrad, about 4 u of the stored model). The
2025 calibration is of the machine after the crash. Run from the repository root:
``python sample_data/history/make_history.py``; it rewrites the files beside it.
"""

from __future__ import annotations

import json
from pathlib import Path

from cmm_core.export import model_from_result, save_model
from cmm_core.model import fit, simulate
from cmm_core.monitor import remeasured

HERE = Path(__file__).resolve().parent
CRASH_SXY_URAD = 12.0
"""The squareness change of the crash (µrad)."""

_H = {"u_axis": [1, 0, 0], "v_axis": [0, 1, 0]}
_H90 = {"u_axis": [0, 1, 0], "v_axis": [-1, 0, 0]}
_XZ = {"u_axis": [1, 0, 0], "v_axis": [0, 0, 1]}
_YZ = {"u_axis": [0, 1, 0], "v_axis": [0, 0, 1]}
PLACEMENTS = {"H0": ({"origin_mm": [250, 200, 50], **_H}, ["A", "B"]),
              "H1": ({"origin_mm": [750, 300, 350], **_H90}, ["A", "C"]),
              "V1": ({"origin_mm": [300, 500, 100], **_XZ}, ["C", "D"]),
              "V2": ({"origin_mm": [600, 150, 100], **_YZ}, ["B", "E"])}
CONFIG = {
    "seed": 2023,
    "setup": {"units": "mm", "frame": "machine",
              "machine": {"layout": "moving_bridge_fxyz", "range_mm": [1000, 800, 600]},
              "positions": {p: {**geo, "probe": probes[0]}
                            for p, (geo, probes) in PLACEMENTS.items()},
              "probes": {"A": [0, 0, -120], "B": [60, 0, -120], "C": [0, 60, -120],
                         "D": [0, -60, -120], "E": [-60, 0, -120]}},
    "probes_per_position": {p: probes for p, (_, probes) in PLACEMENTS.items()},
    "plate": {"rows": 5, "cols": 5, "pitch_mm": 100.0},
}


def _save_model(sim, name: str) -> None:
    result = fit(sim.dataset, "kinematic21", plate="fixed")
    save_model(model_from_result(result), HERE / name)


def main() -> None:
    first = simulate(CONFIG)
    _save_model(first, "calibration_2023-03-01.json")
    _save_model(remeasured(first, 2024), "calibration_2024-03-04.json")
    remeasured(first, 2406, probes_per_position={"H0": ["A", "B"]}).write(
        HERE / "check_2024-06-17")
    crash = {"sxy": CRASH_SXY_URAD}
    remeasured(first, 2502, changes=crash).write(HERE / "check_2025-02-10_after_crash")
    _save_model(remeasured(first, 2025, changes=crash), "calibration_2025-03-03.json")
    (HERE / "dates.json").write_text(json.dumps({
        "calibration_2023-03-01.json": "2023-03-01", "calibration_2024-03-04.json": "2024-03-04",
        "calibration_2025-03-03.json": "2025-03-03"}, indent=1) + "\n")


if __name__ == "__main__":
    main()

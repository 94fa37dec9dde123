"""Write the example files of other tools' formats from ``sample_data/simulated``.

The same ball-plate measurements (the simulated sample's indicated tip centres) in three
forms this project reads (docs/foreign-formats.md, docs/msl-format.md):

- ``run.dmo``: a DMIS output file, one ``FA(label)=FEAT/SPHERE,CART,x,y,z,d`` per ball,
  labels ``BP111_P1_B7`` (position, probe, ball), with DATE and TIME lines;
- ``vendor_export.csv`` and ``mapping.json``: a vendor-style table (semicolons, decimal
  commas, coordinates in µm, German column names) and the column mapping that reads it;
- ``msl/BP111``, ``msl/BP211``, ``msl/BP311``: one MSL cmm-error-map snapshot and metadata
  file per placement (kind ``measured``: the indications in MSL's re-aligned artefact
  frame).

Run from the repository root: ``python sample_data/foreign/make_samples.py`` (deterministic:
the files come out the same).
"""

from __future__ import annotations

import datetime as dt
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
SIM = HERE.parent / "simulated"
PATTERN = r"(?P<position>BP\d+)_P(?P<probe>\w+)_B(?P<ball>\d+)"
T0 = dt.datetime(2026, 11, 24, 8, 0, 0)
MSL_POSITIONS = ("BP111", "BP211", "BP311")
# MSL's layout flags (fixed_table, bridge_axis) of the sample's moving_bridge_fxyz
MSL_FLAGS = {"moving_bridge_fxyz": (True, 1), "moving_bridge_fyxz": (True, 0)}
MSL_PARAMETERS = ("Txx", "Txy", "Txz", "Tyx", "Tyy", "Tyz", "Tzx", "Tzy", "Tzz",
                  "Rxx", "Rxy", "Rxz", "Ryx", "Ryy", "Ryz", "Rzx", "Rzy", "Rzz",
                  "Wxy", "Wxz", "Wyz")


def write_dmis(meas: pd.DataFrame, path: Path) -> None:
    """One TIME line and one sphere feature per probed ball (ball diameter 25.4 mm)."""
    lines = ["$$ CMM error lab example: sample_data/simulated as DMIS output",
             "FILNAM/'ball plate calibration',05.3", "UNITS/MM,ANGDEC", f"DATE={T0:%Y/%m/%d}"]
    for r in meas.itertuples():
        lines.append(f"TIME={T0 + dt.timedelta(minutes=float(r.time_min)):%H:%M:%S}")
        lines.append(f"FA({r.position}_P{r.probe}_B{r.ball})=FEAT/SPHERE,CART,"
                     f"{r.x_mm:.6f},{r.y_mm:.6f},{r.z_mm:.6f},25.4000")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_vendor(meas: pd.DataFrame, table: Path, mapping: Path) -> None:
    """Semicolon-separated, decimal commas, µm, a label column and a time in minutes."""
    out = pd.DataFrame({
        "Name": [f"{r.position}_P{r.probe}_B{r.ball}" for r in meas.itertuples()],
        "X-Wert": meas["x_mm"] * 1000, "Y-Wert": meas["y_mm"] * 1000,
        "Z-Wert": meas["z_mm"] * 1000, "Zeit": meas["time_min"],
        "Temperatur": meas["temp_C"]})
    table.write_text(out.to_csv(sep=";", decimal=",", index=False, float_format="%.3f"),
                     encoding="utf-8")
    mapping.write_text(json.dumps({
        "x": "X-Wert", "y": "Y-Wert", "z": "Z-Wert", "label": "Name", "pattern": PATTERN,
        "time": "Zeit", "time_unit": "min", "temperature": "Temperatur", "unit": "um",
        "decimal": ","}, indent=1) + "\n", encoding="utf-8")


def _realign(tips: np.ndarray, nx: int, ny: int) -> np.ndarray:
    """MSL's artefact frame: origin ball 0, x through ball nx − 1, xy plane through ball
    nx·(ny − 1)."""
    ex = tips[nx - 1] - tips[0]
    ex /= np.linalg.norm(ex)
    ez = np.cross(ex, tips[nx * (ny - 1)] - tips[0])
    ez /= np.linalg.norm(ez)
    return (tips - tips[0]) @ np.column_stack([ex, np.cross(ez, ex), ez])


def _angles_deg(R: np.ndarray) -> np.ndarray:
    """(rx, ry, rz) in degrees with R = Rz·Ry·Rx (MSL's rotation/deg)."""
    return np.degrees([math.atan2(R[2, 1], R[2, 2]), -math.asin(R[2, 0]),
                       math.atan2(R[1, 0], R[0, 0])])


def write_msl(meas: pd.DataFrame, setup: dict, folder: Path) -> None:
    """One snapshot + metadata per placement of :data:`MSL_POSITIONS`."""
    n = int(round(math.sqrt(setup["plate"]["balls"])))
    pitch = setup["plate"]["pitch_mm"]
    fixed, bridge = MSL_FLAGS[setup["machine"]["layout"]]
    for pos in MSL_POSITIONS:
        pl = setup["positions"][pos]
        u, v = np.asarray(pl["u_axis"], float), np.asarray(pl["v_axis"], float)
        R = np.column_stack([u, v, np.cross(u, v)])
        probe = np.asarray(setup["probes"][pl["probe"]], float)
        location = np.asarray(pl["origin_mm"], float) - probe
        g = meas[(meas["position"] == pos) & (meas["probe"] == pl["probe"])
                 & (meas["repeat"] == 0)].sort_values("ball")
        tips = _realign(g[["x_mm", "y_mm", "z_mm"]].to_numpy(), n, n)
        head = ["save time,2026-11-24 08:00:00.000000", f"title,Plate {pos}", f"name,{pos}",
                "artefact.title,5 x 5 ball plate", f"artefact.nballs,{n},{n}",
                f"artefact.ball_spacing,{pitch}",
                "location," + ", ".join(repr(float(x)) for x in location),
                "rotation/deg," + ", ".join(repr(round(float(a), 9)) for a in _angles_deg(R))]
        d = folder / pos
        d.mkdir(parents=True, exist_ok=True)
        rows = [f"{k},{x:.5f},{y:.5f},{z:.5f}" for k, (x, y, z) in enumerate(tips)]
        (d / "snapshot.csv").write_text("\n".join(head + ["id,mmt_x,mmt_y,mmt_z"] + rows)
                                        + "\n", encoding="utf-8")
        meta = head + ["cmm_model.title,simulated bridge CMM",
                       "cmm_model.size," + ",".join(f"{r:g}" for r in setup["machine"]["range_mm"]),
                       f"cmm_model.fixed_table,{fixed}", f"cmm_model.bridge_axis,{bridge}",
                       "probe.title,stylus", f"probe.name,P{pl['probe']}",
                       "probe.length," + ",".join(repr(float(x)) for x in probe),
                       "model parameters"] + [f"{p},[0.0, 0.0]" for p in MSL_PARAMETERS]
        (d / "metadata.csv").write_text("\n".join(meta) + "\n", encoding="utf-8")


def main() -> None:
    meas = pd.read_csv(SIM / "measurements.csv", dtype={"probe": str, "position": str})
    if "repeat" not in meas:
        meas["repeat"] = 0
    setup = json.loads((SIM / "setup.json").read_text(encoding="utf-8"))
    write_dmis(meas, HERE / "run.dmo")
    write_vendor(meas, HERE / "vendor_export.csv", HERE / "mapping.json")
    write_msl(meas, setup, HERE / "msl")


if __name__ == "__main__":
    main()

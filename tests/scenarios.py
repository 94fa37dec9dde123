"""Simulated layouts other than the sample data's, and hidden effects outside the catalogue.

Used by the diagnosis tests and ``bench/power.py``: the product is judged on data it has
never seen, so its statistics are checked on other pitches, placements, probes and seeds.
Outside-catalogue effects are added to the simulated readings afterwards (the simulator
only knows catalogue effects, by design).
"""

from __future__ import annotations

import numpy as np

from cmm_core.io import Dataset, read_setup, resolve
from cmm_core.model import simulate
from cmm_core.plan.proposals import plate_grid

_H = {"u_axis": [1, 0, 0], "v_axis": [0, 1, 0]}
_H90 = {"u_axis": [0, 1, 0], "v_axis": [-1, 0, 0]}
_XZ = {"u_axis": [1, 0, 0], "v_axis": [0, 0, 1]}
_YZ = {"u_axis": [0, 1, 0], "v_axis": [0, 0, 1]}
_D1 = {"u_axis": [0.707106781187, 0.707106781187, 0], "v_axis": [0, 0, 1]}
_D2 = {"u_axis": [0.707106781187, -0.707106781187, 0], "v_axis": [0, 0, 1]}

LAYOUTS = {
    # 4 placements of a 5 x 5 plate at 100 mm pitch, five styli
    "pitch100_4pos": {
        "plate": {"rows": 5, "cols": 5, "pitch_mm": 100.0},
        "range_mm": [1000, 800, 600],
        "positions": {"H0": ({"origin_mm": [250, 200, 50], **_H}, ["A", "B"]),
                      "H1": ({"origin_mm": [750, 300, 350], **_H90}, ["A", "C"]),
                      "V1": ({"origin_mm": [300, 500, 100], **_XZ}, ["C", "D"]),
                      "V2": ({"origin_mm": [600, 150, 100], **_YZ}, ["B", "E"])},
        "probes": {"A": [0, 0, -120], "B": [60, 0, -120], "C": [0, 60, -120],
                   "D": [0, -60, -120], "E": [-60, 0, -120]},
    },
    # 3 placements of a 6 x 6 plate at 80 mm pitch, one stylus each
    "pitch80_3pos": {
        "plate": {"rows": 6, "cols": 6, "pitch_mm": 80.0},
        "range_mm": [900, 900, 600],
        "positions": {"H": ({"origin_mm": [250, 250, 80], **_H}, ["1", "4"]),
                      "D1": ({"origin_mm": [200, 200, 100], **_D1}, ["2", "4"]),
                      "D2": ({"origin_mm": [200, 650, 100], **_D2}, ["3", "4"])},
        "probes": {"1": [0, 0, -150], "2": [40, -40, -150], "3": [-40, -40, -150],
                   "4": [0, 0, -60]},
    },
    # 5 placements of a 4 x 4 plate at 150 mm pitch, two styli shared across placements
    "pitch150_5pos": {
        "plate": {"rows": 4, "cols": 4, "pitch_mm": 150.0},
        "range_mm": [1200, 1000, 800],
        "positions": {"Hlow": ({"origin_mm": [300, 250, 50], **_H}, ["P", "Q"]),
                      "Hhigh": ({"origin_mm": [400, 300, 450], **_H}, ["P", "Q"]),
                      "XZ": ({"origin_mm": [350, 600, 100], **_XZ}, ["P", "R"]),
                      "D1": ({"origin_mm": [300, 150, 150], **_D1}, ["Q", "R"]),
                      "D2": ({"origin_mm": [350, 800, 150], **_D2}, ["P", "R"])},
        "probes": {"P": [0, 0, -100], "Q": [0, 80, -100], "R": [80, 0, -100]},
    },
}


def layout_config(name: str, **extra) -> dict:
    """Simulator configuration of one layout; ``extra`` keys are merged in."""
    lay = LAYOUTS[name]
    setup = {"units": "mm", "frame": "machine",
             "machine": {"layout": "moving_bridge_fxyz", "range_mm": lay["range_mm"]},
             "positions": {p: {**geo, "probe": probes[0]}
                           for p, (geo, probes) in lay["positions"].items()},
             "probes": lay["probes"]}
    cfg = {"setup": setup, "plate": dict(lay["plate"]),
           "probes_per_position": {p: probes for p, (_, probes) in lay["positions"].items()}}
    for k, v in extra.items():
        cfg[k] = {**cfg[k], **v} if isinstance(v, dict) and k in cfg else v
    return cfg


def perturb(data: Dataset, delta_mm) -> Dataset:
    """The dataset with ``delta_mm`` (n, 3) added to every reading (machine frame)."""
    meas = data.meas.copy()
    for a, col in enumerate(("x_mm", "y_mm", "z_mm")):
        meas[col] = meas[col].to_numpy() + delta_mm[:, a]
    raw = meas.drop(columns=[c for c in ("mx_mm", "my_mm", "mz_mm") if c in meas])
    return Dataset(resolve(raw, data.setup, data.certificate), data.setup,
                   data.certificate, data.name)


def machine_xyz(data: Dataset) -> np.ndarray:
    return data.meas[["mx_mm", "my_mm", "mz_mm"]].to_numpy()


def placement_scale(data: Dataset, rng, sd_ppm=8.0, axis=0) -> Dataset:
    """Outside the catalogue: each placement reads lengths along one machine axis with
    its own scale (a placement-dependent thermal state of the machine's scale)."""
    xyz = machine_xyz(data)
    delta = np.zeros_like(xyz)
    for p in data.positions:
        sel = (data.meas["position"] == p).to_numpy()
        s = rng.normal(0, sd_ppm) * 1e-6
        delta[sel, axis] = s * (xyz[sel, axis] - xyz[sel, axis].mean())
    return perturb(data, delta)


def local_bump(data: Dataset, centre_mm, width_mm=60.0, amp_um=3.0, axis=1) -> Dataset:
    """Outside the catalogue: a local bump of the positioning error of one axis (a dent
    in a scale), Gaussian in that axis's coordinate."""
    xyz = machine_xyz(data)
    delta = np.zeros_like(xyz)
    delta[:, axis] = amp_um * 1e-3 * np.exp(-0.5 * ((xyz[:, axis] - centre_mm) / width_mm) ** 2)
    return perturb(data, delta)


def simulated(name: str, seed: int, **extra):
    """``simulate`` of one layout."""
    return simulate({**layout_config(name, **extra), "seed": seed})


def layout_on(name: str, layout: str, seed: int, **extra) -> dict:
    """Simulator configuration of one scenario on another machine layout
    (``gantry_fxyz`` ...)."""
    cfg = {**layout_config(name, **extra), "seed": seed}
    cfg["setup"] = {**cfg["setup"], "machine": {**cfg["setup"]["machine"], "layout": layout}}
    return cfg


def layout_data(name: str, layout: str, seed: int, **extra):
    """``simulate`` of one scenario on another machine layout (``gantry_fxyz`` ...)."""
    return simulate(layout_on(name, layout, seed, **extra))


def gantry_config(seed: int, noise_um: float = 0.5, **extra) -> dict:
    """A gantry with a 900 mm Z stroke, plate B1 low on the table: stood in XZ near B1
    its top ball is at z = 810 mm, the ram at 960 mm with the 150 mm stylus (within the
    simulator's 100 mm of slack, out of the machine's reach)."""
    return {"seed": int(seed), "noise_um": noise_um, **extra,
            "setup": {"units": "mm", "frame": "machine",
                      "machine": {"layout": "gantry_fxyz", "range_mm": [1500, 1200, 900]},
                      "positions": {"B1": {"origin_mm": [400, 300, 190], **_H, "probe": "T"},
                                    "B2": {"origin_mm": [500, 350, 450], **_H, "probe": "T"},
                                    "V": {"origin_mm": [400, 700, 150], **_XZ,
                                          "probe": "S"}},
                      "probes": {"T": [0, 0, -150], "S": [0, -80, -150]}},
            "plate": {"rows": 5, "cols": 5, "pitch_mm": 150.0},
            "probes_per_position": {"B1": ["T"], "B2": ["T", "S"], "V": ["S"]}}


def arm_config(seed: int, noise_um: float = 0.5, **extra) -> dict:
    """A horizontal arm (column along X, arm along Y) with styli pointing sideways, one
    155 mm along X (a step gauge laid out from the tip ran off the X stroke)."""
    return {"seed": int(seed), "noise_um": noise_um, **extra,
            "setup": {"units": "mm", "frame": "machine",
                      "machine": {"layout": "horizontal_arm_fxzy",
                                  "range_mm": [1200, 800, 900]},
                      "positions": {"A": {"origin_mm": [300, 200, 100], **_H, "probe": "X"},
                                    "B": {"origin_mm": [350, 250, 500], **_H, "probe": "Y"},
                                    "V": {"origin_mm": [300, 450, 150], **_XZ,
                                          "probe": "Y"}},
                      "probes": {"Y": [0, -150, 0], "X": [155, -60, 0]}},
            "plate": {"rows": 4, "cols": 4, "pitch_mm": 120.0},
            "probes_per_position": {"A": ["X", "Y"], "B": ["Y"], "V": ["Y", "X"]}}


def proposal_scale_readings(data: Dataset, cand) -> np.ndarray:
    """Every scale reading (tip minus stylus offset, mm, (n, 3)) a proposal asks for,
    laid out here from the placement's geometry, not by the core's reach check: each
    ball of the certificate's grid with each stylus of each new placement; for a
    repeat, the readings of the data it measures again (same placement, stylus, balls)."""
    if cand.repeat:
        m = data.meas
        probes = data.setup.raw["probes"]
        out = []
        for p, r in cand.repeat.items():
            at = ((m["position"] == p) & (m["probe"].astype(str) == str(r["probe"]))
                  & m["ball"].isin(r["balls"])).to_numpy()
            out.append(m.loc[at, ["mx_mm", "my_mm", "mz_mm"]].to_numpy(float)
                       - np.asarray(probes[str(r["probe"])], float))
        return np.vstack(out) if out else np.zeros((0, 3))
    g = plate_grid(data)
    probes = {**data.setup.raw["probes"], **cand.probes}
    # without the placements' stylus: the setup reader's slack check is not the question
    positions = {p: {k: v for k, v in pl.items() if k != "probe"}
                 for p, pl in cand.positions.items()}
    setup = read_setup({"units": "mm", "frame": "machine",
                        "machine": data.setup.raw["machine"], "positions": positions,
                        "probes": probes}, name="check")
    b = np.arange(g.rows * g.cols)
    plate = np.column_stack([b % g.cols, b // g.cols, 0 * b]) * g.pitch_mm + g.offset_mm
    out = [setup.positions[p].to_machine(plate) - np.asarray(probes[q], float)
           for p, styli in cand.probes_of.items() for q in styli]
    return np.vstack(out) if out else np.zeros((0, 3))


TWIST_SHAPES = {"s2": lambda s: s**2, "s3": lambda s: s**3,
                "sin": lambda s: np.sin(np.pi * s / 2), "lin": lambda s: s,
                "mid": lambda s: (1 - s**2) ** 2, "tanh": lambda s: np.tanh(3 * s)}
"""Shapes g(s) of :func:`bridge_roll` along the travel (s in [-1, 1])."""


def bridge_roll(data: Dataset, layout: str, range_mm, amp_urad: float, shape: str = "s2",
                axis_height_mm: float = 0.0, at_reading: bool = False) -> Dataset:
    """Outside the block's exact shapes: the bridge (or gantry beam) of a ``layout`` with
    x and y bridge axes rolls about its travel axis a by ``θ = amp · g(s) · v`` (the
    carriage's load share ``v`` across the bridge times how the supports' compliance
    changes along the travel, ``s``; ``blocks.bridge_twist``), about a roll axis at
    height ``axis_height_mm`` (a gantry's rails stand above the table). Shapes g:
    ``"s2"`` (s², a rail stiffer at its middle), ``"s3"`` (s³), ``"sin"`` (sin(π s/2)
    ... an asymmetric support), ``"lin"`` (s, the block's own first shape), ``"mid"``
    ((1 − s²)², a soft middle), ``"tanh"`` (tanh 3s, a step in stiffness). Evaluated at
    the tips' machine coordinates (a stylus offset then shifts s and v: a per-stylus
    roll no carriage makes, named drift on ``(1 − s²)²``-like shapes), or with
    ``at_reading`` at the carriage's position, the tip less the probe offset, where the
    carriage's weight stands (the block's physics); the tip moves by
    ``θ e_a × (r − (·, 0, h))``."""
    chain = {"moving_bridge_fxyz": "xy", "gantry_fxyz": "xy",
             "moving_bridge_fyxz": "yx", "gantry_fyxz": "yx"}[layout]
    a, b = "xyz".index(chain[0]), "xyz".index(chain[1])
    xyz = machine_xyz(data)
    w = xyz
    if at_reading:
        probes = data.setup.probes
        w = xyz - np.array([probes[str(q)] for q in data.meas["probe"].astype(str)], float)
    rng = np.asarray(range_mm, float)
    s = 2 * w[:, a] / rng[a] - 1
    v = 2 * w[:, b] / rng[b] - 1
    theta = amp_urad * 1e-6 * TWIST_SHAPES[shape](s) * v
    lever = xyz.copy()
    lever[:, a] = 0.0
    lever[:, 2] -= axis_height_mm
    return perturb(data, theta[:, None] * np.cross(np.eye(3)[a], lever))

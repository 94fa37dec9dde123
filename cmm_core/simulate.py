"""Virtual CMM: simulate ball-plate measurements with known errors and effects.

The simulation is the exact inverse of the fit's measurement model (see ``fit``): for
every probed ball the true tip centre ``s = R_k c_b' + t_k`` is computed (plate form,
thermal expansion and sag included in ``c_b'``), the scale readings ``x`` that reach it are
found by solving ``x*(x, p_true) = s + drift`` with exact rotations
(``kinematics.invert``), and the CMM reports ``r = x + p_nominal`` plus noise.

Configuration keys (all optional; see ``DEFAULT_CONFIG``): ``seed``, ``setup`` (a setup
dict in the SPEC format, frame ``machine``; default the thesis placements),
``probes_per_position``, ``plate`` (``rows, cols, pitch_mm, form_um, certificate_u_um``),
``kinematic`` (``spec``, ``order``, ``coefficients`` by label, ``random_um``,
``random_urad``; the spec may carry periodic scale errors, e.g.
``"kinematic21,periodic_x:180"`` with coefficients ``dxx[sin180]``, ``dxx[cos180]``), ``noise_um``, ``effects`` (``plate_thermal``: ``cte_per_K`` and
``temp_C`` per position [start, finish]; ``plate_sag``: ``uu, uv, vv`` µm;
``probe_offset``: per-probe vectors in µm or ``sd_um``; ``drift``: per-position vectors in
µm/h or ``sd_um_per_h``; ``backlash``: reversal span ``x_um, y_um, z_um``), ``order`` (``row``, ``serpentine``, ``random``),
``probes_interleaved``, ``minutes_per_ball``, ``repeats``.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from . import kinematics as kin
from .dataset import THESIS_DIR, Dataset
from .effects import parse_spec
from .fit import approach_directions, plate_effect_basis
from .io import Certificate, read_setup, resolve, write_certificate, write_long_csv

DEFAULT_CONFIG = {
    "seed": 0,
    "setup": None,
    "probes_per_position": {"BP111": ["1", "2"], "BP112": ["1", "2"], "BP211": ["3", "4"],
                            "BP212": ["3", "4"], "BP311": ["5", "6"], "BP312": ["5", "6"]},
    "plate": {"rows": 5, "cols": 5, "pitch_mm": 133.0, "form_um": 2.0,
              "certificate_u_um": 0.1},
    "kinematic": {"spec": "kinematic21", "order": 2, "coefficients": {},
                  "random_um": 1.0, "random_urad": 1.0},
    "noise_um": 0.5,
    "effects": {},
    "order": "row",
    "probes_interleaved": False,
    "minutes_per_ball": 0.5,
    "repeats": 1,
}


def thesis_machine_setup() -> dict:
    """The thesis placements as a machine-frame setup dict (a copy)."""
    raw = json.loads((THESIS_DIR / "setup.json").read_text())
    raw["frame"] = "machine"
    for p in raw["positions"].values():
        p.pop("temp_C", None)
        p.pop("rh_percent", None)
    return raw


@dataclass(frozen=True)
class Simulation:
    """A simulated dataset and the truth behind it.

    Attributes
    ----------
    dataset : Dataset
        Measurements (machine frame), setup and certificate as a user would load them.
    truth : dict
        True parameter values by fit label (kinematic coefficients in µm / µrad, effects).
    true_plate_mm : ndarray (B, 3)
        The true ball centres (the certificate adds its own calibration noise).
    config : dict
        The full configuration used (defaults filled in).
    """

    dataset: Dataset
    truth: dict
    true_plate_mm: np.ndarray
    config: dict

    def write(self, out_dir) -> None:
        """Write ``measurements.csv``, ``setup.json``, ``certificate.csv``, ``truth.json``."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        write_long_csv(self.dataset.meas, out / "measurements.csv")
        (out / "setup.json").write_text(json.dumps(self.dataset.setup.raw, indent=1))
        write_certificate(self.dataset.certificate, out / "certificate.csv")
        (out / "truth.json").write_text(json.dumps({"truth": self.truth,
                                                    "config": self.config}, indent=1))


_EFFECT_KEYS = {"plate_thermal": {"cte_per_K", "temp_C"}, "plate_sag": {"uu", "uv", "vv"},
                "probe_offset": None, "drift": None, "backlash": {"x_um", "y_um", "z_um"}}


def _check_config(cfg):
    """Unknown keys are errors, never silently ignored (a typo would hide an effect)."""
    unknown = set(cfg) - set(DEFAULT_CONFIG)
    if unknown:
        raise ValueError(f"simulation config: unknown key(s) {sorted(unknown)}; expected "
                         f"some of {sorted(DEFAULT_CONFIG)}.")
    for sect in ("plate", "kinematic"):
        extra = set(cfg.get(sect) or {}) - set(DEFAULT_CONFIG[sect])
        if extra:
            raise ValueError(f"simulation config: unknown key(s) {sorted(extra)} in "
                             f"'{sect}'; expected some of {sorted(DEFAULT_CONFIG[sect])}.")
    for name, body in (cfg.get("effects") or {}).items():
        if name not in _EFFECT_KEYS:
            raise ValueError(f"simulation config: unknown effect {name!r}; expected one of "
                             f"{sorted(_EFFECT_KEYS)}.")
        allowed = _EFFECT_KEYS[name]
        if allowed is not None and set(body) - allowed:
            raise ValueError(f"simulation config: effect {name!r} takes {sorted(allowed)}, "
                             f"found {sorted(set(body) - allowed)}.")
    if not float(cfg.get("noise_um", 0.5)) >= 0:
        raise ValueError("simulation config: noise_um must be >= 0.")


def _merge(base, over):
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) \
            else copy.deepcopy(v)
    return out


def _visit_order(rows, cols, how, rng):
    idx = np.arange(rows * cols).reshape(rows, cols)
    if how == "row":
        return idx.ravel()
    if how == "serpentine":
        idx[1::2] = idx[1::2, ::-1]
        return idx.ravel()
    if how == "random":
        return rng.permutation(rows * cols)
    raise ValueError(f"order must be 'row', 'serpentine' or 'random', got {how!r}.")


def simulate(config: dict | None = None) -> Simulation:
    """Simulate a virtual CMM measuring a ball plate (see the module docstring)."""
    _check_config(config or {})
    cfg = _merge(DEFAULT_CONFIG, config)
    rng = np.random.default_rng(cfg["seed"])
    setup_raw = copy.deepcopy(cfg["setup"] or thesis_machine_setup())
    setup_raw["frame"] = "machine"
    pl = cfg["plate"]
    rows, cols, pitch = int(pl["rows"]), int(pl["cols"]), float(pl["pitch_mm"])
    gx, gy = np.meshgrid(np.arange(cols) * pitch, np.arange(rows) * pitch)
    nominal = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(rows * cols)])
    plate = nominal + rng.normal(0, pl["form_um"], nominal.shape) * 1e-3
    plate -= plate[0]
    setup_raw.setdefault("plate", {})["cte_per_K"] = cfg["effects"].get(
        "plate_thermal", {}).get("cte_per_K", setup_raw.get("plate", {}).get("cte_per_K",
                                                                           11.5e-6))
    setup = read_setup(setup_raw)
    positions = list(setup.positions)
    ppp = cfg["probes_per_position"] or {}
    probes_of = {p: [str(q) for q in ppp.get(p, [setup.positions[p].probe
                                                 or next(iter(setup.probes))])]
                 for p in positions}

    km = cfg["kinematic"]
    spec = parse_spec(km["spec"], default_order=int(km["order"]))
    terms = kin.KinematicTerms(spec.active, tuple(setup.range_mm), spec.periods)
    coef = np.zeros(terms.n)
    for i, lab in enumerate(terms.labels):
        sd = km["random_um"] if terms.unit(lab) == "um" else km["random_urad"]
        coef[i] = km["coefficients"].get(lab, rng.normal(0, sd) if sd else 0.0)
    truth = dict(zip(terms.labels, coef.tolist(), strict=True))

    eff = cfg["effects"]
    probe_err = {q: np.zeros(3) for q in setup.probes}
    if "probe_offset" in eff:
        po = eff["probe_offset"]
        if "sd_um" in po:
            vals = rng.normal(0, po["sd_um"], (len(setup.probes), 3))
            vals -= vals.mean(0)  # the fit's gauge: offset errors sum to zero
            probe_err = {q: v for q, v in zip(setup.probes, vals, strict=True)}
        else:
            probe_err.update({str(q): np.asarray(v, float) for q, v in po.items()})
        truth.update({f"probe{q}.{a}": float(v[i]) for q, v in probe_err.items()
                      for i, a in enumerate("xyz")})
    drift = {p: np.zeros(3) for p in positions}
    if "drift" in eff:
        dr = eff["drift"]
        for p in positions:
            drift[p] = (rng.normal(0, dr["sd_um_per_h"], 3) if "sd_um_per_h" in dr
                        else np.asarray(dr.get(p, [0, 0, 0]), float))
        truth.update({f"{p}.drift_{a}": float(drift[p][i]) for p in positions
                      for i, a in enumerate("xyz")})
    cte = 0.0
    temps = {p: (20.0, 20.0) for p in positions}
    if "plate_thermal" in eff:
        th = eff["plate_thermal"]
        cte = float(th.get("cte_per_K", 11.5e-6))
        for i, p in enumerate(positions):
            t = th.get("temp_C", {}).get(p) if isinstance(th.get("temp_C"), dict) else None
            temps[p] = tuple(t) if t else (20.0 + 0.4 * i, 20.2 + 0.4 * i)
        truth["plate_thermal.cte"] = cte * 1e6
    sag = np.zeros(3)
    if "plate_sag" in eff:
        sg = eff["plate_sag"]
        sag = np.array([sg.get("uu", 0.0), sg.get("uv", 0.0), sg.get("vv", 0.0)], float)
        truth.update({"plate_sag.uu": sag[0], "plate_sag.uv": sag[1], "plate_sag.vv": sag[2]})
    centre, sag_basis = plate_effect_basis(plate)

    records = []
    clock = 0.0
    visit = _visit_order(rows, cols, cfg["order"], rng)
    for p in positions:
        seq = [(b, q) for b in visit for q in probes_of[p]] if cfg["probes_interleaved"] \
            else [(b, q) for q in probes_of[p] for b in visit]
        seq = seq * int(cfg["repeats"])
        t_start = clock
        times = t_start + np.arange(len(seq)) * cfg["minutes_per_ball"]
        clock = times[-1] + 10.0  # re-fixturing the plate takes time
        t0, t1 = temps[p]
        frac = (times - times[0]) / max(times[-1] - times[0], 1e-9)
        for j, (b, q) in enumerate(seq):
            records.append((p, q, int(b) + 1, times[j], t0 + (t1 - t0) * frac[j],
                            j // (len(visit) * len(probes_of[p])), times[j] - times.mean()))
    df = pd.DataFrame(records, columns=["position", "probe", "ball", "time_min", "temp_C",
                                        "repeat", "_dt_min"])
    bi = df["ball"].to_numpy() - 1
    dT = df["temp_C"].to_numpy() - 20.0
    c = centre + (plate[bi] - centre) * (1 + cte * dT[:, None])
    horiz = np.array([setup.positions[p].horizontal for p in df["position"]])
    c[:, 2] += (sag_basis[bi] @ sag) * 1e-3 * horiz
    R = np.array([setup.positions[p].rotation for p in df["position"]])
    o = np.array([setup.positions[p].origin_mm for p in df["position"]])
    s = np.einsum("nij,nj->ni", R, c) + o
    hours = df["_dt_min"].to_numpy() / 60.0
    s = s + np.array([drift[p] for p in df["position"]]) * hours[:, None] * 1e-3
    pnom = np.array([setup.probes[q] for q in df["probe"]])
    ptrue = pnom + np.array([probe_err[q] for q in df["probe"]]) * 1e-3
    x = kin.invert(terms, coef, s, ptrue)
    if "backlash" in eff:
        # rows are in time order: the reading is short by half the span along the last move
        span = np.array([eff["backlash"].get(f"{a}_um", 0.0) for a in "xyz"], float)
        x = x - approach_directions(x) * span / 2 * 1e-3
        truth.update({f"backlash.{a}": float(v) for a, v in zip("xyz", span, strict=True)})
    r = x + pnom + rng.normal(0, cfg["noise_um"], x.shape) * 1e-3
    df["x_mm"], df["y_mm"], df["z_mm"] = r.T
    df = df.drop(columns="_dt_min")
    if cfg["repeats"] <= 1:
        df = df.drop(columns="repeat")
    df["source"] = "measurements.csv"
    df["row"] = np.arange(2, len(df) + 2)
    cu = float(pl["certificate_u_um"])
    cert_xyz = plate + rng.normal(0, cu, plate.shape) * 1e-3 if cu > 0 else plate.copy()
    cert = Certificate(np.arange(1, rows * cols + 1), cert_xyz,
                       np.full(plate.shape, max(cu, 1e-3)))
    meas = resolve(df, setup, cert)
    return Simulation(Dataset(meas, setup, cert, name=f"simulated (seed {cfg['seed']})"),
                      truth, plate, cfg)

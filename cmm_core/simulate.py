"""Virtual CMM: simulate ball-plate measurements with known errors and effects.

The simulation is the exact inverse of the fit's measurement model (see ``fit``): for
every probed ball the true tip centre ``s = R_k c_b' + t_k`` is computed (plate form,
thermal expansion and sag included in ``c_b'``), the scale readings ``x`` that reach it are
found by solving ``x*(x, p_true) = s + drift`` with exact rotations
(``kinematics.invert``), and the CMM reports ``r = x + p_nominal`` plus noise. The effects
are the fit's own blocks (``cmm_core.blocks``): each draws its true parameters
(``Block.draw``) and the fit's model at the truth gives the targets (``Problem.targets``).

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
import difflib
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from . import kinematics as kin
from .blocks import BY_TOKEN
from .blocks.base import SimContext
from .dataset import THESIS_DIR, Dataset
from .effects import MAX_ORDER, parse_spec
from .fit import Observations, Problem, approach_directions
from .io import (
    Certificate,
    DataError,
    _check_celsius,
    _cut,
    read_setup,
    resolve,
    write_certificate,
    write_long_csv,
)

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


_EFFECT_KEYS = {token: None if b.sim_keys is None else set(b.sim_keys)
                for token, b in BY_TOKEN.items()}


def _check_config(cfg, name="simulation config"):
    """Check a configuration before anything is simulated; every problem a DataError
    naming the key (``plate.rows``) and what was expected.

    Unknown keys are errors, never silently ignored (a typo would hide an effect), and so
    are unknown coefficient labels, positions and probes; numbers must be finite and in
    range (a pitch of 0, a single row of balls or a negative time per ball would
    simulate something no plate or CMM does).
    """
    def bad(column, message, hint=None):
        return DataError(message, file=name, column=column, hint=hint)

    def number(*args, **kw):
        return _number(bad, *args, **kw)

    _check_keys(cfg, bad)
    _check_run(cfg, bad, number)
    _check_plate_config(cfg, bad, number)
    _check_kinematic_config(cfg, bad, number)
    for token, body in (cfg.get("effects") or {}).items():
        for k, (lo, hi) in BY_TOKEN[token].sim_ranges.items():
            if k in body:
                number(f"effects.{token}.{k}", body[k], lo, hi)


def _check_keys(cfg, bad):
    """The configuration's shape: known keys and sections, known effects and their keys."""
    if not isinstance(cfg, dict):
        raise bad(None, f"expected a JSON object with some of {sorted(DEFAULT_CONFIG)}, "
                  f"found {type(cfg).__name__} {_cut(cfg)}.")
    unknown = set(cfg) - set(DEFAULT_CONFIG)
    if unknown:
        raise bad(str(sorted(unknown)[0]), f"unknown key(s) {sorted(map(str, unknown))}; "
                  f"expected some of {sorted(DEFAULT_CONFIG)}.")
    for sect in ("plate", "kinematic", "effects"):
        if sect in cfg and not isinstance(cfg[sect], dict):
            raise bad(sect, f"expected a JSON object for {sect!r}, found "
                      f"{type(cfg[sect]).__name__} {_cut(cfg[sect])}.")
    for sect in ("plate", "kinematic"):
        extra = set(cfg.get(sect) or {}) - set(DEFAULT_CONFIG[sect])
        if extra:
            raise bad(f"{sect}.{sorted(map(str, extra))[0]}", f"unknown key(s) "
                      f"{sorted(map(str, extra))} in '{sect}'; expected some of "
                      f"{sorted(DEFAULT_CONFIG[sect])}.")
    for key, body in (cfg.get("effects") or {}).items():
        if key not in _EFFECT_KEYS:
            raise bad(f"effects.{key}", f"unknown effect {_cut(key)}; expected one of "
                      f"{sorted(_EFFECT_KEYS)}.")
        if not isinstance(body, dict):
            raise bad(f"effects.{key}", f"expected a JSON object of the effect's values, "
                      f"found {type(body).__name__} {_cut(body)}.",
                      hint=f'write e.g. "effects": {{"{key}": {{}}}}.')
        allowed = _EFFECT_KEYS[key]
        if allowed is not None and set(body) - allowed:
            raise bad(f"effects.{key}", f"effect {key!r} takes {sorted(allowed)}, found "
                      f"{sorted(map(str, set(body) - allowed))}.")


def _number(bad, column, value, lo=None, hi=None, *, integer=False, positive=False):
    """A finite number (or whole number) in range, or a DataError naming the key."""
    ok = isinstance(value, int | float) and not isinstance(value, bool) and \
        math.isfinite(value) and (not integer or float(value).is_integer())
    rng_txt = (f" from {lo:g}" if lo is not None else "") + (
        f" to {hi:g}" if hi is not None and lo is not None else
        f" and at most {hi:g}" if hi is not None else "")
    what = ("a whole number" if integer else "a number greater than 0" if positive
            else "a finite number") + rng_txt
    if not ok or (positive and value <= 0) or (lo is not None and value < lo) or (
            hi is not None and value > hi):
        raise bad(column, f"expected {what}, found {_cut(value)}.")
    return int(value) if integer else float(value)


def _check_run(cfg, bad, number):
    """Seed, noise, timing, visiting order, probes per position and the setup's type."""
    top = {k: cfg.get(k, DEFAULT_CONFIG[k]) for k in DEFAULT_CONFIG}
    number("seed", top["seed"], 0, 2**63 - 1, integer=True)
    number("noise_um", top["noise_um"], 0, 1000)
    number("minutes_per_ball", top["minutes_per_ball"], positive=True, hi=1440)
    number("repeats", top["repeats"], 1, 100, integer=True)
    if top["order"] not in ("row", "serpentine", "random"):
        raise bad("order", f"expected 'row', 'serpentine' or 'random', found "
                  f"{_cut(top['order'])}.")
    if not isinstance(top["probes_interleaved"], bool):
        raise bad("probes_interleaved", f"expected true or false, found "
                  f"{_cut(top['probes_interleaved'])}.")
    ppp = cfg.get("probes_per_position")
    if ppp is not None and not isinstance(ppp, dict):
        raise bad("probes_per_position", f"expected an object position: [probes], found "
                  f"{_cut(ppp)}.")
    for pos, qs in (ppp or {}).items():
        if not isinstance(qs, list) or not qs or not all(
                isinstance(q, str | int) and not isinstance(q, bool) for q in qs):
            raise bad(f"probes_per_position.{pos}", f"expected a non-empty list of probe "
                      f"names, found {_cut(qs)}.")
    if top["setup"] is not None and not isinstance(top["setup"], dict):
        raise bad("setup", f"expected a setup object (or null for the thesis placements), "
                  f"found {type(top['setup']).__name__} {_cut(top['setup'])}.")


def _check_plate_config(cfg, bad, number):
    """The plate: at least 2 x 2 balls, a pitch, form and certificate uncertainty."""
    pl = {**DEFAULT_CONFIG["plate"], **(cfg.get("plate") or {})}
    rows = number("plate.rows", pl["rows"], 1, 100, integer=True)
    cols = number("plate.cols", pl["cols"], 1, 100, integer=True)
    if min(rows, cols) < 2:
        raise bad("plate.rows" if rows < 2 else "plate.cols", f"a plate of {rows} x {cols} "
                  "balls lies on one line; expected at least 2 rows and 2 columns (3 balls "
                  "off one line define the plate frame).")
    number("plate.pitch_mm", pl["pitch_mm"], 1.0, 5000.0)
    number("plate.form_um", pl["form_um"], 0, 1000)
    number("plate.certificate_u_um", pl["certificate_u_um"], 0, 1000)


def _check_kinematic_config(cfg, bad, number):
    """The true kinematic model: a spec, an order, random sizes and coefficients."""
    km = {**DEFAULT_CONFIG["kinematic"], **(cfg.get("kinematic") or {})}
    if not isinstance(km["spec"], str):
        raise bad("kinematic.spec", f"expected a model spec such as \"kinematic21\", found "
                  f"{_cut(km['spec'])}.")
    number("kinematic.order", km["order"], 1, MAX_ORDER, integer=True)
    number("kinematic.random_um", km["random_um"], 0, 1e4)
    number("kinematic.random_urad", km["random_urad"], 0, 1e4)
    if not isinstance(km["coefficients"], dict):
        raise bad("kinematic.coefficients", f"expected an object of label: value, found "
                  f"{_cut(km['coefficients'])}.")
    for lab, val in km["coefficients"].items():
        number(f"kinematic.coefficients.{lab}", val, -1e5, 1e5)


def _check_against_setup(cfg, setup, terms, name, own_ppp):
    """The parts of a configuration that name positions, probes or coefficient labels,
    checked against the setup and the model's terms (unknown names are refused: they
    would be dropped silently)."""
    def bad(column, message, hint=None):
        return DataError(message, file=name, column=column, hint=hint)

    def vector(column, v):
        if not (isinstance(v, list | tuple) and len(v) == 3 and all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                for x in v)):
            raise bad(column, f"expected 3 finite numbers (µm or µm/h), found {_cut(v)}.")

    def known(column, key, names, what):
        if str(key) not in names:
            close = difflib.get_close_matches(str(key), list(names), n=1, cutoff=0.6)
            raise bad(column, f"{what} {_cut(key)} is not in the setup (known: "
                      f"{_cut(', '.join(names), 200)})" + (f"; did you mean {close[0]!r}?"
                                                           if close else "."))

    positions, probes = list(setup.positions), list(setup.probes)
    # only the user's own entries: the default names the thesis positions, which a setup
    # of its own need not have
    ppp = own_ppp
    if ppp is not None and not isinstance(ppp, dict):
        raise bad("probes_per_position", f"expected an object position: [probes], found "
                  f"{_cut(ppp)}.")
    for pos, qs in (ppp or {}).items():
        known(f"probes_per_position.{pos}", pos, positions, "position")
        if not isinstance(qs, list) or not qs or not all(
                isinstance(q, str | int) and not isinstance(q, bool) for q in qs):
            raise bad(f"probes_per_position.{pos}", f"expected a non-empty list of probe "
                      f"names, found {_cut(qs)}.")
        for q in qs:
            known(f"probes_per_position.{pos}", q, probes, "probe")
    labels = terms.labels
    for lab in cfg["kinematic"]["coefficients"]:
        if lab not in labels:
            close = difflib.get_close_matches(str(lab), labels, n=3, cutoff=0.5)
            raise bad(f"kinematic.coefficients.{lab}", f"{_cut(lab)} is not a coefficient of "
                      f"the model {cfg['kinematic']['spec']!r} at order "
                      f"{cfg['kinematic']['order']}" + (f"; did you mean "
                                                        f"{' or '.join(map(repr, close))}?"
                                                        if close else "."),
                      hint="labels are function[order], e.g. dxx[1], rxy[2], sxy; a higher "
                           "order needs it in the spec, e.g. \"kinematic21,dyz:3\".")
    eff = cfg["effects"]
    for key, v in eff.get("probe_offset", {}).items():
        if key != "sd_um":
            known(f"effects.probe_offset.{key}", key, probes, "probe")
            vector(f"effects.probe_offset.{key}", v)
    for key, v in eff.get("drift", {}).items():
        if key != "sd_um_per_h":
            known(f"effects.drift.{key}", key, positions, "position")
            vector(f"effects.drift.{key}", v)
    temps = eff.get("plate_thermal", {}).get("temp_C")
    if temps is not None:
        if not isinstance(temps, dict):
            raise bad("effects.plate_thermal.temp_C", f"expected an object position: "
                      f"[start, finish] in °C, found {_cut(temps)}.")
        for pos, t in temps.items():
            col = f"effects.plate_thermal.temp_C.{pos}"
            known(col, pos, positions, "position")
            if not (isinstance(t, list) and len(t) == 2 and all(
                    isinstance(x, int | float) and not isinstance(x, bool) for x in t)):
                raise bad(col, f"expected [start, finish] in °C, found {_cut(t)}.")
            _check_celsius(np.asarray(t, float), name, col)


def _check_plate_in_machine(setup, nominal, name):
    """Every ball of the simulated plate, in every position, inside the machine."""
    rng = np.asarray(setup.range_mm, float)
    tol = np.maximum(0.05 * rng, 100.0)
    for pos, pl in setup.positions.items():
        m = pl.to_machine(nominal)
        out = ((m < -tol) | (m > rng + tol)).any(axis=1)
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise DataError(f"ball {i + 1} of the plate reaches {np.round(m[i], 1).tolist()} "
                            f"mm in position {pos!r}, outside the machine's range "
                            f"{rng.tolist()} mm.", file=name, column="plate",
                            hint="use fewer balls or a smaller pitch_mm, or move the "
                                 "position's origin_mm.")


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


def _design(df, setup, plate) -> Observations:
    """The observations a simulated schedule makes, before any reading exists: what the
    fit's model needs to place every ball (``Problem.targets``)."""
    positions = list(dict.fromkeys(df["position"]))
    probes = list(dict.fromkeys(df["probe"]))
    pos = df["position"].map({p: i for i, p in enumerate(positions)}).to_numpy()
    prb = df["probe"].map({q: i for i, q in enumerate(probes)}).to_numpy()
    tm = df["time_min"].to_numpy(float)
    hours = np.zeros(len(df))
    for i in range(len(positions)):
        hours[pos == i] = (tm[pos == i] - tm[pos == i].mean()) / 60.0
    pnom = np.array([setup.probes[q] for q in probes], float)[prb]
    return Observations(
        df, np.zeros((len(df), 3)), pnom, pos, prb, df["ball"].to_numpy() - 1, positions,
        probes, np.arange(1, len(plate) + 1), plate, None,
        df["temp_C"].to_numpy(float) - 20.0, True, hours,
        np.array([setup.positions[p].horizontal for p in positions]),
        np.array([setup.positions[p].rotation for p in positions]),
        np.array([setup.positions[p].origin_mm for p in positions]),
        np.asarray(setup.range_mm, float), False, np.zeros((len(df), 3)))


def simulate(config: dict | None = None, *, name: str = "simulation config") -> Simulation:
    """Simulate a virtual CMM measuring a ball plate (see the module docstring).

    Parameters
    ----------
    config : dict, optional
        The configuration (see the module docstring); checked completely first.
    name : str
        Name of the configuration (its file) in error messages.

    Raises
    ------
    DataError
        Naming the key that is wrong, what was expected and, for a misspelt label,
        position or probe, the name it resembles.
    """
    config = {} if config is None else config
    _check_config(config, name)
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
    setup = read_setup(setup_raw, name=f"{name} (setup)")
    if not setup.probes:
        raise DataError("the setup defines no probes; expected at least one offset.",
                        file=name, column="setup.probes")
    _check_plate_in_machine(setup, nominal, name)
    positions = list(setup.positions)
    ppp = cfg["probes_per_position"] or {}
    probes_of = {p: [str(q) for q in ppp.get(p, [setup.positions[p].probe
                                                 or next(iter(setup.probes))])]
                 for p in positions}

    km = cfg["kinematic"]
    try:
        spec = parse_spec(km["spec"], default_order=int(km["order"]))
    except ValueError as exc:
        raise DataError(str(exc), file=name, column="kinematic.spec") from None
    terms = kin.KinematicTerms(spec.active, tuple(setup.range_mm), spec.periods)
    _check_against_setup(cfg, setup, terms, name, config.get("probes_per_position"))
    coef = np.zeros(terms.n)
    for i, lab in enumerate(terms.labels):
        sd = km["random_um"] if terms.unit(lab) == "um" else km["random_urad"]
        coef[i] = km["coefficients"].get(lab, rng.normal(0, sd) if sd else 0.0)
    truth = dict(zip(terms.labels, coef.tolist(), strict=True))

    eff = cfg["effects"]
    sim = SimContext(positions, [str(q) for q in setup.probes],
                     {p: (20.0, 20.0) for p in positions})
    for token, block in BY_TOKEN.items():
        if token in eff:
            truth.update(block.draw(eff[token], sim, rng))
    temps = sim.temps_C

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
                            j // (len(visit) * len(probes_of[p]))))
    df = pd.DataFrame(records, columns=["position", "probe", "ball", "time_min", "temp_C",
                                        "repeat"])
    for col, by_pos in sim.columns.items():
        # recorded like temp_C: start to finish over each position's measuring time
        df[col] = np.nan
        for p, (t0, t1) in by_pos.items():
            sel = (df["position"] == p).to_numpy()
            tm = df.loc[sel, "time_min"].to_numpy()
            df.loc[sel, col] = t0 + (t1 - t0) * (tm - tm[0]) / max(np.ptp(tm), 1e-9)
    # the fit's own model at the truth, inverted (see the module docstring)
    model = parse_spec(",".join([km["spec"], *(t for t in BY_TOKEN if t in eff)]),
                       default_order=int(km["order"]))
    prob = Problem(_design(df, setup, plate), model, "fixed")
    state = prob.initial_state()
    state.update(c=plate.copy(), R=prob.obs.R0.copy(), t=prob.obs.t0_mm.copy(),
                 x=np.array([truth.get(lab, 0.0) for lab in prob.layout.labels]))
    x = kin.invert(terms, coef, *prob.targets(state))
    if eff:
        # effects of the readings themselves (the approach direction of backlash, the
        # scale reading of machine_thermal) are known once the machine has moved: a
        # second inversion with the first readings (their change is below 1e-9 mm)
        prob = Problem(replace(prob.obs, r_mm=x + prob.obs.p_mm,
                               approach=approach_directions(x)), model, "fixed")
        x = kin.invert(terms, coef, *prob.targets(state))
    pnom = prob.obs.p_mm
    r = x + pnom + rng.normal(0, cfg["noise_um"], x.shape) * 1e-3
    df["x_mm"], df["y_mm"], df["z_mm"] = r.T
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

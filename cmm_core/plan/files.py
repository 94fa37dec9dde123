"""Plan files: read and check ``PLAN.json`` (format in ``docs/planning.md``).

A plan file holds one setup (machine, placements, styli), the plate, the model, the
noise and the measurement order and timing shared by its strategies, the strategies to
compare (each a set of placements with their styli, optionally with its own noise and
measurement settings) and an optional ``design`` section (``designer``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..diagnosis import FAMILY_ALPHA
from ..io import DataError, Setup, read_json, read_setup, refuse_unknown_keys
from ..io.errors import cut_repr
from ..model import MAX_ORDER, PLATE_MODES, check_repeat_at_end, parse_spec
from .designer import DesignResult, design
from .evaluation import evaluate
from .plans import Plan, _build

TOP_KEYS = ("name", "setup", "plate", "model", "noise_um", "measurement", "strategies",
            "design", "seed", "provenance")
"""The plan file's keys; ``provenance`` (what wrote the file, ``next --plan-out``) is
kept for the reader of the file and not used by the plan."""
PLATE_DEFAULTS = {"rows": 5, "cols": 5, "pitch_mm": 133.0, "certificate_u_um": 0.13,
                  "geometry": "fixed"}
_MIN_PRIOR = 0.01
"""Smallest expected size of the kinematic coefficients (µm, µrad) a plan may state:
a CMM's errors are tens of nanometres at the least."""
MODEL_DEFAULTS = {"spec": "kinematic21", "order": 2, "prior_um": 1.0, "prior_urad": 1.0,
                  "alpha": FAMILY_ALPHA, "periods_mm": {}, "expected": {}}
MEASUREMENT_DEFAULTS = {"order": "row", "probes_interleaved": False, "repeats": 1,
                        "minutes_per_ball": 0.5, "minutes_per_placement": 10.0}
STRATEGY_KEYS = ("name", "placements", "noise_um", "measurement", "repeat_at_end")


@dataclass(frozen=True)
class PlanFile:
    """A plan file read and checked.

    Attributes
    ----------
    strategies : list of Plan
        The strategies to evaluate side by side.
    base : Plan
        Every placement of the setup with its default stylus (the pool's geometry).
    design : dict or None
        The ``design`` section (pool, target, criterion), checked by ``designer``.
    name : str
        File name for messages.
    """

    strategies: list
    base: Plan
    design: dict | None
    name: str


def _bad(name, column, message, hint=None):
    return DataError(message, file=name, column=column, hint=hint)


def _number(name, column, value, lo, hi, *, integer=False):
    ok = isinstance(value, int | float) and not isinstance(value, bool) and np.isfinite(
        value) and lo <= value <= hi and (not integer or float(value).is_integer())
    if not ok:
        what = "a whole number" if integer else "a number"
        raise _bad(name, column, f"expected {what} from {lo:g} to {hi:g}, found "
                   f"{cut_repr(value)}.")
    return int(value) if integer else float(value)


def _section(raw, key, defaults, name, prefix=""):
    val = raw.get(key, {})
    if not isinstance(val, dict):
        raise _bad(name, prefix + key, f"expected a JSON object, found {cut_repr(val)}.")
    refuse_unknown_keys(val, sorted(defaults), name, f"{prefix}{key}.")
    return {**copy.deepcopy(defaults), **val}


def _check_measurement(m, name, prefix):
    if m["order"] not in ("row", "serpentine", "random"):
        raise _bad(name, prefix + ".order", f"expected 'row', 'serpentine' or 'random', "
                   f"found {cut_repr(m['order'])}.")
    if not isinstance(m["probes_interleaved"], bool):
        raise _bad(name, prefix + ".probes_interleaved",
                   f"expected true or false, found {cut_repr(m['probes_interleaved'])}.")
    m["repeats"] = _number(name, prefix + ".repeats", m["repeats"], 1, 100, integer=True)
    m["minutes_per_ball"] = _number(name, prefix + ".minutes_per_ball",
                                    m["minutes_per_ball"], 1e-3, 1440)
    m["minutes_per_placement"] = _number(name, prefix + ".minutes_per_placement",
                                         m["minutes_per_placement"], 0, 1440)
    return m


def _plan_setup(raw, name, base_dir):
    """The plan's machine and placements, ``(raw dict, Setup)``: a setup object or a file
    read relative to the plan, always in the machine frame (a plan places the plate: no
    tables are read)."""
    if "setup" not in raw:
        raise _bad(name, "setup", "missing: expected the machine and its placements (a "
                   "setup object, or the name of a setup file).")
    setup_raw = raw["setup"]
    if isinstance(setup_raw, str):
        path = base_dir / setup_raw
        try:
            setup_raw, _ = read_json(path)
        except DataError as exc:
            raise _bad(name, "setup", f"cannot read the setup file {str(path)!r}: "
                       f"{exc.detail}", hint="a setup file name is read relative to the "
                       "plan file.") from None
    if not isinstance(setup_raw, dict):
        raise _bad(name, "setup", f"expected a setup object or file name, found "
                   f"{cut_repr(setup_raw)}.")
    setup_raw = copy.deepcopy(setup_raw)
    setup_raw["frame"] = "machine"
    return setup_raw, read_setup(setup_raw, name=f"{name} (setup)")


def _plan_plate(raw, name):
    """The plate section: rows, columns, pitch, certificate u and the geometry mode."""
    plate = _section(raw, "plate", PLATE_DEFAULTS, name)
    plate["rows"] = _number(name, "plate.rows", plate["rows"], 2, 100, integer=True)
    plate["cols"] = _number(name, "plate.cols", plate["cols"], 2, 100, integer=True)
    plate["pitch_mm"] = _number(name, "plate.pitch_mm", plate["pitch_mm"], 1, 5000)
    plate["certificate_u_um"] = _number(name, "plate.certificate_u_um",
                                        plate["certificate_u_um"], 1e-3, 1000)
    if plate["geometry"] not in PLATE_MODES:
        raise _bad(name, "plate.geometry", f"expected one of {list(PLATE_MODES)}, found "
                   f"{cut_repr(plate['geometry'])}.")
    return plate


def _plan_model(raw, name):
    """The expected error model: spec, order, prior sizes, level, periods, expected sizes."""
    model = _section(raw, "model", MODEL_DEFAULTS, name)
    model["order"] = _number(name, "model.order", model["order"], 1, MAX_ORDER, integer=True)
    try:
        parse_spec(str(model["spec"]), default_order=model["order"])
    except ValueError as exc:
        raise _bad(name, "model.spec", str(exc)) from None
    for k in ("prior_um", "prior_urad"):
        # the expected size of a CMM's errors: 0 would say the machine is perfect, and the
        # simulations and the designer's weights would be void (the designer took 0 for 1)
        model[k] = _number(name, f"model.{k}", model[k], _MIN_PRIOR, 1e4)
    model["alpha"] = _number(name, "model.alpha", model["alpha"], 1e-6, 0.5)
    per = model["periods_mm"]
    if not isinstance(per, dict) or set(per) - set("xyz"):
        raise _bad(name, "model.periods_mm", f"expected an object axis (x, y, z): period "
                   f"in mm, found {cut_repr(per)}.")
    model["periods_mm"] = {a: _number(name, f"model.periods_mm.{a}", v, 1, 1e5)
                           for a, v in per.items()}
    exp = model["expected"]
    if not isinstance(exp, dict):
        raise _bad(name, "model.expected", f"expected an object effect: expected size (in "
                   f"the effect's unit), found {cut_repr(exp)}.")
    for k in exp:  # an effect of the catalogue (a misspelt one would read "not detectable")
        try:
            parse_spec(f"{model['spec']},{k}", default_order=model["order"])
        except ValueError as exc:
            raise _bad(name, f"model.expected.{k}", str(exc)) from None
    model["expected"] = {str(k): _number(name, f"model.expected.{k}", v, 0, 1e6)
                         for k, v in exp.items()}
    return model


def read_plan(source: str | Path | bytes | dict, *, name: str | None = None,
              base_dir: str | Path | None = None) -> PlanFile:
    """Read a plan file (path, JSON text, bytes or an already parsed dict) and check it.

    A ``setup`` given as a file name is read relative to the plan file (or to
    ``base_dir`` for text and dicts; default the working directory). Every refusal is a
    :class:`~cmm_core.io.DataError` naming the file and the key (``plate.rows``), what
    was expected and what was found.
    """
    base_dir = Path(base_dir or ".")
    if isinstance(source, dict):
        raw, name = source, name or "plan"
    else:
        if isinstance(source, str | Path) and not str(source).lstrip().startswith("{"):
            base_dir = Path(source).resolve().parent
        raw, name = read_json(source, name)
    if not isinstance(raw, dict):
        raise _bad(name, None, f"expected a JSON object with some of {list(TOP_KEYS)}, "
                   f"found {type(raw).__name__}.")
    refuse_unknown_keys(raw, TOP_KEYS, name)
    setup_raw, setup = _plan_setup(raw, name, base_dir)
    plate = _plan_plate(raw, name)
    model = _plan_model(raw, name)
    noise = _number(name, "noise_um", raw.get("noise_um", 0.5), 1e-4, 1000)
    meas = _check_measurement(_section(raw, "measurement", MEASUREMENT_DEFAULTS, name),
                              name, "measurement")
    seed = _number(name, "seed", raw.get("seed", 0), 0, 2**32 - 1, integer=True)
    default_probe = next(iter(setup.probes), None)
    if default_probe is None:
        raise _bad(name, "setup.probes", "no probes defined; expected at least one stylus "
                   "offset (mm).")
    everything = {p: (pl.probe or default_probe,) for p, pl in setup.positions.items()}
    proto = Plan(str(raw.get("name", "plan")), setup_raw, everything, plate, model, noise,
                 meas, seed)
    base = _build(proto, everything, proto.name)
    strategies = []
    items = raw.get("strategies", [{"name": proto.name}])
    if not isinstance(items, list) or not items:
        raise _bad(name, "strategies", f"expected a non-empty list of strategies, found "
                   f"{cut_repr(items)}.")
    for i, st in enumerate(items):
        where = f"strategies[{i}]"
        if not isinstance(st, dict):
            raise _bad(name, where, f"expected an object with some of {list(STRATEGY_KEYS)}, "
                       f"found {cut_repr(st)}.")
        refuse_unknown_keys(st, STRATEGY_KEYS, name, f"{where}.")
        units = units_of(st.get("placements", list(everything)), setup, everything,
                         name, f"{where}.placements")
        m = _check_measurement(_section(st, "measurement", meas, name, f"{where}."), name,
                               f"{where}.measurement")
        again = check_repeat_at_end(
            st.get("repeat_at_end", {}), f"{where}.repeat_at_end",
            lambda col, msg, hint=None: _bad(name, col, msg, hint),
            styli={p: list(q) for p, q in units.items()},
            n_balls=int(plate["rows"]) * int(plate["cols"]))
        p = Plan(str(st.get("name", f"strategy {i + 1}")), setup_raw, units, plate, model,
                 _number(name, f"{where}.noise_um", st.get("noise_um", noise), 1e-4, 1000),
                 m, seed)
        strategies.append(_build(p, units, p.name, again))
    names = [s.name for s in strategies]
    if len(set(names)) != len(names):
        raise _bad(name, "strategies", f"strategy names must differ, found {names}.")
    design = raw.get("design")
    if design is not None and not isinstance(design, dict):
        raise _bad(name, "design", f"expected an object (pool, target, criterion), found "
                   f"{cut_repr(design)}.")
    return PlanFile(strategies, base, design, name)


def units_of(spec: list | dict, setup: Setup, defaults: dict, name: str,
             column: str) -> dict:
    """Placements and styli of a strategy: a list of placement names (each with its
    setup stylus) or an object placement: [styli]; every name checked against the setup."""
    if isinstance(spec, list):
        for i, p in enumerate(spec):
            if not isinstance(p, str):  # a list or object is no placement name
                raise _bad(name, f"{column}[{i}]", f"expected a placement name, found "
                           f"{cut_repr(p)}.")
        spec = {p: list(defaults.get(p, ())) for p in spec}
    if not isinstance(spec, dict) or not spec:
        raise _bad(name, column, f"expected a non-empty list of placements or an object "
                   f"placement: [styli], found {cut_repr(spec)}.")
    out = {}
    for pos, qs in spec.items():
        if pos not in setup.positions:
            raise _bad(name, f"{column}.{pos}", f"placement {cut_repr(pos)} is not in the setup "
                       f"(known: {', '.join(setup.positions)}).")
        if isinstance(qs, str):
            qs = [qs]
        if not isinstance(qs, list) or not qs:
            raise _bad(name, f"{column}.{pos}", f"expected a non-empty list of styli, found "
                       f"{cut_repr(qs)}.")
        for q in qs:
            if str(q) not in setup.probes:
                raise _bad(name, f"{column}.{pos}", f"stylus {cut_repr(q)} is not among the "
                           f"setup's probes {sorted(setup.probes)}.")
        out[str(pos)] = tuple(dict.fromkeys(str(q) for q in qs))
    return out


def evaluate_file(pf: PlanFile, *, detection: bool = True) -> dict:
    """``{"strategies": [...]}``: every strategy of a plan file, evaluated."""
    return {"strategies": [evaluate(p, detection=detection).to_dict()
                           for p in pf.strategies]}


def read_design(section: dict, base: Plan, name: str) -> dict:
    """Check a plan file's ``design`` section; returns keyword arguments of :func:`design`.
    """
    known = ("pool", "target", "criterion", "name", "random_plans", "restarts", "seed")
    refuse_unknown_keys(section, known, name, "design.")
    setup = read_setup(base.setup, name=name)
    defaults = {p: (pl.probe or next(iter(setup.probes)),) for p, pl in
                setup.positions.items()}
    pool = units_of(section.get("pool", list(defaults)), setup, defaults, name, "design.pool")
    target = section.get("target")
    if not isinstance(target, dict) or not target:
        raise DataError(f"expected an object with some of determined, U3_um, detect, found "
                        f"{cut_repr(target)}.", file=name, column="design.target")
    bad = sorted(set(target) - {"determined", "U3_um", "detect"})
    if bad:
        raise DataError(f"unknown target {bad[0]!r}; expected determined, U3_um or detect.",
                        file=name, column=f"design.target.{bad[0]}")
    if "U3_um" in target and not (isinstance(target["U3_um"], int | float)
                                  and not isinstance(target["U3_um"], bool)
                                  and 0 < target["U3_um"] < 1e4):
        raise DataError(f"expected a positive U3 in µm, found {cut_repr(target['U3_um'])}.",
                        file=name, column="design.target.U3_um")
    det = target.get("detect", {})
    if not isinstance(det, dict) or not all(isinstance(v, int | float) and v > 0
                                            for v in det.values()):
        raise DataError(f"expected an object effect: size (in the effect's unit), found "
                        f"{cut_repr(det)}.", file=name, column="design.target.detect")
    crit = section.get("criterion", "D")
    if crit not in ("D", "A"):
        raise DataError(f"expected 'D' or 'A', found {cut_repr(crit)}.", file=name,
                        column="design.criterion")
    n = section.get("random_plans", 20)
    if not isinstance(n, int) or isinstance(n, bool) or not 0 <= n <= 1000:
        raise DataError(f"expected a whole number 0-1000, found {cut_repr(n)}.", file=name,
                        column="design.random_plans")
    r = section.get("restarts", 20)
    if not isinstance(r, int) or isinstance(r, bool) or not 0 <= r <= 1000:
        raise DataError(f"expected a whole number 0-1000, found {cut_repr(r)}.", file=name,
                        column="design.restarts")
    return {"pool": pool, "target": target, "criterion": crit, "n_random": n, "restarts": r,
            "seed": int(section.get("seed", 0)), "name": str(section.get("name", "designed"))}


def design_from_file(pf: PlanFile) -> DesignResult:
    """Run the ``design`` section of a read plan file (:func:`read_plan`); returns the
    :class:`~cmm_core.plan.DesignResult`."""
    if pf.design is None:
        raise DataError("has no 'design' section to run; add one (pool, target) or "
                        "evaluate the plan's strategies instead.", file=pf.name)
    kw = read_design(pf.design, pf.base, pf.name)

    return design(pf.base, **kw)

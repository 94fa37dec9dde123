"""The simulator's configuration: its defaults and its checks.

Every problem is a ``DataError`` naming the key (``plate.rows``) and what was expected:
unknown keys, effects, labels, positions and probes are refused (a typo would silently
hide an effect), numbers must be finite and in range. Each effect block declares the keys
and ranges it accepts (``Block.sim_keys``, ``Block.sim_ranges``) and checks the names and
values it reads against the setup (``Block.check_sim``).
"""

from __future__ import annotations

import difflib
import math

import numpy as np

from ..io import ARTEFACTS, DataError, range_tolerance, refuse_unknown_keys
from ..io.errors import cut_repr
from .blocks import BY_TOKEN
from .blocks.simulation import SimCheck, SimulatorEffect
from .effects import MAX_ORDER

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
    "repeat_at_end": {},
    "artefact": None,
}
"""``artefact`` None: the setup's (``io.setup.ARTEFACTS``; a ball plate unless the setup
says otherwise); ``"hole_plate"`` simulates the plate's features as holes."""


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

    _check_keys(cfg, bad, name)
    _check_run(cfg, bad, number)
    _check_plate_config(cfg, bad, number)
    _check_kinematic_config(cfg, bad, number)
    for token, body in (cfg.get("effects") or {}).items():
        for k, (lo, hi) in BY_TOKEN[token].sim_ranges.items():
            if k in body:
                number(f"effects.{token}.{k}", body[k], lo, hi)


def _check_keys(cfg, bad, name):
    """The configuration's shape: known keys and sections, known effects and their keys."""
    if not isinstance(cfg, dict):
        raise bad(None, f"expected a JSON object with some of {sorted(DEFAULT_CONFIG)}, "
                  f"found {type(cfg).__name__} {cut_repr(cfg)}.")
    refuse_unknown_keys(cfg, sorted(DEFAULT_CONFIG), name)
    for sect in ("plate", "kinematic", "effects"):
        if sect in cfg and not isinstance(cfg[sect], dict):
            raise bad(sect, f"expected a JSON object for {sect!r}, found "
                      f"{type(cfg[sect]).__name__} {cut_repr(cfg[sect])}.")
    for sect in ("plate", "kinematic"):
        refuse_unknown_keys(cfg.get(sect) or {}, sorted(DEFAULT_CONFIG[sect]), name, f"{sect}.")
    for key, body in (cfg.get("effects") or {}).items():
        if key not in _EFFECT_KEYS:
            raise bad(f"effects.{key}", f"unknown effect {cut_repr(key)}; expected one of "
                      f"{sorted(_EFFECT_KEYS)}.")
        if not isinstance(body, dict):
            raise bad(f"effects.{key}", f"expected a JSON object of the effect's values, "
                      f"found {type(body).__name__} {cut_repr(body)}.",
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
        raise bad(column, f"expected {what}, found {cut_repr(value)}.")
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
                  f"{cut_repr(top['order'])}.")
    if not isinstance(top["probes_interleaved"], bool):
        raise bad("probes_interleaved", f"expected true or false, found "
                  f"{cut_repr(top['probes_interleaved'])}.")
    ppp = cfg.get("probes_per_position")
    if ppp is not None and not isinstance(ppp, dict):
        raise bad("probes_per_position", f"expected an object position: [probes], found "
                  f"{cut_repr(ppp)}.")
    for pos, qs in (ppp or {}).items():
        if not isinstance(qs, list) or not qs or not all(
                isinstance(q, str | int) and not isinstance(q, bool) for q in qs):
            raise bad(f"probes_per_position.{pos}", f"expected a non-empty list of probe "
                      f"names, found {cut_repr(qs)}.")
    if top["artefact"] is not None and top["artefact"] not in ARTEFACTS:
        raise bad("artefact", f"unknown artefact {cut_repr(top['artefact'])}; expected one of "
                  f"{', '.join(ARTEFACTS)} (or null for the setup's).")
    if top["setup"] is not None and not isinstance(top["setup"], dict):
        raise bad("setup", f"expected a setup object (or null for the thesis placements), "
                  f"found {type(top['setup']).__name__} {cut_repr(top['setup'])}.")


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
                  f"{cut_repr(km['spec'])}.")
    number("kinematic.order", km["order"], 1, MAX_ORDER, integer=True)
    number("kinematic.random_um", km["random_um"], 0, 1e4)
    number("kinematic.random_urad", km["random_urad"], 0, 1e4)
    if not isinstance(km["coefficients"], dict):
        raise bad("kinematic.coefficients", f"expected an object of label: value, found "
                  f"{cut_repr(km['coefficients'])}.")
    for lab, val in km["coefficients"].items():
        number(f"kinematic.coefficients.{lab}", val, -1e5, 1e5)


def _check_against_setup(cfg, setup, terms, name, own_ppp):
    """The parts of a configuration that name positions, probes or coefficient labels,
    checked against the setup and the model's terms (unknown names are refused: they
    would be dropped silently)."""
    positions, probes = list(setup.positions), list(setup.probes)
    check = SimCheck(name, tuple(positions), tuple(probes), terms.layout)
    bad, known = check.bad, check.known
    # only the user's own entries: the default names the thesis positions, which a setup
    # of its own need not have
    ppp = own_ppp
    if ppp is not None and not isinstance(ppp, dict):
        raise bad("probes_per_position", f"expected an object position: [probes], found "
                  f"{cut_repr(ppp)}.")
    for pos, qs in (ppp or {}).items():
        known(f"probes_per_position.{pos}", pos, positions, "position")
        if not isinstance(qs, list) or not qs or not all(
                isinstance(q, str | int) and not isinstance(q, bool) for q in qs):
            raise bad(f"probes_per_position.{pos}", f"expected a non-empty list of probe "
                      f"names, found {cut_repr(qs)}.")
        for q in qs:
            known(f"probes_per_position.{pos}", q, probes, "probe")
    # the styli the simulator measures each position with (virtual_cmm.simulate)
    ppp_all = cfg["probes_per_position"] or {}
    check_repeat_at_end(cfg["repeat_at_end"], "repeat_at_end", bad, styli={
        p: [str(q) for q in ppp_all.get(p, [])] or [str(setup.positions[p].probe or probes[0])]
        for p in positions}, n_balls=int(cfg["plate"]["rows"]) * int(cfg["plate"]["cols"]))
    labels = terms.labels
    for lab in cfg["kinematic"]["coefficients"]:
        if lab not in labels:
            close = difflib.get_close_matches(str(lab), labels, n=3, cutoff=0.5)
            raise bad(f"kinematic.coefficients.{lab}", f"{cut_repr(lab)} is not a coefficient of "
                      f"the model {cfg['kinematic']['spec']!r} at order "
                      f"{cfg['kinematic']['order']}" + (f"; did you mean "
                                                        f"{' or '.join(map(repr, close))}?"
                                                        if close else "."),
                      hint="labels are function[order], e.g. dxx[1], rxy[2], sxy; a higher "
                           "order needs it in the spec, e.g. \"kinematic21,dyz:3\".")
    # each effect checks the names and values its block reads (Block.check_sim)
    for token, body in cfg["effects"].items():
        BY_TOKEN[token].check_sim(body, f"effects.{token}", check)


def check_repeat_at_end(spec, column: str, bad, *, styli: dict, n_balls: int) -> dict:
    """Balls measured once more on a placement after its own readings (a simulation
    config's or a plan strategy's ``repeat_at_end``): placement -> ``{"probe": stylus,
    "balls": [numbers]}``, each placement one of ``styli`` (placement -> the styli it is
    measured with), the stylus one of its, each ball on the plate of ``n_balls`` and named
    once; optional ``time_min`` (one time per ball, minutes: when each is read, e.g. in
    the next session after every placement, ``plan.proposals``' repeats; default right
    after the placement's last reading) and ``setup_min`` (minutes to set the plate up
    again before them; default 0: the plate not moved). Returns it with the stylus as
    text; ``bad(column, message, hint=None)`` makes the refusal."""
    if not isinstance(spec, dict):
        raise bad(column, f"expected an object placement: {{\"probe\": stylus, "
                  f"\"balls\": [numbers]}}, found {cut_repr(spec)}.")
    out: dict[str, dict] = {}
    for pos, body in spec.items():
        where = f"{column}.{pos}"
        if pos not in styli:
            raise bad(where, f"placement {cut_repr(pos)} is not among those measured "
                      f"({', '.join(styli)}).")
        if not isinstance(body, dict) or not {"probe", "balls"} <= set(map(str, body)) \
                or not set(map(str, body)) <= {"probe", "balls", "time_min", "setup_min"}:
            raise bad(where, f"expected an object with the keys probe and balls (and "
                      f"optionally time_min, setup_min), found {cut_repr(body)}.")
        q, balls = body["probe"], body["balls"]
        if isinstance(q, bool) or not isinstance(q, str | int) or str(q) not in styli[pos]:
            raise bad(f"{where}.probe", f"stylus {cut_repr(q)} is not among the styli "
                      f"{pos} is measured with ({', '.join(styli[pos])}).",
                      hint="repeat a ball with a stylus the placement is measured with.")
        if not isinstance(balls, list) or not balls or not all(
                isinstance(b, int) and not isinstance(b, bool) and 1 <= b <= n_balls
                for b in balls):
            raise bad(f"{where}.balls", f"expected a non-empty list of ball numbers from 1 "
                      f"to {n_balls}, found {cut_repr(balls)}.")
        if len(set(balls)) != len(balls):
            raise bad(f"{where}.balls", f"expected distinct ball numbers (each repeated "
                      f"once at the end), found {cut_repr(balls)}.")
        out[str(pos)] = {"probe": str(q), "balls": list(balls)}
        times = body.get("time_min")
        if times is not None:
            if not isinstance(times, list) or len(times) != len(balls) or not all(
                    isinstance(t, int | float) and not isinstance(t, bool)
                    and np.isfinite(t) and t >= 0 for t in times):
                raise bad(f"{where}.time_min", f"expected one time in minutes (at least "
                          f"0) per ball, {len(balls)}, found {cut_repr(times)}.")
            out[str(pos)]["time_min"] = [float(t) for t in times]
        setup = body.get("setup_min")
        if setup is not None:
            if isinstance(setup, bool) or not isinstance(setup, int | float) \
                    or not np.isfinite(setup) or setup < 0:
                raise bad(f"{where}.setup_min", f"expected the minutes (at least 0) to set "
                          f"the plate up again, found {cut_repr(setup)}.")
            out[str(pos)]["setup_min"] = float(setup)
    return out


def _check_plate_in_machine(setup, nominal, name, probes_per_position=None):
    """Every ball of the simulated plate, in every position, within reach of the machine:
    the scale reading (tip minus probe offset) of every stylus used there inside the
    strokes, as the reader checks measured points (``io.matching``)."""
    rng = np.asarray(setup.range_mm, float)
    tol = range_tolerance(rng)
    for pos, pl in setup.positions.items():
        m = pl.to_machine(nominal)
        used = (probes_per_position or {}).get(pos) or list(setup.probes)
        out = np.zeros(len(m), bool)
        for q in used:
            c = m - setup.probes[q] if q in setup.probes else m
            out |= ((c < -tol) | (c > rng + tol)).any(axis=1)
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise DataError(f"ball {i + 1} of the plate reaches {np.round(m[i], 1).tolist()} "
                            f"mm in position {pos!r}, outside the machine's range "
                            f"{rng.tolist()} mm.", file=name, column="plate",
                            hint="use fewer balls or a smaller pitch_mm, or move the "
                                 "position's origin_mm.")


def simulator_effects() -> list:
    """The hidden effects a simulator panel offers, one
    :class:`blocks.simulation.SimulatorEffect` per block with a
    :attr:`~blocks.base.Block.sim_label`, in ``blocks.REGISTRY`` order: draw a checkbox
    ``label`` (tooltip ``help``) and, when ticked, one number input per ``params`` entry
    (label, default, range, step); ``effect.config(values)`` is then the
    ``effects.<token>`` body of the configuration."""
    return [SimulatorEffect(token, b.sim_label, b.sim_help, tuple(b.sim_params),
                            dict(b.sim_fixed))
            for token, b in BY_TOKEN.items() if b.sim_label]

"""The candidate measurements of "measure next" (:class:`NextMeasurement`), generated from
the data set's own setup and machine range: the plate shifted, moved to the ends of the
strokes, raised, rotated in its plane or stood up; new styli; the styli in reverse order;
repeats at the end of placements whose styli were measured in blocks; and instruments (a
laser, a step gauge, a ball bar). Each carries its machine time from the plan's time model
(``files.MEASUREMENT_DEFAULTS``: minutes per ball and per placement). The plate is the
data's, a regular grid read from its certificate (:func:`plate_grid`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ...io import DataError, Dataset
from ..files import MEASUREMENT_DEFAULTS

SHIFT_FRACTION = 0.5
"""Default fraction of the ball pitch by which the plate is shifted."""

STYLUS_OFFSET_MM = 60.0
"""Lateral offset (mm) of the extra styli proposed."""

REPEAT_BALLS = (4, 12)
"""Balls a stylus is measured again on at the end of a placement (:func:`repeat_candidates`):
a few, and more for a small drift."""

FAMILIES = {
    "placement": "the plate moved, shifted, raised or turned in its plane",
    "orientation": "a second plate orientation (the plate stood in XZ or YZ)",
    "stylus": "another stylus offset sideways",
    "stylus_length": "another stylus length",
    "order": "the styli in reverse order",
    "repeat": "a repeat of a placement (appended to the current one, or in the next session)",
    "instrument": "instrument runs (a laser, a step gauge, a ball bar: next --instruments)",
}
"""Family of a candidate (:attr:`NextMeasurement.family`) -> the family in words: what a
conclusion names when no candidate decides and a family was not searched."""

WIDER = ("instrument", "stylus_length", "orientation")
"""Families that may decide what the plate moved in its plane cannot (they see other
error functions): named when nothing decides and they were not searched."""


@dataclass(frozen=True)
class NextMeasurement:
    """One extra measurement: a plate placement measured with some styli.

    Attributes
    ----------
    name : str
        Short key (``shift_y``, ``rot90``, ``xz``, ``stylus_x``, ...).
    description : str
        The measurement in words ("the plate of H0 shifted 40 mm along Y").
    positions : dict
        New placement name -> placement in the setup format (machine frame).
    probes : dict
        Stylus name -> offset (mm) for styli the data set does not have yet.
    probes_of : dict
        New placement name -> list of stylus names measured there, in order.
    time_min : float
        Machine time in minutes (balls × styli × minutes per ball + minutes per
        placement; ``files.MEASUREMENT_DEFAULTS``; an instrument: its readings × minutes
        per ball + minutes per placement for setting it up).
    instrument : dict
        For an instrument instead of the plate: ``kind`` (``laser``, ``step_gauge``,
        ``ball_bar``) and the keywords of its simulator (``simulate_laser``, ...) but the
        simulation; empty for a plate placement.
    repeat : dict
        For a repeat of placements already measured (:func:`repeat_candidates`):
        placement -> ``{"probe": stylus, "balls": [...], "time_min": [...], "setup_min":
        minutes, "session": "current" | "next"}``, the stylus measured again on those
        balls at those times, all after the data's last reading: appended to the current
        placement (still set up, ``setup_min`` 0) or in the next session, the plate set up
        again at that placement (``setup_min`` to set it up; taken at the same pose);
        ``positions`` is then empty.
    family : str
        The kind of measurement, a key of :data:`FAMILIES` (``placement``,
        ``orientation``, ``stylus``, ``stylus_length``, ``order``, ``repeat``,
        ``instrument``): which families a ranking searched.
    """

    name: str
    description: str
    positions: dict
    probes: dict
    probes_of: dict
    time_min: float
    instrument: dict = field(default_factory=dict)
    repeat: dict = field(default_factory=dict)
    family: str = "placement"


@dataclass(frozen=True)
class PlateGrid:
    """The plate as a regular grid, read from the certificate.

    Attributes
    ----------
    rows, cols : int
        Balls per column and per row (ball ``b`` at column ``(b-1) % cols``).
    pitch_mm : float
        Ball spacing in mm.
    offset_mm : ndarray (B, 3)
        Certificate minus nominal grid (mm), both relative to ball 1.
    """

    rows: int
    cols: int
    pitch_mm: float
    offset_mm: np.ndarray = field(repr=False)


def plate_grid(data: Dataset) -> PlateGrid:
    """Rows, columns and pitch of the data's plate from its certificate.

    Raises
    ------
    DataError
        When there is no certificate or the balls are not a row-major regular grid.
    """
    cert = data.certificate
    if cert is None:
        raise DataError("the data set has no certificate; expected one giving the plate's "
                        "ball centres.", file=data.name, column="certificate",
                        hint="load the plate's certificate: proposals simulate the same plate")
    xyz = np.asarray(cert.xyz_mm, float)
    xyz = xyz - xyz[0]
    d = np.linalg.norm(xyz[1:] - xyz[0], axis=1)
    pitch = float(d.min()) if d.size else 0.0
    cols = int(np.sum(np.abs(xyz[:, 1]) < 0.25 * pitch)) if pitch > 0 else 0
    rows = len(xyz) // max(cols, 1)
    ok = pitch > 0 and rows * cols == len(xyz) and cols > 1
    if ok:
        # the nominal pitch (0.1 mm): the certificate's departure from it is carried in
        # ``offset_mm`` and moves the simulated readings onto the certified balls
        pitch = round(float(np.median(np.linalg.norm(np.diff(xyz[:cols], axis=0), axis=1))),
                      1)
        b = np.arange(len(xyz))
        nominal = np.column_stack([b % cols * pitch, b // cols * pitch, np.zeros(len(xyz))])
        off = xyz - nominal
        ok = bool(np.abs(off).max() < 0.25 * pitch)
    if not ok:
        raise DataError(f"the certificate's {len(xyz)} balls are not a row-major regular "
                        f"grid; expected ball b at column (b-1) % cols, found pitch "
                        f"{pitch:.3g} mm and {cols} balls in the first row.",
                        file=data.name, column="certificate",
                        hint="proposals need a ball plate with a regular grid")
    return PlateGrid(rows, cols, pitch, off)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def styli_at(data: Dataset, placement: str) -> list[str]:
    """The styli measured at ``placement``, in the order first measured: read from the
    measurement rows, as the fit reads them, so that a setup naming the stylus on each row
    (no ``probe`` per placement) is handled as one naming it per placement; else the
    placement's own ``probe``; else the setup's first stylus."""
    m = data.meas
    rows = m.loc[m["position"].astype(str) == str(placement), "probe"]
    styli = [str(q) for q in dict.fromkeys(rows.dropna())]
    if styli:
        return styli
    own = data.setup.raw["positions"][placement].get("probe")
    return [str(own)] if own is not None else [str(next(iter(data.setup.raw["probes"])))]


def _placement_time(n_balls: int, n_probes: int, minutes_per_ball: float,
                    minutes_per_placement: float) -> float:
    """``Plan.time_min`` for one placement (a Plan needs a full plan to be built)."""
    return float(n_balls * n_probes * minutes_per_ball + minutes_per_placement)


def measurement_candidates(data: Dataset, *, reference: str | None = None,
                           shift_fraction: float = SHIFT_FRACTION,
                           stylus_offset_mm: float = STYLUS_OFFSET_MM,
                           minutes_per_ball: float | None = None,
                           minutes_per_placement: float | None = None,
                           repeat_balls: int | Sequence[int] = REPEAT_BALLS,
                           ) -> list[NextMeasurement]:
    """The default candidate measurements for a data set.

    From a reference placement (default: the first horizontal one): the plate shifted
    along X, Y by ``shift_fraction`` of its pitch, moved to the low and the high end of the
    X and Y strokes (every stylus's scale reading 5 % from each end), raised (or lowered) by a third of the
    Z stroke; rotated 90° and 180° in its plane about its centre; stood in XZ and in YZ;
    measured again with a stylus offset ``stylus_offset_mm`` along X, along Y, and a
    stylus 100 mm longer; and, with two styli or more, measured again with its styli in
    reverse order; and where styli were measured in blocks, the first stylus measured
    again on such a placement after the data's last reading (:func:`repeat_candidates`,
    on ``repeat_balls`` balls: appended to the current placement, or in the next
    session). Each new placement is measured with the reference's styli (the new
    stylus alone for a stylus candidate). Candidates outside the machine are dropped by
    :func:`propose` (with the reason). Machine time: the plan's time model
    (``Plan.time_min``), minutes per ball and per placement defaulting to
    ``files.MEASUREMENT_DEFAULTS``.
    """
    grid = plate_grid(data)
    defaults: dict = MEASUREMENT_DEFAULTS
    per_ball = float(defaults["minutes_per_ball"] if minutes_per_ball is None
                     else minutes_per_ball)
    per_place = float(defaults["minutes_per_placement"] if minutes_per_placement is None
                      else minutes_per_placement)
    raw = data.setup.raw
    pos = raw["positions"]
    if reference is None:
        reference = next((p for p in pos if data.setup.positions[p].horizontal), next(iter(pos)))
    if reference not in pos:
        raise DataError(f"unknown placement {reference!r}; expected one of {sorted(pos)}.",
                        file=data.name, column="reference", hint="name a placement of the setup")
    ref = pos[reference]
    o = np.asarray(ref["origin_mm"], float)
    u, v = _unit(ref["u_axis"]), _unit(ref["v_axis"])
    styli = styli_at(data, reference)
    half = np.array([(grid.cols - 1), (grid.rows - 1)]) * grid.pitch_mm / 2.0
    centre = o + half[0] * u + half[1] * v
    rng_mm = np.asarray(data.setup.range_mm, float)
    shift = shift_fraction * grid.pitch_mm
    dz = rng_mm[2] / 3.0 * (1.0 if o[2] + rng_mm[2] / 3.0 < 0.8 * rng_mm[2] else -1.0)
    n_balls = grid.rows * grid.cols
    out = []

    def add(name, text, origin, uu, vv, probes_of_new, new_probes=None,
            family="placement"):
        key = f"next_{name}"
        place = {"origin_mm": [float(x) for x in origin], "u_axis": [float(x) for x in uu],
                 "v_axis": [float(x) for x in vv], "probe": probes_of_new[0]}
        out.append(NextMeasurement(name, text, {key: place}, dict(new_probes or {}),
                                   {key: list(probes_of_new)},
                                   _placement_time(n_balls, len(probes_of_new), per_ball,
                                                   per_place), family=family))

    for a, ax in enumerate("XY"):
        e = np.eye(3)[a]
        add(f"shift_{ax.lower()}", f"the plate of {reference} shifted {shift:g} mm along "
            f"{ax}", o + shift * e, u, v, styli)
    extent = (grid.cols - 1) * grid.pitch_mm * np.abs(u) + (grid.rows - 1) * grid.pitch_mm \
        * np.abs(v)
    low = o - np.minimum(u, 0) * (grid.cols - 1) * grid.pitch_mm \
        - np.minimum(v, 0) * (grid.rows - 1) * grid.pitch_mm  # the plate's lowest corner
    # the ends of the strokes are the ram's (the scale readings): every stylus's reading
    # 5 % inside, so the tip's end moves by the styli's offsets
    offs = np.array([raw["probes"][q] for q in styli], float)
    for a, ax in enumerate("XY"):
        for end, corner in (("low", 0.05 * rng_mm[a] + offs[:, a].max()),
                            ("high", 0.95 * rng_mm[a] + offs[:, a].min() - extent[a])):
            move = corner - low[a]
            if abs(move) > grid.pitch_mm:  # else a shift by part of the pitch covers it
                add(f"{end}_{ax.lower()}", f"the plate of {reference} moved {move:+g} mm "
                    f"along {ax}, to the {end} end of the stroke", o + move * np.eye(3)[a],
                    u, v, styli)
    add("height", f"the plate of {reference} {'raised' if dz > 0 else 'lowered'} "
        f"{abs(dz):g} mm", o + dz * np.eye(3)[2], u, v, styli)
    for deg, (uu, vv) in {90: (v, -u), 180: (-u, -v)}.items():
        add(f"rot{deg}", f"the plate of {reference} rotated {deg}° in its plane",
            centre - half[0] * uu - half[1] * vv, uu, vv, styli)
    for plane, uu in {"XZ": np.eye(3)[0], "YZ": np.eye(3)[1]}.items():
        add(plane.lower(), f"the plate stood in {plane} near {reference}",
            o + np.array([0.0, 0.0, 20.0]), uu, np.eye(3)[2], styli, family="orientation")
    tip = np.asarray(raw["probes"][styli[0]], float)
    # longer along the stylus itself (a horizontal arm's styli point sideways); a stylus
    # at the ram's reference point is lengthened down, as on a bridge
    along = tip / np.linalg.norm(tip) if np.linalg.norm(tip) > 0 else np.array([0, 0, -1.0])
    for name, off, text, fam in (("stylus_x", [stylus_offset_mm, 0, 0],
                                  f"{stylus_offset_mm:g} mm along X", "stylus"),
                                 ("stylus_y", [0, stylus_offset_mm, 0],
                                  f"{stylus_offset_mm:g} mm along Y", "stylus"),
                                 ("stylus_long", 100.0 * along, "100 mm longer",
                                  "stylus_length")):
        q = f"next_{name}"
        add(name, f"{reference} again with a new stylus {q} offset {text}", o, u, v, [q],
            {q: (tip + np.asarray(off, float)).tolist()}, family=fam)
    if len(styli) > 1:
        add("reverse", f"{reference} again with its styli in reverse order "
            f"({', '.join(styli[::-1])})", o, u, v, styli[::-1], family="order")
    return out + repeat_candidates(data, n_balls=repeat_balls, minutes_per_ball=per_ball,
                                   minutes_per_placement=per_place)


def blocked_styli(data: Dataset) -> dict[str, list[str]]:
    """Placements whose styli were measured in blocks: two styli or more, each stylus's
    readings one run in time (``time_min``), -> their styli in the order measured. There a
    placement's drift and its later styli's offsets look alike (``Drift``'s aliases); none
    without a ``time_min`` column (a repeat's time would be unknown)."""
    m = data.meas
    if "time_min" not in m or not m["time_min"].notna().all():
        return {}
    out = {}
    for p in data.setup.raw["positions"]:
        rows = m.loc[m["position"] == p].sort_values("time_min", kind="stable")
        seq = rows["probe"].astype(str).tolist()
        runs = [q for i, q in enumerate(seq) if i == 0 or q != seq[i - 1]]
        if len(runs) > 1 and len(runs) == len(set(runs)):
            out[str(p)] = runs
    return out


def last_placement(data: Dataset) -> str | None:
    """The placement measured last (the one of the latest ``time_min``): the plate still
    set up on the machine, where a repeat is appended to the current placement; None
    without times."""
    m = data.meas
    if "time_min" not in m or not m["time_min"].notna().any():
        return None
    return str(m.loc[m["time_min"].idxmax(), "position"])


def _times_text(times: Sequence[float]) -> str:
    """Times of a repeat's readings in words: "at 120.5 min", "at 120.5 to 122 min"."""
    return (f"at {times[0]:g} min" if len(times) == 1
            else f"at {times[0]:g} to {times[-1]:g} min")


def repeat_candidates(data: Dataset, *, n_balls: int | Sequence[int] = REPEAT_BALLS,
                      minutes_per_ball: float | None = None,
                      minutes_per_placement: float | None = None) -> list[NextMeasurement]:
    """Repeats that tell a placement's drift from its styli's offsets: measurements the
    lab can make next, after the data's last reading.

    For each placement whose styli were measured in blocks (:func:`blocked_styli`): its
    first stylus measured again on the first ``n_balls`` balls it measured there (the
    same balls, the earliest times) (``repeat_<placement>_<n>``); and, with two such
    placements or more, the same on each (``repeat_all_<n>``). The placement measured
    last (:func:`last_placement`) is still set up: its repeat is appended to the current
    placement, right after the data's last reading. Any other was taken down when the
    next was measured: its repeat is in the next session, the plate set up again at that
    placement (``minutes_per_placement`` to set it up, then its balls), after the data's
    last reading; ``repeat_all`` appends to the current placement first, then sets up each
    other in the setup's order. Every repeated reading is timed (``repeat[p]["time_min"]``,
    after the data's last ``time_min``; ``setup_min``: the set-up before it, 0 when
    appended; ``session``: ``"current"`` or ``"next"``), which is what the drift model sees.
    A stylus's offset repeats exactly; a drift of ``v`` µm/h moves the repeated readings by
    ``v`` times the time elapsed since the first ones (``Drift``'s own remedy: "repeating
    the first ball at the end of each position"). The plate set up again is taken at the
    same pose (the placement's own pose parameters: a fixture that puts it back within
    the noise). Machine time: balls × minutes per ball, plus minutes per placement for
    each placement set up again (the plan's time model, ``files.MEASUREMENT_DEFAULTS``).
    """
    defaults: dict = MEASUREMENT_DEFAULTS
    per_ball = float(defaults["minutes_per_ball"] if minutes_per_ball is None
                     else minutes_per_ball)
    per_place = float(defaults["minutes_per_placement"] if minutes_per_placement is None
                      else minutes_per_placement)
    m = data.meas
    out: list[NextMeasurement] = []
    counts = [int(n_balls)] if isinstance(n_balls, int | np.integer) else \
        [int(n) for n in n_balls]
    blocked = blocked_styli(data)
    if not blocked:
        return out
    last = last_placement(data)
    t_last = float(m["time_min"].max())
    named: set = set()  # a count above a stylus's balls gives the same repeat again
    position = m["position"].astype(str)

    def balls_of(p: str, styli: list, n: int) -> list:
        rows = m.loc[(position == str(p)) & (m["probe"].astype(str) == styli[0])]
        rows = rows.sort_values("time_min", kind="stable")
        return [int(b) for b in dict.fromkeys(rows["ball"])][:max(n, 1)]

    def timed(p: str, probe: str, balls: list, clock: float) -> dict:
        # the current placement's repeat follows its last reading; another placement is
        # set up again first (the plan's minutes per placement)
        setup = 0.0 if p == last else per_place
        return {"probe": probe, "balls": balls, "setup_min": setup,
                "session": "current" if p == last else "next",
                "time_min": [clock + setup + per_ball * (j + 1) for j in range(len(balls))]}

    def words(p: str, r: dict) -> str:
        balls = r["balls"]
        what = (f"stylus {r['probe']} measured again on {len(balls)} ball(s) of {p} (balls "
                f"{', '.join(map(str, balls))}) {_times_text(r['time_min'])}")
        if r["session"] == "current":
            return f"{what}, appended to the current placement {p} (still set up)"
        return (f"{what}, in the next session: the plate set up again at {p} "
                f"({r['setup_min']:g} min) after the last reading ({t_last:g} min)")

    for n in counts:
        # the current placement first (still set up), then the others as set up anew
        order = sorted(blocked, key=lambda p: p != last)
        each, clock = {}, t_last
        for p in order:
            balls = balls_of(p, blocked[p], n)
            r = timed(p, blocked[p][0], balls, t_last)
            name = f"repeat_{p}_{len(balls)}"
            if name not in named:
                named.add(name)
                out.append(NextMeasurement(
                    name, words(p, r), {}, {}, {}, len(balls) * per_ball + r["setup_min"],
                    repeat={p: r}, family="repeat"))
            each[p] = timed(p, blocked[p][0], balls, clock)
            clock = each[p]["time_min"][-1]
        # named by the balls each placement repeats (fewer than n where a stylus has less)
        sizes = sorted({len(r["balls"]) for r in each.values()})
        label = "-".join(map(str, sizes))
        if len(each) > 1 and f"repeat_all_{label}" not in named:
            named.add(f"repeat_all_{label}")
            out.append(NextMeasurement(
                f"repeat_all_{label}", f"the first stylus of each of {', '.join(each)} "
                f"measured again on {label} of its balls: "
                + "; then ".join(words(p, r) for p, r in each.items()), {}, {}, {},
                sum(len(r["balls"]) * per_ball + r["setup_min"] for r in each.values()),
                repeat=each, family="repeat"))
    return out


def _tagged(c: NextMeasurement, tag: str) -> NextMeasurement:
    """The candidate with its placement and new styli renamed by ``tag`` (unique names
    when several references or fractions are combined)."""
    def ren(n):
        return f"{n}_{tag}" if n.startswith("next_") else n

    return NextMeasurement(
        f"{c.name}_{tag}", c.description,
        {ren(p): {**pl, "probe": ren(str(pl.get("probe", c.probes_of[p][0])))}
         for p, pl in c.positions.items()},
        {ren(q): v for q, v in c.probes.items()},
        {ren(p): [ren(q) for q in qs] for p, qs in c.probes_of.items()}, c.time_min,
        c.instrument, c.repeat, c.family)


def wide_candidates(data: Dataset, fractions: Sequence[float] = (0.25, 0.5, 0.75)
                    ) -> list[NextMeasurement]:
    """A large candidate set: :func:`measurement_candidates` from every placement as the
    reference and at each shift ``fractions`` of the pitch (a study for
    :func:`propose_many`); duplicates are kept once (same placement, styli and offsets)."""
    out, seen = [], set()
    for p in data.setup.raw["positions"]:
        for i, f in enumerate(fractions):
            for c in measurement_candidates(data, reference=p, shift_fraction=f):
                if i and not c.name.startswith("shift_"):
                    continue
                key = json.dumps([list(c.positions.values()), list(c.probes_of.values()),
                                  c.probes, c.repeat], sort_keys=True)
                if key in seen:
                    continue
                seen.add(key)
                out.append(_tagged(c, f"{p}_{round(100 * f)}"))
    return out


def instrument_candidates(data: Dataset, *, reference: str | None = None,
                          n_readings: int = 21, minutes_per_ball: float | None = None,
                          minutes_per_placement: float | None = None
                          ) -> list[NextMeasurement]:
    """Instrument candidates, laid out in the machine's scale readings (the ram: tip
    minus stylus offset), so that each is inside the strokes whatever the stylus.

    The reference point is the ram's scale reading with the reference placement's first
    stylus (as measured: :func:`styli_at`) on the plate's centre, kept 5 % inside each
    stroke. Through it: a laser positioning run along X, Y and Z (``n_readings`` readings
    from 5 % to 95 % of the stroke, reflector at that stylus's offset); a step gauge along
    X and along Y (its first face read at 5 % of the stroke, ``n_readings - 1`` lengths
    up to 80 % of it); a ball bar of 40 % of the smaller horizontal stroke in four
    orientations (0°, 45°, 90°, 135°) about it (moved in XY until both balls are inside
    the strokes). Machine time: readings × minutes per ball + minutes per placement
    (setting the instrument up), the plan's time model applied to instruments (an
    assumption: ``files.MEASUREMENT_DEFAULTS``). :func:`propose` still checks every
    point against the strokes (a stylus longer than a stroke cannot be laid out so)."""
    defaults: dict = MEASUREMENT_DEFAULTS
    per_ball = float(defaults["minutes_per_ball"] if minutes_per_ball is None
                     else minutes_per_ball)
    per_place = float(defaults["minutes_per_placement"] if minutes_per_placement is None
                      else minutes_per_placement)
    grid = plate_grid(data)
    pos = data.setup.raw["positions"]
    if reference is None:
        reference = next((p for p in pos if data.setup.positions[p].horizontal), next(iter(pos)))
    if reference not in pos:
        raise DataError(f"unknown placement {reference!r}; expected one of {sorted(pos)}.",
                        file=data.name, column="reference", hint="name a placement of the setup")
    ref = pos[reference]
    u, v = _unit(ref["u_axis"]), _unit(ref["v_axis"])
    centre = (np.asarray(ref["origin_mm"], float) + (grid.cols - 1) * grid.pitch_mm / 2 * u
              + (grid.rows - 1) * grid.pitch_mm / 2 * v)
    stylus = styli_at(data, reference)[0]
    tip = np.asarray(data.setup.raw["probes"][stylus], float)
    R = np.asarray(data.setup.range_mm, float)
    # the instruments' simulators take the laser's line as a ram point but the gauges'
    # faces and the bar's balls as tip points: all are derived from the ram's reading
    ram = np.clip(centre - tip, 0.05 * R, 0.95 * R)
    offset = tip.tolist()
    out = []
    for a, ax in enumerate("xyz"):
        out.append(NextMeasurement(
            f"laser_{ax}", f"a laser positioning run along {ax.upper()} through the centre "
            f"of {reference} ({n_readings} readings, stylus {stylus})", {}, {}, {},
            n_readings * per_ball + per_place,
            {"kind": "laser", "axis": ax, "line_mm": ram.tolist(),
             "positions_mm": np.linspace(0.05 * R[a], 0.95 * R[a], n_readings).tolist(),
             "offset_mm": offset}, family="instrument"))
    for a, ax in enumerate("xy"):
        start = ram + tip
        start[a] = 0.05 * R[a] + tip[a]
        end = start.copy()
        end[a] = 0.85 * R[a] + tip[a]
        out.append(NextMeasurement(
            f"step_gauge_{ax}", f"a step gauge along {ax.upper()} through the centre of "
            f"{reference} ({n_readings - 1} lengths, stylus {stylus})", {}, {}, {},
            (n_readings - 1) * per_ball + per_place,
            {"kind": "step_gauge", "start_mm": start.tolist(), "end_mm": end.tolist(),
             "lengths_mm": np.linspace(0.8 * R[a] / (n_readings - 1), 0.8 * R[a],
                                       n_readings - 1).tolist(), "offset_mm": offset},
            family="instrument"))
    half = 0.2 * min(R[0], R[1])
    mid = ram.copy()
    mid[:2] = np.clip(mid[:2], half, R[:2] - half)  # both balls inside in XY
    ang = np.deg2rad([0.0, 45.0, 90.0, 135.0])
    d = half * np.column_stack([np.cos(ang), np.sin(ang), np.zeros(4)])
    out.append(NextMeasurement(
        "ball_bar_xy", f"a ball bar of {2 * half:g} mm at 0°, 45°, 90° and 135° in XY about "
        f"the centre of {reference} (stylus {stylus})", {}, {}, {},
        4 * 2 * per_ball + per_place,
        {"kind": "ball_bar", "start_mm": (mid + tip - d).tolist(),
         "end_mm": (mid + tip + d).tolist(), "offset_mm": offset}, family="instrument"))
    return out

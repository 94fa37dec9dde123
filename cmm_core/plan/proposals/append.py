"""A candidate measured: the data set with the candidate's measurement appended
(:func:`append_measurement`; a repeat simulated from a fit, :func:`repeat_from_fit`), the
candidate's own observations for the design (:func:`measurement_observations`), an
instrument measured on the data's machine (:func:`instrument_of`), and the data set as a
fit selects it (:func:`restrict`).

The candidate's observations are simulated on the virtual CMM (``simulate``) in the data's
machine frame, with the data's plate (rows, columns and pitch read from the certificate, a
regular grid) and the plan module's time model (``files.MEASUREMENT_DEFAULTS``: minutes per
ball and per placement).
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

from ...io import DataError, Dataset, read_setup, resolve
from ...model import (
    BallBar,
    FitResult,
    LaserRun,
    Observations,
    Simulation,
    StepGauge,
    select,
    simulate,
    simulate_ball_bar,
    simulate_laser,
    simulate_step_gauge,
)
from .candidates import NextMeasurement, plate_grid

_NO_ERRORS = {"random_um": 0.0, "random_urad": 0.0}
"""Simulator keys: no kinematic errors drawn (the simulator's default draws 1 µm, 1 µrad)."""

_COLUMNS = ["position", "probe", "ball", "time_min", "temp_C", "x_mm", "y_mm", "z_mm"]

_RESOLVED = ("mx_mm", "my_mm", "mz_mm")
"""Columns ``io.resolve`` adds (machine-frame tip centres): computed again on a subset."""


def append_measurement(data: Dataset, cand: NextMeasurement, *, config: dict | None = None,
              seed: int = 0) -> Dataset:
    """The data set with the candidate's measurement appended, simulated on the virtual
    CMM with ``config``'s errors (default: none, no noise) in the data's machine frame.

    The simulated readings are moved by the certificate's departure from the nominal
    grid (rotated into the placement), so that the appended balls are the certificate's.

    A repeat (``cand.repeat``) is simulated at its placement's pose in the setup (the
    truth of a simulated data set) and appended to that placement at its own times
    (after the data's last reading: appended to the current placement, or in the next
    session); its drift continues that of the readings before over all the time elapsed: ``config``'s ``effects.drift`` must then give each
    repeated placement's own vector (µm/h), not a spread.

    Raises
    ------
    DataError
        When the candidate's plate or styli leave the machine's range.
    """
    if cand.repeat:
        return _append_repeat(data, cand, config or {}, seed)
    grid = plate_grid(data)
    raw = copy.deepcopy(data.setup.raw)
    raw["frame"] = "machine"
    probes = {**raw["probes"], **cand.probes}
    setup = {k: raw[k] for k in ("units", "machine") if k in raw}
    setup.update({"frame": "machine", "positions": cand.positions, "probes": probes})
    if "artefact" in raw:
        setup["artefact"] = raw["artefact"]
    config = config or {}
    cfg = {**config, "seed": seed, "setup": setup,
           "noise_um": config.get("noise_um", 0.0),
           "kinematic": {**_NO_ERRORS, **config.get("kinematic", {})},
           "probes_per_position": cand.probes_of,
           "plate": {"rows": grid.rows, "cols": grid.cols, "pitch_mm": grid.pitch_mm,
                     "form_um": 0.0, "certificate_u_um": 0.0}}
    sim = simulate(cfg, name=f"proposal {cand.name!r}")
    new = sim.dataset.meas
    xyz = new[["x_mm", "y_mm", "z_mm"]].to_numpy().copy()
    for p in cand.positions:
        sel = (new["position"] == p).to_numpy()
        R = sim.dataset.setup.positions[p].rotation
        xyz[sel] += grid.offset_mm[new.loc[sel, "ball"].to_numpy() - 1] @ np.asarray(R).T
    new = new.assign(x_mm=xyz[:, 0], y_mm=xyz[:, 1], z_mm=xyz[:, 2])
    old = data.meas
    new = new.assign(time_min=new["time_min"] + float(old["time_min"].max()) + 10.0,
                     source=f"proposal {cand.name}")
    cols = [c for c in _COLUMNS if c in old and c in new]
    both = pd.concat([old[cols + [c for c in ("source", "row") if c in old]],
                      new[cols + ["source", "row"]]], ignore_index=True)
    raw["positions"] = {**raw["positions"], **cand.positions}
    raw["probes"] = probes
    merged = read_setup(raw, name=f"{data.name} + {cand.name}")
    return Dataset(resolve(both, merged, data.certificate), merged, data.certificate,
                   f"{data.name} + {cand.name}")


def _with_rows(data: Dataset, new: pd.DataFrame, name: str) -> Dataset:
    """The data set with rows ``new`` (the measurement columns, ``source``, ``row``)
    appended to its placements (the setup unchanged, read in the machine frame as
    :func:`append_measurement`'s)."""
    old = data.meas
    cols = [c for c in _COLUMNS if c in old and c in new]
    # a ball measured again with the same stylus: the io's ``repeat`` column tells them
    # apart (0 for the readings before when they have none)
    again = int(old["repeat"].max()) + 1 if "repeat" in old else 1
    old = old if "repeat" in old else old.assign(repeat=0)
    # a ball repeated twice among the new rows (a union of repeats at two times) is
    # told apart from itself too
    new = new.assign(repeat=again + new.groupby(["position", "probe", "ball"]).cumcount()
                     .to_numpy())
    cols += ["repeat"]
    both = pd.concat([old[cols + [c for c in ("source", "row") if c in old]],
                      new[cols + ["source", "row"]]], ignore_index=True)
    raw = copy.deepcopy(data.setup.raw)
    raw["frame"] = "machine"
    merged = read_setup(raw, name=f"{data.name} + {name}")
    return Dataset(resolve(both, merged, data.certificate), merged, data.certificate,
                   f"{data.name} + {name}")


def _repeat_drift(data: Dataset, cand: NextMeasurement, drift: Mapping) -> dict:
    """Placement -> drift vector (µm/h) a repeat continues (``effects.drift`` of a
    simulator configuration: per placement; zero for a placement not given)."""
    if "sd_um_per_h" in drift:
        raise ValueError(f"{cand.name} repeats readings of placements already measured: "
                         "their drift continues; give effects.drift per placement (µm/h), "
                         "not sd_um_per_h.")
    return {p: np.asarray(drift.get(p, [0.0, 0.0, 0.0]), float) for p in cand.repeat}


def _append_repeat(data: Dataset, cand: NextMeasurement, config: dict, seed: int
                   ) -> Dataset:
    """:func:`append_measurement` of a repeat: the repeated stylus simulated at each
    placement's pose (``config``'s machine, styli and noise), the balls and times of
    ``cand.repeat`` kept, the placement's drift added as the drift block does
    (``+ v · hours``, hours from the mean time of the placement's readings before, so
    that the repeat continues them; ``Drift.reading_stage``, the simulator's targets)."""
    grid = plate_grid(data)
    raw = data.setup.raw
    effects = dict(config.get("effects", {}))
    drift = _repeat_drift(data, cand, effects.pop("drift", {}) or {})
    setup = {k: copy.deepcopy(raw[k]) for k in ("units", "machine", "artefact") if k in raw}
    setup.update({"frame": "machine", "probes": copy.deepcopy(raw["probes"]),
                  "positions": {p: copy.deepcopy(raw["positions"][p]) for p in cand.repeat}})
    for pl in setup["positions"].values():
        for key in ("temp_C", "rh_percent"):
            pl.pop(key, None)
    cfg = {**config, "effects": effects, "seed": seed, "setup": setup,
           "noise_um": config.get("noise_um", 0.0),
           "kinematic": {**_NO_ERRORS, **config.get("kinematic", {})},
           "probes_per_position": {p: [r["probe"]] for p, r in cand.repeat.items()},
           "plate": {"rows": grid.rows, "cols": grid.cols, "pitch_mm": grid.pitch_mm,
                     "form_um": 0.0, "certificate_u_um": 0.0}}
    sim = simulate(cfg, name=f"proposal {cand.name!r}")
    meas = sim.dataset.meas
    parts = []
    for p, r in cand.repeat.items():
        rows = meas.loc[meas["position"] == p].set_index("ball").loc[r["balls"]]
        rows = rows.reset_index()
        R = np.asarray(sim.dataset.setup.positions[p].rotation)
        xyz = rows[["x_mm", "y_mm", "z_mm"]].to_numpy().copy()
        xyz += grid.offset_mm[rows["ball"].to_numpy() - 1] @ R.T
        t = np.asarray(r["time_min"], float)
        t0 = float(data.meas.loc[data.meas["position"] == p, "time_min"].mean())
        xyz += np.outer((t - t0) / 60.0, drift[p]) * 1e-3
        parts.append(rows.assign(x_mm=xyz[:, 0], y_mm=xyz[:, 1], z_mm=xyz[:, 2],
                                 time_min=t))
    new = pd.concat(parts, ignore_index=True).assign(source=f"proposal {cand.name}")
    return _with_rows(data, new, cand.name)


def repeat_from_fit(data: Dataset, cand: NextMeasurement, fitted: FitResult, *,
                    noise_um: float = 0.0, seed: int = 0) -> Dataset:
    """The data set with a repeat appended, simulated from a fit of the data itself (its
    pose, plate, styli and machine as fitted: what the one-click simulation takes as the
    truth): each repeated reading is the fitted model's value of the first reading of
    that stylus and ball (the reading minus its residual), moved by the fitted drift of
    the placement (``+ v · Δt``, zero without drift) over the time elapsed, plus normal
    noise ``noise_um``. Other effects of time (temperatures) are taken as at the first
    reading."""
    obs = fitted.problem.obs
    t = obs.table.reset_index(drop=True)
    res = np.asarray(fitted.residuals_um, float)
    vals = dict(zip(fitted.labels, fitted.values, strict=True))
    rng = np.random.default_rng(seed)
    parts = []
    for p, r in cand.repeat.items():
        v = np.array([vals.get(f"{p}.drift_{a}", 0.0) for a in "xyz"])
        sel = t.loc[(t["position"] == p) & (t["probe"].astype(str) == r["probe"])]
        sel = sel.sort_values("time_min", kind="stable").drop_duplicates("ball")
        idx = pd.Series(sel.index.to_numpy(), index=sel["ball"].to_numpy()).loc[
            r["balls"]].to_numpy()
        first = t.loc[idx]
        xyz = first[["x_mm", "y_mm", "z_mm"]].to_numpy(float) - res[idx] * 1e-3
        tm = np.asarray(r["time_min"], float)
        xyz += np.outer((tm - first["time_min"].to_numpy(float)) / 60.0, v) * 1e-3
        xyz += rng.normal(0.0, noise_um, xyz.shape) * 1e-3
        new = first[["position", "probe", "ball"] + [c for c in ("temp_C",) if c in first]]
        parts.append(new.assign(time_min=tm, x_mm=xyz[:, 0], y_mm=xyz[:, 1],
                                z_mm=xyz[:, 2]))
    new = pd.concat(parts, ignore_index=True)
    new = new.assign(source=f"proposal {cand.name}", row=np.arange(2, len(new) + 2))
    return _with_rows(data, new, cand.name)


def restrict(data: Dataset, *, positions: Sequence[str] | None = None,
             probes: Sequence[str] | None = None,
             exclude: Iterable[Sequence] = ()) -> Dataset:
    """The data set as a fit selects it: the rows ``model.select`` keeps for
    ``positions``, ``probes`` and ``exclude`` (its table, the one selection rule), the
    placements with no observation left out of the setup. The data set itself when
    nothing is left out.

    Raises
    ------
    DataError
        When the selection leaves no observation.
    """
    try:
        kept = select(data, positions=positions, probes=probes,
                      exclude=[tuple(e) for e in exclude]).table
    except ValueError as exc:
        raise DataError(f"{exc}", file=data.name, column="position") from None
    if len(kept) == len(data.meas):
        return data
    raw = copy.deepcopy(data.setup.raw)
    used = set(kept["position"])
    raw["positions"] = {p: pl for p, pl in raw["positions"].items() if p in used}
    setup = read_setup(raw, name=data.name)
    fresh = kept.drop(columns=list(_RESOLVED), errors="ignore")
    return Dataset(resolve(fresh, setup, data.certificate), setup, data.certificate,
                   data.name)


def measurement_observations(data: Dataset, cands: list) -> Observations:
    """The candidates' own noise-free, error-free observations (virtual CMM, nominal
    certificate), all in one simulation (each candidate is its own placement): their
    Jacobian rows stack onto the current data's.

    Raises
    ------
    DataError
        When a candidate's plate or styli leave the machine's range.
    """
    grid = plate_grid(data)
    setup = {k: copy.deepcopy(data.setup.raw[k]) for k in ("units", "machine", "artefact")
             if k in data.setup.raw}
    probes = dict(data.setup.raw["probes"])
    for c in cands:
        probes.update(c.probes)
    setup.update({"frame": "machine", "probes": probes,
                  "positions": {p: pl for c in cands for p, pl in c.positions.items()}})
    cfg = {"seed": 0, "setup": setup, "noise_um": 0.0, "kinematic": dict(_NO_ERRORS),
           "probes_per_position": {p: q for c in cands for p, q in c.probes_of.items()},
           "plate": {"rows": grid.rows, "cols": grid.cols, "pitch_mm": grid.pitch_mm,
                     "form_um": 0.0, "certificate_u_um": 0.0}}
    return select(simulate(cfg, name="proposals").dataset)


def _first_outside(scale: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[int, int] | None:
    """(point, axis) of the first scale reading outside ``[lo, hi]``, or None."""
    bad = (scale < lo) | (scale > hi)
    rows = np.flatnonzero(bad.any(axis=1))
    if not rows.size:
        return None
    i = int(rows[0])
    return i, int(np.flatnonzero(bad[i])[0])


def reached_range(data: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) scale readings per axis, mm, that a proposal may ask for: the stroke
    ``[0, range_mm]`` widened to the readings the current data already made (tip minus
    the offset of the stylus probing it). A machine's zero is not always a stroke's end
    (the thesis's plates stand at z = 0 with an upward stylus): what it measured, it can
    measure again; nothing beyond both is proposed."""
    rng = np.asarray(data.setup.range_mm, float)
    m = data.meas
    probes = data.setup.raw["probes"]
    off = np.array([probes[str(q)] for q in m["probe"]], float).reshape(-1, 3)
    scale = m[list(_RESOLVED)].to_numpy(float) - off
    if not len(scale):
        return np.zeros(3), rng
    return np.minimum(0.0, scale.min(axis=0)), np.maximum(rng, scale.max(axis=0))


def out_of_reach(data: Dataset, cand: NextMeasurement) -> str:
    """Why the machine cannot measure the candidate's plate, or "" when it can.

    The virtual CMM's own check (``simulation_config._check_plate_in_machine``, as
    ``io.matching`` checks measured points): the scale reading of every ball (tip minus
    the offset of the stylus probing it) of every new placement, with every stylus
    measured there, inside the strokes (:func:`reached_range`); here without the
    simulator's slack
    (``io.range_tolerance``: at least 100 mm, for a rough nominal setup), since the
    product lays the proposal out itself: a proposal needs a reachable pose. The balls
    are the certificate's (the appended readings are, :func:`append_measurement`). A
    repeat is of a placement already measured (""); an instrument is checked once
    measured (:func:`instrument_out_of_reach`).
    """
    if cand.repeat or cand.instrument or not cand.positions:
        return ""
    grid = plate_grid(data)
    raw = data.setup.raw
    probes = {**raw["probes"], **cand.probes}
    # the placements without their stylus: the setup reader's check of ball 1 (with the
    # slack a user's rough setup needs) would refuse what the check below reports, ball
    # by ball and with no slack, as a reason to skip
    positions = {p: {k: copy.deepcopy(v) for k, v in pl.items() if k != "probe"}
                 for p, pl in cand.positions.items()}
    try:
        setup = read_setup({**{k: copy.deepcopy(raw[k]) for k in ("units", "machine")
                               if k in raw},
                            "frame": "machine", "positions": positions, "probes": probes},
                           name=f"proposal {cand.name!r}")
    except DataError as exc:
        return f"its layout is refused: {exc}"

    b = np.arange(grid.rows * grid.cols)
    balls = np.column_stack([b % grid.cols * grid.pitch_mm, b // grid.cols * grid.pitch_mm,
                             np.zeros(b.size)]) + grid.offset_mm
    lo, hi = reached_range(data)
    for p, styli in cand.probes_of.items():
        tips = setup.positions[p].to_machine(balls)
        for q in styli:
            hit = _first_outside(tips - np.asarray(probes[q], float), lo, hi)
            if hit is not None:
                i, a = hit
                reading = tips[i, a] - float(probes[q][a])
                return (f"ball {i + 1} with stylus {q} needs the scale reading {reading:.1f} "
                        f"mm of axis {'xyz'[a]}, outside the machine's stroke {round(lo[a], 1):g} to "
                        f"{round(hi[a], 1):g} mm")
    return ""


def instrument_out_of_reach(inst, range_mm) -> str:
    """Why the machine cannot read an instrument's points, or "" when it can: each point's
    scale reading (``points()``: indicated point minus offset, what the fit evaluates the
    model at) inside the strokes; the fit's own check (``instruments._check_in_range``)
    without its margin (``model.RANGE_MARGIN``, for files of a real machine)."""
    rng = np.asarray(range_mm, float)
    for x, _ in inst.points():
        hit = _first_outside(np.asarray(x, float), np.zeros(3), rng)
        if hit is not None:
            i, a = hit
            return (f"the scale reading {x[i, a]:.1f} mm of axis {'xyz'[a]} is outside "
                    f"the machine's stroke 0 to {rng[a]:g} mm")
    return ""


def _in_machine(data: Dataset, cands: list) -> tuple:
    """(observations of the candidates that fit in the machine, those candidates, skipped
    ones with the reason): each checked by :func:`out_of_reach` first, then one
    simulation unless some still fail in it (one at a time to tell which)."""
    skipped: dict[str, str] = {}
    reach = [c for c in cands if not _skip(skipped, c, out_of_reach(data, c))]
    try:
        return (measurement_observations(data, reach) if reach else None), reach, skipped
    except DataError:
        ok = []
        for c in reach:
            try:
                measurement_observations(data, [c])
                ok.append(c)
            except DataError as exc:
                skipped[c.name] = str(exc)
        return (measurement_observations(data, ok) if ok else None), ok, skipped


def _skip(skipped: dict, cand: NextMeasurement, why: str) -> bool:
    """Record ``why`` for ``cand`` in ``skipped`` when it is not empty; True then."""
    if why:
        skipped[cand.name] = why
    return bool(why)


_SIMULATORS: dict = {"laser": simulate_laser, "step_gauge": simulate_step_gauge,
               "ball_bar": simulate_ball_bar}


def _machine(data: Dataset, kinematic: dict | None = None):
    """The data's machine without errors (the simulator's ``Simulation`` the instrument
    simulators read their truth from), measuring the first placement; with
    ``kinematic`` (simulator keys, :func:`truth_config`), the machine with those errors."""
    grid = plate_grid(data)
    raw = data.setup.raw
    p = next(iter(raw["positions"]))
    setup = {k: copy.deepcopy(raw[k]) for k in ("units", "machine") if k in raw}
    setup.update({"frame": "machine", "probes": copy.deepcopy(raw["probes"]),
                  "positions": {p: copy.deepcopy(raw["positions"][p])}})
    for key in ("temp_C", "rh_percent"):
        setup["positions"][p].pop(key, None)
    return simulate({"seed": 0, "setup": setup, "noise_um": 0.0,
                     "kinematic": {**_NO_ERRORS, **(kinematic or {})},
                     "plate": {"rows": grid.rows, "cols": grid.cols,
                               "pitch_mm": grid.pitch_mm, "form_um": 0.0,
                               "certificate_u_um": 0.0}}, name="proposals")


def instrument_of(cand: NextMeasurement, sim: Simulation, seed: int | None = 0
                  ) -> LaserRun | StepGauge | BallBar:
    """The candidate's instrument measured on ``sim``'s machine (a ``Simulation``)."""
    kw = {k: v for k, v in cand.instrument.items() if k != "kind"}
    return _SIMULATORS[cand.instrument["kind"]](sim, seed=seed, **kw)

"""Measure next: the extra measurement that settles what the data cannot (issue 29).

When the diagnosis cannot tell two effects A and B apart (aliases, runners-up), this module
generates candidate measurements from the data set's own setup and machine range, and
scores each by what it decides: the discrimination between A and B the augmented data set
(current data plus the candidate) would give, per minute of machine time.

How a candidate is scored. Each rival in turn is the truth at the size it is fitted to on
the current data (``θ_A``, the parameters A has and B has not). The noise-free augmented
design (``J``, the weighted Jacobian at the nominal linearisation of the model holding both
rivals; the current readings and the candidate's simulated ones) gives the mean misfit the
other rival leaves:

    λ_A = ‖(I − P_B) J_A θ_A‖²,

``P_B`` the projector on B's columns (baseline, B, the new placement's pose), ``J_A`` A's
own columns, weighted by 1/σ. That is the χ² the fit of B leaves on noise-free data from A
(Δχ² of the noise-free augmented design), and the non-centrality of the diagnosis's nested
F-test "A is still needed once B is in" (``verdict._encompassing``): F(k_A, ν, λ_A) with k_A
the rank A adds to B, ν the residual dof of the model with both (Scheffé 1959, §2.8; the
linear-model power of ``detect.py``). The power to separate is

    power_A = P(F(k_A, ν, λ_A) > F⁻¹(1 − α; k_A, ν)),

α the level the diagnosis judges the pair at: its nested tests judge both directions at
the level of the candidate it ranks first (``verdict._encompassing``), so both powers of
two model tokens are taken at the first rival's level (its share of the family-wise rate,
weighted Bonferroni), which is that candidate's when the rivals are the diagnosis's
(:func:`rivals_of`, :func:`open_pairs`; for rivals given in the other order, an
approximation); a placement-scale rival at the placement-scale test's level.

The fitted ``θ̂_A`` carries noise, and the more so the worse the current data separate the
rivals (that is why a proposal is asked for): ``E‖M θ̂‖² = ‖M θ‖² + tr(M C Mᵀ)`` for an
unbiased ``θ̂`` of covariance ``C`` (``M = (I − P_B) J_A``), so λ_A is taken as
``‖M θ̂_A‖² − tr(M C_A Mᵀ)`` (at least 0): at exactly the fitted size it would overstate
the separation (by Δχ² ≈ 15 of 45 for a probe offset against drift on the 80 mm layout,
bench/proposals.py); the size itself is kept as ``delta_chi2_fitted``.

The predicted power is an expectation over the size's uncertainty, not the power at one
size (:func:`_expected_power`). The noise-corrected λ is unbiased, but the power at it is
not the expected power: when the current data fit the size within its noise, λ is often
clipped at 0 and the power there is the level, although the truth's λ is, as often, well
above it (drift rates fitted within ±1.3-3.5 µm/h against a 1 µm/h spread: 65 % predicted
against 93 % measured, docs/proposals.md "Validation"). So ``power_A`` is the assurance
of the nested test (O'Hagan & Stevens 2001; Spiegelhalter, Abrams & Myles 2004 §6.5):
``E[P(F(k_A, ν, λ_A(θ)) > F⁻¹(1 − α))]`` over ``θ ~ N(θ̂_A, C_A)``, the current data's
posterior of A's size under a flat prior (the linear model with σ known), with
``λ_A(θ) = θᵀ Mᵀ M θ``. With ``C_A → 0`` it is the power at the fitted size.

A candidate decides the pair with power ``min(power_A, power_B)``. Proposals are ranked
on the powers at the noise-corrected sizes (``Proposal.power_at_size``): those reaching
``target`` power first, by machine time; then the others by power. Not on the assurance:
under the flat prior it credits a candidate for seeing directions the current data leave
loose (large sizes there are as likely as small ones), so a rival fitted to nothing but
noise gets a power above :data:`NO_POWER` from a candidate that sees little of it, and
that candidate would outrank one that shows the other rival with certainty (the weak
``rxz:4`` case of bench/proposals.py, seed 9: ``low_x`` at 0.33/0.15 against ``high_x``
at 0.95/0.002; ``high_x`` separates the rivals, ``low_x`` does not).

A repeat (:func:`repeat_candidates`: a stylus measured again at the end of a placement
already measured) adds rows to that placement, not a new one: it is scored on the design
of the whole augmented data set (:func:`_score_repeats`).

The candidate's observations are simulated on the virtual CMM (``simulate``) in the data's
machine frame, with the data's plate (rows, columns and pitch read from the certificate, a
regular grid) and the plan module's time model (``files.MEASUREMENT_DEFAULTS``: minutes per
ball and per placement).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats
from scipy.stats import qmc

from .._blas import single_blas_thread
from ..diagnosis import FAMILY_ALPHA, SCALE_ALPHA, Diagnosis, diagnose
from ..diagnosis import scale_columns as placement_scales
from ..io import DataError, Dataset, read_setup, resolve
from ..model import (
    BY_TOKEN,
    BallBar,
    FitResult,
    LaserRun,
    Observations,
    Problem,
    Simulation,
    StepGauge,
    fit,
    select,
    simulate,
    simulate_ball_bar,
    simulate_laser,
    simulate_step_gauge,
    weighted_residual,
)
from .detect import candidate_tokens
from .files import MEASUREMENT_DEFAULTS
from .study import dask_client

TARGET_POWER = 0.9
"""Power at which a proposal counts as deciding the pair of rivals."""

SHIFT_FRACTION = 0.5
"""Default fraction of the ball pitch by which the plate is shifted."""

REPEAT_BALLS = (4, 12)
"""Balls a stylus is measured again on at the end of a placement (:func:`repeat_candidates`):
a few, and more for a small drift."""

NO_POWER = 0.05
"""A power below this (one chance in twenty) decides nothing: the ranking does not tell
such powers apart (:func:`_rank_key`)."""

_ASSURANCE_DRAWS = 256
"""Points of the quasi-Monte Carlo of the expected power (:func:`_expected_power`), each
taken with its mirror image: scrambled Sobol' normals (a power of two, as Sobol' points
balance best). On the tests' tiny case the expectation is within 0.2 points of a
400 000-draw reference (0.19 and 0.08); 200 pseudo-random mirrored pairs missed it by up
to 2.4 points."""

_ASSURANCE_SEED = 2001
"""Seed of the Sobol' scrambling (fixed: the same design gives the same score)."""

CHUNK = 16
"""Candidates per Dask task of :func:`propose_many`."""

STYLUS_OFFSET_MM = 60.0
"""Lateral offset (mm) of the extra styli proposed."""

SCALE_RTOL = 1e-3
"""Part of a placement-scale column (its norm) that must be left once the baseline's
columns are projected out for that scale to be fitted (``diagnosis.crossval``'s rank
rule)."""

BASELINE = "baseline"
"""A rival that adds nothing: the model as it is. The rival of an effect whose addition
would leave parameter combinations undetermined (``Candidate.would_leave_undetermined``):
a proposal is scored by the rank the effect then adds (``Proposal.dof``, against the
current data's in the outcome) and its power to be seen; with the baseline true there is
nothing to see, so only the effect's power counts."""

PSEUDO = frozenset({"placement_scale", "baseline"})
"""Rivals that are not model tokens (:data:`PLACEMENT_SCALE`, :data:`BASELINE`): given
second."""

PLACEMENT_SCALE = "placement_scale"
"""A rival that is not a model token: each placement's own scale along each machine axis
it spans (outside the catalogue; the diagnosis's placement-scale test,
``diagnosis.placement_scale_columns``). A new placement brings its own scales."""

_NO_ERRORS = {"random_um": 0.0, "random_urad": 0.0}
"""Simulator keys: no kinematic errors drawn (the simulator's default draws 1 µm, 1 µrad)."""

_COLUMNS = ["position", "probe", "ball", "time_min", "temp_C", "x_mm", "y_mm", "z_mm"]

_RESOLVED = ("mx_mm", "my_mm", "mz_mm")
"""Columns ``io.resolve`` adds (machine-frame tip centres): computed again on a subset."""


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
        For a repeat at the end of placements already measured (:func:`repeat_candidates`):
        placement -> ``{"probe": stylus, "balls": [...], "time_min": [...]}``, the stylus
        measured again on those balls at those times (after the placement's last reading,
        before its plate is moved: the same pose); ``positions`` is then empty.
    """

    name: str
    description: str
    positions: dict
    probes: dict
    probes_of: dict
    time_min: float
    instrument: dict = field(default_factory=dict)
    repeat: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Proposal:
    """A candidate measurement scored by how well it separates two rival models.

    Attributes
    ----------
    candidate : NextMeasurement
        The measurement.
    rivals : tuple of str
        The two rival tokens (A, B).
    delta_chi2 : dict
        Rival taken as the truth -> expected Δχ² (non-centrality λ) the other rival leaves
        on the noise-free augmented data, its size's noise taken out: ``‖M θ̂‖² −
        tr(M C Mᵀ)`` (at least 0), ``C`` the covariance of the fitted ``θ̂`` (module
        docstring).
    dof : dict
        Rival taken as the truth -> (k, ν): numerator and denominator dof of its nested
        F-test.
    level : dict
        Rival taken as the truth -> the level its nested test is judged at (two model
        tokens: both at the first rival's level, as the diagnosis's nested tests).
    power : dict
        Rival taken as the truth -> probability that its nested test rejects the other:
        the expected power over the uncertainty of the rival's fitted size
        (:func:`_expected_power`, the "assurance").
    power_min : float
        The smaller of the two powers: the probability the pair is decided.
    per_minute : float
        The smaller expected Δχ² per minute of machine time.
    outcome : str
        The predicted outcome in words.
    delta_chi2_fitted : dict
        Rival taken as the truth -> Δχ² at exactly its fitted size (``‖M θ̂‖²``): the χ²
        the other rival leaves on noise-free data simulated from the fit.
    own : dict
        Rival -> how many parameters it has that the other has not (on the augmented
        data; a gauge, such as a probe offset's reference, counts too): the rank it adds,
        ``dof[rival][0]``, is what the data determine of them.
    power_at_size : dict
        Rival taken as the truth -> the power at exactly ``delta_chi2`` (the noise-corrected
        size, no spread): what the ranking reads (module docstring); ``power`` is its
        expectation over the size's uncertainty.
    """

    candidate: NextMeasurement
    rivals: tuple
    delta_chi2: dict
    dof: dict
    level: dict
    power: dict
    power_min: float
    per_minute: float
    outcome: str
    delta_chi2_fitted: dict = field(default_factory=dict)
    own: dict = field(default_factory=dict)
    power_at_size: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready record."""
        c = self.candidate
        return {"name": c.name, "description": c.description, "time_min": c.time_min,
                "positions": c.positions, "probes": c.probes, "probes_of": c.probes_of,
                "instrument": c.instrument, "repeat": c.repeat,
                "rivals": list(self.rivals), "delta_chi2": self.delta_chi2,
                "delta_chi2_fitted": self.delta_chi2_fitted, "own_parameters": self.own,
                "dof": {k: list(v) for k, v in self.dof.items()}, "level": self.level,
                "power": self.power, "power_min": self.power_min,
                "power_at_size": self.power_at_size,
                "delta_chi2_per_min": self.per_minute, "outcome": self.outcome}


@dataclass(frozen=True)
class Proposals:
    """Ranked proposals for the next measurement.

    Attributes
    ----------
    rivals : tuple of str
        The two rival tokens scored.
    baseline : str
        Spec of the baseline the rivals are added to.
    current : dict
        Rival taken as the truth -> power of its nested test with the current data alone
        (the same formula without a candidate): what the data already decide (not for
        :data:`BASELINE`, which has nothing to see).
    ranked : list of Proposal
        Best first: those reaching ``target`` power by machine time (at equal time by
        power, then Δχ² per minute), then the rest by power.
    skipped : dict
        Candidate name -> why it was not scored (outside the machine, ...).
    target : float
        Power at which a pair counts as decided.
    message : str
        The conclusion in words.
    """

    rivals: tuple
    baseline: str
    current: dict
    ranked: list
    skipped: dict
    target: float
    message: str = ""

    def to_dict(self) -> dict:
        """JSON-ready record (``next`` command's output)."""
        return {"rivals": list(self.rivals), "baseline": self.baseline,
                "current_power": self.current, "target_power": self.target,
                "proposals": [p.to_dict() for p in self.ranked], "skipped": self.skipped,
                "message": self.message}


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
    X and Y strokes (5 % from each end), raised (or lowered) by a third of the
    Z stroke; rotated 90° and 180° in its plane about its centre; stood in XZ and in YZ;
    measured again with a stylus offset ``stylus_offset_mm`` along X, along Y, and a
    stylus 100 mm longer; and, with two styli or more, measured again with its styli in
    reverse order; and where styli were measured in blocks, the first stylus measured
    again at the end of such a placement (:func:`repeat_candidates`, on
    ``repeat_balls`` balls). Each new placement is measured with the reference's styli (the new
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
    probes_in = {p: list(dict.fromkeys(data.meas.loc[data.meas["position"] == p, "probe"]))
                 for p in pos}
    if reference is None:
        reference = next((p for p in pos if data.setup.positions[p].horizontal), next(iter(pos)))
    if reference not in pos:
        raise DataError(f"unknown placement {reference!r}; expected one of {sorted(pos)}.",
                        file=data.name, column="reference", hint="name a placement of the setup")
    ref = pos[reference]
    o = np.asarray(ref["origin_mm"], float)
    u, v = _unit(ref["u_axis"]), _unit(ref["v_axis"])
    styli = probes_in[reference] or [ref.get("probe")]
    half = np.array([(grid.cols - 1), (grid.rows - 1)]) * grid.pitch_mm / 2.0
    centre = o + half[0] * u + half[1] * v
    rng_mm = np.asarray(data.setup.range_mm, float)
    shift = shift_fraction * grid.pitch_mm
    dz = rng_mm[2] / 3.0 * (1.0 if o[2] + rng_mm[2] / 3.0 < 0.8 * rng_mm[2] else -1.0)
    n_balls = grid.rows * grid.cols
    out = []

    def add(name, text, origin, uu, vv, probes_of_new, new_probes=None):
        key = f"next_{name}"
        place = {"origin_mm": [float(x) for x in origin], "u_axis": [float(x) for x in uu],
                 "v_axis": [float(x) for x in vv], "probe": probes_of_new[0]}
        out.append(NextMeasurement(name, text, {key: place}, dict(new_probes or {}),
                             {key: list(probes_of_new)},
                             _placement_time(n_balls, len(probes_of_new), per_ball,
                                             per_place)))

    for a, ax in enumerate("XY"):
        e = np.eye(3)[a]
        add(f"shift_{ax.lower()}", f"the plate of {reference} shifted {shift:g} mm along "
            f"{ax}", o + shift * e, u, v, styli)
    extent = (grid.cols - 1) * grid.pitch_mm * np.abs(u) + (grid.rows - 1) * grid.pitch_mm \
        * np.abs(v)
    low = o - np.minimum(u, 0) * (grid.cols - 1) * grid.pitch_mm \
        - np.minimum(v, 0) * (grid.rows - 1) * grid.pitch_mm  # the plate's lowest corner
    for a, ax in enumerate("XY"):
        for end, corner in (("low", 0.05 * rng_mm[a]),
                            ("high", 0.95 * rng_mm[a] - extent[a])):
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
            o + np.array([0.0, 0.0, 20.0]), uu, np.eye(3)[2], styli)
    tip = np.asarray(raw["probes"][styli[0]], float)
    for name, off, text in (("stylus_x", [stylus_offset_mm, 0, 0],
                             f"{stylus_offset_mm:g} mm along X"),
                            ("stylus_y", [0, stylus_offset_mm, 0],
                             f"{stylus_offset_mm:g} mm along Y"),
                            ("stylus_long", [0, 0, -100.0], "100 mm longer")):
        q = f"next_{name}"
        add(name, f"{reference} again with a new stylus {q} offset {text}", o, u, v, [q],
            {q: (tip + np.asarray(off, float)).tolist()})
    if len(styli) > 1:
        add("reverse", f"{reference} again with its styli in reverse order "
            f"({', '.join(styli[::-1])})", o, u, v, styli[::-1])
    return out + repeat_candidates(data, n_balls=repeat_balls, minutes_per_ball=per_ball)


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


def repeat_candidates(data: Dataset, *, n_balls: int | Sequence[int] = REPEAT_BALLS,
                      minutes_per_ball: float | None = None) -> list[NextMeasurement]:
    """Repeats that tell a placement's drift from its styli's offsets.

    For each placement whose styli were measured in blocks (:func:`blocked_styli`): its
    first stylus measured again on the first ``n_balls`` balls it measured there (the
    same balls, the earliest times), right after the placement's last reading, before its
    plate is moved (``repeat_<placement>_<n>``); and, with two such placements or more,
    the same at the end of each (``repeat_all_<n>``). A stylus's offset repeats
    exactly; a drift of ``v`` µm/h moves the repeated readings by ``v`` times the time
    elapsed since the first ones (``Drift``'s own remedy: "repeating the first ball at
    the end of each position"). Machine time: balls × minutes per ball (the plan's time
    model, ``files.MEASUREMENT_DEFAULTS``; no new placement: the plate stays where it
    is). For a placement no longer on the machine the repeat is a change of plan for the
    next run of the same placements.
    """
    defaults: dict = MEASUREMENT_DEFAULTS
    per_ball = float(defaults["minutes_per_ball"] if minutes_per_ball is None
                     else minutes_per_ball)
    m = data.meas
    out = []
    counts = [int(n_balls)] if isinstance(n_balls, int | np.integer) else \
        [int(n) for n in n_balls]
    blocked = blocked_styli(data)
    named: set = set()  # a count above a stylus's balls gives the same repeat again
    position = m["position"].astype(str)
    for n in counts:
        each = {}
        for p, styli in blocked.items():
            rows = m.loc[(position == str(p)) & (m["probe"].astype(str) == styli[0])]
            rows = rows.sort_values("time_min", kind="stable")
            balls = [int(b) for b in dict.fromkeys(rows["ball"])][:max(n, 1)]
            end = float(m.loc[position == str(p), "time_min"].max())
            each[p] = {"probe": styli[0], "balls": balls,
                       "time_min": [end + per_ball * (j + 1) for j in range(len(balls))]}
            name = f"repeat_{p}_{len(balls)}"
            if name in named:
                continue
            named.add(name)
            out.append(NextMeasurement(
                name, f"stylus {styli[0]} measured again on "
                f"{len(balls)} ball(s) of {p} (balls {', '.join(map(str, balls))}) at the "
                f"end of {p}, before its plate is moved", {}, {}, {},
                len(balls) * per_ball, repeat={p: each[p]}))
        # named by the balls each placement repeats (fewer than n where a stylus has less)
        sizes = sorted({len(r["balls"]) for r in each.values()})
        label = "-".join(map(str, sizes))
        if len(each) > 1 and f"repeat_all_{label}" not in named:
            named.add(f"repeat_all_{label}")
            out.append(NextMeasurement(
                f"repeat_all_{label}", f"the first stylus of each of {', '.join(each)} "
                f"measured again on {label} of its balls at the end of that placement, "
                f"before its plate is moved", {}, {}, {},
                sum(len(r["balls"]) for r in each.values()) * per_ball, repeat=each))
    return out


def _tagged(c: NextMeasurement, tag: str) -> NextMeasurement:
    """The candidate with its placement and new styli renamed by ``tag`` (unique names
    when several references or fractions are combined)."""
    def ren(n):
        return f"{n}_{tag}" if n.startswith("next_") else n

    return NextMeasurement(
        f"{c.name}_{tag}", c.description,
        {ren(p): {**pl, "probe": ren(pl["probe"])} for p, pl in c.positions.items()},
        {ren(q): v for q, v in c.probes.items()},
        {ren(p): [ren(q) for q in qs] for p, qs in c.probes_of.items()}, c.time_min,
        c.instrument, c.repeat)


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


def append_measurement(data: Dataset, cand: NextMeasurement, *, config: dict | None = None,
              seed: int = 0) -> Dataset:
    """The data set with the candidate's measurement appended, simulated on the virtual
    CMM with ``config``'s errors (default: none, no noise) in the data's machine frame.

    The simulated readings are moved by the certificate's departure from the nominal
    grid (rotated into the placement), so that the appended balls are the certificate's.

    A repeat (``cand.repeat``) is simulated at its placement's pose in the setup (the
    truth of a simulated data set) and appended to that placement; its drift continues
    that of the readings before: ``config``'s ``effects.drift`` must then give each
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
    new = new.assign(repeat=again)
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


def rival_pairs(candidates: Sequence[Mapping[str, Any]], *, top: int = 3
                ) -> list[tuple[str, str]]:
    """Every pair a diagnosis leaves open, most pressing first: the first candidate
    with each of its aliases; its runner-up (the next significant candidate of another
    function); then each alias of the next ``top - 1`` significant candidates. Each pair
    once, whichever its order.

    Parameters
    ----------
    candidates : sequence of mappings
        The diagnosis's ranked candidates as ``Candidate.to_dict`` gives them (at least
        ``effect``, ``aliases`` (list of tokens) and ``significant``); optional
        ``stands_in_for_scale``: true when the placement-scale test found the candidate
        standing in for each placement's own scale (then it and :data:`PLACEMENT_SCALE`
        are a pair, after the aliases); optional ``would_leave_undetermined`` (list):
        the parameter combinations its addition leaves undetermined (then it and
        :data:`BASELINE` are a pair, last).
    top : int
        How many of the first candidates' aliases count.
    """
    out: list[tuple[str, str]] = []

    def add(a: str, b: str) -> None:
        if a != b and (a, b) not in out and (b, a) not in out:
            out.append((a, b))

    if not candidates:
        return out
    first = candidates[0]
    for al in first["aliases"]:
        add(first["effect"], al)
    name = str(first["effect"]).partition(":")[0]
    other = next((c for c in candidates[1:] if c["significant"]
                  and str(c["effect"]).partition(":")[0] != name), None)
    if other is not None:
        add(first["effect"], other["effect"])
    for c in [c for c in candidates[1:] if c["significant"]][:max(top - 1, 0)]:
        for al in c["aliases"]:
            add(c["effect"], al)
    for c in candidates[:max(top, 1)]:
        if c.get("stands_in_for_scale"):
            add(c["effect"], PLACEMENT_SCALE)
    for c in candidates[:max(top, 1)]:
        if c.get("would_leave_undetermined"):
            add(c["effect"], BASELINE)
    return out


def open_pairs(diagnosis: Diagnosis | Mapping[str, Any], *, top: int = 3
               ) -> list[tuple[str, str]]:
    """Every pair of rivals a diagnosis leaves open (:func:`rival_pairs`), read from the
    diagnosis itself: each candidate's aliases and significance, whether it stands in
    for each placement's own scale (``HoldoutCheck.stands_in_for_scale``, the rule
    ``diagnosis.crossval.check`` judges by; not merely a failed check), and the combinations its addition would leave
    undetermined (then it and :data:`BASELINE` are a pair). The one rule of the ``next``
    command's default rivals (:func:`rivals_of`) and the app's "Measure next".

    Parameters
    ----------
    diagnosis : Diagnosis or mapping
        A :class:`~cmm_core.diagnosis.Diagnosis`, or its JSON document
        (``Diagnosis.to_dict``, the ``diagnose`` command's output): ``candidates`` as
        ``Candidate.to_dict`` gives them (aliases as a list), ``holdout`` as
        ``HoldoutCheck.to_dict`` (absent: no placement-scale pair).
    top : int
        How many of the first candidates count (:func:`rival_pairs`).
    """
    if isinstance(diagnosis, Diagnosis):
        cands = [{"effect": c.effect, "aliases": list(c.aliases),
                  "significant": bool(c.significant), "level": float(c.level),
                  "would_leave_undetermined": list(c.would_leave_undetermined)}
                 for c in diagnosis.candidates]
        scale = {h.effect: h.stands_in_for_scale for h in diagnosis.holdout}
    else:
        cands = [dict(c) for c in diagnosis.get("candidates") or []]
        scale = {h["effect"]: bool(h.get("stands_in_for_scale"))
                 for h in diagnosis.get("holdout") or []}
    return rival_pairs([{"effect": c["effect"], "aliases": list(c["aliases"]),
                         "significant": bool(c["significant"]),
                         "stands_in_for_scale": scale.get(c["effect"], False),
                         "would_leave_undetermined": list(
                             c.get("would_leave_undetermined") or [])}
                        for c in cands], top=top)


def rivals_of(diagnosis: Diagnosis) -> tuple[str, str]:
    """The pair the diagnosis leaves open: the first of :func:`open_pairs` for its first
    candidate (``top=1``): its first alias, or else the next significant candidate of
    another function (a runner-up), or else :data:`PLACEMENT_SCALE` when it stands in
    for each placement's own scale, or else :data:`BASELINE` when its addition would
    leave combinations undetermined.

    Raises
    ------
    ValueError
        When the diagnosis ranked no candidate or leaves no pair open.
    """
    cands = diagnosis.candidates
    if not cands:
        raise ValueError("the diagnosis ranked no candidate: there is nothing to decide.")
    pairs = open_pairs(diagnosis, top=1)
    if not pairs:
        raise ValueError(f"the diagnosis names {cands[0].effect} with no alias, no "
                         "significant runner-up, no stand-in for the placements' scales "
                         "and nothing left undetermined: there is nothing to decide; give "
                         "the rivals.")
    return pairs[0]


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


def _basis(A: np.ndarray, rtol: float, sv_ref: float | None = None) -> tuple:
    """Orthonormal basis of the column space of ``A`` (columns scaled to unit norm, the
    fit's rank rule: singular values above ``rtol`` times the largest, or ``sv_ref``)."""
    norms = np.linalg.norm(A, axis=0)
    S = A / np.where(norms > 0, norms, 1.0)
    if not S.size:
        return np.zeros((A.shape[0], 0)), 0.0
    U, sv, _ = np.linalg.svd(S, full_matrices=False)
    ref = sv.max() if sv_ref is None else sv_ref
    return U[:, sv > rtol * ref], float(sv.max())


@dataclass(frozen=True)
class _Design:
    """Weighted Jacobian at the nominal linearisation of the model holding both rivals,
    its column labels, and which labels each rival's own model has."""

    J: np.ndarray
    labels: list
    has: dict


def _both(rf: RivalFits):
    """The model holding both rivals (the baseline for a placement-scale rival)."""
    a, b = rf.rivals
    return rf.specs[a] if b in PSEUDO else rf.specs[a].with_token(b)


def scale_columns(obs: Observations, sigma_um: float, n_rows: int
                  ) -> tuple[np.ndarray, list[str]]:
    """Weighted columns of each placement's own scale (1 ppm) along each machine axis it
    spans, rows as the weighted residual's (``diagnosis.scale_columns``, the columns of
    the diagnosis's placement-scale test, for any observations). Labels
    ``<placement>.scale_<axis>``."""
    S, labels = placement_scales(obs, sigma_um, n_rows)
    return S, [f"{name}.scale_{axis}" for name, axis in labels]


def _design(obs, rf: RivalFits) -> _Design:
    a, b = rf.rivals
    f = rf.fits[a]
    prob = Problem(obs, _both(rf), f.plate)
    J = weighted_residual(prob, prob.initial_state(), f.sigma_um, True)[2].toarray()
    labels = list(prob.layout.labels)
    has = {r: set(Problem(obs, rf.specs[r], f.plate).layout.labels) for r in (a, b)}
    if PLACEMENT_SCALE in rf.rivals:
        S, lab_s = scale_columns(obs, f.sigma_um, J.shape[0])
        J = np.hstack([J, S])
        labels += lab_s
        has[PLACEMENT_SCALE] |= set(lab_s)
    return _Design(J, labels, has)


def _stack(d1: _Design, d2: _Design) -> _Design:
    """The design of both observation sets: rows stacked, columns matched by label (a
    parameter one set does not have has zero columns there)."""
    labels = list(dict.fromkeys(d1.labels + d2.labels))
    col = {lab: i for i, lab in enumerate(labels)}
    J = np.zeros((d1.J.shape[0] + d2.J.shape[0], len(labels)))
    J[:d1.J.shape[0], [col[lab] for lab in d1.labels]] = d1.J
    J[d1.J.shape[0]:, [col[lab] for lab in d2.labels]] = d2.J
    return _Design(J, labels, {r: d1.has[r] | d2.has[r] for r in d1.has})


def _separation(des: _Design, truth: str, other: str, theta: dict, *, rank_rtol: float,
                level: float, spread: tuple | None = None) -> tuple:
    """(λ, k, ν, power, λ at the fitted size, parameter count, power at λ) of the nested
    test "``truth`` is needed once ``other`` is in" on the noise-free design with ``truth``
    true at ``theta`` (module docstring). ``spread``: ``(labels, covariance)`` of
    ``theta``'s fit; λ is then the expected-size estimate ``‖M θ‖² − tr(M C Mᵀ)`` (at
    least 0), which takes out what the fitted size owes to noise, and the power is the
    expected power over the size's uncertainty (:func:`_expected_power`); the last item
    is the power at λ itself (what the ranking reads, module docstring)."""
    lab_b = des.has[other]
    own = [i for i, lab in enumerate(des.labels) if lab in des.has[truth] and lab not in lab_b]
    JB = des.J[:, [i for i, lab in enumerate(des.labels) if lab in lab_b]]
    JA = des.J[:, own]
    U, sv_max = _basis(JB, rank_rtol)
    mu = JA @ np.array([theta.get(des.labels[i], 0.0) for i in own])
    lam_fit = float(np.sum((mu - U @ (U.T @ mu)) ** 2))
    M = JA - U @ (U.T @ JA)
    k = _basis(M, rank_rtol, sv_max)[0].shape[1] if own else 0
    nu = max(des.J.shape[0] - U.shape[1] - k, 1)
    if k == 0:
        return 0.0, 0, nu, 0.0, 0.0, len(own), 0.0
    lam = lam_fit
    if spread is not None:
        at = {lab: i for i, lab in enumerate(spread[0])}
        ix = [at.get(des.labels[i], -1) for i in own]
        C = np.zeros((len(own), len(own)))
        got = [j for j, i in enumerate(ix) if i >= 0]
        C[np.ix_(got, got)] = np.asarray(spread[1])[np.ix_([ix[j] for j in got],
                                                          [ix[j] for j in got])]
        lam = max(lam_fit - float(np.sum((M @ C) * M)), 0.0)
        theta_own = np.array([theta.get(des.labels[i], 0.0) for i in own])
        return lam, k, nu, _expected_power(M.T @ M, theta_own, C, k, nu, level), lam_fit, \
            len(own), _power(lam, k, nu, level)
    point = _power(lam, k, nu, level)
    return lam, k, nu, point, lam_fit, len(own), point


def _expected_power(G: np.ndarray, theta: np.ndarray, cov: np.ndarray, k: int, nu: int,
                   level: float, draws: int = _ASSURANCE_DRAWS) -> float:
    """Expected power ``E[P(F(k, ν, λ(θ)) > F⁻¹(1 − α))]`` over ``θ ~ N(θ̂, C)``, with
    ``λ(θ) = θᵀ G θ`` (``G = MᵀM``, module docstring): the assurance of the nested test
    (O'Hagan & Stevens 2001, "Bayesian assessment of sample size for clinical trials of
    cost-effectiveness", Med. Decis. Making 21: the power averaged over a design prior;
    Spiegelhalter, Abrams & Myles 2004, §6.5), the design prior being the current data's
    posterior of the rival's own parameters under a flat prior, ``N(θ̂, C)``, ``C`` the
    fit's covariance (σ known; the linear model's posterior, Box & Tiao 1973 §2.7).

    Why not the power at one size: λ is a quadratic form in θ, and the fitted θ̂ may be
    hardly more than its noise along ``M`` (a proposal is asked for because the current
    data do not separate the rivals). The unbiased ``‖M θ̂‖² − tr(M C Mᵀ)`` is then often
    clipped at 0, where the power is the level, although the truth's λ is, as often, well
    above it (a drift rate of 1 µm/h spread fitted within ±1.3-3.5 µm/h,
    docs/proposals.md "Validation"). Averaging the power over the sizes the data allow
    weighs the large λ the data cannot exclude as well as the small. ``λ(θ)`` under
    ``θ ~ N(θ̂, C)`` is a weighted sum of non-central χ² variables (with ``C = L Lᵀ``
    and ``Lᵀ G L = V diag(w) Vᵀ``: ``Σ w_j χ²₁(δ_j²)``, ``δ = Vᵀ L⁻¹ θ̂``), and ``P`` is
    a non-central F tail: the expectation is taken by quasi-Monte Carlo, ``draws``
    scrambled Sobol' normal points ``z`` each with its mirror, ``θ̂ ± L z`` (Owen 1997,
    randomised QMC; fixed seed: the same number for the same design; the two of a pair
    have the same mean, so E[θ] is exact and the odd part of λ in ``z`` cancels), every
    power at once (vectorised ``ncf.sf``). With ``C → 0`` it is the power at ``λ(θ̂)``.

    Parameters
    ----------
    G : ndarray (p, p)
        ``MᵀM``: λ of a size θ is ``θᵀ G θ``.
    theta : ndarray (p,)
        The fitted size ``θ̂``.
    cov : ndarray (p, p)
        Its covariance ``C`` (positive semi-definite; negative eigenvalues from rounding
        are taken as 0).
    k, nu : int
        Numerator and denominator dof of the nested F-test.
    level : float
        Its level α.
    draws : int
        Antithetic pairs of the Monte Carlo.

    Returns
    -------
    float
        The expected power, in ``[level, 1]``.
    """
    theta = np.asarray(theta, float)
    cov = np.asarray(cov, float)
    w, V = np.linalg.eigh(0.5 * (cov + cov.T)) if theta.size else (np.zeros(0), cov)
    L = V * np.sqrt(np.clip(w, 0.0, None))
    if not theta.size or not np.any(L):
        return _power(float(theta @ G @ theta), k, nu, level)
    d = L @ _normal_points(theta.size, int(draws))
    # λ(θ̂ ± d) = θ̂ᵀGθ̂ ± 2 θ̂ᵀG d + dᵀG d
    base, cross = float(theta @ G @ theta), 2.0 * (theta @ G) @ d
    quad = np.sum(d * (G @ d), axis=0)
    lam = np.concatenate([base + cross + quad, base - cross + quad])
    return float(np.mean(_powers(np.clip(lam, 0.0, None), k, nu, level)))


def _power(lam: float, k: int, nu: int, level: float) -> float:
    """P(F(k, ν, λ) > F⁻¹(1 − level; k, ν)) at one λ (:func:`_powers`)."""
    return float(_powers(np.array([lam], float), k, nu, level)[0])


@lru_cache(maxsize=64)
def _normal_points(dim: int, n: int) -> np.ndarray:
    """``(dim, n)`` standard normal points: scrambled Sobol' (``_ASSURANCE_SEED``) through
    the normal quantile; cached (read-only), as every candidate of a rival asks for the
    same."""
    u = qmc.Sobol(dim, scramble=True, seed=_ASSURANCE_SEED).random(n)
    z = stats.norm.ppf(np.clip(u, 1e-12, 1.0 - 1e-12)).T
    z.flags.writeable = False
    return z


def _powers(lam: np.ndarray, k: int, nu: int, level: float) -> np.ndarray:
    """P(F(k, ν, λ) > F⁻¹(1 − level; k, ν)) for each λ: the level itself at λ = 0
    (scipy's ``ncf`` returns nonsense there, e.g. -0.99), the χ² limit (ν → ∞) where
    ``ncf`` fails."""
    lam = np.asarray(lam, float)
    crit = stats.f.isf(level, k, nu)
    with np.errstate(all="ignore"):
        p = np.array(np.broadcast_to(stats.ncf.sf(crit, k, nu, lam), lam.shape), float)
    bad = ~((p >= 0.0) & (p <= 1.0))
    if bad.any():
        p[bad] = stats.ncx2.sf(k * crit, k, lam[bad])
    p = np.minimum(np.maximum(p, float(level)), 1.0)
    p[lam <= 0.0] = float(level)
    return p


def _outcome(cand: NextMeasurement, rivals, lam: dict, power_min: float,
             rank: tuple | None = None) -> str:
    a, b = rivals
    if b == BASELINE:
        k, k_now = rank or (0, 0)
        return (f"with {cand.description}, the data determine {k} parameter "
                f"combination(s) of {a} ({k_now} now) and it stands out by Δχ² ≈ "
                f"{lam[a]:.0f}: decided with {100 * power_min:.0f} % power in "
                f"{cand.time_min:.0f} min")
    return (f"with {cand.description}, {a} and {b} differ by Δχ² ≈ {min(lam.values()):.0f}"
            f" ({a} true: {lam[a]:.0f}, {b} true: {lam[b]:.0f}): decided with "
            f"{100 * power_min:.0f} % power in {cand.time_min:.0f} min")


@dataclass(frozen=True)
class RivalFits:
    """The two rivals fitted to the current data.

    Attributes
    ----------
    rivals : tuple of str
        The rival tokens (A, B).
    specs : dict
        Rival -> the baseline with it added (``ModelSpec``).
    fits : dict
        Rival -> its ``FitResult`` on the current data.
    levels : dict
        Rival -> the level its nested test is judged at: for two model tokens the first
        rival's level, both directions (:func:`fit_rivals`).
    """

    rivals: tuple
    specs: dict
    fits: dict
    levels: dict


def fit_rivals(data: Dataset, rivals: Sequence[str], *, baseline: str = "kinematic21", order: int = 2,
               plate: str | None = None, sigma_um: float = 0.5,
               alpha: float = FAMILY_ALPHA) -> RivalFits:
    """Fit the baseline with each rival added to the current data (their fitted sizes),
    and the level each direction is judged at (:func:`_levels`: for two model tokens the
    first rival's, ``detect.candidate_tokens``).

    Raises
    ------
    ValueError
        When a rival is a pseudo-rival given first, or a rival token the baseline already
        holds (adding it changes nothing: there would be nothing to tell apart).
    """
    if rivals[0] in PSEUDO:
        raise ValueError(f"give {rivals[0]} as the second rival (after the effect it is "
                         "told apart from).")
    base = fit(data, baseline, order=order, plate=plate, sigma_um=sigma_um, max_iter=2000)
    spec0 = base.problem.spec
    specs = {r: spec0 if r in PSEUDO else spec0.with_token(r) for r in rivals}
    for r in rivals:
        if r not in PSEUDO and specs[r] == spec0:
            b0 = spec0.to_string()
            raise ValueError(f"{r} is already in the baseline {b0}; give a baseline without "
                             f"it (e.g. '{b0},-{r.partition(':')[0]}').")
    fits = {r: _scale_fit(base) if r == PLACEMENT_SCALE else base if r == BASELINE else
            fit(data, specs[r], plate=base.plate, sigma_um=sigma_um, max_iter=2000,
                certificate_test=False) for r in rivals}
    return RivalFits(tuple(rivals), specs, fits, _levels(base, rivals, alpha))


def _levels(base: FitResult, rivals: Sequence[str], alpha: float) -> dict:
    """Rival -> the level its nested test is judged at (module docstring): both
    directions of two model tokens at the first rival's own level (its share of
    ``alpha``, ``detect.candidate_tokens``), as the diagnosis's nested tests judge both
    at the level of the candidate it ranks first (``verdict._encompassing``), which is
    the first rival when the rivals are the diagnosis's (:func:`rivals_of`,
    :func:`open_pairs`); :data:`PLACEMENT_SCALE` at the placement-scale test's level
    (``SCALE_ALPHA``, as ``crossval.check`` judges it) and the effect against it at its
    own; :data:`BASELINE` at ``alpha`` (it has nothing to see: not scored)."""
    own = {**candidate_tokens(base, alpha)[2], PLACEMENT_SCALE: SCALE_ALPHA, BASELINE: alpha}
    fallback = alpha / max(len(own), 1)
    a = rivals[0]
    first = float(own.get(a, own.get(a.partition(":")[0], fallback)))
    return {r: float(own[r]) if r in PSEUDO else first for r in rivals}


@dataclass(frozen=True)
class ScaleFit:
    """Each placement's own scale fitted to the baseline's residual (the rival
    :data:`PLACEMENT_SCALE`, linearised at the baseline's fit as the diagnosis's
    placement-scale test): what :class:`RivalFits` reads of a fit.

    Attributes
    ----------
    labels : list of str
        ``<placement>.scale_<axis>`` (:func:`scale_columns`).
    values : ndarray
        Fitted scales (ppm).
    covariance : ndarray
        Their covariance (ppm²) from σ.
    rank_rtol : float
        The baseline fit's rank rule.
    problem : Problem
        The baseline's problem.
    sigma_um : float
        σ of the fit (µm).
    plate : str
        The baseline's plate geometry.
    """

    labels: list
    values: np.ndarray
    covariance: np.ndarray
    rank_rtol: float
    problem: Problem
    sigma_um: float
    plate: str


def _scale_fit(base: FitResult) -> ScaleFit:
    """The placement scales fitted to the baseline's weighted residual with the
    baseline's columns projected out (Frisch-Waugh-Lovell)."""
    r, J = weighted_residual(base.problem, base.state, base.sigma_um, True)[1:]
    J = J.toarray()
    S, labels = scale_columns(base.problem.obs, base.sigma_um, r.size)
    Q, _ = _basis(J, base.rank_rtol)
    norms = np.linalg.norm(S, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    Sp = (S - Q @ (Q.T @ S)) / norms
    # the scales the baseline leaves undetermined (what is left of a column after the
    # baseline is projected out is below SCALE_RTOL of it) are not fitted: zero, zero
    # variance (as the placement-scale test's rank rule)
    U, sv, Vt = np.linalg.svd(Sp, full_matrices=False)
    keep = sv > SCALE_RTOL
    V, inv = Vt[keep].T, 1.0 / sv[keep]
    # r is readings minus model: a placement's scale moves its readings by s (x - x̄)
    values = (V * inv) @ (U[:, keep].T @ r) / norms
    cov = ((V * inv**2) @ V.T) / np.outer(norms, norms)
    return ScaleFit(labels, values, cov, base.rank_rtol, base.problem, base.sigma_um,
                    base.plate)


def _score_on(des: _Design, rf: RivalFits) -> dict:
    a, b = rf.rivals
    out = {}
    for t, o in ((a, b), (b, a)):
        f = rf.fits[t]
        out[t] = _separation(des, t, o, dict(zip(f.labels, f.values, strict=True)),
                             rank_rtol=f.rank_rtol, level=rf.levels[t],
                             spread=(f.labels, f.covariance))
    return out


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


def _in_machine(data: Dataset, cands: list) -> tuple:
    """(observations of the candidates that fit in the machine, those candidates, skipped
    ones with the reason); one simulation unless some do not fit."""
    try:
        return measurement_observations(data, cands), list(cands), {}
    except DataError:
        ok, skipped = [], {}
        for c in cands:
            try:
                measurement_observations(data, [c])
                ok.append(c)
            except DataError as exc:
                skipped[c.name] = str(exc)
        return (measurement_observations(data, ok) if ok else None), ok, skipped


_SIMULATORS: dict = {"laser": simulate_laser, "step_gauge": simulate_step_gauge,
               "ball_bar": simulate_ball_bar}


def instrument_candidates(data: Dataset, *, reference: str | None = None,
                          n_readings: int = 21, minutes_per_ball: float | None = None,
                          minutes_per_placement: float | None = None
                          ) -> list[NextMeasurement]:
    """Instrument candidates: a laser positioning run along X, Y and Z through the
    reference plate's centre (``n_readings`` readings from 5 % to 95 % of the stroke,
    reflector at the reference stylus's offset); a step gauge along X and along Y (from
    5 % of the stroke, ``n_readings - 1`` lengths up to 80 % of it); a ball bar of 40 % of
    the smaller horizontal stroke in four orientations (0°, 45°, 90°, 135°) about that
    centre. Machine time: readings × minutes per ball + minutes per placement (setting
    the instrument up), the plan's time model applied to instruments (an assumption:
    ``files.MEASUREMENT_DEFAULTS``)."""
    defaults: dict = MEASUREMENT_DEFAULTS
    per_ball = float(defaults["minutes_per_ball"] if minutes_per_ball is None
                     else minutes_per_ball)
    per_place = float(defaults["minutes_per_placement"] if minutes_per_placement is None
                      else minutes_per_placement)
    grid = plate_grid(data)
    pos = data.setup.raw["positions"]
    if reference is None:
        reference = next((p for p in pos if data.setup.positions[p].horizontal), next(iter(pos)))
    ref = pos[reference]
    u, v = _unit(ref["u_axis"]), _unit(ref["v_axis"])
    centre = (np.asarray(ref["origin_mm"], float) + (grid.cols - 1) * grid.pitch_mm / 2 * u
              + (grid.rows - 1) * grid.pitch_mm / 2 * v)
    tip = [float(x) for x in data.setup.raw["probes"][ref["probe"]]]
    R = np.asarray(data.setup.range_mm, float)
    out = []
    for a, ax in enumerate("xyz"):
        out.append(NextMeasurement(
            f"laser_{ax}", f"a laser positioning run along {ax.upper()} through the centre "
            f"of {reference} ({n_readings} readings)", {}, {}, {},
            n_readings * per_ball + per_place,
            {"kind": "laser", "axis": ax, "line_mm": centre.tolist(),
             "positions_mm": np.linspace(0.05 * R[a], 0.95 * R[a], n_readings).tolist(),
             "offset_mm": tip}))
    for a, ax in enumerate("xy"):
        start = centre.copy()
        start[a] = 0.05 * R[a]
        end = start.copy()
        end[a] = 0.85 * R[a]
        out.append(NextMeasurement(
            f"step_gauge_{ax}", f"a step gauge along {ax.upper()} through the centre of "
            f"{reference} ({n_readings - 1} lengths)", {}, {}, {},
            (n_readings - 1) * per_ball + per_place,
            {"kind": "step_gauge", "start_mm": start.tolist(), "end_mm": end.tolist(),
             "lengths_mm": np.linspace(0.8 * R[a] / (n_readings - 1), 0.8 * R[a],
                                       n_readings - 1).tolist(), "offset_mm": tip}))
    half = 0.2 * min(R[0], R[1])
    ang = np.deg2rad([0.0, 45.0, 90.0, 135.0])
    d = half * np.column_stack([np.cos(ang), np.sin(ang), np.zeros(4)])
    out.append(NextMeasurement(
        "ball_bar_xy", f"a ball bar of {2 * half:g} mm at 0°, 45°, 90° and 135° in XY about "
        f"the centre of {reference}", {}, {}, {}, 4 * 2 * per_ball + per_place,
        {"kind": "ball_bar", "start_mm": (centre - d).tolist(),
         "end_mm": (centre + d).tolist(), "offset_mm": tip}))
    return out


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


def _instrument_design(obs, now: _Design, rf: RivalFits, inst) -> _Design:
    """The design rows of one instrument: the rows it appends to the current data's."""
    f = rf.fits[rf.rivals[0]]
    prob = Problem(replace(obs, instruments=(inst,)), _both(rf), f.plate)
    J = weighted_residual(prob, prob.initial_state(), f.sigma_um, True)[2].toarray()
    return _Design(J[now.J.shape[0]:], list(prob.layout.labels), now.has)


def _rows(des: _Design, keep: np.ndarray) -> _Design:
    """The design of some observations only (``keep``: one flag per observation; three
    weighted rows each, first), without the columns that are empty there. Rows after the
    observations' (a plate prior's, three per certificate ball) are left out: the current
    data's design holds them once."""
    J = des.J[:3 * len(keep)][np.repeat(keep, 3)]
    used = np.abs(J).sum(axis=0) > 0
    return _Design(J[:, used], [lab for lab, u in zip(des.labels, used, strict=True) if u],
                   des.has)


def _proposals(results, rivals, rf: RivalFits, rank_now: int = 0) -> list:
    """Proposals from ``(candidate, {rival: (λ, k, ν, power, λ fitted, parameters,
    power at λ)})`` pairs."""
    out = []
    for cand, res in results:
        lam = {t: v[0] for t, v in res.items()}
        power = {t: v[3] for t, v in res.items()}
        # with the baseline true there is nothing to see: the effect's power decides
        pmin = min(v for t, v in power.items() if t != BASELINE)
        lmin = min(v for t, v in lam.items() if t != BASELINE)
        a = rivals[0]
        out.append(Proposal(cand, rivals, lam, {t: (v[1], v[2]) for t, v in res.items()},
                            dict(rf.levels), power, pmin, lmin / cand.time_min,
                            _outcome(cand, rivals, lam, pmin, (res[a][1], rank_now)),
                            {t: v[4] for t, v in res.items()},
                            {t: v[5] for t, v in res.items()},
                            {t: v[6] for t, v in res.items()}))
    return out


def _power_max(p: Proposal) -> float:
    """The larger of the two powers at the noise-corrected sizes (the effect's alone
    against :data:`BASELINE`)."""
    return max(v for t, v in _ranked_power(p).items() if t != BASELINE)


def _power_min(p: Proposal) -> float:
    """The smaller of the two powers at the noise-corrected sizes (the effect's alone
    against :data:`BASELINE`)."""
    return min(v for t, v in _ranked_power(p).items() if t != BASELINE)


def _ranked_power(p: Proposal) -> dict:
    """The powers the ranking reads: at the noise-corrected sizes (module docstring)."""
    return p.power_at_size or p.power


def _delta_chi2_max(p: Proposal) -> float:
    """The larger expected Δχ² (of the augmented data: the current data's share too)."""
    return max(v for t, v in p.delta_chi2.items() if t != BASELINE)


def _rank_key(target: float):
    """Ranking: proposals reaching ``target`` power first, by machine time; then the
    others by power; at equal time by power, then by the other direction's power, then
    by the smaller Δχ² per minute, then by the larger Δχ² (when the smaller power is
    below :data:`NO_POWER`: the larger Δχ² first, the smaller being noise), then by
    name (the same order however the candidates were split). Powers are compared in whole percent (as they
    are shown): a smaller difference is none, and powers below :data:`NO_POWER` are all
    alike. The other direction decides when one rival cannot be seen whatever is
    measured (its size fitted to hardly more than noise: its power near the level for
    every candidate, 0.013 against 0.001 being no difference): the pair is then decided,
    if at all, by the other rival standing out, and the candidate that shows it best
    comes first. The powers read are those at the noise-corrected sizes
    (``Proposal.power_at_size``, module docstring)."""
    def pct(x: float) -> float:
        # rounded twice: the same candidate scored in another chunk differs by 1e-15;
        # below NO_POWER nothing is decided: no difference
        x = round(round(x, 9), 2)
        return 0.0 if x < NO_POWER else x

    def key(p: Proposal) -> tuple:
        pmin = _power_min(p)
        seen = pct(pmin) > 0.0
        # the smaller Δχ² per minute while both rivals can be seen; else the other's Δχ²
        size = (-round(p.per_minute, 6), -round(_delta_chi2_max(p), 6)) if seen else \
            (-round(_delta_chi2_max(p), 6), -round(p.per_minute, 6))
        return (pmin < target, p.candidate.time_min if pmin >= target
                else -pct(pmin), -pct(pmin), -pct(_power_max(p)), *size,
                p.candidate.name)

    return key


def _score_candidates(now: _Design, obs, ok: list, rf: RivalFits):
    """``(candidate, {rival: (λ, k, ν, power)})`` for each candidate, from one design of
    all their observations (rows of each placement stacked onto the current data's)."""
    if obs is None:
        return
    extra = _design(obs, rf)
    for cand in ok:
        keep = obs.pos == obs.positions.index(next(iter(cand.positions)))
        yield cand, _score_on(_stack(now, _rows(extra, keep)), rf)


def _union(reps: list) -> NextMeasurement | None:
    """One repeat holding every candidate's rows, or None when two candidates repeat a
    ball with the same stylus at different times (they cannot share one design)."""
    rows: dict = {}
    for c in reps:
        for p, r in c.repeat.items():
            for b, t in zip(r["balls"], r["time_min"], strict=True):
                if rows.setdefault((p, r["probe"], int(b)), float(t)) != float(t):
                    return None
    each: dict = {}
    for (p, q, b), t in rows.items():
        if p in each and each[p]["probe"] != q:
            return None
        r = each.setdefault(p, {"probe": q, "balls": [], "time_min": []})
        r["balls"].append(b)
        r["time_min"].append(t)
    return NextMeasurement("repeats", "every repeat", {}, {}, {}, 0.0, repeat=each)


def _score_repeats(data: Dataset, reps: list, rf: RivalFits):
    """``(candidate, {rival: (λ, k, ν, power, ...)})`` for each repeat. A repeat adds rows
    to placements already measured, so its design is that of the whole augmented data
    set, its hours counted from the mean time of the placement's readings before (moving
    that centre changes a drift column by a multiple of the placement's translation
    columns, which every rival holds: the projections and λ do not change; the fit of the
    augmented data centres anew). One design of all the repeats' rows together serves
    each: its rows are the current data's and that candidate's."""
    if not reps:
        return
    union = _union(reps)
    if union is None:
        for c in reps:
            yield c, _score_on(_design(select(append_measurement(data, c)), rf), rf)
        return
    obs = select(append_measurement(data, union))
    t = obs.table
    new = (t["source"] == f"proposal {union.name}").to_numpy()
    # each placement's hours from the mean time of its readings before (the current
    # data's own centring): the current rows' design is then the same whichever
    # repeats the union holds (the same numbers however the candidates are split)
    tm = t["time_min"].to_numpy(float)
    hours = obs.hours.copy()
    for i in range(len(obs.positions)):
        at = obs.pos == i
        if (at & new).any():
            hours[at] = (tm[at] - tm[at & ~new].mean()) / 60.0
    obs = replace(obs, hours=hours)
    des = _design(obs, rf)
    key = list(zip(t["position"].astype(str), t["probe"].astype(str), t["ball"].astype(int),
                   strict=True))
    n3 = 3 * len(t)
    for c in reps:
        mine = {(p, r["probe"], int(b)) for p, r in c.repeat.items() for b in r["balls"]}
        keep = np.repeat(~new | np.array([k in mine for k in key]), 3)
        J = np.vstack([des.J[:n3][keep], des.J[n3:]])
        yield c, _score_on(_Design(J, des.labels, des.has), rf)


@single_blas_thread
def propose(data: Dataset, rivals: Sequence[str] | None = None, *, baseline: str = "kinematic21", order: int = 2,
            plate: str | None = None, sigma_um: float = 0.5, alpha: float = FAMILY_ALPHA,
            cands: list | None = None, target: float = TARGET_POWER,
            diagnosis: Diagnosis | None = None) -> Proposals:
    """Rank candidate measurements by how well they decide between two rivals.

    Parameters
    ----------
    data : Dataset
        The current measurements (with a certificate of a regular-grid plate).
    rivals : sequence of two str, optional
        The rival tokens; default the diagnosis's first candidate and its alias or
        runner-up (:func:`rivals_of`), running ``diagnose`` when ``diagnosis`` is None.
    baseline, order, plate, sigma_um, alpha
        The diagnosis's settings.
    cands : list of NextMeasurement, optional
        Default :func:`measurement_candidates` of the data.
    target : float
        Power at which a proposal decides the pair.

    Returns
    -------
    Proposals
    """
    if rivals is None:
        diagnosis = diagnosis or diagnose(data, baseline, order=order, plate=plate,
                                          sigma_um=sigma_um, alpha=alpha)
        rivals = rivals_of(diagnosis)
    rivals = tuple(rivals)
    if len(rivals) != 2 or rivals[0] == rivals[1]:
        raise ValueError(f"expected two different rival tokens, got {list(rivals)}.")
    rf = fit_rivals(data, rivals, baseline=baseline, order=order, plate=plate,
                    sigma_um=sigma_um, alpha=alpha)
    now = _design(select(data), rf)
    scores_now = _score_on(now, rf)
    current = {t: v[3] for t, v in scores_now.items() if t != BASELINE}
    rank_now = scores_now[rivals[0]][1]
    cands = list(cands if cands is not None else measurement_candidates(data))
    plates = [c for c in cands if not c.instrument and not c.repeat]
    scored, skipped = [], {}
    for i in range(0, len(plates), CHUNK):  # one simulation and design per chunk
        obs, ok, out = _in_machine(data, plates[i:i + CHUNK])
        skipped.update(out)
        scored += _proposals(_score_candidates(now, obs, ok, rf), rivals, rf, rank_now)
    scored += _proposals(_score_repeats(data, [c for c in cands if c.repeat], rf), rivals,
                         rf, rank_now)
    tools = [c for c in cands if c.instrument]
    if tools:
        sim0, obs_now = _machine(data), select(data)
        scored += _proposals(((c, _score_on(_stack(now, _instrument_design(
            obs_now, now, rf, instrument_of(c, sim0))), rf)) for c in tools), rivals, rf,
            rank_now)
    scored.sort(key=_rank_key(target))
    a, b = rivals
    if scored:
        msg = (f"{a} against {b}: the current data decide with {100 * min(current.values()):.0f}"
               f" % power. Best next measurement: {scored[0].outcome}.")
    else:
        msg = f"{a} against {b}: no candidate measurement fits in the machine."
    return Proposals(rivals, rf.fits[a].problem.spec.to_string(), current, scored, skipped,
                     target, msg)


def _score_chunk(cands: list, data: Dataset, rivals, settings: dict) -> Proposals:
    """One Dask task of :func:`propose_many` (BLAS single-threaded: ``propose``)."""
    return propose(data, rivals, cands=cands, **settings)


def propose_many(data: Dataset, rivals: Sequence[str], cands: list, *,
                 client: Any = None, scheduler: str | None = None, workers: int = 2,
                 chunk: int = CHUNK, **settings: Any) -> Proposals:
    """:func:`propose` for a large candidate set (e.g. :func:`wide_candidates`), scored
    in chunks of ``chunk`` candidates on Dask: ``client``, else a scheduler address, else
    a ``LocalCluster`` of ``workers`` processes (``study.dask_client``, as the plan
    studies run). ``settings``: :func:`propose`'s keywords. The rivals must be given."""
    if rivals is None:
        raise ValueError("propose_many needs the two rivals (run propose once, or "
                         "rivals_of(diagnosis)).")
    chunks = [cands[i:i + chunk] for i in range(0, len(cands), max(int(chunk), 1))]
    if len(chunks) <= 1:
        return propose(data, rivals, cands=cands, **settings)

    def go(c):
        return c.gather(c.map(_score_chunk, chunks, data=data, rivals=tuple(rivals),
                              settings=settings, pure=False))

    if client is not None:
        parts = go(client)
    else:
        with dask_client(scheduler, workers) as c:
            parts = go(c)
    target = settings.get("target", TARGET_POWER)
    ranked = sorted((p for part in parts for p in part.ranked), key=_rank_key(target))
    skipped = {k: v for part in parts for k, v in part.skipped.items()}
    first = parts[0]
    msg = first.message.partition(" Best next measurement:")[0]
    if ranked:
        msg += f" Best next measurement: {ranked[0].outcome}."
    return Proposals(first.rivals, first.baseline, first.current, ranked, skipped, target,
                     msg)


def truth_config(fitted: FitResult, exclude_positions: Iterable[str] = ()) -> dict:
    """Simulator keys (``kinematic``, ``effects``) that make a rival's fit the truth: all
    its kinematic coefficients and its effects' fitted parameters (``Block.injection``);
    parameters of the data's own placements (drift, ...) are left out, since a new
    placement has its own."""
    exclude_positions = tuple(exclude_positions)
    vals = dict(zip(fitted.labels, fitted.values, strict=True))
    groups = dict(zip(fitted.labels, fitted.groups, strict=True))
    kin = {lab: float(v) for lab, v in vals.items() if groups[lab] == "kinematic"}
    spec = ",".join(t for t in fitted.problem.spec.to_string().split(",")
                    if t.partition(":")[0] not in BY_TOKEN)
    effects = {}
    for tok, block in BY_TOKEN.items():
        own = {lab: float(v) for lab, v in vals.items() if groups[lab] == tok
               and not any(lab.startswith(f"{p}.") for p in exclude_positions)}
        body = block.injection(own) if own else None
        if body:
            effects[tok] = body
    return {"kinematic": {"spec": spec, "order": int(fitted.problem.spec.orders[0][1])
                          if fitted.problem.spec.orders else 2, "coefficients": kin},
            "effects": effects}


@dataclass(frozen=True)
class Outcome:
    """The diagnosis of the data with a proposal appended, simulated with one rival as
    the truth.

    Attributes
    ----------
    truth : str
        The rival taken as the truth (at its size fitted on the current data).
    verdict : str or None
        The diagnosis's verdict on the augmented data.
    aliases : list of str
        The aliases it still reports for its first candidate.
    separated : bool
        The verdict is the truth and the other rival is no longer its alias.
    message : str
        The diagnosis's message.
    """

    truth: str
    verdict: str | None
    aliases: list
    separated: bool
    message: str


@single_blas_thread
def simulate_outcomes(data: Dataset, proposal: Proposal, *, baseline: str = "kinematic21",
                      order: int = 2, plate: str | None = None, sigma_um: float = 0.5,
                      seed: int = 0) -> dict:
    """One click, simulated: for each rival as the truth (its fit on the current data),
    simulate the proposal with noise σ, append it to the data and run the diagnosis.
    Returns ``{rival: Outcome}``.

    An instrument candidate is measured on the machine of each rival's fitted kinematic
    errors (its effects belong to the plate's placements and styli, which an instrument
    does not see), with the instrument simulator's own noise, and fitted jointly with the
    data as every instrument file is."""
    if PLACEMENT_SCALE in proposal.rivals:
        raise ValueError(f"{PLACEMENT_SCALE} is outside the catalogue: the virtual CMM "
                         "cannot simulate it as the truth (score the proposal instead).")
    if BASELINE in proposal.rivals:
        raise ValueError(f"against the {BASELINE} the outcome is the effect's own test: "
                         "its power is the proposal's score (nothing to simulate).")
    a, b = proposal.rivals
    rf = fit_rivals(data, proposal.rivals, baseline=baseline, order=order, plate=plate,
                    sigma_um=sigma_um)
    out = {}
    cand = proposal.candidate
    aug: Dataset | Observations
    for t, o in ((a, b), (b, a)):
        if cand.repeat:  # the same placements: their fitted poses, plate and drift
            aug = repeat_from_fit(data, cand, rf.fits[t], noise_um=sigma_um, seed=seed)
        elif cand.instrument:
            machine = _machine(data, truth_config(rf.fits[t])["kinematic"])
            obs = select(data)
            aug = replace(obs, instruments=(*obs.instruments,
                                            instrument_of(cand, machine, seed=seed)))
        else:
            cfg = {**truth_config(rf.fits[t], data.setup.raw["positions"]),
                   "noise_um": sigma_um}
            aug = append_measurement(data, cand, config=cfg, seed=seed)
        d = diagnose(aug, baseline, order=order, plate=plate, sigma_um=sigma_um)
        al = list(d.candidates[0].aliases) if d.candidates else []
        out[t] = Outcome(t, d.verdict, al, bool(d.verdict == t and o not in al), d.message)
    return out


def plan_file(data: Dataset, proposal: Proposal, *, baseline: str = "kinematic21",
              order: int = 2, noise_um: float = 0.5) -> dict:
    """The proposal as a ``plan`` JSON document (docs/planning.md, "The plan file"): the
    data set's setup with the proposal's placement and styli added, its plate, and two
    strategies: the current placements alone and with the proposal (a repeat: the same
    placements with its balls measured again at their end, ``repeat_at_end``)."""
    c = proposal.candidate
    if c.instrument:
        raise ValueError(f"{c.name} is an instrument: a plan file holds plate placements, "
                         "styli and repeats only; measure the instrument as proposed (its "
                         "kind, path and offset are in the proposal).")
    grid = plate_grid(data)
    raw = copy.deepcopy(data.setup.raw)
    for pl in raw["positions"].values():
        for key in ("temp_C", "rh_percent"):
            pl.pop(key, None)
    raw["frame"] = "machine"
    raw["positions"] = {**raw["positions"], **copy.deepcopy(c.positions)}
    raw["probes"] = {**raw["probes"], **c.probes}
    now = {p: list(dict.fromkeys(data.meas.loc[data.meas["position"] == p, "probe"]))
           for p in data.setup.raw["positions"]}
    return {"name": f"measure next: {c.name}", "setup": raw,
            "plate": {"rows": grid.rows, "cols": grid.cols, "pitch_mm": grid.pitch_mm},
            "model": {"spec": baseline, "order": order}, "noise_um": noise_um,
            "strategies": [{"name": "current data", "placements": now},
                           {"name": f"with {c.description}",
                            "placements": {**now, **c.probes_of}}
                           | ({"repeat_at_end": {p: {"probe": r["probe"],
                                                     "balls": list(r["balls"])}
                                                 for p, r in c.repeat.items()}}
                              if c.repeat else {})]}

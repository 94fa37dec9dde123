"""The observations a fit uses: a selection of a dataset as arrays (machine frame, mm).

``select`` picks positions and probes, drops excluded rows, and derives what the effect
blocks need: plate temperatures (column or the setup's records), time within each
position, the approach direction of each axis (backlash), nominal placements and the
starting plate (certificate, or the mean measured plate).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from ..io import DataError, Dataset, Setup, refuse_unknown_keys
from ..machine import DEFAULT_LAYOUT, LAYOUTS

__all__ = ["Observations", "select", "approach_directions", "setup_layout",
           "instrument_observations", "has_plate"]


@dataclass(frozen=True)
class Observations:
    """Arrays of the observations a fit uses (a selection of a dataset).

    Attributes
    ----------
    table : DataFrame
        The selected rows (position, probe, ball, source, row ...).
    r_mm, p_mm : ndarray (n, 3)
        Measured tip centres and nominal probe offsets, machine frame.
    pos, probe, ball : ndarray of int (n,)
        Indices into ``positions``, ``probes``, ``balls``.
    positions, probes : list of str
    balls : ndarray of int
    plate0_mm : ndarray (B, 3)
        Starting plate coordinates (certificate, or the mean measured plate).
    cert_u_um : ndarray (B, 3) or None
        Certificate standard uncertainties (µm); None: exact, or no certificate.
    dT_K : ndarray (n,)
        Plate temperature minus 20 °C (zero when not recorded).
    has_temp : bool
    hours : ndarray (n,)
        Time minus the position's mean time, in hours.
    horizontal : ndarray of bool (P,)
    R0, t0_mm : ndarray (P, 3, 3), (P, 3)
        Nominal placements from the setup.
    range_mm : ndarray (3,)
    has_certificate : bool
    approach : ndarray (n, 3)
        Direction of the last move of each axis before the point (+1, -1; 0 before the
        axis first moved), from the measurement order of the whole file (``backlash``).
    layout : str
        Machine layout from the setup's ``machine.layout`` (``kinematics.LAYOUTS``): the
        kinematic chain the fit models.
    instruments : tuple
        Laser runs and step gauges fitted with the plate (``instruments``; ``fit``'s
        ``instruments=``). Kept here so that every model fitted or scored on these
        observations (the diagnosis's candidates and refits) has their rows too.
    artefact : str
        ``"ball_plate"`` or ``"hole_plate"`` (the setup's ``artefact``): a hole plate's
        observations give only the two coordinates in the plate's plane (``hole_plate``).
    cert_u_source : str
        Where the certificate's uncertainty came from, in words (``Certificate.u_source``).
    """

    table: pd.DataFrame
    r_mm: np.ndarray
    p_mm: np.ndarray
    pos: np.ndarray
    probe: np.ndarray
    ball: np.ndarray
    positions: list
    probes: list
    balls: np.ndarray
    plate0_mm: np.ndarray
    cert_u_um: np.ndarray | None
    dT_K: np.ndarray
    has_temp: bool
    hours: np.ndarray
    horizontal: np.ndarray
    R0: np.ndarray
    t0_mm: np.ndarray
    range_mm: np.ndarray
    has_certificate: bool
    approach: np.ndarray
    layout: str = DEFAULT_LAYOUT
    instruments: tuple = ()
    artefact: str = "ball_plate"
    cert_u_source: str = ""


def setup_layout(setup: Setup) -> str:
    """The setup's ``machine.layout``; the moving bridge FXYZ when it names none."""
    machine = setup.raw.get("machine") if isinstance(setup.raw, dict) else None
    return machine.get("layout", DEFAULT_LAYOUT) if isinstance(machine, dict) \
        else DEFAULT_LAYOUT


def approach_directions(ram_mm: np.ndarray, time_min: np.ndarray | None = None, *,
                    min_move_mm: float = 0.5) -> np.ndarray:
    """Direction from which each axis last moved before each point (backlash state).

    Parameters
    ----------
    ram_mm : ndarray (n, 3)
        Scale readings (tip centre minus probe offset) in file order, mm.
    time_min : ndarray (n,), optional
        Measurement times; without them the file order is the measurement order (docs/formats.md).
    min_move_mm : float
        Smaller steps (noise, a ball repeated in place) leave an axis's state unchanged.

    Returns
    -------
    ndarray (n, 3)
        +1 or -1 per axis, 0 until the axis has first moved.
    """
    n = len(ram_mm)
    order = np.arange(n) if time_min is None else np.argsort(time_min, kind="stable")
    step = np.diff(ram_mm[order], axis=0)
    sign = np.where(np.abs(step) > min_move_mm, np.sign(step), 0.0)
    sign = np.vstack([np.zeros((1, 3)), sign])
    # an axis keeps the direction of its last real move: forward-fill the non-zero signs
    idx = np.where(sign != 0, np.arange(n)[:, None], 0)
    np.maximum.accumulate(idx, axis=0, out=idx)
    out = np.empty((n, 3))
    out[order] = np.take_along_axis(sign, idx, axis=0)
    return out


def _codes(column: pd.Series) -> tuple[np.ndarray, list]:
    """Index of each value among the distinct values in order of first appearance, and
    those values (``pd.factorize``: one pass over the column, no Python loop)."""
    codes, uniques = pd.factorize(column, sort=False)
    return codes.astype(np.int64), list(uniques)


def selected_rows(meas: pd.DataFrame, positions: Iterable[str] | None = None,
                  probes: Iterable[str] | None = None) -> np.ndarray:
    """Boolean mask of the rows of ``meas`` (``Dataset.meas``) of the chosen positions and
    probes (None: all), as :func:`select` takes them."""
    keep = np.ones(len(meas), bool)
    if positions is not None:
        keep &= meas["position"].isin(list(positions)).to_numpy()
    if probes is not None:
        keep &= meas["probe"].isin(list(probes)).to_numpy()
    return keep


def select(data: Dataset, *, positions: Iterable[str] | None = None,
       probes: Iterable[str] | None = None,
       exclude: Iterable[tuple[str, str, int]] = ()) -> Observations:
    """Observations of the chosen positions and probes, minus excluded rows.

    ``exclude`` holds ``(position, probe, ball)`` triples (outliers the user removed).
    """
    df = data.meas
    keep = selected_rows(df, positions, probes)
    ex = {(str(a), str(b), int(c)) for a, b, c in exclude}
    if ex:
        # one vectorised membership test of the (position, probe, ball) triples
        rows = pd.MultiIndex.from_arrays([df["position"], df["probe"],
                                          df["ball"].to_numpy().astype(int)])
        keep &= ~rows.isin(list(ex))
    t = df[keep].reset_index(drop=True)
    # backlash state follows every move the machine made, excluded balls included
    has_time = "time_min" in df and df["time_min"].notna().all()
    codes, names = pd.factorize(df["probe"])
    ram_all = df[["mx_mm", "my_mm", "mz_mm"]].to_numpy(float) - np.array(
        [data.setup.probes[q] for q in names], float).reshape(-1, 3)[codes]
    approach = approach_directions(
        ram_all, df["time_min"].to_numpy(float) if has_time else None)[keep]
    if len(t) == 0:
        raise ValueError("no observations left after the selection; choose at least one "
                         "position and probe.")
    # codes in order of first appearance (a Python loop over 10^6 strings took 10 s)
    pos, positions = _codes(t["position"])
    prb, probes = _codes(t["probe"])
    setup = data.setup
    r = t[["mx_mm", "my_mm", "mz_mm"]].to_numpy(float)
    pnom = np.array([setup.probes[q] for q in probes])
    R0 = np.array([setup.positions[p].rotation for p in positions])
    t0 = np.array([setup.positions[p].origin_mm for p in positions])
    cert = data.certificate
    if cert is not None:
        balls = cert.balls
        plate0 = cert.xyz_mm.copy()
        if cert.u_um is None and not cert.u_source:
            raise ValueError("the certificate's uncertainty is not stated; give it in the "
                             "certificate's u columns or the setup's certificate statement "
                             "(load_dataset refuses a certificate without either).")
        cu = cert.u_um  # None: exact, as stated
    else:
        balls = np.unique(t["ball"].to_numpy())
        cu = None
        plate0 = np.zeros((len(balls), 3))
        bidx = np.searchsorted(balls, t["ball"].to_numpy())
        local = np.einsum("nji,nj->ni", R0[pos], r - t0[pos])  # nominal plate frame
        np.add.at(plate0, bidx, local)
        plate0 /= np.bincount(bidx, minlength=len(balls))[:, None]
    ball = np.searchsorted(balls, t["ball"].to_numpy())
    # Temperatures: the column, else start/finish of the position interpolated over order.
    dT = np.zeros(len(t))
    has_temp = "temp_C" in t and t["temp_C"].notna().all()
    if has_temp:
        dT = t["temp_C"].to_numpy(float) - 20.0
    else:
        for i, p in enumerate(positions):
            rec = setup.positions[p].temp_C
            sel = np.flatnonzero(pos == i)
            if len(rec) >= 1 and len(sel):
                has_temp = True
                frac = np.linspace(0, 1, len(sel)) if len(sel) > 1 else np.zeros(1)
                dT[sel] = rec[0] + (rec[-1] - rec[0]) * frac - 20.0
    # Time: the column, else the order of rows (one minute per probed ball, an assumption).
    tm = (t["time_min"].to_numpy(float) if "time_min" in t and t["time_min"].notna().all()
          else np.arange(len(t), dtype=float))
    hours = np.zeros(len(t))
    for i in range(len(positions)):
        sel = pos == i
        hours[sel] = (tm[sel] - tm[sel].mean()) / 60.0
    horiz = np.array([setup.positions[p].horizontal for p in positions])
    return Observations(t, r, pnom[prb], pos, prb, ball, positions, probes, balls, plate0, cu,
                        dT, bool(has_temp), hours, horiz, R0, t0, setup.range_mm,
                        cert is not None, approach, setup_layout(setup),
                        artefact=getattr(setup, "artefact", "ball_plate"),
                        cert_u_source=(cert.u_source if cert is not None else
                                       "no certificate: the plate is self-calibrated"))


def instrument_observations(instruments: Iterable, range_mm: ArrayLike, layout: str = DEFAULT_LAYOUT,
                        *, name: str = "setup") -> Observations:
    """Observations of an instrument-only fit: laser runs, step gauges or ball bars on a
    machine of strokes ``range_mm`` (mm) and ``layout``, with no ball-plate observation
    (no plate, placement or probe).

    ``fit`` then determines the kinematic combinations the instruments see and names the
    others (docs/instruments.md, "Instruments without a plate").

    Parameters
    ----------
    instruments : iterable of LaserRun, StepGauge or BallBar
        As read by ``read_instrument``; at least one.
    range_mm : array (3,)
        Axis strokes of the machine, mm (a setup's ``machine.range_mm``).
    layout : str
        Kinematic chain (``machine.LAYOUTS``; a setup's ``machine.layout``).
    name : str
        Where ``range_mm`` and ``layout`` came from, for messages.
    """
    items = tuple(instruments)
    if not items:
        raise DataError("no ball-plate measurements and no instrument files: nothing to fit.",
                        file=name, hint="give measurement files, or laser, step-gauge or "
                        "ball-bar files (docs/instruments.md).")
    if layout not in LAYOUTS:
        raise DataError(f"machine.layout {layout!r} is not one of: {', '.join(LAYOUTS)}.",
                        file=name, column="machine.layout")
    rng = np.asarray(range_mm, float)
    if rng.shape != (3,) or not np.all(rng > 0):
        raise DataError(f"machine.range_mm must be three positive strokes in mm, found "
                        f"{np.ravel(rng).tolist()}.", file=name, column="machine.range_mm")
    z3, zi = np.zeros((0, 3)), np.zeros(0, int)
    return Observations(pd.DataFrame(columns=["position", "probe", "ball"]), z3, z3, zi, zi,
                        zi, [], [], zi, z3, None, np.zeros(0), False, np.zeros(0),
                        np.zeros(0, bool), np.zeros((0, 3, 3)), z3, rng, False, z3, layout,
                        instruments=items, cert_u_source="no plate: instruments only")


def has_plate(obs: Observations) -> bool:
    """Whether ``obs`` holds ball-plate observations (False: an instrument-only fit)."""
    return len(obs.r_mm) > 0


def check_selection(data: Dataset, positions: Iterable[str] | None,
                probes: Iterable[str] | None,
                exclusions: Iterable[tuple[str, str, int]], name: str) -> None:
    """Positions, probes and excluded ``(position, probe, ball)`` observations a saved
    analysis names exist in its data: an unknown one would silently select or exclude
    nothing. A DataError names the field and the name it most likely misspells."""

    known = {"positions": [str(p) for p in data.positions],
             "probes": [str(q) for q in dict.fromkeys(data.meas["probe"])]}
    for field, names in (("positions", positions), ("probes", probes)):
        refuse_unknown_keys(names or (), known[field], name, f"{field}.", field[:-1])
    have = set(zip(data.meas["position"].astype(str), data.meas["probe"].astype(str),
                   data.meas["ball"].astype(int), strict=True))
    for e in exclusions:
        if (str(e[0]), str(e[1]), int(e[2])) not in have:
            raise DataError(f"excluded observation {list(e)} (position, probe, ball) is not "
                            "in the data; expected one of its measured balls.", file=name,
                            column="exclusions")

"""Reading and writing laser interferometer runs, step-gauge / gauge-block and ball-bar lengths.

Formats (``docs/instruments.md``), machine axes, lengths in mm, errors and uncertainties
in µm::

    laser:       [run,]axis[,component],x_mm,y_mm,z_mm,error_um,u_um[,offset_x_mm,...]
    step gauge:  [gauge,]x1_mm,y1_mm,z1_mm,x2_mm,y2_mm,z2_mm,measured_mm,certified_mm,u_um
                 [,offset_x_mm,offset_y_mm,offset_z_mm][,temp_C,cte_per_K]
    ball bar:    [bar,]x1_mm,y1_mm,z1_mm,x2_mm,y2_mm,z2_mm,certified_mm,u_um
                 [,offset_x_mm,offset_y_mm,offset_z_mm][,temp_C,cte_per_K]

:func:`read_instrument` reads any of them by kind (:data:`INSTRUMENT_KINDS`). Every problem is a :class:`~cmm_core.io.DataError` naming the file, row and column and
what was expected; the cell-level problems of a file are reported together.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import numpy as np
import pandas as pd

from ..io import MAX_PROBE_MM, TEMP_RANGE_C, DataError, refuse_unknown_keys
from ..io.delimited import (
    FileSource,
    file_rows,
    numeric_column,
    read_csv_text,
    require_columns,
    require_rows,
)
from ..io.errors import Problems, cut_repr, likely_typo
from .ballbar import BallBar
from .instruments import MAX_INSTRUMENT_READINGS, LaserRun, StepGauge

__all__ = ["read_laser", "read_step_gauge", "read_ball_bar", "read_instrument",
           "write_laser", "write_step_gauge", "write_ball_bar", "write_instrument",
           "INSTRUMENT_KINDS", "LASER_COLUMNS", "STEP_GAUGE_COLUMNS", "BALL_BAR_COLUMNS",
           "LINE_TOLERANCE_MM", "MAX_ERROR_UM", "MIN_BAR_MM"]

OFFSET_COLUMNS = ("offset_x_mm", "offset_y_mm", "offset_z_mm")
LASER_COLUMNS = ("axis", "x_mm", "y_mm", "z_mm", "error_um", "u_um")
LASER_OPTIONAL = ("run", "component") + OFFSET_COLUMNS
STEP_GAUGE_COLUMNS = ("x1_mm", "y1_mm", "z1_mm", "x2_mm", "y2_mm", "z2_mm", "measured_mm",
                      "certified_mm", "u_um")
STEP_GAUGE_OPTIONAL = ("gauge",) + OFFSET_COLUMNS + ("temp_C", "cte_per_K")
BALL_BAR_COLUMNS = ("x1_mm", "y1_mm", "z1_mm", "x2_mm", "y2_mm", "z2_mm", "certified_mm",
                    "u_um")
BALL_BAR_OPTIONAL = ("bar",) + OFFSET_COLUMNS + ("temp_C", "cte_per_K")

LINE_TOLERANCE_MM = 0.1
"""How far the two coordinates across a laser run's axis may wander within the run."""
MAX_ERROR_UM = 1000.0
"""Largest plausible error reading or uncertainty (µm): a CMM error of a millimetre is a
unit mistake (nm or mm written for µm), not a machine."""
MAX_LENGTH_DIFF_MM = 1.0
"""Largest plausible measured minus certified length (mm): larger is a unit or row mix-up."""
MAX_STYLUS_MM = 50.0
"""Largest plausible difference between the measured length and the distance of the two
probed centres (mm): the stylus diameter, added for a bidirectional measurement."""
MIN_BAR_MM = 1.0
"""Shortest distance of a ball bar's two centres (mm): closer, the row names one ball twice."""
_U_RANGE_UM = (0.001, 100.0)
"""Standard uncertainty of one instrument reading or length a real instrument has (µm).

Below 1 nm no CMM calibration instrument reads: a laser interferometer's wavelength in air
is known to about 1e-7 (Edlén's equation, a 0.1 K or 30 Pa air reading), 10 nm over
100 mm, and its resolution is about 1 nm; step gauges and ball bars are certified to
tens of nm at best. A smaller u (1e-12 written for 1e-6 mm, or a u in mm) would weight
the reading a million times above the plate and wreck the fit. Above 100 µm the reading
carries nothing about errors of a few µm: a unit slip (nm or mm written for µm)."""
_MIN_OFFSET_MM = 1.0
"""Shortest non-zero stylus or reflector offset (mm), as for the setup's probes: a real
offset is zero or at least a stylus's length; 0.15 is a 150 mm stylus in metres."""
_METRE_SPAN_MM = 2.0
"""An instrument file whose points span less than this in every axis is in metres (as
the measurement reader judges a plate): instrument lines and gauges span decimetres."""
_LASER_HINT = ("Columns: [run,]axis[,component],x_mm,y_mm,z_mm,error_um,u_um"
               "[,offset_x_mm,offset_y_mm,offset_z_mm]; docs/instruments.md.")
_SG_HINT = ("Columns: [gauge,]x1_mm,y1_mm,z1_mm,x2_mm,y2_mm,z2_mm,measured_mm,certified_mm,"
            "u_um[,offset_x_mm,offset_y_mm,offset_z_mm][,temp_C,cte_per_K]; "
            "docs/instruments.md.")
_BB_HINT = ("Columns: [bar,]x1_mm,y1_mm,z1_mm,x2_mm,y2_mm,z2_mm,certified_mm,u_um"
            "[,offset_x_mm,offset_y_mm,offset_z_mm][,temp_C,cte_per_K]; docs/instruments.md.")


_QUIET = np.errstate(over="ignore", invalid="ignore")
"""The readers' arithmetic on cells such as 1e308 (reported as out of range, one line)
must not print numpy's overflow warnings beside that line."""


def _columns(df, name, required, optional, form, hint):
    """Refuse unknown (likely misspelt) columns, then missing ones and an empty file."""
    known = required + optional
    for c in df.columns:
        if c not in known:
            guess = likely_typo(str(c), known, cutoff=0.6)
            raise DataError(f"unknown column {cut_repr(c)}"
                            + (f"; did you mean {guess!r}?" if guess else
                               f"; expected {', '.join(known)}."), file=name, row=1,
                            column=str(c), hint=hint)
    require_columns(df, list(required), name, form)
    require_rows(df, name, "reading" if "error_um" in required else "length")


def _axes(df, column, name, found, default=None):
    """Axis letters x/y/z of ``column`` as 0, 1, 2 (``default`` where absent: -1 cells)."""
    if column not in df:
        return np.asarray(default)
    text = df[column].fillna("").astype(str).str.strip().str.lower()
    ok = text.isin(["x", "y", "z"]).to_numpy()
    found.add(~ok, column, lambda i: f"expected an axis x, y or z, found {cut_repr(text.iat[i])}.")
    return np.array(["xyz".index(t) if t in ("x", "y", "z") else 0 for t in text])


def _offsets(df, name, found):
    m = len(df)
    p = np.zeros((m, 3))
    for a, col in enumerate(OFFSET_COLUMNS):
        if col in df:
            p[:, a] = numeric_column(df, col, name, problems=found)
    size = np.linalg.norm(np.nan_to_num(p), axis=1)
    bad = (size > MAX_PROBE_MM) | ((size > 0) & (size < _MIN_OFFSET_MM))
    found.add(bad, OFFSET_COLUMNS[0], lambda i: f"the offset is {size[i]:.4g} mm long; "
              f"expected a stylus or reflector offset in mm (0, or {_MIN_OFFSET_MM:g} to "
              f"{MAX_PROBE_MM:g}).", hint="offsets in metres or µm are refused: write mm, "
              "e.g. 0,0,-150.")
    return p


def _check_mm(found, points, columns):
    """Points (each (m, 3), with their column names) that look like metres or µm, as
    the measurement reader judges a plate: all of them within :data:`_METRE_SPAN_MM` in
    every axis (metres), or a coordinate beyond 1e5 mm (µm)."""
    xyz = np.vstack(points)
    ok = np.isfinite(xyz).all(axis=1)
    if ok.sum() >= 2 and np.ptp(xyz[ok], axis=0).max() < _METRE_SPAN_MM:
        found.add_file(f"the points span only {np.ptp(xyz[ok], axis=0).max():.3g} in every "
                       "axis; they look like metres, not mm.", column=columns[0],
                       hint="multiply by 1000 (instrument files are in mm).")
    for pts, cols in zip(points, (columns[k:k + 3] for k in range(0, len(columns), 3)),
                         strict=True):
        big = np.abs(np.nan_to_num(pts)) > 1e5
        for j, col in enumerate(cols):
            found.add(big[:, j], col, lambda i, j=j, pts=pts: f"value {pts[i, j]:g} mm is "
                      "beyond any CMM's range; it looks like µm.",
                      hint="divide by 1000 (instrument files are in mm).")


def _positive_um(df, col, name, found, what):
    """The ``u_um`` column, each within :data:`_U_RANGE_UM` (what a real instrument has)."""
    v = numeric_column(df, col, name, problems=found)
    lo, hi = _U_RANGE_UM
    bad = np.isfinite(v) & ~((v >= lo) & (v <= hi))
    found.add(bad, col, lambda i: f"expected {what} in µm, {lo:g} to {hi:g} (what an "
              f"instrument can have), found {v[i]:g}.",
              hint="write standard uncertainties in µm (not nm or mm); "
                   "docs/instruments.md#limits.")
    return v


@_QUIET
def read_laser(source: FileSource, name: str | None = None) -> LaserRun:
    """Read a laser interferometer file (module docstring; ``docs/instruments.md``).

    Without a ``run`` column, consecutive rows on one line (same axis, component and
    offset, the cross coordinates within :data:`LINE_TOLERANCE_MM`) form one run.

    Raises
    ------
    DataError
        Naming file, row and column: unknown or missing columns, unreadable numbers, an
        axis other than x/y/z, u outside :data:`_U_RANGE_UM`, an error reading beyond
        :data:`MAX_ERROR_UM`, points in metres or µm, an offset in metres, more than
        :data:`MAX_INSTRUMENT_READINGS` rows, a run that leaves its line or has too few readings.
    """
    df, name = read_csv_text(source, name, max_rows=MAX_INSTRUMENT_READINGS)
    _columns(df, name, LASER_COLUMNS, LASER_OPTIONAL, "laser", _LASER_HINT)
    found = Problems(name, file_rows(df), df.columns)
    axis = _axes(df, "axis", name, found)
    comp = _axes(df, "component", name, found, default=axis)
    r = np.column_stack([numeric_column(df, c, name, problems=found) for c in ("x_mm", "y_mm",
                                                                          "z_mm")])
    err = numeric_column(df, "error_um", name, problems=found)
    big = np.isfinite(err) & (np.abs(err) > MAX_ERROR_UM)
    found.add(big, "error_um", lambda i: f"an error of {err[i]:g} µm is not a CMM's; expected "
              f"µm, at most {MAX_ERROR_UM:g} in size.", hint="convert nm or mm to µm.")
    u = _positive_um(df, "u_um", name, found, "the reading's standard uncertainty")
    p = _offsets(df, name, found)
    _check_mm(found, [r], ["x_mm", "y_mm", "z_mm"])
    found.raise_if_any()
    rows = file_rows(df)
    if "run" in df:
        names = df["run"].fillna("").astype(str).str.strip()
        empty = (names == "").to_numpy()
        found.add(empty, "run", lambda i: "expected a run name, found an empty cell.")
        found.raise_if_any()
        runs = tuple(dict.fromkeys(names))
        run = names.map({k: i for i, k in enumerate(runs)}).to_numpy()
    else:
        run = _consecutive_runs(axis, comp, r, p)
        runs = tuple(f"run{k + 1}" for k in range(run.max() + 1))
    _check_runs(name, rows, run, runs, axis, comp, r, p, "run" if "run" in df else "axis")
    return LaserRun(name, rows, run, runs, axis, comp, r, p, err, u)


def _consecutive_runs(axis, comp, r, p):
    """Run index of each row: a new run where the line, component or offset changes."""
    m = len(axis)
    new = np.zeros(m, bool)
    new[0] = True
    for i in range(1, m):
        cross = [k for k in range(3) if k != axis[i]]
        new[i] = (axis[i] != axis[i - 1] or comp[i] != comp[i - 1]
                  or np.any(p[i] != p[i - 1])
                  or np.any(np.abs(r[i, cross] - r[i - 1, cross]) > LINE_TOLERANCE_MM))
    return np.cumsum(new) - 1


def _check_runs(name, rows, run, runs, axis, comp, r, p, run_col):
    """Each run on one line of one axis, one component and offset, with enough readings."""
    for k, label in enumerate(runs):
        sel = np.flatnonzero(run == k)
        i0 = sel[0]
        for col, v in (("axis", axis), ("component", comp)):
            bad = sel[v[sel] != v[i0]]
            if bad.size:
                raise DataError(f"run {label!r} changes its {col} from {'xyz'[v[i0]]} (row "
                                f"{rows[i0]}) to {'xyz'[v[bad[0]]]}; expected one {col} per "
                                "run.", file=name, row=int(rows[bad[0]]), column=col,
                                hint="give each line and component its own run name.")
        bad = sel[np.any(p[sel] != p[i0], axis=1)]
        if bad.size:
            raise DataError(f"run {label!r} changes its offset; expected one reflector "
                            "offset per run.", file=name, row=int(rows[bad[0]]),
                            column=OFFSET_COLUMNS[0])
        a = axis[i0]
        for c in (c for c in range(3) if c != a):
            dev = np.abs(r[sel, c] - r[i0, c])
            if dev.max() > LINE_TOLERANCE_MM:
                j = sel[np.argmax(dev)]
                raise DataError(
                    f"run {label!r} moves along {'xyz'[a]} but its {'xyz'[c]}_mm changes by "
                    f"{dev.max():.3g} mm (row {rows[i0]} to this row); expected one line, the "
                    f"cross coordinates within {LINE_TOLERANCE_MM:g} mm.", file=name,
                    row=int(rows[j]), column=f"{'xyz'[c]}_mm",
                    hint="a run measures along one axis line: name the runs apart.")
        need = 2 if comp[i0] == a else 3
        if sel.size < need or np.ptp(r[sel, a]) < 1.0:
            raise DataError(
                f"run {label!r} has {sel.size} reading(s) over {np.ptp(r[sel, a]):.3g} mm; "
                f"expected at least {need} readings spread along {'xyz'[a]} (its zero"
                + (" and the optics' slope are" if need == 3 else " is")
                + " unknown, so fewer carry no information).", file=name, row=int(rows[i0]),
                column=run_col)


@_QUIET
def read_step_gauge(source: FileSource, name: str | None = None) -> StepGauge:
    """Read a step-gauge / gauge-block file (module docstring; ``docs/instruments.md``).

    With ``temp_C`` and ``cte_per_K`` the certified length (at 20 °C) is expanded to the
    measuring temperature, ``L (1 + cte (temp_C - 20))``.

    Raises
    ------
    DataError
        Naming file, row and column: unknown or missing columns, unreadable numbers, u
        outside :data:`_U_RANGE_UM`, points in metres or µm, an offset in metres, more
        than :data:`MAX_INSTRUMENT_READINGS` rows, a certified length not positive, measured and
        certified lengths more than
        :data:`MAX_LENGTH_DIFF_MM` apart, a measured length that is not the distance of the
        probed points (within :data:`MAX_STYLUS_MM`), a temperature without a CTE.
    """
    df, name = read_csv_text(source, name, max_rows=MAX_INSTRUMENT_READINGS)
    _columns(df, name, STEP_GAUGE_COLUMNS, STEP_GAUGE_OPTIONAL, "step-gauge", _SG_HINT)
    found = Problems(name, file_rows(df), df.columns)
    num = {c: numeric_column(df, c, name, problems=found) for c in STEP_GAUGE_COLUMNS[:8]}
    r1 = np.column_stack([num[c] for c in ("x1_mm", "y1_mm", "z1_mm")])
    r2 = np.column_stack([num[c] for c in ("x2_mm", "y2_mm", "z2_mm")])
    meas, cert = num["measured_mm"], num["certified_mm"]
    u = _positive_um(df, "u_um", name, found, "the length's standard uncertainty")
    p = _offsets(df, name, found)
    _check_mm(found, [r1, r2], list(STEP_GAUGE_COLUMNS[:6]))
    found.add(np.isfinite(cert) & (cert <= 0), "certified_mm",
              lambda i: f"expected a positive length in mm, found {cert[i]:g}.")
    diff = np.abs(meas - cert)
    found.add(np.isfinite(diff) & (diff > MAX_LENGTH_DIFF_MM), "measured_mm",
              lambda i: f"measured {meas[i]:g} mm against certified {cert[i]:g} mm: they "
              f"differ by {diff[i]:.4g} mm, expected micrometres.",
              hint="check the units (mm) and that each row pairs a length with its "
                   "certified value.")
    dist = np.linalg.norm(r2 - r1, axis=1)
    off = np.abs(meas - dist)
    found.add(np.isfinite(off) & (off > MAX_STYLUS_MM), "measured_mm",
              lambda i: f"the probed points are {dist[i]:.4g} mm apart but the measured "
              f"length is {meas[i]:g} mm; expected them to differ by at most the stylus "
              f"diameter ({MAX_STYLUS_MM:g} mm).", hint="x1..z2 are the indicated tip "
                   "centres of the two probings, machine axes, mm.")
    cert = _temperature(df, name, found, cert)
    found.raise_if_any()
    labels = (tuple(df["gauge"].fillna("").astype(str).str.strip()) if "gauge" in df
              else tuple(f"L{c:g}" for c in num["certified_mm"]))
    return StepGauge(name, file_rows(df), labels, r1, r2, p, meas, cert, u)


def _temperature(df, name, found, cert, hint=_SG_HINT):
    """Certified lengths expanded to the measuring temperature (both columns or neither)."""
    have = [c for c in ("temp_C", "cte_per_K") if c in df]
    if not have:
        return cert
    if len(have) == 1:
        other = ({"temp_C", "cte_per_K"} - set(have)).pop()
        raise DataError(f"has {have[0]} but no {other}; expected both (the gauge's "
                        "temperature and expansion coefficient) or neither.", file=name,
                        row=1, column=have[0], hint=hint)
    t = numeric_column(df, "temp_C", name, problems=found)
    cte = numeric_column(df, "cte_per_K", name, problems=found)
    lo, hi = TEMP_RANGE_C
    found.add(np.isfinite(t) & ((t < lo) | (t > hi)), "temp_C",
              lambda i: f"expected the gauge temperature in °C ({lo:g} to {hi:g}), found "
              f"{t[i]:g}.")
    found.add(np.isfinite(cte) & (np.abs(cte) > 3e-5), "cte_per_K",
              lambda i: f"expected an expansion coefficient per K (steel 11.5e-6), found "
                        f"{cte[i]:g}.")
    return cert * (1 + cte * (t - 20.0))


@_QUIET
def read_ball_bar(source: FileSource, name: str | None = None) -> BallBar:
    """Read a ball-bar file (module docstring; ``docs/instruments.md``): one length per row,
    the indicated centres of the bar's two balls and its certified length.

    With ``temp_C`` and ``cte_per_K`` the certified length (at 20 °C) is expanded to the
    measuring temperature, ``L (1 + cte (temp_C - 20))``.

    Raises
    ------
    DataError
        Naming file, row and column: unknown or missing columns, unreadable numbers, u
        outside :data:`_U_RANGE_UM`, points in metres or µm, an offset in metres, more
        than :data:`MAX_INSTRUMENT_READINGS` rows, a certified length not positive, two centres
        closer than
        :data:`MIN_BAR_MM` (one ball named twice), a distance of the centres more than
        :data:`MAX_LENGTH_DIFF_MM` from the certified length, a temperature without a CTE.
    """
    df, name = read_csv_text(source, name, max_rows=MAX_INSTRUMENT_READINGS)
    _columns(df, name, BALL_BAR_COLUMNS, BALL_BAR_OPTIONAL, "ball-bar", _BB_HINT)
    found = Problems(name, file_rows(df), df.columns)
    num = {c: numeric_column(df, c, name, problems=found) for c in BALL_BAR_COLUMNS[:7]}
    r1 = np.column_stack([num[c] for c in ("x1_mm", "y1_mm", "z1_mm")])
    r2 = np.column_stack([num[c] for c in ("x2_mm", "y2_mm", "z2_mm")])
    cert = num["certified_mm"]
    u = _positive_um(df, "u_um", name, found, "the length's standard uncertainty")
    p = _offsets(df, name, found)
    _check_mm(found, [r1, r2], list(STEP_GAUGE_COLUMNS[:6]))
    found.add(np.isfinite(cert) & (cert <= 0), "certified_mm",
              lambda i: f"expected a positive length in mm, found {cert[i]:g}.")
    dist = np.linalg.norm(r2 - r1, axis=1)
    same = np.isfinite(dist) & (dist < MIN_BAR_MM)
    found.add(same, "x2_mm", lambda i: f"the two ball centres are {dist[i]:.3g} mm apart; "
              f"expected the centres of the bar's two balls, at least {MIN_BAR_MM:g} mm "
              "apart.", hint="x1..z1 and x2..z2 are the indicated centres of the two "
                   "balls, machine axes, mm.")
    diff = np.abs(dist - cert)
    found.add(np.isfinite(diff) & ~same & (cert > 0) & (diff > MAX_LENGTH_DIFF_MM),
              "certified_mm", lambda i: f"the centres are {dist[i]:.6g} mm apart against a "
              f"certified length of {cert[i]:g} mm: they differ by {diff[i]:.4g} mm, "
              "expected micrometres.", hint="check the units (mm) and that each row pairs "
              "a bar placement with its bar's certified length.")
    cert = _temperature(df, name, found, cert, _BB_HINT)
    found.raise_if_any()
    labels = (tuple(df["bar"].fillna("").astype(str).str.strip()) if "bar" in df
              else tuple(f"L{c:g}" for c in num["certified_mm"]))
    return BallBar(name, file_rows(df), labels, r1, r2, p, cert, u)


def write_laser(run: LaserRun, path: str | Path | IO[str]) -> None:
    """Write a laser run in the format :func:`read_laser` reads."""
    df = pd.DataFrame({"run": [run.runs[k] for k in run.run],
                       "axis": ["xyz"[a] for a in run.axis],
                       "component": ["xyz"[c] for c in run.component],
                       "x_mm": run.r_mm[:, 0], "y_mm": run.r_mm[:, 1], "z_mm": run.r_mm[:, 2],
                       "error_um": run.error_um, "u_um": run.u_um})
    if np.any(run.p_mm):
        for a, col in enumerate(OFFSET_COLUMNS):
            df[col] = run.p_mm[:, a]
    df.to_csv(path, index=False, float_format="%.6f")


def write_step_gauge(sg: StepGauge, path: str | Path | IO[str]) -> None:
    """Write step-gauge lengths in the format :func:`read_step_gauge` reads (certified
    lengths as stored: at the measuring temperature)."""
    df = pd.DataFrame({"gauge": list(sg.gauge)})
    for k, (a, b) in enumerate(zip(sg.r1_mm.T, sg.r2_mm.T, strict=True)):
        df[f"{'xyz'[k]}1_mm"], df[f"{'xyz'[k]}2_mm"] = a, b
    df = df[["gauge", *STEP_GAUGE_COLUMNS[:6]]]
    df["measured_mm"], df["certified_mm"], df["u_um"] = sg.measured_mm, sg.certified_mm, sg.u_um
    if np.any(sg.p_mm):
        for a, col in enumerate(OFFSET_COLUMNS):
            df[col] = sg.p_mm[:, a]
    df.to_csv(path, index=False, float_format="%.7f")


def write_ball_bar(bb: BallBar, path: str | Path | IO[str]) -> None:
    """Write ball-bar lengths in the format :func:`read_ball_bar` reads (certified lengths
    as stored: at the measuring temperature)."""
    df = pd.DataFrame({"bar": list(bb.bar)})
    for k, (a, b) in enumerate(zip(bb.r1_mm.T, bb.r2_mm.T, strict=True)):
        df[f"{'xyz'[k]}1_mm"], df[f"{'xyz'[k]}2_mm"] = a, b
    df = df[["bar", *BALL_BAR_COLUMNS[:6]]]
    df["certified_mm"], df["u_um"] = bb.certified_mm, bb.u_um
    if np.any(bb.p_mm):
        for a, col in enumerate(OFFSET_COLUMNS):
            df[col] = bb.p_mm[:, a]
    df.to_csv(path, index=False, float_format="%.7f")


INSTRUMENT_KINDS: dict[str, tuple[Callable[..., Any], Callable[..., None]]] = {
                    "laser": (read_laser, write_laser),
                    "step_gauge": (read_step_gauge, write_step_gauge),
                    "ball_bar": (read_ball_bar, write_ball_bar)}
"""Instrument kind (``LaserRun.kind`` ...) -> its reader and writer; the CLI's flags
``--laser``, ``--step-gauge``, ``--ball-bar`` and other callers (the app, the analysis
record) read a file of a named kind through :func:`read_instrument`."""


def read_instrument(source: FileSource, kind: str, name: str | None = None
                ) -> LaserRun | StepGauge | BallBar:
    """Read an instrument file of ``kind`` (one of :data:`INSTRUMENT_KINDS`).

    Raises
    ------
    DataError
        An unknown kind (naming the known ones and the one it most likely misspells), or
        any problem of the file (its reader's refusals).
    """
    label = name or (Path(source).name if isinstance(source, str | Path) else
                     "instrument file")
    refuse_unknown_keys([kind], list(INSTRUMENT_KINDS), label, "", "instrument kind")
    return INSTRUMENT_KINDS[kind][0](source, name)


def write_instrument(item: LaserRun | StepGauge | BallBar, path: str | Path | IO[str]) -> None:
    """Write an instrument (``LaserRun``, ``StepGauge``, ``BallBar``) in its own format."""
    INSTRUMENT_KINDS[item.kind][1](item, path)

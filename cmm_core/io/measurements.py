"""Measurement files: long form or thesis form (one file per position), every cell checked.

Holds the column sets (:data:`LONG_COLUMNS`, :data:`OPTIONAL_COLUMNS`, ...),
:func:`read_measurements`, :func:`read_measurement_files`, :func:`write_long_csv`, and the
row checks the certificate reader and :func:`~cmm_core.io.matching.resolve` share with it
(:func:`_ball_numbers`, :func:`_check_duplicates`, :func:`_check_units`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import IO

import numpy as np
import pandas as pd

from .delimited import (
    _COLUMNS_HINT,
    MAX_MEASUREMENT_ROWS,
    FileSource,
    _names,
    file_rows,
    numeric_column,
    read_csv_text,
    require_columns,
    require_rows,
)
from .errors import DataError, Problems, cut_repr, likely_typo
from .setup import TEMP_RANGE_C

LONG_COLUMNS = ("position", "probe", "ball", "x_mm", "y_mm", "z_mm")
SCALE_TEMP_COLUMNS = ("temp_x_C", "temp_y_C", "temp_z_C")
"""Temperature of each axis's scale (°C), for the machine thermal effect."""
OPTIONAL_COLUMNS = ("time_min", "temp_C", "repeat", *SCALE_TEMP_COLUMNS)
THESIS_COLUMNS = ("ball", "x_mm", "y_mm", "z_mm")


def read_measurements(source: FileSource, *, name: str | None = None,
                  position: str | None = None) -> pd.DataFrame:
    """Read one measurement CSV in long or thesis form, checking every cell.

    Parameters
    ----------
    source : path, bytes or file-like
    name : str, optional
        File name used in messages and, for thesis form, as the position name.
    position : str, optional
        Position name for a thesis-form file (default: the file stem).

    Returns
    -------
    DataFrame with columns ``position, probe, ball, x_mm, y_mm, z_mm`` and, when given,
    ``time_min, temp_C, repeat``; plus ``source`` (file name) and ``row`` (file row).
    Probes are ``None`` for thesis-form files (the setup names them). ``attrs`` tells the
    ``delimiter`` used and whether decimal commas were read (``decimal_comma``).

    Raises
    ------
    DataError
        With every problem of the file in ``problems`` (see :mod:`cmm_core.io`).
    """
    df, name = read_csv_text(source, name, max_rows=MAX_MEASUREMENT_ROWS)
    # a probe column says long form: without position it must not pass as thesis form,
    # where every position's ball 1 would "appear twice"
    long = "position" in df.columns or "probe" in df.columns
    for c in df.columns:
        # extra columns are kept, but "tempC" for temp_C would silently drop the record
        guess = likely_typo(str(c), LONG_COLUMNS + OPTIONAL_COLUMNS)
        if guess is not None:
            raise DataError(f"unknown column {cut_repr(c)}; did you mean {guess!r}?", file=name,
                            row=1, column=str(c),
                            hint="rename the column. " + _COLUMNS_HINT)
    require_columns(df, LONG_COLUMNS if long else THESIS_COLUMNS, name,
             "long-form" if long else "thesis-form")
    require_rows(df, name, "probed ball")
    found = Problems(name, file_rows(df), df.columns)
    if long:
        out = pd.DataFrame({c: _names(df, c, found) for c in ("position", "probe")})
    else:
        pos = position or Path(name).stem
        out = pd.DataFrame({"position": [pos] * len(df), "probe": [None] * len(df)})
    out["ball"] = _ball_numbers(df, name, found)
    for col in ("x_mm", "y_mm", "z_mm") + tuple(c for c in OPTIONAL_COLUMNS if c in df):
        out[col] = numeric_column(df, col, name, problems=found)
    lo, hi = TEMP_RANGE_C
    for tcol in ("temp_C", *SCALE_TEMP_COLUMNS):
        if tcol not in out:
            continue
        t = out[tcol].to_numpy(float)
        kelvin = np.isfinite(t) & (t > 253) & (t < 343)
        found.add(kelvin, tcol, lambda i, t=t: f"temperature {t[i]:g} looks like kelvin; "
                  f"expected °C ({lo:g} to {hi:g}).", hint="subtract 273.15 (°C, not K).")
        what = "plate" if tcol == "temp_C" else f"{tcol[5]} scale"
        found.add(np.isfinite(t) & ~kelvin & ((t < lo) | (t > hi)), tcol,
                  lambda i, t=t: f"temperature {t[i]:g} °C is not plausible for a CMM room; "
                  f"expected {lo:g} to {hi:g} °C.", hint=f"write the {what} temperature in °C.")
    key = ["position", "probe", "ball"] + (["repeat"] if "repeat" in out else [])
    _check_duplicates(out, key, found,
                      hint="add a 'repeat' column for repeated measurements." if long else
                      "a file in this form holds one position, each ball once; a file with "
                      "several positions needs position and probe columns.")
    _check_units(out[["x_mm", "y_mm", "z_mm"]].to_numpy(), found)
    found.raise_if_any()
    out["ball"] = out["ball"].astype(int)
    out["source"] = name
    out["row"] = found.rows
    out.attrs = {k: df.attrs[k] for k in ("delimiter", "decimal_comma")}
    return out


def read_measurement_files(sources: Iterable[FileSource | tuple[FileSource, str | None]]
                       ) -> pd.DataFrame:
    """Read several files (one long-form file or thesis-form files, one per position)."""
    frames = [read_measurements(s, name=(n if n else None)) for s, n in _named(sources)]
    if not frames:
        raise DataError("no measurement file given.")
    out = pd.concat(frames, ignore_index=True)
    return out


def _named(sources):
    for s in sources:
        if isinstance(s, tuple):
            yield s
        else:
            yield s, None


def _ball_numbers(df, name, problems):
    """Ball numbers (floats, NaN where reported): whole numbers from 1."""
    balls = numeric_column(df, "ball", name, integer=True, problems=problems)
    problems.add(balls < 1, "ball",
                 lambda i: f"expected ball numbers from 1, found {balls[i]:.0f}.")
    balls[balls < 1] = np.nan
    return balls


def _check_duplicates(out, key, found, hint=None):
    """Report every row whose ``key`` values repeat an earlier row (unreadable rows skipped)."""
    # Thesis-form probes are all None until resolve() fills them: not "unreadable".
    ok = out[[k for k in key if k != "probe"]].notna().all(axis=1).to_numpy()
    idx = np.flatnonzero(ok)
    sub = out.iloc[idx][key]
    first = sub.assign(_i=idx).groupby(key, dropna=False, sort=False)["_i"].transform("min")
    first = first.to_numpy()
    again = np.zeros(len(out), bool)
    again[idx[first != idx]] = True
    first_of = np.zeros(len(out), int)
    first_of[idx] = first

    def message(i):
        r = out.iloc[i]
        what = f"ball {r['ball']:.0f}"
        if "position" in key:
            what += f" of position {r['position']}"
        if "probe" in key and r["probe"] is not None and r["probe"] == r["probe"]:
            what += f" with probe {r['probe']}"
        return f"{what} appears twice (also in {found.where(first_of[i], i)})."

    found.add(again, "ball", message, hint=hint)


def _check_units(xyz, found):
    """Coordinates that look like metres or µm: a ball plate spans hundreds of mm."""
    ok = np.isfinite(xyz).all(axis=1)
    span = np.ptp(xyz[ok], axis=0).max() if ok.any() else 0.0
    if ok.sum() >= 4 and span < 2.0:
        found.add_file(f"coordinates span only {span:.3g} in every axis; they look like "
                       "metres, not mm.", column="x_mm",
                       hint="multiply by 1000 (files are in mm).")
    big = np.isfinite(xyz) & (np.abs(np.nan_to_num(xyz)) > 1e5)
    for j, col in enumerate(("x_mm", "y_mm", "z_mm")):
        found.add(big[:, j], col, lambda i, j=j: f"value {xyz[i, j]:g} mm is beyond any "
                  "CMM's range; it looks like µm.", hint="divide by 1000 (files are in mm).")


def write_long_csv(df: pd.DataFrame, path: str | Path | IO[str]) -> None:
    """Write measurements in long form (mm, 6 decimals = 1 nm)."""
    cols = [c for c in LONG_COLUMNS + OPTIONAL_COLUMNS if c in df.columns]
    df[cols].to_csv(path, index=False, float_format="%.6f")

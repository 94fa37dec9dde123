"""Reading and validating measurements, setups and certificates (SPEC "Data formats").

Every problem is reported as a :class:`DataError` naming the file, row and column and what
was expected, with a hint at the fix. Row numbers are the rows a spreadsheet shows (the
header is row 1, so the first data row is row 2; blank lines count as rows).

Measurement and certificate files are checked completely before anything is raised: the
error carries every cell-level problem of the file in ``DataError.problems`` (at most
:data:`MAX_PROBLEMS`, with the full count in ``DataError.n_problems``), while ``str(exc)``
stays one line, the first problem plus "(and N more problems)".
"""

from __future__ import annotations

import csv
import difflib
import io as _io
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .kinematics import LAYOUTS as _KINEMATIC_LAYOUTS

LONG_COLUMNS = ("position", "probe", "ball", "x_mm", "y_mm", "z_mm")
SCALE_TEMP_COLUMNS = ("temp_x_C", "temp_y_C", "temp_z_C")
"""Temperature of each axis's scale (°C), for the machine thermal effect."""
OPTIONAL_COLUMNS = ("time_min", "temp_C", "repeat", *SCALE_TEMP_COLUMNS)
THESIS_COLUMNS = ("ball", "x_mm", "y_mm", "z_mm")
MAX_BYTES = 50 * 1024 * 1024
MAX_PROBLEMS = 50
MIN_CERTIFICATE_BALLS = 3
_NAN_WORDS = {"nan", "+nan", "-nan"}
_DELIM_NAMES = {",": "comma", ";": "semicolon", "\t": "tab"}
# A number written with a decimal comma ("-1,25", "3,5e-2"); only rewritten in files whose
# columns are not separated by commas, where the comma cannot be a column separator.
_DECIMAL_COMMA = re.compile(r"^(\s*[+-]?\d*),(\d+(?:[eE][+-]?\d+)?\s*)$")


class DataError(ValueError):
    """Bad input: the message names file, row, column, what was expected and a fix.

    Attributes
    ----------
    detail, file, row, column, hint
        The parts of the (first) problem.
    problems : list of DataError
        Every problem found (``[self]`` for a single one), capped at :data:`MAX_PROBLEMS`.
    n_problems : int
        How many problems were found, including those beyond the cap.
    """

    def __init__(self, message, *, file=None, row=None, column=None, hint=None):
        self.file, self.row, self.column, self.hint = file, row, column, hint
        self.detail = message
        self.problems = [self]
        self.n_problems = 1
        where = [str(file)] if file else []
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        text = (": ".join([", ".join(where), message]) if where else message)
        if hint:
            text += f" Hint: {hint}"
        super().__init__(text)

    @classmethod
    def collect(cls, problems, total=None) -> DataError:
        """One error reporting several ``problems`` (DataErrors), the first in its message.

        ``total`` is the number found when ``problems`` holds only the first of them.
        """
        first = problems[0]
        err = cls(first.detail, file=first.file, row=first.row, column=first.column,
                  hint=first.hint)
        err.problems = list(problems[:MAX_PROBLEMS])
        err.n_problems = max(total or 0, len(problems))
        more = err.n_problems - 1
        if more:
            err.args = (f"{err.args[0]} (and {more} more problem{'s' * (more > 1)})",)
        return err


class _Problems:
    """Problems found in one file (or, for :func:`resolve`, in rows of several files),
    collected so the user can fix them all in one go.

    Each check keeps its first :data:`MAX_PROBLEMS` cells and counts the rest: enough to
    list the first :data:`MAX_PROBLEMS` of the file by row, without building millions of
    errors for a file that is wrong throughout.

    Parameters
    ----------
    name : str or None
        File name for messages.
    rows : array of int
        File row of each data row.
    columns : sequence of str
        The file's columns, to list problems of one row in column order.
    files : array of str, optional
        File name of each row, when the rows come from several files.
    """

    def __init__(self, name, rows, columns=(), files=None):
        self.name, self.rows, self.columns = name, np.asarray(rows), list(columns)
        self.files = files
        self.found, self.total = [], 0

    def file(self, i):
        """File name of data row ``i``."""
        return self.name if self.files is None else self.files[i]

    def where(self, j, i):
        """'row N' of data row ``j``, with its file when that differs from row ``i``'s."""
        row = f"row {self.rows[j]}"
        return row if self.file(j) == self.file(i) else f"{self.file(j)}, {row}"

    def add(self, mask, column, message, hint=None):
        """Report every True entry of ``mask``; ``message(i)`` words the problem of row i."""
        idx = np.flatnonzero(np.asarray(mask))
        self.total += len(idx)
        for i in idx[:MAX_PROBLEMS]:
            self.found.append(DataError(message(i), file=self.file(i),
                                        row=int(self.rows[i]), column=column, hint=hint))

    def add_file(self, message, column=None, hint=None):
        """Report a problem of the file as a whole (no row)."""
        self.total += 1
        self.found.append(DataError(message, file=self.name, column=column, hint=hint))

    def raise_if_any(self, sort=True):
        """Raise one :class:`DataError` listing the problems (by row when ``sort``)."""
        if not self.found:
            return
        if sort:
            order = {c: k for k, c in enumerate(self.columns)}
            self.found.sort(key=lambda e: (e.row or 0, order.get(e.column, len(order))))
        raise DataError.collect(self.found, self.total)


@dataclass(frozen=True)
class Placement:
    """Nominal placement of the plate in one position (plate -> machine frame).

    Attributes
    ----------
    origin_mm : ndarray (3,)
        Machine coordinates of the plate origin (ball 1).
    rotation : ndarray (3, 3)
        Columns are the plate axes u, v and u x v in machine axes.
    probe : str or None
        Stylus used for files without a probe column.
    temp_C : tuple
        Plate temperatures recorded at start and finish (may be empty).
    rh_percent : tuple
        Relative humidity at start and finish (may be empty).
    """

    origin_mm: np.ndarray
    rotation: np.ndarray
    probe: str | None = None
    temp_C: tuple = ()
    rh_percent: tuple = ()

    @property
    def horizontal(self) -> bool:
        """True when the plate normal is within 10 degrees of machine Z."""
        return abs(self.rotation[2, 2]) > np.cos(np.radians(10))

    def to_machine(self, plate_mm: np.ndarray) -> np.ndarray:
        """Map plate coordinates (n, 3) to machine coordinates."""
        return self.origin_mm + np.asarray(plate_mm) @ self.rotation.T


@dataclass(frozen=True)
class Setup:
    """Machine, plate placements and probe offsets (SPEC setup JSON).

    Attributes
    ----------
    frame : str
        ``machine`` (tip centres in machine axes) or ``plate`` (already in the plate frame).
    range_mm : ndarray (3,)
        Axis strokes of the CMM in mm.
    positions : dict
        Position name -> :class:`Placement`.
    probes : dict
        Probe name -> offset (3,) in mm from the ram reference point to the tip centre.
    cte_per_K : float
        Thermal expansion coefficient of the plate.
    raw : dict
        The JSON as read, for round trips.
    name : str or None
        File name, for messages.
    """

    frame: str
    range_mm: np.ndarray
    positions: dict
    probes: dict
    cte_per_K: float = 11.5e-6
    raw: dict = field(default_factory=dict, repr=False)
    name: str | None = field(default=None, repr=False, compare=False)


@dataclass(frozen=True)
class Certificate:
    """Calibrated ball centres in the plate frame.

    Attributes
    ----------
    balls : ndarray of int (n,)
    xyz_mm : ndarray (n, 3)
    u_um : ndarray (n, 3) or None
        Standard uncertainties of the coordinates in µm, when the file gives them.
    rows : ndarray of int (n,) or None
        File row of each ball, when read from a file (for messages).
    name : str or None
        File name, when read from a file.
    """

    balls: np.ndarray
    xyz_mm: np.ndarray
    u_um: np.ndarray | None = None
    rows: np.ndarray | None = field(default=None, repr=False, compare=False)
    name: str | None = field(default=None, repr=False, compare=False)


def _read_bytes(source, name):
    """The raw bytes of a path, bytes or file-like object, refusing oversized files."""
    if isinstance(source, (str, Path)):
        path = Path(source)
        name = name or path.name
        if not path.exists():
            raise DataError("file not found.", file=name, hint="check the path.")
        if path.stat().st_size > MAX_BYTES:
            raise DataError(f"file is {path.stat().st_size / 1e6:.0f} MB; the limit is "
                            f"{MAX_BYTES / 1e6:.0f} MB.", file=name)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise DataError(f"cannot read ({exc.strerror}).", file=name,
                            hint="check the path and that it is a file.") from None
    elif isinstance(source, bytes):
        data = source
    else:
        data = source.read()
        if isinstance(data, str):
            data = data.encode()
    name = name or "uploaded file"
    if len(data) > MAX_BYTES:
        raise DataError(f"file is {len(data) / 1e6:.0f} MB; the limit is "
                        f"{MAX_BYTES / 1e6:.0f} MB.", file=name)
    return data, name


def _delimiter(header: str) -> str:
    """The column separator of a file, judged from its header line.

    Column names never contain commas, so a header without commas but with semicolons or
    tabs (a spreadsheet export in a locale with decimal commas) names its separator
    unambiguously; ``csv.Sniffer`` is not used because it guesses from the data rows, where
    decimal commas and spaces mislead it.
    """
    if "," in header:
        return ","
    counts = {d: header.count(d) for d in (";", "\t")}
    best = max(counts, key=counts.get)
    return best if counts[best] else ","


def _cut(value, limit: int = 60) -> str:
    """``repr`` of a value for a message, cut to ``limit`` characters: a 1 MB cell or a
    binary blob must not become a 1 MB error line."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 1] + "…"


def _too_many_fields(header, bad, delim, name) -> DataError:
    """Rows with more fields than the header, as one DataError naming every such row."""
    hint = ("a decimal comma (1,5) splits a number into two fields: use a point as "
            "decimal separator, or quote cells that contain commas." if delim == "," else
            f"remove the extra {_DELIM_NAMES[delim]}s or quote cells that contain them.")
    found = _Problems(name, [r for r, _ in bad])
    found.add(np.ones(len(bad), bool), None, lambda i: f"expected {len(header)} fields "
              f"({_cut(','.join(header), 80)}), found {bad[i][1]}.", hint=hint)
    return DataError.collect(found.found, found.total)


def _read_csv(source, name):
    """Read a CSV from a path, bytes or file-like object into strings (nothing coerced).

    The separator is taken from the header line (see :func:`_delimiter`); in a file
    separated by semicolons or tabs, numbers written with a decimal comma are read as
    decimals. Tolerated alike in every file: a UTF-8 byte-order mark, CRLF or CR line
    ends, blank lines (they keep their place in the row numbering), and a separator at
    the end of every line (a common export) as long as nothing follows it. A row with
    more fields than the header, a header naming a column twice, or cells the CSV
    grammar cannot read are refused with their rows.

    Returns
    -------
    df : DataFrame of str
        ``df.attrs`` holds ``delimiter``, ``decimal_comma`` (whether any cell was
        rewritten) and ``rows`` (the file row of each data row; see :func:`_file_rows`).
    name : str
    """
    data, name = _read_bytes(source, name)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataError("is not UTF-8 text (a binary file, or another encoding).", file=name,
                        hint="export the table as CSV (UTF-8).") from exc
    if not text.strip():
        raise DataError("file is empty.", file=name)
    if "\x00" in text:
        raise DataError("contains NUL bytes; it is not a text table.", file=name,
                        hint="export the table as CSV (UTF-8).")
    # one line end everywhere: a bare CR (old Mac export, or a stray one in a cell) would
    # otherwise end a line for one reader and not for another
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    first_line = next(line for line in text.split("\n") if line.strip())
    delim = _delimiter(first_line)
    reader = csv.reader(_io.StringIO(text), delimiter=delim, skipinitialspace=True)
    header, records, rows, bad = None, [], [], []
    try:
        while True:
            start = reader.line_num + 1
            rec = next(reader, None)
            if rec is None:
                break
            if not any(c.strip() for c in rec):
                continue  # blank line: no row, but it keeps its number
            if header is None:
                header = [c.strip() for c in rec]
                continue
            if len(rec) > len(header):
                if any(c.strip() for c in rec[len(header):]):
                    bad.append((start, len(rec)))
                    continue
                rec = rec[:len(header)]  # a trailing separator with nothing after it
            records.append(rec + [""] * (len(header) - len(rec)))
            rows.append(start)
    except csv.Error as exc:
        big = "field larger" in str(exc)
        raise DataError(f"cannot be read as a CSV table ({_cut(str(exc), 80)}).", file=name,
                        row=reader.line_num,
                        hint=(f"a cell is longer than {csv.field_size_limit()} characters: is "
                              "this a CSV table?") if big else
                        "check the quotes in that row.") from None
    if header is None:  # only quotes and separators
        raise DataError("has no header line; expected column names such as "
                        "ball,x_mm,y_mm,z_mm.", file=name, row=1, hint=_COLUMNS_HINT)
    # a separator ending the header line too: drop the nameless columns it made, when empty
    while header and header[-1] == "" and all(r[len(header) - 1].strip() == "" for r in records):
        header.pop()
        records = [r[:len(header)] for r in records]
    if bad:
        raise _too_many_fields(header, bad, delim, name)
    names = [h or f"Unnamed: {k}" for k, h in enumerate(header)]
    twice = sorted({h for h in names if names.count(h) > 1})
    if twice:
        raise DataError(f"the header names column {_cut(twice[0], 40)} twice; expected each "
                        "column once.", file=name, row=1, column=twice[0],
                        hint="rename or delete the repeated column.")
    df = pd.DataFrame(records, columns=names, dtype=object)
    decimal_comma = False
    if delim != ",":
        for col in df.columns.difference(["position", "probe"]):
            fixed = df[col].str.replace(_DECIMAL_COMMA, r"\1.\2", regex=True)
            decimal_comma |= bool((fixed != df[col]).any())
            df[col] = fixed
    df.attrs.update(delimiter=delim, decimal_comma=decimal_comma)
    df.attrs["rows"] = np.asarray(rows, int)
    return df, name


def _file_rows(df) -> np.ndarray:
    """File row of each data row of a :func:`_read_csv` frame (header = row 1)."""
    rows = df.attrs.get("rows")
    return np.arange(2, len(df) + 2) if rows is None else np.asarray(rows)


def _numeric(df, column, name, *, integer=False, allow_missing=False, problems=None):
    """The cells of ``column`` as numbers, every unreadable cell reported with its row.

    Parameters
    ----------
    df : DataFrame
        As read by :func:`_read_csv`.
    column, name : str
        Column to convert; file name for messages.
    integer : bool
        Cells must be whole numbers (ball numbers).
    allow_missing : bool
        Empty cells are NaN rather than problems.
    problems : _Problems, optional
        Collector for the problems. Without one, the problems of this column are raised
        here as one :class:`DataError`.

    Returns
    -------
    ndarray
        Floats, NaN where a cell was reported; ints for ``integer`` when raising here.
    """
    own = problems is None
    if own:
        problems = _Problems(name, _file_rows(df), df.columns)
    text = df[column].fillna("").astype(str).str.strip()
    vals = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float, copy=True)
    blank = (text == "").to_numpy()
    word = text.str.lower().isin(_NAN_WORDS).to_numpy()
    nonfinite = word | np.isinf(vals)
    nonnum = np.isnan(vals) & ~blank & ~word
    problems.add(blank & (not allow_missing), column,
                 lambda i: "expected a number, found an empty cell.",
                 hint="fill in the value or delete the row.")
    problems.add(nonnum, column, lambda i: f"expected a number, found {_cut(text.iat[i])}.",
                 hint="use a point as decimal separator and no units.")
    problems.add(nonfinite, column, lambda i: f"found {_cut(text.iat[i])}, which is not a "
                 "finite number; expected a measured value.",
                 hint="write the measured value or delete the row.")
    vals[nonfinite] = np.nan
    if integer:
        frac = np.isfinite(vals) & (vals != np.round(vals))
        problems.add(frac, column, lambda i: f"expected a whole ball number, found "
                     f"{_cut(text.iat[i])}.")
        vals[frac] = np.nan
    if not own:
        return vals
    problems.raise_if_any()
    return vals.astype(int) if integer and not np.isnan(vals).any() else vals


def _ball_numbers(df, name, problems):
    """Ball numbers (floats, NaN where reported): whole numbers from 1."""
    balls = _numeric(df, "ball", name, integer=True, problems=problems)
    problems.add(balls < 1, "ball",
                 lambda i: f"expected ball numbers from 1, found {balls[i]:.0f}.")
    balls[balls < 1] = np.nan
    return balls


def _names(df, column, problems):
    """Stripped names of ``column``; empty cells reported."""
    names = df[column].fillna("").astype(str).str.strip()
    problems.add((names == "").to_numpy(), column,
                 lambda i: f"expected a {column} name, found an empty cell.")
    return names


_COLUMNS_HINT = ("Columns: position,probe,ball,x_mm,y_mm,z_mm (long form) or "
                 "ball,x_mm,y_mm,z_mm (one file per position), optional time_min, temp_C, "
                 "repeat; lengths in mm, time in minutes, temperature in °C.")


def _require(df, columns, name, form):
    missing = [c for c in columns if c not in df.columns]
    if not missing:
        return
    if len(df.columns) == 1:
        # One column named like "ball x_mm y_mm": the separator is neither comma,
        # semicolon nor tab, so listing missing columns would only confuse.
        raise DataError(f"found a single column {_cut(df.columns[0])}; expected {form} columns "
                        f"{','.join(columns)} separated by commas.", file=name, row=1,
                        hint="save the table as CSV with commas (or semicolons or tabs) "
                             "between the columns.")
    raise DataError(f"missing column(s) {', '.join(missing)}; expected {form} columns "
                    f"{','.join(columns)}, found {','.join(df.columns)}.", file=name,
                    row=1, column=missing[0],
                    hint=_COLUMNS_HINT)


def _require_rows(df, name, what):
    """A file with a header but no data would load as an empty dataset: refuse it."""
    if len(df) == 0:
        raise DataError(f"has no data rows; expected a header followed by one row per "
                        f"{what}.", file=name,
                        hint="export the measured values, not only the column names.")


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


def read_measurements(source, *, name=None, position=None) -> pd.DataFrame:
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
        With every problem of the file in ``problems`` (see the module docstring).
    """
    df, name = _read_csv(source, name)
    # a probe column says long form: without position it must not pass as thesis form,
    # where every position's ball 1 would "appear twice"
    long = "position" in df.columns or "probe" in df.columns
    for c in df.columns:
        # extra columns are kept, but "tempC" for temp_C would silently drop the record
        guess = _typo(str(c), LONG_COLUMNS + OPTIONAL_COLUMNS)
        if guess is not None:
            raise DataError(f"unknown column {_cut(c)}; did you mean {guess!r}?", file=name,
                            row=1, column=str(c),
                            hint="rename the column. " + _COLUMNS_HINT)
    _require(df, LONG_COLUMNS if long else THESIS_COLUMNS, name,
             "long-form" if long else "thesis-form")
    _require_rows(df, name, "probed ball")
    found = _Problems(name, _file_rows(df), df.columns)
    if long:
        out = pd.DataFrame({c: _names(df, c, found) for c in ("position", "probe")})
    else:
        pos = position or Path(name).stem
        out = pd.DataFrame({"position": [pos] * len(df), "probe": [None] * len(df)})
    out["ball"] = _ball_numbers(df, name, found)
    for col in ("x_mm", "y_mm", "z_mm") + tuple(c for c in OPTIONAL_COLUMNS if c in df):
        out[col] = _numeric(df, col, name, problems=found)
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


def read_measurement_files(sources) -> pd.DataFrame:
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


def read_json(source, name=None):
    """Parse JSON from a path, bytes, text or file-like object; every failure a DataError.

    A UTF-8 byte-order mark is tolerated as in CSV files; binary or non-UTF-8 content,
    invalid JSON and absurdly nested documents are refused naming the file.

    Returns
    -------
    obj, name
        The parsed document and the file name used in messages.
    """
    if isinstance(source, (str, Path)) and not (isinstance(source, str)
                                                and source.lstrip()[:1] in ("{", "[")):
        data, name = _read_bytes(source, name)
    elif isinstance(source, str):
        data = source.encode()
    else:
        data, name = _read_bytes(source, name)
    name = name or "uploaded file"
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DataError("is not UTF-8 text (a binary file, or another encoding); expected "
                        "a JSON document.", file=name) from None
    if not text.strip():
        raise DataError("file is empty; expected a JSON document.", file=name)
    try:
        return json.loads(text), name
    except json.JSONDecodeError as exc:
        raise DataError(f"is not valid JSON: {exc.msg} at line {exc.lineno}, column "
                        f"{exc.colno}.", file=name,
                        hint="check the quotes, commas and brackets near that place.") from None
    except (RecursionError, ValueError) as exc:
        raise DataError(f"is not valid JSON ({_cut(str(exc), 80)}).", file=name) from None


def read_setup(source, *, name="setup.json") -> Setup:
    """Read the setup JSON (path, dict, bytes or file-like) and check its fields.

    Besides the structure, the values are checked against what a CMM setup can be:
    ``machine.layout`` from :data:`LAYOUTS`; strokes, origins and probe offsets in mm (not
    metres or µm); u and v axes of unit length and orthogonal within
    :data:`AXIS_TOLERANCE_DEG`; temperatures in °C (not K); a plate CTE per K.
    """
    if isinstance(source, dict):
        raw = source
    else:
        raw, name = read_json(source, None if isinstance(source, (str, Path)) else name)
    if not isinstance(raw, dict):
        raise DataError("expected a JSON object.", file=name)
    _check_keys(raw, SETUP_KEYS[""], name, "")
    for sub in ("machine", "plate"):
        if isinstance(raw.get(sub), dict):
            _check_keys(raw[sub], SETUP_KEYS[sub], name, sub)
    units = raw.get("units", "mm")
    if units != "mm":
        raise DataError(f"units must be 'mm', found {_cut(units)}.", file=name, column="units")
    frame = raw.get("frame", "machine")
    if frame not in ("machine", "plate"):
        raise DataError(f"frame must be 'machine' or 'plate', found {_cut(frame)}.", file=name,
                        column="frame")
    machine = _json_object(raw, "machine", name)
    layout = machine.get("layout", LAYOUTS[0])
    if not isinstance(layout, str) or layout not in LAYOUTS:
        close = difflib.get_close_matches(str(layout), list(LAYOUTS), n=1, cutoff=0.5)
        raise DataError(f"machine.layout {_cut(layout)} is not a supported kinematic chain"
                        + (f" (did you mean {close[0]!r}?)" if close else "")
                        + f"; expected one of: {', '.join(LAYOUTS)}.", file=name,
                        column="machine.layout",
                        hint="the name gives the chain from the workpiece to the probe, F the "
                             "foundation: 'moving_bridge_fxyz' (the bridge moves in x, the y "
                             "carriage runs across it, z ram), 'fixed_bridge_xfyz' (the table "
                             "moves in x); see docs/layouts.md.")
    rng = _vector(machine.get("range_mm", [1200, 1000, 700]), name, "machine.range_mm",
                  "three positive lengths (mm)")
    if (rng <= 0).any():
        raise DataError(f"machine.range_mm must be three positive lengths, found {rng}.",
                        file=name, column="machine.range_mm")
    if rng.min() < MIN_STROKE_MM or rng.max() > MAX_STROKE_MM:
        raise DataError(f"machine.range_mm {rng.tolist()} is not a CMM's strokes in mm "
                        f"(expected {MIN_STROKE_MM:g} to {MAX_STROKE_MM:g} mm per axis).",
                        file=name, column="machine.range_mm",
                        hint="strokes in metres (1.2) or inches are refused: write mm, e.g. "
                             "[1200, 1000, 700].")
    tol = _range_tolerance(rng)
    probes = {}
    for pname, vec in _json_object(raw, "probes", name).items():
        col = f"probes.{pname}"
        p = _vector(vec, name, col, "a vector of 3 numbers (mm)")
        size = float(np.linalg.norm(p))
        if 0 < size < 1.0 or size > MAX_PROBE_MM:
            raise DataError(f"probe offset {p.tolist()} is {size:.4g} mm long; expected a "
                            f"stylus offset in mm (0, or 1 to {MAX_PROBE_MM:g} mm).", file=name,
                            column=col, hint="offsets in metres or µm are refused: write mm, "
                            "e.g. [0, 0, -150].")
        probes[str(pname)] = p
    positions = {}
    for pos, spec in _json_object(raw, "positions", name).items():
        key = f"positions.{pos}"
        if not isinstance(spec, dict):
            raise DataError(f"expected an object with origin_mm, u_axis, v_axis, found "
                            f"{type(spec).__name__} {_cut(spec)}.", file=name, column=key)
        _check_keys(spec, SETUP_KEYS["position"], name, key)
        if "origin_mm" not in spec:
            raise DataError("position needs origin_mm (and u_axis, v_axis) as 3-vectors.",
                            file=name, column=key)
        origin = _vector(spec["origin_mm"], name, key + ".origin_mm", "3 numbers (mm)")
        if ((origin < -tol) | (origin > rng + tol)).any():
            raise DataError(f"origin_mm {origin.tolist()} lies outside the machine's range "
                            f"{rng.tolist()} mm.", file=name, column=key + ".origin_mm",
                            hint="write the origin (ball 1) in machine coordinates in mm.")
        if 0 < np.abs(origin).max() < 2.0 and rng.max() >= 100:
            raise DataError(f"origin_mm {origin.tolist()} is within 2 mm of the machine zero; "
                            "it looks like metres, not mm.", file=name,
                            column=key + ".origin_mm", hint="multiply by 1000 (mm).")
        u = _vector(spec.get("u_axis", [1, 0, 0]), name, key + ".u_axis", "3 numbers")
        v = _vector(spec.get("v_axis", [0, 1, 0]), name, key + ".v_axis", "3 numbers")
        if np.linalg.norm(u) < 1e-12:
            raise DataError("u_axis is the zero vector.", file=name, column=key + ".u_axis")
        if np.linalg.norm(v) < 1e-12 or np.linalg.norm(np.cross(u, v)) < 1e-6 * (
                np.linalg.norm(u) * np.linalg.norm(v)):
            raise DataError("u_axis and v_axis are parallel (or v_axis is zero).", file=name,
                            column=key)
        off = abs(90.0 - np.degrees(np.arccos(np.clip(
            u @ v / (np.linalg.norm(u) * np.linalg.norm(v)), -1, 1))))
        if off > AXIS_TOLERANCE_DEG:
            raise DataError(f"u_axis and v_axis are {90 - off:.3g}° apart; expected "
                            f"orthogonal axes (within {AXIS_TOLERANCE_DEG:g}°).", file=name,
                            column=key, hint="the plate axes are at right angles: check "
                            "v_axis (e.g. u [1, 0, 0] with v [0, 1, 0] or [0, 0, 1]).")
        for ax, vec in (("u_axis", u), ("v_axis", v)):
            if abs(np.linalg.norm(vec) - 1) > 1e-3:
                raise DataError(f"{ax} {vec.tolist()} has length {np.linalg.norm(vec):.4g}; "
                                "expected a unit vector.", file=name, column=f"{key}.{ax}",
                                hint="divide by its length (e.g. [0.7071, 0.7071, 0]).")
        u = u / np.linalg.norm(u)
        v = v - u * (u @ v)  # removes rounding below the tolerance only
        v = v / np.linalg.norm(v)
        probe = spec.get("probe")
        if probe is not None and str(probe) not in probes:
            raise DataError(f"probe {_cut(probe)} is not among the probes {sorted(probes)}.",
                            file=name, column=key + ".probe")
        records = {rec: _record(spec.get(rec, ()), name, f"{key}.{rec}", rec)
                   for rec in ("temp_C", "rh_percent")}
        positions[str(pos)] = Placement(origin, np.column_stack([u, v, np.cross(u, v)]),
                                        None if probe is None else str(probe),
                                        records["temp_C"], records["rh_percent"])
    if not positions:
        raise DataError("no positions defined.", file=name, column="positions")
    plate = _json_object(raw, "plate", name)
    for key, lo in (("pitch_mm", 1.0), ("balls", 3)):
        val = plate.get(key)
        if val is not None and (isinstance(val, bool) or not isinstance(val, int | float)
                                or not np.isfinite(val) or val < lo
                                or (key == "balls" and not float(val).is_integer())):
            raise DataError(f"plate.{key} must be {'a length >= 1 mm' if key == 'pitch_mm' else 'a whole number >= 3'} "
                            f"(or absent), found {_cut(val)}.", file=name, column=f"plate.{key}")
    cte = plate.get("cte_per_K", 11.5e-6)
    if isinstance(cte, bool) or not isinstance(cte, int | float) or not np.isfinite(cte):
        raise DataError(f"plate.cte_per_K must be a number (1/K, e.g. 11.5e-6), found "
                        f"{_cut(cte)}.", file=name, column="plate.cte_per_K")
    if not CTE_RANGE_PER_K[0] <= cte <= CTE_RANGE_PER_K[1]:
        raise DataError(f"plate.cte_per_K {cte:g} is not a plate material's expansion per K; "
                        f"expected {CTE_RANGE_PER_K[0]:g} to {CTE_RANGE_PER_K[1]:g} "
                        "(steel 11.5e-6, Zerodur about 0).", file=name,
                        column="plate.cte_per_K",
                        hint="write it per K, not per MK or %/K: 11.5e-6 for steel.")
    cte = float(cte)
    return Setup(frame, rng, positions, probes, cte, raw, name)


LAYOUTS = tuple(_KINEMATIC_LAYOUTS)
"""Kinematic chains the model supports (``machine.layout``; ``kinematics.LAYOUTS``), the
default first."""
AXIS_TOLERANCE_DEG = 0.1
"""Largest departure of a position's u and v axes from a right angle (degrees)."""
MIN_STROKE_MM, MAX_STROKE_MM = 10.0, 50_000.0
MAX_PROBE_MM = 2000.0
CTE_RANGE_PER_K = (-1e-6, 3e-5)
"""Plausible plate CTE: Zerodur's about ±0.1e-6 to aluminium's 23e-6 and a margin."""
TEMP_RANGE_C = (0.0, 50.0)
"""Plausible temperatures of a CMM room or a plate (°C)."""


def _range_tolerance(rng):
    """How far beyond the strokes a point may lie (styli reach past them)."""
    return np.maximum(0.05 * np.asarray(rng, float), 100.0)


def _record(val, name, column, what):
    """Temperatures (°C) or humidities (%) of a setup position: a number or list."""
    val = [val] if isinstance(val, int | float) and not isinstance(val, bool) else val
    if not isinstance(val, list | tuple) or not all(
            isinstance(t, int | float) and not isinstance(t, bool) for t in val):
        raise DataError(f"{what} must be a number or a list of numbers, found {_cut(val)}.",
                        file=name, column=column)
    out = tuple(float(t) for t in val)
    if what == "temp_C":
        _check_celsius(np.asarray(out), name, column)
    elif any(not 0 <= t <= 100 for t in out):
        raise DataError(f"relative humidity {list(out)} must be 0 to 100 %.", file=name,
                        column=column, hint="write percent, not a fraction.")
    return out


def _check_celsius(t, name, column, row=None):
    """Temperatures must be finite °C in :data:`TEMP_RANGE_C`; kelvin named as such."""
    bad = ~np.isfinite(t) | (t < TEMP_RANGE_C[0]) | (t > TEMP_RANGE_C[1])
    if not bad.any():
        return
    x = float(t[bad][0])
    kelvin = 253 < x < 343
    raise DataError(f"temperature {x:g} is {'in kelvin' if kelvin else 'not plausible'}; "
                    f"expected °C ({TEMP_RANGE_C[0]:g} to {TEMP_RANGE_C[1]:g}).", file=name,
                    row=row, column=column,
                    hint="subtract 273.15 (°C, not K)." if kelvin else
                    "write the plate temperature in °C.")


SETUP_KEYS = {
    "": ("units", "frame", "machine", "positions", "probes", "plate"),
    "machine": ("layout", "range_mm"),
    "plate": ("cte_per_K", "balls", "pitch_mm"),
    "position": ("origin_mm", "u_axis", "v_axis", "probe", "temp_C", "rh_percent"),
}
"""Keys the setup reader uses, per object; other keys are free (notes, names), but one
that looks like a misspelt known key is refused (it would silently leave a default)."""


COLUMN_ALIASES = {"time": "time_min", "t_min": "time_min", "minutes": "time_min",
                  "time_s": "time_min", "time_h": "time_min", "temp": "temp_C",
                  "temperature": "temp_C", "t_c": "temp_C", "temp_k": "temp_C",
                  "x": "x_mm", "y": "y_mm", "z": "z_mm", "x_m": "x_mm", "y_m": "y_mm",
                  "z_m": "z_mm", "x_in": "x_mm", "y_in": "y_mm", "z_in": "z_mm",
                  "x_um": "x_mm", "y_um": "y_mm", "z_um": "z_mm", "pos": "position",
                  "placement": "position", "stylus": "probe", "ball_no": "ball",
                  "rep": "repeat", "u_axis": "u_axis", "uaxis": "u_axis", "vaxis": "v_axis"}
"""Names (lower case) that stand for a known column or key: refused with the name they
mean, since read as an extra column they would silently leave a record (time, a
temperature) out, and a unit in the name says the values are not in mm, minutes or °C."""


def _fold(key: str) -> str:
    """A key as compared for misspellings: case, hyphens and spaces do not count."""
    return str(key).lower().replace("-", "_").replace(" ", "_")


def _typo(key: str, known, cutoff: float = 0.85):
    """The known key ``key`` most likely misspells (case, a dropped letter), or None."""
    if key in known:
        return None
    low = {_fold(k): k for k in known}
    if _fold(key) in low:
        return low[_fold(key)]
    if key.lower() in COLUMN_ALIASES and COLUMN_ALIASES[key.lower()] in known:
        return COLUMN_ALIASES[key.lower()]
    close = difflib.get_close_matches(_fold(key), list(low), n=1, cutoff=cutoff)
    return low[close[0]] if close else None


def _check_keys(obj: dict, known, name, where: str):
    for k in obj:
        guess = _typo(str(k), known)
        if guess is not None:
            raise DataError(f"unknown key {_cut(k)}; did you mean {guess!r}? (A misspelt key "
                            "would silently leave its default.)", file=name,
                            column=f"{where}.{k}" if where else str(k))


def _json_object(raw: dict, key: str, name) -> dict:
    """``raw[key]`` when it is a JSON object (``{}`` when absent), else a DataError."""
    val = raw.get(key, {})
    if not isinstance(val, dict):
        raise DataError(f"expected a JSON object for {key!r}, found {type(val).__name__} "
                        f"{_cut(val)}.", file=name, column=key)
    return val


def _vector(val, name, column, expected) -> np.ndarray:
    """A length-3 float vector from JSON, or a DataError saying what was expected."""
    v = None
    # JSON numbers only: np.asarray would read ["1", "0", "0"] or [true, 0, 0] silently
    if isinstance(val, list | tuple) and all(isinstance(x, int | float) and not
                                             isinstance(x, bool) for x in val):
        v = np.asarray(val, float)
    if v is None or v.shape != (3,) or not np.isfinite(v).all():
        raise DataError(f"must be {expected}, found {_cut(val)}.", file=name, column=column)
    return v


def read_certificate(source, *, name=None) -> Certificate:
    """Read a certificate CSV ``ball,x_mm,y_mm,z_mm[,u_x_um,u_y_um,u_z_um]``.

    Every cell is checked (see :func:`read_measurements`); the certificate must then give
    at least three balls that do not lie on one line, the least that defines a plate frame.
    """
    df, name = _read_csv(source, name)
    _require(df, THESIS_COLUMNS, name, "certificate")
    _require_rows(df, name, "calibrated ball")
    found = _Problems(name, _file_rows(df), df.columns)
    balls = _ball_numbers(df, name, found)
    xyz = np.column_stack([_numeric(df, c, name, problems=found)
                           for c in ("x_mm", "y_mm", "z_mm")])
    _check_duplicates(pd.DataFrame({"ball": balls}), ["ball"], found)
    _check_units(xyz, found)
    u = _uncertainties(df, name, found)
    found.raise_if_any()
    _check_plate_frame(xyz, name)
    rows = _file_rows(df)
    _check_isolated_balls(xyz, balls, rows, name)
    balls = balls.astype(int)
    order = np.argsort(balls)
    return Certificate(balls[order], xyz[order], None if u is None else u[order],
                       rows=rows[order], name=name)


def _check_isolated_balls(xyz, balls, rows, name):
    """A ball far from every other ball of the plate is a typing or unit slip (a ball at
    y = 5000 mm on a 532 mm plate), not a calibrated centre: refuse it with its row.

    "Far" is more than ten times the median nearest-neighbour distance and more than
    100 mm, which no regular or irregular plate layout reaches.
    """
    if len(xyz) < 4:
        return
    from scipy.spatial import cKDTree

    nn = cKDTree(xyz).query(xyz, k=2)[0][:, 1]
    typical = float(np.median(nn))
    far = nn > max(10 * typical, 100.0)
    if far.any():
        found = _Problems(name, rows, ("ball", "x_mm", "y_mm", "z_mm"))
        found.add(far, "x_mm", lambda i: f"ball {balls[i]:.0f} at {np.round(xyz[i], 3).tolist()} "
                  f"mm lies {nn[i]:.0f} mm from its nearest neighbour (typical spacing "
                  f"{typical:.0f} mm); expected a ball of the plate.",
                  hint="check its coordinates for a slipped digit or another unit.")
        found.raise_if_any()


def _uncertainties(df, name, found):
    """The u_x_um, u_y_um, u_z_um columns (positive µm), or None when the file has none."""
    cols = ("u_x_um", "u_y_um", "u_z_um")
    present = [c for c in cols if c in df.columns]
    if not present:
        return None
    if len(present) < 3:
        # Dropping the given ones silently would fit as if there were no uncertainties.
        found.add_file(f"has {', '.join(present)} but not "
                       f"{', '.join(c for c in cols if c not in present)}; expected all "
                       "three uncertainty columns or none.", column=present[0])
        return None
    u = np.column_stack([_numeric(df, c, name, problems=found) for c in cols])
    for j, col in enumerate(cols):
        found.add(u[:, j] <= 0, col, lambda i, j=j: f"expected a positive uncertainty "
                  f"(µm), found {u[i, j]:g}.")
    return u


def _check_plate_frame(xyz, name):
    """A plate frame needs three balls off one line (origin, x direction, xy plane)."""
    n = len(xyz)
    if n < MIN_CERTIFICATE_BALLS:
        raise DataError(f"has {n} ball{'s' * (n != 1)}; expected at least "
                        f"{MIN_CERTIFICATE_BALLS} (a plate frame needs 3 non-collinear "
                        "balls).", file=name, column="ball",
                        hint="give the calibrated centres of all balls of the plate.")
    sv = np.linalg.svd(xyz - xyz.mean(axis=0), compute_uv=False)
    # a measured row of balls is off its line by µm: that defines no plate plane, so
    # "on one line" means within 0.1 % of the plate's size
    if sv[1] <= 1e-3 * max(sv[0], 1.0):
        raise DataError("all balls lie on one line; expected at least 3 non-collinear "
                        "balls to define the plate frame.", file=name, column="x_mm",
                        hint="check the coordinates, or give more balls of the plate.")


def resolve(meas: pd.DataFrame, setup: Setup, certificate: Certificate | None = None):
    """Attach probes from the setup, check names and balls, map to machine coordinates.

    Returns a copy of ``meas`` with the probe filled in and columns ``mx_mm, my_mm,
    mz_mm`` (machine-frame tip centres) added. Raises one :class:`DataError` listing every
    problem (an unknown position or probe once per file, duplicates and balls missing from
    the certificate once per row), each naming its file and row.
    """
    df = meas.copy()
    found = _Problems(None, df["row"].to_numpy(), files=df["source"].to_numpy())
    known_pos = df["position"].isin(list(setup.positions)).to_numpy()
    found.add(_first_per(df, ~known_pos, ["source", "position"]), "position",
              lambda i: f"position {_cut(df['position'].iat[i])} is not in the setup (known: "
              f"{', '.join(setup.positions)}).",
              hint=f"add it to {setup.name or 'the setup'} or rename the file.")
    default = df["position"].map(lambda p: setup.positions[p].probe
                                 if p in setup.positions else None)
    no_probe = df["probe"].isna().to_numpy()
    if no_probe.any():
        df["probe"] = df["probe"].astype(object).where(~no_probe, default)
    orphan = no_probe & known_pos & df["probe"].isna().to_numpy()
    found.add(_first_per(df, orphan, ["source", "position"]), None,
              lambda i: "no probe column and the setup names no probe for position "
              f"{_cut(df['position'].iat[i])}.",
              hint="add \"probe\" to the position in setup.json.")
    unknown = (df["probe"].notna() & ~df["probe"].isin(list(setup.probes))).to_numpy()
    found.add(_first_per(df, unknown, ["source", "probe"]), "probe",
              lambda i: f"probe {_cut(df['probe'].iat[i])} is not in the setup (known: "
              f"{', '.join(setup.probes)}).",
              hint=f"add its offset to 'probes' in {setup.name or 'the setup'}.")
    key = ["position", "probe", "ball"] + (["repeat"] if "repeat" in df.columns else [])
    _check_duplicates(df, key, found,
                      hint="add a 'repeat' column for repeated measurements.")
    if certificate is not None:
        extra = (~df["ball"].isin(set(certificate.balls.tolist()))).to_numpy()
        found.add(extra, "ball", lambda i: f"ball {df['ball'].iat[i]} is not on the "
                  f"certificate (balls {certificate.balls.min()}-{certificate.balls.max()}).")
    found.raise_if_any(sort=False)
    raw_xyz = df[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    xyz = raw_xyz
    if setup.frame == "plate":
        m = np.empty_like(xyz)
        for pos, pl in setup.positions.items():
            sel = (df["position"] == pos).to_numpy()
            m[sel] = pl.to_machine(xyz[sel])
        xyz = m
    if certificate is not None:
        _check_certificate_in_machine(df, setup, certificate)
    _check_geometry(df, raw_xyz, xyz, setup, certificate, found)
    found.raise_if_any(sort=False)
    df["mx_mm"], df["my_mm"], df["mz_mm"] = xyz.T
    return df


def _check_certificate_in_machine(df, setup, cert):
    """Every certificate ball, placed by every position of the data, must lie in the
    machine: a ball outside says the certificate row (or the placement) is wrong."""
    rng = np.asarray(setup.range_mm, float)
    tol = _range_tolerance(rng)
    for pos in dict.fromkeys(df["position"]):
        m = setup.positions[pos].to_machine(cert.xyz_mm)
        out = ((m < -tol) | (m > rng + tol)).any(axis=1)
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise DataError(f"ball {cert.balls[i]} at {np.round(cert.xyz_mm[i], 3).tolist()} "
                            f"mm, placed by position {_cut(pos)}, lies at "
                            f"{np.round(m[i], 1).tolist()} mm, outside the machine's range "
                            f"{rng.tolist()} mm.", file=cert.name or "certificate",
                            row=None if cert.rows is None else int(cert.rows[i]),
                            hint="check the certificate's coordinates (mm, plate frame) "
                                 "and the position's origin_mm and axes in the setup.")


_UNIT_RATIOS = ((1 / 25.4, "inches", "multiply by 25.4"), (1e-3, "metres",
                "multiply by 1000"), (1e3, "µm", "divide by 1000"),
                (25.4, "mm while the certificate is in inches", "check the certificate's units"))


def _check_geometry(df, raw_xyz, xyz, setup, cert, found):
    """Measured points against the setup: inside the machine, where the nominal placement
    puts the plate, and at the certificate's scale.

    Units, frame and placement mistakes otherwise fit (a plate measured in inches fitted
    at an RMS of 28 mm and exit 0); each is named here with its likely fix. The placement
    tolerance is generous (15 % of the longest stroke, at least 150 mm): a nominal setup
    is rough, a wrong unit or frame is not.
    """
    rng = np.asarray(setup.range_mm, float)
    tol = _range_tolerance(rng)
    outside = ((xyz < -tol) | (xyz > rng + tol)).any(axis=1)
    where = f"the setup {setup.name}" if setup.name else "the setup"
    frame_hint = (f"{where} has \"frame\": \"machine\""
                  f"{'' if 'frame' in setup.raw else ' (the default: no frame key)'}: if the "
                  "coordinates are in the plate frame (ball 1 at 0, 0, 0), set \"frame\": "
                  "\"plate\"." if setup.frame == "machine" else f"{where} has \"frame\": "
                  "\"plate\": if the coordinates are machine coordinates, set \"frame\": "
                  "\"machine\".")
    found.add(outside & _first_rows(df, outside), None,
              lambda i: f"point {np.round(xyz[i], 1).tolist()} mm (machine frame) lies "
              f"outside the machine's range {rng.tolist()} mm.",
              hint="coordinates must be in mm; " + frame_hint)
    if outside.any():
        return
    place_tol = max(150.0, 0.15 * rng.max())
    n = len(df)
    for (_src, pos), idx in df.groupby(["source", "position"], sort=False).indices.items():
        pl = setup.positions[pos]
        balls = df["ball"].to_numpy()[idx]
        if cert is not None:
            known = {b: k for k, b in enumerate(cert.balls.tolist())}
            plate = cert.xyz_mm[[known[b] for b in balls]]
        else:
            sel = balls == 1
            if not sel.any():
                continue
            idx, plate = idx[sel], np.zeros((int(sel.sum()), 3))
        expect = pl.to_machine(plate)
        dist = float(np.median(np.linalg.norm(xyz[idx] - expect, axis=1)))
        ratio = None
        if cert is not None and len(idx) >= 3:
            spread = np.sqrt(((plate - plate.mean(0)) ** 2).sum(1).mean())
            got = np.sqrt(((xyz[idx] - xyz[idx].mean(0)) ** 2).sum(1).mean())
            ratio = got / spread if spread > 0 else None
        unit = next((u for u in _UNIT_RATIOS if ratio and abs(ratio / u[0] - 1) < 0.05), None)
        where = f"position {_cut(pos)}"
        if unit is not None:
            msg = (f"distances between the balls of {where} are {ratio:.4g} times the "
                   f"certificate's: the coordinates look like {unit[1]}.")
            hint = (f"{unit[2]} (files are in mm)" + (f"; certificate {cert.name}."
                                                      if cert.name else "."))
        elif ratio is not None and abs(ratio - 1) > 0.01:
            msg = (f"distances between the balls of {where} are {ratio:.4g} times the "
                   "certificate's; expected the same plate (within 1 %).")
            hint = (f"check that the certificate {cert.name or ''}, the units (mm) and the "
                    "ball numbering match the measurement.")
        elif dist > place_tol:
            as_plate = float(np.median(np.linalg.norm(raw_xyz[idx] - plate, axis=1)))
            as_machine = float(np.median(np.linalg.norm(raw_xyz[idx] - expect, axis=1)))
            msg = (f"{where} is measured {dist:.0f} mm (median) from where the setup places "
                   f"its balls; expected within {place_tol:.0f} mm.")
            frame_wrong = (as_plate < place_tol if setup.frame == "machine"
                           else as_machine < place_tol)
            hint = frame_hint if frame_wrong else (
                f"check origin_mm and the axes of {where} in the setup, the units (mm) and "
                "the frame.")
        else:
            continue
        found.add(np.arange(n) == idx[0], None, lambda i, m=msg: m, hint=hint)


def _first_rows(df, mask) -> np.ndarray:
    """``mask`` reduced to the first masked row of each file (one problem per file)."""
    return _first_per(df, mask, ["source"])


def _first_per(df, mask, key) -> np.ndarray:
    """``mask`` reduced to the first masked row of each ``key`` group: a wrong name is one
    problem, however many rows repeat it."""
    idx = np.flatnonzero(mask)
    first = ~df.iloc[idx][key].astype(str).duplicated().to_numpy()
    out = np.zeros(len(df), bool)
    out[idx[first]] = True
    return out


def missing_balls(meas: pd.DataFrame, certificate: Certificate | None) -> list:
    """``(position, probe, [balls])`` for every position/probe that lacks balls."""
    if certificate is None:
        allb = set(meas["ball"].unique().tolist())
    else:
        allb = set(certificate.balls.tolist())
    out = []
    for (pos, probe), g in meas.groupby(["position", "probe"], sort=False, dropna=False):
        miss = sorted(allb - set(g["ball"].tolist()))
        if miss:
            out.append((pos, probe, miss))
    return out


def write_long_csv(df: pd.DataFrame, path) -> None:
    """Write measurements in long form (mm, 6 decimals = 1 nm)."""
    cols = [c for c in LONG_COLUMNS + OPTIONAL_COLUMNS if c in df.columns]
    df[cols].to_csv(path, index=False, float_format="%.6f")


def write_certificate(cert: Certificate, path) -> None:
    """Write a certificate CSV (with uncertainty columns when present)."""
    df = pd.DataFrame({"ball": cert.balls, "x_mm": cert.xyz_mm[:, 0],
                       "y_mm": cert.xyz_mm[:, 1], "z_mm": cert.xyz_mm[:, 2]})
    if cert.u_um is not None:
        df["u_x_um"], df["u_y_um"], df["u_z_um"] = cert.u_um.T
    df.to_csv(path, index=False, float_format="%.6f")

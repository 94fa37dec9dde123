"""Tables written by other software, read through a column mapping into the long form.

A :class:`TableMapping` says which column of a delimited table holds the position, probe,
ball and the x, y, z coordinates (and optionally the time and the plate temperature), in
which unit the lengths are written, which decimal separator and field delimiter the file
uses, and which constant position or probe stands in when the table has no such column.
Ball numbers (and position or probe) may instead come from a feature label such as
``BP111_5`` through a regular expression with named groups, as in vendor exports with a
``Feature`` column. :func:`preview` shows the first converted rows and every problem
without raising; :func:`apply_mapping` converts the whole file into a
:class:`ForeignTable`: the project's long-form measurement table and its CSV text, ready
for :func:`~cmm_core.io.load_dataset`.

The converted table is checked by the project's own reader
(:func:`~cmm_core.io.read_measurements`: duplicates, units that look like metres or µm,
kelvin temperatures), and its CSV keeps every row on the line of the source file it came
from (blank lines pad the gaps), so any later message naming a row names the row of the
user's file. Columns in messages are the source file's. See ``docs/foreign-formats.md``.

Holds also what :mod:`.dmis` shares: :class:`ForeignTable`, the label-pattern check and the
final conversion to long form.
"""

from __future__ import annotations

import io as _io
import re
from collections.abc import Iterable
from dataclasses import dataclass, fields, replace

import numpy as np
import pandas as pd

from .delimited import (
    _DECIMAL_COMMA,
    _DELIM_NAMES,
    MAX_MEASUREMENT_ROWS,
    FileSource,
    file_rows,
    numeric_column,
    read_bytes,
    read_csv_text,
    read_json,
)
from .errors import DataError, Problems, cut_repr, likely_typo, refuse_unknown_keys
from .measurements import LONG_COLUMNS, read_measurements

LENGTH_UNITS_MM = {"mm": 1.0, "um": 1e-3, "inch": 25.4}
"""Length units a mapped table may be written in, and the size of one unit in mm."""
TIME_UNITS_MIN = {"min": 1.0, "s": 1.0 / 60.0, "h": 60.0}
"""Time units of a mapped time column, and the size of one unit in minutes."""
DECIMALS = (".", ",")
"""Decimal separators of a mapped table."""
DELIMITERS = ("auto", ",", ";", "\t")
"""Field delimiters of a mapped table; ``auto`` takes the one the header line shows."""
LABEL_GROUPS = ("position", "probe", "ball")
"""Named groups a label pattern may have."""
_COLUMN_KEYS = ("x", "y", "z", "position", "probe", "ball", "label", "time", "temperature")
"""Keys of a :class:`TableMapping` that name a column of the source table."""

_ALIASES = {"µm": "um", "μm": "um", "micron": "um", "microns": "um", "in": "inch",
            "inches": "inch", '"': "inch", "millimetre": "mm", "millimeter": "mm",
            "minutes": "min", "minute": "min", "sec": "s", "seconds": "s", "hours": "h",
            "hour": "h", "tab": "\t", "\\t": "\t", "comma": ",", "semicolon": ";",
            "point": ".", "dot": "."}
_UNIT_HINT = "choose the unit the coordinates are written in (mm, um or inch)."
_NUMBER_HINT = ("write a number without units, with the decimal separator the mapping "
                "says.")
_PREFIX_SHOWN = 5  # labels named in the one-line note on labels left out


@dataclass(frozen=True, eq=False)
class ForeignTable:
    """A foreign file converted to the project's long form.

    Attributes
    ----------
    meas : DataFrame
        As :func:`~cmm_core.io.read_measurements` returns it: ``position, probe, ball,
        x_mm, y_mm, z_mm``, optional ``time_min, temp_C, repeat``, and ``source`` (=
        :attr:`csv_name`) and ``row`` (the line of the source file each row came from).
    csv_text : str
        The long-form CSV (lengths in mm with 6 decimals, 1 nm). Each data row stands on
        the line of the source file it came from; blank lines pad the gaps.
    csv_name : str
        Name under which the CSV is loaded: the source name and ``(mapped)``.
    name : str
        The source file's name.
    notes : tuple of str
        How the file was read (separator, unit conversion, constants used, labels left
        out), one line each.
    unmatched : tuple of str
        Every label that did not match the pattern (not loaded), in file order.
    mapping : dict or None
        The column mapping the table was read through (``TableMapping.to_dict()``); None
        for a file read otherwise (DMIS).
    source_text : str or None
        The source table's text, kept with ``mapping`` so that a project file or an
        analysis record reloads the table through it; None when not UTF-8 text (the
        converted ``csv_text`` is kept then).
    """

    meas: pd.DataFrame
    csv_text: str
    csv_name: str
    name: str
    notes: tuple = ()
    unmatched: tuple = ()
    mapping: dict | None = None
    source_text: str | None = None

    def as_source(self) -> tuple:
        """``(file-like, name)`` of the CSV, as :func:`~cmm_core.io.load_dataset` takes a
        measurement file."""
        return _io.BytesIO(self.csv_text.encode()), self.csv_name


@dataclass(frozen=True, eq=False)
class Preview:
    """The first converted rows of a mapped table and every problem found, unloaded.

    Attributes
    ----------
    rows : DataFrame
        The first rows in long form (``position, probe, ball, x_mm, y_mm, z_mm``, optional
        ``time_min, temp_C``) with the source ``row``; NaN where a cell could not be read.
    n_rows : int
        Rows converted in the whole file (labels left out not counted).
    problems : tuple of str
        One line per problem (file, row, column, what was expected); empty when the table
        would load.
    notes : tuple of str
        How the file was read, one line each.
    """

    rows: pd.DataFrame
    n_rows: int
    problems: tuple = ()
    notes: tuple = ()

    @property
    def ok(self) -> bool:
        """Whether :func:`apply_mapping` would load the table."""
        return not self.problems


@dataclass(frozen=True, eq=False)
class TableInfo:
    """What a delimited table offers for mapping (see :func:`inspect_table`).

    Attributes
    ----------
    columns : tuple of str
        The header's column names.
    delimiter : str
        The field delimiter read from the header line.
    decimal : str
        ``","`` when numbers were written with decimal commas, else ``"."``.
    n_rows : int
        Data rows.
    suggestion : dict
        Mapping keys with the column that most likely holds them (see
        :func:`suggest_mapping`).
    """

    columns: tuple
    delimiter: str
    decimal: str
    n_rows: int
    suggestion: dict


@dataclass(frozen=True)
class TableMapping:
    """How the columns of a delimited table become the long form.

    Column keys name a column of the source table (``None``: not in the table).

    Attributes
    ----------
    x, y, z : str
        Columns of the coordinates (the tip centre as the CMM reports it).
    position, probe, ball : str or None
        Columns of the position name, the probe name and the ball number.
    label : str or None
        Column of a feature label (``BP111_5``) read with ``pattern``.
    pattern : str or None
        Regular expression a whole label must match, with named groups ``ball`` and
        optionally ``position`` and ``probe``, e.g. ``(?P<position>BP\\d+)_(?P<ball>\\d+)``.
        Rows whose label does not match are left out and listed.
    time : str or None
        Column of the probing time, in ``time_unit``.
    temperature : str or None
        Column of the plate temperature, °C.
    constant_position : str or None
        Position of every row when neither a column nor the pattern gives one.
    constant_probe : str or None
        Probe of every row when neither a column nor the pattern gives one.
    unit : {"mm", "um", "inch"}
        Unit of the coordinates (converted to mm).
    time_unit : {"min", "s", "h"}
        Unit of the time column (converted to minutes).
    decimal : {".", ","}
        Decimal separator of the numbers.
    delimiter : {"auto", ",", ";", "\\t"}
        Field delimiter; ``auto`` takes the one the header line shows, another value is
        checked against it.

    Raises
    ------
    DataError
        On construction, for any value out of place (one line: the key, what was expected,
        what was found).
    """

    x: str
    y: str
    z: str
    position: str | None = None
    probe: str | None = None
    ball: str | None = None
    label: str | None = None
    pattern: str | None = None
    time: str | None = None
    temperature: str | None = None
    constant_position: str | None = None
    constant_probe: str | None = "1"
    unit: str = "mm"
    time_unit: str = "min"
    decimal: str = "."
    delimiter: str = "auto"

    def __post_init__(self) -> None:
        _check_mapping(self.to_dict(), "column mapping")

    def to_dict(self) -> dict:
        """Every key and its value (JSON-ready; :meth:`from_dict` reads it back)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, obj: dict, *, name: str = "column mapping") -> TableMapping:
        """A mapping from a JSON object, every key checked.

        Parameters
        ----------
        obj : dict
            Keys as :meth:`to_dict` writes them; ``x``, ``y``, ``z`` required, the others
            default.
        name : str
            File name for messages.

        Raises
        ------
        DataError
            For a key not known (with the key it most likely misspells), a missing
            coordinate column, or a value of the wrong type or out of its choices.
        """
        if not isinstance(obj, dict):
            raise DataError(f"expected a JSON object of mapping keys, found "
                            f"{type(obj).__name__} {cut_repr(obj, 40)}.", file=name,
                            hint="write {\"x\": \"X\", \"y\": \"Y\", \"z\": \"Z\", ...}.")
        known = [f.name for f in fields(cls)]
        refuse_unknown_keys(obj, known, name, what="mapping key")
        for k in ("x", "y", "z"):
            if obj.get(k) is None:
                raise DataError(f"missing key {k!r}; expected the name of the table column "
                                f"holding the {k} coordinate.", file=name, column=k)
        full = {**{f.name: f.default for f in fields(cls) if f.name not in ("x", "y", "z")},
                **obj}
        _check_mapping(full, name)
        return cls(**obj)


def read_mapping(source: FileSource, name: str | None = None) -> TableMapping:
    """Read a column mapping from a JSON file (path, bytes, text or file-like).

    Raises
    ------
    DataError
        Naming the file and the key that is wrong (see :meth:`TableMapping.from_dict`).
    """
    obj, name = read_json(source, name)
    return TableMapping.from_dict(obj, name=name or "column mapping")


# ---------------------------------------------------------------------------------------
# Checks of the mapping itself
# ---------------------------------------------------------------------------------------

def _choice(d, key, choices, name):
    """``d[key]`` must be one of ``choices``: refused with the one it most likely means."""
    value = d[key]
    if value in choices:
        return
    guess = _ALIASES.get(str(value).strip().lower()) if isinstance(value, str) else None
    if guess not in choices:
        guess = likely_typo(str(value), choices, cutoff=0.6) if isinstance(value, str) else None
    shown = ", ".join(repr(c) for c in choices)
    raise DataError(f"expected one of {shown}, found {cut_repr(value)}"
                    + (f"; did you mean {guess!r}?" if guess in choices else "."),
                    file=name, column=key)


def _label_regex(pattern, name, column="pattern", *, position=False):
    """A label pattern compiled and checked: named groups only from :data:`LABEL_GROUPS`,
    ``ball`` among them, and ``position`` when ``position`` (no other source of it).

    Parameters
    ----------
    pattern : str
        The regular expression (a whole label must match it).
    name, column : str
        Where the pattern came from, for messages.
    position : bool
        Whether the pattern must give the position.

    Returns
    -------
    re.Pattern

    Raises
    ------
    DataError
        One line: the regular expression's error, an unknown group (with the group it most
        likely misspells) or a missing group.
    """
    if not isinstance(pattern, str) or not pattern.strip():
        raise DataError(f"expected a regular expression with named groups, found "
                        f"{cut_repr(pattern)}.", file=name, column=column,
                        hint="e.g. (?P<position>BP\\d+)_(?P<ball>\\d+).")
    try:
        rx = re.compile(pattern)
    except re.error as exc:
        raise DataError(f"is not a valid regular expression: {exc}.", file=name,
                        column=column, hint="e.g. (?P<position>BP\\d+)_(?P<ball>\\d+).") \
            from None
    for group in rx.groupindex:
        if group not in LABEL_GROUPS:
            guess = likely_typo(group, LABEL_GROUPS, cutoff=0.6)
            raise DataError(f"unknown group {group!r}"
                            + (f"; did you mean {guess!r}?" if guess else ";")
                            + f" expected groups {', '.join(LABEL_GROUPS)}.", file=name,
                            column=column)
    need = ["ball"] + (["position"] if position else [])
    missing = [g for g in need if g not in rx.groupindex]
    if missing:
        raise DataError(f"has no group {missing[0]!r}; expected (?P<{missing[0]}>...) "
                        f"around the {missing[0]} in the label.", file=name, column=column,
                        hint="e.g. (?P<position>BP\\d+)_(?P<ball>\\d+)"
                        + ("" if position else "; or give a default position") + ".")
    return rx


def _check_mapping(d: dict, name) -> None:
    """Every value of a mapping dict in place (one DataError for the first that is not)."""
    for key in _COLUMN_KEYS + ("constant_position", "constant_probe"):
        v = d.get(key)
        if v is not None and (not isinstance(v, str) or not v.strip()):
            what = "a column name" if key in _COLUMN_KEYS else f"a {key.split('_')[1]} name"
            raise DataError(f"expected {what} (text) or null, found {cut_repr(v)}.",
                            file=name, column=key)
    _choice(d, "unit", tuple(LENGTH_UNITS_MM), name)
    _choice(d, "time_unit", tuple(TIME_UNITS_MIN), name)
    _choice(d, "decimal", DECIMALS, name)
    _choice(d, "delimiter", DELIMITERS, name)
    if (d.get("label") is None) != (d.get("pattern") is None):
        given, other = ("label", "pattern") if d.get("label") is not None else ("pattern",
                                                                                "label")
        raise DataError(f"{given} given without {other}; expected both (the column of "
                        "feature labels and the pattern that reads them) or neither.",
                        file=name, column=other)
    groups = {}
    if d.get("pattern") is not None:
        need_pos = d.get("position") is None and d.get("constant_position") is None
        groups = _label_regex(d["pattern"], name, position=need_pos).groupindex
    elif d.get("ball") is None:
        raise DataError("no ball number: expected a 'ball' column, or a 'label' column "
                        "with a 'pattern' that has a (?P<ball>...) group.", file=name,
                        column="ball")
    if d.get("position") is None and d.get("constant_position") is None \
            and "position" not in groups:
        raise DataError("no position: expected a 'position' column, a (?P<position>...) "
                        "group in the pattern or a 'constant_position'.", file=name,
                        column="position")
    if d.get("probe") is None and d.get("constant_probe") is None \
            and "probe" not in groups:
        raise DataError("no probe: expected a 'probe' column, a (?P<probe>...) group in "
                        "the pattern or a 'constant_probe'.", file=name, column="probe")
    numeric = [k for k in ("x", "y", "z", "ball", "time", "temperature")
               if d.get(k) is not None]
    for i, a in enumerate(numeric):
        for b in numeric[i + 1:]:
            if d[a] == d[b]:
                raise DataError(f"{a} and {b} both name column {d[a]!r}; expected a "
                                "column of its own for each.", file=name, column=b)


# ---------------------------------------------------------------------------------------
# From a table to long-form values
# ---------------------------------------------------------------------------------------

def suggest_mapping(columns: Iterable[str]) -> dict[str, str]:
    """The column most likely holding each mapping key, by its name.

    Recognises the project's own names (``x_mm``), bare axis letters (``X``, ``X-Wert``,
    ``X [mm]``), ``Feature``/``Name``/``Label`` for the label and common words for ball,
    position, probe, time and temperature. Keys with no likely column are left out.
    """
    words = {
        "x": r"x(_mm|_um|_in)?([ _-]?(wert|value|meas|actual|ist))?",
        "y": r"y(_mm|_um|_in)?([ _-]?(wert|value|meas|actual|ist))?",
        "z": r"z(_mm|_um|_in)?([ _-]?(wert|value|meas|actual|ist))?",
        "ball": r"(ball|ball_?no|ball_?number|kugel|sphere_?no)",
        "position": r"(position|pos|placement|lage|setup)",
        "probe": r"(probe|stylus|tastereinsatz|taster|tip)",
        "label": r"(feature|name|label|element|merkmal|id)",
        "time": r"(time_?min|time|zeit|t_?min|minutes)",
        "temperature": r"(temp_?c|temp|temperature|temperatur)",
    }
    out: dict[str, str] = {}
    for key, rx in words.items():
        for c in columns:
            bare = re.sub(r"\s*[\[(].*?[\])]\s*$", "", str(c)).strip().lower()
            if re.fullmatch(rx, bare) and c not in out.values():
                out[key] = c
                break
    if "ball" in out:
        out.pop("label", None)
    return out


def inspect_table(source: FileSource, *, name: str | None = None) -> TableInfo:
    """Read a delimited table's header and rows for mapping (nothing converted).

    Raises
    ------
    DataError
        When the file cannot be read as a table (see :func:`~cmm_core.io.read_csv_text`).
    """
    df, name = read_csv_text(source, name, max_rows=MAX_MEASUREMENT_ROWS)
    return TableInfo(tuple(df.columns), df.attrs["delimiter"],
                     "," if df.attrs["decimal_comma"] else ".", len(df),
                     suggest_mapping(df.columns))


def _check_table(df, m: TableMapping, name):
    """The mapped columns exist; delimiter and decimal separator agree with the file."""
    delim = df.attrs["delimiter"]
    if m.delimiter != "auto" and m.delimiter != delim:
        raise DataError(f"the header line is {_DELIM_NAMES[delim]}-separated; the mapping "
                        f"says {_DELIM_NAMES[m.delimiter]}.", file=name, row=1,
                        hint="choose the delimiter the file uses, or 'auto'.")
    if m.decimal == "." and df.attrs["decimal_comma"]:
        raise DataError(f"numbers are written with decimal commas (the file is "
                        f"{_DELIM_NAMES[delim]}-separated); the mapping says decimal "
                        "point.", file=name, hint="choose ',' as decimal separator.")
    for key in _COLUMN_KEYS:
        col = getattr(m, key)
        if col is not None and col not in df.columns:
            guess = likely_typo(col, list(df.columns), cutoff=0.6)
            raise DataError(f"the mapping's {key} column {col!r} is not in the file"
                            + (f"; did you mean {guess!r}?" if guess else ";")
                            + f" found columns {cut_repr(', '.join(df.columns), 120)}.",
                            file=name, row=1, column=col)


def _label_rows(df, m: TableMapping):
    """Which rows' labels match the pattern, their groups, and the labels left out."""
    labels = df[m.label].fillna("").astype(str).str.strip()
    if m.pattern is None:  # the caller reads labels only for a mapping with a pattern
        raise ValueError("the mapping has no label pattern")
    rx = re.compile(m.pattern)
    hits = [rx.fullmatch(s) for s in labels]
    keep = np.array([h is not None for h in hits], bool)
    groups = {g: [h.group(g) if h else None for h, k in zip(hits, keep, strict=True) if k]
              for g in rx.groupindex}
    return keep, groups, labels[keep].tolist(), labels[~keep].tolist()


def _unmatched_note(unmatched, pattern, what="label") -> str | None:
    """One line: how many labels did not match the pattern and the first few of them."""
    if not unmatched:
        return None
    shown = ", ".join(cut_repr(s, 30) for s in unmatched[:_PREFIX_SHOWN])
    more = " ..." if len(unmatched) > _PREFIX_SHOWN else ""
    return (f"{len(unmatched)} {what}(s) do not match the pattern {pattern} and were "
            f"left out: {shown}{more}.")


def _names_from(n, column_values, group_values, constant, what, labels, found, column):
    """Names of one key (position or probe) from a column, else the pattern's group, else
    the constant; a row with none reported.

    Parameters
    ----------
    n : int
        Number of rows.
    column_values, group_values : sequence of str or None, or None
        The values of the source column and of the pattern group, when given.
    constant : str or None
    what : str
        ``position`` or ``probe``, for messages.
    labels : list of str or None
        Labels of the rows, for messages.
    found : Problems
    column : str or None
        Source column reported.
    """
    if column_values is not None:
        out = pd.Series(column_values, dtype=object).fillna("").astype(str).str.strip()
        found.add((out == "").to_numpy(), column,
                  lambda i: f"expected a {what} name, found an empty cell.")
        return out.tolist()
    if group_values is not None:
        out = [(g or "").strip() or constant for g in group_values]
        found.add(np.array([o is None for o in out], bool), column,
                  lambda i: f"label {labels[i]!r} matched the pattern without a {what} "
                  "group; expected one, or a default.")
        return out
    return [constant] * n


def _balls_from(group_values, labels, found, column):
    """Ball numbers (floats, NaN where reported) from the pattern's ball group."""
    balls = np.full(len(group_values), np.nan)
    for i, g in enumerate(group_values):
        if g is not None and g.strip().isdigit():
            balls[i] = int(g)
    found.add(np.isnan(balls), column,
              lambda i: f"label {labels[i]!r}: the ball group matched "
              f"{cut_repr(group_values[i])}; expected a whole ball number.",
              hint="let the ball group match digits only, e.g. (?P<ball>\\d+).")
    return balls


def _numbers(sub, column, m, name, found):
    """A mapped numeric column as floats, decimal commas read when the mapping says so."""
    if m.decimal == "," and sub.attrs["delimiter"] == ",":
        # quoted "1,5" in a comma-separated file: read_csv_text leaves it as it is
        sub = sub.assign(**{column: sub[column].str.replace(_DECIMAL_COMMA, r"\1.\2",
                                                            regex=True)})
    return numeric_column(sub, column, name, problems=found)


def _convert(df, m: TableMapping, name):
    """The mapped table's long-form values, every cell problem collected, nothing raised
    for cells (a file-level problem raises).

    Returns
    -------
    long : DataFrame
        Long-form columns, NaN where a cell was reported.
    rows : ndarray of int
        Source file row of each long-form row.
    labels : list of str or None
    unmatched : list of str
    found : Problems
    notes : list of str
    """
    _check_table(df, m, name)
    rows = file_rows(df)
    keep, groups, labels, unmatched = (np.ones(len(df), bool), {}, None, [])
    if m.label is not None:
        keep, groups, labels, unmatched = _label_rows(df, m)
    sub = df.loc[keep].reset_index(drop=True)
    sub.attrs = {**df.attrs, "rows": rows[keep]}
    found = Problems(name, rows[keep], df.columns)
    long = pd.DataFrame(index=range(len(sub)))
    for what, const in (("position", m.constant_position), ("probe", m.constant_probe)):
        col = getattr(m, what)
        long[what] = _names_from(len(sub), None if col is None else sub[col], groups.get(what), const,
                                what, labels, found, col or m.label)
    if m.ball is not None:
        balls = numeric_column(sub, m.ball, name, integer=True, problems=found)
    else:
        balls = _balls_from(groups["ball"], labels, found, m.label)
    long["ball"] = balls
    factor = LENGTH_UNITS_MM[m.unit]
    for axis in ("x", "y", "z"):
        long[f"{axis}_mm"] = _numbers(sub, getattr(m, axis), m, name, found) * factor
    if m.time is not None:
        long["time_min"] = _numbers(sub, m.time, m, name, found) * TIME_UNITS_MIN[m.time_unit]
    if m.temperature is not None:
        long["temp_C"] = _numbers(sub, m.temperature, m, name, found)
    found.found = [DataError(e.detail, file=e.file, row=e.row, column=e.column,
                             hint=_NUMBER_HINT if e.hint and "decimal separator" in e.hint
                             else e.hint) for e in found.found]
    return long, rows[keep], labels, unmatched, found, _notes(df, m, unmatched)


def _notes(df, m: TableMapping, unmatched) -> list:
    """How the table was read, one line each."""
    notes = []
    delim = df.attrs["delimiter"]
    if delim != "," or m.decimal == ",":
        notes.append(f"read as {_DELIM_NAMES[delim]}-separated"
                     + (" with decimal commas." if m.decimal == "," else "."))
    if m.unit != "mm":
        notes.append(f"coordinates converted from {m.unit} to mm (× {LENGTH_UNITS_MM[m.unit]:g}).")
    if m.time is not None and m.time_unit != "min":
        notes.append(f"times converted from {m.time_unit} to minutes.")
    groups = re.compile(m.pattern).groupindex if m.pattern else {}
    for what, const in (("position", m.constant_position), ("probe", m.constant_probe)):
        if getattr(m, what) is None and what not in groups:
            notes.append(f"{what} {const!r} for every row (no {what} column).")
    note = _unmatched_note(unmatched, m.pattern)
    if note:
        notes.append(note)
    return notes


# ---------------------------------------------------------------------------------------
# From long-form values to a checked ForeignTable
# ---------------------------------------------------------------------------------------

def _repeat_index(labels) -> np.ndarray | None:
    """Repeat index of each row (0 for the first time a label appears, 1 the next ...);
    None when no label repeats."""
    if labels is None:
        return None
    rep = pd.Series(labels).groupby(labels, sort=False).cumcount().to_numpy()
    return rep if rep.any() else None


def _csv_text(long: pd.DataFrame, rows) -> str:
    """Long-form CSV with each data row on its source line (blank lines pad) when the
    source rows allow it (all after line 1, increasing)."""
    cols = [c for c in (*LONG_COLUMNS, "time_min", "temp_C", "repeat") if c in long]
    body = long[cols].to_csv(index=False, float_format="%.6f", lineterminator="\n")
    lines = body.rstrip("\n").split("\n")
    rows = np.asarray(rows, int)
    if len(rows) and rows[0] >= 2 and np.all(np.diff(rows) > 0):
        out = [""] * int(rows[-1])
        out[0] = lines[0]
        for r, line in zip(rows, lines[1:], strict=True):
            out[r - 1] = line
        lines = out
    return "\n".join(lines) + "\n"


def _remapped(exc: DataError, name, colmap, prefix, rows, padded) -> DataError:
    """A DataError of the long-form reader told in the source's terms: its columns, rows
    (when the CSV was not padded to them) and the label of the row."""
    by_csv_row = {r: i for i, r in enumerate(rows)} if padded else \
        {k + 2: k for k in range(len(rows))}

    def row_of(r):
        i = by_csv_row.get(r)
        return None if i is None else int(rows[i])

    out = []
    for p in exc.problems:
        detail = p.detail
        if not padded:
            detail = re.sub(r"\brow (\d+)", lambda g: f"row {row_of(int(g[1])) or g[1]}", detail)
        i = None if p.row is None else by_csv_row.get(p.row)
        if prefix is not None and i is not None and prefix[i]:
            detail = f"{prefix[i]}: {detail}"
        hint = p.hint
        if p.column in ("x_mm", "y_mm", "z_mm") and ("look" in detail or "µm" in detail):
            hint = _UNIT_HINT
        elif "appears twice" in detail:
            hint = ("check the pattern or the position, probe and ball columns: each ball "
                    "once per position and probe.")
        out.append(DataError(detail, file=name, row=row_of(p.row) if not padded else p.row,
                             column=colmap.get(p.column, p.column), hint=hint))
    return DataError.collect(out, exc.n_problems)


def _finish(long, rows, name, *, colmap, notes=(), unmatched=(), labels=None,
           prefix=None) -> ForeignTable:
    """Long-form values checked by the project's measurement reader, as a ForeignTable.

    Parameters
    ----------
    long : DataFrame
        ``position, probe, ball, x_mm, y_mm, z_mm`` and optional ``time_min, temp_C``.
    rows : array of int
        Source file row (line) of each row.
    name : str
        Source file name.
    colmap : dict
        Long-form column -> the source's column (or None), for messages.
    notes, unmatched : sequence of str
    labels : list of str, optional
        Feature label of each row: a label seen again becomes a ``repeat``.
    prefix : list of str, optional
        Text put before a message about each row (the sphere's label).

    Raises
    ------
    DataError
        Every problem of the long-form reader, in the source's rows and columns.
    """
    long = long.copy()
    notes = list(notes)
    rep = _repeat_index(labels)
    if rep is not None:
        long["repeat"] = rep
        notes.append(f"{int((rep > 0).sum())} row(s) repeat a label seen before: "
                     "numbered as repeats 1, 2 ... (column 'repeat').")
    long["ball"] = long["ball"].astype(int)
    text = _csv_text(long, rows)
    rows = np.asarray(rows, int)
    padded = bool(len(rows) and rows[0] >= 2 and np.all(np.diff(rows) > 0))
    csv_name = f"{name} (mapped)"
    try:
        meas = read_measurements(_io.BytesIO(text.encode()), name=csv_name)
    except DataError as exc:
        raise _remapped(exc, name, colmap, prefix, rows, padded) from None
    meas["row"] = rows
    return ForeignTable(meas, text, csv_name, name, tuple(notes), tuple(unmatched))


def _colmap(m: TableMapping) -> dict:
    return {"position": m.position or m.label, "probe": m.probe or m.label,
            "ball": m.ball or m.label, "x_mm": m.x, "y_mm": m.y, "z_mm": m.z,
            "time_min": m.time, "temp_C": m.temperature}


def _as_mapping(mapping) -> TableMapping:
    return mapping if isinstance(mapping, TableMapping) else TableMapping.from_dict(mapping)


def apply_mapping(source: FileSource, mapping: TableMapping | dict, *,
              name: str | None = None) -> ForeignTable:
    """Convert a whole delimited table through a column mapping to the long form.

    Parameters
    ----------
    source : path, bytes or file-like
        The table (comma-, semicolon- or tab-separated).
    mapping : TableMapping or dict
    name : str, optional
        File name for messages (default: the path's name).

    Returns
    -------
    ForeignTable

    Raises
    ------
    DataError
        With every problem of the file in ``problems`` (file, row and the source's column;
        ``str(exc)`` one line): a mapped column missing, a cell that is not a number, a
        label whose ball group is not a number, no row matching the pattern, duplicates,
        units that look wrong.
    """
    m = _as_mapping(mapping)
    raw, name = read_bytes(source, name)
    df, name = read_csv_text(raw, name, max_rows=MAX_MEASUREMENT_ROWS)
    if len(df) == 0:
        raise DataError("has no data rows; expected a header followed by one row per "
                        "probed ball.", file=name,
                        hint="export the measured values, not only the column names.")
    long, rows, labels, unmatched, found, notes = _convert(df, m, name)
    found.raise_if_any()
    if len(long) == 0:
        shown = ", ".join(cut_repr(s, 30) for s in unmatched[:_PREFIX_SHOWN])
        raise DataError(f"no label matches the pattern {m.pattern}; found {shown}"
                        + (" ..." if len(unmatched) > _PREFIX_SHOWN else "") + ".",
                        file=name, column=m.label,
                        hint="the pattern must match a whole label, e.g. "
                        "(?P<position>BP\\d+)_(?P<ball>\\d+) for BP111_5.")
    prefix = None if labels is None else [repr(s) for s in labels]
    table = _finish(long, rows, name, colmap=_colmap(m), notes=notes, unmatched=unmatched,
                    labels=labels, prefix=prefix)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:  # kept converted only: the record's files are text
        text = None
    return replace(table, mapping=m.to_dict(), source_text=text)


def _empty_rows() -> pd.DataFrame:
    return pd.DataFrame(columns=["row", *LONG_COLUMNS])


def _lines(exc: DataError) -> list:
    """Every problem of a DataError as one line each, with a last line for those not
    listed."""
    out = [str(p) for p in exc.problems]
    hidden = exc.n_problems - len(exc.problems)
    if hidden > 0:
        out.append(f"... and {hidden} more problem(s) not listed.")
    return out


def preview(source: FileSource, mapping: TableMapping | dict, *, name: str | None = None,
        n: int = 10) -> Preview:
    """The first rows of a table converted through a mapping, and every problem, without
    loading anything and without raising.

    Parameters
    ----------
    source : path, bytes or file-like
    mapping : TableMapping or dict
    name : str, optional
        File name for messages.
    n : int
        Rows shown.

    Returns
    -------
    Preview
        Problems (one line each) stand where :func:`apply_mapping` would raise.
    """
    try:
        m = _as_mapping(mapping)
        df, name = read_csv_text(source, name, max_rows=MAX_MEASUREMENT_ROWS)
        long, rows, labels, unmatched, found, notes = _convert(df, m, name)
    except DataError as exc:
        return Preview(_empty_rows(), 0, tuple(_lines(exc)))
    problems = []
    if found.found:
        problems = _lines(DataError.collect(sorted(found.found, key=lambda e: e.row or 0),
                                            found.total))
    elif len(long) == 0:
        problems = [str(DataError("no row to load: no label matches the pattern.", file=name,
                                  column=m.label))]
    else:
        try:
            prefix = None if labels is None else [repr(s) for s in labels]
            _finish(long, rows, name, colmap=_colmap(m), labels=labels, prefix=prefix)
        except DataError as exc:
            problems = _lines(exc)
    shown = long.head(n).copy()
    shown.insert(0, "row", rows[:len(shown)])
    return Preview(shown.reset_index(drop=True), len(long), tuple(problems), tuple(notes))


_SPHERE_COLUMNS = ("position", "probe", "ball", "x_mm", "y_mm", "z_mm", "time_min")
"""The long form's columns a sphere reader fills (none from a table column)."""


def _sphere_table(hits, rx, labels, lines, xyz_mm, minutes, *, name, pattern, notes,
                  unmatched, prefix, default_position, default_probe) -> ForeignTable:
    """The long form of the spheres whose labels matched (the DMIS and QIF readers'
    common end): their position, probe and ball from the labels (:func:`_label_columns`),
    coordinates and times; every problem of a label raised at once; the notes of the
    groups the pattern lacks and of the labels left out after the reader's own
    ``notes``."""
    found = Problems(name, lines)
    long = _label_columns(hits, rx, labels, found, default_position, default_probe)
    long["x_mm"], long["y_mm"], long["z_mm"] = np.asarray(xyz_mm, float).reshape(-1, 3).T
    if minutes is not None:
        long["time_min"] = minutes
    found.raise_if_any()
    notes = list(notes)
    if "probe" not in rx.groupindex:
        notes.append(f"probe {str(default_probe)!r} for every sphere (no probe group).")
    if "position" not in rx.groupindex:
        notes.append(f"position {default_position!r} for every sphere (no position group).")
    um = _unmatched_note(unmatched, pattern)
    if um:
        notes.append(um)
    return _finish(long, lines, name, colmap=dict.fromkeys(_SPHERE_COLUMNS, None),
                   notes=notes, unmatched=unmatched, labels=labels, prefix=prefix)


def _label_columns(hits, rx, labels, found, default_position, default_probe) -> pd.DataFrame:
    """``position``, ``probe`` and ``ball`` of each matched label (``hits``, matches of the
    pattern ``rx``): a group the pattern lacks takes its default; problems go to ``found``.
    Shared by the DMIS and QIF readers."""
    return pd.DataFrame({
        "position": _names_from(len(hits), None, [h.groupdict().get("position") for h in hits]
                                if "position" in rx.groupindex else None, default_position,
                                "position", labels, found, None),
        "probe": _names_from(len(hits), None, [h.groupdict().get("probe") for h in hits]
                             if "probe" in rx.groupindex else None, str(default_probe),
                             "probe", labels, found, None),
        "ball": _balls_from([h["ball"] for h in hits], labels, found, None),
    })

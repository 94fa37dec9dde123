"""DMIS output files (``.dmo``): measured spheres read into the long form.

A DMIS output file reports each measured feature as a statement; this reader takes the
spheres, ``FA(label)=FEAT/SPHERE,CART,x,y,z,d`` (measured) or ``F(label)=...`` (nominal;
used only when the file has no measured sphere), with an optional ``INNER``/``OUTER``
before ``CART``. A ``$`` at the end of a line continues the statement on the next line;
``$$`` starts a comment. ``UNITS/MM`` (or ``CM``, ``METER``, ``INCH``, ``FEET``) sets the
unit of the spheres that follow (converted to mm; without a UNITS line: mm, with a note);
``DATE=`` and ``TIME=`` lines give the time of the spheres that follow, read as minutes
from the first DATE/TIME of the file (``time_min``).

The user maps each label to position, probe and ball by a regular expression with named
groups (see :func:`read_dmis`); labels that do not match are listed (one line: how many,
the first few) and left out. Every problem names the file, the line (as ``row``) and the
sphere's label. See ``docs/foreign-formats.md``.

:func:`read_foreign` routes any foreign measurement file to its reader: a QIF document to
:func:`cmm_core.io.read_qif`, a DMIS file here, any other table through a column mapping.
"""

from __future__ import annotations

import re
from datetime import date, datetime, time, timedelta
from pathlib import Path

import numpy as np

from .delimited import MAX_MEASUREMENT_ROWS, FileSource, read_bytes
from .errors import DataError, cut_repr
from .qif import QIF_LABEL_PATTERN, is_qif, read_qif
from .table_mapping import (
    ForeignTable,
    TableMapping,
    _label_regex,
    _sphere_table,
    apply_mapping,
)

DMIS_UNITS_MM = {"MM": 1.0, "CM": 10.0, "METER": 1000.0, "INCH": 25.4, "FEET": 304.8}
"""Length units of a DMIS ``UNITS/`` statement and the size of one unit in mm."""
DMIS_SUFFIXES = (".dmo", ".dmi", ".dms")
"""File name endings read as DMIS by :func:`read_foreign`."""

_SPHERE = re.compile(r"^(?P<kind>FA|F)\s*\(\s*(?P<label>[^)]*?)\s*\)\s*=\s*FEAT\s*/\s*"
                     r"SPHERE\s*(?P<args>.*)$", re.I)
_FEATURE = re.compile(r"^(?P<kind>FA|F)\s*\(\s*(?P<label>[^)]*?)\s*\)\s*=\s*FEAT\s*/\s*"
                      r"(?P<type>\w+)", re.I)
"""Any other feature (a circle, a point, a plane): not a ball, but said, not dropped."""
_ASSIGN = re.compile(r"^(?P<key>DATE|TIME)\s*=\s*(?P<value>.*)$", re.I)
_UNITS = re.compile(r"^UNITS\s*/\s*(?P<unit>[A-Z]*)", re.I)
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
_MONTHS = {m: i + 1 for i, m in enumerate(("JAN", "FEB", "MAR", "APR", "MAY", "JUN", "JUL",
                                           "AUG", "SEP", "OCT", "NOV", "DEC"))}
_DATES = (  # (pattern, order of the groups)
    (re.compile(r"^(\d{4})[/.-](\d{1,2})[/.-](\d{1,2})$"), "ymd"),  # 2026/11/24 (DMIS)
    (re.compile(r"^(\d{1,2})\.(\d{1,2})\.(\d{2}|\d{4})$"), "dmy"),  # 24.11.2026
    (re.compile(r"^(\d{1,2})/(\d{1,2})/(\d{2}|\d{4})$"), "mdy"),  # 11/24/2026
    (re.compile(r"^(\d{1,2})[- ]([A-Za-z]{3})[A-Za-z]*[- ](\d{2}|\d{4})$"), "dMy"),  # 24-NOV-2026
)
_TIME = re.compile(r"^(\d{1,2}):(\d{2})(?::(\d{2})(?:[.,](\d+))?)?$")
_DATE_FORMS = "2026/11/24, 2026-11-24, 24.11.2026, 11/24/2026 or 24-NOV-2026"
_NO_DATE = date(2000, 1, 1)  # the day of TIME lines in a file without any DATE line


def _statements(text):
    """(first line, statement) of every DMIS statement: comments (``$$``) dropped, lines
    ending in ``$`` joined with the next."""
    parts, start = [], None
    for k, raw in enumerate(text.split("\n"), 1):
        line = raw.split("$$", 1)[0].strip()
        if not line:
            continue
        if start is None:
            start = k
        if line.endswith("$"):
            parts.append(line[:-1].strip())
            continue
        parts.append(line)
        yield start, "".join(parts)
        parts, start = [], None
    if parts:
        yield start, "".join(parts)


def _value(text: str) -> str:
    """The value of ``DATE=``/``TIME=`` without quotes and blanks."""
    return text.strip().strip("'\"").strip()


def _parse_date(text):
    """A DMIS date in one of the common forms (see :data:`_DATE_FORMS`), or None."""
    for rx, order in _DATES:
        g = rx.match(text)
        if not g:
            continue
        parts = dict(zip(order, g.groups(), strict=True))
        month = _MONTHS.get(parts["M"][:3].upper()) if "M" in parts else int(parts["m"])
        year = int(parts["y"])
        year += 2000 if year < 100 else 0
        try:
            return date(year, month or 0, int(parts["d"]))
        except (ValueError, TypeError):
            return None
    return None


def _parse_time(text):
    """A DMIS time ``HH:MM[:SS[.fff]]``, or None."""
    g = _TIME.match(text)
    if not g:
        return None
    h, m, s, frac = g.groups()
    try:
        return time(int(h), int(m), int(s or 0), int(((frac or "0") + "000000")[:6]))
    except ValueError:
        return None


def _decode(data: bytes, name):
    """The text of a DMIS file; not UTF-8: Latin-1 with a note; binary refused."""
    if b"\x00" in data:
        raise DataError("contains NUL bytes; it is not a DMIS text file.", file=name,
                        hint="give the DMIS output file (.dmo) as the CMM software wrote it.")
    try:
        return data.decode("utf-8-sig"), None
    except UnicodeDecodeError:
        return data.decode("latin-1"), "not UTF-8: read as Latin-1."


class _Sphere:
    """One sphere statement as read: kind, label, line, values in mm and its time."""

    __slots__ = ("kind", "label", "line", "xyz_mm", "stamp")

    def __init__(self, kind, label, line, xyz_mm, stamp):
        self.kind, self.label, self.line = kind, label, line
        self.xyz_mm, self.stamp = xyz_mm, stamp


class _Reader:
    """The state while reading a DMIS file's statements in order."""

    def __init__(self, name):
        self.name = name
        self.unit, self.unit_line = None, None
        self.units_used = set()
        self.day, self.clock = None, None
        self.stamps = []  # (line, day or None, clock) of every DATE/TIME
        self.spheres = []
        self.others = []  # (line, kind, type, label) of measured features not spheres
        self.problems = []
        self.first_unitless = None

    def error(self, line, message, hint=None):
        self.problems.append(DataError(message, file=self.name, row=line, hint=hint))

    def units(self, line, unit):
        factor = DMIS_UNITS_MM.get(unit.upper())
        if factor is None:
            self.error(line, f"UNITS/{cut_repr(unit, 20)[1:-1]}: expected a length unit "
                       f"{', '.join(DMIS_UNITS_MM)}.", hint="write e.g. UNITS/MM,ANGDEC.")
            return
        self.unit = unit.upper()

    def assign(self, line, key, value):
        v = _value(value)
        if key.upper() == "DATE":
            day = _parse_date(v)
            if day is None:
                self.error(line, f"DATE={cut_repr(v, 30)[1:-1]}: expected a date such as "
                           f"{_DATE_FORMS}.")
                return
            self.day = day
        else:
            clock = _parse_time(v)
            if clock is None:
                self.error(line, f"TIME={cut_repr(v, 30)[1:-1]}: expected a time of day "
                           "such as 14:05:33.")
                return
            self.clock = clock
            self.stamps.append((line, self.day, clock))

    def sphere(self, line, kind, label, args):
        if len(self.spheres) >= MAX_MEASUREMENT_ROWS:
            raise DataError(f"has more than {MAX_MEASUREMENT_ROWS} spheres (row {line} is "
                            "beyond the limit of a measurement file).", file=self.name,
                            row=line, hint="split the run into several files "
                                           "(docs/formats.md#size-limits).")
        toks = [t.strip() for t in args.split(",")]
        where = f"sphere {kind.upper()}({label})"
        if toks[0]:
            self.error(line, f"{where}: expected a comma after FEAT/SPHERE, found "
                       f"{cut_repr(toks[0], 30)}.")
            return
        toks = toks[1:]
        if toks and toks[0].upper() in ("INNER", "OUTER"):
            toks = toks[1:]
        if not toks or toks[0].upper() != "CART":
            found = cut_repr(toks[0], 20) if toks else "nothing"
            self.error(line, f"{where}: expected CART (cartesian x,y,z,d), found {found}.",
                       hint="output the spheres in cartesian coordinates.")
            return
        vals = toks[1:]
        if len(vals) < 4:
            self.error(line, f"{where}: expected 4 values x,y,z,d after CART, found "
                       f"{len(vals)}.", hint="check the continuation lines ($ at the end).")
            return
        bad = [(a, v) for a, v in zip("xyzd", vals, strict=False) if not _NUMBER.match(v)]
        if bad:
            a, v = bad[0]
            self.error(line, f"{where}: expected a number as its {a} value, found "
                       f"{cut_repr(v, 30)}.")
            return
        if self.unit is None and self.first_unitless is None:
            self.first_unitless = line
        unit = self.unit or "MM"
        self.units_used.add(unit)
        xyz = np.array([float(v) for v in vals[:3]]) * DMIS_UNITS_MM[unit]
        stamp = None if self.clock is None else (self.day, self.clock)
        self.spheres.append(_Sphere(kind.upper(), label, line, xyz, stamp))


def _read_statements(text, name) -> _Reader:
    rd = _Reader(name)
    for line, st in _statements(text):
        g = _SPHERE.match(st)
        if g:
            rd.sphere(line, g["kind"], g["label"], g["args"])
            continue
        g = _FEATURE.match(st)
        if g:
            rd.others.append((line, g["kind"].upper(), g["type"].upper(), g["label"]))
            continue
        g = _UNITS.match(st)
        if g:
            rd.units(line, g["unit"])
            continue
        g = _ASSIGN.match(st)
        if g:
            rd.assign(line, g["key"], g["value"])
    return rd


def _minutes(rd: _Reader, spheres):
    """Minutes of each sphere from the first DATE/TIME, or None (with a note) when some
    sphere comes before any TIME; a sphere timed before the one above it is a problem."""
    if not rd.stamps:
        return None, None
    if any(s.stamp is None for s in spheres):
        n = sum(s.stamp is None for s in spheres)
        return None, (f"{n} sphere(s) come before the first TIME line: no time column "
                      "(the row order is the measurement order).")
    first_day = next((d for _, d, _ in rd.stamps if d is not None), _NO_DATE)
    t0 = datetime.combine(rd.stamps[0][1] or first_day, rd.stamps[0][2])
    when = [datetime.combine(s.stamp[0] or first_day, s.stamp[1]) for s in spheres]
    for k in range(1, len(spheres)):
        if when[k] < when[k - 1]:
            s = spheres[k]
            fmt = "%Y-%m-%d %H:%M:%S" if any(d for _, d, _ in rd.stamps) else "%H:%M:%S"
            rd.error(s.line, f"sphere {s.kind}({s.label}) is timed {when[k]:{fmt}}, before "
                     f"the sphere above it ({when[k - 1]:{fmt}}, row {spheres[k - 1].line}); "
                     "expected the times in measurement order.",
                     hint="check the DATE and TIME lines (a run past midnight needs a DATE "
                     "line for the new day).")
    return np.array([(t - t0) / timedelta(minutes=1) for t in when]), None



def read_dmis(source: FileSource, *, name: str | None = None, pattern: str,
          default_probe: str = "1", default_position: str | None = None) -> ForeignTable:
    """Read the spheres of a DMIS output file into the project's long form.

    Parameters
    ----------
    source : path, bytes or file-like
        The DMIS output file.
    name : str, optional
        File name for messages (default: the path's name).
    pattern : str
        Regular expression a whole sphere label must match, with named groups ``ball``
        and optionally ``position`` and ``probe``, e.g. ``BP(?P<position>\\w+)_(?P<ball>\\d+)``.
    default_probe : str
        Probe of the spheres whose label has no ``probe`` group.
    default_position : str, optional
        Position of the spheres whose label has no ``position`` group (one file per
        placement); without it the pattern must have a ``position`` group.

    Returns
    -------
    ForeignTable
        Long form in mm, with ``time_min`` (minutes from the first DATE/TIME) when every
        sphere has a time, and ``repeat`` when a label is measured again. ``row`` is the
        line of each sphere's statement.

    Raises
    ------
    DataError
        With every problem in ``problems`` (``str(exc)`` one line), each naming the file,
        the line (``row``) and the sphere's label: a value that is not a number, too few
        values, a non-cartesian sphere, an unknown UNITS, an unreadable DATE or TIME, times
        going back, a ball group that is not a number, no sphere, or no label matching the
        pattern; and a bad pattern (naming it).
    """
    rx = _label_regex(pattern, "label pattern", "pattern", position=default_position is None)
    data, name = read_bytes(source, name)
    text, note = _decode(data, name)
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    rd = _read_statements(text, name)
    notes = [note] if note else []
    measured = [s for s in rd.spheres if s.kind == "FA"]
    spheres = measured or rd.spheres
    if measured and len(measured) < len(rd.spheres):
        notes.append(f"{len(rd.spheres) - len(measured)} nominal sphere(s) F(...) ignored: "
                     "the measured FA(...) are read.")
    others = [o for o in rd.others if o[1] == "FA"]
    if others:
        shown = ", ".join(f"{t} FA({lab}) (row {line})" for line, _, t, lab in others[:3])
        notes.append(f"{len(others)} measured feature(s) other than spheres left out: "
                     f"{shown}{', ...' if len(others) > 3 else ''}; a ball is a "
                     "FEAT/SPHERE.")
    if not rd.spheres and not rd.problems:
        raise DataError("has no sphere feature; expected FA(label)=FEAT/SPHERE,CART,x,y,z,d "
                        "statements.", file=name,
                        hint="give the DMIS output (.dmo) of the ball-plate measurement.")
    hits = [rx.fullmatch(s.label) for s in spheres]
    unmatched = [s.label for s, h in zip(spheres, hits, strict=True) if h is None]
    spheres = [s for s, h in zip(spheres, hits, strict=True) if h is not None]
    hits = [h for h in hits if h is not None]
    minutes, time_note = _minutes(rd, spheres)
    if rd.problems:
        rd.problems.sort(key=lambda e: e.row or 0)
        raise DataError.collect(rd.problems)
    if not spheres:
        shown = ", ".join(cut_repr(s, 30) for s in unmatched[:5])
        raise DataError(f"none of the {len(unmatched)} sphere label(s) matches the pattern "
                        f"{pattern}; found {shown}" + (" ..." if len(unmatched) > 5 else "")
                        + ".", file=name,
                        hint="the pattern must match a whole label, e.g. "
                        "BP(?P<position>\\w+)_(?P<ball>\\d+) for BP111_5.")
    labels = [s.label for s in spheres]
    lines = np.array([s.line for s in spheres], int)
    return _sphere_table(
        hits, rx, labels, lines, [s.xyz_mm for s in spheres], minutes, name=name,
        pattern=pattern, notes=notes + _unit_notes(rd) + ([time_note] if time_note else []),
        unmatched=unmatched, prefix=[f"sphere {s.kind}({s.label})" for s in spheres],
        default_position=default_position, default_probe=default_probe)


def _unit_notes(rd: _Reader) -> list:
    notes = []
    if rd.first_unitless is not None:
        notes.append(f"no UNITS line before the first sphere (row {rd.first_unitless}): "
                     "lengths read as mm.")
    for unit in sorted(rd.units_used - {"MM"}):
        notes.append(f"lengths in {unit} converted to mm (× {DMIS_UNITS_MM[unit]:g}).")
    return notes


def read_foreign(source: FileSource, *, name: str | None = None,
             mapping: TableMapping | dict | None = None, pattern: str | None = None,
             default_probe: str = "1", default_position: str | None = None,
             qif_pattern: str | None = None) -> ForeignTable:
    """A QIF document, a DMIS output file or a mapped delimited table, as a ForeignTable.

    Parameters
    ----------
    source : path, bytes or file-like
    name : str, optional
        File name (default: the path's name). A QIF document (:func:`~cmm_core.io.is_qif`:
        an ending in :data:`~cmm_core.io.QIF_SUFFIXES`, or XML content that is a
        ``QIFDocument``) is read by :func:`~cmm_core.io.read_qif` with ``qif_pattern``; an
        ending in :data:`DMIS_SUFFIXES` as DMIS with ``pattern``; any other file through
        ``mapping``.
    mapping : TableMapping or dict, optional
    pattern, default_probe, default_position
        As :func:`read_dmis` (``default_probe`` and ``default_position`` serve QIF too).
    qif_pattern : str, optional
        The label pattern of a QIF document's spheres; default
        :data:`~cmm_core.io.QIF_LABEL_PATTERN`, the ``position/probe/ball`` this program's
        QIF export writes.

    Raises
    ------
    DataError
        From the reader, or when what the file needs (a pattern, a mapping) is not given.
    """
    if name is None and isinstance(source, (str, Path)):
        name = Path(source).name
    shown = name or "uploaded file"
    if is_qif(source, name):
        return read_qif(source, name=name, pattern=qif_pattern or QIF_LABEL_PATTERN,
                        default_probe=default_probe, default_position=default_position)
    if shown.lower().endswith(DMIS_SUFFIXES):
        if pattern is None:
            raise DataError("is a DMIS file; expected a label pattern with named groups "
                            "(position, probe, ball) to read its spheres.", file=shown,
                            hint="give the pattern, e.g. BP(?P<position>\\w+)_(?P<ball>\\d+).")
        return read_dmis(source, name=name, pattern=pattern, default_probe=default_probe,
                         default_position=default_position)
    if mapping is None:
        raise DataError("expected a column mapping to read this table.", file=shown,
                        hint="give a mapping JSON (docs/foreign-formats.md).")
    if not isinstance(mapping, TableMapping):
        mapping = TableMapping.from_dict(mapping)
    return apply_mapping(source, mapping, name=name)

"""QIF 3.0 results documents (ANSI/DMSC QIF 3.0): measured spheres read into the long form.

A QIF document (root ``QIFDocument`` in the namespace :data:`QIF_NS`) reports measured
features in ``Results/MeasurementResultsSet/MeasurementResults/MeasuredFeatures`` (QIF 3.0
Part 6, QIFResults.xsd); this reader takes each ``SphereFeatureMeasurement`` (Part 3,
Features.xsd) and its ``Location``, the measured centre. Its label is its ``FeatureName``,
else the ``FeatureName`` of the ``SphereFeatureItem`` its ``FeatureItemId`` refers to.
Lengths are in the document's ``FileUnits/PrimaryUnits/LinearUnit`` (Part 2, Units.xsd:
a known ``UnitName``, else its ``UnitConversion`` factor to metres), or in the unit a
``Location``'s ``linearUnit`` attribute names; without FileUnits, mm (with a note).
``TimeStamp`` of every sphere gives ``time_min`` (minutes from the first).

As for DMIS (:func:`cmm_core.io.read_dmis`), labels are mapped to position, probe and ball
by a regular expression; the default is the label this program's QIF export writes,
``position/probe/ball`` (:data:`QIF_LABEL_PATTERN`). Every problem is a :class:`DataError`
naming the file, the element (and its line, as ``row``) and what was expected. See
``docs/formats.md`` ("QIF 3.0").
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from .delimited import FileSource, read_bytes
from .errors import DataError, cut_repr
from .table_mapping import (
    ForeignTable,
    _label_regex,
    _sphere_table,
)

QIF_NS = "http://qifstandards.org/xsd/qif3"
"""The QIF 3.0 namespace."""
QIF_LABEL_PATTERN = r"(?P<position>.+)/(?P<probe>[^/]+)/(?P<ball>\d+)"
"""Label of a measured sphere as this program's QIF export writes it,
``position/probe/ball`` (``BP111/1/5``): the default pattern of :func:`read_qif`."""
QIF_UNITS_MM = {"mm": 1.0, "millimeter": 1.0, "millimetre": 1.0, "cm": 10.0,
                "centimeter": 10.0, "centimetre": 10.0, "m": 1000.0, "meter": 1000.0,
                "metre": 1000.0, "um": 0.001, "micrometer": 0.001, "micrometre": 0.001,
                "micron": 0.001, "in": 25.4, "inch": 25.4, "ft": 304.8, "foot": 304.8,
                "feet": 304.8}
"""Length ``UnitName`` values read (case-insensitive) and the size of one unit in mm."""
QIF_SUFFIXES = (".qif",)
"""File name endings read as QIF whatever their content (:func:`is_qif`); an ``.xml`` file
is read as QIF when its content is a QIF document."""
_SNIFF_BYTES = 4096
"""How much of a file's start :func:`is_qif` reads: the root element and its namespace
declaration stand within the first lines of any QIF document."""

_Q = f"{{{QIF_NS}}}"
# the root start tag, any prefix, and the QIF namespace URI declared anywhere in the head
_ROOT = re.compile(rb"<(?:[\w.-]+:)?QIFDocument[\s/>]")
_OPEN = re.compile(rb"<(?:[\w.-]+:)?SphereFeatureMeasurement[\s/>]")
_MEASURED = (f"{_Q}Results/{_Q}MeasurementResultsSet/{_Q}MeasurementResults/"
             f"{_Q}MeasuredFeatures/{_Q}SphereFeatureMeasurement")


def is_qif(source: FileSource, name: str | None = None) -> bool:
    """Whether ``source`` is to be read as a QIF document (:func:`read_qif`).

    Parameters
    ----------
    source : path, bytes or file-like
        The file.
    name : str, optional
        Its name (default: the path's name).

    Returns
    -------
    bool
        True when the name ends in :data:`QIF_SUFFIXES`, or when the first
        4096 bytes (``_SNIFF_BYTES``) of a path or of bytes hold a ``QIFDocument`` start tag
        and the QIF namespace (an ``.xml`` from a CMM's software). A file-like object is
        judged by its name alone, so that sniffing never consumes a stream. Never raises:
        an unreadable file is not QIF here, and its reader says what is wrong with it.
    """
    if name is None and isinstance(source, (str, Path)):
        name = Path(source).name
    if name and name.lower().endswith(QIF_SUFFIXES):
        return True
    if isinstance(source, (bytes, bytearray, memoryview)):
        head = bytes(source[:_SNIFF_BYTES])
    elif isinstance(source, (str, Path)):
        if not Path(source).is_file():  # a pipe would block the open; read_bytes says why
            return False
        try:
            with Path(source).open("rb") as fh:
                head = fh.read(_SNIFF_BYTES)
        except OSError:
            return False
    else:
        return False
    return _ROOT.search(head) is not None and QIF_NS.encode() in head


def _parse(data: bytes, name: str) -> ET.Element:
    # a QIF document has no DTD; refusing one keeps entity expansion out of the parser
    if re.search(rb"<!DOCTYPE", data[:4096]):
        raise DataError("has a DOCTYPE declaration; expected a QIF XML document without one.",
                        file=name, hint="give the QIF document as the software wrote it.")
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise DataError(f"is not well-formed XML ({exc}); expected a QIF 3.0 document.",
                        file=name, hint="give the QIF document (.qif, .xml).") from None
    if root.tag != f"{_Q}QIFDocument":
        raise DataError(f"root element <{_local(root.tag)}>"
                        + (f" in namespace {root.tag[1:].split('}')[0]}" if "}" in root.tag
                           else " without a namespace")
                        + f": expected <QIFDocument> in namespace {QIF_NS}.", file=name,
                        hint="give a QIF 3.0 document (ANSI/DMSC QIF 3.0).")
    return root


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _unit_mm(el: ET.Element, where: str, name: str) -> float:
    """Size in mm of a QIF ``LinearUnit`` element (its UnitName, else UnitConversion)."""
    unit = (el.findtext(f"{_Q}UnitName") or "").strip()
    if unit.lower() in QIF_UNITS_MM:
        return QIF_UNITS_MM[unit.lower()]
    factor = el.findtext(f"{_Q}UnitConversion/{_Q}Factor")
    offset = float(el.findtext(f"{_Q}UnitConversion/{_Q}Offset") or 0)
    try:
        size = float(factor) * 1000.0 if factor is not None and offset == 0 else None
    except ValueError:
        size = None
    if size is None or not (np.isfinite(size) and size > 0):
        raise DataError(f"{where}/UnitName {cut_repr(unit, 30)}: expected a length unit "
                        f"({', '.join(sorted({'mm', 'cm', 'm', 'um', 'inch', 'ft'}))}) or a "
                        "UnitConversion with a Factor to metres and no Offset.", file=name,
                        hint="write <UnitName>mm</UnitName>.")
    return size


def _units(root: ET.Element, name: str) -> tuple[float, dict, list]:
    """(file length unit in mm, {unit name: mm} of the document, notes)."""
    known = dict(QIF_UNITS_MM)
    lin = root.find(f"{_Q}FileUnits/{_Q}PrimaryUnits/{_Q}LinearUnit")
    if lin is None:
        return 1.0, known, ["no FileUnits/PrimaryUnits/LinearUnit: lengths read as mm."]
    size = _unit_mm(lin, "FileUnits/PrimaryUnits/LinearUnit", name)
    known[(lin.findtext(f"{_Q}UnitName") or "").strip().lower()] = size
    for other in root.iterfind(f"{_Q}FileUnits/{_Q}OtherUnits/{_Q}LinearUnit"):
        known[(other.findtext(f"{_Q}UnitName") or "").strip().lower()] = _unit_mm(
            other, "FileUnits/OtherUnits/LinearUnit", name)
    notes = [] if size == 1.0 else [f"lengths in {lin.findtext(f'{_Q}UnitName')} converted "
                                    f"to mm (× {size:g})."]
    return size, known, notes


class _Sphere:
    """One SphereFeatureMeasurement as read."""

    __slots__ = ("label", "line", "xyz_mm", "stamp")

    def __init__(self, label, line, xyz_mm, stamp):
        self.label, self.line, self.xyz_mm, self.stamp = label, line, xyz_mm, stamp


def _lines(data: bytes, n: int) -> list[int]:
    """Line of each SphereFeatureMeasurement's start tag, in document order (for messages
    and the long form's ``row``); ordinals if the text does not show them one to one."""
    starts = [data.count(b"\n", 0, m.start()) + 1 for m in _OPEN.finditer(data)]
    return starts if len(starts) == n else list(range(1, n + 1))


def _sphere(el, line, items, file_mm, units, name, problems) -> _Sphere | None:
    ident = el.get("id", "?")
    where = f"SphereFeatureMeasurement id={ident}"

    def refuse(msg, hint=None):
        problems.append(DataError(f"{where}: {msg}", file=name, row=line, hint=hint))

    label = (el.findtext(f"{_Q}FeatureName") or "").strip()
    if not label:
        ref = (el.findtext(f"{_Q}FeatureItemId") or "").strip()
        label = items.get(ref, "")
        if not label:
            refuse("no FeatureName, nor a FeatureItemId of a SphereFeatureItem with one; "
                   "expected the sphere's label.", hint="name each measured sphere "
                   "(FeatureName), e.g. BP111/1/5.")
            return None
    where += f" ({label})"
    loc = el.find(f"{_Q}Location")
    if loc is None or not (loc.text or "").strip():
        refuse("no Location; expected the measured centre x y z.",
               hint="export the measured (actual) sphere centres.")
        return None
    vals = loc.text.split()
    try:
        xyz = np.array([float(v) for v in vals], float)
    except ValueError:
        xyz = np.array([])
    if xyz.shape != (3,) or not np.isfinite(xyz).all():
        refuse(f"Location {cut_repr(loc.text.strip(), 40)}: expected three numbers x y z.")
        return None
    size = file_mm
    unit = loc.get("linearUnit")
    if unit is not None:
        size = units.get(unit.strip().lower())
        if size is None:
            refuse(f"Location linearUnit {cut_repr(unit, 20)}: expected a length unit of "
                   "the document's FileUnits or one of " + ", ".join(
                       ("mm", "cm", "m", "um", "inch", "ft")) + ".")
            return None
    stamp = el.findtext(f"{_Q}TimeStamp")
    when = None
    if stamp is not None:
        try:
            when = datetime.fromisoformat(stamp.strip())
        except ValueError:
            refuse(f"TimeStamp {cut_repr(stamp, 30)}: expected an xs:dateTime such as "
                   "2026-11-24T14:05:33.")
            return None
        when = when.replace(tzinfo=None) if when.tzinfo is None else when
    return _Sphere(label, line, xyz * size, when)


def _minutes(spheres) -> tuple[np.ndarray | None, str | None]:
    if not spheres or all(s.stamp is None for s in spheres):
        return None, None
    if any(s.stamp is None for s in spheres):
        n = sum(s.stamp is None for s in spheres)
        return None, f"{n} sphere(s) have no TimeStamp: no time column."
    try:
        t0 = spheres[0].stamp
        return np.array([(s.stamp - t0) / timedelta(minutes=1) for s in spheres]), None
    except TypeError:  # time zones on some stamps only: not comparable
        return None, "TimeStamps with and without a time zone: no time column."


def read_qif(source: FileSource, *, name: str | None = None,
             pattern: str = QIF_LABEL_PATTERN, default_probe: str = "1",
             default_position: str | None = None) -> ForeignTable:
    """Read the measured spheres of a QIF 3.0 results document into the long form.

    Implements the reading of QIF 3.0 Part 6 (QIFResults.xsd: ``MeasurementResults``) and
    Part 3 (Features.xsd: ``SphereFeatureMeasurement``, ``SphereFeatureItem``), with the
    file units of Part 2 (Units.xsd).

    Parameters
    ----------
    source : path, bytes or file-like
        The QIF document.
    name : str, optional
        File name for messages (default: the path's name).
    pattern : str
        Regular expression a whole sphere label must match, with named groups ``ball``
        and optionally ``position`` and ``probe``; default :data:`QIF_LABEL_PATTERN`
        (``position/probe/ball``, as this program's export writes).
    default_probe : str
        Probe of the spheres whose label has no ``probe`` group.
    default_position : str, optional
        Position of the spheres whose label has no ``position`` group; without it the
        pattern must have a ``position`` group.

    Returns
    -------
    ForeignTable
        Long form in mm (``time_min`` when every sphere has a TimeStamp); ``row`` is the
        line of each sphere's ``SphereFeatureMeasurement`` element.

    Raises
    ------
    DataError
        With every problem in ``problems``, each naming the file, the element and what was
        expected: not XML or not a ``QIFDocument``, no ``Results`` or no measured sphere,
        a sphere without label or ``Location``, a Location that is not three numbers, an
        unknown length unit, an unreadable TimeStamp, no label matching the pattern.
    """
    rx = _label_regex(pattern, "label pattern", "pattern", position=default_position is None)
    data, name = read_bytes(source, name)
    root = _parse(data, name)
    if root.find(f"{_Q}Results") is None:
        raise DataError("has no <Results>; expected measured spheres in Results/"
                        "MeasurementResultsSet/MeasurementResults/MeasuredFeatures.",
                        file=name, hint="export the measurement results (QIF Results), "
                        "not only the plan or the product.")
    file_mm, units, notes = _units(root, name)
    elements = root.findall(_MEASURED)
    if not elements:
        raise DataError("has no <SphereFeatureMeasurement> in Results/"
                        "MeasurementResultsSet/MeasurementResults/MeasuredFeatures; expected "
                        "the measured ball centres.", file=name,
                        hint="export the ball-plate measurement's sphere features.")
    items = {it.get("id", ""): (it.findtext(f"{_Q}FeatureName") or "").strip()
             for it in root.iter(f"{_Q}SphereFeatureItem")}
    problems: list[DataError] = []
    read = [_sphere(el, line, items, file_mm, units, name, problems)
            for el, line in zip(elements, _lines(data, len(elements)), strict=True)]
    if problems:
        raise DataError.collect(problems)
    spheres = [s for s in read if s is not None]
    hits = [rx.fullmatch(s.label) for s in spheres]
    unmatched = [s.label for s, h in zip(spheres, hits, strict=True) if h is None]
    spheres = [s for s, h in zip(spheres, hits, strict=True) if h is not None]
    hits = [h for h in hits if h is not None]
    if not spheres:
        shown = ", ".join(cut_repr(s, 30) for s in unmatched[:5])
        raise DataError(f"none of the {len(unmatched)} SphereFeatureMeasurement label(s) "
                        f"matches the pattern {pattern}; found {shown}"
                        + (" ..." if len(unmatched) > 5 else "") + ".", file=name,
                        hint="the pattern must match a whole label, e.g. "
                        "(?P<position>.+)/(?P<probe>[^/]+)/(?P<ball>\\d+) for BP111/1/5.")
    minutes, time_note = _minutes(spheres)
    labels = [s.label for s in spheres]
    lines = np.array([s.line for s in spheres], int)
    return _sphere_table(
        hits, rx, labels, lines, [s.xyz_mm for s in spheres], minutes, name=name,
        pattern=pattern, notes=notes + ([time_note] if time_note else []),
        unmatched=unmatched, prefix=[f"SphereFeatureMeasurement ({s.label})" for s in spheres],
        default_position=default_position, default_probe=default_probe)

"""Reader of the files of MSL cmm-error-map (Measurement Standards Laboratory of New Zealand).

MSL writes a measurement as a *snapshot* (ball coordinates in the artefact frame) and a
*metadata* file (machine, probe, model parameters), each behind the same eight header
lines; ``docs/msl-format.md`` describes the format and every convention applied here:

- **kind**: a file does not say whether it is simulated or measured, so the caller says
  (``kind``). MSL's simulated snapshots hold ``nominal + deviation`` where the deviation is
  its kinematic model's true minus indicated position; the reader reverses it (indicated
  = nominal - deviation). Measured snapshots are indications and are taken as they are.
- **origin**: MSL's ``location`` is the ram (scale) position of ball id 0; the ball's tip
  centre, this project's ``origin_mm``, is ``location + probe.length``.
- **angles**: ``rotation/deg`` ``(rx, ry, rz)`` gives ``R = Rz(rz) Ry(ry) Rx(rx)``.
- **balls**: MSL id ``k`` (from 0, row-major, x fastest) is ball ``k + 1``.
- **layout**: ``fixed_table`` and ``bridge_axis`` name one of four of this project's
  layouts (:data:`MSL_LAYOUTS`); MSL evaluates a moving table's functions at the table's
  own position, so odd powers of them change sign (:func:`msl_coefficients`).

Every problem is a :class:`~cmm_core.io.DataError` naming file, row and column; the
cell-level problems of a file are reported together, and the caller's choices in the
caller's words (:class:`MslNames`: keywords here, flags on the command line).

The other way, :func:`msl_parameters` turns this project's coefficients into MSL's
parameters (the conventions above in reverse) and :func:`msl_metadata_text` writes them
in MSL's metadata form, which :func:`read_msl_metadata` reads back.
"""

from __future__ import annotations

import ast
import io as _io
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime

import numpy as np
import pandas as pd
from numpy.polynomial import Chebyshev, Polynomial
from numpy.typing import ArrayLike

from ..machine import LAYOUTS, split_chain
from .dataset import Dataset, load_dataset
from .delimited import FileSource, read_bytes
from .errors import DataError, cut_repr, likely_typo

__all__ = ["ForeignDataset", "ForeignStepGauge", "MslFiles", "read_msl_files",
           "read_msl_plate", "read_msl_bar",
           "read_msl_metadata", "msl_header", "combine_plates", "sniff", "msl_layout",
           "msl_rotation", "msl_coefficients", "msl_parameters", "msl_metadata_text",
           "msl_degree", "rounding_u_um", "MslNames", "MSL_API_NAMES", "MSL_LAYOUTS",
           "MSL_KINDS", "MSL_PARAMETERS", "MSL_HEADER_KEYS", "MSL_ROUNDING_U_UM",
           "MSL_MAX_DEVIATION_MM", "MSL_SQUARENESS_CARRIERS"]

MSL_HEADER_KEYS = ("save time", "title", "name", "artefact.title", "artefact.nballs",
               "artefact.ball_spacing", "location", "rotation/deg")
"""The eight header lines every MSL CSV starts with, in order."""
_SNAPSHOT_COLUMNS = ("id", "mmt_x", "mmt_y", "mmt_z")
_METADATA_KEYS = ("cmm_model.title", "cmm_model.size", "cmm_model.fixed_table",
                 "cmm_model.bridge_axis", "probe.title", "probe.name", "probe.length")
MSL_PARAMETERS = ("Txx", "Txy", "Txz", "Tyx", "Tyy", "Tyz", "Tzx", "Tzy", "Tzz",
                  "Rxx", "Rxy", "Rxz", "Ryx", "Ryy", "Ryz", "Rzx", "Rzy", "Rzz",
                  "Wxy", "Wxz", "Wyz")
"""MSL's 21 parameter names in file order (the W terms are unused by its current model)."""
MSL_LAYOUTS = {(True, 0): "moving_bridge_fyxz", (True, 1): "moving_bridge_fxyz",
               (False, 0): "fixed_bridge_yfxz", (False, 1): "fixed_bridge_xfyz"}
"""``(fixed_table, bridge_axis)`` -> this project's layout. ``bridge_axis`` is the axis whose
carriage runs across the bridge; with a moving table the table moves along the other
horizontal axis."""
MSL_KINDS = ("simulated", "measured")
MSL_ROUNDING_U_UM = 0.01 / math.sqrt(12.0)
"""Standard uncertainty of one coordinate printed to 5 decimals of a mm (0.01 µm steps)."""
MSL_MAX_DEVIATION_MM = 1.0
"""Largest plausible departure of a ball from MSL's nominal grid: more is a wrong pitch,
ball order or unit, not a CMM error."""
MSL_SQUARENESS_CARRIERS = {"sxy": "Tyx", "sxz": "Tzx", "syz": "Tzy"}
"""The MSL straightness whose linear part carries each squareness when this project's
model is written in MSL's form (:func:`msl_parameters`): the three MSL's own validation
parameters use (:func:`msl_coefficients` reads either straightness of a pair)."""
_FOREIGN_COLUMNS = {"id,mmt_x,mmt_y,mmt_z": "snapshot",
                    "id,cmm_nom_x,cmm_nom_y,cmm_nom_z": "full-data",
                    "cmm_model.title": "metadata"}


@dataclass(frozen=True)
class MslNames:
    """How the readers' refusals name the caller's choices.

    The files cannot say what they hold or which certificate the artefact has, so several
    refusals tell the caller what to give; a Python caller gives keywords, a command-line
    user flags. Each attribute is the phrase a message uses (the defaults,
    :data:`MSL_API_NAMES`, are the Python API's).

    Attributes
    ----------
    kind : str
        How to state the kind (both choices).
    measured, simulated : str
        One kind, as the caller states it.
    certificate_u : str
        The certificate statement.
    certificate_example : str
        An example of it.
    metadata : str
        How to give the metadata file.
    machine : str
        What replaces a metadata file (empty: nothing does).
    plate, bar : str
        How to give a plate and a bar snapshot (the other reader of a refused file).
    pairing : str
        How a metadata file is paired with its snapshot.
    files : str
        How to give MSL files at all (a file that is none).
    metadata_flag : str
        The metadata file's keyword or flag alone.
    lead_plate, lead_bar, lead_metadata : str
        What leads a one-problem refusal of a file given as a plate snapshot, a bar
        snapshot or metadata (:func:`read_msl_files`; the command line's flags, empty for
        none).
    """

    kind: str = "kind='simulated' or kind='measured'"
    measured: str = "kind='measured'"
    simulated: str = "kind='simulated'"
    certificate_u: str = "certificate_u"
    certificate_example: str = ('certificate_u={"U_um": [0.26, 0.0019], "k": 2, '
                                '"combine": "quadrature"}')
    metadata: str = "metadata"
    machine: str = "layout, range_mm, probe_mm"
    plate: str = "read it with cmm_core.io.msl.read_msl_plate"
    bar: str = "read it with cmm_core.io.msl.read_msl_bar"
    pairing: str = "expected the metadata saved with it"
    files: str = ("read MSL files with cmm_core.io.msl.read_msl_plate or read_msl_bar "
                  "(snapshot, metadata, kind=...)")
    metadata_flag: str = "metadata"
    lead_plate: str = ""
    lead_bar: str = ""
    lead_metadata: str = ""


MSL_API_NAMES = MslNames()
"""The Python API's words (keywords and functions) in the readers' refusals."""


@dataclass(frozen=True)
class ForeignDataset:
    """A plate measurement read from another tool, in this project's own formats.

    Attributes
    ----------
    measurements_csv : str
        Long-form measurement CSV (``position,probe,ball,x_mm,y_mm,z_mm``; machine-frame
        tip centres, mm).
    setup : dict
        Setup JSON (``docs/formats.md#setup``), including the ``certificate`` statement.
    certificate_csv : str
        Certificate CSV ``ball,x_mm,y_mm,z_mm``: MSL's nominal grid in the plate frame.
    notes : tuple of str
        Each convention applied, in words (kind, origin, angles, balls, layout ...).
    kind : str
        ``"simulated"`` or ``"measured"`` (:data:`MSL_KINDS`).
    name : str
        Snapshot file name(s), for messages and the dataset's label.
    parameters : dict
        MSL's model parameters as the metadata lists them (power-series coefficients,
        lowest power first); informative only (see ``docs/msl-format.md``).
    artefact : str
        The artefact the snapshot measured, as its header names it (``artefact.title``):
        snapshots of different artefacts are not one dataset (:func:`combine_plates`).
    decimals : int
        The most decimals of a mm any coordinate of the snapshot is written with (MSL
        writes 5): the file's resolution, whose rounding is a simulation's only noise
        (:func:`rounding_u_um`).
    placement : tuple
        ``(location, rotation/deg, probe vector)`` as numbers: two snapshots with the same
        are one placement (:func:`combine_plates` refuses it twice).
    """

    measurements_csv: str
    setup: dict
    certificate_csv: str
    notes: tuple
    kind: str
    name: str = "MSL snapshot"
    parameters: dict = field(default_factory=dict)
    artefact: str = ""
    decimals: int = 5
    placement: tuple = ()

    def to_dataset(self, name: str | None = None) -> Dataset:
        """Read the three texts with :func:`cmm_core.io.load_dataset` (every check of a
        user's own files applies); raises its :class:`DataError`."""
        label = name or f"MSL {self.kind}: {self.name}"
        ds = load_dataset([(_io.BytesIO(self.measurements_csv.encode()),
                            f"{self.name} (as measurements.csv)")],
                          self.setup,
                          (_io.BytesIO(self.certificate_csv.encode()),
                           f"{self.name} (nominal grid as certificate.csv)"),
                          name=label)
        return replace(ds, notes=tuple(self.notes))

    def setup_json(self) -> str:
        """The setup as JSON text, to save beside the two CSV texts."""
        return json.dumps(self.setup, indent=1)


@dataclass(frozen=True)
class ForeignStepGauge:
    """A step-gauge (bar) measurement read from another tool, in this project's format.

    Attributes
    ----------
    step_gauge_csv : str
        Step-gauge CSV (``docs/instruments.md``): one length per row from ball 1 to each
        other ball, indicated tip centres in machine axes (mm).
    setup : dict
        The machine (layout, range) and probe of the measurement, in setup JSON form
        (no positions: a step gauge needs no plate).
    notes, kind, name, parameters, decimals
        As :class:`ForeignDataset`.

    Read the text with ``cmm_core.model.read_instrument(io.BytesIO(text.encode()),
    "step_gauge")`` (the model's reader; ``io`` does not import ``model``).
    """

    step_gauge_csv: str
    setup: dict
    notes: tuple
    kind: str
    name: str = "MSL bar snapshot"
    parameters: dict = field(default_factory=dict)
    decimals: int = 5


# --------------------------------------------------------------------------- conventions


def msl_layout(fixed_table: bool, bridge_axis: int) -> str:
    """This project's layout of MSL's ``(cmm_model.fixed_table, cmm_model.bridge_axis)``.

    >>> msl_layout(False, 1)  # MSL's "old PMM866": table in x, y across a fixed bridge
    'fixed_bridge_xfyz'
    """
    try:
        return MSL_LAYOUTS[(bool(fixed_table), int(bridge_axis))]
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"no layout for fixed_table={fixed_table!r}, bridge_axis="
                         f"{bridge_axis!r}; MSL knows bridge_axis 0 (x) or 1 (y).") from None


def msl_rotation(angles_deg: ArrayLike) -> np.ndarray:
    """``R = Rz(rz) Ry(ry) Rx(rx)`` of MSL's ``rotation/deg`` ``(rx, ry, rz)`` in degrees.

    Columns are the artefact's x, y, z axes in machine axes; a plate point ``q`` is at
    ``location + R q`` (ram position). Entries are rounded to 1e-12: MSL writes 90° as
    89.99999999999999.
    """
    rx, ry, rz = np.radians(np.asarray(angles_deg, float))

    def rot(axis, a):  # right-handed rotation by a about machine axis 0, 1 or 2
        c, s = math.cos(a), math.sin(a)
        i, j = (axis + 1) % 3, (axis + 2) % 3
        m = np.eye(3)
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m

    return np.round(rot(2, rz) @ rot(1, ry) @ rot(0, rx), 12) + 0.0


def msl_coefficients(parameters: dict, layout: str, range_mm: Sequence[float] | np.ndarray,
                 order: int | None = None) -> dict:
    """MSL model parameters as this project's kinematic coefficients (labels -> µm, µrad).

    MSL's chain is this project's (``docs/msl-format.md``): its deviation is this project's
    error ``e = x* - (x + p)`` with the same functions on the carriages that carry the
    probe; a moving table's functions are evaluated there at ``-u``, so here a table
    function is ``f(-u)``. Power series (mm, rad; per mm) become Chebyshev series over the
    stroke (µm, µrad). A straightness function's linear part is a squareness here
    (``Tyx`` or ``Txy`` -> ``sxy``, ``Tzx`` or ``Txz`` -> ``sxz``, ``Tzy`` or ``Tyz`` ->
    ``syz``), up to a rotation of each placement, which the fit absorbs.

    Parameters
    ----------
    parameters : dict
        Name (``Txx`` ... ``Rzz``) -> coefficients ``[c0, c1, ...]`` or a bare ``c1``; the
        unused ``W`` terms are ignored.
    layout : str
        This project's layout (:func:`msl_layout`).
    range_mm : sequence of 3 float
        Axis strokes, over which the Chebyshev series are defined.
    order : int, optional
        Order of the labels returned (default: the highest power given, at least 1).

    Raises
    ------
    ValueError
        A constant term (this project's functions are zero at the axis origin).
    """
    table = split_chain(LAYOUTS[layout])[0]
    polys = {}
    for name, c in parameters.items():
        if name[0] == "W" or name not in MSL_PARAMETERS:
            continue
        c = [0.0, float(c)] if not isinstance(c, list | tuple) else [float(v) for v in c]
        if c and c[0] != 0.0:
            raise ValueError(f"{name} has a constant term {c[0]:g}; this project's error "
                             "functions are zero at the axis origin.")
        polys[name] = c
    deg = max([len(c) - 1 for c in polys.values()] + [1])
    order = order or deg
    out = {}
    square = {"sxy": 0.0, "sxz": 0.0, "syz": 0.0}
    pair = {"yx": "sxy", "xy": "sxy", "zx": "sxz", "xz": "sxz", "zy": "syz", "yz": "syz"}
    for name, c in polys.items():
        a, b = name[1].lower(), name[2].lower()
        on_table = a in table
        if on_table:  # MSL evaluates a table function at -u
            c = [v * (-1) ** k for k, v in enumerate(c)]
        scale = 1e3 if name[0] == "T" else 1e6  # mm -> µm, rad -> µrad
        stroke = float(range_mm["xyz".index(a)])
        p = Polynomial(np.asarray(c) * scale)
        cheb = p.convert(kind=Chebyshev, domain=[0.0, stroke]).coef
        cheb = np.pad(cheb, (0, max(0, order + 1 - len(cheb))))
        kind = "d" if name[0] == "T" else "r"
        if kind == "d" and a != b:
            slope = p(stroke) / stroke * 1e3  # chord slope: µm/mm -> µrad
            square[pair[a + b]] += -slope if on_table else slope
            first = 2
        else:
            first = 1
        for j in range(first, order + 1):
            out[f"{kind}{a}{b}[{j}]"] = float(cheb[j])
    out.update(square)
    return out


def msl_parameters(coefficients: dict, layout: str, range_mm: Sequence[float] | np.ndarray
                   ) -> tuple[dict, list]:
    """This project's kinematic coefficients as MSL's model parameters: the inverse of
    :func:`msl_coefficients`.

    Each Chebyshev series over the stroke (µm, µrad) becomes a power series in the axis
    position, lowest power first and zero at the axis origin (mm and mm/mm for T, rad and
    rad/mm for R); a moving table's function changes the sign of its odd powers back
    (MSL evaluates it at the table's own position); each squareness becomes the linear part
    of the straightness :data:`MSL_SQUARENESS_CARRIERS` names. ``msl_coefficients`` of the
    result at the model's order gives ``coefficients`` back.

    Parameters
    ----------
    coefficients : dict
        Label (``dxx[1]``, ``dxy[2]``, ``sxy`` ...) -> value in µm or µrad.
    layout : str
        This project's layout; one of :data:`MSL_LAYOUTS` (MSL knows no other).
    range_mm : sequence of 3 float
        Axis strokes over which the Chebyshev series are defined.

    Returns
    -------
    parameters : dict
        Every name of :data:`MSL_PARAMETERS` -> coefficients ``[0.0, c1, ...]``, at least
        two (the W terms and every function the model lacks are zero).
    left_out : list of str
        Labels MSL's parameters cannot hold (periodic terms, anything not a kinematic
        function of the 21 errors).

    Raises
    ------
    ValueError
        A layout MSL does not know.
    """
    if layout not in MSL_LAYOUTS.values():
        raise ValueError(f"MSL's model knows the layouts {', '.join(MSL_LAYOUTS.values())}; "
                         f"this model's is {layout}.")
    table = split_chain(LAYOUTS[layout])[0]
    carriers = {v: k for k, v in MSL_SQUARENESS_CARRIERS.items()}
    series: dict[str, dict[int, float]] = {}
    square, left_out = {}, []
    for label, value in coefficients.items():
        if label in MSL_SQUARENESS_CARRIERS:
            square[label] = float(value)
            continue
        name, _, rest = label.partition("[")
        if (len(name) != 3 or name[0] not in "dr" or name[1] not in "xyz"
                or name[2] not in "xyz" or not rest[:-1].isdigit()):
            left_out.append(label)
            continue
        series.setdefault(name, {})[int(rest[:-1])] = float(value)
    out = {p: [0.0, 0.0] for p in MSL_PARAMETERS}
    for p in MSL_PARAMETERS[:18]:
        a, b = p[1].lower(), p[2].lower()
        name = ("d" if p[0] == "T" else "r") + a + b
        given = series.get(name, {})
        on_table = a in table
        stroke = float(range_mm["xyz".index(a)])
        deg = max([1, *given])
        cheb = np.zeros(deg + 1)
        for j, v in given.items():
            cheb[j] = v
        if p[0] == "T" and a != b:
            # straightness: T_j minus its chord (zero at both ends); the chord through
            # T_j(-1) = (-1)^j and T_j(1) = 1 is a T0 + T1 part
            lo, hi = sum(cheb[j] * (-1) ** j for j in range(2, deg + 1)), cheb[2:].sum()
            cheb[0], cheb[1] = -(lo + hi) / 2, -(hi - lo) / 2
        else:  # positioning, rotation: T_j - T_j(-1), zero at the axis origin
            cheb[0] = -sum(cheb[j] * (-1) ** j for j in range(1, deg + 1))
        coef = Chebyshev(cheb, domain=[0.0, stroke]).convert(kind=Polynomial).coef
        poly = np.zeros(deg + 1)
        poly[:len(coef)] = np.real(coef)
        if p in carriers:  # the squareness as the chord slope (µrad -> µm/mm)
            sq = square.get(carriers[p], 0.0) * 1e-3
            poly[1] += -sq if on_table else sq
        if on_table:  # back to MSL's evaluation at the table's own position
            poly = poly * (-1.0) ** np.arange(poly.size)
        poly[0] = 0.0  # zero at the origin by construction; no rounding residue
        scale = 1e-3 if p[0] == "T" else 1e-6  # µm -> mm, µrad -> rad
        out[p] = [float(v) * scale + 0.0 for v in poly]
    return out, left_out


def msl_degree(parameters: dict) -> int | None:
    """The polynomial degree of MSL's model as a metadata file lists it: the longest
    coefficient list of the 18 used parameters, less one (MSL's own files: 1, linear);
    None when the file lists no parameters."""
    lists = [len(c) - 1 for p, c in parameters.items() if p in MSL_PARAMETERS[:18]]
    return max(max(lists), 1) if lists else None


def rounding_u_um(decimals: int) -> float:
    """Standard uncertainty (µm) of a coordinate rounded to ``decimals`` decimals of a mm:
    the step over √12 (5 decimals: :data:`MSL_ROUNDING_U_UM`)."""
    return 1e3 * 10.0 ** -int(decimals) / math.sqrt(12.0)


# --------------------------------------------------------------------------- writing


def msl_metadata_text(parameters: dict, layout: str, range_mm: Sequence[float] | np.ndarray,
                      *, probe_name: str = "ram",
                      probe_mm: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
                      title: str = "cmm-error-lab fitted machine", name: str = "fit",
                      machine: str = "cmm-error-lab fitted machine", save_time: str = "",
                      digits: int = 10) -> str:
    """A machine in MSL's metadata form, as :func:`read_msl_metadata` (and
    :func:`read_msl_plate`) read it.

    The eight header lines (``artefact.*``, ``location`` and ``rotation/deg`` say no
    artefact: one ball, at the origin, unrotated), the machine and probe lines, ``model
    parameters`` and the 21 parameters, each a Python list as MSL writes it. Nothing else:
    the readers take the first line to be ``save time``, so no comment or provenance line
    can precede it, and every line after ``model parameters`` to be a parameter.

    Parameters
    ----------
    parameters : dict
        MSL parameter name -> coefficients (:func:`msl_parameters`).
    layout : str
        One of :data:`MSL_LAYOUTS`' layouts (written as its two flags).
    range_mm : sequence of 3 float
        The strokes (``cmm_model.size``).
    probe_name, probe_mm : optional
        The probe (``probe.name``, ``probe.length``), default the ram reference point.
    title, name, save_time : str, optional
        The header's ``title``, ``name`` (commas become spaces: MSL's lines are CSV) and
        ``save time`` (default now, in MSL's form: ``datetime.isoformat(sep=" ")``).
    machine : str, optional
        ``cmm_model.title``: the machine's name, where MSL writes its machine type's
        (``PMM866``); the provenance belongs in ``title``.
    digits : int, optional
        Significant digits of each coefficient.

    Raises
    ------
    ValueError
        A layout MSL does not know.
    """
    flags = {v: k for k, v in MSL_LAYOUTS.items()}
    if layout not in flags:
        raise ValueError(f"MSL's model knows the layouts {', '.join(flags)}; this model's "
                         f"is {layout}.")
    fixed, bridge = flags[layout]

    def clean(text):  # one CSV cell: MSL's reader splits each line on commas
        return " ".join(str(text).replace(",", " ").split())

    def num(v):
        return repr(float(f"{float(v):.{digits}g}") + 0.0)

    when = save_time or _now()
    lines = [f"save time,{when}", f"title,{clean(title)}", f"name,{clean(name)}",
             "artefact.title,none (a fitted machine)", "artefact.nballs,1,1",
             "artefact.ball_spacing,1.0", "location,0.0, 0.0, 0.0",
             "rotation/deg,0.0, 0.0, 0.0", f"cmm_model.title,{clean(machine)}",
             "cmm_model.size," + ",".join(num(v) for v in range_mm),
             f"cmm_model.fixed_table,{fixed}", f"cmm_model.bridge_axis,{bridge}",
             "probe.title,stylus", f"probe.name,{clean(probe_name) or 'ram'}",
             "probe.length," + ",".join(num(v) for v in probe_mm), "model parameters"]
    for p in MSL_PARAMETERS:
        c = parameters.get(p, [0.0, 0.0])
        lines.append(f"{p},[{', '.join(num(v) for v in c)}]")
    return "\n".join(lines) + "\n"


def _now():
    # MSL's own form of the save time (its app writes datetime.isoformat(sep=" ")), always
    # to the microsecond
    return datetime.now().strftime("%Y-%m-%d %H:%M:%S.%f")


# --------------------------------------------------------------------------- parsing


@dataclass(frozen=True)
class _Header:
    name: str
    rows: dict  # key -> (row, raw text)
    nballs: tuple
    pitch_mm: float
    location_mm: np.ndarray
    angles_deg: np.ndarray


def _lines(source, name, what):
    data, name = read_bytes(source, name)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DataError("is not UTF-8 text; expected an MSL cmm-error-map CSV.",
                        file=name) from None
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise DataError(f"file is empty; expected an MSL {what} file.", file=name)
    return lines, name


def _numbers(text, n, name, row, column, what, integer=False):
    parts = [t.strip() for t in text.split(",")]
    try:
        vals = [float(t) for t in parts]
    except ValueError:
        vals = None
    if vals is None or len(vals) != n or not all(map(math.isfinite, vals)) or (
            integer and not all(v.is_integer() for v in vals)):
        raise DataError(f"expected {what}, found {cut_repr(text)}.", file=name, row=row,
                        column=column)
    return np.array(vals)


def _header(lines, name, what, use) -> _Header:
    """The eight header lines, checked key by key (row = line number)."""
    rows = {}
    for i, key in enumerate(MSL_HEADER_KEYS):
        row = i + 1
        if i >= len(lines):
            raise DataError(f"ends after {len(lines)} lines; expected the {len(MSL_HEADER_KEYS)} "
                            f"header lines of an MSL {what} file.", file=name, row=row,
                            column=key)
        got, _, rest = lines[i].partition(",")
        if got.strip() != key:
            raise DataError(f"expected the header key {key!r}, found {cut_repr(got)}; this "
                            f"is not an MSL cmm-error-map {what} file.", file=name, row=row,
                            column=key, hint=use)
        rows[key] = (row, rest)
    nb = _numbers(rows["artefact.nballs"][1], 2, name, 5, "artefact.nballs",
                  "two whole numbers of balls (nx, ny)", integer=True)
    if (nb < 1).any():
        raise DataError(f"expected at least one ball in x and y, found {nb.astype(int).tolist()}.",
                        file=name, row=5, column="artefact.nballs")
    pitch = _numbers(rows["artefact.ball_spacing"][1], 1, name, 6, "artefact.ball_spacing",
                     "one ball spacing in mm")[0]
    if not 1.0 <= pitch <= 5000.0:
        raise DataError(f"ball spacing {pitch:g} is not a spacing in mm (1 to 5000).",
                        file=name, row=6, column="artefact.ball_spacing")
    loc = _numbers(rows["location"][1], 3, name, 7, "location", "x, y, z in mm")
    ang = _numbers(rows["rotation/deg"][1], 3, name, 8, "rotation/deg",
                   "three angles rx, ry, rz in degrees")
    if (np.abs(ang) > 360).any():
        raise DataError(f"angles {ang.tolist()} are beyond ±360°; expected degrees.",
                        file=name, row=8, column="rotation/deg")
    return _Header(name, rows, tuple(int(v) for v in nb), float(pitch), loc, ang)


def _snapshot(source, name, use):
    """Header and ball coordinates (artefact frame, mm) of a snapshot file."""
    lines, name = _lines(source, name, "snapshot")
    head = _header(lines, name, "snapshot", use)
    row = len(MSL_HEADER_KEYS) + 1
    cols = lines[row - 1].strip().rstrip(",") if len(lines) >= row else ""
    if cols != ",".join(_SNAPSHOT_COLUMNS):
        other = next((k for c, k in _FOREIGN_COLUMNS.items() if cols.startswith(c)), None)
        raise DataError(
            (f"this is an MSL {other} file, not a snapshot" if other else
             f"expected the columns {','.join(_SNAPSHOT_COLUMNS)}, found {cut_repr(cols)}")
            + ".", file=name, row=row, column="id",
            hint="give the snapshot.csv saved with it (and its metadata.csv).")
    nx, ny = head.nballs
    data = lines[row:]
    problems = []
    xyz = np.full((len(data), 3), np.nan)
    decimals = 0
    for k, line in enumerate(data):
        r = row + 1 + k
        cells = [c.strip() for c in line.split(",")]
        if cells and cells[-1] == "" and len(cells) == 5:
            cells = cells[:4]
        if len(cells) != 4:
            problems.append(DataError(f"expected 4 fields ({','.join(_SNAPSHOT_COLUMNS)}), "
                                      f"found {len(cells)}.", file=name, row=r))
            continue
        if cells[0] != str(k):
            problems.append(DataError(f"expected id {k} (MSL numbers the balls from 0 in "
                                      f"row order), found {cut_repr(cells[0])}.", file=name,
                                      row=r, column="id"))
        for j, c in enumerate(cells[1:]):
            try:
                v = float(c)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                problems.append(DataError(f"expected a number (mm), found {cut_repr(c)}.",
                                          file=name, row=r, column=_SNAPSHOT_COLUMNS[j + 1]))
            xyz[k, j] = v
            # the file's resolution: a simulation's only noise is its rounding
            decimals = max(decimals, _decimals(c))
    if problems:
        raise DataError.collect(problems)
    if len(data) != nx * ny:
        raise DataError(f"has {len(data)} ball rows; the header says {nx} × {ny} = {nx * ny}.",
                        file=name, row=row + min(len(data), nx * ny) + (len(data) > nx * ny),
                        column="id", hint="the file is cut short or belongs to another "
                        "artefact: check artefact.nballs.")
    dev = xyz - _grid(nx, ny, head.pitch_mm)
    far = np.argwhere(np.abs(dev) > MSL_MAX_DEVIATION_MM)
    if far.size:
        problems = [DataError(f"ball id {k} lies {dev[k, j]:+.4g} mm from its nominal "
                              f"{_grid(nx, ny, head.pitch_mm)[k, j]:g} mm; expected "
                              "micrometres.", file=name, row=row + 1 + int(k),
                              column=_SNAPSHOT_COLUMNS[j + 1],
                              hint="check the ball order, artefact.ball_spacing and units "
                                   "(mm).") for k, j in far]
        raise DataError.collect(problems)
    return head, xyz, decimals


def _decimals(cell):
    """Decimals of a mm a coordinate is written with (``1.5e-05``: 5 + 1)."""
    mant, _, exp = cell.lower().partition("e")
    digits = len(mant.partition(".")[2])
    try:
        return max(0, digits - int(exp or 0))
    except ValueError:
        return digits


def _grid(nx, ny, pitch):
    """MSL's nominal grid: id k at (k mod nx, k div nx, 0) × pitch."""
    k = np.arange(nx * ny)
    return np.column_stack([(k % nx) * pitch, (k // nx) * pitch, np.zeros(k.size)])


def _metadata(source, name, head: _Header | None, use, names: MslNames = MSL_API_NAMES):
    """Machine, probe and model parameters of a metadata file, checked against the
    snapshot's header (``head``; None: a metadata file alone)."""
    lines, name = _lines(source, name, "metadata")
    meta = _header(lines, name, "metadata", use)
    for key in MSL_HEADER_KEYS[2:]:
        if head is None:  # a metadata file alone: no snapshot to repeat
            break
        a, b = meta.rows[key][1].strip(), head.rows[key][1].strip()
        if a != b:
            raise DataError(f"{key} {cut_repr(a)} differs from the snapshot's {cut_repr(b)} "
                            f"({head.name}); {names.pairing}.", file=name,
                            row=meta.rows[key][0], column=key)
    vals, rows = {}, {}
    i = len(MSL_HEADER_KEYS)
    while i < len(lines) and lines[i].strip() != "model parameters":
        key, _, rest = lines[i].partition(",")
        key = key.strip()
        if key not in _METADATA_KEYS:
            guess = likely_typo(key, _METADATA_KEYS)
            if lines[i].startswith("id,"):
                raise DataError("this is an MSL snapshot or full-data file, not metadata.",
                                file=name, row=i + 1, hint="give the metadata.csv saved "
                                "with the snapshot.")
            raise DataError(f"unknown metadata key {cut_repr(key)}"
                            + (f"; did you mean {guess!r}?" if guess else
                               f"; expected {', '.join(_METADATA_KEYS)}."),
                            file=name, row=i + 1, column=key)
        vals[key], rows[key] = rest, i + 1
        i += 1
    missing = [k for k in _METADATA_KEYS if k not in vals]
    if missing:
        raise DataError(f"has no {', '.join(missing)}; expected every machine and probe "
                        "line of an MSL metadata file.", file=name, column=missing[0])
    size = _numbers(vals["cmm_model.size"], 3, name, rows["cmm_model.size"],
                    "cmm_model.size", "three strokes x, y, z in mm")
    flag = vals["cmm_model.fixed_table"].strip()
    if flag not in ("True", "False"):
        raise DataError(f"expected True or False, found {cut_repr(flag)}.", file=name,
                        row=rows["cmm_model.fixed_table"], column="cmm_model.fixed_table")
    axis = vals["cmm_model.bridge_axis"].strip()
    if axis not in ("0", "1"):
        raise DataError(f"expected 0 (x) or 1 (y), found {cut_repr(axis)}.", file=name,
                        row=rows["cmm_model.bridge_axis"], column="cmm_model.bridge_axis")
    probe = _numbers(vals["probe.length"], 3, name, rows["probe.length"], "probe.length",
                     "the probe vector x, y, z in mm")
    params = _parameters(lines, i + 1, name)
    return {"title": vals["cmm_model.title"].strip(), "size_mm": size,
            "fixed_table": flag == "True", "bridge_axis": int(axis),
            "probe_name": vals["probe.name"].strip() or "msl", "probe_mm": probe,
            "parameters": params}


def _parameters(lines, start, name):
    params, problems = {}, []
    for k in range(start, len(lines)):
        key, _, rest = lines[k].partition(",")
        key = key.strip()
        if not key and not rest.strip():
            continue
        if key not in MSL_PARAMETERS:
            problems.append(DataError(f"unknown model parameter {cut_repr(key)}; expected "
                                      f"one of {', '.join(MSL_PARAMETERS)}.", file=name,
                                      row=k + 1, column=key))
            continue
        try:
            v = ast.literal_eval(rest.strip())
            v = [float(x) for x in v] if isinstance(v, list | tuple) else [0.0, float(v)]
        except (ValueError, SyntaxError, TypeError):
            v = None
        if v is None or not all(map(math.isfinite, v)):
            problems.append(DataError(f"expected a list of polynomial coefficients, found "
                                      f"{cut_repr(rest)}.", file=name, row=k + 1, column=key))
            continue
        params[key] = v
    if problems:
        raise DataError.collect(problems)
    missing = [p for p in MSL_PARAMETERS if p not in params]
    if start <= len(lines) and missing:
        raise DataError(f"lists no {', '.join(missing)}; expected all 21 model parameters.",
                        file=name, column=missing[0])
    return params


def _kind(kind, certificate_u, name, names: MslNames = MSL_API_NAMES):
    if kind is None:
        raise DataError("an MSL file does not say whether it is simulated or measured; "
                        f"give {names.kind}.", file=name,
                        hint="simulated files hold nominal + (true - indicated): the reader "
                             "must know which to apply the sign.")
    if kind not in MSL_KINDS:
        raise DataError(f"the kind must be 'simulated' or 'measured', found "
                        f"{cut_repr(kind)}; give {names.kind}.", file=name)
    if kind == "simulated":
        if certificate_u is not None:
            raise DataError(f"a simulated file's nominal grid is exact; {names.certificate_u} "
                            f"is for {names.measured}.", file=name)
        return {"exact": True, "source": "MSL simulation: the nominal grid is exact"}
    if certificate_u is None:
        raise DataError(f"{names.measured} needs {names.certificate_u}, the artefact "
                        "certificate's uncertainty; the MSL file does not state it.", file=name,
                        hint=f"e.g. {names.certificate_example} (U = sqrt(a² + (b·L)²), L mm "
                             "from ball 1).")
    if not isinstance(certificate_u, dict) or "U_um" not in certificate_u or set(
            certificate_u) - {"U_um", "k", "combine", "source"}:
        raise DataError(f"{names.certificate_u} must be {{'U_um': [a_um, b_um_per_mm], "
                        f"'k': 2, 'combine': 'quadrature'}}, found {cut_repr(certificate_u)}.",
                        file=name)
    ab = certificate_u["U_um"]
    if not (isinstance(ab, list | tuple) and len(ab) == 2 and all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            and v >= 0 for v in ab)):
        raise DataError(f"{names.certificate_u}: U_um must be [a_um, b_um_per_mm], two "
                        f"numbers >= 0, found {cut_repr(ab)}.", file=name)
    out = {"U_um": [float(ab[0]), float(ab[1])], "k": certificate_u.get("k", 2),
           "combine": certificate_u.get("combine", "quadrature")}
    if "source" in certificate_u:
        out["source"] = str(certificate_u["source"])
    return out


def _use(what, names: MslNames = MSL_API_NAMES):
    if names is MSL_API_NAMES:
        return (f"read an MSL {what} with cmm_core.io.msl.read_msl_"
                f"{'bar' if what == 'bar' else 'plate'}(snapshot, metadata, kind=...)")
    return f"an MSL {what} snapshot: {names.bar if what == 'bar' else names.plate}"


def _machine(meta, head, layout, range_mm, probe_mm, name, names: MslNames = MSL_API_NAMES):
    """Layout, strokes, probe vector and name, from the metadata or the caller."""
    if meta is not None:
        lay = msl_layout(meta["fixed_table"], meta["bridge_axis"])
        note = (f"layout: MSL fixed_table={meta['fixed_table']}, bridge_axis="
                f"{meta['bridge_axis']} ({'moving bridge' if meta['fixed_table'] else 'fixed bridge, moving table'}, "
                f"{'xy'[meta['bridge_axis']]} across the bridge) is {lay}; MSL evaluates a "
                "moving table's functions at the table's own position (-u), so odd powers "
                "of them change sign between the two (msl_coefficients).")
        return lay, meta["size_mm"], meta["probe_mm"], meta["probe_name"], note
    missing = [k for k, v in (("layout", layout), ("range_mm", range_mm),
                              ("probe_mm", probe_mm)) if v is None]
    if missing:
        raise DataError("without the metadata file the machine is unknown; give "
                        + (f"{names.metadata} or {', '.join(missing)}." if names.machine else
                           f"{names.metadata}."), file=head.name,
                        hint="the metadata.csv saved with the snapshot holds the layout "
                             "flags, the machine size and the probe vector.")
    return (layout, np.asarray(range_mm, float), np.asarray(probe_mm, float), "msl",
            f"layout: {layout}, as the caller gave it (no metadata file).")


def _common_notes(head, kind, probe, decimals=5):
    nx, ny = head.nballs
    r = msl_rotation(head.angles_deg)
    dev = ("simulated: the snapshot holds nominal + deviation, and MSL's deviation is its "
           "kinematic model's true minus indicated position; the reader reverses it "
           "(indicated = nominal - deviation), so a fit gives MSL's parameters with their "
           "sign" if kind == "simulated" else
           "measured: the snapshot's coordinates are the CMM's indications, taken as they "
           "are")
    return [
        f"kind: {dev}.",
        f"origin: ball 1's tip centre is location + probe.length = "
        f"{_fmt(head.location_mm)} + {_fmt(probe)} = {_fmt(head.location_mm + probe)} mm "
        "(MSL's location is the ram position of ball id 0, without the probe).",
        f"angles: rotation/deg (rx, ry, rz) = {_fmt(head.angles_deg)}° applied as R = "
        f"Rz(rz)·Ry(ry)·Rx(rx) (about the fixed x axis first): artefact x = {_fmt(r[:, 0])}, "
        f"y = {_fmt(r[:, 1])} in machine axes.",
        f"balls: MSL id k (from 0, row-major, x fastest, {nx} per row) is ball k + 1 at "
        f"nominal ((k mod {nx})·{head.pitch_mm:g}, (k div {nx})·{head.pitch_mm:g}, 0) mm.",
        "frame: the snapshot's artefact-frame coordinates (MSL re-aligns them on ids 0, "
        f"{nx - 1}{'' if ny == 1 else f' and {nx * (ny - 1)}'}) are placed in machine axes by "
        "the nominal placement; a fit's placement absorbs the re-alignment.",
        f"units: mm as in the file; its {decimals} decimals are steps of "
        f"{1e3 * 10.0 ** -decimals:g} µm.",
    ]


def _fmt(v):
    return "(" + ", ".join(f"{x:.6g}" for x in np.asarray(v, float) + 0.0) + ")"


def _parameter_notes(params, kind):
    if not params:
        return []
    used = [p for p in MSL_PARAMETERS[:18] if any(params.get(p, [0.0]))]
    if not used:
        return ["parameters: the metadata lists all model parameters as zero (MSL's plate "
                "validation metadata does so although its data were generated with "
                "non-zero parameters: do not take them as the truth)."]
    return [f"parameters: the metadata lists {', '.join(used)} as non-zero"
            + (" (the generating parameters of a simulation)." if kind == "simulated"
               else ".")]


# --------------------------------------------------------------------------- readers


def read_msl_plate(snapshot: FileSource, metadata: FileSource | None = None, *,
               kind: str | None = None, certificate_u: dict | None = None,
               position: str | None = None, layout: str | None = None,
               range_mm: ArrayLike | None = None, probe_mm: ArrayLike | None = None,
               snapshot_name: str | None = None, metadata_name: str | None = None,
               names: MslNames = MSL_API_NAMES) -> ForeignDataset:
    """Read an MSL cmm-error-map plate snapshot (and its metadata) as this project's files.

    Parameters
    ----------
    snapshot, metadata : path, bytes or file-like
        MSL's ``snapshot.csv`` and the ``metadata.csv`` saved with it.
    kind : {"simulated", "measured"}
        Required: the files do not say. Simulated snapshots hold nominal + (true -
        indicated); the reader reverses the deviation (module docstring).
    certificate_u : dict, required for kind="measured"
        The artefact certificate's uncertainty, ``{"U_um": [a_um, b_um_per_mm], "k": 2,
        "combine": "quadrature"}`` (the setup's ``certificate`` statement).
    position : str, optional
        Position name (default MSL's ``name``).
    layout, range_mm, probe_mm : optional
        The machine, when no metadata file is given (all three then required).
    snapshot_name, metadata_name : str, optional
        File names for messages (default the path's name).
    names : MslNames, optional
        How refusals name the caller's choices (default the keywords above; the command
        line gives its flags).

    Returns
    -------
    ForeignDataset

    Raises
    ------
    DataError
        Naming file, row and column: a missing kind, an unreadable or inconsistent file, a
        bar file (read it with :func:`read_msl_bar`).
    """
    use = _use("plate", names)
    head, xyz, decimals = _snapshot(snapshot, snapshot_name, use)
    certificate = _kind(kind, certificate_u, head.name, names)
    assert kind is not None  # _kind refused a missing kind
    nx, ny = head.nballs
    if ny < 2 or nx < 2:
        raise DataError(f"has {nx} × {ny} balls: a bar or step gauge, not a plate.",
                        file=head.name, row=5, column="artefact.nballs",
                        hint=f"{names.bar}.")
    meta = None if metadata is None else _metadata(metadata, metadata_name, head, use, names)
    lay, rng, probe, pname, lay_note = _machine(meta, head, layout, range_mm, probe_mm,
                                                head.name, names)
    pos = position or head.rows["name"][1].strip() or "msl"
    nominal = _grid(nx, ny, head.pitch_mm)
    plate = 2.0 * nominal - xyz if kind == "simulated" else xyz
    R = msl_rotation(head.angles_deg)
    origin = head.location_mm + probe
    tips = origin + plate @ R.T
    meas = pd.DataFrame({"position": pos, "probe": pname, "ball": np.arange(1, nx * ny + 1),
                         "x_mm": tips[:, 0], "y_mm": tips[:, 1], "z_mm": tips[:, 2]})
    cert = pd.DataFrame({"ball": np.arange(1, nx * ny + 1), "x_mm": nominal[:, 0],
                         "y_mm": nominal[:, 1], "z_mm": nominal[:, 2]})
    setup = {"units": "mm", "frame": "machine",
             "machine": {"layout": lay, "range_mm": [float(v) for v in rng]},
             "positions": {pos: {"origin_mm": [float(v) for v in origin],
                                 "u_axis": [float(v) for v in R[:, 0]],
                                 "v_axis": [float(v) for v in R[:, 1]], "probe": pname}},
             "probes": {pname: [float(v) for v in probe]},
             "certificate": certificate}
    notes = _common_notes(head, kind, probe, decimals) + [lay_note]
    notes.append("certificate: MSL's nominal grid, "
                 + ("exact (a noise-free simulation): setup certificate.exact = true."
                    if kind == "simulated" else
                    f"with the uncertainty the caller stated: U_um = {certificate['U_um']}, "
                    f"k = {certificate['k']}, {certificate['combine']}."))
    params = meta["parameters"] if meta else {}
    notes += _parameter_notes(params, kind)
    return ForeignDataset(meas.to_csv(index=False, float_format="%.7f"), setup,
                          cert.to_csv(index=False, float_format="%.6f"), tuple(notes), kind,
                          head.name, params,
                          head.rows["artefact.title"][1].strip(), decimals,
                          (tuple(head.location_mm), tuple(head.angles_deg), tuple(probe)))


def read_msl_bar(snapshot: FileSource, metadata: FileSource | None = None, *,
             kind: str | None = None, certificate_u: dict | None = None,
             layout: str | None = None, range_mm: ArrayLike | None = None,
             probe_mm: ArrayLike | None = None, snapshot_name: str | None = None,
             metadata_name: str | None = None,
             names: MslNames = MSL_API_NAMES) -> ForeignStepGauge:
    """Read an MSL cmm-error-map bar (step gauge) snapshot as this project's step-gauge file.

    One length per row, from ball 1 (MSL id 0) to each other ball: the indicated tip
    centres in machine axes (location + probe + R·q), the indicated length between them
    and the nominal length ``k · ball_spacing`` as the certified one. A step gauge needs no
    plate. ``u_um`` is the file's rounding (:data:`MSL_ROUNDING_U_UM`) for a simulation, and the
    certificate's ``U(L) / k`` (``certificate_u``) for a measurement.

    Parameters and errors as :func:`read_msl_plate`; a plate file is refused (read it with
    :func:`read_msl_plate`).
    """
    use = _use("bar", names)
    head, xyz, decimals = _snapshot(snapshot, snapshot_name, use)
    certificate = _kind(kind, certificate_u, head.name, names)
    assert kind is not None  # _kind refused a missing kind
    nx, ny = head.nballs
    if ny != 1 or nx < 2:
        raise DataError(f"has {nx} × {ny} balls: a plate, not a bar or step gauge.",
                        file=head.name, row=5, column="artefact.nballs",
                        hint=f"{names.plate}.")
    meta = None if metadata is None else _metadata(metadata, metadata_name, head, use, names)
    lay, rng, probe, pname, lay_note = _machine(meta, head, layout, range_mm, probe_mm,
                                                head.name, names)
    nominal = _grid(nx, 1, head.pitch_mm)
    bar = 2.0 * nominal - xyz if kind == "simulated" else xyz
    R = msl_rotation(head.angles_deg)
    tips = head.location_mm + probe + bar @ R.T
    length = np.arange(1, nx) * head.pitch_mm
    if kind == "simulated":
        u = np.full(nx - 1, rounding_u_um(decimals))
        u_note = (f"u_um: {rounding_u_um(decimals):.4g} µm, the rounding of the file's "
                  f"{decimals} decimals (the nominal lengths of a simulation are exact).")
    else:
        a, b = certificate["U_um"]
        big = (np.hypot(a, b * length) if certificate["combine"] == "quadrature"
               else a + b * length)
        u = big / float(certificate["k"])
        u_note = ("u_um: the certificate's U(L)/k as the caller stated it; add the "
                  "probing repeatability if it matters.")
    label = head.rows["name"][1].strip() or "bar"
    sg = pd.DataFrame({"gauge": [f"{label} 1-{k + 1}" for k in range(1, nx)]})
    for a, axis in enumerate("xyz"):
        sg[f"{axis}1_mm"] = tips[0, a]
    for a, axis in enumerate("xyz"):
        sg[f"{axis}2_mm"] = tips[1:, a]
    sg["measured_mm"] = np.linalg.norm(tips[1:] - tips[0], axis=1)
    sg["certified_mm"], sg["u_um"] = length, u
    if np.any(probe):
        for a, axis in enumerate("xyz"):
            sg[f"offset_{axis}_mm"] = probe[a]
    notes = [n for n in _common_notes(head, kind, probe, decimals) if not n.startswith("frame")]
    notes += [lay_note, u_note,
              f"lengths: from ball 1 to balls 2-{nx}, certified = k·{head.pitch_mm:g} mm "
              "(MSL's nominal); measured = the distance of the indicated tip centres.",
              "plate: a step gauge needs no plate; fit it with the plate data of the same "
              "machine (cmm_core fit --step-gauge)."]
    params = meta["parameters"] if meta else {}
    notes += _parameter_notes(params, kind)
    setup = {"units": "mm", "machine": {"layout": lay, "range_mm": [float(v) for v in rng]},
             "probes": {pname: [float(v) for v in probe]}}
    return ForeignStepGauge(sg.to_csv(index=False, float_format="%.7f"), setup, tuple(notes),
                            kind, head.name, params, decimals)


def read_msl_metadata(source: FileSource, name: str | None = None) -> dict:
    """An MSL metadata file on its own: the machine, probe and model parameters.

    What :func:`msl_metadata_text` writes, and any metadata file MSL saves; its header is
    checked as a snapshot's (but against no snapshot).

    Returns
    -------
    dict
        ``title``, ``layout`` (:func:`msl_layout`), ``range_mm``, ``probe_name``,
        ``probe_mm`` and ``parameters`` (name -> power-series coefficients, lowest power
        first, as listed).

    Raises
    ------
    DataError
        Naming file, row and column.
    """
    meta = _metadata(source, name, None, _use("plate"))
    return {"title": meta["title"], "layout": msl_layout(meta["fixed_table"],
                                                         meta["bridge_axis"]),
            "range_mm": [float(v) for v in meta["size_mm"]], "probe_name": meta["probe_name"],
            "probe_mm": [float(v) for v in meta["probe_mm"]],
            "parameters": meta["parameters"]}


def msl_header(source: FileSource, name: str | None = None,
               names: MslNames = MSL_API_NAMES) -> tuple:
    """What identifies a measurement in an MSL file's header: ``name``,
    ``artefact.title``, ``artefact.nballs``, ``artefact.ball_spacing``, ``location`` and
    ``rotation/deg`` as written. A snapshot and the metadata saved with it have the same
    (the readers refuse a pair that differ), so this pairs them whatever their order.
    ``names``: as :func:`read_msl_plate`.

    Raises
    ------
    DataError
        A file that is not an MSL file, naming its row and column.
    """
    lines, name = _lines(source, name, "snapshot or metadata")
    head = _header(lines, name, "snapshot or metadata", names.files)
    return tuple(head.rows[k][1].strip() for k in MSL_HEADER_KEYS[2:])


def combine_plates(datasets: Iterable[ForeignDataset]) -> ForeignDataset:
    """Several MSL plate snapshots (one placement each) as one dataset.

    The machine (layout, range), kind, certificate and plate must agree; positions and
    probes are renamed with a suffix where their names repeat (a probe name that repeats
    with the same vector is shared). One placement (the same location, rotation and probe
    vector) given twice is refused: fitted twice, its balls would count double.

    Raises
    ------
    DataError
        Naming the snapshot that does not agree.
    """
    datasets = list(datasets)
    if not datasets:
        raise DataError("no MSL plate given.")
    first = datasets[0]
    frames: list[pd.DataFrame] = []
    positions: dict[str, dict] = {}
    probes: dict[str, list[float]] = {}
    notes: list[str] = []
    placements: dict[tuple, str] = {}
    for ds in datasets:
        if ds.placement and ds.placement in placements:
            # one placement fitted twice would count its balls double and divide every
            # uncertainty it gives by √2 without a word
            raise DataError(f"is the placement of {placements[ds.placement]} again (the same "
                            "location, rotation/deg and probe.length); each placement may be "
                            "fitted once.", file=ds.name, column="location",
                            hint="give each placement's snapshot once.")
        placements.setdefault(ds.placement, ds.name)
        for key, what in (("machine", "machine"), ("certificate", "certificate statement")):
            if ds.setup[key] != first.setup[key]:
                raise DataError(f"its {what} {cut_repr(ds.setup[key])} differs from "
                                f"{first.name}'s {cut_repr(first.setup[key])}; expected one "
                                "machine and one artefact.", file=ds.name, column=key)
        if ds.artefact != first.artefact:
            # one dataset is one plate with one certificate statement: never one statement
            # silently stretched over two artefacts
            raise DataError(f"it measured the artefact {cut_repr(ds.artefact)}, "
                            f"{first.name} the artefact {cut_repr(first.artefact)}; one "
                            "dataset is one plate with one certificate statement.",
                            file=ds.name, column="artefact.title",
                            hint="load each artefact's snapshots on their own, each with "
                                 "its own certificate statement.")
        if ds.certificate_csv != first.certificate_csv or ds.kind != first.kind:
            raise DataError(f"its artefact or kind differs from {first.name}'s; expected one "
                            "plate, all simulated or all measured.", file=ds.name)
        df = pd.read_csv(_io.StringIO(ds.measurements_csv), dtype={"position": str,
                                                                   "probe": str})
        rename = {}
        for q, vec in ds.setup["probes"].items():
            new = q
            while new in probes and probes[new] != vec:
                new += "'"
            probes[new] = vec
            rename[q] = new
        for p, spec in ds.setup["positions"].items():
            new = p
            while new in positions:
                new += "'"
            positions[new] = dict(spec, probe=rename[spec["probe"]])
            df.loc[df["position"] == p, "position"] = new
        df["probe"] = df["probe"].map(rename)
        frames.append(df)
        notes += [f"{ds.name}: {n}" for n in ds.notes]
    setup = dict(first.setup, positions=positions, probes=probes)
    meas = pd.concat(frames, ignore_index=True)
    return replace(first, measurements_csv=meas.to_csv(index=False, float_format="%.7f"),
                   setup=setup, notes=tuple(notes),
                   name=", ".join(ds.name for ds in datasets),
                   decimals=max(ds.decimals for ds in datasets), placement=())


@dataclass(frozen=True)
class MslFiles:
    """MSL plate and bar snapshots read together with their metadata
    (:func:`read_msl_files`): what the command line and the app both load.

    Attributes
    ----------
    plates : list of ForeignDataset
        The plate snapshots, in the order given.
    bars : list of ForeignStepGauge
        The bar snapshots, in the order given.
    notes : list of str
        How they were read: every reader note once, naming the snapshots it applies to
        (``every MSL snapshot`` when all), after each metadata file taken from beside its
        snapshot.
    """

    plates: list
    bars: list
    notes: list

    @property
    def parts(self) -> list:
        """Every snapshot read, plates first."""
        return [*self.plates, *self.bars]

    def plate(self) -> ForeignDataset:
        """The plates as one dataset's files (:func:`combine_plates`), with :attr:`notes`."""
        return replace(combine_plates(self.plates), notes=tuple(self.notes))

    def dataset(self) -> Dataset:
        """The plates loaded (:meth:`ForeignDataset.to_dataset`), with :attr:`notes`."""
        return self.plate().to_dataset()

    def step_gauges(self) -> list[tuple[str, str]]:
        """``(name, step-gauge CSV text)`` of each bar, for
        ``cmm_core.model.read_instrument(..., "step_gauge", name=name)`` (``io`` does not
        import ``model``)."""
        return [(f"{bar.name} (as a step gauge)", bar.step_gauge_csv) for bar in self.bars]


def read_msl_files(plates: Sequence[tuple[str, FileSource]] = (),
                   bars: Sequence[tuple[str, FileSource]] = (),
                   metadata: Sequence[tuple[str, FileSource]] = (), *,
                   kind: str | None = None, certificate_u: dict | None = None,
                   beside=None, names: MslNames = MSL_API_NAMES) -> MslFiles:
    """Plate and bar snapshots with their metadata files, read as one measurement.

    Each metadata file is paired with the snapshot whose header it repeats
    (:func:`msl_header`), in any order; then each snapshot is read with
    :func:`read_msl_plate` or :func:`read_msl_bar`. Fit the plates
    (:meth:`MslFiles.dataset`) with the bars as step gauges (:meth:`MslFiles.step_gauges`).

    Parameters
    ----------
    plates, bars : sequence of (name, source)
        The snapshots: a name for messages and a path, bytes or file-like object.
    metadata : sequence of (name, source)
        The metadata files, in any order.
    kind, certificate_u
        As :func:`read_msl_plate`, for every snapshot.
    beside : callable, optional
        ``beside(name)`` -> ``(name, source)`` of the metadata saved beside snapshot
        ``name`` (MSL saves ``metadata.csv`` in the snapshot's folder), or None. Taken when
        no metadata file given repeats the snapshot's header and that one does; a note
        says so.
    names : MslNames, optional
        The caller's words in refusals; a one-problem refusal of a file is led by
        ``names.lead_plate``, ``lead_bar`` or ``lead_metadata`` (the command line's
        flags), the role the file was given in.

    Raises
    ------
    DataError
        Naming the file: a metadata file given twice or paired with no snapshot, a
        snapshot (placement) given twice, a snapshot without metadata, a bad file.
    """
    lead_of = {"plate": names.lead_plate, "bar": names.lead_bar,
               "metadata": names.lead_metadata}
    metas = list(metadata)  # indexed: two uploads may share a name (MSL's metadata.csv)
    given: dict[tuple, int] = {}
    for i, (mname, msrc) in enumerate(metas):
        key = _led({mname: lead_of["metadata"]}, msl_header, msrc, mname, names)
        if key in given:
            raise DataError(f"repeats the header of {names.metadata_flag} "
                            f"{metas[given[key]][0]} (name {key[0]!r}, location {key[4]}, "
                            f"rotation {key[5]}); give each snapshot's metadata once.",
                            file=mname)
        given[key] = i
    seen: dict[tuple, str] = {}
    pairs, beside_notes, used = [], [], set()
    for role, (sname, ssrc) in [*(("plate", p) for p in plates),
                                *(("bar", b) for b in bars)]:
        key = _led({sname: lead_of[role]}, msl_header, ssrc, sname, names)
        if key in seen:
            # one placement fitted twice would count its balls double and divide every
            # uncertainty it gives by √2 without a word
            raise _lead(DataError(f"repeats the header of {seen[key]} (name {key[0]!r}, "
                                  f"location {key[4]}, rotation {key[5]}): the same placement "
                                  "given twice; each may be fitted once.", file=sname,
                                  hint="give the snapshot once."), lead_of[role])
        seen[key] = sname
        meta = None
        if key in given:
            meta = metas[given[key]]
            used.add(given[key])
        near = beside(sname) if meta is None and beside is not None else None
        if near is not None and _led({near[0]: lead_of["metadata"]}, msl_header, near[1],
                                     near[0], names) == key:
            meta = near
            beside_notes.append(f"{sname}: metadata: {near[0]}, the metadata.csv saved "
                                f"beside the snapshot (no {names.metadata_flag} repeats its "
                                "header).")
        # without metadata the reader refuses the snapshot in the caller's words (after its
        # own checks: a metadata file given as a snapshot is named as such)
        pairs.append((role, sname, ssrc, meta))
    unpaired = [metas[i][0] for i in given.values() if i not in used]
    if unpaired:
        raise _lead(DataError("repeats the header of none of the snapshots given (name, "
                              "artefact, location, rotation); it is no snapshot's metadata.",
                              file=unpaired[0], hint="give it with the snapshot it was saved "
                                                     "with, or leave it out."),
                    lead_of["metadata"])
    read_plates: list[ForeignDataset] = []
    read_bars: list[ForeignStepGauge] = []
    for role, sname, ssrc, meta in pairs:
        read = read_msl_plate if role == "plate" else read_msl_bar
        leads = {sname: lead_of[role]}
        if meta is not None:  # the same file given as both: its metadata role leads
            leads[meta[0]] = lead_of["metadata"]
        (read_plates if role == "plate" else read_bars).append(_led(
            leads, read, ssrc, None if meta is None else meta[1], kind=kind,
            certificate_u=certificate_u, snapshot_name=sname,
            metadata_name=None if meta is None else meta[0], names=names))
    return MslFiles(read_plates, read_bars,
                    beside_notes + _grouped_notes([*read_plates, *read_bars]))


def _lead(exc: DataError, lead: str) -> DataError:
    """``exc`` led by ``lead`` (the flag that gave its file), if it is one problem."""
    if not lead or exc.n_problems != 1 or exc.detail.startswith(lead):
        return exc
    return DataError(f"{lead}: {exc.detail}", file=exc.file, row=exc.row, column=exc.column,
                     hint=exc.hint)


def _led(leads: dict, read, *a, **kw):
    """``read(*a, **kw)``, its refusal led by the word ``leads`` gives its file."""
    try:
        return read(*a, **kw)
    except DataError as exc:
        out = _lead(exc, leads.get(str(exc.file), ""))
        if out is exc:
            raise
        raise out from None


def _grouped_notes(parts: list) -> list[str]:
    """Each reader note once, naming the snapshots it applies to (``every MSL snapshot``
    when all): three placements' identical conventions are not said three times."""
    named: dict[str, list[str]] = {}
    for part in parts:
        for note in part.notes:
            named.setdefault(note, []).append(part.name)
    every = len(parts) > 1
    return [f"{'every MSL snapshot' if every and len(n) == len(parts) else ', '.join(n)}: "
            f"{note}" for note, n in named.items()]


# --------------------------------------------------------------------------- sniffing


def sniff(source: FileSource, names: MslNames = MSL_API_NAMES) -> str | None:
    """A sentence naming the MSL reader when ``source`` is an MSL cmm-error-map file, else
    None: for the plain readers, whose column checks would only say that columns are
    missing. Never raises for unreadable input. ``names`` other than the API's (the
    command line's): the sentence names only how to give the file there
    (``names.plate``, ``names.bar``, ``names.kind``)."""
    try:
        data, _ = read_bytes(source, None)
        text = data[:8192].decode("utf-8-sig", errors="replace")
    except (DataError, OSError, AttributeError, TypeError):
        return None
    lines = text.replace("\r", "\n").split("\n")
    if not lines[0].startswith("save time,") or not any(
            ln.startswith("artefact.nballs,") for ln in lines[:8]):
        return None
    line9 = next((ln.strip() for ln in lines[8:9]), "")
    what = next((k for c, k in _FOREIGN_COLUMNS.items() if line9.startswith(c)), "")
    nb = next((ln.split(",", 1)[1] for ln in lines[:8] if ln.startswith("artefact.nballs,")),
              "")
    if what == "metadata" and nb.replace(" ", "") == "1,1":
        # one ball, no artefact: a machine alone, as msl_metadata_text writes it (MSL's
        # own rule, ny = 1 a bar, would send it to the bar reader, which it is not for)
        return ("this looks like an MSL cmm-error-map metadata file of a machine alone "
                "(no artefact: one ball at the origin), as cmm-error-lab export "
                "--msl-parameters writes it: it is no snapshot's metadata; "
                + ("it is not fitted, nor given with --msl-metadata."
                   if names is not MSL_API_NAMES else
                   "read its machine and parameters with "
                   "cmm_core.io.msl.read_msl_metadata."))
    bar = nb.replace(" ", "").endswith(",1")
    reader = "read_msl_bar" if bar else "read_msl_plate"
    art = "bar (step gauge)" if bar else "plate"
    if names is not MSL_API_NAMES:
        give = names.bar if bar else names.plate
        if what == "metadata":
            return (f"this looks like an MSL cmm-error-map {art} metadata file: give its "
                    f"snapshot.csv ({give}) and this file with {names.metadata_flag} (or "
                    "beside the snapshot, as MSL saves them).")
        return (f"this looks like an MSL cmm-error-map {art} "
                + ("full-data file: not read; " if what == "full-data" else "file: ")
                + f"{give} (its snapshot.csv) and give {names.kind}.")
    if what == "snapshot":
        return (f"this looks like an MSL cmm-error-map {art} snapshot file: read it with "
                f"cmm_core.io.{reader} with its metadata.csv and kind='simulated' or "
                f"'measured' (CLI: --msl{'-bar' if bar else ''} SNAPSHOT.csv --msl-metadata "
                "METADATA.csv --msl-kind KIND).")
    if what == "metadata":
        return (f"this looks like an MSL cmm-error-map {art} metadata file: give it with its "
                f"snapshot.csv to cmm_core.io.{reader} (CLI: --msl-metadata).")
    if what == "full-data":
        return (f"this looks like an MSL cmm-error-map {art} full-data file: read the "
                f"snapshot.csv saved with it with cmm_core.io.{reader}.")
    return (f"this looks like an MSL cmm-error-map file: read its snapshot with "
            f"cmm_core.io.{reader}.")

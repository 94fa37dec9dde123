"""The setup JSON: machine, probes and plate placements, checked against what a CMM can be.

Holds :class:`Placement` and :class:`Setup`, :func:`read_setup` with one helper per section
of the file (machine, probes, positions, plate), the plausibility limits it checks against
(:data:`LAYOUTS`, strokes, probe lengths, axis orthogonality, CTE, temperatures) and the
small JSON value checks (:func:`_vector`, :func:`_record`, :func:`_json_object`).
:func:`check_celsius`, :data:`TEMP_RANGE_C` and :func:`range_tolerance` are shared with
the measurement reader, the simulator config and :func:`~cmm_core.io.matching.resolve`.
"""

from __future__ import annotations

import datetime as _dt
import difflib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from ..machine import LAYOUTS as _KINEMATIC_LAYOUTS
from .delimited import FileSource, read_json
from .errors import DataError, _check_keys, cut_repr, likely_typo

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
_MAX_PLATE_BALLS = 10_000
"""Most balls a setup's plate may state (``plate.balls``): ball plates have 9 to a few
hundred."""


ARTEFACTS = ("ball_plate", "hole_plate")
"""What the plate's features are (setup ``artefact``, default the first): balls, whose
centres are points of the artefact, or holes probed from inside, whose centres give only
the two in-plane coordinates (the coordinate along the hole axis is the probing height)."""

SETUP_KEYS = {
    "": ("units", "frame", "machine", "positions", "probes", "plate", "artefact",
         "certificate", "calibration_date"),
    "certificate": ("exact", "U_um", "k", "combine", "length_from", "source"),
    "machine": ("layout", "range_mm", "id"),
    "plate": ("cte_per_K", "balls", "pitch_mm"),
    "position": ("origin_mm", "u_axis", "v_axis", "probe", "temp_C", "rh_percent"),
}
"""Keys the setup reader uses, per object; other keys are free (notes, names), but one
that looks like a misspelt known key is refused (it would silently leave a default)."""


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
    """Machine, plate placements and probe offsets (the setup JSON of docs/formats.md).

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
    artefact : str
        One of :data:`ARTEFACTS`: ``"ball_plate"`` (default) or ``"hole_plate"``.
    certificate_u : CertificateUncertainty or None
        What the setup states about the certificate's uncertainty (``certificate``), or
        None when it states nothing (the certificate file must then carry it).
    """

    frame: str
    range_mm: np.ndarray
    positions: dict
    probes: dict
    cte_per_K: float = 11.5e-6
    raw: dict = field(default_factory=dict, repr=False)
    name: str | None = field(default=None, repr=False, compare=False)
    artefact: str = ARTEFACTS[0]
    certificate_u: CertificateUncertainty | None = None

    @property
    def machine_id(self) -> str | None:
        """The machine's identity (``machine.id``: its name and serial), None when the
        setup names none; written into every record made from this setup."""
        m = self.raw.get("machine")
        return m.get("id") if isinstance(m, dict) else None

    @property
    def calibration_date(self) -> str | None:
        """The day the measurements were made (``calibration_date``, ISO 8601), None
        when not stated."""
        return self.raw.get("calibration_date")


MAX_MACHINE_ID = 200
"""Characters of ``machine.id`` at most: a name and a serial, not a document."""

_FREE_KEYS = ("source", "name", "note", "notes", "description")
"""Keys free at any level (a note): never taken for a key of another section."""


def _home(key: str) -> str | None:
    """Where a setup key (or the key it most likely misspells) belongs
    (``machine.layout``, ``positions.<name>.probe``), or None for a key of no section
    (free: a note)."""
    if str(key) in _FREE_KEYS:
        return None
    everywhere = {k: section for section, keys in SETUP_KEYS.items() for k in keys
                  if k not in _FREE_KEYS}
    k = key if key in everywhere else likely_typo(str(key), everywhere)
    if k is None:
        return None
    prefix = {"": "", "position": "positions.<name>."}.get(everywhere[k],
                                                          everywhere[k] + ".")
    return prefix + k


def _refuse_misplaced(obj: dict, where: str, name) -> None:
    """Refuse a key of another section placed here (``where``: ``""`` for the top level,
    ``machine``, ``positions.BP1`` ...): read at the wrong level it would be ignored and
    its default used silently (a top-level ``layout`` fits the default layout)."""
    own = SETUP_KEYS["position" if where.startswith("positions.") else where]
    for k in obj:
        home = _home(str(k))
        if k in own or home is None or home.rsplit(".", 1)[-1] in own:
            continue
        here = f"{where}.{k}" if where else str(k)
        level = f"in {where}" if where else "at the top level"
        there = repr(home) if "." in home else f"the top-level {home!r}"
        raise DataError(f"key {cut_repr(k)} does not belong {level}; did you mean {there}?",
                        file=name, column=here,
                        hint="move it into its section (docs/formats.md#setup); at the wrong "
                             "level it would be ignored and its default used.")


def read_setup(source: FileSource | dict, *, name: str | None = "setup.json") -> Setup:
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
    _refuse_misplaced(raw, "", name)
    for sub in ("machine", "plate", "certificate"):
        if isinstance(raw.get(sub), dict):
            _check_keys(raw[sub], SETUP_KEYS[sub], name, sub)
            _refuse_misplaced(raw[sub], sub, name)
    units = raw.get("units", "mm")
    if units != "mm":
        raise DataError(f"units must be 'mm', found {cut_repr(units)}.", file=name, column="units")
    frame = raw.get("frame", "machine")
    if frame not in ("machine", "plate"):
        raise DataError(f"frame must be 'machine' or 'plate', found {cut_repr(frame)}.", file=name,
                        column="frame")
    # the sections in file order, so the first problem reported stays the same
    rng = _machine_range(_json_object(raw, "machine", name), name)
    _identity(raw, name)
    probes = _probes(_json_object(raw, "probes", name), name)
    positions = {str(pos): _placement(spec, f"positions.{pos}", rng, probes, name)
                 for pos, spec in _json_object(raw, "positions", name).items()}
    if not positions:
        raise DataError("no positions defined.", file=name, column="positions")
    cte = _plate_cte(_json_object(raw, "plate", name), name)
    return Setup(frame, rng, positions, probes, cte, raw, name, _artefact(raw, name),
                 _certificate_u(raw, name))


COMBINE = ("quadrature", "linear")


@dataclass(frozen=True)
class CertificateUncertainty:
    """The certificate's expanded uncertainty as the setup states it (``certificate``).

    ``U(k) = sqrt(a² + (b L)²)`` (``combine = "quadrature"``) or ``a + b L``
    (``"linear"``) in µm, ``L`` the distance of a ball from ball 1 in mm, the form
    calibration certificates print (thesis appendix 1: ``a = 0.26 µm``, ``b = 1.9e-3 µm/mm``,
    ``k = 2``, in quadrature); or an exact certificate (a noise-free simulation).

    Attributes
    ----------
    exact : bool
        The certificate is exact: no uncertainty enters a fit, test or budget.
    a_um : float
        Constant part of U in µm.
    b_um_per_mm : float
        Length-proportional part of U in µm per mm.
    k : float
        Coverage factor of the stated U; the standard uncertainty is U / k.
    combine : str
        ``"quadrature"`` or ``"linear"``.
    source : str
        Where the statement comes from, as the user wrote it (may be empty).
    """

    exact: bool = False
    a_um: float = 0.0
    b_um_per_mm: float = 0.0
    k: float = 2.0
    combine: str = "quadrature"
    source: str = ""

    def u_um(self, xyz_mm: np.ndarray) -> np.ndarray | None:
        """Standard uncertainty (µm) of every coordinate, (n, 3); None when exact."""
        if self.exact:
            return None
        length = np.linalg.norm(xyz_mm - xyz_mm[0], axis=1)
        big_u = (np.hypot(self.a_um, self.b_um_per_mm * length) if self.combine == "quadrature"
                 else self.a_um + self.b_um_per_mm * length)
        return np.repeat((big_u / self.k)[:, None], 3, axis=1)

    def describe(self) -> str:
        """One line for the app, the CLI JSON and the report."""
        if self.exact:
            text = "exact, as the setup states (no certificate uncertainty enters)"
        else:
            form = (f"sqrt({self.a_um:g}² + ({self.b_um_per_mm:g}·L)²)"
                    if self.combine == "quadrature"
                    else f"{self.a_um:g} + {self.b_um_per_mm:g}·L")
            text = (f"stated in the setup: U(k={self.k:g}) = {form} µm, L in mm from ball 1, "
                    f"per coordinate")
        return text + (f" ({self.source})" if self.source else "")


def _certificate_u(raw: dict, name) -> CertificateUncertainty | None:
    """The setup's ``certificate`` statement, checked; None when absent."""
    if "certificate" not in raw:
        return None
    spec = _json_object(raw, "certificate", name)
    col = "certificate"
    source = str(spec.get("source", ""))[:200]
    exact = spec.get("exact", False)
    if not isinstance(exact, bool):
        raise DataError(f"certificate.exact must be true or false, found {cut_repr(exact)}.",
                        file=name, column=col + ".exact")
    if exact:
        if "U_um" in spec:
            raise DataError("certificate states both exact and U_um; keep one.", file=name,
                            column=col, hint="exact: true for a noise-free simulation, else "
                            "U_um: [a, b] with k.")
        return CertificateUncertainty(exact=True, source=source)
    if "U_um" not in spec:
        raise DataError("certificate needs U_um: [a_um, b_um_per_mm] (with k), or "
                        "exact: true.", file=name, column=col,
                        hint='e.g. "certificate": {"U_um": [0.26, 0.0019], "k": 2}.')
    ab = spec["U_um"]
    if not (isinstance(ab, list) and len(ab) == 2
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in ab)):
        raise DataError(f"certificate.U_um must be [a_um, b_um_per_mm], two numbers, found "
                        f"{cut_repr(ab)}.", file=name, column=col + ".U_um")
    a, b = float(ab[0]), float(ab[1])
    if not (np.isfinite(a) and np.isfinite(b)) or a < 0 or b < 0 or a + b <= 0 or a > 100 \
            or b > 1.0:
        raise DataError(f"certificate.U_um {ab} is not a plate certificate's uncertainty; "
                        "expected a in 0-100 µm and b in 0-1 µm per mm, not both zero.",
                        file=name, column=col + ".U_um",
                        hint="for an exact (simulated) certificate write exact: true.")
    k = spec.get("k")
    if not isinstance(k, int | float) or isinstance(k, bool) or not 1.0 <= k <= 4.0:
        raise DataError(f"certificate.k must be the coverage factor of U_um (1 to 4), found "
                        f"{cut_repr(k)}.", file=name, column=col + ".k",
                        hint="certificates usually state k = 2.")
    combine = spec.get("combine", "quadrature")
    if combine not in COMBINE:
        raise DataError(f"certificate.combine must be one of {', '.join(COMBINE)}, found "
                        f"{cut_repr(combine)}.", file=name, column=col + ".combine")
    length_from = spec.get("length_from", "ball_1")
    if length_from != "ball_1":
        raise DataError(f"certificate.length_from must be 'ball_1' (L from ball 1), found "
                        f"{cut_repr(length_from)}.", file=name, column=col + ".length_from")
    return CertificateUncertainty(False, a, b, float(k), combine, source)


def _artefact(raw: dict, name) -> str:
    """The ``artefact`` key: one of :data:`ARTEFACTS` (the first when absent); an unknown
    value is refused naming the known ones and the one it most likely misspells."""
    artefact = raw.get("artefact", ARTEFACTS[0])
    if not isinstance(artefact, str) or artefact not in ARTEFACTS:
        guess = likely_typo(str(artefact), ARTEFACTS, cutoff=0.6)
        hint = f"did you mean {guess!r}? " if guess else ""
        raise DataError(f"unknown artefact {cut_repr(artefact)}; {hint}expected one of "
                        f"{', '.join(ARTEFACTS)}.", file=name, column="artefact")
    return artefact


def _identity(raw: dict, name) -> None:
    """``machine.id`` a short text and ``calibration_date`` an ISO 8601 date, when given."""
    machine = raw.get("machine")
    mid = machine.get("id") if isinstance(machine, dict) else None
    if mid is not None and not (isinstance(mid, str) and mid.strip()
                                and len(mid) <= MAX_MACHINE_ID):
        raise DataError(f"machine.id must be the machine's name and serial (text of 1 to "
                        f"{MAX_MACHINE_ID} characters), found {cut_repr(mid)}.", file=name,
                        column="machine.id", hint='e.g. "Leitz PMM-C 12.10.6, s/n 0815".')
    day = raw.get("calibration_date")
    if day is None:
        return
    try:
        ok = isinstance(day, str) and _dt.date.fromisoformat(day).isoformat() == day
    except ValueError:
        ok = False
    if not ok:
        raise DataError(f"calibration_date must be a date YYYY-MM-DD, found {cut_repr(day)}.",
                        file=name, column="calibration_date",
                        hint='the day the plate was measured, e.g. "2024-03-04".')


def _machine_range(machine: dict, name) -> np.ndarray:
    """The ``machine`` section: its layout checked, its strokes (mm) returned."""
    layout = machine.get("layout", LAYOUTS[0])
    if not isinstance(layout, str) or layout not in LAYOUTS:
        close = difflib.get_close_matches(str(layout), list(LAYOUTS), n=1, cutoff=0.5)
        raise DataError(f"machine.layout {cut_repr(layout)} is not a supported kinematic chain"
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
    return rng


def _probes(section: dict, name) -> dict:
    """The ``probes`` section: name -> offset (mm), each of a stylus's length."""
    probes = {}
    for pname, vec in section.items():
        col = f"probes.{pname}"
        p = _vector(vec, name, col, "a vector of 3 numbers (mm)")
        size = float(np.linalg.norm(p))
        if 0 < size < 1.0 or size > MAX_PROBE_MM:
            raise DataError(f"probe offset {p.tolist()} is {size:.4g} mm long; expected a "
                            f"stylus offset in mm (0, or 1 to {MAX_PROBE_MM:g} mm).", file=name,
                            column=col, hint="offsets in metres or µm are refused: write mm, "
                            "e.g. [0, 0, -150].")
        probes[str(pname)] = p
    return probes


def _placement(spec, key: str, rng, probes: dict, name) -> Placement:
    """One entry of ``positions`` (``key`` is ``positions.<name>``) as a :class:`Placement`."""
    if not isinstance(spec, dict):
        raise DataError(f"expected an object with origin_mm, u_axis, v_axis, found "
                        f"{type(spec).__name__} {cut_repr(spec)}.", file=name, column=key)
    _check_keys(spec, SETUP_KEYS["position"], name, key)
    _refuse_misplaced(spec, key, name)
    if "origin_mm" not in spec:
        raise DataError("position needs origin_mm (and u_axis, v_axis) as 3-vectors.",
                        file=name, column=key)
    origin = _vector(spec["origin_mm"], name, key + ".origin_mm", "3 numbers (mm)")
    probe = spec.get("probe")
    if probe is not None and str(probe) not in probes:
        raise DataError(f"probe {cut_repr(probe)} is not among the probes {sorted(probes)}.",
                        file=name, column=key + ".probe")
    # ball 1 is a tip position: with the position's stylus known its scale reading is
    # checked, else the tip is bounded by what the longest stylus can reach
    carriage = origin - probes[str(probe)] if probe is not None else origin
    tol = (range_tolerance(rng) if probe is not None
           else reach_tolerance(rng, probes.values()))
    if ((carriage < -tol) | (carriage > rng + tol)).any():
        what = (f"with probe {probe} the carriage stands at {np.round(carriage, 1).tolist()}"
                if probe is not None else "no stylus reaches it")
        raise DataError(f"origin_mm {origin.tolist()} lies outside the machine's range "
                        f"{rng.tolist()} mm ({what}).", file=name, column=key + ".origin_mm",
                        hint="write the origin (ball 1 tip centre) in machine coordinates in "
                             "mm.")
    if 0 < np.abs(origin).max() < 2.0 and rng.max() >= 100:
        raise DataError(f"origin_mm {origin.tolist()} is within 2 mm of the machine zero; "
                        "it looks like metres, not mm.", file=name,
                        column=key + ".origin_mm", hint="multiply by 1000 (mm).")
    rotation = _plate_axes(spec, key, name)
    records = {rec: _record(spec.get(rec, ()), name, f"{key}.{rec}", rec)
               for rec in ("temp_C", "rh_percent")}
    return Placement(origin, rotation, None if probe is None else str(probe),
                     records["temp_C"], records["rh_percent"])


def _plate_axes(spec: dict, key: str, name) -> np.ndarray:
    """The rotation (columns u, v, u x v) from a position's u_axis and v_axis."""
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
    return np.column_stack([u, v, np.cross(u, v)])


def _plate_cte(plate: dict, name) -> float:
    """The ``plate`` section: pitch and ball count checked, the CTE (1/K) returned."""
    # a plate's pitch lies within a machine's stroke, and a plate of more balls than
    # MAX_PLATE_BALLS would be a table of its own
    for key, lo, hi, what in (("pitch_mm", 1.0, MAX_STROKE_MM, "a length in mm"),
                              ("balls", 3, _MAX_PLATE_BALLS, "a whole number")):
        val = plate.get(key)
        if val is not None and (isinstance(val, bool) or not isinstance(val, int | float)
                                or not np.isfinite(val) or not lo <= val <= hi
                                or (key == "balls" and not float(val).is_integer())):
            raise DataError(f"plate.{key} must be {what} from {lo:g} to {hi:g} (or absent), "
                            f"found {cut_repr(val)}.", file=name, column=f"plate.{key}")
    cte = plate.get("cte_per_K", 11.5e-6)
    if isinstance(cte, bool) or not isinstance(cte, int | float) or not np.isfinite(cte):
        raise DataError(f"plate.cte_per_K must be a number (1/K, e.g. 11.5e-6), found "
                        f"{cut_repr(cte)}.", file=name, column="plate.cte_per_K")
    if not CTE_RANGE_PER_K[0] <= cte <= CTE_RANGE_PER_K[1]:
        raise DataError(f"plate.cte_per_K {cte:g} is not a plate material's expansion per K; "
                        f"expected {CTE_RANGE_PER_K[0]:g} to {CTE_RANGE_PER_K[1]:g} "
                        "(steel 11.5e-6, Zerodur about 0).", file=name,
                        column="plate.cte_per_K",
                        hint="write it per K, not per MK or %/K: 11.5e-6 for steel.")
    return float(cte)


def range_tolerance(rng: ArrayLike) -> np.ndarray:
    """How far beyond the strokes a scale reading (the carriage: tip minus probe offset)
    may lie, mm per axis: 5 % of the stroke, at least 100 mm (a nominal setup is rough)."""
    return np.maximum(0.05 * np.asarray(rng, float), 100.0)


def reach_tolerance(rng: ArrayLike, probes_mm: Iterable[ArrayLike]) -> np.ndarray:
    """How far beyond the strokes a stylus tip may lie, mm per axis: the scale tolerance
    plus the longest of ``probes_mm`` (a plausibility bound on a tip whose stylus is not
    known; a tip whose stylus is known is checked by its scale reading instead)."""
    longest = max((float(np.linalg.norm(p)) for p in probes_mm), default=0.0)
    return range_tolerance(rng) + longest


def _record(val, name, column, what):
    """Temperatures (°C) or humidities (%) of a setup position: a number or list."""
    val = [val] if isinstance(val, int | float) and not isinstance(val, bool) else val
    if not isinstance(val, list | tuple) or not all(
            isinstance(t, int | float) and not isinstance(t, bool) for t in val):
        raise DataError(f"{what} must be a number or a list of numbers, found {cut_repr(val)}.",
                        file=name, column=column)
    out = tuple(float(t) for t in val)
    if what == "temp_C":
        check_celsius(np.asarray(out), name, column)
    elif any(not 0 <= t <= 100 for t in out):
        raise DataError(f"relative humidity {list(out)} must be 0 to 100 %.", file=name,
                        column=column, hint="write percent, not a fraction.")
    return out


def check_celsius(t: np.ndarray, name: str | None, column: str, row: int | None = None) -> None:
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


def _json_object(raw: dict, key: str, name) -> dict:
    """``raw[key]`` when it is a JSON object (``{}`` when absent), else a DataError."""
    val = raw.get(key, {})
    if not isinstance(val, dict):
        raise DataError(f"expected a JSON object for {key!r}, found {type(val).__name__} "
                        f"{cut_repr(val)}.", file=name, column=key)
    return val


def _vector(val, name, column, expected) -> np.ndarray:
    """A length-3 float vector from JSON, or a DataError saying what was expected."""
    v = None
    # JSON numbers only: np.asarray would read ["1", "0", "0"] or [true, 0, 0] silently
    if isinstance(val, list | tuple) and all(isinstance(x, int | float) and not
                                             isinstance(x, bool) for x in val):
        v = np.asarray(val, float)
    if v is None or v.shape != (3,) or not np.isfinite(v).all():
        raise DataError(f"must be {expected}, found {cut_repr(val)}.", file=name, column=column)
    return v

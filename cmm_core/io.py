"""Reading and validating measurements, setups and certificates (SPEC "Data formats").

Every problem is reported as a :class:`DataError` naming the file, row and column and what
was expected, with a hint at the fix. Row numbers are 1-based data rows as a spreadsheet
shows them (the header is row 1, so the first data row is row 2).
"""

from __future__ import annotations

import io as _io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

LONG_COLUMNS = ("position", "probe", "ball", "x_mm", "y_mm", "z_mm")
OPTIONAL_COLUMNS = ("time_min", "temp_C", "repeat")
THESIS_COLUMNS = ("ball", "x_mm", "y_mm", "z_mm")
MAX_BYTES = 50 * 1024 * 1024


class DataError(ValueError):
    """Bad input: the message names file, row, column, what was expected and a fix."""

    def __init__(self, message, *, file=None, row=None, column=None, hint=None):
        self.file, self.row, self.column, self.hint = file, row, column, hint
        self.detail = message
        where = [str(file)] if file else []
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        text = (": ".join([", ".join(where), message]) if where else message)
        if hint:
            text += f" Hint: {hint}"
        super().__init__(text)


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
    """

    frame: str
    range_mm: np.ndarray
    positions: dict
    probes: dict
    cte_per_K: float = 11.5e-6
    raw: dict = field(default_factory=dict, repr=False)


@dataclass(frozen=True)
class Certificate:
    """Calibrated ball centres in the plate frame.

    Attributes
    ----------
    balls : ndarray of int (n,)
    xyz_mm : ndarray (n, 3)
    u_um : ndarray (n, 3) or None
        Standard uncertainties of the coordinates in µm, when the file gives them.
    """

    balls: np.ndarray
    xyz_mm: np.ndarray
    u_um: np.ndarray | None = None


def _read_csv(source, name):
    """Read a CSV from a path, bytes or file-like object into strings (nothing coerced)."""
    if isinstance(source, (str, Path)):
        path = Path(source)
        name = name or path.name
        if not path.exists():
            raise DataError("file not found.", file=name, hint="check the path.")
        if path.stat().st_size > MAX_BYTES:
            raise DataError(f"file is {path.stat().st_size / 1e6:.0f} MB; the limit is "
                            f"{MAX_BYTES / 1e6:.0f} MB.", file=name)
        data = path.read_bytes()
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
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataError("is not UTF-8 text.", file=name,
                        hint="export the table as CSV (UTF-8).") from exc
    if not text.strip():
        raise DataError("file is empty.", file=name)
    try:
        df = pd.read_csv(_io.StringIO(text), dtype=str, skipinitialspace=True)
    except (pd.errors.ParserError, ValueError) as exc:
        raise DataError(f"is not a valid CSV table ({exc}).", file=name) from exc
    df.columns = [str(c).strip() for c in df.columns]
    return df, name


def _numeric(df, column, name, *, integer=False, allow_missing=False):
    raw = df[column]
    vals = pd.to_numeric(raw.str.strip() if raw.dtype == object else raw, errors="coerce")
    bad = vals.isna() & ~(allow_missing & raw.isna())
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        raise DataError(f"expected a number, found {raw.iloc[i]!r}.", file=name, row=i + 2,
                        column=column, hint="use a point as decimal separator and no units.")
    arr = vals.to_numpy(dtype=float)
    if integer:
        frac = np.abs(arr - np.round(arr)) > 0
        if frac.any():
            i = int(np.flatnonzero(frac)[0])
            raise DataError(f"expected a whole ball number, found {raw.iloc[i]!r}.",
                            file=name, row=i + 2, column=column)
        return np.round(arr).astype(int)
    return arr


def _require(df, columns, name, form):
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise DataError(f"missing column(s) {', '.join(missing)}; expected {form} columns "
                        f"{','.join(columns)}, found {','.join(df.columns)}.", file=name,
                        hint="see SPEC 'Data formats' for the column names (lengths in mm).")


def read_measurements(source, *, name=None, position=None) -> pd.DataFrame:
    """Read one measurement CSV in long or thesis form.

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
    Probes are ``None`` for thesis-form files (the setup names them).
    """
    df, name = _read_csv(source, name)
    if "position" in df.columns:
        _require(df, LONG_COLUMNS, name, "long-form")
        out = pd.DataFrame({"position": df["position"].str.strip(),
                            "probe": df["probe"].str.strip()})
        for col, label in (("position", "position"), ("probe", "probe")):
            empty = out[col].isna() | (out[col] == "")
            if empty.any():
                i = int(np.flatnonzero(empty.to_numpy())[0])
                raise DataError(f"expected a {label} name, found an empty cell.", file=name,
                                row=i + 2, column=col)
    else:
        _require(df, THESIS_COLUMNS, name, "thesis-form")
        pos = position or Path(name).stem
        out = pd.DataFrame({"position": [pos] * len(df), "probe": [None] * len(df)})
    out["ball"] = _numeric(df, "ball", name, integer=True)
    for col in ("x_mm", "y_mm", "z_mm"):
        out[col] = _numeric(df, col, name)
    for col in OPTIONAL_COLUMNS:
        if col in df.columns:
            out[col] = _numeric(df, col, name)
    if (out["ball"] < 1).any():
        i = int(np.flatnonzero((out["ball"] < 1).to_numpy())[0])
        raise DataError(f"expected ball numbers from 1, found {out['ball'].iloc[i]}.",
                        file=name, row=i + 2, column="ball")
    out["source"] = name
    out["row"] = np.arange(2, len(out) + 2)
    _check_units(out, name)
    return out


def _check_units(df, name):
    """Coordinates that look like metres: a ball plate spans hundreds of mm."""
    xyz = df[["x_mm", "y_mm", "z_mm"]].to_numpy()
    if len(df) >= 4 and np.ptp(xyz, axis=0).max() < 2.0:
        raise DataError(f"coordinates span only {np.ptp(xyz, axis=0).max():.3g} in every "
                        "axis; they look like metres, not mm.", file=name,
                        column="x_mm", hint="multiply by 1000 (files are in mm).")
    big = np.abs(xyz) > 1e5
    if big.any():
        i, j = np.argwhere(big)[0]
        raise DataError(f"value {xyz[i, j]} mm is beyond any CMM's range; it looks like µm.",
                        file=name, row=int(i) + 2, column=("x_mm", "y_mm", "z_mm")[j],
                        hint="divide by 1000 (files are in mm).")


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


def read_setup(source, *, name="setup.json") -> Setup:
    """Read the setup JSON (path, dict, bytes or file-like) and check its fields."""
    if isinstance(source, dict):
        raw = source
    else:
        if isinstance(source, (str, Path)):
            name = Path(source).name
            try:
                text = Path(source).read_text()
            except OSError as exc:
                raise DataError(f"cannot read ({exc.strerror}).", file=name) from exc
        else:
            text = source if isinstance(source, str) else source.read()
            text = text.decode() if isinstance(text, bytes) else text
        try:
            raw = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataError(f"is not valid JSON: {exc.msg} at line {exc.lineno}.",
                            file=name) from exc
    if not isinstance(raw, dict):
        raise DataError("expected a JSON object.", file=name)
    units = raw.get("units", "mm")
    if units != "mm":
        raise DataError(f"units must be 'mm', found {units!r}.", file=name, column="units")
    frame = raw.get("frame", "machine")
    if frame not in ("machine", "plate"):
        raise DataError(f"frame must be 'machine' or 'plate', found {frame!r}.", file=name,
                        column="frame")
    machine = _json_object(raw, "machine", name)
    rng = _vector(machine.get("range_mm", [1200, 1000, 700]), name, "machine.range_mm",
                  "three positive lengths (mm)")
    if (rng <= 0).any():
        raise DataError(f"machine.range_mm must be three positive lengths, found {rng}.",
                        file=name, column="machine.range_mm")
    probes = {str(pname): _vector(vec, name, f"probes.{pname}", "a vector of 3 numbers (mm)")
              for pname, vec in _json_object(raw, "probes", name).items()}
    positions = {}
    for pos, spec in _json_object(raw, "positions", name).items():
        key = f"positions.{pos}"
        if not isinstance(spec, dict):
            raise DataError(f"expected an object with origin_mm, u_axis, v_axis, found "
                            f"{type(spec).__name__} {spec!r}.", file=name, column=key)
        if "origin_mm" not in spec:
            raise DataError("position needs origin_mm (and u_axis, v_axis) as 3-vectors.",
                            file=name, column=key)
        origin = _vector(spec["origin_mm"], name, key + ".origin_mm", "3 numbers (mm)")
        u = _vector(spec.get("u_axis", [1, 0, 0]), name, key + ".u_axis", "3 numbers")
        v = _vector(spec.get("v_axis", [0, 1, 0]), name, key + ".v_axis", "3 numbers")
        if np.linalg.norm(u) < 1e-12:
            raise DataError("u_axis is the zero vector.", file=name, column=key + ".u_axis")
        u = u / np.linalg.norm(u)
        v = v - u * (u @ v)
        if np.linalg.norm(v) < 1e-6:
            raise DataError("u_axis and v_axis are parallel (or v_axis is zero).", file=name,
                            column=key)
        v = v / np.linalg.norm(v)
        probe = spec.get("probe")
        if probe is not None and str(probe) not in probes:
            raise DataError(f"probe {probe!r} is not among the probes {sorted(probes)}.",
                            file=name, column=key + ".probe")
        records = {}
        for rec in ("temp_C", "rh_percent"):
            val = spec.get(rec, ())
            val = [val] if isinstance(val, int | float) else val
            try:
                records[rec] = tuple(float(t) for t in val)
            except (TypeError, ValueError):
                raise DataError(f"{rec} must be a number or a list of numbers, found {val!r}.",
                                file=name, column=f"{key}.{rec}") from None
        positions[str(pos)] = Placement(origin, np.column_stack([u, v, np.cross(u, v)]),
                                        None if probe is None else str(probe),
                                        records["temp_C"], records["rh_percent"])
    if not positions:
        raise DataError("no positions defined.", file=name, column="positions")
    cte = _json_object(raw, "plate", name).get("cte_per_K", 11.5e-6)
    if isinstance(cte, bool) or not isinstance(cte, int | float) or not np.isfinite(cte):
        raise DataError(f"plate.cte_per_K must be a number (1/K, e.g. 11.5e-6), found {cte!r}.",
                        file=name, column="plate.cte_per_K")
    cte = float(cte)
    return Setup(frame, rng, positions, probes, cte, raw)


def _json_object(raw: dict, key: str, name) -> dict:
    """``raw[key]`` when it is a JSON object (``{}`` when absent), else a DataError."""
    val = raw.get(key, {})
    if not isinstance(val, dict):
        raise DataError(f"expected a JSON object for {key!r}, found {type(val).__name__} "
                        f"{val!r}.", file=name, column=key)
    return val


def _vector(val, name, column, expected) -> np.ndarray:
    """A length-3 float vector from JSON, or a DataError saying what was expected."""
    try:
        v = np.asarray(val, float)
    except (TypeError, ValueError):
        v = None
    if v is None or v.shape != (3,) or not np.isfinite(v).all():
        raise DataError(f"must be {expected}, found {val!r}.", file=name, column=column)
    return v


def read_certificate(source, *, name=None) -> Certificate:
    """Read a certificate CSV ``ball,x_mm,y_mm,z_mm[,u_x_um,u_y_um,u_z_um]``."""
    df, name = _read_csv(source, name)
    _require(df, THESIS_COLUMNS, name, "certificate")
    balls = _numeric(df, "ball", name, integer=True)
    xyz = np.column_stack([_numeric(df, c, name) for c in ("x_mm", "y_mm", "z_mm")])
    dup = pd.Series(balls).duplicated()
    if dup.any():
        i = int(np.flatnonzero(dup.to_numpy())[0])
        raise DataError(f"ball {balls[i]} appears twice.", file=name, row=i + 2, column="ball")
    u = None
    if all(c in df.columns for c in ("u_x_um", "u_y_um", "u_z_um")):
        u = np.column_stack([_numeric(df, c, name) for c in ("u_x_um", "u_y_um", "u_z_um")])
        if (u <= 0).any():
            i, j = np.argwhere(u <= 0)[0]
            raise DataError("uncertainties must be positive.", file=name, row=int(i) + 2,
                            column=("u_x_um", "u_y_um", "u_z_um")[j])
    order = np.argsort(balls)
    return Certificate(balls[order], xyz[order], None if u is None else u[order])


def resolve(meas: pd.DataFrame, setup: Setup, certificate: Certificate | None = None):
    """Attach probes from the setup, check names and balls, map to machine coordinates.

    Returns a copy of ``meas`` with the probe filled in and columns ``mx_mm, my_mm,
    mz_mm`` (machine-frame tip centres) added. Raises :class:`DataError` naming the file and
    row of the first problem.
    """
    df = meas.copy()
    for i, r in enumerate(df.itertuples()):
        if r.position not in setup.positions:
            raise DataError(f"position {r.position!r} is not in the setup (known: "
                            f"{', '.join(setup.positions)}).", file=r.source, row=r.row,
                            column="position", hint="add it to setup.json or rename the file.")
        if r.probe is None or (isinstance(r.probe, float) and np.isnan(r.probe)):
            probe = setup.positions[r.position].probe
            if probe is None:
                raise DataError(f"no probe column and the setup names no probe for position "
                                f"{r.position!r}.", file=r.source, row=r.row,
                                hint="add \"probe\" to the position in setup.json.")
            df.iat[i, df.columns.get_loc("probe")] = probe
    unknown = ~df["probe"].isin(list(setup.probes))
    if unknown.any():
        r = df[unknown].iloc[0]
        raise DataError(f"probe {r.probe!r} is not in the setup (known: "
                        f"{', '.join(setup.probes)}).", file=r.source, row=r.row,
                        column="probe", hint="add its offset to setup.json 'probes'.")
    key = ["position", "probe", "ball"] + (["repeat"] if "repeat" in df.columns else [])
    dup = df.duplicated(key)
    if dup.any():
        r = df[dup].iloc[0]
        raise DataError(f"ball {r.ball} of position {r.position} with probe {r.probe} appears "
                        "twice.", file=r.source, row=r.row, column="ball",
                        hint="add a 'repeat' column for repeated measurements.")
    if certificate is not None:
        known = set(certificate.balls.tolist())
        extra = ~df["ball"].isin(known)
        if extra.any():
            r = df[extra].iloc[0]
            raise DataError(f"ball {r.ball} is not on the certificate (balls "
                            f"{certificate.balls.min()}-{certificate.balls.max()}).",
                            file=r.source, row=r.row, column="ball")
    xyz = df[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    if setup.frame == "plate":
        m = np.empty_like(xyz)
        for pos, pl in setup.positions.items():
            sel = (df["position"] == pos).to_numpy()
            m[sel] = pl.to_machine(xyz[sel])
        xyz = m
    df["mx_mm"], df["my_mm"], df["mz_mm"] = xyz.T
    return df


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

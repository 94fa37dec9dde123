"""Measurements against setup and certificate: names, duplicates, machine frame, geometry.

Holds :func:`resolve` (probes attached from the setup, unknown names and duplicates
reported per file and row, coordinates mapped to the machine frame), the geometry checks
that catch wrong units, frame or placement before a fit does (:func:`_check_geometry`,
:func:`_check_certificate_in_machine`) and :func:`missing_balls`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .certificate import Certificate
from .errors import DataError, Problems, cut_repr
from .measurements import _check_duplicates
from .setup import Setup, range_tolerance, reach_tolerance


def resolve(meas: pd.DataFrame, setup: Setup, certificate: Certificate | None = None
        ) -> pd.DataFrame:
    """Attach probes from the setup, check names and balls, map to machine coordinates.

    Returns a copy of ``meas`` with the probe filled in and columns ``mx_mm, my_mm,
    mz_mm`` (machine-frame tip centres) added. Raises one :class:`DataError` listing every
    problem (an unknown position or probe once per file, duplicates and balls missing from
    the certificate once per row), each naming its file and row.
    """
    df = meas.copy()
    found = Problems(None, df["row"].to_numpy(), files=df["source"].to_numpy())
    known_pos = df["position"].isin(list(setup.positions)).to_numpy()
    found.add(_first_per(df, ~known_pos, ["source", "position"]), "position",
              lambda i: f"position {cut_repr(df['position'].iat[i])} is not in the setup (known: "
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
              f"{cut_repr(df['position'].iat[i])}.",
              hint="add \"probe\" to the position in setup.json.")
    unknown = (df["probe"].notna() & ~df["probe"].isin(list(setup.probes))).to_numpy()
    found.add(_first_per(df, unknown, ["source", "probe"]), "probe",
              lambda i: f"probe {cut_repr(df['probe'].iat[i])} is not in the setup (known: "
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
    for pos in dict.fromkeys(df["position"]):
        # a certificate ball is a tip: it may lie as far out as this position's styli reach
        used = df.loc[df["position"] == pos, "probe"].dropna().unique()
        tol = reach_tolerance(rng, [setup.probes[q] for q in used if q in setup.probes])
        m = setup.positions[pos].to_machine(cert.xyz_mm)
        out = ((m < -tol) | (m > rng + tol)).any(axis=1)
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise DataError(f"ball {cert.balls[i]} at {np.round(cert.xyz_mm[i], 3).tolist()} "
                            f"mm, placed by position {cut_repr(pos)}, lies at "
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
    tol = range_tolerance(rng)
    # the machine's range bounds its scale readings, the carriage: tip minus probe offset
    # (a 600 mm stylus reaches 600 mm past the strokes)
    codes, probes = pd.factorize(df["probe"])  # one lookup per stylus, not per row
    offsets = np.array([setup.probes[q] for q in probes], float).reshape(-1, 3)[codes]
    carriage = xyz - offsets
    outside = ((carriage < -tol) | (carriage > rng + tol)).any(axis=1)
    where = f"the setup {setup.name}" if setup.name else "the setup"
    frame_hint = (f"{where} has \"frame\": \"machine\""
                  f"{'' if 'frame' in setup.raw else ' (the default: no frame key)'}: if the "
                  "coordinates are in the plate frame (ball 1 at 0, 0, 0), set \"frame\": "
                  "\"plate\"." if setup.frame == "machine" else f"{where} has \"frame\": "
                  "\"plate\": if the coordinates are machine coordinates, set \"frame\": "
                  "\"machine\".")
    found.add(outside & _first_rows(df, outside), None,
              lambda i: f"point {np.round(xyz[i], 1).tolist()} mm (machine frame) lies "
              f"outside the machine's range {rng.tolist()} mm: its scale reading (tip minus "
              f"probe {df['probe'].iat[i]}) is {np.round(carriage[i], 1).tolist()} mm.",
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
        where = f"position {cut_repr(pos)}"
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

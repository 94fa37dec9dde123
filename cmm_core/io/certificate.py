"""Certificates: calibrated ball centres in the plate frame, and their uncertainties.

Holds :class:`Certificate`, :func:`read_certificate` with its checks (optional
uncertainty columns, at least three balls off one line to define a plate frame, no ball
far from the others) and :func:`write_certificate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
import pandas as pd

from .delimited import (
    FileSource,
    file_rows,
    numeric_column,
    read_csv_text,
    require_columns,
    require_rows,
)
from .errors import DataError, Problems
from .measurements import THESIS_COLUMNS, _ball_numbers, _check_duplicates, _check_units

MIN_CERTIFICATE_BALLS = 3


@dataclass(frozen=True)
class Certificate:
    """Calibrated ball centres in the plate frame.

    Attributes
    ----------
    balls : ndarray of int (n,)
    xyz_mm : ndarray (n, 3)
    u_um : ndarray (n, 3) or None
        Standard uncertainties of the coordinates in µm: from the file's columns or the
        setup's statement; None for an exact certificate or one whose uncertainty nobody
        stated yet (``u_source`` tells which).
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
    u_source: str = ""
    """Where ``u_um`` came from, in words (empty: not stated; no fit may use it)."""


def read_certificate(source: FileSource, *, name: str | None = None) -> Certificate:
    """Read a certificate CSV ``ball,x_mm,y_mm,z_mm[,u_x_um,u_y_um,u_z_um]``.

    Every cell is checked (see :func:`read_measurements`); the certificate must then give
    at least three balls that do not lie on one line, the least that defines a plate frame.
    """
    df, name = read_csv_text(source, name)
    require_columns(df, THESIS_COLUMNS, name, "certificate")
    require_rows(df, name, "calibrated ball")
    found = Problems(name, file_rows(df), df.columns)
    balls = _ball_numbers(df, name, found)
    xyz = np.column_stack([numeric_column(df, c, name, problems=found)
                           for c in ("x_mm", "y_mm", "z_mm")])
    _check_duplicates(pd.DataFrame({"ball": balls}), ["ball"], found)
    _check_units(xyz, found)
    u = _uncertainties(df, name, found)
    found.raise_if_any()
    _check_plate_frame(xyz, name)
    rows = file_rows(df)
    _check_isolated_balls(xyz, balls, rows, name)
    balls = balls.astype(int)
    order = np.argsort(balls)
    return Certificate(balls[order], xyz[order], None if u is None else u[order],
                       rows=rows[order], name=name,
                       u_source="" if u is None else f"{name}: columns u_x_um, u_y_um, u_z_um")


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
        found = Problems(name, rows, ("ball", "x_mm", "y_mm", "z_mm"))
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
    u = np.column_stack([numeric_column(df, c, name, problems=found) for c in cols])
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


def write_certificate(cert: Certificate, path: str | Path | IO[str]) -> None:
    """Write a certificate CSV (with uncertainty columns when present)."""
    df = pd.DataFrame({"ball": cert.balls, "x_mm": cert.xyz_mm[:, 0],
                       "y_mm": cert.xyz_mm[:, 1], "z_mm": cert.xyz_mm[:, 2]})
    if cert.u_um is not None:
        df["u_x_um"], df["u_y_um"], df["u_z_um"] = cert.u_um.T
    df.to_csv(path, index=False, float_format="%.6f")

"""Geometry helpers shared by the fit, outlier detection and the report (no solver).

Rigid best fit of point sets (Kabsch), the skew matrix of small rotations, and the plate
frame in which thermal expansion and sag are written.
"""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Stacked skew matrices ``[v]×`` (n, 3, 3): ``skew(v)[i] @ w == cross(v[i], w)``."""
    z = np.zeros(len(v))
    return np.stack([z, -v[:, 2], v[:, 1], v[:, 2], z, -v[:, 0], -v[:, 1], v[:, 0], z],
                    1).reshape(-1, 3, 3)


def rigid_fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t with ``src @ R.T + t`` closest to dst (Kabsch/SVD)."""
    cs, cd = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cd - R @ cs


def plate_effect_basis(plate_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre of the plate (thermal expansion is about it) and the sag basis per ball:
    ``(u², u·v, v²)`` in plate coordinates normalised to [-1, 1] over the plate, so that
    each coefficient is the bowl height at the plate's edge."""
    centre = plate_mm.mean(0)
    half = np.maximum(np.ptp(plate_mm, axis=0) / 2, 1.0)
    xi = (plate_mm - centre) / half
    return centre, np.column_stack([xi[:, 0] ** 2, xi[:, 0] * xi[:, 1], xi[:, 1] ** 2])

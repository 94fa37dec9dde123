"""Robust outlier detection across positions (median / MAD), never dropping silently.

Each position-and-probe group is brought into the plate frame through its nominal
placement and re-aligned rigidly (least squares over the balls not yet flagged) to a
reference plate: the per-ball median over all groups when there are at least three groups,
otherwise the certificate. A coordinate is flagged when its deviation from the reference
exceeds ``k`` robust standard deviations (1.4826 × MAD of that axis over all balls and
groups, and of that axis within its own group) and ``floor_um``. The MAD is robust to a few gross errors, and the floor keeps
sub-micrometre scatter from being flagged on very repeatable data.

A hole plate (setup ``artefact``, ``hole_plate``) is compared in its plane only: the
coordinate along the hole axis is the probing height the operator chose, not a property of
the plate, so it is set to zero (the plate-frame ``z``, reported as 0 and never flagged).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..io import Dataset
from ..machine import rigid_fit


@dataclass(frozen=True)
class OutlierReport:
    """Flagged coordinates.

    Attributes
    ----------
    outliers : list of dict
        ``{"position", "probe", "ball", "axis", "deviation_um", "robust_z", "source", "row"}``
        for every flagged coordinate, largest first.
    scale_um : dict
        Robust standard deviation of the deviations per axis.
    threshold_um : dict
        Flagging threshold per axis.
    reference : str
        ``median of N groups`` or ``certificate``.
    deviations : DataFrame
        Deviation of every coordinate from the reference (µm), for plotting.
    certificate_suspects : list of dict
        ``{"ball", "axis", "deviation_um", "robust_z"}``: certificate coordinates that the
        median of all positions contradicts (median minus certificate).
    """

    outliers: list
    scale_um: dict
    threshold_um: dict
    reference: str
    deviations: pd.DataFrame
    certificate_suspects: Sequence[dict] = ()

    @property
    def exclusions(self) -> list:
        """``(position, probe, ball)`` triples of the flagged observations."""
        return sorted({(o["position"], o["probe"], o["ball"]) for o in self.outliers})


def detect_outliers(data: Dataset, *, k: float = 5.0, floor_um: float = 10.0,
                    iterations: int = 3) -> OutlierReport:
    """Flag gross errors by comparing every position with the others.

    Parameters
    ----------
    data : Dataset
    k : float
        Threshold in robust standard deviations.
    floor_um : float
        Deviations below this are never flagged.
    """
    df = data.meas
    groups = list(df.groupby(["position", "probe"], sort=False))
    balls = (data.certificate.balls if data.certificate is not None
             else np.unique(df["ball"]))
    bidx = {b: i for i, b in enumerate(balls)}
    G = len(groups)
    tables = np.full((G, len(balls), 3), np.nan)
    meta = []
    for g, ((pos, probe), sub) in enumerate(groups):
        pl = data.setup.positions[pos]
        local = (sub[["mx_mm", "my_mm", "mz_mm"]].to_numpy() - pl.origin_mm) @ pl.rotation
        for b, row in zip(sub["ball"], local, strict=True):
            tables[g, bidx[b]] = row
        meta.append((pos, probe, dict(zip(sub["ball"], zip(sub["source"], sub["row"],
                                                             strict=True), strict=True))))
    use_median = G >= 3 or data.certificate is None
    in_plane = getattr(data.setup, "artefact", "ball_plate") == "hole_plate"
    cert_ref = None if data.certificate is None else data.certificate.xyz_mm
    if in_plane:  # a hole's normal coordinate is its probing height (module docstring)
        tables[:, :, 2] = np.where(np.isnan(tables[:, :, 2]), np.nan, 0.0)
        if cert_ref is not None:
            cert_ref = cert_ref * np.array([1.0, 1.0, 0.0])
    flagged = np.zeros(tables.shape, bool)
    aligned = tables.copy()
    for _ in range(iterations):
        if use_median or cert_ref is None:  # no certificate: use_median is True
            ref = np.nanmedian(np.where(flagged, np.nan, aligned), axis=0)
        else:
            ref = cert_ref
        for g in range(G):
            ok = ~np.isnan(tables[g, :, 0]) & ~flagged[g].any(1) & ~np.isnan(ref[:, 0])
            if ok.sum() >= 3:
                R, t = rigid_fit(tables[g][ok], ref[ok])
                aligned[g] = tables[g] @ R.T + t
        dev = (aligned - ref) * 1e3
        scale = {}
        for a in range(3):
            vals = dev[:, :, a][~np.isnan(dev[:, :, a])]
            mad = np.median(np.abs(vals - np.median(vals))) if vals.size else 0.0
            scale[a] = 1.4826 * mad
        thr = {a: max(k * scale[a], floor_um) for a in range(3)}
        # A group whose own scatter is large (a systematic pattern such as sag, not a
        # blunder) is judged against its own robust scale as well.
        med = np.nanmedian(dev, axis=1, keepdims=True)
        own = 1.4826 * np.nanmedian(np.abs(dev - med), axis=1, keepdims=True)
        limit = np.maximum(np.array([thr[a] for a in range(3)]), k * own)
        flagged = np.abs(np.nan_to_num(dev - med)) > limit
    out, rows = [], []
    for g, (pos, probe, src) in enumerate(meta):
        for i, b in enumerate(balls):
            if np.isnan(dev[g, i, 0]):
                continue
            rows.append({"position": pos, "probe": probe, "ball": int(b),
                         "dx_um": dev[g, i, 0], "dy_um": dev[g, i, 1], "dz_um": dev[g, i, 2]})
            for a in range(3):
                if flagged[g, i, a]:
                    s, r = src.get(b, (None, None))
                    out.append({"position": pos, "probe": probe, "ball": int(b),
                                "axis": "xyz"[a], "deviation_um": round(float(dev[g, i, a]), 3),
                                "robust_z": round(float(dev[g, i, a] / max(scale[a], 1e-9)), 1),
                                "source": s, "row": None if r is None else int(r)})
    out.sort(key=lambda o: -abs(o["deviation_um"]))
    axes = dict(zip("xyz", range(3), strict=True))
    cert = []
    if use_median and data.certificate is not None and G >= 3:
        cert = _certificate_check(ref, data.certificate, k, floor_um)
    return OutlierReport(out, {n: float(scale[a]) for n, a in axes.items()},
                         {n: float(thr[a]) for n, a in axes.items()},
                         f"median of {G} groups" if use_median else "certificate",
                         pd.DataFrame(rows), cert)


def _certificate_check(ref, cert, k, floor_um):
    """Certificate balls that disagree with the median of all positions.

    The median plate is aligned rigidly to the certificate; a certificate coordinate is
    suspect when it differs by more than ``k`` robust standard deviations and
    ``floor_um``. Such a value cannot be excluded like a measurement: fit with the plate
    free or as a prior, or query the calibration laboratory."""
    ok = ~np.isnan(ref[:, 0])
    R, t = rigid_fit(ref[ok], cert.xyz_mm[ok])
    dev = np.full(ref.shape, np.nan)
    dev[ok] = ((ref[ok] @ R.T + t) - cert.xyz_mm[ok]) * 1e3
    out = []
    for a in range(3):
        v = dev[ok, a]
        sc = 1.4826 * np.median(np.abs(v - np.median(v)))
        thr = max(k * sc, floor_um)
        for i in np.flatnonzero(ok):
            if abs(dev[i, a] - np.median(v)) > thr:
                out.append({"ball": int(cert.balls[i]), "axis": "xyz"[a],
                            "deviation_um": round(float(dev[i, a]), 3),
                            "robust_z": round(float(dev[i, a] / max(sc, 1e-9)), 1)})
    return out

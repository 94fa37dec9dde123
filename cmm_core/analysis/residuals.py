"""Where the model fails: residual breakdowns and per-position trends against the plate.

These are the views a metrologist reads before asking which effect is missing: the RMS
and χ² share by position, probe, ball and axis, residual against machine coordinates and
time, and, with a certificate, each position's own scale and out-of-plane bowl; and the
tables the app and the report show beside them (residual RMS per position and probe, the
instruments of a joint fit, the uncertainty gain the instruments bring).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from ..io import Dataset
from ..model import FitResult


def breakdown(result: FitResult, by: str) -> pd.DataFrame:
    """RMS per axis (µm), χ² and its share of the total, grouped by ``position``,
    ``probe`` or ``ball``; largest share first."""
    rf = result.residuals_frame()
    chi = (rf[["rx_um", "ry_um", "rz_um"]] ** 2).sum(axis=1) / result.sigma_um**2
    rf = rf.assign(chi2=chi)
    g = rf.groupby(by, sort=False)
    out = pd.DataFrame({
        "n": g.size(),
        "rms_x_um": g["rx_um"].apply(lambda s: float(np.sqrt(np.mean(s**2)))),
        "rms_y_um": g["ry_um"].apply(lambda s: float(np.sqrt(np.mean(s**2)))),
        "rms_z_um": g["rz_um"].apply(lambda s: float(np.sqrt(np.mean(s**2)))),
        "chi2": g["chi2"].sum(),
    })
    out["chi2_share"] = out["chi2"] / max(chi.sum(), 1e-300)
    return out.sort_values("chi2_share", ascending=False).reset_index()


def against_coordinates(result: FitResult) -> pd.DataFrame:
    """Long table of residual components against machine coordinates and time, for the
    'residual against each machine coordinate' plots."""
    o = result.problem.obs
    x = o.r_mm - o.p_mm
    rf = result.residuals_frame()
    rows = []
    for a, comp in enumerate("xyz"):
        rows.append(pd.DataFrame({
            "component": comp, "residual_um": result.residuals_um[:, a],
            "x_mm": x[:, 0], "y_mm": x[:, 1], "z_mm": x[:, 2],
            "hours": o.hours, "position": rf["position"], "probe": rf["probe"],
            "ball": rf["ball"]}))
    return pd.concat(rows, ignore_index=True)


def approach_split(result: FitResult) -> pd.DataFrame:
    """Mean residual of each axis over the balls approached from + and from − along it.

    A backlash (reversal) error shows as a ``reversal_um`` = mean(−) − mean(+) of the sign
    of the span (a reading approached from + is short by half of it) but smaller, since
    the placements and kinematic terms of the fit absorb part of it: this view points at
    the effect; the ``backlash`` block of a fit estimates the span. The standard
    uncertainty is Type A, from the scatter within each group.
    """
    o = result.problem.obs
    rows = []
    for a, comp in enumerate("xyz"):
        r = result.residuals_um[:, a]
        plus, minus = r[o.approach[:, a] > 0], r[o.approach[:, a] < 0]
        row = {"axis": comp, "n_plus": len(plus), "n_minus": len(minus),
               "mean_plus_um": np.nan, "mean_minus_um": np.nan, "reversal_um": np.nan,
               "u_reversal_um": np.nan}
        if len(plus) >= 2 and len(minus) >= 2:
            row.update(mean_plus_um=plus.mean(), mean_minus_um=minus.mean(),
                       reversal_um=minus.mean() - plus.mean(),
                       u_reversal_um=float(np.sqrt(plus.var(ddof=1) / len(plus)
                                                     + minus.var(ddof=1) / len(minus))))
        rows.append(row)
    return pd.DataFrame(rows)


def position_trends(data: Dataset, exclude: Iterable[tuple[str, str, int]] = ()) -> pd.DataFrame:
    """Each position's in-plane scale (ppm) and out-of-plane bowl (µm) against the
    certificate, with standard uncertainties from the least-squares scatter.

    In the plate frame, after a rigid in-plane motion: ``du = s_u·u`` and ``dv = s_v·v``;
    out of plane: a plane plus ``b_uu ξ² + b_uv ξη + b_vv η²`` with ξ, η in [-1, 1] over
    the plate. A scale common to every position points at the certificate or the plate
    temperature; one position's own scale at that placement's axes; a bowl that is present
    only when the plate lies horizontally at sag.
    """
    if data.certificate is None:
        raise ValueError("position trends need a certificate; load one.")
    C = data.certificate.xyz_mm
    ex = {(str(p), str(q), int(b)) for p, q, b in exclude}
    rows = []
    for (pos, probe), _ in data.meas.groupby(["position", "probe"], sort=False):
        T = data.plate_frame_table(pos, probe)
        keep = ~np.isnan(T[:, 0]) & np.array([(pos, probe, int(b)) not in ex
                                              for b in data.certificate.balls])
        c, dv = C[keep], (T - C)[keep] * 1e3
        n = len(c)
        if n < 6:
            continue
        A = np.zeros((2 * n, 5))
        A[:n, 0], A[:n, 2], A[:n, 3] = 1, -c[:, 1], c[:, 0] * 1e-3
        A[n:, 1], A[n:, 2], A[n:, 4] = 1, c[:, 0], c[:, 1] * 1e-3
        b = np.concatenate([dv[:, 0], dv[:, 1]])
        sol, cov, rms_xy = _lsq(A, b)
        centre, half = C.mean(0), np.maximum(np.ptp(C, 0) / 2, 1)
        xi, eta = (c[:, 0] - centre[0]) / half[0], (c[:, 1] - centre[1]) / half[1]
        B = np.column_stack([np.ones(n), xi, eta, xi**2, xi * eta, eta**2])
        zs, zcov, rms_z = _lsq(B, dv[:, 2])
        u = np.sqrt(np.diag(cov))
        uz = np.sqrt(np.diag(zcov))
        rows.append({"position": pos, "probe": probe,
                     "horizontal": data.setup.positions[pos].horizontal,
                     "scale_u_ppm": sol[3], "u_scale_u_ppm": u[3],
                     "scale_v_ppm": sol[4], "u_scale_v_ppm": u[4],
                     "bowl_uu_um": zs[3], "u_bowl_uu_um": uz[3],
                     "bowl_uv_um": zs[4], "u_bowl_uv_um": uz[4],
                     "bowl_vv_um": zs[5], "u_bowl_vv_um": uz[5],
                     "rms_inplane_um": rms_xy, "rms_out_of_plane_um": rms_z})
    return pd.DataFrame(rows)


def _lsq(A, b):
    """Least squares with the covariance scaled by the residual scatter (Type A)."""
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    r = b - A @ sol
    dof = max(len(b) - A.shape[1], 1)
    s2 = r @ r / dof
    return sol, s2 * np.linalg.pinv(A.T @ A), float(np.sqrt(np.mean(r**2)))


def residual_summary(result: FitResult) -> pd.DataFrame:
    """RMS of the residuals (µm) per position and probe and axis."""
    df = result.residuals_frame()
    g = df.groupby(["position", "probe"], sort=False)[["rx_um", "ry_um", "rz_um"]]
    out = g.apply(lambda s: np.sqrt((s**2).mean())).reset_index()
    out.columns = ["position", "probe", "rms_x_um", "rms_y_um", "rms_z_um"]
    return out


def instrument_tables(summary: Iterable[dict], residuals: pd.DataFrame
                  ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The instruments of a joint fit as two tables (app and report alike): per
    instrument its kind, file, readings, rows, χ² and the RMS of the normalised residuals
    (residual / u, near 1 when the model explains the instrument as its u says); and per
    reading its residual (model minus reading, nuisances removed, µm), u and residual / u.
    ``summary``: ``instruments.summary``; ``residuals``: ``instruments.residuals_frame``."""
    per = residuals.assign(z=residuals["residual_um"] / residuals["u_um"])
    # per instrument, not per file name: two runs.csv from different folders are two
    table = pd.DataFrame([{"kind": s["kind"], "file": s["file"], "readings": s["readings"],
                           "rows": s["rows"], "chi2": s["chi2"],
                           "RMS residual/u": s["rms_z"],
                           "RMS residual (µm)": s["rms_um"]} for s in summary])
    readings = per.rename(columns={"residual_um": "residual (µm)", "u_um": "u (µm)",
                                   "z": "residual/u"})
    return table, readings


def uncertainty_gain(joint: FitResult, plate_only: FitResult) -> pd.DataFrame:
    """Per kinematic coefficient its standard uncertainty from the plate alone
    (``plate_only``, a FitResult) and with the instruments (``joint``, the same model, σ
    and selection) and the gain, their ratio (how many times smaller u gets), largest
    first. Units per row: µm or µrad."""
    cols = ["parameter", "unit", "u"]
    a = joint.parameters_frame().query("block == 'kinematic'")[cols]
    b = plate_only.parameters_frame().query("block == 'kinematic'")[cols]
    out = b.merge(a, on=["parameter", "unit"], suffixes=(" plate only", " with instruments"))
    out["gain"] = out["u plate only"] / out["u with instruments"]
    out["unit"] = out["unit"].map(lambda u: str(u).replace("urad", "µrad").replace("um", "µm"))
    return out.sort_values("gain", ascending=False, kind="stable").reset_index(drop=True)


# ---------------------------------------------------------------------------------------
# History, placements
# ---------------------------------------------------------------------------------------

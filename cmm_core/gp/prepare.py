"""Checked, standardised data of a GP fit and hyperparameters in its units.

:func:`_prepare` checks the inputs and observations, resolves the length-scale and noise
groups and the mean's basis, reduces the basis to the columns the data determine (pivoted
QR; R&W §2.7 needs ``H`` of full column rank), and standardises for conditioning: inputs
centred and scaled by one common factor (their extent), outputs by their RMS after the
least-squares basis fit. The :class:`_Context` it returns carries the standardised
:class:`~cmm_core.gp.likelihood._Problem` and the offset that turns its log marginal
likelihood back into data units. :func:`_theta_from` converts readable hyperparameters
(mm, µm) into the standardised log hyperparameters the optimiser works in.

References: Rasmussen & Williams (2006), *Gaussian Processes for Machine Learning*, §2.7
(explicit basis functions), §5.4.1 (marginal likelihood); thesis chapter 5.

See Also
--------
cmm_core.gp : ``fit_gp`` and ``log_marginal_likelihood``, the callers.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from .basis import _as_inputs, _resolve_mean
from .likelihood import _RANK_RTOL, KERNELS, _Problem


class _Context:
    """Standardised data and basis shared by ``fit_gp`` and ``log_marginal_likelihood``."""


def _resolve_groups(groups, kernel, d):
    """Length-scale group of each input: one group (se_iso), one per input (se_ard), or
    as given (labels 0..G-1, every label used)."""
    if groups is None:
        return np.zeros(d, dtype=int) if kernel == "se_iso" else np.arange(d)
    g = np.asarray(groups)
    if g.shape != (d,) or not np.issubdtype(g.dtype, np.integer) or g.min() != 0 \
            or set(g.tolist()) != set(range(int(g.max()) + 1)):
        raise ValueError(f"groups = {list(np.atleast_1d(groups))}: expected one integer "
                         f"label per input ({d}), labels 0, 1, ... each used at least once")
    return g.astype(int)


def _resolve_noise_groups(noise_groups, n):
    g = np.asarray(noise_groups)
    if g.shape != (n,) or not np.issubdtype(g.dtype, np.integer) or g.min() != 0 \
            or set(g.tolist()) != set(range(int(g.max()) + 1)):
        raise ValueError(f"noise_groups has shape {g.shape} and labels "
                         f"{sorted(set(np.ravel(g).tolist()))[:8]}: expected one integer label "
                         f"per point ({n}), labels 0, 1, ... each used at least once")
    return g.astype(int)


def _prepare(X, y, mean, kernel, groups=None, noise_groups=None):
    X = _as_inputs(X, "X")
    y = np.asarray(y, dtype=float)
    if y.ndim == 2 and y.shape[1] == 1:
        y = y[:, 0]
    if y.ndim != 1 or len(y) != len(X):
        raise ValueError(f"y has shape {y.shape}, expected ({len(X)},): one value per row of X")
    if not np.all(np.isfinite(y)):
        raise ValueError("y contains NaN or inf values: expected finite observations "
                         "(drop or impute them before fitting)")
    if kernel not in KERNELS:
        raise ValueError(f"kernel {kernel!r} is unknown: expected one of {KERNELS}")
    n, d = X.shape
    groups = _resolve_groups(groups, kernel, d)
    label, H, names, basis_fn = _resolve_mean(mean, X)
    if not np.all(np.isfinite(H)):
        raise ValueError("the mean's basis contains NaN or inf values at the training points")
    m_user = H.shape[1]

    # basis: column-normalise, pivoted QR, drop what the data cannot determine
    if m_user:
        col = np.linalg.norm(H, axis=0)
        zero = col == 0
        col[zero] = 1.0
        Qf, Rf, piv = sla.qr(H / col, mode="economic", pivoting=True, check_finite=False)
        diag = np.abs(np.diag(Rf))
        r = int(np.sum(diag > _RANK_RTOL * diag[0])) if diag.size and diag[0] > 0 else 0
        keep = np.sort(piv[:r])
        # QR again on the kept columns in their original order (R upper triangular for them)
        Q, R = sla.qr(H[:, keep] / col[keep], mode="economic", check_finite=False)
        col_keep = col[keep]
        dropped = tuple(names[j] for j in range(m_user) if j not in set(keep.tolist()))
    else:
        keep = np.zeros(0, dtype=int)
        Q, R, col_keep, dropped = np.zeros((n, 0)), np.zeros((0, 0)), np.zeros(0), ()
    m = Q.shape[1]
    if n < m + 2:
        raise ValueError(f"{n} points for a mean with {m} determinable basis functions: "
                         f"expected at least {m + 2} (use a simpler mean or more points)")

    centre = X.mean(axis=0)
    extent = float(np.ptp(X, axis=0).max())
    if extent == 0:
        raise ValueError("all input points coincide: expected at least two distinct points")
    x_scale = extent
    Xs = (X - centre) / x_scale
    resid = y - Q @ (Q.T @ y) if m else y
    y_scale = float(np.sqrt(np.mean(resid**2)))
    y_rms = float(np.sqrt(np.mean(y**2)))
    if y_scale <= 1e-12 * y_rms or y_scale == 0:
        y_scale = y_rms or 1.0

    ctx = _Context()
    ctx.__dict__.update(n=n, d=d, m=m, m_user=m_user, label=label, names=names,
                        basis_fn=basis_fn, keep=keep, Q=Q, R=R, col_keep=col_keep,
                        dropped=dropped, extent=extent, x_scale=x_scale, y_scale=y_scale,
                        centre=centre, Xs=Xs, X=X, y=y, groups=groups, kernel=kernel)
    if noise_groups is not None:
        noise_groups = _resolve_noise_groups(noise_groups, n)
    ctx.prob = _Problem(Xs, y / y_scale, Q, groups, noise_groups)
    # log ML in data units = standardised value + offset (undo y scaling and basis scaling)
    logdetR = float(np.log(np.abs(np.diag(R))).sum()) if m else 0.0
    ctx.lml_offset = -(n - m) * np.log(y_scale) - logdetR - float(np.log(col_keep).sum())
    return ctx


_HYPER = ("length_scale_mm", "signal_sd_um", "noise_sd_um")


def _theta_from(hyper: dict, ctx, nl, theta):
    """Standardised log hyperparameters from readable ones (data units)."""
    theta = np.array(theta, dtype=float)
    nn = ctx.prob.n_noise
    units = {"signal_sd_um": ctx.y_scale, "noise_sd_um": ctx.y_scale}
    for k, v in hyper.items():
        if k not in _HYPER:
            raise ValueError(f"hyperparameter {k!r} is unknown: expected one of {_HYPER}")
        v = np.atleast_1d(np.asarray(v, dtype=float))
        if np.any(~np.isfinite(v)) or np.any(v <= 0):
            raise ValueError(f"{k} = {v}: expected positive finite values")
        if k == "length_scale_mm":
            if v.size not in (1, nl):
                raise ValueError(f"length_scale_mm has {v.size} values, expected 1 or {nl}")
            theta[:nl] = np.log(v / ctx.x_scale)
        elif k == "noise_sd_um":
            if v.size not in (1, nn):
                raise ValueError(f"noise_sd_um has {v.size} values, expected 1 or {nn} (one "
                                 "per noise group)")
            theta[nl + 1:] = np.log(v / units[k])
        else:
            if v.size != 1:
                raise ValueError(f"{k} has {v.size} values, expected 1")
            theta[nl] = np.log(v[0] / units[k])
    return theta

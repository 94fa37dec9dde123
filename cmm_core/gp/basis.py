"""Inputs and explicit basis functions of the GP mean (thesis eq. 5.11, R&W §2.7).

The parametric mean of the GP is ``h(x)ᵀβ`` with ``h`` a set of explicit basis functions
whose coefficients β are marginalised under a vague prior (Rasmussen & Williams 2006,
*Gaussian Processes for Machine Learning*, §2.7). This module holds what defines ``h``:

- :func:`polynomial_basis`, the built-in polynomial means (``MEANS``): nothing, a constant,
  a linear or full quadratic polynomial, and thesis eq. 5.11 (``meanMylinear_2D``);
- the checks on an input array (:func:`_as_inputs`) and on a user basis, given as a
  callable ``h(X)`` (:func:`_eval_basis`) or a design matrix (:func:`_resolve_mean`), e.g. a
  kinematic model's Jacobian (thesis chapter 5).

See Also
--------
cmm_core.gp : ``fit_gp``, which uses the basis (the public names are re-exported there).
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np
from numpy.typing import ArrayLike

MEANS = ("zero", "constant", "linear", "quadratic", "thesis_quadratic")
"""Built-in parametric means (explicit basis functions marginalised analytically)."""

_MAX_INPUTS = 6  # ram position and probe offset


def polynomial_basis(X: ArrayLike, kind: str) -> tuple[np.ndarray, tuple[str, ...]]:
    """Design matrix of a built-in polynomial mean, in the units of ``X``.

    Parameters
    ----------
    X : array_like (n, d)
    kind : {"zero", "constant", "linear", "quadratic", "thesis_quadratic"}
        ``quadratic`` is the full quadratic in all inputs (1, x_i, x_i x_j for i <= j);
        ``thesis_quadratic`` is thesis eq. 5.11 exactly (``meanMylinear_2D``:
        a1 + a2 x1 + a3 x1², first input only).

    Returns
    -------
    H : ndarray (n, m)
    names : tuple of str
        Column names, e.g. ``("1", "x1", "x1*x2")``.
    """
    X = np.atleast_2d(np.asarray(X, dtype=float))
    n, d = X.shape
    lab = [f"x{i + 1}" for i in range(d)]
    if kind == "zero":
        return np.zeros((n, 0)), ()
    cols, names = [np.ones(n)], ["1"]
    if kind == "thesis_quadratic":
        return np.column_stack([np.ones(n), X[:, 0], X[:, 0] ** 2]), ("1", "x1", "x1^2")
    if kind in ("linear", "quadratic"):
        cols += [X[:, i] for i in range(d)]
        names += lab
    if kind == "quadratic":
        for i, j in combinations_with_replacement(range(d), 2):
            cols.append(X[:, i] * X[:, j])
            names.append(f"{lab[i]}^2" if i == j else f"{lab[i]}*{lab[j]}")
    if kind not in ("constant", "linear", "quadratic"):
        raise ValueError(f"mean {kind!r} is not a built-in mean: expected one of {MEANS}, a "
                         "callable h(X) -> (n, m) or an (n, m) design matrix")
    return np.column_stack(cols), tuple(names)


def _as_inputs(X, name):
    X = np.asarray(X, dtype=float)
    if X.ndim == 1:
        X = X[:, None]
    if X.ndim != 2 or not 1 <= X.shape[1] <= _MAX_INPUTS:
        raise ValueError(f"{name} has shape {np.shape(X)}, expected (n,) or (n, d) with "
                         f"d = 1 to {_MAX_INPUTS} input coordinates (3 machine coordinates, "
                         "3 more for the probe offset)")
    if not np.all(np.isfinite(X)):
        raise ValueError(f"{name} contains NaN or inf values: expected finite coordinates")
    return X


def _eval_basis(fn, X, m=None):
    H = np.asarray(fn(X), dtype=float)
    if H.ndim == 1:
        H = H[:, None]
    if H.ndim != 2 or H.shape[0] != len(X) or (m is not None and H.shape[1] != m):
        raise ValueError(f"the basis function returned shape {H.shape}, expected "
                         f"({len(X)}, {m if m is not None else 'm'})")
    return H


def _resolve_mean(mean, X):
    """(label, H in data units, names, callable or None)."""
    if isinstance(mean, str):
        H, names = polynomial_basis(X, mean)
        return mean, H, names, (lambda Z, _k=mean: polynomial_basis(Z, _k)[0])
    if callable(mean):
        H = _eval_basis(mean, X)
        return "callable", H, tuple(f"h{j + 1}" for j in range(H.shape[1])), mean
    H = np.asarray(mean, dtype=float)
    if H.ndim == 1:
        H = H[:, None]
    if H.ndim != 2 or H.shape[0] != len(X):
        raise ValueError(f"the mean design matrix has shape {np.shape(mean)}, expected "
                         f"({len(X)}, m): one row per training point")
    return "matrix", H, tuple(f"h{j + 1}" for j in range(H.shape[1])), None

"""The constrained Gauss-Newton step shared by the fit, the diagnosis and the checks.

Constraints ``C x = 0`` are imposed by a QR null space (thesis appendix 2); columns are
scaled so that ``JᵀJ`` has a unit diagonal; the numerical rank of the reduced normal matrix
(relative tolerance ``rank_rtol`` on its singular values) decides which parameter
combinations the data determine. Those it does not are written out by
:func:`describe_null` as a metrologist reads them (``0.50·a − 0.77·b``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

__all__ = ["Normal", "normal_equations", "solve", "describe_null", "signed_sum",
           "surely_determined"]


def normal_equations(J: Any, d: np.ndarray, chunk: int = 30000) -> tuple[np.ndarray, np.ndarray]:
    """``JᵀJ`` and ``Jᵀd`` accumulated over dense row chunks (BLAS), far faster than a
    sparse-sparse product when a dense kinematic block sits in every row."""
    n = J.shape[1]
    N = np.zeros((n, n))
    g = np.zeros(n)
    for i in range(0, J.shape[0], chunk):
        A = J[i:i + chunk]
        A = A.toarray() if sp.issparse(A) else np.asarray(A)
        N += A.T @ A
        g += A.T @ d[i:i + chunk]
    return N, g


class Normal:
    """Constrained, column-scaled normal equations of one linearisation (thesis appendix 2:
    QR null space of the constraints), eigen-decomposed once so that steps for several
    Levenberg-Marquardt dampings cost a matrix-vector product each.

    Parameters
    ----------
    J : sparse or ndarray (m, n)
        Weighted Jacobian.
    d : ndarray (m,)
        Weighted residual.
    C : ndarray (k, n)
        Constraint rows, ``C x = 0``.
    rank_rtol : float
        Singular values below ``rank_rtol`` times the largest count as zero.
    normal : tuple, optional
        ``(JᵀJ, Jᵀd)`` when the caller already has them (holdout: the full problem's
        normal equations minus one placement's rows); ``J`` and ``d`` are then unused.

    Attributes
    ----------
    S : ndarray (n,)
        Column scales.
    Z : ndarray (n, n - rank C)
        Orthonormal basis of the constraints' null space (scaled space).
    null : ndarray (n, j)
        Directions the data do not determine (scaled space).
    rank : int
        Numerical rank of the reduced problem.
    """

    def __init__(self, J: Any, d: np.ndarray | None, C: np.ndarray, rank_rtol: float,
             normal: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        if normal is not None:
            N0, g0 = normal
        elif d is None:
            raise ValueError("Normal needs J and d, or the normal equations")
        else:
            N0, g0 = normal_equations(J, d)
        self.S, self.Z, Nr = _reduced(N0, C)
        lam, V = np.linalg.eigh(Nr)
        lam = np.clip(lam, 0, None)
        sv = np.sqrt(lam)
        keep = sv > rank_rtol * sv.max() if sv.max() > 0 else np.zeros_like(sv, bool)
        self.lam, self.Vk = lam[keep], V[:, keep]
        self.null = self.Z @ V[:, ~keep]
        self.rank = int(keep.sum())
        self.proj_g = self.Vk.T @ (self.Z.T @ (self.S * g0))

    def step(self, mu: float = 0.0) -> np.ndarray:
        """Minimum-norm step; ``mu`` > 0 damps it (scaled space, where JᵀJ has unit
        diagonal): the poorly determined directions shrink first."""
        return -(self.S * (self.Z @ (self.Vk @ (self.proj_g / (self.lam + mu)))))

    def cov(self) -> np.ndarray:
        """Covariance of the parameters (unit-weighted residuals): the pseudo-inverse of
        the reduced normal matrix mapped back to the parameters."""
        ZV = self.Z @ self.Vk
        return (self.S[:, None] * ((ZV / self.lam) @ ZV.T)) * self.S[None, :]

    def freeze_null(self, C: np.ndarray) -> np.ndarray:
        """``C`` with the undetermined directions appended as constraints: what the design
        cannot determine is held (decided once, at the nominal linearisation)."""
        return np.vstack([C, (self.null / self.S[:, None]).T]) if self.null.shape[1] else C


def _reduced(N0, C):
    """Column scales S, null-space basis Z of the scaled constraints and the reduced,
    scaled normal matrix ``Zᵀ S N S Z`` (symmetrised) of :class:`Normal`."""
    n = N0.shape[0]
    norms = np.sqrt(np.clip(np.diag(N0), 0, None))
    S = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
    if C.shape[0]:
        Q, _ = sla.qr((C * S).T)
        Z = Q[:, np.linalg.matrix_rank(C * S):]
    else:
        Z = np.eye(n)
    Nr = Z.T @ (S[:, None] * N0 * S[None, :]) @ Z
    return S, Z, (Nr + Nr.T) / 2


def surely_determined(N0: np.ndarray, C: np.ndarray, rank_rtol: float) -> bool:
    """True when :class:`Normal` of the normal matrix ``N0`` under ``C`` would find no
    undetermined direction, decided without an eigendecomposition: a Cholesky factorisation
    of the reduced matrix minus ``rank_rtol²`` times its trace (which bounds its largest
    eigenvalue), with a 1 % margin, succeeds. False does not mean rank-deficient: ask
    :class:`Normal`."""
    _, _, Nr = _reduced(N0, C)
    shift = 1.01 * rank_rtol**2 * np.trace(Nr)
    if not shift > 0:
        return False
    try:
        np.linalg.cholesky(Nr - shift * np.eye(Nr.shape[0]))
    except np.linalg.LinAlgError:
        return False
    return True


def solve(J: Any, d: np.ndarray | None, C: np.ndarray, rank_rtol: float
      ) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """Minimum-norm Gauss-Newton step under constraints C x = 0. Returns step, covariance,
    rank, null vectors (see :class:`Normal`)."""
    ne = Normal(J, d, C, rank_rtol)
    return ne.step(), ne.cov(), ne.rank, ne.null


def describe_null(null: np.ndarray, labels: Sequence[str], limit: int = 6
              ) -> tuple[list[str], set[str]]:
    """Undetermined combinations written out, and the labels carrying weight in any.

    Returns ``(combos, names)``: one string per null vector with its loadings of at least
    0.2 (of the largest), and the set of labels with a loading of at least 0.05.
    """
    combos: list[str] = []
    names: set[str] = set()
    for j in range(null.shape[1]):
        w = null[:, j] / np.abs(null[:, j]).max()
        idx = np.argsort(-np.abs(w))
        big = [i for i in idx if abs(w[i]) >= 0.2][:limit]
        names.update(labels[i] for i in idx if abs(w[i]) >= 0.05)
        combos.append(signed_sum((w[i], labels[i]) for i in big))
    return combos, names


def signed_sum(terms: Iterable[tuple[float, str]]) -> str:
    """``0.50·a − 0.77·b``: a linear combination written as a metrologist would."""
    out = ""
    for k, (w, lab) in enumerate(terms):
        sign = "−" if w < 0 else "+"
        out += (f"{'−' if w < 0 else ''}{abs(w):.2f}·{lab}" if k == 0
                else f" {sign} {abs(w):.2f}·{lab}")
    return out

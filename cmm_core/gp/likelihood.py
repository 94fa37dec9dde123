"""The GP's covariance and log marginal likelihood with its gradient (R&W §2.7, §5.4.1).

:class:`_Problem` holds the standardised training data of one fit and evaluates, with one
Cholesky factorisation per call, the negative log marginal likelihood of Rasmussen &
Williams (2006), *Gaussian Processes for Machine Learning* (R&W), eq. 2.30, or eq. 2.45
when explicit basis functions are marginalised, and its analytic gradient in the log
hyperparameters (R&W eq. 5.9 with the projected matrix ``P`` of §2.7). The covariance is
the squared exponential of thesis eq. 5.1 (R&W eq. 2.31), isotropic or with one length
scale per group of inputs (ARD, R&W eq. 5.1), plus Gaussian noise, one level per noise
group. :func:`_kinv_lower` gives ``K⁻¹`` for the gradient's traces and the closed-form
leave-one-out predictions (R&W eq. 5.12, in ``cmm_core.gp.result``).

See Also
--------
cmm_core.gp.prepare : builds the problem from the data (standardisation, basis QR).
cmm_core.gp.optimise : maximises the likelihood over the hyperparameters.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack
from scipy.spatial.distance import cdist

KERNELS = ("se_iso", "se_ard")
"""Squared-exponential covariance, isotropic (one length scale) or ARD (one per input)."""

_LOG2PI = np.log(2 * np.pi)
_JITTER_START = 1e-10  # relative to the mean diagonal of K
_JITTER_MAX = 1e-4
_RANK_RTOL = 1e-9  # basis columns with pivoted-QR |R_jj| below this times |R_00| are dropped


class _Problem:
    """Standardised data and the negative log marginal likelihood with its gradient.

    Internal units: ``Xs = (X - centre)/x_scale``, ``ys = y/y_scale``; the basis is the
    orthonormal ``Q`` of a pivoted QR of the column-normalised user basis.
    """

    def __init__(self, Xs, ys, Q, groups, noise_groups=None):
        self.Xs, self.ys, self.Q = Xs, ys, Q
        # noise group of each point (one noise variance per group)
        self.noise_groups = (np.zeros(len(ys), dtype=int) if noise_groups is None
                             else np.asarray(noise_groups, dtype=int))
        self.n_noise = int(self.noise_groups.max()) + 1
        self.groups = np.asarray(groups, dtype=int)
        self.n, self.d = Xs.shape
        self.m = Q.shape[1]
        self.n_groups = int(self.groups.max()) + 1
        # squared distances per length-scale group (G, n, n)
        self.D2 = np.stack([cdist(Xs[:, self.groups == g], Xs[:, self.groups == g],
                                  "sqeuclidean") for g in range(self.n_groups)])
        self.n_jitter = 0
        self.n_eval = 0

    def n_length(self):
        return self.n_groups

    def kernel(self, log_l, sf2):
        if self.n_groups > 1:
            K = np.tensordot(0.5 / np.exp(2 * log_l), self.D2, axes=1)
        else:
            K = self.D2[0] * (0.5 / np.exp(2 * log_l[0]))
        np.negative(K, out=K)
        np.exp(K, out=K)
        K *= sf2
        return K

    def scaled_d2(self, log_l):
        """Σ_g D2_g / l_g²: squared distances in units of the length scales."""
        return np.tensordot(1.0 / np.exp(2 * np.asarray(log_l)), self.D2, axes=1)

    def factor(self, theta):
        """Cholesky factor of K_y (jitter only if it fails) and the basis quantities.

        ``L`` is LAPACK potrf's lower factor with the upper triangle zeroed, so that potri
        on it gives K⁻¹'s lower triangle and zeros (see ``_kinv_lower``).
        """
        nl = self.n_length()
        log_l, sf2, sn2 = theta[:nl], np.exp(2 * theta[nl]), np.exp(2 * theta[nl + 1:])
        Kf = self.kernel(log_l, sf2)
        noise = sn2[self.noise_groups]
        jitter = 0.0
        scale = sf2 + sn2.max()
        while True:
            Ky = Kf.copy()
            Ky.flat[:: self.n + 1] += noise + jitter
            L, info = lapack.dpotrf(Ky, lower=1, clean=1, overwrite_a=1)
            if info == 0:
                break
            new = _JITTER_START * scale if jitter == 0 else 10 * jitter
            if new > _JITTER_MAX * scale:
                return None
            jitter = new
        if jitter:
            self.n_jitter += 1
        a0 = sla.cho_solve((L, True), self.ys, check_finite=False)
        st = {"L": L, "Kf": Kf, "sf2": sf2, "sn2": sn2, "log_l": log_l, "jitter": jitter}
        if self.m:
            KiQ = sla.cho_solve((L, True), self.Q, check_finite=False)
            A = self.Q.T @ KiQ
            try:
                LA, _ = sla.cho_factor(A, lower=True, check_finite=False)
            except sla.LinAlgError:
                return None
            beta = sla.cho_solve((LA, True), self.Q.T @ a0, check_finite=False)
            alpha = a0 - KiQ @ beta
            logdetA = 2 * np.log(np.diag(LA)).sum()
            # P = K⁻¹ - WᵀW (R&W §2.7): the basis part of the projected matrix, never formed
            W = sla.solve_triangular(LA, KiQ.T, lower=True, check_finite=False)
            st.update(KiQ=KiQ, LA=LA, beta=beta, logdetA=logdetA, W=W)
        else:
            alpha, logdetA = a0, 0.0
            st.update(beta=np.zeros(0), logdetA=0.0, W=None)
        st["alpha"] = alpha
        st["lml"] = (-0.5 * self.ys @ alpha - np.log(np.diag(L)).sum() - 0.5 * logdetA
                     - 0.5 * (self.n - self.m) * _LOG2PI)
        return st

    def p_diag(self, st, T):
        """diag(P) from K⁻¹'s lower triangle ``T``."""
        d = np.diag(T).copy()
        if st["W"] is not None:
            d -= np.einsum("ki,ki->i", st["W"], st["W"])
        return d

    def trace_p(self, st, T, G):
        """tr(P G) for a symmetric G, from K⁻¹'s lower triangle ``T`` (upper zero)."""
        t = 2 * np.vdot(T, G) - np.dot(np.diag(T), np.diag(G))
        if st["W"] is not None:
            t -= np.vdot(st["W"] @ G, st["W"])
        return t

    def objective(self, theta):
        """Negative log marginal likelihood and its gradient in log hyperparameters.

        ∂ log p/∂θ_j = ½ αᵀ ∂K_j α - ½ tr(P ∂K_j), α = P y (R&W eq. 5.9 with P). One
        Cholesky factorisation serves both; K⁻¹ for the traces is LAPACK potri on the
        factor in place (its lower triangle only: a third of cho_solve's flops with the
        identity, and no n×n symmetrisation).
        """
        self.n_eval += 1
        st = self.factor(theta)
        if st is None:
            return 1e25, np.zeros_like(theta)
        alpha, Kf = st["alpha"], st["Kf"]
        T = _kinv_lower(st.pop("L"), overwrite=True)
        if T is None:
            return 1e25, np.zeros_like(theta)
        nl = self.n_length()
        g = np.empty_like(theta)
        for i in range(nl):
            G = self.D2[i] * Kf  # ∂K/∂log l_i times l_i²
            g[i] = 0.5 * (alpha @ (G @ alpha) - self.trace_p(st, T, G)) / np.exp(
                2 * st["log_l"][i])
        g[nl] = alpha @ (Kf @ alpha) - self.trace_p(st, T, Kf)  # ∂K/∂log σ_f = 2 K_f
        g[nl + 1:] = st["sn2"] * np.bincount(self.noise_groups,
                                             weights=alpha**2 - self.p_diag(st, T),
                                             minlength=self.n_noise)
        return -st["lml"], -g

    def subset(self, idx):
        """The same problem on the points ``idx`` (same standardisation), or None when the
        subset does not determine the basis or misses a noise group."""
        groups = self.noise_groups[idx]
        if np.unique(groups).size != self.n_noise:
            return None
        Q = self.Q[idx]
        if self.m:
            Q, R = np.linalg.qr(Q)
            dg = np.abs(np.diag(R))
            if dg.min() <= _RANK_RTOL * dg.max():
                return None
        sub = object.__new__(_Problem)
        sub.__dict__.update(self.__dict__)
        sub.Xs, sub.ys, sub.Q, sub.noise_groups = self.Xs[idx], self.ys[idx], Q, groups
        sub.n = len(idx)
        sub.D2 = self.D2[:, idx][:, :, idx]
        sub.n_jitter = sub.n_eval = 0
        return sub


def _kinv_lower(L, overwrite=False):
    """Lower triangle of K⁻¹ (upper triangle zero) from the clean lower factor ``L``, by
    LAPACK potri; None if it fails (a zero on the factor's diagonal)."""
    T, info = lapack.dpotri(L, lower=1, overwrite_c=overwrite)
    return T if info == 0 else None

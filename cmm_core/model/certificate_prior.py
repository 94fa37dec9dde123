"""The certificate's own uncertainty in a fit with the certificate fixed.

With the plate fixed to its certificate (thesis §4.5.1) the certificate's calibration
errors land in the residuals of every placement alike: they are not repeatability. Two
numbers must count them:

- the **χ² test**: the statistic is the generalised least-squares χ² of the fixed model,
  whose residual covariance is σ²I plus the certificate's, reached as the χ² of the same
  model with the certificate as a prior weighted by its uncertainty (one Gauss-Newton
  step from the fixed solution: the model is linear in the plate coordinates);
- the **parameters' covariance**: the fixed fit's estimate is ``δ = -C Jᵀ r`` (``C`` its
  constrained inverse of ``JᵀJ``, weighted units); with ``r = e + J_c ε``, ``e`` the
  probing noise and ``ε`` the certificate's errors (µm, covariance ``D = diag(u_cert²)``)
  seen through the plate columns ``J_c``, its covariance is the sandwich
  ``C + C (Jᵀ J_c) D (J_cᵀ J) C`` (GUM: the certificate is an input quantity whose
  uncertainty propagates through the fit). Without it the uncertainties of a fit with
  the certificate fixed are those of a perfect certificate: on simulated thesis layouts
  with certificate u = σ/5 the coefficients' mean z² was 1.06-1.34 instead of 1.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .blocks.plate import Plate
from .hole_plate import is_hole_plate
from .normal import _normal_columns, _plate_cross
from .problem import Problem, held_constraints, weighted_residual
from .solver import Normal
from .state import State

if TYPE_CHECKING:
    from .result import FitResult

__all__ = ["certificate_terms", "held_prior_rows"]


def _cert_u_um(prob: Problem) -> np.ndarray:
    """The certificate's standard uncertainties (B, 3) µm; a plate prior needs them."""
    if prob.obs.cert_u_um is None:
        raise ValueError("the observations have no certificate uncertainties")
    return prob.obs.cert_u_um


def certificate_terms(prob: Problem, state: State, design_null: np.ndarray, sigma_um: float,
                      rank_rtol: float, cov: np.ndarray,
                      normal: tuple[float, np.ndarray, np.ndarray, int] | None = None
                      ) -> tuple[float, int, np.ndarray, np.ndarray]:
    """``(χ² test statistic, its dof, covariance, sensitivity)`` of a fit with the
    certificate fixed, the covariance with the certificate's uncertainty propagated, and
    the parameters' sensitivity to the certificate's errors in units of their standard
    uncertainty (``S = C Jᵀ J_c diag(u)``, parameters × 3 per ball: the certificate's part
    of the covariance is ``S Sᵀ``; two fits with one certificate share ``S₁ S₂ᵀ``).

    Parameters
    ----------
    prob : problem.Problem
        The fixed-plate problem, ``state`` its solution, ``design_null`` the combinations
        its design left undetermined (held), ``cov`` its σ-only covariance.
    normal : tuple, optional
        ``(cost, JᵀJ, Jᵀr, rows)``: the fixed problem's weighted normal equations at
        ``state``, when the fit has them. The prior problem's then differ only in its plate
        columns (the residuals are the same at the certificate): those are computed
        (``normal._normal_columns``) and the rest is taken from these, instead of a second
        accumulation over every column.
    """

    pp = Problem(prob.obs, prob.spec, "prior")
    st = state.relabelled(prob.layout.labels, pp.layout.labels)
    if normal is not None and not is_hole_plate(prob.obs):
        cost, N, g, n_rows = _prior_normal_equations(prob, pp, state, st, sigma_um,
                                                             normal)
    else:
        _, cost, N, g, n_rows = pp.normal_equations(st, sigma_um)
    C = pp.constraints()
    if design_null.size:
        C = np.vstack([C, held_constraints(prob.layout.labels, design_null, pp)])
    ne = Normal(None, None, C, rank_rtol, normal=(N, g))
    s = ne.step()
    chi2 = float(cost + 2 * g @ s + s @ N @ s)  # |r + J s|² from the normal equations
    dof = int(n_rows - ne.rank - held_prior_rows(pp))
    # the cross block Jᵀ J_c of the prior problem's normal equations (prior rows touch
    # only the plate columns): the fixed parameters against the plate coordinates (µm)
    col = {lab: i for i, lab in enumerate(pp.layout.labels)}
    rows = np.array([col[lab] for lab in prob.layout.labels])
    plate = pp.layout.blocks["plate"]
    G = N[np.ix_(rows, np.arange(plate.start, plate.stop))]
    u2 = np.nan_to_num(_cert_u_um(prob).ravel() ** 2, posinf=0.0)  # released: no value
    CG = cov @ G
    S = CG * np.sqrt(u2)
    return chi2, dof, cov + S @ S.T, S


def _prior_normal_equations(prob, pp, state, st, sigma_um, normal):
    """``(cost, JᵀJ, Jᵀr, rows)`` of the prior problem ``pp`` at ``st`` from the fixed
    problem's ``normal`` at the same point: every column but the plate's is the fixed
    problem's (same residuals, same Jacobian), the plate columns are computed, and the
    prior rows ``(c - c_cert)/u`` (zero at the certificate) are added."""
    cost, Nf, gf, rows = normal
    col = {lab: i for i, lab in enumerate(pp.layout.labels)}
    fixed = np.array([col[lab] for lab in prob.layout.labels], dtype=int)
    s = pp.layout.blocks["plate"]
    pc = np.arange(s.start, s.stop)
    kept = _plate_cross(prob, state)
    if kept is not None:  # from the fit's last accumulation, at this state
        G, gc, Ncc = kept
        Nc = np.zeros((pp.layout.n, pc.size))
        Nc[fixed] = G
        Nc[pc] = Ncc
    else:  # blocks along the placements (runs of the data), not the balls
        Nc, gc = _normal_columns(pp, st, sigma_um, pc, key=prob.obs.pos)
    N, g = np.zeros((pp.layout.n,) * 2), np.zeros(pp.layout.n)
    N[np.ix_(fixed, fixed)] = Nf
    N[:, pc] = Nc
    N[pc, :] = Nc.T
    g[fixed] = gf
    g[pc] = gc
    rp, Jp = pp.block(Plate).prior_rows(st, True)
    Jp = Jp.toarray()
    return (float(cost + rp @ rp), N + Jp.T @ Jp, g + Jp.T @ rp, int(rows + rp.size))


def residual_u_um(result: FitResult, chunk: int = 30000) -> np.ndarray:
    """Standard uncertainty (µm, (n, 3)) the certificate's errors add to each residual of
    a fit with the certificate fixed (zeros otherwise): the residual ``r = (I - J C Jᵀ)
    (e + J_c ε)`` (weighted) carries, besides the noise's ``σ²(1 - h_ii)``, the
    certificate's ``Σ_j [(J_c - J C Jᵀ J_c)_ij]² u_j²``. Computed when asked (the
    residual checks of the app), from the sparse Jacobian a chunk of rows at a time."""
    prob = result.problem
    if result.covariance_noise is None:
        return np.zeros((prob.n_obs, 3))

    pp = Problem(prob.obs, prob.spec, "prior")
    st = result.state.relabelled(prob.layout.labels, pp.layout.labels)
    J = weighted_residual(pp, st, result.sigma_um, True)[2][: 3 * prob.n_obs].tocsc()
    col = {lab: i for i, lab in enumerate(pp.layout.labels)}
    plate = pp.layout.blocks["plate"]
    Jp = J[:, [col[lab] for lab in prob.layout.labels]].tocsr()
    Jc = J[:, plate.start:plate.stop].tocsr()
    CG = np.nan_to_num(result.covariance_noise) @ (Jp.T @ Jc).toarray()
    u2 = np.nan_to_num(_cert_u_um(prob).ravel() ** 2, posinf=0.0)
    var = np.empty(Jc.shape[0])
    for i in range(0, var.size, chunk):
        R = Jc[i:i + chunk].toarray() - Jp[i:i + chunk] @ CG
        var[i:i + chunk] = (R**2) @ u2
    return (np.sqrt(var) * result.sigma_um).reshape(-1, 3)


def held_prior_rows(prob: Problem) -> int:
    """Certificate-prior rows that are zero whatever the data: the plate's gauge
    constraints (translations, rotations, scale) hold the plate's deviation from the
    certificate at zero along those modes, so those prior rows carry no residual and no
    degree of freedom (clean simulations: mean χ² equals dof only with them removed)."""
    if prob.plate != "prior":
        return 0
    plate = prob.block(Plate)
    assert plate is not None  # a prior plate is a Plate block (Plate.wanted)
    G = prob.instruments.plate_gauge(plate, plate.constraints())  # as the fit applies it
    keep = np.isfinite(_cert_u_um(prob).ravel())
    return int(np.linalg.matrix_rank(G[:, keep])) if keep.any() else 0

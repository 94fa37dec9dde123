"""A hole plate: only the in-plane coordinates of each probed centre are observed.

A hole plate's features are holes probed from inside. A hole's centre comes from probing
the cylinder at a depth the operator chooses, so only its two coordinates in the plate's
plane are properties of the artefact; its coordinate along the hole axis (the plate
normal) is the probing height, not a property of the plate. The fit therefore uses only the
in-plane part of each observation's residual (setup ``"artefact": "hole_plate"``,
``docs/formats.md``): with ``n_i`` the plate normal of the observation's placement in
machine axes (the third column of the placement rotation ``R_k``, which turns with the
placement),

    d_i' = P_i d_i,   P_i = I - n_i n_iᵀ                                             (1)

so the residual along the normal is dropped from χ², the Jacobian (``P_i J_i`` plus the
turning of ``n_i`` with the placement rotation) and the degrees of freedom (two rows per
observation). ``d_i'`` keeps the machine-frame shape (n, 3) of every other residual: the
residual tables, plots and leverages need no change. Equivalently, each observation gets a
free offset along the hole axis (its probing height), eliminated exactly.

What the plane cannot see is held by gauge constraints instead of being reported as
undetermined: the tilt of each placement out of its plane (its two rotations about
in-plane axes) and its translation along the normal (``blocks.placement``), and, for a
self-calibrated or prior plate, the hole coordinates along the normal
(``blocks.plate``). The placements start at the setup's nominal tilt (an error ``θ`` of it
changes in-plane coordinates by ``θ² L / 2``), with their in-plane rotation and
translation fitted to the measured centres, so the data's normal coordinates enter
nowhere but the kinematic model's evaluation point.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .fit_state import State
from .geometry import skew
from .units import URAD

__all__ = ["is_hole_plate", "in_plane", "initial_state", "normal_equations", "ROUNDING"]

ROUNDING = 1e-12
"""Jacobian entries below this share of its largest are set to zero: the rounding residue
of the projection (exact zeros, ~1e-16) and real entries too small to change any result (a
residual of 1e-6 µm turning with the normal, ``URAD`` per µrad)."""


def is_hole_plate(obs) -> bool:
    """Whether the observations are of a hole plate (setup ``artefact``)."""
    return getattr(obs, "artefact", "ball_plate") == "hole_plate"


def in_plane(prob, state, d, J):
    """Eq. 1: the residuals ``d`` (µm, (n, 3)) without their component along each
    placement's plate normal, and the Jacobian ``J`` (CSR, (3n, N)) of those, or None.

    The normal turns with the placement rotation (``blocks.placement``: ``R <- exp(w) R``,
    ``w`` in µrad), which adds ``[(n·d) [n]× + n (d × n)ᵀ] URAD`` to the rotation columns
    (µm per µrad: negligible beside the data, kept so the Jacobian is exact)."""
    o = prob.obs
    n = state.R[o.pos][:, :, 2]
    along = np.einsum("ni,ni->n", n, d)
    out = d - n * along[:, None]
    if J is None:
        return out, None
    m = len(d)
    P = np.eye(3) - n[:, :, None] * n[:, None, :]
    PJ = sp.bsr_matrix((P, np.arange(m), np.arange(m + 1)), shape=(3 * m, 3 * m)) @ J
    turn = (along[:, None, None] * skew(n)
            + n[:, :, None] * np.cross(d, n)[:, None, :]) * URAD
    cols = prob.layout.blocks["rotation"].start + 3 * o.pos[:, None, None] + np.arange(3)
    rows = 3 * np.arange(m)[:, None, None] + np.arange(3)[:, None]
    extra = sp.csr_matrix((turn.ravel(), (np.broadcast_to(rows, turn.shape).ravel(),
                                          np.broadcast_to(cols, turn.shape).ravel())),
                          shape=J.shape)
    J = (PJ + extra).tocsr()
    # What the projection removes exactly (a hole's normal coordinate, a placement's
    # normal translation) is left at rounding level, 1e-16 of the Jacobian: as columns of
    # that norm the solver would scale them by 1e16 and lose its rank decisions
    J.data[np.abs(J.data) < ROUNDING * np.abs(J.data).max(initial=0.0)] = 0.0
    J.eliminate_zeros()
    return out, J


def initial_state(prob):
    """Starting state of a hole plate: the nominal plate, and each placement at the setup's
    nominal tilt with its in-plane rotation and translation fitted to the measured centres
    (2-D Procrustes in the nominal plate frame; the normal translation is the mean normal
    coordinate, which no residual sees)."""
    o = prob.obs
    R = np.empty((prob.P, 3, 3))
    t = np.empty((prob.P, 3))
    for k in range(prob.P):
        sel = o.pos == k
        local = (o.r_mm[sel] - o.t0_mm[k]) @ o.R0[k]  # nominal plate frame
        c = o.plate0_mm[o.ball[sel]]
        a, b = c[:, :2] - c[:, :2].mean(0), local[:, :2] - local[:, :2].mean(0)
        phi = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]),
                         np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
        cs, sn = np.cos(phi), np.sin(phi)
        Rz = np.array([[cs, -sn, 0.0], [sn, cs, 0.0], [0.0, 0.0, 1.0]])
        shift = local.mean(0) - Rz @ c.mean(0)
        R[k], t[k] = o.R0[k] @ Rz, o.t0_mm[k] + o.R0[k] @ shift
    return State(o.plate0_mm.copy(), R, t, np.zeros(prob.layout.n))


def normal_equations(prob, state, sigma_um: float):
    """Weighted normal equations of a hole plate (``fit.Problem.normal_equations``): from
    the assembled, projected Jacobian of ``fit.weighted_residual`` (the blocked
    accumulation of ``normal`` evaluates the blocks' unprojected Jacobians), with two
    rows per observation counted."""
    from .fit import weighted_residual
    from .normal import NormalEquations

    d, r, J = weighted_residual(prob, state, sigma_um, True)
    N = (J.T @ J).toarray()
    return NormalEquations(d, float(r @ r), N, J.T @ r, r.size - prob.n_obs)

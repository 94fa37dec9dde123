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
(``blocks.plate``). Since the tilt is held where it starts, it must start right: an error
``θ`` of it shortens the in-plane coordinates along the tilt by ``θ²/2`` (2 µm per metre
at 2 mrad), which the fit would absorb as a machine scale error with χ² passing. Each
placement therefore starts in the least-squares plane of its own measured centres
(:func:`measured_normal`; the setup's when within 0.1 mrad of it), with its in-plane
rotation and translation fitted to them.
That plane is the plate's only if every hole of a placement was probed at the same depth
below the surface (the assumption: one probing depth per placement; holes probed 0.3 mm
deeper at one edge of a 500 mm plate tilt it by 0.6 mrad, 0.2 µm per metre in length).
The machine's own errors along the normal tilt the measured plane by their slopes (tens
of µrad), whose square is negligible. :func:`tilt_note` says when the measured plane is
far from the setup's. Beyond that the data's normal coordinates enter nowhere but the
kinematic model's evaluation point.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from ..machine import skew
from ..units import URAD
from .state import State

__all__ = ["is_hole_plate", "in_plane", "initial_state", "measured_normal", "tilt_note",
           "ROUNDING", "TILT_NOTE_RAD", "TILT_USE_RAD"]

ROUNDING = 1e-12
"""Jacobian entries below this share of its largest are set to zero: the rounding residue
of the projection (exact zeros, ~1e-16) and real entries too small to change any result (a
residual of 1e-6 µm turning with the normal, ``URAD`` per µrad)."""

TILT_USE_RAD = 1e-4
"""A measured plane within this of the setup's normal is not used: the nominal tilt then
shortens in-plane lengths by at most ``θ²/2`` = 0.005 µm per metre (negligible), and
such angles are within the slopes the machine's own errors give the measured plane. A
start off the setup's normal by a few µrad would also let the errors along the normal
leak into the in-plane residuals at that level, and the rank check would name them (and
the in-plane functions they mimic) undetermined where nothing is gained."""

TILT_NOTE_RAD = 3e-4
"""A measured plane this far from the setup's normal is named in the fit message: the
nominal tilt would have shortened in-plane lengths by ``θ²/2`` = 0.045 µm per metre, about
the uncertainty of a well-determined scale."""


def is_hole_plate(obs: object) -> bool:
    """Whether the observations are of a hole plate (setup ``artefact``)."""
    return getattr(obs, "artefact", "ball_plate") == "hole_plate"


def in_plane(prob: Any, state: State, d: np.ndarray, J: Any) -> tuple[np.ndarray, Any]:
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


def measured_normal(r_mm: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """Unit normal of the least-squares plane through the points ``r_mm`` ((m, 3), mm),
    on the side of ``nominal``; ``nominal`` itself when that plane is within
    :data:`TILT_USE_RAD` of it, or when the points span no plane (fewer
    than three, or all on one line: the smallest two singular values within 1e-6 of each
    other relative to the largest)."""
    r = np.asarray(r_mm, float)
    if len(r) < 3:
        return nominal
    s, vt = np.linalg.svd(r - r.mean(0), full_matrices=False)[1:]
    if s[1] <= 1e-6 * s[0]:
        return nominal
    n = vt[2] if vt[2] @ nominal >= 0 else -vt[2]
    return n if np.linalg.norm(np.cross(n, nominal)) > TILT_USE_RAD else nominal


def _turn(a, b):
    """The rotation by the smallest angle that takes unit vector ``a`` to ``b``."""
    axis = np.cross(a, b)
    sn, cs = np.linalg.norm(axis), float(a @ b)
    if sn < 1e-15:
        return np.eye(3)
    K = skew((axis / sn)[None])[0]
    return np.eye(3) + sn * K + (1 - cs) * K @ K


def initial_state(prob: Any) -> State:
    """Starting state of a hole plate: the nominal plate, and each placement tilted into
    the plane of its measured centres (:func:`measured_normal`: the in-plane residuals
    never see the tilt, which is then held), with its in-plane rotation and translation
    fitted to them (2-D Procrustes in that plane; the normal translation is the mean
    normal coordinate, which no residual sees)."""
    o = prob.obs
    R = np.empty((prob.P, 3, 3))
    t = np.empty((prob.P, 3))
    for k in range(prob.P):
        sel = o.pos == k
        n0 = o.R0[k][:, 2]
        Rb = _turn(n0, measured_normal(o.r_mm[sel], n0)) @ o.R0[k]
        local = (o.r_mm[sel] - o.t0_mm[k]) @ Rb  # plate frame in the measured plane
        c = o.plate0_mm[o.ball[sel]]
        a, b = c[:, :2] - c[:, :2].mean(0), local[:, :2] - local[:, :2].mean(0)
        phi = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]),
                         np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
        cs, sn = np.cos(phi), np.sin(phi)
        Rz = np.array([[cs, -sn, 0.0], [sn, cs, 0.0], [0.0, 0.0, 1.0]])
        shift = local.mean(0) - Rz @ c.mean(0)
        R[k], t[k] = Rb @ Rz, o.t0_mm[k] + Rb @ shift
    return State(o.plate0_mm.copy(), R, t, np.zeros(prob.layout.n))


def tilt_note(prob: Any, state: State) -> str:
    """A sentence for the fit message naming the placements whose plane (the normal of
    ``state``, held from :func:`initial_state`) is more than :data:`TILT_NOTE_RAD` from the
    setup's normal, or "" (also for a ball plate)."""
    o = prob.obs
    if not is_hole_plate(o):
        return ""
    cos = np.einsum("ki,ki->k", state.R[:, :, 2], o.R0[:, :, 2])
    ang = np.arccos(np.clip(cos, -1.0, 1.0))
    far = [(p, a) for p, a in zip(o.positions, ang, strict=True) if a > TILT_NOTE_RAD]
    if not far:
        return ""
    worst = max(a for _, a in far)
    named = ", ".join(f"{p} {a * 1e3:.1f} mrad" for p, a in far)
    return (f" The hole plate's measured plane differs from the setup's orientation "
            f"({named}): each placement's tilt was taken from the plane of its measured "
            f"centres, since with the setup's tilt in-plane lengths would be short by "
            f"θ²/2, up to {worst ** 2 / 2 * 1e3:.2g} µm per metre, and read as a machine "
            "scale error. Check the setup's u_axis and v_axis, and that every hole of a "
            "placement was probed at the same depth.")

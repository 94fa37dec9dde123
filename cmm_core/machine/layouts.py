"""Kinematic chains of the machine layouts other than the moving bridge FXYZ.

A layout's chain (``kinematics.LAYOUTS``) lists the three carriages from the workpiece to
the probe with ``F`` for the foundation: carriages right of ``F`` carry the probe, each
riding on the one before it; carriages left of ``F`` move the table, and with it the
workpiece. ``docs/layouts.md`` derives the model and states the sign conventions.

With the tool carriages ``a1 .. ak`` (foundation to probe) and the table carriages
``b1 .. bm`` (foundation to workpiece), exact rotations, the modelled tip centre is

    P   = U_a1 + R_a1 [ U_a2 + R_a2 [ ... U_ak + R_ak p ] ]                    (L1)
    v_0 = P,   v_j = R_bj^T ( v_(j-1) + V_bj ),   x*(x, p) = v_m                 (L2)

    U_a = a e_a + d_a + s_a     (the tool carriage's reference point in its parent)
    V_b = b e_b + s_b - d_b     (minus the table's reference point in the foundation)

with ``d_a = (d_ax, d_ay, d_az)`` the carriage's translational errors, ``R_a = Rz Ry Rx``
of its rotations ``(r_ax, r_ay, r_az)`` and ``s_a`` its squareness terms (``sxy*y`` in x
for the y carriage; ``sxz*z`` in x and ``syz*z`` in y for the z carriage). A table's
errors are its own motion in the foundation frame: they enter with the opposite sign, and
its rotations act about the table's reference point on the lever ``v_(j-1) + V_bj``, which
holds the table's own coordinate. Squareness is a property of the measured axes and
enters with the same sign in every layout. For the chain ``Fxyz``, (L1) is thesis eq. 4.13
(``kinematics._forward_block``, which the default layout keeps using).

Shapes follow ``kinematics``: vectors (3, m), rotations (3, 3, m); ``None`` stands for the
identity (a product over no carriage).
"""

from __future__ import annotations

import numpy as np

from ..units import UM, URAD
from .terms import AXES, SQUARENESS, KinematicTerms, _dmv, _Evaluation, _mm, _mv

__all__ = ["split_chain", "forward_block", "probe_rotation"]


def split_chain(chain: str) -> tuple[str, str]:
    """``(table, tool)`` carriages of a chain, each listed from the foundation outwards:
    ``split_chain("xFyz") == ("x", "yz")``, ``split_chain("Fxzy") == ("", "xzy")``."""
    f = chain.index("F")
    return chain[:f][::-1], chain[f + 1:]


def _t(M):
    """Transpose per point of a (3, 3, m) rotation, or the identity (None)."""
    return None if M is None else M.transpose(1, 0, 2)


def _mv_t(M, v):
    """``M^T v`` per point, without forming the transpose."""
    out = M[0] * v[0]
    out += M[1] * v[1]
    out += M[2] * v[2]
    return out


def _compose(A, B):
    """Matrix product per point; None is the identity."""
    if A is None:
        return B
    if B is None:
        return A
    return _mm(A, B)


def _apply(M, v):
    """``M v`` per point; None is the identity."""
    return v if M is None else _mv(M, v)


def _column(M, c, m):
    """Column ``c`` of ``M`` (3, m); of the identity when M is None."""
    if M is not None:
        return M[:, c].copy()
    out = np.zeros((3, m))
    out[c] = 1.0
    return out


def _d_rotation(R, ang, comp):
    """``∂R/∂angle_comp`` as a (3, 3, m) array, column by column (``kinematics._dmv``)."""
    m = R.shape[-1]
    out = np.empty_like(R)
    for k in range(3):
        out[:, k] = _dmv(R, ang, comp, _column(None, k, m))
    return out


def _offsets(v, x_mm):
    """Nominal motion ``a e_a``, translational errors ``d_a`` and squareness ``s_a`` of each
    carriage, (3, m) arrays in mm. Squareness values are angle x coordinate (µrad mm)."""
    m = x_mm.shape[0]
    zero = np.zeros(m)
    nominal, d = {}, {}
    for i, a in enumerate(AXES):
        nominal[a] = np.zeros((3, m))
        nominal[a][i] = x_mm[:, i]
        d[a] = np.stack([v[f"d{a}{c}"] for c in AXES]) * UM
    s = {"x": np.zeros((3, m)), "y": np.stack([v["sxy"] * URAD, zero, zero]),
         "z": np.stack([v["sxz"] * URAD, v["syz"] * URAD, zero])}
    return nominal, d, s


def _squareness_axis(name):
    """Carriage and direction of a squareness term: sxy -> (y, x), sxz -> (z, x), syz ->
    (z, y)."""
    return ("y", 0) if name == "sxy" else ("z", 0 if name == "sxz" else 1)


def forward_block(terms: KinematicTerms, sl: dict[str, slice], coef: np.ndarray,
              x_mm: np.ndarray, p_mm: np.ndarray, xs_out: np.ndarray,
              J_out: np.ndarray | None) -> None:
    """Eq. (L1)-(L2) on one block of points: fills ``xs_out`` (m, 3) in mm and, when given,
    ``J_out`` (m, 3, terms.n), d x*/d coefficient in mm per µm or µrad.

    Jacobian (chain rule through (L1)-(L2)): with ``H_b`` = d x*/d v_b (the transposed
    rotations of the table carriages nearer the workpiece than b), ``G = d x*/dP`` and
    ``Q_a`` the product of the tool rotations between the foundation and carriage a,

    - tool carriage a: d/d(d_a) = G Q_a, d/dθ = G Q_a (∂R_a/∂θ) (lever of a);
    - table carriage b: d/d(d_b) = -H_b R_b^T, d/dθ = H_b (∂R_b/∂θ)^T (v_(j-1) + V_b);
    - squareness: the translational column of its carriage with a plus sign.
    """
    table, tool = split_chain(terms.chain)
    m = x_mm.shape[0]
    ev = _Evaluation(terms, coef, x_mm)
    R = ev.R
    nominal, d, s = _offsets(ev.values, x_mm)
    lever, P = {}, p_mm.T
    for a in reversed(tool):  # (L1), from the probe back to the foundation
        lever[a] = P
        P = nominal[a] + d[a] + s[a] + _mv(R[a], P)
    arm, X = {}, P
    for b in table:  # (L2), from the foundation to the workpiece
        arm[b] = X + nominal[b] + s[b] - d[b]
        X = _mv_t(R[b], arm[b])
    xs_out[:] = X.T
    if J_out is None:
        return
    H: dict[str, np.ndarray | None] = {}
    HV: dict[str, np.ndarray | None] = {}
    acc: np.ndarray | None = None
    for b in reversed(table):
        H[b] = acc
        acc = _compose(acc, _t(R[b]))
        HV[b] = acc  # d x*/d V_b = H_b R_b^T
    G, acc = acc, None
    TU: dict[str, np.ndarray | None] = {}
    for a in tool:
        TU[a] = _compose(G, acc)  # d x*/d U_a = G Q_a
        acc = _compose(acc, R[a])
    for name, _ in terms.functions:
        D = ev.designs[name]
        if name in SQUARENESS:
            ax, c = _squareness_axis(name)
            col = _column(HV[ax] if ax in table else TU[ax], c, m) * URAD
        elif name[0] == "d":
            ax, c = name[1], AXES.index(name[2])
            col = (-UM * _column(HV[ax], c, m) if ax in table
                   else UM * _column(TU[ax], c, m))
        else:
            ax, c = name[1], AXES.index(name[2])
            if ax in table:
                dR = _d_rotation(R[ax], ev.angles[ax], c)
                col = _apply(H[ax], _mv_t(dR, arm[ax]))
            else:
                col = _apply(TU[ax], _dmv(R[ax], ev.angles[ax], c, lever[ax]))
            col *= URAD
        for k in range(3):
            for j in range(D.shape[1]):
                np.multiply(col[k], D[:, j], out=J_out[:, k, sl[name].start + j])


def probe_rotation(chain: str, R: dict[str, np.ndarray]) -> np.ndarray:
    """``d x*/d p`` of a chain, (3, 3, m): the table rotations transposed (workpiece first)
    times the tool rotations (foundation first)."""
    table, tool = split_chain(chain)
    out = None
    for b in reversed(table):
        out = _compose(out, _t(R[b]))
    for a in tool:
        out = _compose(out, R[a])
    return out if out is not None else np.broadcast_to(
        np.eye(3)[:, :, None], (3, 3, next(iter(R.values())).shape[-1])).copy()

"""The 21-error kinematic model of a moving-bridge FXYZ CMM (thesis eq. 4.1-4.9, 4.13).

Conventions (docs/formats.md): the modelled tip centre for scale readings
``x = (x, y, z)`` and probe offset ``p`` is

    x*(x, p) = xx(x) + Rx(x) [ xy(y) + Ry(y) [ xz(z) + Rz(z) p ] ]

with ``xx = (x + dxx, dxy, dxz)``, ``xy = (dyx + sxy*y, y + dyy, dyz)``,
``xz = (dzx + sxz*z, dzy + syz*z, z + dzz)`` and ``Ra = Rz(r_az) Ry(r_ay) Rx(r_ax)``. The
reported tip is ``r = x + p`` and the error is ``e = x* - (x + p)``; the true point is
``r + e``.

Units: coordinates in mm; translational coefficients in µm; rotational and squareness
coefficients in µrad. Every error function is a Chebyshev series in its own axis
coordinate mapped from ``[0, range]`` to ``[-1, 1]``, zero at the axis origin; straightness
functions carry no linear term (thesis appendix 2 constraints made explicit).

Other machine layouts (:data:`LAYOUTS`, ``KinematicTerms.layout``) stack the same three
carriages in another order, and a carriage that moves the table (the workpiece) enters
inverted: see ``layouts`` and ``docs/layouts.md``. The moving bridge FXYZ above
is the default and is evaluated by the code below unchanged.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..units import UM, URAD
from .layouts import forward_block, probe_rotation
from .terms import (
    SQUARENESS,
    KinematicTerms,
    _Evaluation,
    _mm,
    _mv,
    _to_rows,
    direction_of,
)

__all__ = ["model_point", "error", "jacobian", "probe_jacobian", "invert"]


def model_point(terms: KinematicTerms, coef: ArrayLike, x_mm: ArrayLike,
            p_mm: ArrayLike) -> np.ndarray:
    """Modelled tip centre ``x*(x, p)`` in mm (thesis eq. 4.13), exact rotations.

    Parameters
    ----------
    terms : KinematicTerms
    coef : array (terms.n,)
        Kinematic coefficients (µm, µrad).
    x_mm, p_mm : arrays (n, 3)
        Scale readings and probe offsets in mm, machine axes.

    ``coef`` may also be ``(n, terms.n)``: one coefficient set per point, which evaluates
    many draws of the coefficients at once (Monte Carlo).
    """
    return _forward(terms, np.asarray(coef, float), np.asarray(x_mm, float),
                    np.asarray(p_mm, float))[0]


def error(terms: KinematicTerms, coef: ArrayLike, x_mm: ArrayLike, p_mm: ArrayLike
      ) -> np.ndarray:
    """Kinematic error ``e = x* - (x + p)`` in µm, shape (n, 3)."""
    x_mm = np.asarray(x_mm, float)
    p_mm = np.asarray(p_mm, float)
    return (model_point(terms, coef, x_mm, p_mm) - x_mm - p_mm) / UM


# Points per block of ``_forward``: the block's temporaries and its rows of J (a few MB)
# stay in cache; filling a 10^5-point J in one pass was 3× slower (bench/fit.py).
_BLOCK = 8192


def _forward(terms, coef, x_mm, p_mm, want_jac=False, scale=1.0):
    """x*(x, p) (n, 3) and, if asked, J (n, 3, terms.n), computed by blocks of points.

    J is a view of a coefficient-major ``(3, terms.n, n)`` array: a function's column is
    written as rows of contiguous points (a (n, 3, k) layout wrote 1-2 numbers per inner
    loop, 65 ns a number), and the normal equations take ``Jᵀ J`` per component from it
    with no copy (``normal.accumulate``)."""
    n = x_mm.shape[0]
    p_mm = np.broadcast_to(p_mm, (n, 3))
    xs = np.empty((n, 3))
    J = np.empty((3, terms.n, n)).transpose(2, 0, 1) if want_jac else None
    sl = terms.slices
    for lo in range(0, n, _BLOCK):
        b = slice(lo, min(lo + _BLOCK, n))
        args = (terms, sl, coef[b] if coef.ndim == 2 else coef, x_mm[b], p_mm[b], xs[b],
                None if J is None else J[b])
        if terms.chain == "Fxyz":
            _forward_block(*args, scale=scale)
        else:
            forward_block(*args)
            if J is not None and scale != 1.0:
                J[b] *= scale
    return xs, J


def _forward_block(terms, sl, coef, x_mm, p_mm, xs_out, J_out, scale=1.0):
    """One block of ``_forward``: fills ``xs_out`` (m, 3) and ``J_out`` (m, 3, terms.n),
    the latter times ``scale``."""
    ev = _Evaluation(terms, coef, x_mm)
    v = ev.values
    x, y, z = x_mm.T
    p = p_mm.T
    X = np.stack([x + v["dxx"] * UM, v["dxy"] * UM, v["dxz"] * UM])
    # Squareness values are already angle x coordinate (µrad mm): see ``basis``.
    Y = np.stack([v["dyx"] * UM + v["sxy"] * URAD, y + v["dyy"] * UM, v["dyz"] * UM])
    Z = np.stack([v["dzx"] * UM + v["sxz"] * URAD, v["dzy"] * UM + v["syz"] * URAD,
                  z + v["dzz"] * UM])
    Rx, Ry, Rz = ev.R["x"], ev.R["y"], ev.R["z"]
    Rz_p = _mv(Rz, p)
    A = Z + Rz_p
    Ry_A = _mv(Ry, A)
    B = Y + Ry_A
    Rx_B = _mv(Rx, B)
    np.add(X, Rx_B, out=xs_out.T)
    if J_out is None:
        return
    # d x*/d coefficient, mm per unit coefficient: chain rule through the axis stack. A
    # function's columns are (its direction, (3, m)) times (its design, (m, k)), written
    # in one broadcast product. A rotation R = Rz(c) Ry(b) Rx(a) of a vector w turns
    # under its angles as d(R w) = ω × (R w) with ω = R e_x, Rz e_y, e_z for a, b, c
    # (each rotation commutes with the cross product by its own axis), so the three
    # angles of an axis cost three cross products of one rotated vector.
    RxRy = _mm(Rx, Ry)
    Jt = J_out.transpose(1, 2, 0)  # (3, terms.n, m): rows of contiguous points
    designs = {}  # each basis transposed once: (k, m), rows of contiguous points
    for key in {id(D): D for D in ev.designs.values()}.values():
        designs[id(key)] = np.ascontiguousarray(key.T)
    designs = {nm: designs[id(D)] for nm, D in ev.designs.items()}
    turned = {"x": (None, Rx_B), "y": (Rx, Ry_A), "z": (RxRy, Rz_p)}
    for name, _ in terms.functions:
        D = designs[name]
        if name in SQUARENESS:
            k = 0 if name in ("sxy", "sxz") else 1
            col = (Rx if name == "sxy" else RxRy)[:, k] * (URAD * scale)
        elif name[0] == "d":
            ax, comp = name[1], direction_of(name)
            if ax == "x":
                # the x carriage's translations act along the machine axes themselves
                s = sl[name]
                Jt[:, s] = 0.0
                np.multiply(D, UM * scale, out=Jt[comp, s])
                continue
            col = (Rx if ax == "y" else RxRy)[:, comp] * (UM * scale)
        else:
            ax, comp = name[1], direction_of(name)
            outer, w = turned[ax]
            col = _cross(_omega(ev.R[ax], ev.angles[ax], comp), w)
            if outer is not None:
                col = _mv(outer, col)
            col *= URAD * scale
        np.multiply(col[:, None, :], D[None, :, :], out=Jt[:, sl[name]])


def _omega(R, ang, comp):
    """Axis of the rotation that angle ``comp`` of ``R = Rz(c) Ry(b) Rx(a)`` adds,
    ``d(R w) = ω × (R w)``: ``R e_x``, ``Rz(c) e_y`` or ``e_z``, shape (3, m) or (3, 1)."""
    if comp == 0:
        return R[:, 0]
    if comp == 1:
        c = ang[2]
        return np.stack([-np.sin(c), np.cos(c), np.zeros_like(c)])
    return np.array([[0.0], [0.0], [1.0]])


def _cross(a, b):
    """a × b for (3, m) arrays (or a (3, 1) one)."""
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def jacobian(terms: KinematicTerms, coef: ArrayLike, x_mm: ArrayLike, p_mm: ArrayLike,
             *, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Model point and its analytic Jacobian.

    Returns
    -------
    xs_mm : array (n, 3)
        ``x*(x, p)`` in mm.
    J : array (n, 3, terms.n)
        ``d x* / d coef`` in mm per coefficient unit (µm or µrad); a view of a
        coefficient-major ``(3, terms.n, n)`` array (``np.ascontiguousarray`` gives rows);
        times ``scale`` when given (``1 / UM``: µm per coefficient unit, written once
        instead of a second pass over J).
    """
    return _forward(terms, np.asarray(coef, float), np.asarray(x_mm, float),
                    np.asarray(p_mm, float), want_jac=True, scale=float(scale))


def probe_jacobian(terms: KinematicTerms, coef: ArrayLike, x_mm: ArrayLike) -> np.ndarray:
    """``d x* / d p`` at the scale readings, shape (n, 3, 3): Rx Ry Rz on the moving
    bridge FXYZ, the chain's rotations for other layouts (``layouts``)."""
    ev = _Evaluation(terms, np.asarray(coef, float), np.asarray(x_mm, float),
                     rotations_only=True)
    if terms.chain != "Fxyz":
        return _to_rows(probe_rotation(terms.chain, ev.R))
    return _to_rows(_mm(_mm(ev.R["x"], ev.R["y"]), ev.R["z"]))


def invert(terms: KinematicTerms, coef: ArrayLike, s_mm: ArrayLike, p_mm: ArrayLike,
       iterations: int = 6) -> np.ndarray:
    """Scale readings ``x`` at which the CMM reaches true tip ``s``: solve x*(x, p) = s.

    Fixed-point iteration ``x <- x + (s - x*(x, p))``; the map is a contraction because the
    errors change by parts per million across the volume, so a few steps reach 1e-12 mm.
    """
    s_mm = np.asarray(s_mm, float)
    p_mm = np.asarray(p_mm, float)
    x = s_mm - p_mm
    for _ in range(iterations):
        x = x + (s_mm - model_point(terms, coef, x, p_mm))
    return x

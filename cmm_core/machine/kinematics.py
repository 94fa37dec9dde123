"""The 21-error kinematic model of a moving-bridge FXYZ CMM (thesis eq. 4.1-4.9, 4.13).

Conventions (SPEC "The kinematic model"): the modelled tip centre for scale readings
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
inverted: see ``kinematics_layouts`` and ``docs/layouts.md``. The moving bridge FXYZ above
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
    _dmv,
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
_BLOCK = 4096


def _forward(terms, coef, x_mm, p_mm, want_jac=False):
    """x*(x, p) (n, 3) and, if asked, J (n, 3, terms.n), computed by blocks of points."""
    n = x_mm.shape[0]
    p_mm = np.broadcast_to(p_mm, (n, 3))
    xs = np.empty((n, 3))
    J = np.empty((n, 3, terms.n)) if want_jac else None
    sl = terms.slices
    block = _forward_block
    if terms.chain != "Fxyz":
        block = forward_block
    for lo in range(0, n, _BLOCK):
        b = slice(lo, min(lo + _BLOCK, n))
        block(terms, sl, coef[b] if coef.ndim == 2 else coef, x_mm[b], p_mm[b],
              xs[b], None if J is None else J[b])
    return xs, J


def _forward_block(terms, sl, coef, x_mm, p_mm, xs_out, J_out):
    """One block of ``_forward``: fills ``xs_out`` (m, 3) and ``J_out`` (m, 3, terms.n)."""
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
    A = Z + _mv(Rz, p)
    B = Y + _mv(Ry, A)
    xs_out[:] = (X + _mv(Rx, B)).T
    if J_out is None:
        return
    # d x*/d coefficient, mm per unit coefficient: chain rule through the axis stack. Each
    # function's columns are (its direction, (3, m)) × (its design, (m, k)); they are
    # written one (component, coefficient) column at a time, a loop over the m points.
    RxRy = _mm(Rx, Ry)
    for name, _ in terms.functions:
        D = ev.designs[name]
        ax, comp = (None, None) if name in SQUARENESS else (name[1], direction_of(name))
        if name in SQUARENESS:
            k = 0 if name in ("sxy", "sxz") else 1
            col = (Rx if name == "sxy" else RxRy)[:, k] * URAD
        elif name[0] == "d" and ax == "x":
            # the x carriage's translations act along the machine axes themselves
            J_out[:, :, sl[name]] = 0.0
            np.multiply(D, UM, out=J_out[:, comp, sl[name]])
            continue
        elif name[0] == "d":
            col = (Rx if ax == "y" else RxRy)[:, comp] * UM
        else:
            if ax == "x":
                col = _dmv(Rx, ev.angles["x"], comp, B)
            elif ax == "y":
                col = _mv(Rx, _dmv(Ry, ev.angles["y"], comp, A))
            else:
                col = _mv(RxRy, _dmv(Rz, ev.angles["z"], comp, p))
            col *= URAD
        for c in range(3):
            for j in range(D.shape[1]):
                np.multiply(col[c], D[:, j], out=J_out[:, c, sl[name].start + j])


def jacobian(terms: KinematicTerms, coef: ArrayLike, x_mm: ArrayLike, p_mm: ArrayLike
         ) -> tuple[np.ndarray, np.ndarray]:
    """Model point and its analytic Jacobian.

    Returns
    -------
    xs_mm : array (n, 3)
        ``x*(x, p)`` in mm.
    J : array (n, 3, terms.n)
        ``d x* / d coef`` in mm per coefficient unit (µm or µrad).
    """
    return _forward(terms, np.asarray(coef, float), np.asarray(x_mm, float),
                    np.asarray(p_mm, float), want_jac=True)


def probe_jacobian(terms: KinematicTerms, coef: ArrayLike, x_mm: ArrayLike) -> np.ndarray:
    """``d x* / d p`` at the scale readings, shape (n, 3, 3): Rx Ry Rz on the moving
    bridge FXYZ, the chain's rotations for other layouts (``kinematics_layouts``)."""
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

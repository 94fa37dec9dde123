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

import difflib
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import chebyshev as C

from .units import UM, URAD

AXES = "xyz"
POSITIONING = ("dxx", "dyy", "dzz")
STRAIGHTNESS = ("dxy", "dxz", "dyx", "dyz", "dzx", "dzy")
TRANSLATIONAL = ("dxx", "dxy", "dxz", "dyx", "dyy", "dyz", "dzx", "dzy", "dzz")
ROTATIONAL = ("rxx", "rxy", "rxz", "ryx", "ryy", "ryz", "rzx", "rzy", "rzz")
SQUARENESS = ("sxy", "sxz", "syz")
ERROR_NAMES = TRANSLATIONAL + ROTATIONAL + SQUARENESS

LAYOUTS = {
    "moving_bridge_fxyz": "Fxyz",
    "moving_bridge_fyxz": "Fyxz",
    "fixed_bridge_xfyz": "xFyz",
    "fixed_bridge_yfxz": "yFxz",
    "gantry_fxyz": "Fxyz",
    "gantry_fyxz": "Fyxz",
    "horizontal_arm_fxzy": "Fxzy",
    "horizontal_arm_fyzx": "Fyzx",
}
"""Machine layouts (``machine.layout``) and their kinematic chains, read from the workpiece
to the probe: axes left of ``F`` (the foundation) move the table, axes right of it carry
the probe, each riding on the one before it. ``xFyz``: the table moves in x, the y
carriage runs across a fixed bridge and carries the z ram. A gantry has the chain of the
moving bridge of the same axis order; its name records the machine. See
``docs/layouts.md`` for the conventions."""
DEFAULT_LAYOUT = "moving_bridge_fxyz"


def check_layout(layout: str) -> str:
    """The layout's chain; an unknown name raises ValueError listing the known ones."""
    if layout in LAYOUTS:
        return LAYOUTS[layout]
    close = difflib.get_close_matches(str(layout), list(LAYOUTS), n=1, cutoff=0.5)
    raise ValueError(f"machine layout {str(layout)[:60]!r} is not a known kinematic chain"
                     + (f" (did you mean {close[0]!r}?)" if close else "")
                     + f"; expected one of: {', '.join(LAYOUTS)}.")


def axis_of(name: str) -> int:
    """Index of the axis whose coordinate an error function depends on (squareness: y or z)."""
    if name in SQUARENESS:
        return 1 if name == "sxy" else 2
    return AXES.index(name[1])


def direction_of(name: str) -> int:
    """Index of the direction a translational error acts in, or the rotation axis."""
    return AXES.index(name[2])


def n_coefficients(name: str, order: int) -> int:
    """Number of coefficients of one error function at a polynomial order (0 = absent)."""
    if order <= 0:
        return 0
    if name in SQUARENESS:
        return 1
    if name in STRAIGHTNESS:
        return max(order - 1, 0)
    return order


def basis(name: str, u_mm: np.ndarray, order: int, stroke_mm: float) -> np.ndarray:
    """Chebyshev basis of one error function, shape ``(n, n_coefficients)``.

    Positioning and rotation functions use ``T_j(s) - T_j(-1)``, j = 1..order, so they are
    zero at the axis origin. Straightness functions use ``T_j(s)`` minus the chord through
    its values at both ends of the stroke, j = 2..order: zero at both ends, so their linear
    part (squareness or frame orientation, SPEC) is not duplicated. Squareness is the axis
    coordinate itself in mm (the coefficient is an angle in µrad).
    """
    u = np.asarray(u_mm, dtype=float)
    k = n_coefficients(name, order)
    if k == 0:
        return np.zeros((u.size, 0))
    if name in SQUARENESS:
        return u.reshape(-1, 1).copy()
    s = 2.0 * u / stroke_mm - 1.0
    V = C.chebvander(s, order)  # columns T_0..T_order
    if name in STRAIGHTNESS:
        j = np.arange(2, order + 1)
        lo = (-1.0) ** j
        chord = np.outer((1 - s) / 2, lo) + np.outer((1 + s) / 2, np.ones_like(lo))
        return V[:, 2:] - chord
    return V[:, 1:] - (-1.0) ** np.arange(1, order + 1)


def periodic_basis(u_mm: np.ndarray, period_mm: float) -> np.ndarray:
    """Periodic positioning term ``sin(2πu/λ)``, ``cos(2πu/λ) - 1``: zero at the axis
    origin like every function, shape ``(n, 2)`` (coefficients in µm)."""
    a = 2 * np.pi * np.asarray(u_mm, dtype=float) / float(period_mm)
    return np.column_stack([np.sin(a), np.cos(a) - 1.0])


@dataclass(frozen=True)
class KinematicTerms:
    """Which of the 21 error functions are in a model, and at which order.

    Attributes
    ----------
    orders : tuple of (str, int)
        ``(name, order)`` for every function present, in ``ERROR_NAMES`` order.
    range_mm : tuple of float
        Axis strokes (x, y, z) in mm over which the Chebyshev series are defined.
    periods : tuple of (str, float)
        ``(positioning function, period mm)``: a periodic scale error added to ``dxx``,
        ``dyy`` or ``dzz`` (two coefficients, sine and cosine, µm), e.g. from a lead screw
        or a rack. Empty by default.
    layout : str
        Machine layout, a key of :data:`LAYOUTS` (default the moving bridge FXYZ); it fixes
        the order of the carriages in the chain and which one moves the table.
    """

    orders: tuple
    range_mm: tuple
    periods: tuple = ()
    layout: str = DEFAULT_LAYOUT

    def __post_init__(self):
        check_layout(self.layout)

    @property
    def chain(self) -> str:
        """Kinematic chain of the layout, e.g. ``Fxyz`` or ``xFyz`` (see :data:`LAYOUTS`)."""
        return LAYOUTS[self.layout]

    @property
    def functions(self) -> tuple:
        """``(name, order)`` of every function with coefficients (order 0 when a
        positioning function carries only its periodic term), ``ERROR_NAMES`` order."""
        od, per = dict(self.orders), dict(self.periods)
        return tuple((n, od.get(n, 0)) for n in ERROR_NAMES if od.get(n, 0) > 0 or n in per)

    def n_of(self, name: str) -> int:
        """Number of coefficients of one function (polynomial and periodic)."""
        return (n_coefficients(name, dict(self.orders).get(name, 0))
                + 2 * (name in dict(self.periods)))

    @property
    def slices(self) -> dict:
        """Coefficient slice of each function in the kinematic coefficient vector."""
        out, i = {}, 0
        for name, _ in self.functions:
            k = self.n_of(name)
            out[name] = slice(i, i + k)
            i += k
        return out

    @property
    def n(self) -> int:
        """Total number of kinematic coefficients."""
        return sum(self.n_of(nm) for nm, _ in self.functions)

    @property
    def labels(self) -> list:
        """One label per coefficient, e.g. ``dxx[1]`` (Chebyshev degree in brackets),
        ``dxx[sin200]`` / ``dxx[cos200]`` for a periodic term of period 200 mm."""
        out, per = [], dict(self.periods)
        for name, order in self.functions:
            if name in SQUARENESS:
                out.append(name)
                continue
            first = 2 if name in STRAIGHTNESS else 1
            out += [f"{name}[{j}]" for j in range(first, order + 1)]
            if name in per:
                out += [f"{name}[sin{per[name]:g}]", f"{name}[cos{per[name]:g}]"]
        return out

    def unit(self, label: str) -> str:
        """Unit of a coefficient: µm for translational, µrad for rotations and squareness."""
        return "um" if label.startswith("d") else "urad"

    def design(self, name: str, u_mm: np.ndarray) -> np.ndarray:
        """Basis matrix of one function at axis coordinates ``u_mm``."""
        order = dict(self.orders).get(name, 0)
        D = basis(name, u_mm, order, self.range_mm[axis_of(name)])
        per = dict(self.periods)
        if name in per:
            D = np.hstack([D, periodic_basis(u_mm, per[name])])
        return D


# Rotations are kept as nine component arrays (3, 3, n), never as a stack of n 3×3
# matrices: numpy's batched matmul on (n, 3, 3) runs a tiny 3×3 product per point and was
# 70 % of a 10^5-point fit (bench/fit.py), while a product of component arrays is 27 vector
# multiply-adds over n. Every quantity below is a (3, n) or (3, 3, n) array.


def _rot_zyx(a, b, c):
    """R = Rz(c) Ry(b) Rx(a), exact, in closed form: shape (3, 3, n)."""
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    R = np.empty((3, 3) + np.shape(a))
    R[0, 0], R[0, 1], R[0, 2] = cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa
    R[1, 0], R[1, 1], R[1, 2] = sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa
    R[2, 0], R[2, 1], R[2, 2] = -sb, cb * sa, cb * ca
    return R


def _mv(M, v):
    """Matrix-vector product per point: (3, 3, n) × (3, n) -> (3, n)."""
    out = M[:, 0] * v[0]
    out += M[:, 1] * v[1]
    out += M[:, 2] * v[2]
    return out


def _mm(A, B):
    """Matrix product per point: (3, 3, n) × (3, 3, n) -> (3, 3, n)."""
    out = np.empty(np.broadcast_shapes(A.shape, B.shape))
    for k in range(3):
        out[:, k] = _mv(A, B[:, k])
    return out


def _cross(axis, v):
    """e_axis × v for a (3, n) array v."""
    out = np.zeros_like(v)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    out[i], out[j] = -v[j], v[i]
    return out


def _dmv(R, ang, comp, v):
    """(∂R/∂angle_comp) v for R = Rz Ry Rx with angles ``ang`` = (a, b, c).

    ∂(Rz Ry Rx)/∂a = R [e_x]×, ∂/∂c = [e_z]× R and ∂/∂b = Rz [e_y]× Ry Rx (each rotation
    commutes with the cross product by its own axis), so no derivative matrix is formed.
    """
    if comp == 0:
        return _mv(R, _cross(0, v))
    if comp == 2:
        return _cross(2, _mv(R, v))
    a, b, c = ang
    ca, sa, cc, sc = np.cos(a), np.sin(a), np.cos(c), np.sin(c)
    w = np.stack([v[0], ca * v[1] - sa * v[2], sa * v[1] + ca * v[2]])  # Rx v
    cb, sb = np.cos(b), np.sin(b)
    w = np.stack([cb * w[0] + sb * w[2], w[1], -sb * w[0] + cb * w[2]])  # Ry Rx v
    w = _cross(1, w)
    return np.stack([cc * w[0] - sc * w[1], sc * w[0] + cc * w[1], w[2]])  # Rz (...)


class _Evaluation:
    """Error functions and rotation matrices of the three axes at the observation points."""

    def __init__(self, terms: KinematicTerms, coef: np.ndarray, xyz_mm: np.ndarray,
                 rotations_only: bool = False):
        n = xyz_mm.shape[0]
        sl = terms.slices
        wanted = ROTATIONAL if rotations_only else ERROR_NAMES
        self.designs = {nm: terms.design(nm, xyz_mm[:, axis_of(nm)])
                        for nm, _ in terms.functions if nm in wanted}
        self.values = {}
        for name in wanted:
            if name in sl and coef.ndim == 2:  # one coefficient set per point (Monte Carlo)
                self.values[name] = np.einsum("nk,nk->n", self.designs[name], coef[:, sl[name]])
            elif name in sl:
                self.values[name] = self.designs[name] @ coef[sl[name]]
            else:
                self.values[name] = np.zeros(n)
        v = self.values
        self.angles = {ax: [v[f"r{ax}{c}"] * URAD for c in AXES] for ax in AXES}
        self.R = {ax: _rot_zyx(*self.angles[ax]) for ax in AXES}


def _to_rows(M):
    """(3, 3, n) -> (n, 3, 3), contiguous, for the public results."""
    return np.ascontiguousarray(np.moveaxis(M, -1, 0))


def model_point(terms: KinematicTerms, coef, x_mm, p_mm):
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


def error(terms: KinematicTerms, coef, x_mm, p_mm):
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
        from .kinematics_layouts import forward_block as block
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


def jacobian(terms: KinematicTerms, coef, x_mm, p_mm):
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


def probe_jacobian(terms: KinematicTerms, coef, x_mm):
    """``d x* / d p`` at the scale readings, shape (n, 3, 3): Rx Ry Rz on the moving
    bridge FXYZ, the chain's rotations for other layouts (``kinematics_layouts``)."""
    ev = _Evaluation(terms, np.asarray(coef, float), np.asarray(x_mm, float),
                     rotations_only=True)
    if terms.chain != "Fxyz":
        from .kinematics_layouts import probe_rotation
        return _to_rows(probe_rotation(terms.chain, ev.R))
    return _to_rows(_mm(_mm(ev.R["x"], ev.R["y"]), ev.R["z"]))


def invert(terms: KinematicTerms, coef, s_mm, p_mm, iterations: int = 6):
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

"""The kinematic model's vocabulary: error names, machine layouts, Chebyshev error terms
and their evaluation at points (thesis eq. 4.1-4.9; ``kinematics`` composes them into the
forward model, ``layouts`` into the other layouts' chains).

Units: coordinates in mm; translational coefficients in µm; rotational and squareness
coefficients in µrad.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.polynomial import chebyshev as C

from ..units import URAD

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


def basis(name: str, u_mm: np.ndarray, order: int, stroke_mm: float, *,
          vander: np.ndarray | None = None) -> np.ndarray:
    """Chebyshev basis of one error function, shape ``(n, n_coefficients)``.

    Positioning and rotation functions use ``T_j(s) - T_j(-1)``, j = 1..order, so they are
    zero at the axis origin. Straightness functions use ``T_j(s)`` minus the chord through
    its values at both ends of the stroke, j = 2..order: zero at both ends, so their linear
    part (squareness or frame orientation, docs/formats.md) is not duplicated. Squareness is the axis
    coordinate itself in mm (the coefficient is an angle in µrad).

    ``vander``: ``chebvander(2 u / stroke - 1, K)`` for some K >= order, when the caller
    has it (the functions of one axis share it); its first columns are this order's.
    """
    u = np.asarray(u_mm, dtype=float)
    k = n_coefficients(name, order)
    if k == 0:
        return np.zeros((u.size, 0))
    if name in SQUARENESS:
        return u.reshape(-1, 1).copy()
    s = 2.0 * u / stroke_mm - 1.0
    V = C.chebvander(s, order) if vander is None else vander[:, :order + 1]  # T_0..T_order
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

    def __post_init__(self) -> None:
        check_layout(self.layout)

    @property
    def chain(self) -> str:
        """Kinematic chain of the layout, e.g. ``Fxyz`` or ``xFyz`` (see :data:`LAYOUTS`)."""
        return LAYOUTS[self.layout]

    @cached_property
    def functions(self) -> tuple:
        """``(name, order)`` of every function with coefficients (order 0 when a
        positioning function carries only its periodic term), ``ERROR_NAMES`` order."""
        od, per = dict(self.orders), dict(self.periods)
        return tuple((n, od.get(n, 0)) for n in ERROR_NAMES if od.get(n, 0) > 0 or n in per)

    @cached_property
    def _order_of(self) -> dict:
        """``orders`` as a dict (every lookup of the evaluation uses it)."""
        return dict(self.orders)

    @cached_property
    def _period_of(self) -> dict:
        """``periods`` as a dict."""
        return dict(self.periods)

    def n_of(self, name: str) -> int:
        """Number of coefficients of one function (polynomial and periodic)."""
        return (n_coefficients(name, self._order_of.get(name, 0))
                + 2 * (name in self._period_of))

    @cached_property
    def slices(self) -> dict:
        """Coefficient slice of each function in the kinematic coefficient vector."""
        out, i = {}, 0
        for name, _ in self.functions:
            k = self.n_of(name)
            out[name] = slice(i, i + k)
            i += k
        return out

    @cached_property
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

    def design_key(self, name: str) -> tuple:
        """What :meth:`design` depends on besides the points: functions with the same key
        have the same basis matrix (every rotation of an axis at one order, say)."""
        kind = ("s" if name in SQUARENESS else "t" if name in STRAIGHTNESS else "p")
        return (axis_of(name), kind, self._order_of.get(name, 0),
                self._period_of.get(name))

    def design(self, name: str, u_mm: np.ndarray, *, vander: np.ndarray | None = None
               ) -> np.ndarray:
        """Basis matrix of one function at axis coordinates ``u_mm`` (``vander``: see
        :func:`basis`)."""
        order = self._order_of.get(name, 0)
        D = basis(name, u_mm, order, self.range_mm[axis_of(name)], vander=vander)
        per = self._period_of
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
        # one basis matrix per distinct (axis, kind, order, period): the functions of an
        # axis share it (21 functions, at most 9 bases at one order)
        by_key: dict = {}
        self.designs = {}
        top: dict[int, int] = {}  # highest Chebyshev order of each axis: one Vandermonde matrix per axis
        for nm, order in terms.functions:
            if nm in wanted and nm not in SQUARENESS:
                top[axis_of(nm)] = max(top.get(axis_of(nm), 0), order)
        vander = {a: C.chebvander(2.0 * xyz_mm[:, a] / terms.range_mm[a] - 1.0, k)
                  for a, k in top.items()}
        for nm, _ in terms.functions:
            if nm in wanted:
                key = terms.design_key(nm)
                if key not in by_key:
                    by_key[key] = terms.design(nm, xyz_mm[:, key[0]],
                                               vander=vander.get(key[0]))
                self.designs[nm] = by_key[key]
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

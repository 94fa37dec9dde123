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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import chebyshev as C

AXES = "xyz"
POSITIONING = ("dxx", "dyy", "dzz")
STRAIGHTNESS = ("dxy", "dxz", "dyx", "dyz", "dzx", "dzy")
TRANSLATIONAL = ("dxx", "dxy", "dxz", "dyx", "dyy", "dyz", "dzx", "dzy", "dzz")
ROTATIONAL = ("rxx", "rxy", "rxz", "ryx", "ryy", "ryz", "rzx", "rzy", "rzz")
SQUARENESS = ("sxy", "sxz", "syz")
ERROR_NAMES = TRANSLATIONAL + ROTATIONAL + SQUARENESS

UM = 1e-3  # mm per µm
URAD = 1e-6  # rad per µrad


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
    """

    orders: tuple
    range_mm: tuple
    periods: tuple = ()

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


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([o, z, z, z, c, -s, z, s, c], -1).reshape(*np.shape(a), 3, 3)


def _rot_y(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([c, z, s, z, o, z, -s, z, c], -1).reshape(*np.shape(a), 3, 3)


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([c, -s, z, s, c, z, z, z, o], -1).reshape(*np.shape(a), 3, 3)


def _drot(a, which):
    """Derivative of an elementary rotation matrix with respect to its angle."""
    c, s = np.cos(a), np.sin(a)
    z = np.zeros_like(a)
    if which == 0:
        m = [z, z, z, z, -s, -c, z, c, -s]
    elif which == 1:
        m = [-s, z, c, z, z, z, -c, z, -s]
    else:
        m = [-s, -c, z, c, -s, z, z, z, z]
    return np.stack(m, -1).reshape(*np.shape(a), 3, 3)


class _Evaluation:
    """Error functions and rotation matrices of one axis at the observation points."""

    def __init__(self, terms: KinematicTerms, coef: np.ndarray, xyz_mm: np.ndarray):
        n = xyz_mm.shape[0]
        sl = terms.slices
        self.designs = {nm: terms.design(nm, xyz_mm[:, axis_of(nm)])
                        for nm, _ in terms.functions}
        self.values = {}
        for name in ERROR_NAMES:
            if name in sl and coef.ndim == 2:  # one coefficient set per point (Monte Carlo)
                self.values[name] = np.einsum("nk,nk->n", self.designs[name], coef[:, sl[name]])
            elif name in sl:
                self.values[name] = self.designs[name] @ coef[sl[name]]
            else:
                self.values[name] = np.zeros(n)
        v = self.values
        self.angles = {}
        self.R = {}
        for ax in AXES:
            ang = [v[f"r{ax}x"] * URAD, v[f"r{ax}y"] * URAD, v[f"r{ax}z"] * URAD]
            self.angles[ax] = ang
            Rx, Ry, Rz = _rot_x(ang[0]), _rot_y(ang[1]), _rot_z(ang[2])
            self.R[ax] = (Rz @ Ry @ Rx, (Rx, Ry, Rz))


def _mv(M, v):
    return np.einsum("nij,nj->ni", M, v)


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


def _forward(terms, coef, x_mm, p_mm, want_jac=False):
    ev = _Evaluation(terms, coef, x_mm)
    v = ev.values
    n = x_mm.shape[0]
    x, y, z = x_mm.T
    X = np.stack([x + v["dxx"] * UM, v["dxy"] * UM, v["dxz"] * UM], 1)
    # Squareness values are already angle x coordinate (µrad mm): see ``basis``.
    Y = np.stack([v["dyx"] * UM + v["sxy"] * URAD, y + v["dyy"] * UM, v["dyz"] * UM], 1)
    Z = np.stack([v["dzx"] * UM + v["sxz"] * URAD, v["dzy"] * UM + v["syz"] * URAD,
                  z + v["dzz"] * UM], 1)
    Rx, Ry, Rz = ev.R["x"][0], ev.R["y"][0], ev.R["z"][0]
    A = Z + _mv(Rz, p_mm)
    B = Y + _mv(Ry, A)
    xs = X + _mv(Rx, B)
    if not want_jac:
        return xs, None
    # d x*/d coefficient, mm per unit coefficient: chain rule through the axis stack.
    J = np.zeros((n, 3, terms.n))
    RxRy = Rx @ Ry
    sl = terms.slices
    eye = np.eye(3)
    for name, _ in terms.functions:
        D = ev.designs[name]
        s = sl[name]
        if name in SQUARENESS:
            k = 0 if name in ("sxy", "sxz") else 1
            lead = Rx if name == "sxy" else RxRy
            J[:, :, s] = (lead[:, :, k] * URAD)[:, :, None] * D[:, None, :]
            continue
        ax, comp = name[1], direction_of(name)
        if name[0] == "d":
            col = {"x": np.broadcast_to(eye[:, comp], (n, 3)), "y": Rx[:, :, comp],
                   "z": RxRy[:, :, comp]}[ax]
            J[:, :, s] = (col * UM)[:, :, None] * D[:, None, :]
            continue
        ang = ev.angles[ax][comp]
        Rxe, Rye, Rze = ev.R[ax][1]
        dR = _drot(ang, comp)
        dM = {0: Rze @ Rye @ dR, 1: Rze @ dR @ Rxe, 2: dR @ Rye @ Rxe}[comp]
        if ax == "x":
            col = _mv(dM, B)
        elif ax == "y":
            col = _mv(Rx @ dM, A)
        else:
            col = _mv(RxRy @ dM, p_mm)
        J[:, :, s] = (col * URAD)[:, :, None] * D[:, None, :]
    return xs, J


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
    """``d x* / d p`` = Rx Ry Rz at the scale readings, shape (n, 3, 3)."""
    ev = _Evaluation(terms, np.asarray(coef, float), np.asarray(x_mm, float))
    return ev.R["x"][0] @ ev.R["y"][0] @ ev.R["z"][0]


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

"""Ball bars: lengths between two probed ball centres, fitted jointly with the plate.

A ball bar (a bar of 300-800 mm with a precision sphere at each end, or two spheres on a
rigid frame) is placed in several orientations and positions in the machine; at each
placement the CMM probes both spheres and reports their centres ``r1``, ``r2`` (machine
axes, indicated tip centres, stylus offset ``p``). The length the CMM indicates is
``|r2 - r1|``; the bar's certified length ``L`` is its true one. With the kinematic model
``x*`` (``kinematics``; sign convention in ``instruments``)::

    pred = |r2 - r1| + (|x*(r2 - p, p) - x*(r1 - p, p)| - |r2 - r1|) - L_certified   (3)

(mm), the indicated length corrected by the model's change of the distance between the two
centres, minus the certified length; the row is ``pred / u``. Like a step gauge the row
depends on the kinematic coefficients only, and only through a length: a ball bar sees the
scale and squareness of the axes in the plane of its orientations, and nothing of rigid
motion (no placement, no zero). Format and what it separates: ``docs/instruments.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..machine import KinematicTerms
from ..machine import kinematics as kin
from ..units import UM
from .instruments import length_change, truth_of

__all__ = ["BallBar", "simulate_ball_bar"]


@dataclass(frozen=True, eq=False)
class BallBar:
    """Lengths of a ball bar between two probed ball centres (``instrument_files.read_ball_bar``).

    Attributes
    ----------
    source : str
        File name (for messages and the fit's report).
    rows : ndarray of int (m,)
        File row of each length.
    bar : tuple of str
        Label of each length (bar and orientation, e.g. ``"B500 xy+"``).
    r1_mm, r2_mm : ndarray (m, 3)
        Indicated centres of the two balls, machine axes, mm.
    p_mm : ndarray (m, 3)
        Stylus offset from the ram reference point (both balls probed with it), mm.
    certified_mm : ndarray (m,)
        The bar's certified length at the measuring temperature, mm.
    u_um : ndarray (m,)
        Standard uncertainty of the indicated minus the certified length (certificate,
        probing of the two spheres, bar temperature), µm.
    """

    source: str
    rows: np.ndarray
    bar: tuple
    r1_mm: np.ndarray
    r2_mm: np.ndarray
    p_mm: np.ndarray
    certified_mm: np.ndarray
    u_um: np.ndarray
    kind = "ball_bar"
    sees_scale = True

    @cached_property
    def measured_mm(self) -> np.ndarray:
        """The length the CMM indicates: the distance of the two indicated centres, mm."""
        return np.linalg.norm(self.r2_mm - self.r1_mm, axis=1)

    def points(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """``(scale readings mm, offsets mm)`` of the two centres, where the model is
        evaluated."""
        return [(self.r1_mm - self.p_mm, self.p_mm), (self.r2_mm - self.p_mm, self.p_mm)]

    @cached_property
    def transform(self) -> tuple[np.ndarray, np.ndarray]:
        """``(T, Q)``: each length is one row weighted by ``1 / u`` (no nuisance)."""
        w = 1.0 / self.u_um
        return np.diag(w), np.eye(w.size)

    def predict(self, terms: KinematicTerms, coef: np.ndarray, want_jac: bool
            ) -> tuple[np.ndarray, np.ndarray | None]:
        """Eq. 3 in µm and its Jacobian (µm per coefficient unit, (m, terms.n)) when
        wanted."""
        change, Jp = length_change(terms, coef, self.r1_mm, self.r2_mm, self.p_mm, want_jac)
        return (self.measured_mm - self.certified_mm + change) / UM, Jp

    def labels(self) -> list[str]:
        """Label of each length (the report's per-reading label)."""
        return list(self.bar)


def simulate_ball_bar(sim: Any, start_mm: ArrayLike, end_mm: ArrayLike, *,
                  offset_mm: ArrayLike = (0.0, 0.0, 0.0), u_um: float = 0.3,
                  seed: int | None = None, labels: Sequence[str] | None = None,
                  source: str = "simulated ball bar") -> BallBar:
    """Ball-bar lengths on ``sim``'s true machine: each row of ``start_mm``, ``end_mm``
    ((m, 3) or (3,), machine axes, mm) holds the true centres of the two balls of one
    placement of the bar; the certified length is their distance. Each centre is probed
    where the CMM indicates ``r = x + p`` with ``x*(x, p)`` the true centre
    (``kinematics.invert``); the noise N(0, u) of the indicated length is put on the second
    centre, along the bar.

    Parameters
    ----------
    sim : virtual_cmm.Simulation
    start_mm, end_mm : array (m, 3) or (3,)
        True ball centres, mm machine axes.
    offset_mm : (3,) array
        Stylus offset, mm.
    u_um : float
        Standard deviation of the length noise, and the file's ``u_um``.
    seed : int or None
        Noise seed.
    labels : list of str, optional
        Label of each length (default ``L<length>#<k>``).
    """
    terms, coef = truth_of(sim)
    t1, t2 = np.atleast_2d(np.asarray(start_mm, float)), np.atleast_2d(np.asarray(end_mm,
                                                                                   float))
    t1, t2 = np.broadcast_arrays(t1, t2)
    m = len(t1)
    p = np.broadcast_to(np.asarray(offset_mm, float), (m, 3)).copy()
    r1 = kin.invert(terms, coef, t1, p) + p
    r2 = kin.invert(terms, coef, t2, p) + p
    L = np.linalg.norm(t2 - t1, axis=1)
    direction = (r2 - r1) / np.linalg.norm(r2 - r1, axis=1)[:, None]
    r2 = r2 + direction * (np.random.default_rng(seed).normal(0.0, u_um, m) * UM)[:, None]
    names = tuple(labels) if labels is not None else tuple(
        f"L{v:.0f}#{k + 1}" for k, v in enumerate(L))
    return BallBar(source, np.arange(2, m + 2), names, r1.copy(), r2, p, L,
                   np.full(m, float(u_um)))

"""One model on one selection of observations: the parameter layout of its effect blocks,
residuals and their analytic Jacobian, gauge constraints and weighted residual rows
(thesis eq. 4.13-4.15; the solver that uses them is ``fitting.fit``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
import scipy.sparse as sp

from ..machine import KinematicTerms, plate_effect_basis, rigid_fit
from ..units import UM
from . import hole_plate
from . import normal as _normal
from .blocks import REGISTRY
from .blocks.base import Block
from .blocks.context import Eval
from .blocks.kinematic import Kinematic
from .blocks.plate import Plate
from .effects import ModelSpec
from .instruments import Instruments
from .observations import Observations
from .state import State

__all__ = ["Problem", "held_constraints", "augmented_state", "weighted_residual"]

_B = TypeVar("_B", bound=Block)


@dataclass
class _Layout:
    """Column layout of the parameter vector: block name -> slice, plus labels/units."""

    blocks: dict[str, slice] = field(default_factory=dict)
    labels: list[str] = field(default_factory=list)
    units: list[str] = field(default_factory=list)
    groups: list[str] = field(default_factory=list)

    def add(self, name: str, labels: Sequence[str], unit: str | Sequence[str]) -> None:
        i = len(self.labels)
        self.blocks[name] = slice(i, i + len(labels))
        self.labels += labels
        self.units += [unit] * len(labels) if isinstance(unit, str) else unit
        self.groups += [name] * len(labels)

    @property
    def n(self) -> int:
        return len(self.labels)


class Problem:
    """Parameter layout, residuals and analytic Jacobian of one model on one selection.

    The model is the sum of its effect blocks (``cmm_core.model.blocks``): each lays out its
    columns, takes part in the probe, plate and reading stages of the residual, writes its
    Jacobian columns and its gauge constraints.
    """

    def __init__(self, obs: Observations, spec: ModelSpec, plate: str) -> None:
        self.obs, self.spec, self.plate = obs, spec, plate
        self.terms = KinematicTerms(spec.active, tuple(obs.range_mm), spec.periods,
                                        obs.layout)
        self.n_obs = len(obs.r_mm)
        # an instrument-only fit has no plate (instrument_observations)
        self.plate_centre: np.ndarray = np.zeros(3)
        self.sag_basis: np.ndarray = np.zeros((0, 3))
        if self.n_obs:
            self.plate_centre, self.sag_basis = plate_effect_basis(obs.plate0_mm)
        self.B, self.P, self.Q = len(obs.balls), len(obs.positions), len(obs.probes)
        self.blocks = [cls(self) for cls in REGISTRY if cls.wanted(spec, plate)]
        L = _Layout()
        for b in self.blocks:
            for name, labels, unit in b.columns(obs):
                L.add(name, labels, unit)
        self.layout = L
        self.instruments = Instruments(self)  # laser and step-gauge rows (their own module)
        self._kinematic = next(b for b in self.blocks if isinstance(b, Kinematic))

    def block(self, cls: type[_B]) -> _B | None:
        """The block of this class in the model, or None."""
        return next((b for b in self.blocks if isinstance(b, cls)), None)

    # --- state ---------------------------------------------------------------------
    def initial_state(self) -> State:
        """Nominal plate, placements by a rigid fit of the plate to each position."""
        if hole_plate.is_hole_plate(self.obs):  # in-plane fit at the nominal tilt
            return hole_plate.initial_state(self)
        o = self.obs
        R = np.empty((self.P, 3, 3))
        t = np.empty((self.P, 3))
        for k in range(self.P):
            sel = o.pos == k
            R[k], t[k] = rigid_fit(o.plate0_mm[o.ball[sel]], o.r_mm[sel])
        return State(o.plate0_mm.copy(), R, t, np.zeros(self.layout.n))

    def _placed(self, ev: Eval) -> np.ndarray:
        """Probe and plate stages, then the placed ball ``R_k c' + t_k`` (mm)."""
        o, state = self.obs, ev.state
        p = o.p_mm.copy()
        for b in self.blocks:
            p = b.probe_stage(ev, p)
        ev.p_mm = p
        c = state.c[o.ball]
        for b in self.blocks:
            c = b.plate_stage(ev, c)
        ev.plate_mm = c
        ev.Rk = state.R[o.pos]
        return np.einsum("nij,nj->ni", ev.Rk, c) + state.t[o.pos]

    def _reading(self, ev: Eval, d: np.ndarray) -> np.ndarray:
        for b in self.blocks:
            d = b.reading_stage(ev, d)
        return d

    def _evaluate(self, state: State, want_jac: bool) -> tuple[np.ndarray, Eval]:
        ev = Eval(self, state, want_jac)
        placed = self._placed(ev)
        xs = self._kinematic.model(ev)
        return self._reading(ev, (xs - placed) / UM), ev

    def targets(self, state: State) -> tuple[np.ndarray, np.ndarray]:
        """What the kinematic model must return for every residual to vanish (mm), and
        the true probe offsets (mm): the simulator inverts the model to these
        (``simulate``), so that it is the exact inverse of the fit's model."""
        ev = Eval(self, state, False)
        placed = self._placed(ev)
        # the reading stage is linear in the residual: d = (x* - placed)/UM + L
        L = self._reading(ev, np.zeros_like(placed))
        assert ev.p_mm is not None  # set by the probe stage (_placed)
        return placed - L * UM, ev.p_mm

    def plate_points(self, state: State) -> np.ndarray:
        """Plate coordinates of every observation after thermal and sag effects (mm)."""
        ev = Eval(self, state, False)
        c = state.c[self.obs.ball]
        for b in self.blocks:
            c = b.plate_stage(ev, c)
        return c

    def residual(self, state: State, want_jac: bool = False) -> tuple[np.ndarray, Any]:
        """Residuals (n, 3) in µm and, if asked, the sparse Jacobian (3n, N); a hole
        plate's without their components along the plate normal (``hole_plate``). The
        Jacobian is a ``scipy.sparse`` CSR matrix or None, typed Any: scipy ships no
        type information here (``mypy.ini``)."""
        out = self._residual3(state, want_jac)
        return hole_plate.in_plane(self, state, *out) if hole_plate.is_hole_plate(self.obs) \
            else out

    def _residual3(self, state: State, want_jac: bool) -> tuple[np.ndarray, Any]:
        d, ev = self._evaluate(state, want_jac)
        if not want_jac:
            return d, None
        n = self.n_obs
        cols, vals = [], []
        for b in self.blocks:
            for block_cols, M in b.jacobian(ev):
                # M: (n, 3, k) derivative of the 3 residual components wrt k columns. Every
                # row has the same number of entries per block: CSR is assembled directly
                cols.append(np.broadcast_to(block_cols[:, None, :], M.shape))
                vals.append(M)
        # fill one preallocated (n, 3, k) array per CSR field: concatenating broadcast
        # blocks would copy the dense kinematic block twice (10^5 points: 0.5 s a call)
        k = sum(c.shape[2] for c in cols)
        itype = np.int32 if max(self.layout.n, 3 * n * k) < 2**31 - 1 else np.int64
        data, index = np.empty((n, 3, k)), np.empty((n, 3, k), itype)
        j = 0
        for c, v in zip(cols, vals, strict=True):
            data[:, :, j:j + c.shape[2]] = v
            index[:, :, j:j + c.shape[2]] = c
            j += c.shape[2]
        J = sp.csr_matrix((data.reshape(-1), index.reshape(-1),
                           np.arange(3 * n + 1, dtype=itype) * k), shape=(3 * n, self.layout.n))
        return d, J

    def normal_equations(self, state: State, sigma_um: float, rows: int = _normal.ROWS,
                         plate_cross: bool = True) -> _normal.NormalEquations:
        """Weighted normal equations ``JᵀJ``, ``Jᵀr`` at ``state``, accumulated over blocks
        of ``rows`` observations without forming ``J`` (``normal.accumulate``): residuals
        (µm), ``r·r``, N, g and the number of weighted rows."""
        if not self.n_obs:  # instruments only: no plate rows to accumulate
            return _instrument_normal_equations(self, state)
        if hole_plate.is_hole_plate(self.obs):  # projected rows: J assembled
            return _hole_plate_normal_equations(self, state, sigma_um)
        return _normal.accumulate(self, state, sigma_um, rows, plate_cross)

    def constraints(self) -> np.ndarray:
        """Gauge constraints C (rows) on the parameter vector: C x = 0."""
        L, rows = self.layout, []
        for b in self.blocks:
            G = b.constraints()
            if G is None:
                continue
            if isinstance(b, Plate):  # an instrument may release the plate's scale
                G = self.instruments.plate_gauge(b, G)
            s = L.blocks[b.columns(self.obs)[0][0]]
            C = np.zeros((G.shape[0], L.n))
            C[:, s.start:s.start + G.shape[1]] = G  # G may span the block's next groups
            rows.append(C)
        return np.vstack(rows) if rows else np.zeros((0, L.n))

    def update(self, state: State, step: np.ndarray) -> State:
        """Apply a step: placements are updated multiplicatively so the rotation
        parameters stay small increments (exact Jacobian at zero), the plate into its
        coordinates."""
        new = state.with_x(state.x + step)
        for b in self.blocks:
            new = b.update(new)
        return new


def held_constraints(labels: Sequence[str], design_null: np.ndarray, prob: Problem
                     ) -> np.ndarray:
    """Constraint rows, in ``prob``'s parameter vector, that hold the combinations a fit
    with parameters ``labels`` could not determine (its ``design_null``): a model scored
    or tested from that fit keeps them held, or it would be credited with them."""
    col = {lab: i for i, lab in enumerate(prob.layout.labels)}
    held = np.zeros((design_null.shape[0], prob.layout.n))
    for j, lab in enumerate(labels):
        held[:, col[lab]] = design_null[:, j]
    return held


def augmented_state(base: Any, prob: Problem) -> State:
    """A fit's solution (``base``: a ``FitResult``; typed Any, as ``result`` imports this
    module) expressed in another problem's parameter vector on the same
    observations (parameters the fit does not have start at zero): the linearisation
    point from which a candidate effect is scored (``diagnosis.scoring.score``,
    ``diagnosis.crossval``)."""
    return base.state.relabelled(base.labels, prob.layout.labels)


def weighted_residual(prob: Problem, state: State, sigma_um: float, want_jac: bool
                      ) -> tuple[np.ndarray, np.ndarray, Any]:
    """Residuals (µm, (n, 3)), the weighted residual vector and its Jacobian (a sparse
    CSR matrix; None when ``want_jac`` is False).

    Observation rows are divided by σ; with a plate prior, rows ``(c - c_cert) / u_cert``
    follow (the certificate weighted by its uncertainty), then the instruments' rows.
    """
    d, J = prob.residual(state, want_jac)
    r = d.ravel() / sigma_um
    if J is not None:
        J.data /= sigma_um  # J is this call's own: scaled in place, not copied
    if prob.plate == "prior":
        plate = prob.block(Plate)
        assert plate is not None  # a prior plate is a Plate block (Plate.wanted)
        rp, Jp = plate.prior_rows(state, want_jac)
        r = np.concatenate([r, rp])
        if J is not None:
            J = sp.vstack([J, Jp]).tocsr()
    r, J = prob.instruments.append(r, J, state, prob.layout.n)  # laser, step gauge rows
    return d, r, J


def _hole_plate_normal_equations(prob, state, sigma_um: float):
    """Weighted normal equations of a hole plate (``Problem.normal_equations``): from the
    assembled, projected Jacobian of :func:`weighted_residual` (the blocked accumulation
    of ``normal`` evaluates the blocks' unprojected Jacobians), with two rows per
    observation counted."""
    d, r, J = weighted_residual(prob, state, sigma_um, True)
    N = (J.T @ J).toarray()
    return _normal.NormalEquations(d, float(r @ r), N, J.T @ r, r.size - prob.n_obs)


def _instrument_normal_equations(prob, state):
    """Normal equations of an instrument-only problem (``Problem.normal_equations`` with
    no plate observation): the instruments' weighted rows alone, on the kinematic
    columns; every other column (placements, plate effects) stays empty and is named
    undetermined by the fit's rank rule."""
    p = prob.layout.n
    N, g = np.zeros((p, p)), np.zeros(p)
    r, J = prob.instruments.rows(state, True)
    k = prob.instruments.cols
    N[k, k] = J.T @ J
    g[k] = J.T @ r
    return _normal.NormalEquations(np.zeros((0, 3)), float(r @ r), N, g, r.size)

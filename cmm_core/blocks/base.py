"""The protocol every effect block implements, and the evaluation context they share.

The residual of an observation (µm) is built in stages (``fit`` module docstring)::

    p' = probe stage(p)                    probe_offset
    x* = kinematic model(r - p, p')        kinematic (thesis eq. 4.13)
    c' = plate stage(c_b)                  plate_thermal, plate_sag
    d  = (x* - (R_k c' + t_k)) / UM        placement
    d  = reading stage(d)                  drift, backlash

A block takes part in the stages it overrides; each writes its own columns of the
Jacobian. Adding an effect is adding one block module and listing it in
``blocks.REGISTRY``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Eval:
    """Working values of one residual evaluation, shared by the blocks.

    Attributes
    ----------
    problem : fit.Problem
        The problem being evaluated (observations, layout, blocks).
    state : dict
        Plate coordinates ``c`` (B, 3) mm, placements ``R`` (P, 3, 3), ``t`` (P, 3) mm and
        the parameter vector ``x``.
    want_jac : bool
        Whether the Jacobian is wanted.
    p_mm : ndarray (n, 3)
        Probe offsets after the probe stage.
    plate_mm : ndarray (n, 3)
        Plate coordinates of each observation after the plate stage.
    plate_scale : ndarray (n,) or float
        Thermal scale factor applied to the plate coordinates (plate Jacobian).
    Rk : ndarray (n, 3, 3)
        Rotation of each observation's placement.
    kin_jac : ndarray (n, 3, k) or None
        Kinematic model Jacobian (mm per coefficient unit).
    """

    problem: object
    state: dict
    want_jac: bool
    p_mm: np.ndarray | None = None
    plate_mm: np.ndarray | None = None
    plate_scale: np.ndarray | float = 1.0
    Rk: np.ndarray | None = None
    kin_jac: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    @property
    def obs(self):
        return self.problem.obs

    def x(self, name):
        """Parameters of one layout slice."""
        return self.state["x"][self.problem.layout.blocks[name]]

    def start(self, name):
        """First column of one layout slice."""
        return self.problem.layout.blocks[name].start


@dataclass(frozen=True)
class Effect:
    """One catalogue entry: what it is, what it needs, what it is confused with.

    Attributes
    ----------
    name : str
        Catalogue name used in model specs (``dyz``, ``dyz:3``, ``plate_sag``).
    title : str
        Short human title.
    explanation : str
        What a metrologist would write about the physical effect.
    needs : str
        The data it needs to be identifiable.
    confused_with : str
        Effects it can be mistaken for with common measurement plans.
    separate_by : str
        The measurement that separates it from those.
    """

    name: str
    title: str
    explanation: str
    needs: str
    confused_with: str
    separate_by: str


@dataclass
class SimContext:
    """What a block's :meth:`Block.draw` sees of a simulation, and may set.

    Attributes
    ----------
    positions, probes : list of str
        Positions and probes of the setup.
    temps_C : dict
        Plate temperature of each position at its start and finish (°C); 20 °C unless a
        block (plate_thermal) sets it.
    columns : dict
        Further columns a block records: column -> {position: (start, finish)},
        interpolated over each position's measuring time like ``temp_C``.
    """

    positions: list
    probes: list
    temps_C: dict = field(default_factory=dict)
    columns: dict = field(default_factory=dict)


class Block:
    """One physical effect: its parameters, the data it needs, its residual contribution,
    Jacobian and gauge constraints.

    Subclasses set :attr:`token` (the catalogue name that adds it to a model; ``None``
    for blocks always present) and override what they take part in.
    """

    token: str | None = None
    """Catalogue name that puts the block in a model (``None``: always in the model)."""
    entry: Effect | None = None
    """Its catalogue entry (what it is, needs, is confused with, is separated by)."""

    sim_keys: frozenset | None = frozenset()
    """Keys the simulator accepts under ``effects.<token>`` (None: position or probe names
    besides those of :attr:`sim_ranges`, checked against the setup)."""
    sim_ranges: dict = {}
    """Numeric simulator keys and their allowed (low, high) range."""

    def __init__(self, problem):
        self.problem = problem

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng) -> dict:
        """True parameter values (by fit label) for the simulator's ``effects.<token>``
        configuration ``cfg``; random draws come from ``rng``."""
        return {}

    @classmethod
    def wanted(cls, spec, plate: str) -> bool:
        """Whether a model with this spec and plate mode contains the block."""
        return cls.token is not None and cls.token in spec.effects

    @staticmethod
    def needs(obs) -> str | None:
        """Why these observations cannot determine the effect (None: they can)."""
        return None

    def columns(self, obs) -> list:
        """Layout entries ``(name, labels, unit)`` the block adds (unit: str or list)."""
        return []

    # --- stages ---------------------------------------------------------------------
    def probe_stage(self, ev: Eval, p):
        return p

    def plate_stage(self, ev: Eval, c):
        return c

    def reading_stage(self, ev: Eval, d):
        return d

    def jacobian(self, ev: Eval) -> list:
        """``[(cols (n, 3, k) or broadcastable, values (n, 3, k))]``: derivatives of the
        three residual components with respect to ``k`` columns."""
        return []

    def constraints(self) -> np.ndarray | None:
        """Gauge constraint rows on the block's own columns (``C x = 0``), or None."""
        return None


def per_group_cols(start: int, group: np.ndarray):
    """Columns ``start + 3 g + (0, 1, 2)`` of per-group xyz parameters, (n, 3)."""
    return start + 3 * group[:, None] + np.arange(3)


def shared_cols(start: int, k: int, n: int):
    """The same ``k`` columns for every observation, (n, k)."""
    return np.broadcast_to(np.arange(start, start + k), (n, k))

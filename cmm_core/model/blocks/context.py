"""What a block works in: the working values of one residual evaluation (:class:`Eval`),
what a block reads of the problem, the fit and the model spec (protocols, not the classes:
``problem``, ``result`` and ``effects`` import the blocks, so importing them here would
close an import circle, ``tests/test_wings.py``), the shapes of what a block returns
(layout entries, Jacobian parts, detection shapes) and the Jacobian's column helpers.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ...machine import KinematicTerms
from ..observations import Observations
from ..state import State

Column = tuple[str, Sequence[str], str | Sequence[str]]
"""A layout entry :meth:`~.base.Block.columns` adds: ``(name, labels, unit)``, the unit
one string for every label or one per label."""

Jacobian = list[tuple[np.ndarray, np.ndarray]]
"""What :meth:`~.base.Block.jacobian` returns: ``[(cols, values)]``, ``values`` (n, 3, k)
the derivatives of the three residual components with respect to the ``k`` columns
``cols`` ((n, 3, k) or broadcastable to it, e.g. (n, k))."""

Shape = tuple[str, dict[str, float]]
"""A detection shape of :meth:`~.base.Block.detection_shapes`: ``(name, {label:
weight})``."""


class LayoutLike(Protocol):
    """What a block reads of the problem's parameter layout (``problem._Layout``)."""

    @property
    def blocks(self) -> dict[str, slice]:
        """Layout name -> slice of the parameter vector."""
        ...

    @property
    def n(self) -> int:
        """Length of the parameter vector."""
        ...


class ProblemLike(Protocol):
    """What a block reads of the problem it belongs to (``problem.Problem``). A protocol,
    not the class: ``problem`` imports the blocks, so importing it here would close an
    import circle (``tests/test_wings.py``)."""

    @property
    def obs(self) -> Observations:
        """The observations fitted."""
        ...

    @property
    def layout(self) -> LayoutLike:
        """Column layout of the parameter vector."""
        ...

    @property
    def terms(self) -> KinematicTerms:
        """The kinematic model's terms."""
        ...

    @property
    def plate_centre(self) -> np.ndarray:
        """Centre of the plate (3,) mm, about which it expands."""
        ...

    @property
    def sag_basis(self) -> np.ndarray:
        """Sag shapes of every ball (B, 3)."""
        ...


class SpecLike(Protocol):
    """What :meth:`~.base.Block.wanted` reads of a model spec (``effects.ModelSpec``; a
    protocol, as ``effects`` imports the blocks)."""

    @property
    def effects(self) -> Collection[str]:
        """Physical effects present (catalogue tokens)."""
        ...


class FitLike(Protocol):
    """What :meth:`~.base.Block.compensation` reads of a fit (``result.FitResult``; a
    protocol, as ``result`` imports the problem, which imports the blocks)."""

    @property
    def problem(self) -> ProblemLike:
        """The fitted problem."""
        ...

    @property
    def labels(self) -> Sequence[str]:
        """One label per parameter."""
        ...

    @property
    def values(self) -> np.ndarray:
        """Parameter estimates (p,)."""
        ...

    @property
    def covariance(self) -> np.ndarray:
        """Parameter covariance (p, p)."""
        ...


@dataclass
class Eval:
    """Working values of one residual evaluation, shared by the blocks.

    Attributes
    ----------
    problem : problem.Problem
        The problem being evaluated (observations, layout, blocks).
    state : state.State
        Plate coordinates, placements and the parameter vector.
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
        Kinematic model Jacobian (µm per coefficient unit).
    """

    problem: ProblemLike
    state: State
    want_jac: bool
    p_mm: np.ndarray | None = None
    plate_mm: np.ndarray | None = None
    plate_scale: np.ndarray | float = 1.0
    Rk: np.ndarray | None = None
    kin_jac: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    @property
    def obs(self) -> Observations:
        """The problem's observations."""
        return self.problem.obs

    def x(self, name: str) -> np.ndarray:
        """Parameters of one layout slice."""
        return self.state.x[self.problem.layout.blocks[name]]

    def start(self, name: str) -> int:
        """First column of one layout slice."""
        return self.problem.layout.blocks[name].start


def per_group_cols(start: int, group: np.ndarray) -> np.ndarray:
    """Columns ``start + 3 g + (0, 1, 2)`` of per-group xyz parameters, (n, 3)."""
    return start + 3 * group[:, None] + np.arange(3)


def shared_cols(start: int, k: int, n: int) -> np.ndarray:
    """The same ``k`` columns for every observation, (n, k)."""
    return np.broadcast_to(np.arange(start, start + k), (n, k))

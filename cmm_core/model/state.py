"""The point a kinematic fit linearises at: plate, placements and parameter vector.

The plate coordinates and placements are carried outside the parameter vector so that
the fitted parameters stay small increments (thesis §4.5: rotations updated
multiplicatively, the plate into its coordinates); ``x`` holds the parameters of the
problem's layout (``problem.Problem.layout``). A state is immutable: a Gauss-Newton step
makes a new one (``problem.Problem.update``), each block replacing what it owns.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["State"]


@dataclass(frozen=True)
class State:
    """Plate, placements and parameters of one linearisation point."""

    c: np.ndarray
    """Ball coordinates of the plate (B, 3), mm, plate frame."""
    R: np.ndarray
    """Rotation of each placement (P, 3, 3): plate frame to machine frame."""
    t: np.ndarray
    """Translation of each placement (P, 3), mm."""
    x: np.ndarray
    """Parameter vector in the layout's units (µm, µrad, ...)."""

    def with_x(self, x: ArrayLike) -> State:
        """The same plate and placements with another parameter vector."""
        return replace(self, x=np.asarray(x, dtype=float))

    def relabelled(self, labels: Sequence[str], new_labels: Sequence[str]) -> State:
        """The same point expressed in another layout's parameter vector: parameters of
        ``new_labels`` that ``labels`` does not have start at zero (a model with an
        effect added, linearised at the solution of the model without it)."""
        old = dict(zip(labels, self.x, strict=True))
        return self.with_x(np.array([old.get(lab, 0.0) for lab in new_labels]))

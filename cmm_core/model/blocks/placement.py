"""Rigid placement of each plate position: a small rotation (µrad) and translation (µm)
from the setup's nominal placement, updated multiplicatively so that the parameters stay
small increments at which the Jacobian is exact."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from ...machine import skew
from ...units import UM, URAD
from ..hole_plate import initial_state, is_hole_plate
from ..observations import Observations
from ..state import State
from .base import Block
from .context import Column, Eval, Jacobian, SpecLike, per_group_cols


class Placement(Block):
    """Rotation and translation of every position (always in the model)."""

    @classmethod
    def wanted(cls, spec: SpecLike, plate: str) -> bool:
        return True

    def columns(self, obs: Observations) -> list[Column]:
        return [("rotation", [f"{p}.r{a}" for p in obs.positions for a in "xyz"], "urad"),
                ("translation", [f"{p}.t{a}" for p in obs.positions for a in "xyz"], "um")]

    def jacobian(self, ev: Eval) -> Jacobian:
        o = ev.obs
        assert ev.Rk is not None and ev.plate_mm is not None  # set by Problem._placed
        v = np.einsum("nij,nj->ni", ev.Rk, ev.plate_mm)
        n = len(o.pos)
        return [(per_group_cols(ev.start("rotation"), o.pos), skew(v) * UM),
                (per_group_cols(ev.start("translation"), o.pos),
                 -np.broadcast_to(np.eye(3), (n, 3, 3)))]

    def constraints(self) -> np.ndarray | None:
        """None for a ball plate. A hole plate sees each placement only in its plane
        (``hole_plate``): its tilt (rotations about the plate's u and v axes) and its
        translation along the normal are held at their start, rows over the rotation and
        then the translation columns. The axes are the starting placement's (the plane of
        its measured centres, ``hole_plate.initial_state``), not the setup's: rows off the
        unseen directions by the angle between them would leave combinations seen only
        through that angle, which the rank check calls undetermined."""
        o = self.problem.obs
        if not is_hole_plate(o):
            return None
        P = len(o.positions)
        G = np.zeros((3 * P, 6 * P))
        for k, R in enumerate(initial_state(self.problem).R):
            G[3 * k, 3 * k:3 * k + 3] = R[:, 0]
            G[3 * k + 1, 3 * k:3 * k + 3] = R[:, 1]
            G[3 * k + 2, 3 * P + 3 * k:3 * P + 3 * k + 3] = R[:, 2]
        return G

    def update(self, new: State) -> State:
        blk = self.problem.layout.blocks
        w = new.x[blk["rotation"]].reshape(-1, 3) * URAD
        tau = new.x[blk["translation"]].reshape(-1, 3) * UM
        x = new.x.copy()
        x[blk["rotation"]] = 0.0
        x[blk["translation"]] = 0.0
        return replace(new, R=Rotation.from_rotvec(w).as_matrix() @ new.R, t=new.t + tau,
                       x=x)

    def report(self, state: State, v: np.ndarray) -> None:
        blk, o = self.problem.layout.blocks, self.problem.obs
        rot = np.array([Rotation.from_matrix(R @ R0.T).as_rotvec() for R, R0 in
                        zip(state.R, o.R0, strict=True)]) / URAD
        v[blk["rotation"]] = rot.ravel()
        v[blk["translation"]] = ((state.t - o.t0_mm) / UM).ravel()

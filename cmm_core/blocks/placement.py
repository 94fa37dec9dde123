"""Rigid placement of each plate position: a small rotation (µrad) and translation (µm)
from the setup's nominal placement, updated multiplicatively so that the parameters stay
small increments at which the Jacobian is exact."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry import skew
from ..units import UM, URAD
from .base import Block, per_group_cols


class Placement(Block):
    """Rotation and translation of every position (always in the model)."""

    @classmethod
    def wanted(cls, spec, plate):
        return True

    def columns(self, obs):
        return [("rotation", [f"{p}.r{a}" for p in obs.positions for a in "xyz"], "urad"),
                ("translation", [f"{p}.t{a}" for p in obs.positions for a in "xyz"], "um")]

    def jacobian(self, ev):
        o = ev.obs
        v = np.einsum("nij,nj->ni", ev.Rk, ev.plate_mm)
        n = len(o.pos)
        return [(per_group_cols(ev.start("rotation"), o.pos), skew(v) * UM),
                (per_group_cols(ev.start("translation"), o.pos),
                 -np.broadcast_to(np.eye(3), (n, 3, 3)))]

    def update(self, new):
        blk = self.problem.layout.blocks
        w = new["x"][blk["rotation"]].reshape(-1, 3) * URAD
        tau = new["x"][blk["translation"]].reshape(-1, 3) * UM
        new["R"] = Rotation.from_rotvec(w).as_matrix() @ new["R"]
        new["t"] = new["t"] + tau
        new["x"][blk["rotation"]] = 0.0
        new["x"][blk["translation"]] = 0.0

    def report(self, state, v):
        blk, o = self.problem.layout.blocks, self.problem.obs
        rot = np.array([Rotation.from_matrix(R @ R0.T).as_rotvec() for R, R0 in
                        zip(state["R"], o.R0, strict=True)]) / URAD
        v[blk["rotation"]] = rot.ravel()
        v[blk["translation"]] = ((state["t"] - o.t0_mm) / UM).ravel()

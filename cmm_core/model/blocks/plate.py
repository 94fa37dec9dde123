"""Plate geometry: the ball coordinates self-calibrated (``free``) or the certificate as a
prior weighted by its uncertainty (``prior``); with the certificate ``fixed`` the block is
absent and the balls sit where the certificate puts them (thesis §4.5.1)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from ...machine import skew
from ...units import UM
from ..hole_plate import is_hole_plate
from ..observations import Observations
from ..state import State
from .base import Block
from .context import Column, Eval, Jacobian, SpecLike, per_group_cols


class Plate(Block):
    """Ball coordinates (µm from the certificate or the mean measured plate)."""

    @classmethod
    def wanted(cls, spec: SpecLike, plate: str) -> bool:
        return plate not in ("fixed", "none")  # "none": instruments only

    def columns(self, obs: Observations) -> list[Column]:
        return [("plate", [f"ball{b}.{a}" for b in obs.balls for a in "xyz"], "um")]

    def jacobian(self, ev: Eval) -> Jacobian:
        scale = np.reshape(ev.plate_scale, (-1, 1, 1))
        assert ev.Rk is not None  # set by the plate stage (Problem._placed)
        return [(per_group_cols(ev.start("plate"), ev.obs.ball), -ev.Rk * scale)]

    def constraints(self) -> np.ndarray:
        """Seven gauge freedoms of a self-calibrated plate (thesis appendix 2): three
        translations and three small rotations, which the placements carry, and the
        isotropic scale, which needs an external length reference. The scale is the last
        row (``instruments.Instruments.plate_gauge`` releases it).

        A hole plate (``hole_plate``) has the in-plane translations, the rotation about
        its normal and its in-plane scale, and every hole's coordinate along the normal
        (no residual sees it) held instead."""
        c = self.problem.obs.plate0_mm - self.problem.plate_centre
        G = np.zeros((c.size, 7))
        for a in range(3):
            G[a::3, a] = 1.0
        rot = skew(c)
        for a in range(3):
            G[:, 3 + a] = -rot[:, :, a].ravel()
        G[:, 6] = c.ravel()
        if is_hole_plate(self.problem.obs):
            normal = np.zeros((c.size, len(c)))
            normal[2::3] = np.eye(len(c))
            G[2::3, 6] = 0.0
            G = np.hstack([G[:, [0, 1, 5]], normal, G[:, 6:]])
        return G.T

    def prior_rows(self, state: State, want_jac: bool) -> tuple[np.ndarray, Any]:
        """Rows ``(c - c_cert) / u_cert`` of the certificate prior and their Jacobian (a
        ``scipy.sparse`` CSR matrix, None unless ``want_jac``; typed Any, as scipy ships no
        type information here). An infinite certificate u releases that coordinate
        (``certificate_check``): no row, so that it neither counts as an observation nor
        constrains the plate."""
        prob, o = self.problem, self.problem.obs
        assert o.cert_u_um is not None  # a prior plate has certificate uncertainties
        s = prob.layout.blocks["plate"]
        dev = (state.c - o.plate0_mm) / UM + state.x[s].reshape(-1, 3)
        keep = np.flatnonzero(np.isfinite(o.cert_u_um.ravel()))
        u = o.cert_u_um.ravel()[keep]
        J = None
        if want_jac:
            J = sp.csr_matrix((1.0 / u, (np.arange(keep.size), s.start + keep)),
                              shape=(keep.size, prob.layout.n))
        return dev.ravel()[keep] / u, J

    def update(self, new: State) -> State:
        s = self.problem.layout.blocks["plate"]
        x = new.x.copy()
        x[s] = 0.0
        return replace(new, c=new.c + new.x[s].reshape(-1, 3) * UM, x=x)

    def report(self, state: State, v: np.ndarray) -> None:
        s = self.problem.layout.blocks["plate"]
        v[s] = ((state.c - self.problem.obs.plate0_mm) / UM).ravel()

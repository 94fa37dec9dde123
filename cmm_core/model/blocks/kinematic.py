"""The 21 kinematic error functions (thesis eq. 4.13): Chebyshev series per function plus
any periodic scale terms (``blocks.periodic``), evaluated at the scale reading ``r - p``
with the probe offset ``p``."""

from __future__ import annotations

import numpy as np

from ...machine import kinematics as kin
from ...units import UM
from ..observations import Observations
from .base import Block
from .context import Column, Eval, Jacobian, SpecLike, shared_cols


class Kinematic(Block):
    """Coefficients of the active error functions (µm, µrad)."""

    @classmethod
    def wanted(cls, spec: SpecLike, plate: str) -> bool:
        return True

    def columns(self, obs: Observations) -> list[Column]:
        t = self.problem.terms
        return [("kinematic", t.labels, [t.unit(x) for x in t.labels])]

    def model(self, ev: Eval) -> np.ndarray:
        """Corrected tip centres x* (mm) of every observation; the Jacobian (µm per
        coefficient unit) is kept in ``ev.kin_jac`` when wanted."""
        o, terms = ev.obs, self.problem.terms
        coef = ev.x("kinematic")
        assert ev.p_mm is not None  # set by the probe stage (Problem._placed)
        if ev.want_jac:
            # in µm per coefficient unit as written (no second pass over J)
            xs, ev.kin_jac = kin.jacobian(terms, coef, o.r_mm - o.p_mm, ev.p_mm,
                                          scale=1.0 / UM)
            return xs
        return kin.model_point(terms, coef, o.r_mm - o.p_mm, ev.p_mm)

    def jacobian(self, ev: Eval) -> Jacobian:
        s = self.problem.layout.blocks["kinematic"]
        if s.stop == s.start:
            return []
        assert ev.kin_jac is not None  # set by model() when the Jacobian is wanted
        return [(shared_cols(s.start, s.stop - s.start, len(ev.obs.pos)), ev.kin_jac)]

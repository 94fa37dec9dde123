"""Sag of a horizontal plate: a bowl ``w = a·u² + b·u·v + c·v²`` along the plate normal,
with (u, v) the plate coordinates normalised to [-1, 1] (``geometry.plate_effect_basis``),
so that each coefficient is the bowl's height at the plate's edge (µm). Vertical
placements do not sag."""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType

import numpy as np

from ...units import UM
from ..observations import Observations
from .base import Block, Effect
from .context import Column, Eval, Jacobian, Shape, shared_cols
from .simulation import SimContext, SimParam


class PlateSag(Block):
    """Bowl heights at the plate's edge (µm)."""

    token = "plate_sag"
    entry = Effect(
        "plate_sag", "plate sag (gravity bending)",
        "a horizontally supported plate bends under its own weight: the out-of-plane "
        "coordinates follow a bowl shared by all horizontal placements and absent when the "
        "plate stands vertically.",
        "horizontal and vertical placements with a certificate (fixed or prior).",
        "the straightness of the axes spanning the plate (dxz, dyz) and plate form.",
        "the same horizontal placement at two heights or a vertical placement.")

    sim_keys = frozenset({"uu", "uv", "vv"})
    sim_ranges = MappingProxyType({k: (-1e3, 1e3) for k in ("uu", "uv", "vv")})
    sim_label = "Plate sag"
    sim_help = "A bowl of the horizontal placements (height at the plate's edge)."
    sim_params = (SimParam("uu", "sag uu (µm)", "um", 3.0, -20.0, 20.0),
                  SimParam("vv", "sag vv (µm)", "um", 3.0, -20.0, 20.0))
    sim_fixed = MappingProxyType({"uv": 0.0})
    physical_check = True

    @classmethod
    def detection_shapes(cls, labels: Sequence[str], positions: Sequence[str],
                         probes: Sequence[str]) -> list[Shape]:
        return [("bowl uu = vv", {"plate_sag.uu": 1.0, "plate_sag.vv": 1.0})]

    @classmethod
    def injection(cls, values: dict[str, float]) -> dict | None:
        return {lab.split(".")[1]: v for lab, v in values.items()}

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng: np.random.Generator) -> dict[str, float]:
        return {f"plate_sag.{k}": float(cfg.get(k, 0.0)) for k in ("uu", "uv", "vv")}

    @staticmethod
    def needs(obs: Observations) -> str | None:
        return None if obs.horizontal.any() else "needs at least one horizontal placement"

    def columns(self, obs: Observations) -> list[Column]:
        return [("plate_sag", ["plate_sag.uu", "plate_sag.uv", "plate_sag.vv"], "um")]

    def plate_stage(self, ev: Eval, c: np.ndarray) -> np.ndarray:
        o = ev.obs
        w = self.problem.sag_basis[o.ball] @ ev.x("plate_sag") * UM
        return c + np.outer(w * o.horizontal[o.pos], [0, 0, 1])

    def jacobian(self, ev: Eval) -> Jacobian:
        o = ev.obs
        assert ev.Rk is not None  # set by the plate stage (Problem._placed)
        nrm = ev.Rk[:, :, 2] * o.horizontal[o.pos][:, None]
        return [(shared_cols(ev.start("plate_sag"), 3, len(o.pos)),
                 -nrm[:, :, None] * self.problem.sag_basis[o.ball][:, None, :])]

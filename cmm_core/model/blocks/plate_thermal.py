"""Thermal expansion of the plate about its centre: ``c' = c0 + (c - c0)(1 + α ΔT)`` with
ΔT the plate temperature minus 20 °C (ISO 1) and α (10⁻⁶/K) the fitted expansion
coefficient; without a certificate at 20 °C it is a uniform scale in every axis."""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType

import numpy as np

from ...io import CTE_RANGE_PER_K
from ...units import PPM, UM
from ..observations import Observations
from .base import Block, Effect
from .context import Column, Eval, Jacobian, Shape, shared_cols
from .simulation import SimCheck, SimContext, SimParam


class PlateThermal(Block):
    """Expansion coefficient of the plate (10⁻⁶/K)."""

    token = "plate_thermal"
    entry = Effect(
        "plate_thermal", "plate thermal expansion",
        "the plate was not at 20 °C: it grows by CTE × (T − 20 °C), a uniform scale of every "
        "ball-to-ball length, different for each recorded temperature.",
        "a temp_C column that varies between positions or over time.",
        "the positioning (scale) errors dxx, dyy, dzz when the temperature is constant.",
        "positions measured at different plate temperatures.")

    sim_keys = frozenset({"cte_per_K", "temp_C"})
    sim_ranges = MappingProxyType({"cte_per_K": CTE_RANGE_PER_K})
    sim_label = "Plate thermal expansion"
    sim_help = "The plate 20.0-20.2 °C, 0.4 K warmer at each position."
    sim_params = (SimParam("cte_per_K", "CTE (10⁻⁶/K)", "1e-6/K", 11.5, 0.0, 30.0, 0.5,
                           1e-6),)
    physical_check = True

    @classmethod
    def detection_shapes(cls, labels: Sequence[str], positions: Sequence[str],
                         probes: Sequence[str]) -> list[Shape]:
        return [("expansion coefficient", {labels[0]: 1.0})]

    @classmethod
    def injection(cls, values: dict[str, float]) -> dict | None:
        return {"cte_per_K": float(sum(values.values())) * 1e-6}

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng: np.random.Generator) -> dict[str, float]:
        """``cte_per_K`` (default 11.5e-6, steel) and each position's start and finish
        temperature (default 20.0-20.2 °C, 0.4 K warmer at each position)."""
        given = cfg.get("temp_C")
        temps = given if isinstance(given, dict) else {}
        for i, p in enumerate(sim.positions):
            t = temps.get(p)
            sim.temps_C[p] = tuple(t) if t else (20.0 + 0.4 * i, 20.2 + 0.4 * i)
        return {"plate_thermal.cte": float(cfg.get("cte_per_K", 11.5e-6)) * 1e6}

    @classmethod
    def check_sim(cls, cfg: dict, where: str, check: SimCheck) -> None:
        check.start_finish_C(f"{where}.temp_C", cfg.get("temp_C"))

    @staticmethod
    def needs(obs: Observations) -> str | None:
        if not obs.has_temp:
            return "needs plate temperatures (temp_C column or setup records)"
        if np.ptp(obs.dT_K) < 1e-6:
            return "the plate temperature never changes, so expansion is a pure scale error"
        return None

    def columns(self, obs: Observations) -> list[Column]:
        return [("plate_thermal", ["plate_thermal.cte"], "1e-6/K")]

    def plate_stage(self, ev: Eval, c: np.ndarray) -> np.ndarray:
        alpha = ev.x("plate_thermal")[0] * PPM
        scale = 1 + alpha * ev.obs.dT_K
        ev.plate_scale = scale
        centre = self.problem.plate_centre
        return centre + (c - centre) * scale[:, None]

    def jacobian(self, ev: Eval) -> Jacobian:
        o = ev.obs
        assert ev.Rk is not None  # set by the plate stage (Problem._placed)
        dc = np.einsum("nij,nj->ni", ev.Rk, ev.state.c[o.ball] - self.problem.plate_centre)
        return [(shared_cols(ev.start("plate_thermal"), 1, len(o.pos)),
                 (-dc * o.dT_K[:, None] * PPM / UM)[:, :, None])]

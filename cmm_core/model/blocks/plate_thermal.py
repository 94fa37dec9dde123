"""Thermal expansion of the plate about its centre: ``c' = c0 + (c - c0)(1 + α ΔT)`` with
ΔT the plate temperature minus 20 °C (ISO 1) and α (10⁻⁶/K) the fitted expansion
coefficient; without a certificate at 20 °C it is a uniform scale in every axis."""

from __future__ import annotations

import numpy as np

from ...io import CTE_RANGE_PER_K
from ...units import PPM, UM
from .base import Block, Effect, SimParam, shared_cols


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
    sim_ranges = {"cte_per_K": CTE_RANGE_PER_K}
    sim_label = "Plate thermal expansion"
    sim_help = "The plate 20.0-20.2 °C, 0.4 K warmer at each position."
    sim_params = (SimParam("cte_per_K", "CTE (10⁻⁶/K)", "1e-6/K", 11.5, 0.0, 30.0, 0.5,
                           1e-6),)
    physical_check = True

    @classmethod
    def detection_shapes(cls, labels, positions, probes):
        return [("expansion coefficient", {labels[0]: 1.0})]

    @classmethod
    def injection(cls, values):
        return {"cte_per_K": float(sum(values.values())) * 1e-6}

    @classmethod
    def draw(cls, cfg, sim, rng):
        """``cte_per_K`` (default 11.5e-6, steel) and each position's start and finish
        temperature (default 20.0-20.2 °C, 0.4 K warmer at each position)."""
        temps = cfg.get("temp_C") if isinstance(cfg.get("temp_C"), dict) else {}
        for i, p in enumerate(sim.positions):
            t = temps.get(p)
            sim.temps_C[p] = tuple(t) if t else (20.0 + 0.4 * i, 20.2 + 0.4 * i)
        return {"plate_thermal.cte": float(cfg.get("cte_per_K", 11.5e-6)) * 1e6}

    @classmethod
    def check_sim(cls, cfg, where, check):
        check.start_finish_C(f"{where}.temp_C", cfg.get("temp_C"))

    @staticmethod
    def needs(obs):
        if not obs.has_temp:
            return "needs plate temperatures (temp_C column or setup records)"
        if np.ptp(obs.dT_K) < 1e-6:
            return "the plate temperature never changes, so expansion is a pure scale error"
        return None

    def columns(self, obs):
        return [("plate_thermal", ["plate_thermal.cte"], "1e-6/K")]

    def plate_stage(self, ev, c):
        alpha = ev.x("plate_thermal")[0] * PPM
        ev.plate_scale = 1 + alpha * ev.obs.dT_K
        centre = self.problem.plate_centre
        return centre + (c - centre) * ev.plate_scale[:, None]

    def jacobian(self, ev):
        o = ev.obs
        dc = np.einsum("nij,nj->ni", ev.Rk, ev.state.c[o.ball] - self.problem.plate_centre)
        return [(shared_cols(ev.start("plate_thermal"), 1, len(o.pos)),
                 (-dc * o.dT_K[:, None] * PPM / UM)[:, :, None])]

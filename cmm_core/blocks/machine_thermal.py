"""Thermal expansion of the machine's scales: an axis whose scale is at T_a reads a length
along it short by α_a (T_a − 20 °C) of the reading (ISO 1), so the true coordinate is the
reading times 1 + α_a ΔT_a. α_a (10⁻⁶/K) is fitted per axis: the scale's expansion
coefficient, or its error when the controller already compensates a nominal one. The
scale temperatures are the ``temp_x_C``, ``temp_y_C``, ``temp_z_C`` columns; an axis
without its column has no parameter."""

from __future__ import annotations

import numpy as np

from ..io import SCALE_TEMP_COLUMNS
from ..units import PPM, UM
from .base import Block, Effect, shared_cols

AXES = "xyz"


def _scale_temps(obs):
    """``{axis index: ΔT_K (n,)}`` of the axes whose scale temperature is recorded."""
    out = {}
    for a, col in enumerate(SCALE_TEMP_COLUMNS):
        if col in obs.table and obs.table[col].notna().all():
            out[a] = obs.table[col].to_numpy(float) - 20.0
    return out


class MachineThermal(Block):
    """Expansion coefficient of each recorded axis scale (10⁻⁶/K)."""

    token = "machine_thermal"
    entry = Effect(
        "machine_thermal", "machine scale thermal expansion",
        "an axis's scale is not at 20 °C (or its controller assumes a wrong expansion "
        "coefficient): the axis reads lengths along it short by CTE × (T − 20 °C), a scale "
        "error that changes with the scale's temperature.",
        "temp_x_C, temp_y_C, temp_z_C columns (the scales' temperatures) that vary between "
        "positions or over time.",
        "the linear positioning errors dxx, dyy, dzz when the scale temperature is constant, "
        "and plate thermal expansion when the plate and the scales warm together.",
        "positions measured at different scale temperatures, with the plate temperature "
        "recorded (temp_C).")
    sim_keys = frozenset({f"{a}_cte_per_K" for a in AXES} | {"temp_C"})
    # an error of a compensated coefficient can have either sign
    sim_ranges = {f"{a}_cte_per_K": (-3e-5, 3e-5) for a in AXES}

    @classmethod
    def draw(cls, cfg, sim, rng):
        """``x_cte_per_K`` ... (default 0: that scale is not simulated) and each position's
        scale temperatures at its start and finish (``temp_C``: position -> [start,
        finish], shared by the three scales; default 20.5-20.8 °C, 0.5 K warmer at each
        position, the y and z scales 0.2 and 0.4 K warmer than x)."""
        temps = cfg.get("temp_C") if isinstance(cfg.get("temp_C"), dict) else {}
        out = {}
        for a, axis in enumerate(AXES):
            key = f"{axis}_cte_per_K"
            if key not in cfg:
                continue
            col = {}
            for i, p in enumerate(sim.positions):
                t = temps.get(p)
                col[p] = tuple(t) if t else (20.5 + 0.5 * i + 0.2 * a, 20.8 + 0.5 * i + 0.2 * a)
            sim.columns[SCALE_TEMP_COLUMNS[a]] = col
            out[f"machine_thermal.cte_{axis}"] = float(cfg[key]) * 1e6
        return out

    @staticmethod
    def needs(obs):
        temps = _scale_temps(obs)
        if not temps:
            return "needs the scales' temperatures (temp_x_C, temp_y_C, temp_z_C columns)"
        if max(np.ptp(t) for t in temps.values()) < 0.01:
            return ("the scale temperatures never change, so the expansion is the linear "
                    "positioning error")
        return None

    def columns(self, obs):
        axes = sorted(_scale_temps(obs))
        return [("machine_thermal", [f"machine_thermal.cte_{AXES[a]}" for a in axes],
                 "1e-6/K")]

    def _terms(self, ev):
        """``(axis, ∂d_axis/∂α_axis (n,))`` per recorded axis: ΔT times the scale
        reading, in µm per 10⁻⁶/K."""
        o = ev.obs
        u = o.r_mm - o.p_mm
        return [(a, dT * u[:, a] * PPM / UM) for a, dT in sorted(_scale_temps(o).items())]

    def reading_stage(self, ev, d):
        d = d.copy()
        for alpha, (a, g) in zip(ev.x("machine_thermal"), self._terms(ev), strict=True):
            d[:, a] += alpha * g
        return d

    def jacobian(self, ev):
        terms = self._terms(ev)
        n = len(ev.obs.pos)
        M = np.zeros((n, 3, len(terms)))
        for j, (a, g) in enumerate(terms):
            M[:, a, j] = g
        return [(shared_cols(ev.start("machine_thermal"), len(terms), n), M)]

"""Reversal error (backlash) of each axis: a reading approached from + is short by half
the reversal span, one approached from - long by as much (µm, the full span fitted).
The approach direction follows every move of the file's measurement order
(``fit.approach_directions``)."""

from __future__ import annotations

import numpy as np

from .base import Block, Effect, shared_cols


class Backlash(Block):
    """Reversal span of each axis (µm)."""

    token = "backlash"
    entry = Effect(
        "backlash", "backlash (reversal error)",
        "an axis reads differently depending on the direction it last moved in (play in the "
        "drive, friction hysteresis of the carriage): balls approached from opposite sides "
        "along an axis differ by the reversal span, whatever their position.",
        "a known measurement order (time_min or the file's row order) that reaches balls "
        "from both directions along an axis: serpentine or random order.",
        "drift and straightness when the direction alternates row by row (serpentine), and "
        "the placement when every ball is approached from the same side.",
        "the same balls in two orders (row-by-row and serpentine), or one ball approached "
        "from both sides.")

    sim_keys = frozenset({"x_um", "y_um", "z_um"})
    sim_ranges = {f"{a}_um": (-1e3, 1e3) for a in "xyz"}

    @classmethod
    def draw(cls, cfg, sim, rng):
        return {f"backlash.{a}": float(cfg.get(f"{a}_um", 0.0)) for a in "xyz"}

    @staticmethod
    def needs(obs):
        if not (np.ptp(obs.approach, axis=0) == 2).any():
            return "every ball was approached from the same side along each axis"
        return None

    def columns(self, obs):
        return [("backlash", [f"backlash.{a}" for a in "xyz"], "um")]

    def reading_stage(self, ev, d):
        return d + ev.x("backlash") * ev.obs.approach / 2

    def jacobian(self, ev):
        o = ev.obs
        return [(shared_cols(ev.start("backlash"), 3, len(o.pos)),
                 np.eye(3)[None] * (o.approach / 2)[:, None, :])]

"""Linear drift of each placement's readings in time (µm/h): thermal drift of the machine
or the fixture while a placement is measured. Time is the ``time_min`` column, else the
row order at one minute per probed ball (said so where it is reported)."""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType

import numpy as np

from ..observations import Observations
from .base import Block, Effect
from .context import Column, Eval, Jacobian, Shape, per_group_cols
from .simulation import SimCheck, SimContext, SimParam


class Drift(Block):
    """Drift rate per placement, xyz (µm/h)."""

    token = "drift"
    entry = Effect(
        "drift", "drift with time",
        "the machine or plate moves slowly during the measurement (thermal drift): each "
        "position's coordinates change linearly with time.",
        "time_min (or a known measurement order) with balls measured in a varied order.",
        "a positioning or straightness error when the balls are measured row by row "
        "(time follows x and y), and a probe step when probes are measured in blocks.",
        "repeating the first ball at the end of each position (and a serpentine or random "
        "order, if the balls were measured row by row).")

    sim_keys = None
    sim_ranges = MappingProxyType({"sd_um_per_h": (0, 1e4)})
    sim_label = "Drift"
    sim_help = "A random linear drift of each position's readings in time."
    sim_params = (SimParam("sd_um_per_h", "sd (µm/h)", "um/h", 2.0, 0.0, 50.0),)
    physical_check = True

    @classmethod
    def detection_shapes(cls, labels: Sequence[str], positions: Sequence[str],
                         probes: Sequence[str]) -> list[Shape]:
        """Every placement drifting alike, along each axis."""
        return [(f"every placement along {a}", {f"{p}.drift_{a}": 1.0 for p in positions})
                for a in "xyz"]

    @classmethod
    def injection(cls, values: dict[str, float]) -> dict | None:
        vec: dict[str, list[float]] = {}
        for lab, v in values.items():
            p, a = lab.rsplit(".drift_", 1)
            vec.setdefault(p, [0.0, 0.0, 0.0])["xyz".index(a)] = v
        return vec

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng: np.random.Generator) -> dict[str, float]:
        """Per-position vectors (µm/h), or ``sd_um_per_h``: random rates."""
        out = {}
        for p in sim.positions:
            v = (rng.normal(0, cfg["sd_um_per_h"], 3) if "sd_um_per_h" in cfg
                 else np.asarray(cfg.get(p, [0, 0, 0]), float))
            out.update({f"{p}.drift_{a}": float(v[i]) for i, a in enumerate("xyz")})
        return out

    @classmethod
    def check_sim(cls, cfg: dict, where: str, check: SimCheck) -> None:
        """Besides ``sd_um_per_h``: positions of the setup, each with a vector (µm/h)."""
        check.vectors_by_name(cfg, where, "sd_um_per_h", check.positions, "position")

    @staticmethod
    def needs(obs: Observations) -> str | None:
        return "needs measurement times" if np.ptp(obs.hours) == 0 else None

    def columns(self, obs: Observations) -> list[Column]:
        return [("drift", [f"{p}.drift_{a}" for p in obs.positions for a in "xyz"], "um/h")]

    def reading_stage(self, ev: Eval, d: np.ndarray) -> np.ndarray:
        o = ev.obs
        return d - ev.x("drift").reshape(-1, 3)[o.pos] * o.hours[:, None]

    def jacobian(self, ev: Eval) -> Jacobian:
        o = ev.obs
        return [(per_group_cols(ev.start("drift"), o.pos),
                 -np.eye(3)[None] * o.hours[:, None, None])]

"""Probe offset errors: each stylus's true offset differs from its nominal one by a few
µm (qualification error). Through the rotation errors a wrong offset moves the corrected
point (thesis eq. 4.13 with ``p + dp``); with the kinematic model it is also a constant
shift of the stylus's points, of which only the differences between styli are
determined (their mean is a placement translation)."""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType

import numpy as np

from ...machine import kinematics as kin
from ...units import UM
from ..observations import Observations
from .base import Block, Effect
from .context import Column, Eval, Jacobian, Shape, per_group_cols
from .simulation import SimCheck, SimContext, SimParam


class ProbeOffset(Block):
    """Offset error of every stylus, xyz (µm); constrained to sum to zero."""

    token = "probe_offset"
    entry = Effect(
        "probe_offset", "probe offset error",
        "a stylus's qualified offset is wrong: every point measured with that stylus is "
        "shifted by the same vector.",
        "several probes measuring the same balls in the same position.",
        "the rigid placement of a position when each position uses only one probe, and "
        "drift when the probes are measured one after the other.",
        "interleave the probes ball by ball within one position.")

    sim_keys = None
    sim_ranges = MappingProxyType({"sd_um": (0, 1e3)})
    sim_label = "Probe offset errors"
    sim_help = "Random offset errors of the styli (summing to zero)."
    sim_params = (SimParam("sd_um", "sd (µm)", "um", 2.0, 0.0, 20.0),)
    physical_check = True

    @classmethod
    def detection_shapes(cls, labels: Sequence[str], positions: Sequence[str],
                         probes: Sequence[str]) -> list[Shape]:
        """The first stylus against the mean of the others, along each axis."""
        q0, rest = probes[0], probes[1:]
        return [(f"stylus {q0} along {a}", {f"probe{q0}.{a}": 1.0,
                                            **{f"probe{q}.{a}": -1.0 / len(rest)
                                               for q in rest}}) for a in "xyz"]

    @classmethod
    def injection(cls, values: dict[str, float]) -> dict | None:
        vec: dict[str, list[float]] = {}
        for lab, v in values.items():
            q, a = lab[len("probe"):].rsplit(".", 1)
            vec.setdefault(q, [0.0, 0.0, 0.0])["xyz".index(a)] = v
        return vec

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng: np.random.Generator) -> dict[str, float]:
        """Per-probe vectors (µm), or ``sd_um``: random errors summing to zero (the
        fit's gauge)."""
        err = {q: np.zeros(3) for q in sim.probes}
        if "sd_um" in cfg:
            vals = rng.normal(0, cfg["sd_um"], (len(sim.probes), 3))
            vals -= vals.mean(0)
            err = dict(zip(sim.probes, vals, strict=True))
        else:
            err.update({str(q): np.asarray(v, float) for q, v in cfg.items()})
        return {f"probe{q}.{a}": float(v[i]) for q, v in err.items()
                for i, a in enumerate("xyz")}

    @classmethod
    def check_sim(cls, cfg: dict, where: str, check: SimCheck) -> None:
        """Besides ``sd_um``: probes of the setup, each with a vector (µm)."""
        check.vectors_by_name(cfg, where, "sd_um", check.probes, "probe")

    @staticmethod
    def needs(obs: Observations) -> str | None:
        return "needs at least two probes" if len(obs.probes) < 2 else None

    def columns(self, obs: Observations) -> list[Column]:
        return [("probe_offset", [f"probe{q}.{a}" for q in obs.probes for a in "xyz"], "um")]

    def probe_stage(self, ev: Eval, p: np.ndarray) -> np.ndarray:
        return p + ev.x("probe_offset").reshape(-1, 3)[ev.obs.probe] * UM

    def jacobian(self, ev: Eval) -> Jacobian:
        o = ev.obs
        Jp = kin.probe_jacobian(self.problem.terms, ev.x("kinematic"), o.r_mm - o.p_mm)
        return [(per_group_cols(ev.start("probe_offset"), o.probe), Jp)]

    def constraints(self) -> np.ndarray | None:
        return np.tile(np.eye(3), (1, len(self.problem.obs.probes)))

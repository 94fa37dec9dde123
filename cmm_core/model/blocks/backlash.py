"""Reversal error (backlash) of each axis: a reading approached from + is short by half
the reversal span, one approached from - long by as much (µm, the full span fitted).
The approach direction follows every move of the file's measurement order
(``observations.approach_directions``).

New points are corrected for the direction from which their axes last moved (their
file order, or ``time_min``): ``e += span · d / 2`` per axis, d = ±1; an axis whose
direction is unknown (before it first moves) gets no correction and half the span as
standard uncertainty instead. The model file keeps ``backlash_um`` and
``cov_with_backlash`` (the joint covariance of the kinematic coefficients and the spans),
as it did before the blocks corrected new points.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType

import numpy as np
import pandas as pd

from ...io import DataError
from ...io.delimited import numeric_column
from ...io.errors import cut_repr
from ..observations import Observations, approach_directions
from .base import Block, Effect
from .compensation import Correction, ModelPart, checked_cov
from .context import Column, Eval, Jacobian, Shape, shared_cols
from .simulation import SimContext, SimParam

LABELS = tuple(f"backlash.{a}" for a in "xyz")


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
    sim_ranges = MappingProxyType({f"{a}_um": (-1e3, 1e3) for a in "xyz"})
    sim_label = "Backlash"
    sim_help = ("Reversal error: each axis reads short by half the span in the direction it "
                "last moved. Visible with serpentine or random order.")
    sim_params = tuple(SimParam(f"{a}_um", f"reversal span {a.upper()} (µm)", "um", 1.5,
                                -20.0, 20.0) for a in "xyz")
    physical_check = True

    @classmethod
    def detection_shapes(cls, labels: Sequence[str], positions: Sequence[str],
                         probes: Sequence[str]) -> list[Shape]:
        return [(f"{a} axis", {f"backlash.{a}": 1.0}) for a in "xyz"]

    @classmethod
    def injection(cls, values: dict[str, float]) -> dict | None:
        return {f"{lab[-1]}_um": v for lab, v in values.items()}

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng: np.random.Generator) -> dict[str, float]:
        return {f"backlash.{a}": float(cfg.get(f"{a}_um", 0.0)) for a in "xyz"}

    @staticmethod
    def needs(obs: Observations) -> str | None:
        if not (np.ptp(obs.approach, axis=0) == 2).any():
            return "every ball was approached from the same side along each axis"
        return None

    def columns(self, obs: Observations) -> list[Column]:
        return [("backlash", [f"backlash.{a}" for a in "xyz"], "um")]

    def reading_stage(self, ev: Eval, d: np.ndarray) -> np.ndarray:
        return d + ev.x("backlash") * ev.obs.approach / 2

    def jacobian(self, ev: Eval) -> Jacobian:
        o = ev.obs
        return [(shared_cols(ev.start("backlash"), 3, len(o.pos)),
                 np.eye(3)[None] * (o.approach / 2)[:, None, :])]

    # --- compensation of new points -----------------------------------------------------
    model_keys = ("backlash_um", "cov_with_backlash")
    model_what = "backlash spans"
    comp_units = "um"

    @classmethod
    def correction_columns(cls, labels: Sequence[str] | None = None) -> tuple[str, ...]:
        """``time_min``: the points' measurement order (else their file order)."""
        return ("time_min",)

    @classmethod
    def part_to_file(cls, part: ModelPart) -> dict:
        return {"backlash_um": part.values.tolist(), "cov_with_backlash": part.cov.tolist()}

    @classmethod
    def part_from_file(cls, d: dict, n_before: int, name: str) -> ModelPart | None:
        if "backlash_um" not in d:
            return None
        try:
            spans = np.asarray(d["backlash_um"], float)
            joint = np.asarray(d["cov_with_backlash"], float)
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"is not a model file written by 'fit --save' "
                            f"({cut_repr(str(exc), 80)}).", file=name) from None
        k = n_before + 3
        if spans.shape != (3,) or joint.shape != (k, k):
            raise DataError(f"expected 3 backlash spans and a {k}x{k} joint covariance, "
                            f"found {spans.shape} and {joint.shape}.", file=name)
        if not np.isfinite(spans).all():
            raise DataError("backlash_um must be 3 finite spans (µm).", file=name,
                            column="backlash_um")
        checked_cov(joint, k, name, "cov_with_backlash")
        return ModelPart(LABELS, spans, joint)

    @classmethod
    def correct(cls, part: ModelPart, points: pd.DataFrame, x_mm: np.ndarray,
                name: str) -> Correction:
        t = None
        if "time_min" in points:
            t = numeric_column(points, "time_min", name, allow_missing=True)
            t = t if np.isfinite(t).all() else None  # incomplete times: the file order
        d = approach_directions(x_mm, t)
        # unknown direction: the correction is ±span/2 with equal odds, σ = |span|/2
        return Correction(part.values * d / 2, np.eye(3)[None] * (d / 2)[:, None, :],
                          (d == 0) * (part.values / 2) ** 2,
                          {f"approach_{a}": d[:, i].astype(int) for i, a in enumerate("xyz")})

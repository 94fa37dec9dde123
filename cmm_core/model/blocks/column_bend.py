"""Column bending under the horizontal arm (issue 26): a non-rigid deflection of the arm's
tip that depends on both the arm's extension and the carriage's height on the column.

Mechanics, for the horizontal-arm layouts (``horizontal_arm_fxzy``: the column travels
along x, the carriage rides up and down the column along z and carries the arm, which
extends along y and holds the probe; ``horizontal_arm_fyzx``: the column travels along y
and the arm extends along x). Write ``u`` for the arm axis's reading and ``h`` for the z
reading, normalised to the strokes: ``l = 2u/U − 1`` and ``η = 2h/H − 1`` in [−1, 1].

1. The arm, of weight W, overhangs the column by ``L = L₀ + u`` (``L₀``: its overhang at
   the reading 0); its centre of mass stands ``∝ L`` from the column, so it loads the
   column at the carriage's height with a bending moment ``M = W L/2`` (plus the probe
   head's weight times L: the same form, ``M ∝ L``) about the horizontal axis
   perpendicular to the arm (the column's travel axis).
2. The column is an elastic cantilever clamped at its base (at ``h₀`` below the machine's
   z = 0, so its loaded length is ``h₀ + h``), loaded by the moment M at the carriage.
   A cantilever of length a under an end moment M turns at its end by ``θ = M a/(EI)``
   and deflects there by ``δ = M a²/(2EI)`` (the cantilever with a couple at its free
   end: Timoshenko & Gere, *Mechanics of Materials*, table of beam deflections, or any
   strength-of-materials text); the column above the carriage carries no moment and
   follows rigidly. So the carriage, and the arm with it, turns by
   ``θ ∝ L (h₀ + h)`` and moves along the arm's direction by ``δ ∝ L (h₀ + h)²``.
3. The tip, at the arm's end ``L`` from the column and ``p_z`` below the arm (the
   stylus), moves vertically by ``−θ L ∝ L² (h₀ + h)`` and along the arm by
   ``δ + θ p_z ∝ L (h₀ + h)² + p_z L (h₀ + h)``.

Expanded in the readings (``L = L₀ + u``, ``h₀ + h``), each of these is a polynomial in
u and h; a term of u alone or h alone is rigid (the arm's own straightness, the
carriage's straightness and rotations along z), and so is a vertical displacement
``f(h) · u``: it is the carriage's rotation about the column's travel axis as a
function of h (``rzx`` on Fxzy, ``rzy`` on Fyzx, at order 1, 2 ...) acting on the arm's
lever ``u``, which the kinematic model holds. What no rigid model holds are the cross
terms left:

- vertically, ``u² h`` (the tilt ``θ ∝ u h`` times the lever ``u``): a vertical bow of
  the arm whose size grows with the height;
- along the arm, ``u h`` and ``u h²`` (the shift ``δ`` and the tilt times the stylus):
  a scale of the arm that changes with height, linearly and quadratically. No rotation
  of any axis moves the tip along the arm in proportion to the arm's own reading.

In normalised coordinates ``u² h``, ``u h``, ``u h²`` are, up to rigid terms, ``l² η``,
``l η`` and ``l η²`` (``u ∝ l + 1``, ``h ∝ η + 1``: ``(l + 1)² (η + 1) = l² η + 2 lη``
``+ (rigid)``, the ``2 lη`` vertical part being rigid, above). The block fits exactly
these three, the tip's displacement at the strokes' corners (µm), the lowest order the
beam gives; the column's own taper or a moment that is not linear in L (an arm whose
counterweight moves) gives higher powers, left to the residual:

- ``column_bend.drop``: ``Δz = t_drop · l² · η``;
- ``column_bend.shear``: ``Δ_arm = t_shear · l · η`` (along the arm's axis);
- ``column_bend.bend``: ``Δ_arm = t_bend · l · η²``.

They are fitted free, not tied to one ``EI``: ``L₀``, ``h₀`` and the stylus length
``p_z`` are the machine's own and unknown. The tilt's product with a stylus's horizontal
offset (µrad × 100 mm, a tenth of a µm) and with the readings' errors is dropped. The
shapes are evaluated at the scale readings (the tip less the probe offset: where the
carriage and arm stand), a reading-stage term like ``bridge_twist``'s.

Bridges and gantries (``moving_bridge_*``, ``gantry_*``, ``fixed_bridge_*``) have no
arm on a column: their deflection under the carriage is ``bridge_twist`` or a rigid error
of the carriage's axis. There the block adds no parameter and says why.

New points are corrected with the same term at their readings (``compensate``): no
further columns are needed. The model file keeps the section ``column_bend``: the fitted
``bend_um`` and ``cov_joint``, the joint covariance of the kinematic coefficients, the
compensating blocks before it and these three; the strokes and the layout are the
model's own ``range_mm`` and ``layout``. A layout without an arm keeps no section.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType

import numpy as np
import pandas as pd

from ...machine import LAYOUTS
from ..observations import Observations
from .base import Effect, LayoutBlock
from .compensation import Correction, ModelPart
from .context import Eval
from .simulation import SimContext, SimParam

SHAPES = ("drop", "shear", "bend")
"""The deflection's shapes ``l²·η`` (vertical), ``l·η`` and ``l·η²`` (along the arm)."""
LABELS = tuple(f"column_bend.{k}" for k in SHAPES)
SECTION_KEYS = ("bend_um", "cov_joint")
"""Keys of the model file's ``column_bend`` section."""
ARMS = {name: chain for name, chain in LAYOUTS.items() if name.startswith("horizontal_arm")}
"""Layouts whose vertical carriage rides a column and carries a horizontal arm."""


def _axes(layout: str) -> int:
    """Index of the arm's axis (the last carried axis of the chain, ``Fxzy`` → y)."""
    return "xyz".index(ARMS[layout][3])


def basis(u_mm: np.ndarray, range_mm: Sequence[float] | np.ndarray,
          layout: str) -> np.ndarray:
    """The shapes ``l²·η``, ``l·η``, ``l·η²`` at scale readings ``u_mm`` (n, 3): (n, 3)
    (module docstring)."""
    c = _axes(layout)
    rng = np.asarray(range_mm, float)
    lv = 2.0 * u_mm[:, c] / rng[c] - 1.0
    eta = 2.0 * u_mm[:, 2] / rng[2] - 1.0
    return np.column_stack([lv**2 * eta, lv * eta, lv * eta**2])


def bend_columns(B: np.ndarray, layout: str) -> np.ndarray:
    """(n, 3, 3) µm per µm: the tip's motion for each parameter, ``e_z`` times the first
    shape and the arm's direction times the other two."""
    c = _axes(layout)
    cols = np.zeros((len(B), 3, 3))
    cols[:, 2, 0] = B[:, 0]
    cols[:, c, 1] = B[:, 1]
    cols[:, c, 2] = B[:, 2]
    return cols


class ColumnBend(LayoutBlock):
    """Bending of a horizontal-arm machine's column under the arm's moment (µm at the
    corners of the arm's and z strokes)."""

    token = "column_bend"
    entry = Effect(
        "column_bend", "column bending under the horizontal arm (non-rigid)",
        "the arm's weight, overhanging the column, puts a moment that grows with the arm's "
        "extension on the column at the carriage's height; the column, clamped at its "
        "base, tilts and leans by amounts that grow with that height, so the probe drops "
        "and shifts along the arm by an amount that depends on both the extension and the "
        "height, which no sum of single-axis (rigid) errors holds.",
        "placements spread along both the arm's stroke and the z stroke (vertical "
        "placements in the plane of the arm and z, or horizontal ones at several "
        "heights), on a horizontal-arm machine.",
        "higher orders of the arm's straightness in z (dyz, dxz ...) and of the carriage's "
        "rotation about the column's travel axis when few heights are measured, the arm's "
        "scale (positioning error) when one height dominates, and plate sag on "
        "horizontal placements alone.",
        "the same horizontal placement at the bottom and the top of the z stroke: a "
        "rigid error of the arm is the same at both, the column's bending grows with the "
        "height (the arm's length and its vertical bow change with z).")

    sim_keys = frozenset({f"{k}_um" for k in SHAPES})
    sim_ranges = MappingProxyType({k: (-1e3, 1e3) for k in sim_keys})
    sim_label = "Column bending (horizontal arm)"
    sim_help = ("The column of a horizontal-arm machine bending under the arm's moment: "
                "the tip drops and shifts along the arm by amounts that depend on both the "
                "arm's extension and the height (non-rigid; other layouts: no effect).")
    sim_params = (SimParam("drop_um", "drop l²·η (µm)", "um", 0.0, -20.0, 20.0, 0.5),
                  SimParam("shear_um", "along the arm l·η (µm)", "um", 0.0, -20.0, 20.0,
                           0.5),
                  SimParam("bend_um", "along the arm l·η² (µm)", "um", 0.0, -20.0, 20.0,
                           0.5))
    physical_check = True

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng: np.random.Generator) -> dict[str, float]:
        return {f"column_bend.{k}": float(cfg.get(f"{k}_um", 0.0)) for k in SHAPES}

    @classmethod
    def injection(cls, values: dict[str, float]) -> dict | None:
        return {f"{lab.split('.')[1]}_um": v for lab, v in values.items()}

    @staticmethod
    def needs(obs: Observations) -> str | None:
        if obs.layout not in ARMS:
            return (f"the {obs.layout} layout has no horizontal arm on a column (a bridge's "
                    "deflection under its carriage is bridge_twist or a rigid error of that "
                    "axis)")
        c = _axes(obs.layout)
        u = obs.r_mm - obs.p_mm
        rng = np.asarray(obs.range_mm, float)
        if np.ptp(u[:, c]) < 0.2 * rng[c] or np.ptp(u[:, 2]) < 0.2 * rng[2]:
            return (f"the balls cover less than a fifth of the {'xyz'[c]} (arm) or z "
                    "stroke, where the column's bending is a rigid error")
        return None

    layouts = ARMS
    labels = LABELS
    lacks = "horizontal arm on a column"
    layouts_what = "a horizontal-arm layout"
    section_keys = SECTION_KEYS
    values_what = "finite bendings (µm)"

    def motion(self, ev: Eval) -> np.ndarray:
        o = ev.obs
        return bend_columns(basis(o.r_mm - o.p_mm, o.range_mm, o.layout), o.layout)

    # --- compensation of new points -----------------------------------------------------
    model_keys = ("column_bend",)
    model_what = "column bending"
    comp_units = "um"

    @classmethod
    def correct(cls, part: ModelPart, points: pd.DataFrame, x_mm: np.ndarray,
                name: str) -> Correction:
        layout = part.context["layout"]
        cols = bend_columns(basis(x_mm, part.context["range_mm"], layout), layout)
        # the fit's reading stage (module docstring), per point
        return Correction(cols @ part.values, cols)

"""Bridge twist under the moving carriage (issue 26): a non-rigid roll of the bridge about
its travel axis whose size depends on where the carriage stands on the bridge.

Mechanics, for the moving bridge and the gantry (``moving_bridge_fxyz``, ``gantry_fxyz``:
the bridge travels along x and the y carriage runs across it; ``*_fyxz``: x and y
swapped). Write a for the bridge's travel axis and b for the carriage's axis across the
bridge, with the readings normalised to the strokes, ``s = 2a/A − 1`` and
``v = 2b/B − 1`` in [−1, 1]. The carriage and ram, of weight W, stand at b on a beam of
span ≈ B carried by two legs (moving bridge: on the granite; gantry: on raised rails).

1. The beam bends under the point load: the carriage drops by ``W b²(B−b)²/(3EIB)`` and
   tilts with the beam's slope ``∝ b(B−b)(B−2b)``; with the carriage hanging off the
   beam's shear centre by e, the torque ``W e`` twists the beam at the carriage by
   ``∝ b(B−b)/B`` (torsion of a beam held at both legs). All of these depend on b
   alone: they are the carriage axis's own straightness and rotations (``dbz``, ``rba``,
   ``rbb``), which the kinematic model already holds at the next orders.
2. The load goes to the legs in the ratio of the lever arms: ``F_far = W b/B``,
   ``F_near = W (B − b)/B``. A leg whose support has the compliance ``c(a)`` (air
   bearings, granite, a rail between its pillars) sinks by ``c(a) F``, so the bridge
   rolls about its travel axis by ``θ = (c_near F_near − c_far F_far)/B``. With
   ``c_near = c_far = c(a)`` this is ``θ(a, b) = −c(a) W v / B``: the bridge's weight
   part (b-independent) is the rigid roll ``raa(a)``, a compliance constant along the
   travel gives ``θ ∝ v`` (again rigid: ``rba`` and ``dbz`` of the carriage axis, as a
   roll depending on b alone acts on the lever ``b e_b`` as a straightness of b), and
   what no rigid model holds is the product of how the compliance changes along the
   travel with the load share: ``θ(a, b) = v · g(s)``.

How the compliance changes along the travel, ``g(s)``, is the machine's own: one end of
the granite or rail stiffer (``g ∝ s``), a rail simply supported at the ends of the
travel (a gantry's rail between its pillars: deflection under a moving point load
``∝ s²(1 − s)²`` in the travel fraction, ``(1 − s²)²`` in s, even), an asymmetric
support (odd and even parts mixed). Any smooth g is, on the stroke, its Taylor
polynomial; its constant is rigid (above), so the block fits the three lowest powers,
the roll at the stroke's corners (µrad) of each:

- ``bridge_twist.lin``: ``θ = t_lin · s · v``;
- ``bridge_twist.quad``: ``θ = t_quad · s² · v`` (the even part: a bow of the supports'
  compliance along the travel; the rail between pillars, ``(1 − s²)² = 1 − 2s² + s⁴``,
  is the rigid constant, ``−2 s²`` and the quartic, whose least-squares remainder on the
  cubic, ``(8/35) P₄(s)`` (Legendre), is at most 23 % of the shape's range and is left
  to the residual);
- ``bridge_twist.cub``: ``θ = t_cub · s³ · v`` (the odd part's bend).

Why three and not two (issue 26): with the two shapes ``s·v`` and ``(1 − s²)² v`` of the
first version, a twist ``s³·v`` or ``s²·v`` was only partly held by the block, and the
rest of its pattern, on placements whose load share v is not balanced along the travel
(``Σ v ≠ 0`` over a placement's balls), is a roll that depends on s alone: the rigid
``rxx:3`` (bridge FXYZ, 100 mm layout) or, through tilted placements where z follows the
travel, ``rzy:3`` (bridge FYXZ, 80 mm layout) explained more χ² per parameter than the
block and was named first (2 of 40 loops of ``bench/nonrigid.py``). On those cases the
cubic family removes 50 and 73 units of χ² where the two-shape block removed 21 and 39
(and the quartic only 2 and 1 more, for two more parameters): the cubic is the lowest
order that holds both. Once the block holds the whole twist, the rigid term adds nothing
given it while the block is still needed given the rigid term, and the diagnosis's
nested test (``diagnosis.verdict``) names the block. Measured (``bench/nonrigid.py``,
items 3 and 4): twists of seven shapes on four bridge and gantry layouts are never named
as a rigid higher order before the twist (0 of 112 loops, and 0 of 112 with the shapes
at the carriage's readings), and real rigid third orders at their detection limit are
never named as the twist (0 of 420).

What the cubic leaves. A twist's constant part in s, ``θ ∝ v`` (item 2: a compliance
the same all along the travel), is rigid, but on the scenario designs only one order
above ``kinematic21``'s (``kinematic21:3`` holds it to noise, ``kinematic21`` does not):
a twist with a large mean over the travel, such as the rail between pillars
``(1 − s²)²`` (mean 8/15 of its peak), is named as the twist and then as a rigid higher
order (``rzx:4``, ``rxy:4``, ``rzy:3``), which is that constant part: the same physics,
rigid. The block does not fit the constant: it would be the rigid terms' own direction
and take real rigid effects.

The roll turns everything the bridge carries about the line it rocks on: the lever is
the tip relative to it. With the line at height ``z0``, ``w − z0 e_z``, ``w = (carried
readings) + p`` (the tip with its a coordinate replaced by the probe's), and the true tip
moves by ``θ e_a × (w − z0 e_z)`` (first order; the products with the other errors,
µrad × µm, are dropped). The line's height in the machine's frame is not known: a moving
bridge rocks on its bearings on the table, below the machine's z = 0 by the ram's lowest
reach; a gantry rocks on rails raised to the top of its stroke and above. So the block
also fits ``θ_k z0`` for each shape as its own parameter, the tip's shear along the
carriage's axis ``e_a × (−Z e_z)`` (``Z`` = 1 m: µrad, the twist times the line's height
in metres):

- ``bridge_twist.lin_h``, ``bridge_twist.quad_h``, ``bridge_twist.cub_h``: ``t_k z0/Z``.

A shear of the carriage's axis that grows with ``s·v`` is no rigid error either (a scale
of b that changes along a). Fitted free, not tied to ``t_k z0``, they also take a
line that is not level. Without them a gantry's twist (z0 ≈ 1 m above the table) left
most of its pattern to high orders and the plate's sag (``tests/scenarios.py``,
``bridge_roll``: plate_sag named on gantry_fxyz, pitch150_5pos). It is a reading stage
term like ``machine_thermal``'s, evaluated at the scale readings.

Fixed bridges (``fixed_bridge_*``) do not move: their deflection under the carriage
depends on the carriage alone (rigid, item 1); the horizontal arm's column bends under
the arm (another effect). There the block adds no parameter and says why.

New points are corrected with the same term at their readings (``compensate``): no
further columns are needed. The model file keeps the section ``bridge_twist``: the
fitted ``twist_urad`` and ``cov_joint``, the joint covariance of the kinematic
coefficients, the compensating blocks before it and these six (a file of the first
version's two shapes ``s·v`` and ``(1 − s²)² v``, with or without their height terms: 2
or 4 twists, is still read and corrects with those shapes); the strokes and the
layout are the model's own ``range_mm`` and ``layout``. A layout without a bridge keeps
no section (a file of a bridge layout whose spec has the block must have it).
"""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType

import numpy as np
import pandas as pd

from ...machine import LAYOUTS
from ...units import UM, URAD
from ..observations import Observations
from .base import Effect, LayoutBlock
from .compensation import Correction, ModelPart
from .context import Eval, Shape
from .simulation import SimContext, SimParam

SHAPES = ("lin", "quad", "cub")
"""The twist's shapes ``g(s) = s, s², s³`` (module docstring)."""
LABELS = tuple(f"bridge_twist.{k}" for k in SHAPES) + tuple(
    f"bridge_twist.{k}_h" for k in SHAPES)
OLD_LABELS = ("bridge_twist.lin", "bridge_twist.mid", "bridge_twist.lin_h",
              "bridge_twist.mid_h")
"""The first version's parameters (shapes ``s·v``, ``(1 − s²)² v``): model files with 2
or 4 twists are read with these."""
Z_REF_MM = 1000.0
"""Reference height ``Z`` of the height terms (module docstring): 1 m."""
SECTION_KEYS = ("twist_urad", "cov_joint")
"""Keys of the model file's ``bridge_twist`` section."""
BRIDGES = {name: chain for name, chain in LAYOUTS.items()
           if name.startswith(("moving_bridge", "gantry"))}
"""Layouts whose first tool carriage is a moving bridge carrying the second."""


def _axes(layout):
    """``(a, b)``: indices of the bridge's travel axis and the carriage's axis on it."""
    chain = BRIDGES[layout]
    return "xyz".index(chain[1]), "xyz".index(chain[2])


def power_basis(u_mm: np.ndarray, range_mm: Sequence[float] | np.ndarray, layout: str,
                powers: Sequence[int]) -> np.ndarray:
    """``s^k · v`` at scale readings ``u_mm`` (n, 3) for each power k: (n, len(powers))
    (module docstring; ``diagnosis.crossval`` tests a rigid term against the twist's
    next power, k = 4)."""
    a, b = _axes(layout)
    rng = np.asarray(range_mm, float)
    s = 2.0 * u_mm[:, a] / rng[a] - 1.0
    v = 2.0 * u_mm[:, b] / rng[b] - 1.0
    return np.column_stack([s**k * v for k in powers])


def basis(u_mm: np.ndarray, range_mm: Sequence[float] | np.ndarray, layout: str,
          old: bool = False) -> np.ndarray:
    """The twist shapes at scale readings ``u_mm`` (n, 3): (n, 3), ``s·v``, ``s²·v``,
    ``s³·v`` (module docstring); ``old``: (n, 2), the first version's ``s·v`` and
    ``(1 − s²)² v`` (model files of 2 or 4 twists)."""
    if old:
        a, b = _axes(layout)
        rng = np.asarray(range_mm, float)
        s = 2.0 * u_mm[:, a] / rng[a] - 1.0
        v = 2.0 * u_mm[:, b] / rng[b] - 1.0
        return np.column_stack([s * v, (1.0 - s**2) ** 2 * v])
    return power_basis(u_mm, range_mm, layout, (1, 2, 3))


def height_direction_um(n: int, layout: str) -> np.ndarray:
    """``e_a × (−Z e_z)`` in µm per µrad (n, 3): the tip's shear for a unit height term
    (the roll about a line ``Z`` above the machine's z = 0, less the roll about z = 0)."""
    a, _ = _axes(layout)
    d = np.cross(np.eye(3)[a], -Z_REF_MM * np.eye(3)[2]) * (URAD / UM)
    return np.broadcast_to(d, (n, 3))


def direction_um(r_mm: np.ndarray, u_mm: np.ndarray, layout: str) -> np.ndarray:
    """``e_a × w`` in µm per µrad of roll: the tip's motion for a unit roll of the bridge,
    ``w`` the tip relative to the bridge's reference line (reported tip ``r_mm`` with its
    a coordinate replaced by the probe's, ``r_a − u_a``)."""
    a, _ = _axes(layout)
    w = np.array(r_mm, float, copy=True)
    w[:, a] -= u_mm[:, a]
    return np.cross(np.eye(3)[a], w) * (URAD / UM)


def twist_columns(B: np.ndarray, r_mm: np.ndarray, u_mm: np.ndarray, layout: str,
                  heights: bool = True) -> np.ndarray:
    """(n, 3, k) µm per µrad: the tip's motion for each parameter, the shapes ``B`` (n, m)
    times the roll's lever (:func:`direction_um`) and then (``heights``) times the height
    terms' shear (:func:`height_direction_um`): k = 2m, or m without the height terms (a
    model file of the first version's two shapes alone)."""
    g = direction_um(r_mm, u_mm, layout)
    cols = [g[:, :, None] * B[:, None, :]]
    if heights:
        cols.append(height_direction_um(len(B), layout)[:, :, None] * B[:, None, :])
    return np.concatenate(cols, axis=2)


class BridgeTwist(LayoutBlock):
    """Roll of the bridge about its travel axis that grows with the carriage's load share
    (µrad at the corners of the strokes), with the height of the line it rolls about."""

    token = "bridge_twist"
    entry = Effect(
        "bridge_twist", "bridge twist under the carriage (non-rigid)",
        "the carriage's weight loads the bridge's two legs in the ratio of its position "
        "across the bridge, and the legs' supports yield differently along the travel: the "
        "bridge rolls about its travel axis by an angle that depends on both the bridge's "
        "and the carriage's position, which no sum of single-axis (rigid) errors holds.",
        "placements spread along both the bridge's travel and the carriage's axis, with "
        "lever arms across the bridge (points at several heights or probe offsets), on a "
        "moving bridge or gantry.",
        "higher orders of the bridge's roll (rxx:3 ...), the carriage's straightness dyz and "
        "roll ryx when the placements cover few bridge positions, and plate sag (a twisted "
        "plate) on horizontal placements alone.",
        "the same horizontal placement at the two ends of the travel (or a vertical "
        "placement across the bridge at two bridge positions): a rigid roll is the same "
        "at both, the twist changes sign with the carriage's side.")

    sim_keys = frozenset({f"{k}_urad" for k in SHAPES} | {f"{k}_h_urad" for k in SHAPES}
                         | {"axis_height_mm"})
    sim_ranges = MappingProxyType({**{k: (-1e3, 1e3) for k in sim_keys},
                                   "axis_height_mm": (-1e4, 1e4)})
    sim_label = "Bridge twist (carriage load)"
    sim_help = ("A roll of a moving bridge or gantry about its travel axis that depends on "
                "where the carriage stands on it (non-rigid; other layouts: no effect).")
    sim_params = (SimParam("lin_urad", "twist s·v (µrad)", "urad", 3.0, -20.0, 20.0, 0.5),
                  SimParam("quad_urad", "twist s²·v (µrad)", "urad", 0.0, -20.0, 20.0, 0.5),
                  SimParam("cub_urad", "twist s³·v (µrad)", "urad", 0.0, -20.0, 20.0, 0.5),
                  SimParam("axis_height_mm", "height of the line it rolls about (mm)",
                           "mm", 0.0, -1000.0, 2000.0, 50.0))
    physical_check = True

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng: np.random.Generator) -> dict[str, float]:
        z0 = float(cfg.get("axis_height_mm", 0.0)) / Z_REF_MM
        out = {}
        for k in SHAPES:
            t = float(cfg.get(f"{k}_urad", 0.0))
            out[f"bridge_twist.{k}"] = t
            out[f"bridge_twist.{k}_h"] = t * z0 + float(cfg.get(f"{k}_h_urad", 0.0))
        return out

    @classmethod
    def detection_shapes(cls, labels: Sequence[str], positions: Sequence[str],
                         probes: Sequence[str]) -> list[Shape]:
        """The twist's shapes about the machine's z = 0 (the height terms are the same
        roll about another line, not an effect of their own)."""
        return [(f"{lab} alone", {lab: 1.0}) for lab in labels if not lab.endswith("_h")]

    @classmethod
    def injection(cls, values: dict[str, float]) -> dict | None:
        return {f"{lab.split('.')[1]}_urad": v for lab, v in values.items()}

    @staticmethod
    def needs(obs: Observations) -> str | None:
        if obs.layout not in BRIDGES:
            return (f"the {obs.layout} layout has no moving bridge carrying a carriage (a fixed "
                    "bridge's deflection under its carriage is a rigid error of that axis)")
        a, b = _axes(obs.layout)
        u = obs.r_mm - obs.p_mm
        rng = np.asarray(obs.range_mm, float)
        if np.ptp(u[:, a]) < 0.2 * rng[a] or np.ptp(u[:, b]) < 0.2 * rng[b]:
            return (f"the balls cover less than a fifth of the {'xyz'[a]} or {'xyz'[b]} "
                    "stroke, where the twist is a rigid roll")
        return None

    layouts = BRIDGES
    labels = LABELS
    lacks = "moving bridge carrying a carriage"
    layouts_what = "a moving bridge or gantry layout"
    sim_shape_keys = frozenset({"axis_height_mm"})  # where the roll's axis is, not a size
    section_keys = SECTION_KEYS
    values_what = "finite twists (µrad)"

    def motion(self, ev: Eval) -> np.ndarray:
        """Each parameter's motion of the tip (:func:`twist_columns`) at the readings."""
        o = ev.obs
        u = o.r_mm - o.p_mm
        return twist_columns(basis(u, o.range_mm, o.layout), o.r_mm, u, o.layout)

    # --- compensation of new points -----------------------------------------------------
    model_keys = ("bridge_twist",)
    model_what = "bridge twist"
    comp_units = "urad"

    @classmethod
    def labels_in_file(cls, k: int) -> tuple[str, ...] | None:
        # 6 terms; 2 or 4 in a file of the first version (shapes s·v, (1 − s²)² v)
        return LABELS if k == len(LABELS) else OLD_LABELS[:k] if k in (2, 4) else None

    @classmethod
    def correct(cls, part: ModelPart, points: pd.DataFrame, x_mm: np.ndarray,
                name: str) -> Correction:
        layout = part.context["layout"]
        r = points[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
        old = len(part.values) != len(LABELS)  # a file of the first version
        B = basis(x_mm, part.context["range_mm"], layout, old=old)
        cols = twist_columns(B, r, x_mm, layout, heights=len(part.values) != 2)
        # the fit's reading stage (module docstring), per point
        return Correction(cols @ part.values, cols)

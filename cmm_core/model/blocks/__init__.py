"""Effect blocks: one physical effect, one class, one module (``base.Block`` protocol; the
types a block works with in ``context``, ``simulation`` and ``compensation``).

The fit (``problem.Problem``) lays out its parameters, evaluates residuals and Jacobians and
collects gauge constraints by looping over :data:`REGISTRY`; the diagnosis asks
:func:`needs` whether the data can see an effect. Adding an effect is adding one module
with its block and listing it here (its catalogue text is the block's ``entry``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from . import periodic
from .backlash import Backlash
from .base import Block
from .bridge_twist import BridgeTwist
from .column_bend import ColumnBend
from .context import Eval
from .drift import Drift
from .kinematic import Kinematic
from .machine_thermal import MachineThermal
from .placement import Placement
from .plate import Plate
from .plate_sag import PlateSag
from .plate_thermal import PlateThermal
from .probe_offset import ProbeOffset

if TYPE_CHECKING:
    from ..observations import Observations

__all__ = ["REGISTRY", "BY_TOKEN", "Block", "Eval", "needs"]

REGISTRY = (Plate, Placement, Kinematic, PlateThermal, PlateSag, ProbeOffset, Drift,
            Backlash, MachineThermal, BridgeTwist, ColumnBend)
"""Blocks in parameter-layout order, which is also the catalogue's order of physical
effects (``effects.PHYSICAL``, model specs written out) and the order in which the stages
run (thermal expansion before sag)."""

BY_TOKEN = {b.token: b for b in REGISTRY if b.token}


def needs(token: str, obs: Observations) -> str | None:
    """Why ``obs`` cannot determine the effect ``token`` adds (None: they can)."""
    name = token.partition(":")[0]
    if name in BY_TOKEN and not len(obs.r_mm):
        # instruments see the kinematic terms only (periodic ones included)
        return "it acts on ball-plate observations, and an instrument-only fit has none"
    if name in BY_TOKEN:
        return BY_TOKEN[name].needs(obs)
    if name in periodic.PERIODIC and not len(obs.r_mm):
        return ("its period is scanned over the ball spacing, and an instrument-only fit "
                "has no ball; a stated period (periodic_x:180) is fitted")
    if name in periodic.PERIODIC:
        return periodic.needs(obs, name)
    return None

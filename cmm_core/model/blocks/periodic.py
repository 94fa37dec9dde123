"""Periodic scale errors (``periodic_x:PERIOD_MM``): a sine and a cosine of the axis
reading added to that axis's positioning function (``dxx``, ``dyy``, ``dzz``), as a lead
screw or a scale's graduation error would (``kinematics.periodic_basis``). Their columns
ride in the kinematic block's terms; this module holds what the data must resolve."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..observations import Observations

PERIODIC = {"periodic_x": "dxx", "periodic_y": "dyy", "periodic_z": "dzz"}
"""Periodic scale error tokens (``periodic_x:200``: period 200 mm) and the positioning
function each one adds to."""

PERIOD_SCAN = (40.0, 36)
"""Shortest period scanned (mm) and the number of periods, spaced geometrically up to the
span of the balls along the axis (longer periods are what a higher polynomial order
describes). The shortest period is raised to what the ball spacing resolves
(:func:`shortest_resolvable_period`)."""

NYQUIST_FACTOR = 2.5
"""A period is scanned only when it is at least this many ball spacings long in every
placement that moves along the axis. Below two spacings a period is sampled as another
one (aliasing); just above two, five balls a row cannot tell a sinusoid from anything
that varies from ball to ball or placement to placement (certificate errors, a
placement's own scale), so a margin is kept."""


def shortest_resolvable_period(obs: Observations, axis: int) -> tuple[float, float]:
    """Shortest period (mm) of a periodic error along ``axis`` that the design resolves,
    and the ball spacing behind it: ``NYQUIST_FACTOR`` times the largest spacing of
    distinct ball coordinates along the axis in any placement-and-stylus group that
    moves along it (each placement samples the error on its own grid; a period its grid
    aliases can be fitted by anything that differs between placements)."""
    u = (obs.r_mm - obs.p_mm)[:, axis]
    spacing = 0.0
    for k in range(len(obs.positions)):
        for q in range(len(obs.probes)):
            v = np.sort(u[(obs.pos == k) & (obs.probe == q)])
            if v.size < 2 or np.ptp(v) < 5.0:
                continue  # this group does not move along the axis
            gaps = np.diff(v)
            gaps = gaps[gaps > 2.0]  # readings of one ball row are one coordinate
            if gaps.size:
                spacing = max(spacing, float(np.median(gaps)))
    return max(NYQUIST_FACTOR * spacing, PERIOD_SCAN[0]), spacing


def needs(obs: Observations, token: str) -> str | None:
    """Why a periodic error along the token's axis cannot be resolved (None: it can)."""
    axis = token.partition(":")[0][-1]
    a = "xyz".index(axis)
    span = np.ptp((obs.r_mm - obs.p_mm)[:, a])
    if span < 2 * PERIOD_SCAN[0]:
        return f"the balls hardly move along {axis}"
    shortest, spacing = shortest_resolvable_period(obs, a)
    if shortest > 0.8 * span:
        return (f"the ball spacing along {axis} ({spacing:.0f} mm) resolves no period "
                f"shorter than {shortest:.0f} mm, and longer ones up to the "
                f"{span:.0f} mm span are what a higher order describes")
    return None

"""A probable blunder in an interim check: one ball centre off, not the machine.

A 0.3 mm misprobe in a check of 200 ball centres fails the χ² test, and the refit then
spreads it over 25 parameters that "moved". Before the machine is blamed the check asks
whether a few observations alone explain the failure:

- the ball centre of largest normalised residual ``z = |residual| / u`` (any of its
  three coordinates) is beyond the Bonferroni bound of the check's ``m`` coordinates,
  ``2 Φ(-z) · m < alpha`` (a single outlier test at the check's level, Pope 1976's
  τ-test with the check's own residual uncertainties);
- left out, the check is made again; at most :data:`MAX_BLUNDERS` are left out one after
  another, and they are called probable blunders only when the check without them
  **passes**: an observation that stands out because the machine changed (a crash's
  squareness leaves its largest residuals beyond the bound too) leaves a failing check
  behind, and then nothing is called a blunder.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..units import p_text
from .check import InterimCheck

MAX_BLUNDERS = 3
"""At most this many ball centres are left out as probable blunders."""


@dataclass(frozen=True)
class Blunder:
    """One ball centre the check leaves out as a probable blunder."""

    position: str
    """Its placement."""
    probe: str
    """Its stylus."""
    ball: int
    """Its ball number."""
    residual_um: tuple[float, float, float]
    """Measured minus predicted, x y z (µm), after the pose fit."""
    z: float
    """Its largest normalised residual (|residual| / u)."""
    p_bonferroni: float
    """``2 Φ(-z) · m``: its single-outlier test over the check's ``m`` coordinates."""

    @property
    def key(self) -> tuple[str, str, int]:
        """``(position, probe, ball)``: how the check's ``exclude`` names it."""
        return (self.position, self.probe, self.ball)

    def text(self) -> str:
        """``ball 13 of H0 with stylus B, off by (+300.1, -0.2, +0.4) µm (z = 290)``."""
        r = ", ".join(f"{v:+.1f}" for v in self.residual_um)
        return (f"ball {self.ball} of {self.position} with stylus {self.probe}, off by "
                f"({r}) µm (z = {self.z:.3g}, Bonferroni {p_text(self.p_bonferroni)})")

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {"position": self.position, "probe": self.probe, "ball": self.ball,
                "residual_um": list(self.residual_um), "z": self.z,
                "p_bonferroni": self.p_bonferroni}


def worst_observation(check: InterimCheck, alpha: float) -> Blunder | None:
    """The ball centre beyond the Bonferroni bound of the check's coordinates (module
    docstring), or None."""
    t = check.table
    if not len(t):
        return None
    r = t[["dx_um", "dy_um", "dz_um"]].to_numpy(float)
    u = t[["u_dx_um", "u_dy_um", "u_dz_um"]].to_numpy(float)
    z = np.where(u > 0, np.abs(r) / np.where(u > 0, u, 1.0), 0.0)
    i = int(np.argmax(z.max(axis=1)))
    zi = float(z[i].max())
    p = min(1.0, float(2 * stats.norm.sf(zi)) * z.size)
    if p >= alpha:
        return None
    row = t.iloc[i]
    return Blunder(str(row["position"]), str(row["probe"]), int(row["ball"]),
                   tuple(float(v) for v in r[i]), zi, p)  # type: ignore[arg-type]


def find_blunders(check: InterimCheck, recheck: Callable[[list], InterimCheck],
                  alpha: float) -> tuple[list[Blunder], InterimCheck]:
    """Probable blunders of a failing check and the check without them.

    ``recheck(keys)`` makes the check again without the observations ``keys``. Returns
    ``([], check)`` unless leaving out at most :data:`MAX_BLUNDERS` ball centres, each
    beyond the Bonferroni bound when it is left out, makes the check pass.
    """
    found: list[Blunder] = []
    current = check
    while not current.passes and len(found) < MAX_BLUNDERS:
        b = worst_observation(current, alpha)
        if b is None:
            break
        found.append(b)
        current = recheck([f.key for f in found])
    return (found, current) if found and current.passes else ([], check)

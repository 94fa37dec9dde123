"""Degenerate GP optima: collapsed, bounded or signal-free hyperparameters.

An optimum of the marginal likelihood is degenerate when the GP it gives is (close to)
white noise (no two distinct training points within two length scales of each other),
a continuous length scale sits at its lower bound or all at their upper bound (the data
show no correlation length), or σ_f sits at its lower bound (no signal). Thesis appendix 3
(the plate with a 100 mm pitch and an 87 mm optimum) sets the collapse threshold; the
rules are listed in ``cmm_core.gp.fit_gp``, Notes, which offers the next-best optimum as
``GPResult.alternative`` when the best is degenerate.

See Also
--------
cmm_core.gp : ``fit_gp``, the caller.
"""

from __future__ import annotations

import numpy as np

_SAME_POINT = 1e-3  # inputs closer than this times the input extent are one location
# collapsed: the closest distinct points are more than this many length scales apart
# (correlation below exp(-2) = 0.14). Not 1: the thesis appendix 3 plate (pitch 100 mm)
# has its optimum at 87 mm, neighbours correlated by 0.52, a working GP.
_COLLAPSE_SPACINGS = 2.0


def _spacing(prob):
    """Smallest distance between distinct training locations (standardised units; points
    closer than ``_SAME_POINT`` are one location) and the mask of distinct pairs."""
    d2 = prob.D2.sum(axis=0)
    far = d2 > _SAME_POINT**2
    return (float(np.sqrt(d2[far].min())) if far.any() else float("nan")), far


def _degeneracy(prob, theta, lb, ub, far, spacing_s, x_scale, cont) -> dict:
    """``degenerate``, ``degenerate_reason`` and ``smallest_spacing_mm`` at ``theta``."""
    nl = prob.n_length()
    reasons = []
    lengths = np.exp(theta[:nl]) * x_scale
    spacing_mm = spacing_s * x_scale
    if far.any():
        nearest = float(np.sqrt(prob.scaled_d2(theta[:nl])[far].min()))
        if nearest > _COLLAPSE_SPACINGS * (1 + 1e-6):
            if nl == 1:
                reasons.append(f"the length scale {lengths[0]:.3g} mm is below half the "
                               f"smallest spacing {spacing_mm:.3g} mm between distinct points")
            else:
                reasons.append(f"the length scales {', '.join(f'{v:.3g}' for v in lengths)} "
                               "mm leave no two distinct points within two length scales of "
                               f"each other (smallest spacing {spacing_mm:.3g} mm)")
            reasons[-1] += (f": neighbouring points are correlated by less than "
                            f"{np.exp(-0.5 * _COLLAPSE_SPACINGS**2):.2f}, the GP is (close "
                            "to) white noise and predicts nothing between them")
    low = [g for g in cont if ub[g] > lb[g] and theta[g] - lb[g] < 1e-6]
    high = [g for g in cont if ub[g] > lb[g] and ub[g] - theta[g] < 1e-6]
    if low:
        reasons.append("length scale " + ", ".join(f"{lengths[g]:.3g}" for g in low)
                       + " mm at its lower bound")
    if cont and len(high) == len(cont):
        reasons.append("length scale " + ", ".join(f"{lengths[g]:.3g}" for g in high)
                       + " mm at its upper bound: the data show no correlation length")
    if ub[nl] > lb[nl] and theta[nl] - lb[nl] < 1e-6:
        reasons.append("signal sd at its lower bound: the GP carries no signal")
    return {"degenerate": bool(reasons), "degenerate_reason": "; ".join(reasons),
            "smallest_spacing_mm": float(spacing_mm)}

"""Blunders first: flagged outliers that carry the misfit are named before any effect.

A gross error of tens of µm among sub-µm residuals dominates χ²: every candidate effect
is then scored, and σ estimated, against residuals that are mostly the blunder, and the
verdict becomes whatever bends furthest towards it (usually ``outside_catalogue`` with a
σ several times the true one). The rule (issue 26, point 1):

    the flagged observations dominate when they hold more than half of the baseline's
    excess χ² (its χ² above the number of degrees of freedom, i.e. above what noise at
    the stated σ gives), counting against them the χ² noise alone would give them
    (one per coordinate).

Rationale: the excess χ² is what the diagnosis explains. When more than half of it sits in
a handful of flagged coordinates, any effect or σ fitted to the residuals is fitted mostly
to them, so the only sound next step is to exclude them and diagnose again. When a real
effect carries most of the excess, the effect is named as usual and the flagged outliers
are only listed (the app's warning above the diagnosis). The outliers themselves are
flagged by :func:`outliers.detect_outliers` (robust, MAD-based, across placements).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ..io import Dataset
from ..model import FitResult
from .outliers import detect_outliers

BLUNDERS = "flagged_outliers"
"""Verdict when flagged outliers dominate the baseline's misfit (:func:`blunder_check`)."""

DOMINANT_SHARE = 0.5
"""Share of the baseline's excess χ² above which the flagged outliers dominate it."""

ACTION = ("exclude them and run the diagnosis again (in the app: the button \"Exclude the "
          "flagged outliers\" on the Compare and diagnose page; on the command line: "
          "--exclude-outliers)")
"""The one action the message offers when the outliers dominate."""


@dataclass(frozen=True)
class BlunderCheck:
    """The flagged outliers still in the fit, and how much of its misfit they hold.

    Attributes
    ----------
    observations : list of dict
        ``{"position", "probe", "ball", "axis", "deviation_um", "source", "row",
        "chi2"}`` per flagged coordinate still in the fit, largest first; ``chi2`` is
        the baseline's χ² of the whole observation (its three coordinates, against σ).
    chi2_share : float
        Share of the baseline's χ² held by the flagged observations (0-1).
    excess_share : float
        Share of the baseline's excess χ² (χ² minus its degrees of freedom) held by the
        flagged observations, less the χ² noise alone gives them (the rule's statistic).
    dominant : bool
        True when ``excess_share`` exceeds :data:`DOMINANT_SHARE` and the baseline fails
        its χ² test: the verdict is :data:`BLUNDERS`.
    exclusions : list of tuple
        ``(position, probe, ball)`` of the flagged observations, for ``exclude=``.
    """

    observations: list
    chi2_share: float
    excess_share: float
    dominant: bool
    exclusions: list

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"observations": self.observations, "chi2_share": self.chi2_share,
                "excess_share": self.excess_share, "dominant": self.dominant,
                "exclusions": [list(e) for e in self.exclusions], "action": ACTION}

    def text(self, limit: int = 3) -> str:
        """``H0/A ball 18 y (39.8 µm, measurements.csv row 19)`` for the first few."""
        parts = []
        for o in self.observations[:limit]:
            where = (f", {o['source']} row {o['row']}" if o.get("source") is not None
                     and o.get("row") is not None else "")
            parts.append(f"{o['position']}/{o['probe']} ball {o['ball']} {o['axis']} "
                         f"({o['deviation_um']:+.1f} µm{where})")
        more = len(self.observations) - limit
        return "; ".join(parts) + (f" and {more} more" if more > 0 else "")

    def message(self) -> str:
        """The verdict in words: which observations, what share of the misfit, the
        action, and why nothing else is offered."""
        n = len(self.exclusions)
        return (f"Flagged outlier(s) first: {n} observation(s) flagged as gross errors hold "
                f"{100 * self.chi2_share:.0f} % of the baseline's χ² "
                f"({100 * self.excess_share:.0f} % of its misfit above noise): "
                f"{self.text()}. Action: {ACTION}. No effect is named and σ is not "
                "estimated from these residuals, which the outliers dominate; the "
                "candidates below are scored with them in and are not a verdict.")


def blunder_check(data: Dataset | object, base: FitResult,
                  exclude: Iterable[tuple[str, str, int]] = ()) -> BlunderCheck | None:
    """The flagged outliers of ``data`` not yet excluded, and their share of ``base``'s χ²
    (rule and rationale: module docstring). None when ``data`` is not a Dataset (no
    readings to flag) or nothing flagged is left in the fit."""
    if not isinstance(data, Dataset):
        return None
    done = {(str(p), str(q), int(b)) for p, q, b in exclude}
    rep = detect_outliers(data)
    flagged = [o for o in rep.outliers
               if (str(o["position"]), str(o["probe"]), int(o["ball"])) not in done]
    if not flagged:
        return None
    o = base.problem.obs
    chi_obs = ((base.residuals_um / base.sigma_um) ** 2).sum(axis=1)
    key = {(str(o.positions[i]), str(o.probes[j]), int(o.balls[k])): n
           for n, (i, j, k) in enumerate(zip(o.pos, o.probe, o.ball, strict=True))}
    rows, seen = [], set()
    for f in flagged:
        k = (str(f["position"]), str(f["probe"]), int(f["ball"]))
        if k not in key:  # not in this fit's selection (positions=, probes=)
            continue
        seen.add(k)
        rows.append({**{c: f[c] for c in ("position", "probe", "ball", "axis",
                                          "deviation_um", "source", "row")},
                     "chi2": float(chi_obs[key[k]])})
    if not rows:
        return None
    idx = [key[k] for k in sorted(seen)]
    total = float(chi_obs.sum())
    chi_flag = float(chi_obs[idx].sum())
    # noise alone gives each coordinate χ² ≈ 1: that much of theirs is not excess
    comps = float(np.count_nonzero(base.residuals_um[idx]))
    excess = max(base.chi2 - base.dof, 1e-300)
    excess_share = float(np.clip((chi_flag - comps) / excess, 0.0, 1.0))
    return BlunderCheck(rows, chi_flag / max(total, 1e-300), excess_share,
                        bool(base.fails_chi2_test and excess_share > DOMINANT_SHARE),
                        sorted(seen))

"""Leave-one-placement-out check: does an effect predict placements it was not fitted to?

An F-test or ΔBIC rewards whatever lowers χ² on the data it was fitted to. A flexible
alias (a periodic error whose period the ball spacing aliases, a higher order that
follows one placement's oddity) lowers it too. A physical effect of the machine or the
plate, fitted on the other placements, *predicts* the held-out one; an alias does not.

The check works on the part of the residual the baseline leaves (Frisch-Waugh-Lovell):
with ``r`` the baseline's weighted residual and ``X`` the effect's columns with the
baseline's columns projected out, the in-sample gain of adding the effect is
``|P_X r|²``. For each placement ``p`` the effect's coefficients are estimated from the
other placements' rows only, and its held-out gain is how much that prediction lowers
``p``'s residual: ``|r_p|² - |r_p - X_p β_(-p)|²``. The baseline itself is common to both
sides of the comparison and stays fitted to all data; what is cross-validated is the
effect. Linearised at the baseline's solution, as ``diagnose.score``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from .fit import FitResult, Problem, augmented_state, weighted_residual
from .solver import Normal

PASS_SHARE = 0.25
"""Share of the in-sample gain the held-out gain must reach. A real effect well above its
detection limit keeps most of its gain out of sample (it loses about its parameter count
to estimation noise); an alias keeps little or makes the prediction worse. Calibrated on
simulated layouts other than the sample data's (``tests/test_honesty.py``)."""

MIN_PLACEMENTS = 3
"""With two placements, one placement alone rarely determines an effect's coefficients."""


@dataclass(frozen=True)
class HoldoutCheck:
    """Outcome of the leave-one-placement-out check of one candidate effect.

    Attributes
    ----------
    effect : str
        Model token checked.
    applicable : bool
        False when the check cannot judge the effect (``reason`` says why): fewer than
        three placements, or every parameter it adds belongs to a single placement
        (drift of each position), so no other placement can predict it.
    passed : bool
        True when the held-out gain reaches ``PASS_SHARE`` of the in-sample gain (True
        when not applicable: the check then has no evidence against the effect).
    gain_in_sample : float
        χ² the effect removes on all data (linearised).
    gain_held_out : float
        Sum over placements of the held-out χ² reduction.
    per_placement : dict
        ``{position: held-out χ² reduction}``.
    reason : str
        Plain-language reading of the numbers.
    """

    effect: str
    applicable: bool
    passed: bool
    gain_in_sample: float
    gain_held_out: float
    per_placement: dict = field(default_factory=dict)
    reason: str = ""

    @property
    def share(self) -> float:
        """Held-out gain as a share of the in-sample gain (0 when nothing is gained)."""
        if not self.applicable or self.gain_in_sample <= 0:
            return 0.0
        return self.gain_held_out / self.gain_in_sample

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"effect": self.effect, "applicable": self.applicable, "passed": self.passed,
                "gain_in_sample": self.gain_in_sample,
                "gain_held_out": self.gain_held_out if self.applicable else None,
                "share": self.share if self.applicable else None,
                "per_placement": self.per_placement, "reason": self.reason}


def _effect_columns(base: FitResult, prob: Problem, cache=None):
    """Baseline residual and the effect's columns with the baseline's projected out.

    Returns ``(r, X, pos_of_row)``: weighted residual (m,), effect columns (m, k) in the
    effect's own gauge, and the placement index of every row (-1: certificate prior, -2:
    instrument rows, laser runs and step gauges, the last rows).
    ``prob`` is the baseline's problem with the effect added; ``cache``, the diagnosis's
    ``scoring.ScoreCache``, holds its columns already.
    """
    idx = None if cache is None else cache.columns(prob)
    if idx is None:
        _, r, J = weighted_residual(prob, augmented_state(base, prob), base.sigma_um, True)
        J = J.toarray()
    else:
        r, J = cache.r, cache.J[:, idx]
    old = set(base.labels)
    is_new = np.array([lab not in old for lab in prob.layout.labels])
    C = prob.constraints()
    Cb = C[:, ~is_new][np.abs(C[:, is_new]).sum(axis=1) == 0]
    if base.design_null.size:
        Cb = np.vstack([Cb, base.design_null])
    Jb, X = J[:, ~is_new], J[:, is_new]
    # the effect's own gauge (probe offsets summing to zero): its constraint null space
    Cn = C[:, is_new][np.abs(C[:, ~is_new]).sum(axis=1) == 0]
    if Cn.shape[0]:
        X = X @ sla.null_space(Cn)
    # project out what the baseline explains (its constrained least-squares hat matrix)
    cov = Normal(Jb, r, Cb, base.rank_rtol).cov()
    X = X - Jb @ (cov @ (Jb.T @ X))
    r = r - Jb @ (cov @ (Jb.T @ r))
    o = prob.obs
    pos_of_row = np.full(r.size, -1)
    pos_of_row[: 3 * prob.n_obs] = np.repeat(o.pos, 3)
    pos_of_row[r.size - prob.instruments.n_rows:] = -2
    return r, X, pos_of_row


def _lstsq(A, b):
    return np.linalg.lstsq(A, b, rcond=1e-10)[0]


def check(base: FitResult, token: str, cache=None) -> HoldoutCheck:
    """Leave-one-placement-out check of adding ``token`` to ``base`` (module docstring);
    ``cache``: the diagnosis's ``scoring.ScoreCache``, if at hand."""
    o = base.problem.obs
    prob = Problem(o, base.problem.spec.with_token(token), base.plate)
    added = {g for g, lab in zip(prob.layout.groups, prob.layout.labels, strict=True)
             if lab not in set(base.labels)}
    if len(o.positions) < MIN_PLACEMENTS:
        return HoldoutCheck(token, False, True, float("nan"), float("nan"), {},
                            f"needs at least {MIN_PLACEMENTS} placements")
    if added <= {"drift"}:
        return HoldoutCheck(token, False, True, float("nan"), float("nan"), {},
                            "its parameters belong to single placements (the drift of each "
                            "position), so no other placement can predict them")
    r, X, pos_of_row = _effect_columns(base, prob, cache)
    # instrument rows (laser, step gauge) train every fold and are held out in none: the
    # in-sample gain compared is that on the rows that are held out
    on = pos_of_row != -2
    gain_in = float(r[on] @ r[on] - np.sum((r - X @ _lstsq(X, r))[on] ** 2))
    per = {}
    for k, name in enumerate(o.positions):
        held = pos_of_row == k
        beta = _lstsq(X[~held], r[~held])
        rp, e = r[held], r[held] - X[held] @ beta
        per[name] = float(rp @ rp - e @ e)
    gain = float(sum(per.values()))
    passed = gain_in > 0 and gain >= PASS_SHARE * gain_in
    if passed:
        why = (f"fitted on the other placements it predicts each held-out one: the held-out "
               f"χ² falls by {gain:.1f}, {100 * gain / gain_in:.0f} % of the {gain_in:.1f} it "
               "removes in sample")
    else:
        worst = min(per, key=per.get)
        why = (f"fitted on the other placements it does not predict the held-out ones: the "
               f"held-out χ² changes by {-gain:+.1f} while in sample it falls by "
               f"{gain_in:.1f} (worst at {worst}: {-per[worst]:+.1f}). It follows what "
               "differs between placements, not a property of the machine or the plate")
    return HoldoutCheck(token, True, passed, gain_in, gain, per, why)

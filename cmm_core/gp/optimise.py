"""Maximisation of the GP's log marginal likelihood over its hyperparameters.

L-BFGS-B in log hyperparameters with the analytic gradient of
:meth:`~cmm_core.gp.likelihood._Problem.objective` (Rasmussen & Williams 2006, *Gaussian
Processes for Machine Learning*, §5.4.1, eq. 5.9), one run per start. For large ``n``
(:func:`_optimise` with a subset problem) every start runs first on a subset of the
points and each distinct optimum found there is polished on all of them: BFGS from the
subset's (finite-difference) Hessian inside the bounds, L-BFGS-B at a bound. The starts
themselves (default start and Latin hypercube) are chosen by ``cmm_core.gp.fit_gp``.

See Also
--------
cmm_core.gp : ``fit_gp``, which calls :func:`_optimise` and :func:`_minimize`.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import OptimizeResult, minimize

_SAME_OPTIMUM = 0.05  # subset optima closer than this in every log hyperparameter are one
# L-BFGS-B's relative-reduction stop: scipy's default 2.2e-9 leaves the log ML 1e-7 below
# the optimum at n = 1000 (its gradient test then stops it first); the subset runs only
# find the basins and keep the default
_FTOL = 1e-12
# BFGS polish: ∞-norm of the gradient at which it stops. The log ML is then within
# |g|²/(2 λ_min) ~ 1e-10 of the optimum (λ_min ~ 10 at n = 1000); 1e-5 is below what its
# round-off (~1e-10) lets the line search see, which then spent 24 evaluations in place
_GTOL = 1e-4
_GTOL_STALLED = 1e-3  # a BFGS polish stalled by round-off below this gradient converged
# a BFGS polish is a few steps from a good start; more means it is lost (L-BFGS-B then)
_BFGS_MAXITER = 15
_PRUNE_NATS = 10.0  # subset optima this far below the best are not polished (_optimise)
_INTERIOR = 2.0  # a subset optimum this far (log) from every bound gets the BFGS polish
_FTOL_PREFIT = 2.2e-9


def _minimize(prob, lo, hi, t0, ftol=_FTOL):
    return minimize(prob.objective, np.clip(t0, lo, hi), jac=True, method="L-BFGS-B",
                    bounds=list(zip(lo, hi, strict=True)), options={"ftol": ftol})


def _optimise(prob, sub, lo, hi, points):
    """One optimisation per start; the result of each, in the order of ``points``.

    Without a subset problem ``sub``: L-BFGS-B from each start on all the points.

    With one, every start runs on the subset first (a likelihood evaluation on 300 points
    costs 1/30 of one on 1000), the optima it reaches are grouped (log hyperparameters
    within ``_SAME_OPTIMUM`` of each other are one optimum), and each distinct optimum is
    polished on all the points; a start's result is the polished optimum of its group, so
    every basin the starts found is still searched on all the data. An optimum inside the
    bounds is polished by BFGS started with the inverse of the subset's Hessian there
    (finite differences of its analytic gradient, × √(n/m)): its first step is then close
    to Newton's, where L-BFGS-B's identity start spent most of its 12 to 27 evaluations in
    line searches (8 with BFGS on the bench data). The factor: the noise curvature grows
    like n/m but the length scale's and σ_f's more slowly (a fixed domain filled in);
    n/m overshot them and made BFGS's line search fail. An optimum at a bound, or a BFGS
    polish that leaves the bounds or fails, gets L-BFGS-B from where it stands.

    Optima more than ``_PRUNE_NATS`` below the best on the subset (a likelihood ratio
    e^-10: collapsed or signal-free optima the whole-bounds starts fall into) are not
    polished; their result is the log ML on all points at the subset optimum, marked
    ``polished=False`` (``fit_gp`` polishes one if it is needed as the alternative).
    """
    if sub is None:
        return [_minimize(prob, lo, hi, t0) for t0 in points]
    pre = [_minimize(sub, lo, hi, t0, _FTOL_PREFIT) for t0 in points]
    reps, group = [], []
    for r in pre:
        ok = float(r.fun) < 1e24
        j = next((i for i, q in enumerate(reps) if ok
                  and np.max(np.abs(q.x - r.x)) < _SAME_OPTIMUM), None)
        if j is None:
            reps.append(r)
            j = len(reps) - 1
        group.append(j)
    best = min(float(q.fun) for q in reps)
    polished = [_polish(prob, sub, lo, hi, q) if float(q.fun) <= best + _PRUNE_NATS
                else _unpolished(prob, q) for q in reps]
    return [polished[j] for j in group]


def _unpolished(prob, pre):
    """A subset optimum far below the best one, evaluated on all points, not optimised."""
    f, g = prob.objective(pre.x)
    return OptimizeResult(x=pre.x, fun=f, jac=g, success=False, status=-1, polished=False,
                          message=f"not polished: {_PRUNE_NATS:g} nats or more below the "
                                  "best optimum on the subset")


def _polish(prob, sub, lo, hi, pre):
    """The optimum on all the points near the subset optimum ``pre`` (see ``_optimise``)."""
    t = pre.x
    inside = float(pre.fun) < 1e24 and np.all(t - lo > _INTERIOR) and np.all(hi - t > _INTERIOR)
    H = _fd_hessian(sub, t) * np.sqrt(prob.n / sub.n) if inside else None
    if H is not None:
        lam, V = np.linalg.eigh(H)
        if lam.min() > 1e-6 * lam.max():  # a clear minimum on the subset
            Hinv = (V / lam) @ V.T
            res = minimize(prob.objective, t, jac=True, method="BFGS",
                           options={"hess_inv0": (Hinv + Hinv.T) / 2, "gtol": _GTOL,
                                    "maxiter": _BFGS_MAXITER})
            # BFGS's "precision loss": the line search found no decrease along the
            # quasi-Newton direction, i.e. the optimum to round-off (at n = 1000 the
            # log ML's round-off, ~1e-10, stalls gradients of ~1e-5 on the way down)
            stalled = res.status == 2 and np.max(np.abs(res.jac)) < _GTOL_STALLED
            if (res.success or stalled) and np.all(res.x >= lo) and np.all(res.x <= hi):
                if stalled:
                    res.success = True
                    res.message = ("BFGS: no further increase of the log ML in floating "
                                   f"point (gradient {np.max(np.abs(res.jac)):.1e})")
                return res
            if float(res.fun) < 1e24:
                t = res.x  # L-BFGS-B carries on from where BFGS stopped (clipped)
    return _minimize(prob, lo, hi, t)


def _fd_hessian(prob, theta, h=1e-4):
    """Hessian of ``prob.objective`` at ``theta``: central differences of its gradient."""
    p = len(theta)
    H = np.empty((p, p))
    for j in range(p):
        e = np.zeros(p)
        e[j] = h
        H[:, j] = (prob.objective(theta + e)[1] - prob.objective(theta - e)[1]) / (2 * h)
    return (H + H.T) / 2

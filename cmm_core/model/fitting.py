"""Gauss-Newton fit of the local kinematic model with effect blocks (thesis §4.5.1).

Each observation is a probed ball centre ``r`` (machine frame, mm) with nominal probe
offset ``p``. Its residual (µm) is the corrected measurement minus the placed ball::

    d = x*(r - p, p + dp) - drift(t) - (R_k c_b' + t_k)

with ``x*`` the kinematic model (thesis eq. 4.13), ``(R_k, t_k)`` the rigid placement of
position k, and ``c_b'`` the plate coordinates of ball b after the plate effects (thermal
expansion, sag). Gauge constraints are imposed by QR null-space projection as in thesis
appendix 2; the numerical rank of the scaled, reduced Jacobian (relative tolerance
``rank_rtol`` on its singular values) decides which parameter combinations the data
determine, and those that they do not are named in the result.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from scipy import stats

from .._blas import single_blas_thread
from ..io import Dataset
from ..units import label as unit_label
from . import hole_plate
from . import normal as _normal
from .blocks import needs
from .certificate_prior import certificate_terms, held_prior_rows
from .effects import ModelSpec, parse_spec
from .observations import Observations, has_plate, select
from .problem import Problem
from .result import IMPLAUSIBLE, FitResult, _message
from .solver import Normal, describe_null
from .words import null_words

__all__ = ["fit", "PLATE_MODES"]
PLATE_MODES = ("fixed", "prior", "free", "none")
"""Plate geometry modes of :func:`fit`; ``"none"`` is an instrument-only fit's (no plate
observation) and no other's."""


@single_blas_thread
def fit(data: Dataset | Observations, spec: str | ModelSpec = "kinematic21", *, order: int = 2,
        plate: str | None = None, sigma_um: float = 0.5,
        positions: Sequence[str] | None = None, probes: Sequence[str] | None = None,
        exclude: Iterable[tuple[str, str, int]] = (), rank_rtol: float = 1e-4,
        max_iter: int = 500, tol: float = 1e-9, certificate_test: bool = True,
        nominal: Any = None, instruments: Sequence | None = None) -> FitResult:
    """Fit a model to ball-plate measurements by Gauss-Newton (thesis §4.5.1).

    Parameters
    ----------
    data : Dataset or Observations
        Ball-plate measurements, or ``instrument_observations`` for an instrument-only fit
        (laser runs, step gauges, ball bars without a plate): the kinematic parameters no
        instrument sees at first order are held and named, each on its own, and the rank
        rule decides among the others (``_unseen_columns``).
    spec : str or ModelSpec
        Model spec (docs/formats.md "Model specs"), e.g. ``"kinematic21"``, ``"kinematic21,plate_sag"``.
    order : int
        Default Chebyshev order (1-5).
    plate : {"fixed", "prior", "free", "none"}, optional
        Plate geometry: certificate fixed (default with a certificate), certificate as a
        prior weighted by its uncertainty, or free (self-calibration; default without);
        ``"none"`` (the only one, and the default) for an instrument-only fit.
    sigma_um : float
        Measurement repeatability (µm) for the weights, χ² and covariance.
    positions, probes : list of str, optional
        Subsets to use (default all).
    exclude : iterable of (position, probe, ball)
        Observations left out (flagged outliers).
    rank_rtol : float
        Singular values of the column-scaled reduced Jacobian below ``rank_rtol`` times the
        largest count as zero: those directions are reported as undetermined.
    certificate_test : bool
        With the certificate fixed, count its uncertainty (``certificate_prior``): in the χ²
        test and, propagated, in every parameter's covariance (one more evaluation);
        False leaves ``chi2_test`` = χ² and the covariance of σ alone (the diagnosis's
        refits compare χ² only).
    nominal : callable, optional
        ``nominal(problem)``: the problem's normal equations at its initial state when the
        caller has them (``scoring.ScoreCache.nominal``), else None.
    instruments : list of LaserRun or StepGauge, optional
        Fitted with the plate (``instruments`` eq. 1-2, docs/instruments.md); default: data's.

    Returns
    -------
    FitResult
        Never raises on non-convergence: ``status`` and ``message`` say what happened.
    """
    if not sigma_um > 0:
        raise ValueError(f"sigma_um must be positive, got {sigma_um}.")
    if isinstance(spec, str):
        spec = parse_spec(spec, default_order=order)
    obs = data if isinstance(data, Observations) else select(
        data, positions=positions, probes=probes, exclude=exclude)
    obs = obs if instruments is None else replace(obs, instruments=tuple(instruments))
    plate = _plate_mode(obs, plate)
    prob = Problem(obs, spec, plate)
    L = prob.layout
    C = prob.constraints()
    state = prob.initial_state()
    n_gauge = C.shape[0]

    status, it = "max_iterations", 0
    # only the normal equations are formed, block by block of observations: never J
    ne0 = nominal(prob) if nominal is not None else None
    # the starting point's accumulation is not the last one (a step follows): the
    # certificate's plate columns are kept only by the later ones
    d, cost, N, g, n_rows = ne0 if ne0 is not None else prob.normal_equations(
        state, sigma_um, plate_cross=False)
    unseen = np.zeros((0, L.n))
    if not has_plate(obs):
        unseen = _unseen_columns(N, rank_rtol)
        C = np.vstack([C, unseen])
    seen = ~unseen.any(axis=0)

    def normal_equations(at):
        """The problem's normal equations at ``at``, the unseen columns emptied: held by
        their unit rows, and with their (second-order) entries gone the column scaling
        keeps those rows of one size (a column norm of 1e-20 scaled them out of the
        constraints' rank)."""
        d, cost, N, g, rows = prob.normal_equations(at, sigma_um)
        return d, cost, N * np.outer(seen, seen), g * seen, rows

    N, g = N * np.outer(seen, seen), g * seen
    # Gauss-Newton with Levenberg-Marquardt damping on rejection: a line search along the
    # full step fails when nearly undetermined directions (a single placement) ask for
    # rotations of radians, where the linearisation no longer holds.
    mu = 0.0
    # Which combinations the data determine is a property of the design, decided at the
    # nominal linearisation and then frozen: re-deciding it as the state moves let weakly
    # coupled directions (sv 1e-5 of the largest for a single placement) become
    # "determined" through the nonlinearity of radian-sized rotations, and the fit slid
    # along that valley without converging.
    ne = Normal(None, None, C, rank_rtol, normal=(N, g))
    null0 = ne.null
    C_run = ne.freeze_null(C)
    # (state, cost) where N and g were linearised: the state itself, but for a last step
    # whose predicted decrease is below the stop (see below)
    lin_state, lin_cost = state, cost
    for it in range(1, max_iter + 1):  # noqa: B007 - `it` reports the iteration count
        if it > 1 or null0.shape[1]:
            ne = Normal(None, None, C_run, rank_rtol, normal=(N, g))
        accepted = last = False
        for attempt in range(16):
            dx = ne.step(mu)
            trial = prob.update(state, dx)
            # the undamped step is nearly always accepted: its normal equations at once,
            # unless the linearisation predicts it ends the fit (a decrease |r|² - |r +
            # J dx|² below the stop): then its cost alone (no Jacobian pass, a fifth of
            # the time), and N, g stay those of this state, a step of < tol of the cost
            # away (thesis eq. 4.15's covariance is then taken one negligible step back)
            last = attempt == 0 and -(2 * g @ dx + dx @ N @ dx) <= tol * max(cost, 1.0) / 2
            if attempt == 0 and not last:
                dt, new_cost, Nt, gt, _ = normal_equations(trial)
            else:
                (dt, new_cost), Nt = _normal.cost_of(prob, trial, sigma_um), None
            if new_cost <= cost * (1 + 1e-12):
                accepted = True
                break
            mu = max(10 * mu, 1e-6)
        if not accepted:
            # no damping lowers the cost: the linearisation's minimum is where we stand
            status = "converged" if cost < np.inf else "failed"
            break
        mu = mu / 10 if mu > 1e-6 else 0.0
        state = trial
        done = cost - new_cost <= tol * max(cost, 1.0)
        if Nt is None and not (last and done):
            dt, new_cost, Nt, gt, _ = normal_equations(state)
        if Nt is not None:
            N, g, lin_state, lin_cost = Nt, gt, state, new_cost
        d, cost = dt, new_cost
        if done:
            status = "converged"
            break
    ne = Normal(None, None, C_run, rank_rtol, normal=(N, g))
    cov, rank = ne.cov(), ne.rank
    cert = None
    if plate == "fixed" and obs.cert_u_um is not None and certificate_test:
        # the certificate's own uncertainty: in the χ² test and in every parameter's u
        # (from the linearisation's own state and cost: its χ² is that of the linearised
        # prior problem's minimum, which the negligible last step does not move)
        cert = certificate_terms(prob, lin_state, C_run[C.shape[0]:], sigma_um, rank_rtol,
                                 cov, normal=(lin_cost, N, g, n_rows))
    null = np.hstack([unseen.T, null0, ne.null])
    cov_noise = None
    if cert is not None:
        cov_noise, cov = cov, cert[2]
    u = np.sqrt(np.clip(np.diag(cov), 0, None))
    combos, names = describe_null(null, L.labels)
    words = null_words(null, L.labels)
    unident = [lab for lab in L.labels if lab in names]
    u = np.array([np.nan if lab in names else ui for lab, ui in zip(L.labels, u, strict=True)])
    values = _report_values(prob, state)
    chi2 = float(cost)
    dof = n_rows - rank - held_prior_rows(prob)
    bic = chi2 + rank * np.log(n_rows)
    rms = float(np.sqrt(np.mean(d**2))) if d.size else float("nan")  # no plate: no RMS
    if hole_plate.is_hole_plate(obs):  # two components of three per observation
        rms *= np.sqrt(1.5)
    chi2_test, dof_test = (chi2, dof) if cert is None else cert[:2]
    msg = _message(status, it, rms, chi2 / max(dof, 1), words,
                   float(stats.chi2.sf(chi2_test, max(dof_test, 1))), int(dof_test),
                   chi2_test / max(dof_test, 1)) + hole_plate.tilt_note(prob, state)
    # an effect the data cannot see adds nothing (or no parameter at all): say so
    msg += "".join(f" {b.token} adds nothing determinable: {why}." for b in prob.blocks
                   if b.token and (why := needs(b.token, obs)))
    kin_block = L.blocks["kinematic"]
    wild = [(L.labels[i], values[i], L.units[i]) for i in range(kin_block.start, kin_block.stop)
            if abs(values[i]) > IMPLAUSIBLE]
    if wild:
        lab, val, unit = max(wild, key=lambda w: abs(w[1]))
        msg += (f" {len(wild)} kinematic parameter(s) reach physically implausible sizes "
                f"(largest {lab} = {val:.3g} {unit_label(unit)}"
                "): the data determine them only weakly and the misfit drives them. Trust "
                "neither them nor the error map built from them; add placements or remove "
                "those functions.")
    return FitResult(
        status=status, message=msg, iterations=it, spec=spec.to_string(explicit=True),
        plate=plate, sigma_um=sigma_um, labels=list(L.labels), units=list(L.units),
        groups=list(L.groups), values=values, u=u, covariance=cov, residuals_um=d,
        table=obs.table, rms_um=rms, chi2=chi2, dof=int(dof), chi2_dof=chi2 / max(dof, 1),
        bic=float(bic), rank=rank, rank_rtol=rank_rtol, unidentifiable=unident,
        null_combinations=combos, null_words=words, n_obs=prob.n_obs, problem=prob, state=state,
        design_null=C_run[n_gauge:], chi2_test=float(chi2_test), dof_test=int(dof_test),
        covariance_noise=cov_noise,
        certificate_sensitivity=None if cert is None else cert[3])


def _plate_mode(obs, plate):
    """The plate mode of :func:`fit` (None: its default), checked against the data."""
    if not has_plate(obs):  # instruments only: no plate, placement or certificate
        if plate not in (None, "none"):
            raise ValueError(f"plate={plate!r} needs ball-plate observations; an "
                             "instrument-only fit has no plate (plate='none').")
        return "none"
    if plate is None:
        return "fixed" if obs.has_certificate else "free"
    if plate not in PLATE_MODES:
        raise ValueError(f"plate must be one of {PLATE_MODES}, got {plate!r}.")
    if plate == "none":
        raise ValueError("plate='none' is for instrument-only fits; these observations have "
                         "a plate: use 'fixed', 'prior' or 'free'.")
    if plate in ("fixed", "prior") and not obs.has_certificate:
        raise ValueError(f"plate={plate!r} needs a certificate; load one or use plate='free'.")
    return plate


def _unseen_columns(N, rank_rtol):
    """Constraint rows (unit rows) holding the parameters an instrument-only fit does not
    see: those whose column norm ``sqrt(N_jj)`` is at most ``rank_rtol`` times the largest.

    The rank rule of :class:`Normal` scales every column to unit norm, which is right when
    each parameter moves the plate's residuals at first order. Without a plate, most
    parameters move no instrument row at all, or only at second order (a step gauge along
    x sees the z errors through the micrometre tilt of its indicated line, 1e-6 of its
    scale): scaled to unit norm those columns looked determined and their values ran to
    10^11 µm. Held here, each is named on its own, and the rank rule decides among the
    columns the instruments see at first order."""
    norms = np.sqrt(np.clip(np.diag(N), 0, None))
    idx = np.flatnonzero(norms <= rank_rtol * norms.max()) if norms.max() > 0 \
        else np.arange(N.shape[0])
    rows = np.zeros((idx.size, N.shape[0]))
    rows[np.arange(idx.size), idx] = 1.0
    return rows


def _report_values(prob, state):
    """Parameter values relative to the nominal setup / certificate, in their units."""
    v = state.x.copy()
    for b in prob.blocks:
        b.report(state, v)
    return v

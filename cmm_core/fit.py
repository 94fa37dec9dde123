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

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from scipy import stats

from . import hole_plate
from . import kinematics as kin
from . import normal as _normal
from ._blas import single_blas_thread
from .blocks import REGISTRY, Eval
from .blocks.kinematic import Kinematic
from .blocks.plate import Plate
from .dataset import Dataset
from .effects import ModelSpec, parse_spec
from .fit_certificate import certificate_terms, held_prior_rows
from .fit_result import CHI2_ALPHA, IMPLAUSIBLE, FitResult, _message
from .fit_state import State
from .geometry import plate_effect_basis, rigid_fit
from .instruments import Instruments
from .observations import Observations, approach_directions, select
from .solver import Normal, describe_null
from .units import UM
from .units import label as unit_label

__all__ = ["Observations", "Problem", "FitResult", "select", "fit", "weighted_residual",
           "augmented_state", "approach_directions", "rigid_fit", "plate_effect_basis",
           "PLATE_MODES", "CHI2_ALPHA"]
PLATE_MODES = ("fixed", "prior", "free")


@dataclass
class _Layout:
    """Column layout of the parameter vector: block name -> slice, plus labels/units."""

    blocks: dict = field(default_factory=dict)
    labels: list = field(default_factory=list)
    units: list = field(default_factory=list)
    groups: list = field(default_factory=list)

    def add(self, name, labels, unit):
        i = len(self.labels)
        self.blocks[name] = slice(i, i + len(labels))
        self.labels += labels
        self.units += [unit] * len(labels) if isinstance(unit, str) else unit
        self.groups += [name] * len(labels)

    @property
    def n(self):
        return len(self.labels)


class Problem:
    """Parameter layout, residuals and analytic Jacobian of one model on one selection.

    The model is the sum of its effect blocks (``cmm_core.blocks``): each lays out its
    columns, takes part in the probe, plate and reading stages of the residual, writes its
    Jacobian columns and its gauge constraints.
    """

    def __init__(self, obs: Observations, spec: ModelSpec, plate: str):
        self.obs, self.spec, self.plate = obs, spec, plate
        self.terms = kin.KinematicTerms(spec.active, tuple(obs.range_mm), spec.periods,
                                        obs.layout)
        self.plate_centre, self.sag_basis = plate_effect_basis(obs.plate0_mm)
        self.n_obs = len(obs.r_mm)
        self.B, self.P, self.Q = len(obs.balls), len(obs.positions), len(obs.probes)
        self.blocks = [cls(self) for cls in REGISTRY if cls.wanted(spec, plate)]
        L = _Layout()
        for b in self.blocks:
            for name, labels, unit in b.columns(obs):
                L.add(name, labels, unit)
        self.layout = L
        self.instruments = Instruments(self)  # laser and step-gauge rows (their own module)
        self._kinematic = next(b for b in self.blocks if isinstance(b, Kinematic))

    def block(self, cls):
        """The block of this class in the model, or None."""
        return next((b for b in self.blocks if isinstance(b, cls)), None)

    # --- state ---------------------------------------------------------------------
    def initial_state(self):
        """Nominal plate, placements by a rigid fit of the plate to each position."""
        if hole_plate.is_hole_plate(self.obs):  # in-plane fit at the nominal tilt
            return hole_plate.initial_state(self)
        o = self.obs
        R = np.empty((self.P, 3, 3))
        t = np.empty((self.P, 3))
        for k in range(self.P):
            sel = o.pos == k
            R[k], t[k] = rigid_fit(o.plate0_mm[o.ball[sel]], o.r_mm[sel])
        return State(o.plate0_mm.copy(), R, t, np.zeros(self.layout.n))

    def _placed(self, ev):
        """Probe and plate stages, then the placed ball ``R_k c' + t_k`` (mm)."""
        o, state = self.obs, ev.state
        p = o.p_mm.copy()
        for b in self.blocks:
            p = b.probe_stage(ev, p)
        ev.p_mm = p
        c = state.c[o.ball]
        for b in self.blocks:
            c = b.plate_stage(ev, c)
        ev.plate_mm = c
        ev.Rk = state.R[o.pos]
        return np.einsum("nij,nj->ni", ev.Rk, c) + state.t[o.pos]

    def _reading(self, ev, d):
        for b in self.blocks:
            d = b.reading_stage(ev, d)
        return d

    def _evaluate(self, state, want_jac):
        ev = Eval(self, state, want_jac)
        placed = self._placed(ev)
        xs = self._kinematic.model(ev)
        return self._reading(ev, (xs - placed) / UM), ev

    def targets(self, state):
        """What the kinematic model must return for every residual to vanish (mm), and
        the true probe offsets (mm): the simulator inverts the model to these
        (``simulate``), so that it is the exact inverse of the fit's model."""
        ev = Eval(self, state, False)
        placed = self._placed(ev)
        # the reading stage is linear in the residual: d = (x* - placed)/UM + L
        L = self._reading(ev, np.zeros_like(placed))
        return placed - L * UM, ev.p_mm

    def plate_points(self, state):
        """Plate coordinates of every observation after thermal and sag effects (mm)."""
        ev = Eval(self, state, False)
        c = state.c[self.obs.ball]
        for b in self.blocks:
            c = b.plate_stage(ev, c)
        return c

    def residual(self, state, want_jac=False):
        """Residuals (n, 3) in µm and, if asked, the sparse Jacobian (3n, N); a hole
        plate's without their components along the plate normal (``hole_plate``)."""
        out = self._residual3(state, want_jac)
        return hole_plate.in_plane(self, state, *out) if hole_plate.is_hole_plate(self.obs) \
            else out

    def _residual3(self, state, want_jac):
        d, ev = self._evaluate(state, want_jac)
        if not want_jac:
            return d, None
        n = self.n_obs
        cols, vals = [], []
        for b in self.blocks:
            for block_cols, M in b.jacobian(ev):
                # M: (n, 3, k) derivative of the 3 residual components wrt k columns. Every
                # row has the same number of entries per block: CSR is assembled directly
                cols.append(np.broadcast_to(block_cols[:, None, :], M.shape))
                vals.append(M)
        # fill one preallocated (n, 3, k) array per CSR field: concatenating broadcast
        # blocks would copy the dense kinematic block twice (10^5 points: 0.5 s a call)
        k = sum(c.shape[2] for c in cols)
        itype = np.int32 if max(self.layout.n, 3 * n * k) < 2**31 - 1 else np.int64
        data, index = np.empty((n, 3, k)), np.empty((n, 3, k), itype)
        j = 0
        for c, v in zip(cols, vals, strict=True):
            data[:, :, j:j + c.shape[2]] = v
            index[:, :, j:j + c.shape[2]] = c
            j += c.shape[2]
        J = sp.csr_matrix((data.reshape(-1), index.reshape(-1),
                           np.arange(3 * n + 1, dtype=itype) * k), shape=(3 * n, self.layout.n))
        return d, J

    def normal_equations(self, state, sigma_um: float, rows: int = _normal.ROWS):
        """Weighted normal equations ``JᵀJ``, ``Jᵀr`` at ``state``, accumulated over blocks
        of ``rows`` observations without forming ``J`` (``normal.accumulate``): residuals
        (µm), ``r·r``, N, g and the number of weighted rows."""
        if hole_plate.is_hole_plate(self.obs):  # projected rows: J assembled
            return hole_plate.normal_equations(self, state, sigma_um)
        return _normal.accumulate(self, state, sigma_um, rows)

    def constraints(self):
        """Gauge constraints C (rows) on the parameter vector: C x = 0."""
        L, rows = self.layout, []
        for b in self.blocks:
            G = b.constraints()
            if G is None:
                continue
            G = self.instruments.plate_gauge(b, G)
            s = L.blocks[b.columns(self.obs)[0][0]]
            C = np.zeros((G.shape[0], L.n))
            C[:, s.start:s.start + G.shape[1]] = G  # G may span the block's next groups
            rows.append(C)
        return np.vstack(rows) if rows else np.zeros((0, L.n))

    def update(self, state, step):
        """Apply a step: placements are updated multiplicatively so the rotation
        parameters stay small increments (exact Jacobian at zero), the plate into its
        coordinates."""
        new = state.with_x(state.x + step)
        for b in self.blocks:
            if hasattr(b, "update"):
                new = b.update(new)
        return new


@single_blas_thread
def fit(data: Dataset | Observations, spec: str | ModelSpec = "kinematic21", *, order: int = 2,
        plate: str | None = None, sigma_um: float = 0.5, positions=None, probes=None,
        exclude=(), rank_rtol: float = 1e-4, max_iter: int = 500, tol: float = 1e-9,
        certificate_test: bool = True, nominal=None, instruments=None) -> FitResult:
    """Fit a model to ball-plate measurements by Gauss-Newton (thesis §4.5.1).

    Parameters
    ----------
    data : Dataset or Observations
    spec : str or ModelSpec
        Model spec (docs/formats.md "Model specs"), e.g. ``"kinematic21"``, ``"kinematic21,plate_sag"``.
    order : int
        Default Chebyshev order (1-5).
    plate : {"fixed", "prior", "free"}, optional
        Plate geometry: certificate fixed (default with a certificate), certificate as a
        prior weighted by its uncertainty, or free (self-calibration; default without).
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
        With the certificate fixed, count its uncertainty (``fit_certificate``): in the χ²
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
    if plate is None:
        plate = "fixed" if obs.has_certificate else "free"
    if plate not in PLATE_MODES:
        raise ValueError(f"plate must be one of {PLATE_MODES}, got {plate!r}.")
    if plate in ("fixed", "prior") and not obs.has_certificate:
        raise ValueError(f"plate={plate!r} needs a certificate; load one or use plate='free'.")
    prob = Problem(obs, spec, plate)
    L = prob.layout
    C = prob.constraints()
    state = prob.initial_state()

    status, it = "max_iterations", 0
    # only the normal equations are formed, block by block of observations: never J
    ne0 = nominal(prob) if nominal is not None else None
    d, cost, N, g, n_rows = ne0 if ne0 is not None else prob.normal_equations(state, sigma_um)
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
    for it in range(1, max_iter + 1):  # noqa: B007 - `it` reports the iteration count
        if it > 1 or null0.shape[1]:
            ne = Normal(None, None, C_run, rank_rtol, normal=(N, g))
        accepted = False
        for attempt in range(16):
            trial = prob.update(state, ne.step(mu))
            # the undamped step is nearly always accepted: its normal equations at once
            if attempt == 0:
                dt, new_cost, Nt, gt, _ = prob.normal_equations(trial, sigma_um)
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
        if Nt is None:
            dt, new_cost, Nt, gt, _ = prob.normal_equations(state, sigma_um)
        d, N, g = dt, Nt, gt
        done = cost - new_cost <= tol * max(cost, 1.0)
        cost = new_cost
        if done:
            status = "converged"
            break
    ne = Normal(None, None, C_run, rank_rtol, normal=(N, g))
    cov, rank = ne.cov(), ne.rank
    cert = None
    if plate == "fixed" and obs.cert_u_um is not None and certificate_test:
        # the certificate's own uncertainty: in the χ² test and in every parameter's u
        cert = certificate_terms(prob, state, C_run[C.shape[0]:], sigma_um, rank_rtol, cov)
    null = np.hstack([null0, ne.null]) if null0.shape[1] else ne.null
    cov_noise = None
    if cert is not None:
        cov_noise, cov = cov, cert[2]
    u = np.sqrt(np.clip(np.diag(cov), 0, None))
    combos, names = describe_null(null, L.labels)
    unident = [lab for lab in L.labels if lab in names]
    u = np.array([np.nan if lab in names else ui for lab, ui in zip(L.labels, u, strict=True)])
    values = _report_values(prob, state)
    chi2 = float(cost)
    dof = n_rows - rank - held_prior_rows(prob)
    bic = chi2 + rank * np.log(n_rows)
    rms = float(np.sqrt(np.mean(d**2)))
    if hole_plate.is_hole_plate(obs):  # two components of three per observation
        rms *= np.sqrt(1.5)
    chi2_test, dof_test = (chi2, dof) if cert is None else cert[:2]
    msg = _message(status, it, rms, chi2 / max(dof, 1), combos,
                   float(stats.chi2.sf(chi2_test, max(dof_test, 1))), int(dof_test),
                   chi2_test / max(dof_test, 1)) + hole_plate.tilt_note(prob, state)
    # an effect the data cannot see adds nothing (or no parameter at all): say so
    msg += "".join(f" {b.token} adds nothing determinable: {why}." for b in prob.blocks
                   if b.token and (why := type(b).needs(obs)))
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
        null_combinations=combos, n_obs=prob.n_obs, problem=prob, state=state,
        design_null=C_run[C.shape[0]:], chi2_test=float(chi2_test), dof_test=int(dof_test),
        covariance_noise=cov_noise)


def held_constraints(labels, design_null, prob: Problem):
    """Constraint rows, in ``prob``'s parameter vector, that hold the combinations a fit
    with parameters ``labels`` could not determine (its ``design_null``): a model scored
    or tested from that fit keeps them held, or it would be credited with them."""
    col = {lab: i for i, lab in enumerate(prob.layout.labels)}
    held = np.zeros((design_null.shape[0], prob.layout.n))
    for j, lab in enumerate(labels):
        held[:, col[lab]] = design_null[:, j]
    return held


def augmented_state(base: FitResult, prob: Problem) -> State:
    """A fit's solution expressed in another problem's parameter vector on the same
    observations (parameters the fit does not have start at zero): the linearisation
    point from which a candidate effect is scored (``diagnose.score``, ``holdout``)."""
    return base.state.relabelled(base.labels, prob.layout.labels)


def weighted_residual(prob: Problem, state, sigma_um: float, want_jac: bool):
    """Residuals (µm, (n, 3)), the weighted residual vector and its Jacobian.

    Observation rows are divided by σ; with a plate prior, rows ``(c - c_cert) / u_cert``
    follow (the certificate weighted by its uncertainty), then the instruments' rows.
    """
    d, J = prob.residual(state, want_jac)
    r = d.ravel() / sigma_um
    if J is not None:
        J.data /= sigma_um  # J is this call's own: scaled in place, not copied
    if prob.plate == "prior":
        rp, Jp = prob.block(Plate).prior_rows(state, want_jac)
        r = np.concatenate([r, rp])
        if J is not None:
            J = sp.vstack([J, Jp]).tocsr()
    r, J = prob.instruments.append(r, J, state, prob.layout.n)  # laser, step gauge rows
    return d, r, J


def _report_values(prob, state):
    """Parameter values relative to the nominal setup / certificate, in their units."""
    v = state.x.copy()
    for b in prob.blocks:
        if hasattr(b, "report"):
            b.report(state, v)
    return v

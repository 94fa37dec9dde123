"""Interim check of a CMM against a stored calibration (issue 28, docs/monitoring.md).

A stored model (``export.Model``: kinematic coefficients ``c`` with covariance ``V``)
predicts where every newly probed ball centre should be. With the certificate's ball
``c_b`` placed rigidly (``R_k c_b + t_k``, placement ``k``) the residual of observation
``i`` (µm) is, as in the fit (``model.fitting``, thesis eq. 4.13)::

    d_i = (x*(r_i - p_i, p'_i) - R_k c_b - t_k) / UM

(``x*`` the model's true tip at scale reading ``r - p``, ``p`` the nominal stylus offset
the CMM reported with, ``p'`` the model's effective offset). Only the rigid
pose of each placement is fitted (a nuisance of 6 parameters linearised about a Kabsch
fit, thesis appendix 2 gauge). If the machine still behaves as stored, ``d`` is normal
with mean ``A β`` (``A`` the pose columns) and the dense covariance::

    Σ = σ² I + J V Jᵀ + K U_cert Kᵀ

``J`` the error's Jacobian in the coefficients at the new points (JCGM 100 eq. 13: the
stored model's uncertainty is correlated across points), ``K`` the placed-ball
derivative (each ball's certificate error shared by every observation of it). The pose
is estimated by generalised least squares; the check is the χ² test of the GLS residual,
``χ² = r̂ᵀ Σ⁻¹ r̂`` with ``3n - 6P`` degrees of freedom (Rao 1973, §4a.3). Each
component's standard uncertainty is ``u_i = sqrt((Σ - A M⁻¹ Aᵀ)_ii)``,
``M = Aᵀ Σ⁻¹ A`` (the leverage of the pose fit included), and its normalised error is
stated as laboratories read one, with the expanded uncertainty ``U_i = k u_i`` at the
coverage factor ``k`` (default 2, as EA-4/02 states U; ISO/IEC 17043:2010 Annex B:
``E_n = (x - X) / sqrt(U_x² + U_X²)``, the stored model's prediction and the new
measurement being the two values): ``E_n = r̂_i / (k u_i)``, ``|E_n| <= 1`` the usual
acceptance (at k = 2 the standard score ``|r̂_i / u_i| <= 2``). The χ² test does not
depend on ``k``.

Σ is dense (3n × 3n, Cholesky by ``scipy.linalg.cho_factor``): memory ``72 n²`` bytes
and time ``O(n³)``; :data:`MAX_OBSERVATIONS` (1500 balls probed: 4500², 162 MB) bounds it.
The stored model's coefficients and the new certificate are taken as independent (the
model file does not hold the certificate it was fitted with).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import linalg, stats

from .._blas import single_blas_thread
from ..export import Model
from ..io import DataError, Dataset, range_tolerance
from ..machine import kinematics as kin
from ..machine import rigid_fit
from ..model import (
    RANGE_MARGIN,
    Observations,
    instrument_observations,
    refuse_repeated,
    select,
)
from ..units import UM
from .identity import refuse_other_machine
from .numbers import json_num

MAX_OBSERVATIONS = 1500
"""Largest number of probed ball centres a check takes (its dense covariance is
``(3n)²`` doubles: 162 MB at 1500)."""

PROBE_TOLERANCE_MM = 0.5
"""A stylus of the new setup whose nominal offset differs from the model's by more is
another stylus: the model knows nothing of it."""


@dataclass(frozen=True)
class CheckSystem:
    """The linear system of an interim check: what the GLS fit and the refit share.

    Attributes
    ----------
    obs : Observations
        The new observations (machine frame).
    d_um : ndarray (3n,)
        Residuals at the starting pose, µm, observation-major (x, y, z of each).
    A : ndarray (3n, 6P)
        Derivative of the placed balls (µm) in each placement's translation (µm) and
        small rotation (µrad) about its centroid.
    J : ndarray (3n, k)
        Derivative of the model's error (µm) in its kinematic coefficients.
    noise_cov : ndarray (3n, 3n)
        σ² I plus the certificate's part: what the new data would scatter with if the
        model were exact.
    cov : ndarray (3n, 3n)
        ``noise_cov + J V Jᵀ``: the full covariance of the residuals.
    x_mm : ndarray (n, 3)
        Scale readings of the observations (reported tip minus the nominal offset).
    sigma_um : float
        σ of one probed coordinate used for the new data.
    n_plate_rows : int
        The first ``n_plate_rows`` (``3n``) rows are the plate's; the rest the instruments'.
    instrument_rows : tuple
        ``(instrument, start, stop)`` per instrument: its rows ``start:stop`` of ``d_um``
        (weighted by ``1/u``, nuisances eliminated: unit noise covariance).
    """

    obs: Observations
    d_um: np.ndarray
    A: np.ndarray
    J: np.ndarray
    noise_cov: np.ndarray
    cov: np.ndarray
    x_mm: np.ndarray
    sigma_um: float
    n_plate_rows: int = -1
    instrument_rows: tuple = ()

    @property
    def n_plate(self) -> int:
        """Number of plate rows (all rows for a system built before instruments)."""
        return len(self.d_um) if self.n_plate_rows < 0 else self.n_plate_rows


@dataclass(frozen=True)
class GlsFit:
    """The pose fit by generalised least squares of a :class:`CheckSystem`.

    Attributes
    ----------
    factor : tuple
        ``cho_factor`` of the system's ``cov``.
    residual_um : ndarray (3n,)
        ``r̂ = d - A β̂``, µm.
    residual_cov_diag : ndarray (3n,)
        ``diag(Σ - A M⁻¹ Aᵀ)``: each residual's variance with the pose fit's leverage.
    chi2 : float
        ``r̂ᵀ Σ⁻¹ r̂``.
    dof : int
        ``3n - 6P``.
    pose : ndarray (6P,)
        The fitted pose increments (µm, µrad).
    """

    factor: tuple
    residual_um: np.ndarray
    residual_cov_diag: np.ndarray
    chi2: float
    dof: int
    pose: np.ndarray


@dataclass(frozen=True)
class InterimCheck:
    """Outcome of :func:`interim_check`.

    Attributes
    ----------
    status : str
        ``"passes"`` (the χ² test does not reject the stored model at ``alpha``) or
        ``"fails"``.
    message : str
        The outcome in one paragraph: the test, its degrees of freedom, the largest E_n
        with its coverage factor (``"Largest |E_n| (k = 2) = ..."``).
    chi2 : float
        χ² of the GLS residuals with the full covariance.
    dof : int
        Its degrees of freedom: 3 per observation less 6 per placement (the poses).
    p_value : float
        ``P(χ²_dof > chi2)``.
    alpha : float
        The test's false-alarm level.
    model_name : str
        The stored model (its file name).
    positions : list of str
        The placements of the new data.
    table : DataFrame
        One row per observation: ``position, probe, ball``, the scale readings
        ``x_mm, y_mm, z_mm`` (for a map), the residual ``dx_um, dy_um, dz_um`` (measured
        minus predicted after the pose fit), its standard uncertainty ``u_dx_um ...``,
        ``En_x, En_y, En_z`` (residual over its expanded uncertainty ``k u``, k the
        ``coverage_factor``) and ``En`` (the largest of the three in absolute value: the
        map's colour, :meth:`largest_En`).
    coverage_95 : float
        Fraction of the plate's residual components and of the instruments' readings
        (``readings``) within their 95 % intervals (``|residual| <= 1.96 u``, whatever
        ``coverage_factor``); about 0.95 when the model holds.
    sigma_um : float
        σ of one probed coordinate of the new data (µm).
    outside_region : int
        Ball centres and instrument points whose scale readings lie outside the region
        the stored model was fitted in (predicted by extrapolation: it is stated, not
        refused).
    system : CheckSystem
        The linear system (for :func:`what_changed`).
    gls : GlsFit
        The pose fit (for :func:`what_changed`).
    instruments : DataFrame
        One row per instrument of the check: ``kind``, ``file``, ``readings``, ``rows``
        (its weighted, nuisance-free rows: the χ² degrees of freedom it adds),
        ``rms_En`` and ``max_abs_En`` over its readings (E_n at ``coverage_factor``);
        empty without.
    readings : DataFrame
        One row per instrument reading: ``kind``, ``file``, ``row`` (the file row),
        ``label`` (run, bar or gauge), ``residual_um`` (the stored model's prediction
        minus the reading, the run's offset and slope removed), ``u_residual_um`` (its
        standard uncertainty: σ of the readings and the stored model's) and ``En``
        (``residual_um / (k u_residual_um)``).
        The check's rows are rotated combinations of the readings (``T (pred −
        measured)``, one fewer per eliminated offset or slope); they are mapped back by
        the instrument's ``Q`` (``transform[1]``), each reading's variance
        ``u² diag(Q Σ_rows Qᵀ)`` (``Σ_rows`` the rows' block of the covariance).
    coverage_factor : float
        The k of every E_n of the check (``E_n = residual / (k u)``; default 2).
    """

    status: str
    message: str
    chi2: float
    dof: int
    p_value: float
    alpha: float
    model_name: str
    positions: list
    table: pd.DataFrame
    coverage_95: float
    sigma_um: float
    outside_region: int
    system: CheckSystem
    gls: GlsFit
    instruments: pd.DataFrame = field(default_factory=pd.DataFrame)
    readings: pd.DataFrame = field(default_factory=pd.DataFrame)
    coverage_factor: float = 2.0

    @property
    def passes(self) -> bool:
        """True when the χ² test does not reject the stored model."""
        return self.status == "passes"

    def largest_En(self, n: int = 10) -> pd.DataFrame:
        """The ``n`` ball centres of largest |E_n| (``table``'s ``En``: the largest of
        each ball's three components), largest first: the report's and the page's list."""
        return self.table.nlargest(min(int(n), len(self.table)), "En")

    def to_dict(self) -> dict:
        """JSON-ready summary (the table's worst rows included)."""
        worst = self.largest_En(10)
        return {"status": self.status, "message": self.message, "chi2": self.chi2,
                "dof": self.dof, "p_value": self.p_value, "alpha": self.alpha,
                "coverage_factor": self.coverage_factor, "En_definition": en_definition(
                    self.coverage_factor),
                "model": self.model_name, "positions": list(self.positions),
                "n_obs": len(self.table), "coverage_95": self.coverage_95,
                "sigma_um": self.sigma_um, "outside_region": self.outside_region,
                "largest_En": [{"position": str(r.position), "probe": str(r.probe),
                                "ball": int(r.ball), "En": float(r.En)}
                               for r in worst.itertuples()],
                "instruments": [{k: (json_num(v) if isinstance(v, float) else v)
                                 for k, v in r.items()}
                                for r in self.instruments.to_dict("records")],
                "largest_En_readings": [
                    {"kind": str(r.kind), "file": str(r.file), "row": int(r.row),
                     "label": str(r.label), "En": json_num(r.En)}
                    for r in self.readings.assign(a=self.readings["En"].abs())
                    .nlargest(min(10, len(self.readings)), "a").itertuples()]
                if len(self.readings) else []}


@single_blas_thread
def interim_check(model: Model, dataset: Dataset | None, *, sigma_um: float | None = None,
                  alpha: float = 0.05, positions: Sequence[str] | None = None,
                  probes: Sequence[str] | None = None,
                  instruments: Sequence = (),
                  exclude: Iterable[Sequence] = (),
                  coverage_factor: float = 2.0) -> InterimCheck:
    """Test new measurements against a stored calibration.

    Parameters
    ----------
    model : Model
        The stored calibration (``export.load_model``), kinematic terms with covariance.
    dataset : Dataset or None
        New ball-plate measurements with their setup and the plate's certificate; one
        placement is enough. None: the instruments alone are the check.
    sigma_um : float, optional
        Repeatability of one probed coordinate (µm); default the stored model's σ.
    alpha : float
        False-alarm level of the χ² test (0 < alpha < 0.5).
    positions, probes : list of str, optional
        Subsets of the new data to use (default all).
    instruments : sequence, optional
        Laser runs, step gauges or ball bars (``model.read_instrument``) measured on the
        same machine: their rows join the test with their own u (a partial check: a ball
        bar in a few orientations, a step gauge along one axis, a laser run).
    exclude : iterable of (position, probe, ball)
        Observations left out of the check (``model.select``): an analysis's own
        exclusions and its outlier rule's, so the check tests the data the fit used.
    coverage_factor : float
        k of the expanded uncertainties the E_n are stated with, ``E_n = residual /
        (k u)`` (default 2: ISO/IEC 17043:2010 Annex B with the k = 2 expanded
        uncertainties of EA-4/02, ``|E_n| <= 1`` the usual acceptance). Presentation
        only: the χ² test and ``coverage_95`` do not depend on it.

    Returns
    -------
    InterimCheck

    Raises
    ------
    DataError
        One line naming the model or data file when they cannot be compared: another
        machine layout or strokes, a stylus the model does not know, no certificate, a
        hole plate, a model with effect parts this check does not propagate, an
        undetermined model, too many observations, an instrument point off the strokes.
    """
    if not 0 < alpha < 0.5:
        raise ValueError(f"alpha must be in (0, 0.5), got {alpha}.")
    k = float(coverage_factor)
    if not (np.isfinite(k) and k > 0):
        raise ValueError(f"coverage_factor must be a positive number, got {coverage_factor}.")
    sys = check_system(model, dataset, sigma_um=sigma_um, positions=positions,
                       probes=probes, instruments=instruments, exclude=exclude)
    g = gls_fit(sys)
    n, m = len(sys.obs.r_mm), sys.n_plate
    u = np.sqrt(np.clip(g.residual_cov_diag, 0, None))
    z = g.residual_um / u  # standard scores: N(0, 1) when the model holds
    En = z / k
    p_value = float(stats.chi2.sf(g.chi2, g.dof))
    status = "passes" if p_value >= alpha else "fails"
    table = _observation_table(sys, g.residual_um[:m], u[:m], En[:m])
    readings = _reading_table(sys, g.residual_um, k)
    inst = _instrument_table(sys, readings)
    lo, hi = (np.asarray(model.summary.get("region_mm", [[-np.inf] * 3, [np.inf] * 3]), float))
    pts = [sys.x_mm[:n]] + [x for it, _, _ in sys.instrument_rows for x, _ in it.points()]
    outside = sum(int((~((x >= lo - 1.0) & (x <= hi + 1.0)).all(axis=1)).sum())
                  for x in pts)
    what = [f"{n} ball centres, {len(sys.obs.positions)} placement(s), poses fitted"] \
        if n else []
    what += [f"{it.kind} {it.source} ({len(it.rows)} reading(s), {stop - start} row(s))"
             for it, start, stop in sys.instrument_rows]
    # the plate's components and the instruments' readings (not their rotated rows)
    all_En = np.concatenate([En[:m], readings["En"].to_numpy(float)])
    worst = int(np.argmax(np.abs(all_En)))
    if worst < m:
        row = table.iloc[worst // 3]
        where = (f"{'xyz'[worst % 3]} of ball {int(row.ball)}, {row.position}/{row.probe}")
    else:
        r = readings.iloc[worst - m]
        where = f"file row {int(r.row)} of {r.kind} {r.file}, {r.label}"
    coverage = float(np.mean(np.abs(k * all_En) <= 1.96))  # standard scores within 95 %
    msg = (f"Interim check against {model.name}: χ² = {g.chi2:.1f} on {g.dof} degrees of "
           f"freedom ({'; '.join(what)}), p = {p_value:.3g}: the machine "
           + ("behaves as the stored model predicts" if status == "passes" else
              "no longer behaves as the stored model predicts")
           + f" at the {100 * alpha:g} % level. Largest |E_n| (k = {k:g}) = "
           f"{abs(all_En[worst]):.2f} ({where}); {100 * np.mean(np.abs(all_En) <= 1):.1f} % "
           "of the "
           + ("components and readings" if len(readings) and m else
              "readings" if len(readings) else "components")
           + f" have |E_n| ≤ 1 and {100 * coverage:.1f} % lie within their 95 % intervals.")
    if model.summary.get("fails_chi2_test"):
        msg += (f" The stored model failed its own χ² test (Birge ratio "
                f"{float(model.summary.get('birge_ratio', float('nan'))):.2f}): its σ "
                "understates its data's scatter, and this check fails more often than "
                f"{100 * alpha:g} % of an unchanged machine's checks.")
    if outside:
        msg += (f" {outside} ball centre(s) or instrument point(s) lie outside the region "
                "the model was fitted in (its predictions there are extrapolated).")
    return InterimCheck(status, msg, float(g.chi2), int(g.dof), p_value, float(alpha),
                        model.name, list(sys.obs.positions) if n else [], table,
                        coverage, sys.sigma_um, outside, sys, g, inst, readings, k)


def en_definition(coverage_factor: float) -> str:
    """The E_n of a check in words, with its coverage factor (the results' ``En_definition``
    and the report's note)."""
    return (f"E_n (k = {coverage_factor:g}) = residual / (k u), u the residual's standard "
            "uncertainty (the new data's σ and the certificate's, the stored model's "
            "J V Jᵀ, the pose fit's leverage): ISO/IEC 17043:2010 Annex B with the "
            "expanded uncertainties at k; |E_n| <= 1 the usual acceptance")


_READING_COLUMNS = ["kind", "file", "row", "label", "residual_um", "u_residual_um", "En"]


def _reading_table(sys: CheckSystem, res: np.ndarray, k: float) -> pd.DataFrame:
    """One row per instrument reading: the rows mapped back by ``Q`` (``InterimCheck``'s
    ``readings``). An instrument's rows have no pose columns, so their residual is
    ``d`` itself and its covariance the rows' block of Σ; E_n at the coverage factor
    ``k``."""
    frames = []
    for it, start, stop in sys.instrument_rows:
        Q = it.transform[1]
        Qm = np.asarray(Q @ np.eye(stop - start), float)  # (readings, rows)
        z = np.asarray(Q @ res[start:stop], float)  # weighted residual per reading
        var = np.einsum("ij,ij->i", Qm @ sys.cov[start:stop, start:stop], Qm)
        sd = np.sqrt(np.clip(var, 0, None))
        En = np.where(sd > 0, z / np.where(sd > 0, sd, 1), 0.0) / k
        frames.append(pd.DataFrame({"kind": it.kind, "file": it.source,
                                    "row": np.asarray(it.rows, int), "label": it.labels(),
                                    "residual_um": it.u_um * z,
                                    "u_residual_um": it.u_um * sd, "En": En}))
    return (pd.concat(frames, ignore_index=True) if frames
            else pd.DataFrame(columns=_READING_COLUMNS))


def _instrument_table(sys: CheckSystem, readings: pd.DataFrame) -> pd.DataFrame:
    """One row per instrument of the check: its readings, rows and their E_n."""
    out, at = [], 0
    for it, start, stop in sys.instrument_rows:  # readings in the order of the rows
        e = readings["En"].to_numpy(float)[at:at + len(it.rows)]
        at += len(it.rows)
        out.append({"kind": it.kind, "file": it.source, "readings": len(it.rows),
                    "rows": stop - start, "rms_En": float(np.sqrt(np.mean(e ** 2))),
                    "max_abs_En": float(np.max(np.abs(e)))})
    return pd.DataFrame(out, columns=["kind", "file", "readings", "rows", "rms_En",
                                      "max_abs_En"])


def _observation_table(sys: CheckSystem, res: np.ndarray, u: np.ndarray,
                       En: np.ndarray) -> pd.DataFrame:
    o = sys.obs
    t = pd.DataFrame({"position": np.asarray(o.positions, object)[o.pos],
                      "probe": np.asarray(o.probes, object)[o.probe],
                      "ball": np.asarray(o.balls)[o.ball]})
    for a, ax in enumerate("xyz"):
        t[f"{ax}_mm"] = sys.x_mm[:, a]
    for name, v in (("d{}_um", res), ("u_d{}_um", u), ("En_{}", En)):
        v3 = v.reshape(-1, 3)
        for a, ax in enumerate("xyz"):
            t[name.format(ax)] = v3[:, a]
    t["En"] = t[["En_x", "En_y", "En_z"]].abs().max(axis=1)
    return t


@single_blas_thread
def check_system(model: Model, dataset: Dataset | None, *, sigma_um: float | None = None,
                 positions: Sequence[str] | None = None,
                 probes: Sequence[str] | None = None,
                 instruments: Sequence = (),
                 exclude: Iterable[Sequence] = ()) -> CheckSystem:
    """The linear system of an interim check (module docstring), validated at the entry.

    ``instruments`` (laser runs, step gauges, ball bars as ``model.read_instrument`` gives
    them) add their nuisance-free weighted rows (``model.instruments``: ``T (pred −
    measured)``, unit covariance) below the plate's; with ``dataset`` None they are the
    whole check. Raises DataError (one line) as :func:`interim_check` says.
    """
    items = tuple(instruments)
    refuse_repeated(items)  # one file twice would count its readings double, as in a fit
    if dataset is None:
        if not items:
            raise DataError("no measurements and no instrument files: nothing to check.",
                            file=model.name, hint="give ball-plate data or instrument files.")
        obs = instrument_observations(items, model.terms.range_mm, model.terms.layout,
                                      name=model.name)
        name = items[0].source
        _refuse_model(model)
    else:
        refuse_other_machine(model, dataset.setup.machine_id, dataset.name)
        obs = select(dataset, positions=positions, probes=probes,
                     exclude=[(str(a), str(b), int(c)) for a, b, c in exclude])
        name = dataset.name
        _refuse_incomparable(model, obs, name)
    _refuse_instruments_off_strokes(model, items)
    m = 3 * len(obs.r_mm) + sum(it.transform[0].shape[0] for it in items)
    if m > 3 * MAX_OBSERVATIONS:
        raise DataError(f"{m} rows to check (ball coordinates and instrument readings); the "
                        f"check takes at most {3 * MAX_OBSERVATIONS} (its covariance is "
                        "dense: (rows)² numbers).", file=name,
                        hint="thin the instrument readings out or check fewer placements.")
    sigma = check_sigma_um(model, sigma_um)
    n, P = len(obs.r_mm), len(obs.positions) if len(obs.r_mm) else 0
    k = len(model.coef)
    x = obs.r_mm - obs.p_mm if n else np.zeros((0, 3))
    d = np.zeros(0)
    J = np.zeros((0, k))
    A = np.zeros((0, 6 * P))
    noise = np.zeros((0, 0))
    if n:
        d, A, J, noise = _plate_rows(model, obs, sigma)
    rows = []
    for it in items:  # the instruments' rows: whitened, their nuisances eliminated
        r_it, Jp = it.predict(model.terms, model.coef, True)
        T = it.transform[0]
        y, G = np.asarray(T @ r_it, float), np.asarray(T @ Jp, float)
        rows.append((it, len(d), len(d) + len(y)))
        d = np.concatenate([d, y])
        J = np.vstack([J, G])
        A = np.vstack([A, np.zeros((len(y), A.shape[1]))])
        noise = linalg.block_diag(noise, np.eye(len(y)))
    cov = noise + J @ model.cov @ J.T
    return CheckSystem(obs, d, A, J, noise, cov, x, sigma, 3 * n, tuple(rows))


def check_sigma_um(model: Model, sigma_um: float | None = None) -> float:
    """σ of one probed coordinate of the new data (µm): ``sigma_um``, or the stored
    model's σ (its ``summary.sigma_um``; 0.5 µm when the file has none). DataError (one
    line, naming the model file) when it is not a positive number."""
    sigma = float(model.summary.get("sigma_um", 0.5) if sigma_um is None else sigma_um)
    if not (np.isfinite(sigma) and sigma > 0):
        raise DataError(f"σ must be a positive number of µm, found {sigma}.", file=model.name,
                        column="summary.sigma_um", hint="give sigma_um.")
    return sigma


def _plate_rows(model: Model, obs: Observations, sigma: float) -> tuple:
    """``(d, A, J, noise)`` of the plate's observations (module docstring)."""
    p = np.array([model.probes_mm[q] for q in obs.probes], float)[obs.probe]
    # as the fit's model (fitting.py): scale readings from the nominal offsets the CMM
    # reported with, the tip from the model's effective offsets (a fitted offset error
    # moves the tip of that stylus; its uncertainty is not in the model file)
    x = obs.r_mm - obs.p_mm
    xs, Jk = kin.jacobian(model.terms, model.coef, x, p)
    corrected = xs  # the true tip
    plate = obs.plate0_mm[obs.ball]
    n, P = len(x), len(obs.positions)
    R = np.empty((n, 3, 3))
    t = np.empty((n, 3))
    A = np.zeros((3 * n, 6 * P))
    for k in range(P):
        sel = np.flatnonzero(obs.pos == k)
        Rk, tk = rigid_fit(plate[sel], corrected[sel])
        R[sel], t[sel] = Rk, tk
        q = plate[sel] @ Rk.T + tk
        q = q - q.mean(axis=0)
        for j, i in enumerate(sel):
            A[3 * i:3 * i + 3, 6 * k:6 * k + 3] = np.eye(3)
            # ω × q in µm for ω in µrad and q in mm: 1e-3 · (-[q]×) ω
            A[3 * i:3 * i + 3, 6 * k + 3:6 * k + 6] = -1e-3 * _cross_matrix(q[j])
    placed = np.einsum("nij,nj->ni", R, plate) + t
    d = ((corrected - placed) / UM).ravel()
    J = (Jk / UM).reshape(3 * n, -1)
    noise = sigma**2 * np.eye(3 * n)
    if obs.cert_u_um is not None:
        # each ball's certificate error moves every observation of it: R_k diag(u²) R_lᵀ
        K = np.zeros((3 * n, 3 * len(obs.balls)))
        for row, b in enumerate(obs.ball):
            K[3 * row:3 * row + 3, 3 * b:3 * b + 3] = R[row]
        noise += (K * (obs.cert_u_um.ravel() ** 2)) @ K.T
    return d, A, J, noise


def _refuse_instruments_off_strokes(model: Model, items: tuple) -> None:
    """One-line DataError for an instrument point outside the model's strokes by more
    than the fit's own margin (``model.RANGE_MARGIN`` of each stroke: 5 %, 30 mm on a
    600 mm Z): beyond, the Chebyshev error functions would be extrapolated, and the fit
    refuses such a point too (``model.instruments``)."""
    rng_model = np.asarray(model.terms.range_mm, float)
    tol = RANGE_MARGIN * rng_model
    for it in items:
        for xi, _ in it.points():
            bad = ((xi < -tol) | (xi > rng_model + tol)).any(axis=1)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise DataError(f"scale reading {np.round(xi[i], 1).tolist()} mm is outside "
                                f"the model's strokes {rng_model.tolist()} mm.",
                                file=it.source, row=int(it.rows[i]), column="x_mm",
                                hint="check the units and the machine.")


def _cross_matrix(v: np.ndarray) -> np.ndarray:
    """``[v]×``: ``[v]× w = v × w``."""
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


@single_blas_thread
def gls_fit(sys: CheckSystem) -> GlsFit:
    """The poses by generalised least squares with the system's full covariance."""
    factor = linalg.cho_factor(sys.cov, lower=True)
    if sys.A.shape[1] == 0:  # instruments alone: no pose
        beta, res = np.zeros(0), sys.d_um.copy()
        lev = np.zeros(len(res))
    else:
        SiA = linalg.cho_solve(factor, sys.A)
        M = sys.A.T @ SiA
        beta = np.linalg.solve(M, SiA.T @ sys.d_um)
        res = sys.d_um - sys.A @ beta
        lev = np.einsum("ij,ij->i", sys.A @ np.linalg.inv(M), sys.A)
    chi2 = float(res @ linalg.cho_solve(factor, res))
    dof = sys.A.shape[0] - sys.A.shape[1]
    return GlsFit(factor, res, np.diag(sys.cov) - lev, chi2, int(dof), beta)


def _refuse_incomparable(model: Model, obs: Observations, name: str) -> None:
    """One-line DataErrors for data the stored model cannot predict."""
    if model.terms.layout != obs.layout:
        raise DataError(f"the model {model.name} is of a {model.terms.layout} machine; the "
                        f"setup describes a {obs.layout}.", file=name, column="machine.layout",
                        hint="check the new data against a model of the same machine.")
    rng_model = np.asarray(model.terms.range_mm, float)
    if not np.allclose(rng_model, obs.range_mm, rtol=0, atol=1.0):
        raise DataError(f"the model {model.name} has strokes {rng_model.tolist()} mm; the setup "
                        f"has {np.asarray(obs.range_mm).tolist()} mm.", file=name,
                        column="machine.range_mm",
                        hint="check the new data against a model of the same machine.")
    _refuse_model(model)
    if getattr(obs, "artefact", "ball_plate") != "ball_plate":
        raise DataError(f"the check takes ball-plate data; the setup's artefact is "
                        f"{obs.artefact}.", file=name, column="artefact")
    _refuse_plate_data(model, obs, name)


def _refuse_model(model: Model) -> None:
    """One-line DataErrors for a stored model the check cannot propagate."""
    if model.parts:
        raise DataError(f"the model {model.name} has {', '.join(model.parts)}, which the "
                        "interim check does not propagate yet; expected a kinematic model "
                        "(with probe offsets).", file=model.name, column="spec",
                        hint="check against a kinematic calibration of the machine.")
    if model.undetermined:
        raise DataError(f"the model {model.name} has combinations its data did not determine: "
                        "its predictions have no uncertainty to test against.",
                        file=model.name, column="undetermined",
                        hint="check against a fully determined calibration.")


def _refuse_plate_data(model: Model, obs: Observations, name: str) -> None:
    """One-line DataErrors for plate data the stored model cannot predict."""
    rng_model = np.asarray(model.terms.range_mm, float)
    if not obs.has_certificate:
        raise DataError("the interim check needs the plate's certificate (the balls' "
                        "calibrated positions); none was given.", file=name,
                        hint="load the certificate with the measurements.")
    n = len(obs.r_mm)
    if n > MAX_OBSERVATIONS:
        raise DataError(f"{n} probed ball centres; the check takes at most "
                        f"{MAX_OBSERVATIONS} (its covariance is dense).", file=name,
                        hint="check with fewer placements or styli (positions=, probes=).")
    for k, pos in enumerate(obs.positions):
        m = int((obs.pos == k).sum())
        if m < 3:
            raise DataError(f"placement {pos} has {m} ball centre(s); a placement needs at "
                            "least 3 for its pose.", file=name, column="position")
    for i, q in enumerate(obs.probes):
        row = int(np.flatnonzero(obs.probe == i)[0])
        file_row = obs.table["row"].iloc[row] if "row" in obs.table else None
        if q not in model.probes_mm:
            raise DataError(f"stylus {q!r} is not in the model {model.name} (known: "
                            f"{', '.join(model.probes_mm)}).", file=name,
                            row=None if file_row is None else int(file_row), column="probe",
                            hint="check with the styli the model was calibrated with.")
        off = float(np.linalg.norm(obs.p_mm[row] - model.probes_mm[q]))
        if off > PROBE_TOLERANCE_MM:
            raise DataError(f"stylus {q!r} has offset {obs.p_mm[row].tolist()} mm in the setup "
                            f"but {np.round(model.probes_mm[q], 3).tolist()} mm in the model "
                            f"{model.name} ({off:.2f} mm apart; expected within "
                            f"{PROBE_TOLERANCE_MM} mm).", file=name, column="probes",
                            hint="a stylus of another length is another stylus: recalibrate.")
    tol = range_tolerance(rng_model)
    x = obs.r_mm - obs.p_mm
    bad = ((x < -tol) | (x > rng_model + tol)).any(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise DataError(f"scale reading {np.round(x[i], 1).tolist()} mm is outside the model's "
                        f"strokes {rng_model.tolist()} mm.", file=name,
                        row=int(obs.table["row"].iloc[i]) if "row" in obs.table else None,
                        column="x_mm", hint="check the units and the machine.")

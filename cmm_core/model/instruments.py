"""Laser interferometer runs, step gauges / gauge blocks and ball bars, fitted with the plate.

These instruments observe the machine's kinematic errors directly, with no plate and no
placement in between: their weighted rows depend on the kinematic coefficients only and
join the fit's least squares beside the ball plate's rows (``normal.accumulate``,
``problem.weighted_residual``), as the certificate prior's rows do. Formats, sign conventions
and what each instrument separates: ``docs/instruments.md``.

Sign convention. The kinematic model (``kinematics``) gives the true point ``x*(x, p)``
of the reading ``r = x + p`` (scale reading ``x``, offset ``p``). An instrument reports the
*error* as calibration practice writes it, indicated minus true::

    E(r) = (r - x*(r - p, p)) / UM                      (µm; minus the kinematic e)

so the correction ``compensate`` adds to a reading, ``e = x* - r``, is minus that error.

Laser interferometer (one reading per row, component ``c`` of axis ``a``'s run)::

    pred_i = E_c(r_i) + o_run [+ s_run (r_i,a - mean)]                           (1)

The interferometer is zeroed at an arbitrary point, so each run carries an unknown offset
``o_run``; a straightness run (``c != a``) also an unknown slope ``s_run`` (the alignment of
the straightness optics). Both enter linearly and are eliminated exactly: with
``W = diag(1 / u)`` and ``V`` the run's offset (and slope) columns, the rows are
``Q2ᵀ W (pred - measured)`` with ``Q2`` an orthonormal basis of the complement of
``range(W V)`` (variable projection: the same estimates, covariance and χ² as fitting the
offsets as parameters, with one row fewer per eliminated nuisance).

Step gauge or gauge block (one length per row, probed points ``r1``, ``r2``)::

    pred = L_measured + |x*(r2 - p, p) - x*(r1 - p, p)| - |r2 - r1| - L_certified   (2)

the measured length corrected by the model's change of the distance between the two
points; the row is ``pred / u``. It is sensitive to the scale of the machine, which a
self-calibrated plate cannot give (``Instruments.plate_gauge``). Ball bars (lengths between
two probed ball centres, eq. 3) are in :mod:`cmm_core.model.ballbar`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, fields
from functools import cached_property
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from ..io import DataError
from ..machine import KinematicTerms
from ..machine import kinematics as kin
from ..units import UM
from .blocks.plate import Plate
from .effects import parse_spec
from .observations import setup_layout
from .state import State

__all__ = ["LaserRun", "StepGauge", "Instruments", "RANGE_MARGIN", "summary",
           "residuals_frame", "truth_of", "simulate_laser", "simulate_step_gauge",
           "length_change", "MAX_INSTRUMENT_READINGS", "content_key",
           "refuse_repeated"]

RANGE_MARGIN = 0.05
"""Share of each axis stroke an instrument point may lie outside ``[0, range]``: beyond,
the Chebyshev error functions would be extrapolated (and a point that far out is more
likely in another frame or unit than a real reading)."""


MAX_INSTRUMENT_READINGS = 20_000
"""Most readings (rows) of one instrument file, read or fitted. A laser run in steps has
tens to hundreds of targets (ISO 230-2: at least five per metre, five times in each
direction), step gauges and ball bars tens of lengths; each reading costs a row of the
kinematic Jacobian in every iteration of the fit, so a file of 10^6 readings would take
gigabytes for no gain in what the model can tell. The readers
(``model.read_instrument``) refuse a longer file before reading it whole; the fit checks
again for readings built in code."""


class _Rows:
    """A linear map applied to a vector ``(m,)`` or to columns ``(m, k)`` through
    ``apply``, without its matrix (the matrices of eq. 1 are ``m × m``): ``T @ d``."""

    def __init__(self, shape: tuple[int, int], apply) -> None:
        self.shape = shape
        self._apply = apply

    def __matmul__(self, y):
        y = np.asarray(y, float)
        if y.shape[0] != self.shape[1]:
            raise ValueError(f"expected {self.shape[1]} rows, found {y.shape[0]}")
        return self._apply(y)


class _Reflectors:
    """Householder reflectors ``H_j = I - τ_j v_j v_jᵀ`` of ``W V`` (LAPACK geqrf) and the
    two maps of :func:`_orthocomplement` as methods: module-level and plain data, so a fit
    that holds them pickles (the app caches fits with ``st.cache_data``)."""

    def __init__(self, V, w) -> None:
        h, tau = np.linalg.qr(w[:, None] * V, mode="raw")
        self.w, self.m, self.k = w, len(w), len(tau)
        self.refl = []
        for j in range(self.k):
            v = h[j].copy()  # raw mode: row j holds the reflector below the diagonal
            v[:j] = 0.0
            v[j] = 1.0
            self.refl.append((v, tau[j]))

    @staticmethod
    def _reflect(y, order):
        y = y.copy()
        for v, t in order:
            y -= t * np.outer(v, v @ y).reshape(y.shape) if y.ndim > 1 else t * v * (v @ y)
        return y

    def rows(self, d):
        """``Q2ᵀ W d``: the weighted readings without their first k rotated rows."""
        y = d * (self.w[:, None] if d.ndim > 1 else self.w)
        return self._reflect(y, self.refl)[self.k:]

    def back(self, z):
        """``Q2 z``."""
        y = np.zeros((self.m, *z.shape[1:]))
        y[self.k:] = z
        return self._reflect(y, self.refl[::-1])


def _orthocomplement(V, w):
    """``(Q2ᵀ W, Q2)`` as maps (:class:`_Rows`): ``Q2`` (m, m - k) an orthonormal basis of
    the complement of ``range(W V)`` with ``W = diag(w)`` (module docstring, eq. 1).

    ``Q`` is kept as its Householder reflectors (:class:`_Reflectors`; LAPACK geqrf,
    ``numpy.linalg.qr(mode="raw")``, the factorisation ``mode="complete"`` forms ``Q``
    from): applying them costs O(m k) time and memory, where the complete ``Q`` took
    ``m²`` numbers (7.4 GiB for a run of 10^6 readings). ``Q = H_0 … H_{k-1}``, so
    ``Qᵀ y`` applies ``H_0`` first and ``Q y`` last; ``Q2ᵀ y`` is ``Qᵀ y`` without its
    first k rows."""
    r = _Reflectors(V, w)
    return _Rows((r.m - r.k, r.m), r.rows), _Rows((r.m, r.m - r.k), r.back)


class _Diagonal:
    """``(diag(w), I)`` as methods (picklable, as :class:`_Reflectors`)."""

    def __init__(self, w) -> None:
        self.w = w

    def rows(self, d):
        return d * (self.w[:, None] if d.ndim > 1 else self.w)

    @staticmethod
    def back(z):
        return z.copy()


class _Stack:
    """The maps of :func:`_stacked` as methods (picklable, as :class:`_Reflectors`)."""

    def __init__(self, parts, m) -> None:
        self.parts, self.m = parts, m

    def rows(self, d):
        return (np.concatenate([t @ d[sel] for sel, t, _ in self.parts]) if self.parts
                else d[:0])

    def back(self, z):
        out = np.zeros((self.m, *z.shape[1:]))
        at = 0
        for sel, t, q in self.parts:
            out[sel] = q @ z[at:at + t.shape[0]]
            at += t.shape[0]
        return out


def _stacked(parts, m):
    """``(T, Q)`` of a file from each run's ``(selection, T_k, Q_k)``: T block-diagonal
    over the runs (rows run after run), Q its transpose's layout."""
    n_rows = sum(t.shape[0] for _, t, _ in parts)
    st = _Stack(parts, m)
    return _Rows((n_rows, m), st.rows), _Rows((m, n_rows), st.back)


@dataclass(frozen=True, eq=False)
class LaserRun:
    """Readings of a laser interferometer file (``instrument_files.read_laser``).

    Attributes
    ----------
    source : str
        File name (for messages and the fit's report).
    rows : ndarray of int (m,)
        File row of each reading.
    run : ndarray of int (m,)
        Run index of each reading into ``runs``; each run has its own zero.
    runs : tuple of str
        Run names.
    axis, component : ndarray of int (m,)
        Moving axis and measured error component (0, 1, 2 = x, y, z): equal for a
        positioning run, different for a straightness run.
    r_mm, p_mm : ndarray (m, 3)
        Indicated point (the reflector, machine axes) and the offset from the ram reference
        point to it, mm.
    error_um, u_um : ndarray (m,)
        Error reading (indicated minus true, relative to the run's zero) and its standard
        uncertainty, µm.
    """

    source: str
    rows: np.ndarray
    run: np.ndarray
    runs: tuple
    axis: np.ndarray
    component: np.ndarray
    r_mm: np.ndarray
    p_mm: np.ndarray
    error_um: np.ndarray
    u_um: np.ndarray
    kind = "laser"

    @property
    def sees_scale(self) -> bool:
        """A positioning run measures lengths along its axis."""
        return bool(np.any(self.axis == self.component))

    def points(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """``(scale readings mm, offsets mm)`` of the points the model is evaluated at."""
        return [(self.r_mm - self.p_mm, self.p_mm)]

    @cached_property
    def transform(self) -> tuple[_Rows, _Rows]:
        """``(T, Q)``: rows = ``T @ (pred - measured)`` (eq. 1), block-diagonal over runs;
        maps, not matrices (:func:`_orthocomplement`)."""
        parts = []
        for k in range(len(self.runs)):
            sel = np.flatnonzero(self.run == k)
            if not sel.size:
                continue
            a = self.axis[sel[0]]
            cols = [np.ones(sel.size)]
            if self.component[sel[0]] != a:
                u = self.r_mm[sel, a]
                cols.append((u - u.mean()) / max(np.ptp(u), 1e-9))
            parts.append((sel, *_orthocomplement(np.column_stack(cols), 1.0 / self.u_um[sel])))
        return _stacked(parts, len(self.run))

    def predict(self, terms: KinematicTerms, coef: np.ndarray, want_jac: bool
            ) -> tuple[np.ndarray, np.ndarray | None]:
        """Predicted error readings (µm, eq. 1 without the nuisances) minus the measured
        ones, and their Jacobian (µm per coefficient unit, (m, terms.n)) when wanted."""
        (x, p), = self.points()
        i = np.arange(len(x))
        if want_jac:
            xs, J = kin.jacobian(terms, coef, x, p)
            Jp = -J[i, self.component] / UM
        else:
            xs, Jp = kin.model_point(terms, coef, x, p), None
        return (self.r_mm - xs)[i, self.component] / UM - self.error_um, Jp

    def labels(self) -> list[str]:
        """Run name of each reading (the report's per-reading label)."""
        return [self.runs[k] for k in self.run]


@dataclass(frozen=True, eq=False)
class StepGauge:
    """Lengths measured on a step gauge or gauge blocks (``instrument_files.read_step_gauge``).

    Attributes
    ----------
    source : str
    rows : ndarray of int (m,)
    gauge : tuple of str
        Label of each length (gauge and face, block size ...).
    r1_mm, r2_mm, p_mm : ndarray (m, 3)
        Indicated tip centres of the two probings and the stylus offset, mm.
    measured_mm, certified_mm : ndarray (m,)
        Length the CMM indicates, and the certified length at the measuring temperature.
    u_um : ndarray (m,)
        Standard uncertainty of measured minus certified length, µm.
    """

    source: str
    rows: np.ndarray
    gauge: tuple
    r1_mm: np.ndarray
    r2_mm: np.ndarray
    p_mm: np.ndarray
    measured_mm: np.ndarray
    certified_mm: np.ndarray
    u_um: np.ndarray
    kind = "step_gauge"
    sees_scale = True

    def points(self) -> list[tuple[np.ndarray, np.ndarray]]:
        return [(self.r1_mm - self.p_mm, self.p_mm), (self.r2_mm - self.p_mm, self.p_mm)]

    @cached_property
    def transform(self) -> tuple[_Rows, _Rows]:
        """``(diag(1/u), I)`` as maps: each length is its own row."""
        diag = _Diagonal(1.0 / self.u_um)
        m = diag.w.size
        return _Rows((m, m), diag.rows), _Rows((m, m), diag.back)

    def predict(self, terms: KinematicTerms, coef: np.ndarray, want_jac: bool
            ) -> tuple[np.ndarray, np.ndarray | None]:
        """Eq. 2 in µm and its Jacobian (µm per coefficient unit)."""
        change, Jp = length_change(terms, coef, self.r1_mm, self.r2_mm, self.p_mm, want_jac)
        return (self.measured_mm - self.certified_mm + change) / UM, Jp

    def labels(self) -> list[str]:
        return list(self.gauge)


def length_change(terms: KinematicTerms, coef: np.ndarray, r1_mm: np.ndarray,
              r2_mm: np.ndarray, p_mm: np.ndarray, want_jac: bool
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """The model's change of the distance between two indicated points (mm),
    ``|x*(r2 - p, p) - x*(r1 - p, p)| - |r2 - r1|``, and its Jacobian (µm per coefficient
    unit, (m, terms.n)) when wanted: the length terms of eq. 2 and 3."""
    x1, x2 = r1_mm - p_mm, r2_mm - p_mm
    if want_jac:
        (s1, J1), (s2, J2) = kin.jacobian(terms, coef, x1, p_mm), kin.jacobian(terms, coef, x2,
                                                                                p_mm)
    else:
        s1, s2 = kin.model_point(terms, coef, x1, p_mm), kin.model_point(terms, coef, x2, p_mm)
    d, e = s2 - s1, r2_mm - r1_mm
    nd, ne = np.linalg.norm(d, axis=1), np.linalg.norm(e, axis=1)
    # |d| - |e| without cancelling two lengths of ~1 m to a micrometre difference
    change = np.einsum("ni,ni->n", d - e, d + e) / (nd + ne)
    Jp = (np.einsum("ni,nik->nk", d / nd[:, None], J2 - J1) / UM) if want_jac else None
    return change, Jp


class Instruments:
    """The instrument rows of one :class:`problem.Problem` (``Problem.instruments``).

    Parameters
    ----------
    problem : problem.Problem
        Its observations carry the instrument data (``Observations.instruments``); its
        kinematic terms and layout fix the model and the columns.
    """

    def __init__(self, problem: Any) -> None:
        self.items = tuple(getattr(problem.obs, "instruments", ()) or ())
        self.terms = problem.terms
        self.cols = problem.layout.blocks.get("kinematic", slice(0, 0))
        if self.items:
            _check_size(self.items)
            refuse_repeated(self.items)
            _check_in_range(self.items, np.asarray(problem.obs.range_mm, float))

    @property
    def sees_scale(self) -> bool:
        """Whether any instrument measures a length (step gauge, ball bar, positioning
        run)."""
        return any(it.sees_scale for it in self.items)

    @property
    def n_rows(self) -> int:
        """Number of weighted rows the instruments add (the last rows of the fit's)."""
        return sum(it.transform[0].shape[0] for it in self.items)

    def plate_gauge(self, block: Plate, G: np.ndarray) -> np.ndarray:
        """A self-calibrated plate's gauge constraints ``G`` (``Plate.constraints``: rigid
        motions, then the isotropic scale, always last) without the scale when an
        instrument gives the machine's scale: the scale is then determined, and holding it
        at the starting plate would bias the machine's positioning errors."""

        if isinstance(block, Plate) and self.sees_scale:
            return G[:-1]
        return G

    def evaluate(self, state: State, want_jac: bool = False) -> list[tuple[Any, np.ndarray, Any]]:
        """Per instrument: ``(item, weighted rows, Jacobian over the kinematic columns or
        None)``."""
        coef = state.x[self.cols]
        out = []
        for it in self.items:
            d, Jp = it.predict(self.terms, coef, want_jac)
            T = it.transform[0]
            out.append((it, T @ d, None if Jp is None else T @ Jp))
        return out

    def rows(self, state: State, want_jac: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """All weighted rows (m,) and their Jacobian over ``self.cols`` (m, k) or None."""
        parts = self.evaluate(state, want_jac)
        k = self.cols.stop - self.cols.start
        r = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0)
        if not want_jac:
            return r, None
        return r, (np.vstack([p[2] for p in parts]) if parts else np.zeros((0, k)))

    def append(self, r: np.ndarray, J: Any, state: State, n_params: int) -> tuple[np.ndarray, Any]:
        """``r`` and the sparse ``J`` of ``problem.weighted_residual`` with the instrument rows
        appended (J in CSR over all ``n_params`` columns, or None)."""
        if not self.items:
            return r, J
        import scipy.sparse as sp

        ri, Ji = self.rows(state, J is not None)
        if J is not None:
            full = np.zeros((ri.size, n_params))
            full[:, self.cols] = Ji
            J = sp.vstack([J, sp.csr_matrix(full)]).tocsr()
        return np.concatenate([r, ri]), J


def _check_size(items):
    """Refuse an instrument file of more than :data:`MAX_INSTRUMENT_READINGS` readings,
    naming it."""
    for it in items:
        if len(it.rows) > MAX_INSTRUMENT_READINGS:
            raise DataError(f"{len(it.rows):,} readings; at most {MAX_INSTRUMENT_READINGS:,} of one "
                            f"instrument file are fitted (a calibration takes tens to "
                            "hundreds per run, and each costs a row of the fit's Jacobian "
                            "in every iteration).", file=it.source,
                            hint="thin the readings out (keep every n-th row).")


def content_key(item: Any) -> str:
    """Fingerprint of an instrument's readings: its kind and every array it holds but the
    file's row numbers (the same readings read from two files give the same key)."""
    h = hashlib.sha256(type(item).__name__.encode())
    for f in fields(item):
        v = getattr(item, f.name)
        if f.name != "rows" and isinstance(v, np.ndarray):
            h.update(f.name.encode() + np.ascontiguousarray(v).tobytes())
    return h.hexdigest()


def refuse_repeated(items: Sequence[Any]) -> None:
    """Refuse the same readings given twice (one file twice, or two files of the same
    content): fitted twice, they would count double and divide every uncertainty they
    give by √2 without a word. Every entry point (CLI, app, analysis record) fits through
    here."""
    seen: dict[str, str] = {}
    for it in items:
        key = content_key(it)
        if key in seen:
            same = seen[key] == it.source
            raise DataError(
                ("is given twice" if same else f"holds the same readings as {seen[key]}")
                + "; each instrument file may be fitted once (twice would count its "
                "readings double).", file=it.source,
                hint="remove the repeated instrument file (on the command line: the "
                "repeated --laser, --step-gauge or --ball-bar).")
        seen[key] = it.source


def _check_in_range(items, range_mm):
    """Refuse instrument points outside the machine's strokes (:data:`RANGE_MARGIN`)."""
    lo, hi = -RANGE_MARGIN * range_mm, (1 + RANGE_MARGIN) * range_mm
    for it in items:
        for x, _ in it.points():
            bad = np.flatnonzero(((x < lo) | (x > hi)).any(axis=1))
            if bad.size:
                i = bad[0]
                a = int(np.flatnonzero((x[i] < lo) | (x[i] > hi))[0])
                raise DataError(
                    f"the scale reading {x[i, a]:.1f} mm of axis {'xyz'[a]} is outside the "
                    f"machine's stroke 0 to {range_mm[a]:g} mm (setup machine.range_mm); "
                    "expected machine coordinates in mm.", file=it.source,
                    row=int(it.rows[i]), hint="instrument files are in machine axes, the "
                    "point minus its offset being the ram's scale reading.")


def _per_reading(it, state_rows):
    """Residual of each reading (µm, nuisances removed) from its weighted rows."""
    Q = it.transform[1]
    return it.u_um * (Q @ state_rows)


def summary(result: Any) -> list:
    """Each instrument of a fit (``FitResult``) with its readings, rows, χ² and χ² share.

    ``rows`` counts the weighted rows the instrument adds (readings minus the eliminated
    run offsets and slopes): the degrees of freedom it brings before parameters.
    ``chi2_share`` is its part of the fit's χ²; near ``rows / (fit rows)`` when the model
    explains the instrument and the plate alike; ``rms_z`` is the RMS of residual / u. A
    laser record names its ``runs``; a ball bar's lists its ``lengths``: label, file row,
    residual (µm, the model's prediction minus the reading) and u (µm) of each.
    """
    prob = result.problem
    out = []
    for it, r, _ in prob.instruments.evaluate(result.state):
        chi2 = float(r @ r)
        res = _per_reading(it, r)
        rec = {"kind": it.kind, "file": it.source, "readings": int(len(it.rows)),
               "rows": int(r.size), "chi2": chi2,
               "chi2_share": chi2 / result.chi2 if result.chi2 > 0 else float("nan"),
               "rms_um": float(np.sqrt(np.mean(res ** 2))),
               "rms_z": float(np.sqrt(np.mean((res / it.u_um) ** 2))),
               "max_abs_z": float(np.max(np.abs(res / it.u_um)))}
        if it.kind == "laser":
            rec["runs"] = list(it.runs)
        if it.kind == "ball_bar":  # a few lengths, each the result of a length test
            rec["lengths"] = [{"label": lab, "row": int(row), "residual_um": float(v),
                               "u_um": float(u)} for lab, row, v, u in
                              zip(it.labels(), it.rows, res, it.u_um, strict=True)]
        out.append(rec)
    return out


def residuals_frame(result: Any) -> pd.DataFrame:
    """One row per instrument reading: kind, file, row, run or gauge label, residual (µm,
    the model's prediction minus the reading, nuisances removed) and u (µm)."""
    frames = []
    for it, r, _ in result.problem.instruments.evaluate(result.state):
        frames.append(pd.DataFrame({"kind": it.kind, "file": it.source, "row": it.rows,
                                    "label": it.labels(), "residual_um": _per_reading(it, r),
                                    "u_um": it.u_um}))
    cols = ["kind", "file", "row", "label", "residual_um", "u_um"]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=cols)


# --- simulation from a Simulation's truth ------------------------------------------------

def truth_of(sim: Any) -> tuple[KinematicTerms, np.ndarray]:
    """``(KinematicTerms, coefficients)`` of a ``virtual_cmm.Simulation``'s true machine: its
    kinematic spec, order, strokes and layout, the coefficients from ``sim.truth``."""

    km, setup = sim.config["kinematic"], sim.dataset.setup
    spec = parse_spec(km["spec"], default_order=int(km["order"]))
    terms = KinematicTerms(spec.active, tuple(setup.range_mm), spec.periods,
                               setup_layout(setup))
    return terms, np.array([sim.truth[lab] for lab in terms.labels])


def simulate_laser(sim: Any, axis: str, line_mm: ArrayLike,
                   positions_mm: Sequence[float] | np.ndarray, *,
               component: str | None = None, offset_mm: ArrayLike = (0.0, 0.0, 0.0),
               u_um: float = 0.2, seed: int | None = None, run: str = "run1",
               source: str = "simulated laser") -> LaserRun:
    """A laser run on ``sim``'s true machine: readings (eq. 1) with noise N(0, u).

    Parameters
    ----------
    sim : virtual_cmm.Simulation
    axis : {"x", "y", "z"}
        Moving axis.
    line_mm : (3,) array
        Ram point of the line (its ``axis`` coordinate is ignored), mm machine axes.
    positions_mm : array
        Scale readings of ``axis`` at the readings, mm.
    component : {"x", "y", "z"}, optional
        Measured component (default ``axis``: positioning; another: straightness).
    offset_mm : (3,) array
        Reflector offset from the ram reference point, mm.
    u_um : float
        Standard deviation of the reading noise, and the file's ``u_um``.
    seed : int or None
        Noise seed.

    The readings are zeroed at the first point (the interferometer's datum), to within
    that point's noise; the run's offset is eliminated in the fit anyway.
    """
    a = "xyz".index(axis)
    c = a if component is None else "xyz".index(component)
    terms, coef = truth_of(sim)
    x = np.tile(np.asarray(line_mm, float), (len(positions_mm), 1))
    x[:, a] = positions_mm
    p = np.broadcast_to(np.asarray(offset_mm, float), x.shape).copy()
    r = x + p
    e = (r - kin.model_point(terms, coef, x, p))[:, c] / UM
    m = len(x)
    noise = np.random.default_rng(seed).normal(0.0, u_um, m)
    return LaserRun(source, np.arange(2, m + 2), np.zeros(m, int), (run,), np.full(m, a),
                    np.full(m, c), r, p, e - e[0] + noise, np.full(m, float(u_um)))


def simulate_step_gauge(sim: Any, start_mm: ArrayLike, end_mm: ArrayLike,
                    lengths_mm: ArrayLike, *, offset_mm: ArrayLike = (0.0, 0.0, 0.0),
                    u_um: float = 0.3, seed: int | None = None,
                    source: str = "simulated step gauge") -> StepGauge:
    """Lengths of a step gauge on ``sim``'s true machine: true faces at ``start + L n``
    (``n`` the unit vector towards ``end_mm``) for each certified length ``L``, probed where
    the CMM indicates ``r = x + p`` with ``x*(x, p)`` the true face (``kinematics.invert``);
    the measured length is ``|r2 - r1|`` plus noise N(0, u). Points in mm, machine axes."""
    terms, coef = truth_of(sim)
    s0, s1 = np.asarray(start_mm, float), np.asarray(end_mm, float)
    n = (s1 - s0) / np.linalg.norm(s1 - s0)
    L = np.asarray(lengths_mm, float)
    m = L.size
    p = np.broadcast_to(np.asarray(offset_mm, float), (m, 3)).copy()
    t1 = np.tile(s0, (m, 1))
    t2 = s0 + L[:, None] * n
    r1 = kin.invert(terms, coef, t1, p) + p
    r2 = kin.invert(terms, coef, t2, p) + p
    noise = np.random.default_rng(seed).normal(0.0, u_um, m) * UM
    return StepGauge(source, np.arange(2, m + 2), tuple(f"L{v:g}" for v in L), r1, r2, p,
                     np.linalg.norm(r2 - r1, axis=1) + noise, L, np.full(m, float(u_um)))

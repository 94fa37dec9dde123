"""GUM Supplement 1 Monte Carlo propagation of distributions (JCGM 101:2008 clause 7).

:func:`monte_carlo` samples every input from its distribution (JCGM 101 6.4), evaluates
the model (additive, or a vectorised measurement function) on the samples (7.2-7.5), and
summarises the model values (7.6) with the probabilistically symmetric and the shortest
coverage intervals (:func:`coverage_intervals`, 7.7); with ``adaptive=True`` it runs the
adaptive procedure of 7.9 to a numerical tolerance of u(y) (:func:`_tolerance`, 7.9.2).
The result is a :class:`MonteCarloResult`.

See Also
--------
cmm_core.gum.framework : the GUM framework (JCGM 100) on the same inputs.
cmm_core.gum : re-exports these names.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .inputs import (
    _SHAPES,
    Contribution,
    _as_contributions,
    _check_number,
    correlation_matrix,
    half_width_divisor,
)


@dataclass(frozen=True)
class MonteCarloResult:
    """Result of the Monte Carlo method of GUM Supplement 1 (JCGM 101 7.6-7.9)."""

    mean: float
    """Estimate y: average of the model values (JCGM 101 eq. 15)."""
    u: float
    """Standard uncertainty u(y): standard deviation of the model values (JCGM 101 eq. 16)."""
    interval_shortest: tuple[float, float]
    """Shortest coverage interval for p (JCGM 101 7.7.2)."""
    interval_symmetric: tuple[float, float]
    """Probabilistically symmetric coverage interval for p (JCGM 101 7.7.2)."""
    coverage_probability: float
    """Coverage probability p."""
    trials: int
    """Number of model evaluations M used."""
    status: str
    """'ok' (fixed M done), 'converged' (adaptive, stabilised), 'max_trials' (adaptive, not
    stabilised within max_trials) or 'cancelled' (progress callback returned False; partial)."""
    tolerance: float | None
    """Numerical tolerance delta of u(y) (JCGM 101 7.9.2), adaptive runs only."""
    seed: int | None
    """Seed of np.random.default_rng (None when a Generator was passed)."""
    elapsed_s: float
    """Wall time of the run."""
    hist_counts: np.ndarray = field(repr=False)
    """Histogram of the model values (for plotting the output PDF)."""
    hist_edges: np.ndarray = field(repr=False)
    """Bin edges of the histogram."""
    values: np.ndarray | None = field(default=None, repr=False)
    """The model values (sorted) when keep_values=True."""


def coverage_intervals(sorted_values: np.ndarray, coverage_probability: float
                       ) -> tuple[tuple[float, float], tuple[float, float]]:
    """Probabilistically symmetric and shortest coverage intervals (JCGM 101 7.7.2).

    With ``q = pM`` (rounded as ``int(pM + 1/2)`` if not an integer) the symmetric interval
    is ``[y_(r), y_(r+q)]`` with ``r = (M - q)/2`` (or ``int((M - q + 1)/2)``) and the
    shortest interval is ``[y_(r*), y_(r*+q)]`` with ``r*`` minimising its length
    (1-based order statistics).
    """
    ys = np.asarray(sorted_values, float)
    m = ys.size
    p = float(coverage_probability)
    if m < 2:
        return (math.nan, math.nan), (math.nan, math.nan)
    pm = p * m
    q = int(pm) if float(pm).is_integer() else int(pm + 0.5)
    q = min(max(q, 1), m - 1)
    r = (m - q) // 2 if (m - q) % 2 == 0 else int((m - q + 1) / 2)
    r = max(r, 1)
    sym = (float(ys[r - 1]), float(ys[r + q - 1]))
    width = ys[q:] - ys[: m - q]
    j = int(np.argmin(width))
    short = (float(ys[j]), float(ys[j + q]))
    return sym, short


def _sampler(cts: Sequence[Contribution], student_t: bool, R: np.ndarray | None = None):
    """Draw ``m`` values of every input: list of arrays (JCGM 101 6.4).

    Inputs correlated through ``R`` are drawn jointly from the multivariate Gaussian
    distribution N(x, diag(u) R diag(u)) (JCGM 101 6.4.8); the others independently.
    """
    R = np.eye(len(cts)) if R is None else R  # no correlation: every input alone
    joint = np.flatnonzero(np.any(R - np.eye(len(cts)) != 0, axis=1))

    def draw(rng: np.random.Generator, m: int) -> list[np.ndarray]:
        out = []
        z_joint = None
        for i, ct in enumerate(cts):
            if i in joint:
                if z_joint is None:     # drawn once per chunk, at the first correlated input
                    z_joint = dict(zip(joint.tolist(), rng.multivariate_normal(
                        np.zeros(joint.size), R[np.ix_(joint, joint)], size=m).T,
                        strict=True))
                out.append(ct.value + ct.u * z_joint[i])
                continue
            if ct.u == 0.0:
                out.append(np.full(m, ct.value))
                continue
            if ct.distribution == "normal":
                if student_t and math.isfinite(ct.dof):
                    # JCGM 101 6.4.9: scaled and shifted t with nu dof; u(x) = s/sqrt(n)
                    z = stats.t.rvs(ct.dof, size=m, random_state=rng)
                else:
                    z = stats.norm.rvs(size=m, random_state=rng)
                out.append(ct.value + ct.u * z)
            else:
                a = ct.u * half_width_divisor(ct.distribution)
                out.append(ct.value + a * _SHAPES[ct.distribution].rvs(size=m, random_state=rng))
        return out
    return draw


def _model(cts: Sequence[Contribution], function: Callable | None):
    if function is None:
        c = np.array([1.0 if ct.c is None else float(ct.c) for ct in cts])

        def f(xs):
            y = c[0] * xs[0]
            for ci, xi in zip(c[1:], xs[1:], strict=True):
                y = y + ci * xi
            return y
        return f

    def g(xs):
        y = np.asarray(function(*xs), float)
        if y.shape != xs[0].shape:
            raise ValueError(f"function: expected a vectorised function returning shape "
                             f"{xs[0].shape}, got shape {y.shape}.")
        return y
    return g


def _tolerance(u: float, n_dig: int) -> float:
    """delta = 1/2 10^l with u = c 10^l, c an n_dig-digit integer (JCGM 101 7.9.2)."""
    if not u > 0:
        return math.inf
    l_exp = math.floor(math.log10(u)) - n_dig + 1
    return 0.5 * 10.0**l_exp


def monte_carlo(contributions: Sequence[Contribution], *, function: Callable | None = None,
                trials: int = 1_000_000, coverage_probability: float = 0.95,
                seed: int | None = None, rng: np.random.Generator | None = None,
                chunk_size: int = 131_072, progress: Callable[[float], bool | None] | None = None,
                adaptive: bool = False, n_dig: int = 2, max_trials: int = 10_000_000,
                student_t_for_finite_dof: bool = False, keep_values: bool = False,
                bins: int = 100, correlations=None) -> MonteCarloResult:
    """Propagate the input distributions by Monte Carlo (JCGM 101 clause 7).

    Parameters
    ----------
    contributions : sequence of Contribution
        Inputs, sampled independently from their distributions (JCGM 101 6.4):
        normal N(x, u^2), rectangular/triangular/arc-sine of half-width a with u = a/sqrt(3),
        a/sqrt(6), a/sqrt(2) about x.
    function : callable, optional
        Vectorised measurement function ``f(x_1, ..., x_N) -> array``; without it
        ``Y = sum c_i X_i``.
    trials : int
        Number of trials M of a fixed-size run (JCGM 101 7.2); ignored when adaptive.
    coverage_probability : float
        p of the coverage intervals.
    seed, rng : optional
        Seed for ``np.random.default_rng`` or a Generator (reproducible runs).
    chunk_size : int
        Trials drawn per vectorised chunk (memory bound; progress is reported per chunk).
    progress : callable, optional
        ``progress(fraction)`` called after every chunk with the fraction done (for an
        adaptive run an estimate from the stabilisation criterion); returning False cancels
        and a partial result with status 'cancelled' is returned.
    adaptive : bool
        Adaptive procedure of JCGM 101 7.9: sequences of ``M = max(100/(1-p), 10^4)``
        trials until twice the standard deviation of the sequence means of y, u(y) and the
        shortest-interval endpoints is at most the tolerance delta of u(y) to ``n_dig``
        significant digits; results from all h M values (7.9.4 g).
    n_dig : int
        Significant decimal digits of u(y) regarded as meaningful (JCGM 101 7.9.2).
    max_trials : int
        Limit of an adaptive run (status 'max_trials' when reached unconverged).
    student_t_for_finite_dof : bool
        Sample normal inputs with finite dof from the scaled and shifted t distribution
        (JCGM 101 6.4.9, Type A input from n = dof + 1 indications, whose u = s/sqrt(n));
        default False samples N(x, u^2) as the GUM framework assumes.
    keep_values : bool
        Keep the sorted model values in the result.
    bins : int
        Number of histogram bins (between the 0.05 % and 99.95 % quantiles).
    correlations : mapping or sequence, optional
        ``{(a, b): r}`` or ``[(a, b, r), ...]`` between named inputs, as for
        :func:`~cmm_core.gum.framework.gum_combine` (validated by
        :func:`~cmm_core.gum.inputs.correlation_matrix`). Correlated inputs must be normal:
        they are drawn from the multivariate Gaussian distribution with covariance
        ``u_i u_j r_ij`` (JCGM 101 6.4.8, JCGM 100 eq. 14); a joint distribution of
        correlated rectangular or other inputs is not defined by their r alone.

    Returns
    -------
    MonteCarloResult
    """
    cts = _as_contributions(contributions)
    p = _checked_arguments(cts, function, coverage_probability, trials, chunk_size, n_dig,
                           max_trials)
    R = _checked_correlation(cts, correlations, student_t_for_finite_dof)
    if rng is None:
        rng = np.random.default_rng(seed)
    else:
        seed = None
    draw = _sampler(cts, student_t_for_finite_dof, R)
    model = _model(cts, function)
    t0 = time.perf_counter()

    def batch(m: int) -> np.ndarray:
        return model(draw(rng, m))

    if adaptive:
        values, status, tol = _adaptive_run(batch, p, chunk_size, max_trials, n_dig, progress)
        if progress is not None and status != "cancelled":
            progress(1.0)
    else:
        values, status, tol = _fixed_run(batch, int(trials), chunk_size, progress)
    values = np.sort(values)
    n = values.size
    mean = float(np.mean(values)) if n else math.nan
    u = float(np.std(values, ddof=1)) if n >= 2 else math.nan
    sym, short = coverage_intervals(values, p)
    counts, edges = _histogram(values, bins)
    return MonteCarloResult(mean=mean, u=u, interval_shortest=short, interval_symmetric=sym,
                            coverage_probability=p, trials=int(n), status=status,
                            tolerance=tol, seed=seed, elapsed_s=time.perf_counter() - t0,
                            hist_counts=counts, hist_edges=edges,
                            values=values if keep_values else None)


def _checked_arguments(cts, function, coverage_probability, trials, chunk_size, n_dig,
                       max_trials) -> float:
    """The arguments of :func:`monte_carlo` checked; returns the coverage probability."""
    if function is not None:
        for i, ct in enumerate(cts):
            if ct.c is not None:
                raise ValueError(f"contributions[{i}].c: expected None when a measurement "
                                 f"function is given, got {ct.c}.")
    p = _check_number(coverage_probability, "coverage_probability")
    if not 0 < p < 1:
        raise ValueError(f"coverage_probability: expected a value in (0, 1), got {p}.")
    for what, v, lo in (("trials", trials, 2), ("chunk_size", chunk_size, 1),
                        ("n_dig", n_dig, 1), ("max_trials", max_trials, 2)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{what}: expected an integer >= {lo}, got {v!r}.")
    return p


def _checked_correlation(cts, correlations, student_t: bool) -> np.ndarray | None:
    """The correlation matrix of the inputs (None when independent); correlated inputs
    must be normal, and not sampled from a t distribution."""
    R = correlation_matrix(cts, correlations)
    off = np.any(R - np.eye(len(cts)) != 0, axis=1)
    if not off.any():
        return None
    for i in np.flatnonzero(off):
        ct = cts[i]
        if ct.distribution != "normal":
            raise ValueError(f"correlations: {ct.name!r} is {ct.distribution}; expected "
                             "normal inputs only to be correlated in the Monte Carlo method "
                             "(JCGM 101 6.4.8, multivariate Gaussian). Hint: its r alone does "
                             "not define a joint distribution of non-normal inputs; use the "
                             "GUM framework (gum_combine) for it.")
        if student_t and math.isfinite(ct.dof):
            raise ValueError(f"correlations: {ct.name!r} has {ct.dof:g} dof and "
                             "student_t_for_finite_dof is set; expected correlated inputs "
                             "to be sampled as Gaussian. Hint: leave student_t_for_finite_dof "
                             "False.")
    return R


def _fixed_run(batch, trials, chunk_size, progress):
    """A run of ``trials`` model values drawn in chunks (JCGM 101 7.2); the progress
    callback may cancel it. Returns ``(values, status, None)``."""
    values = np.empty(trials)
    done = 0
    while done < trials:
        m = min(chunk_size, trials - done)
        values[done:done + m] = batch(m)
        done += m
        if progress is not None and progress(done / trials) is False and done < trials:
            return values[:done], "cancelled", None
    return values, "ok", None


def _adaptive_run(batch, p, chunk_size, max_trials, n_dig, progress):
    """The adaptive procedure of JCGM 101 7.9: sequences of M values until the sequence
    means of y, u(y) and the shortest-interval endpoints are stable to the tolerance of
    u(y). Returns ``(all values, status, tolerance)``."""
    m_seq = max(math.ceil(100.0 / (1.0 - p) - 1e-9), 10_000)     # JCGM 101 7.9.4 a)
    per_chunk = max(1, chunk_size // m_seq)
    h_max = max(2, max_trials // m_seq)
    buf = np.empty(min(h_max, 64) * m_seq)
    summaries = []                                # (y, u, low, high) per sequence
    fraction, status, h, tol = 0.0, "max_trials", 0, None
    while h < h_max:
        n_new = min(per_chunk, h_max - h)
        if buf.size < (h + n_new) * m_seq:
            buf = np.concatenate([buf, np.empty(max(buf.size, n_new * m_seq))])
        for _ in range(n_new):
            seg = buf[h * m_seq:(h + 1) * m_seq]
            seg[:] = batch(m_seq)
            s = np.sort(seg)
            _, short = coverage_intervals(s, p)
            summaries.append((float(np.mean(s)), float(np.std(s, ddof=1)), *short))
            h += 1
            if h >= 2:
                arr = np.array(summaries)
                sd_means = np.std(arr, axis=0, ddof=1) / math.sqrt(h)   # 7.9.4 d)
                u_all = float(np.std(buf[:h * m_seq], ddof=1))
                tol = _tolerance(u_all, n_dig)                         # 7.9.4 e)
                ratio = float(np.max(2.0 * sd_means) / tol)
                if ratio <= 1.0:                                       # 7.9.4 f)
                    return buf[:h * m_seq], "converged", tol
                fraction = max(fraction, min(0.99, 1.0 / ratio**2), h / h_max)
        if progress is not None and progress(fraction) is False:
            return buf[:h * m_seq], "cancelled", tol
    return buf[:h * m_seq], status, tol


def _histogram(values, bins):
    """Histogram of the sorted values between their 0.05 % and 99.95 % quantiles."""
    if values.size < 2:
        return np.zeros(bins, int), np.linspace(0.0, 1.0, bins + 1)
    lo, hi = np.quantile(values, [0.0005, 0.9995])
    if not hi > lo:
        lo, hi = lo - 0.5, hi + 0.5
    return np.histogram(values, bins=bins, range=(lo, hi))

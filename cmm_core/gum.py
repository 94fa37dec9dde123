"""GUM uncertainty budgets (JCGM 100:2008) and GUM Supplement 1 Monte Carlo (JCGM 101:2008).

A budget is a sequence of :class:`Contribution` (one input quantity each: its estimate,
standard uncertainty, probability distribution, sensitivity coefficient and degrees of
freedom). :func:`gum_combine` applies the law of propagation of uncertainty for
uncorrelated inputs (JCGM 100 5.1.2, eq. 10), the Welch-Satterthwaite formula (JCGM 100
G.4.1, eq. G.2b) and the coverage factor from the t distribution (JCGM 100 G.3, G.4).
:func:`monte_carlo` propagates the distributions themselves (JCGM 101 clause 7), with
probabilistically symmetric and shortest coverage intervals (JCGM 101 7.7) and the adaptive
procedure of JCGM 101 7.9. :func:`budget_from_dict` is the ``budget`` command of the CLI
(SPEC "Command line").

Without a measurement function the model is additive, ``Y = sum_i c_i X_i`` (``c_i``
default 1), as in a classical budget table whose rows are already expressed in the unit of
the measurand. With a measurement function ``Y = f(X_1, ..., X_N)`` the sensitivity
coefficients are central differences (JCGM 100 5.1.3) and the Monte Carlo method evaluates
``f`` on the sampled inputs.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

DISTRIBUTIONS = ("normal", "rectangular", "triangular", "u_shaped")
"""Probability distributions an input may have (JCGM 100 4.3.7-4.3.9, JCGM 101 6.4)."""

# Symmetric shapes on [-1, 1] (half-width 1); scaled by the half-width a of the input.
_SHAPES = {
    "rectangular": stats.uniform(loc=-1.0, scale=2.0),      # JCGM 101 6.4.2
    "triangular": stats.triang(0.5, loc=-1.0, scale=2.0),   # JCGM 101 6.4.5
    "u_shaped": stats.arcsine(loc=-1.0, scale=2.0),         # JCGM 101 6.4.6 (arc sine)
}


def half_width_divisor(distribution: str) -> float:
    """Ratio half-width / standard uncertainty: sqrt(3), sqrt(6), sqrt(2) (JCGM 100 4.3.7-4.3.9).

    Computed from the scipy distribution of half-width 1, not hard-coded.
    """
    if distribution not in _SHAPES:
        raise ValueError(f"distribution: expected one of {', '.join(_SHAPES)} for a "
                         f"half-width, got {distribution!r}.")
    return float(1.0 / _SHAPES[distribution].std())


def _check_number(value, what: str, *, positive=False, allow_inf=False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected a number, got {value!r}.") from None
    if isinstance(value, bool) or math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise ValueError(f"{what}: expected a finite number, got {value!r}.")
    if positive and not v > 0:
        raise ValueError(f"{what}: expected a positive number, got {value!r}.")
    return v


@dataclass(frozen=True)
class Contribution:
    """One input quantity of an uncertainty budget (one row of a GUM budget table)."""

    name: str
    """Label of the input quantity (shown in tables)."""
    u: float
    """Standard uncertainty u(x_i) of the input, in the unit of the input (JCGM 100 4.1.5)."""
    distribution: str = "normal"
    """'normal', 'rectangular', 'triangular' or 'u_shaped' (arc sine)."""
    c: float | None = None
    """Sensitivity coefficient dY/dX_i (JCGM 100 5.1.3); None means 1 for an additive model
    or the numerical derivative when a measurement function is given."""
    dof: float = math.inf
    """Degrees of freedom of u(x_i) (JCGM 100 G.3, G.4.2); inf for an exactly known u."""
    value: float = 0.0
    """Estimate x_i of the input (the expectation of its distribution)."""
    unit: str = ""
    """Unit of the input quantity (documentation only)."""

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise ValueError(f"name: expected a string, got {self.name!r}.")
        if self.distribution not in DISTRIBUTIONS:
            raise ValueError(f"{self.name}: distribution: expected one of "
                             f"{', '.join(DISTRIBUTIONS)}, got {self.distribution!r}.")
        u = _check_number(self.u, f"{self.name}: u")
        if u < 0:
            raise ValueError(f"{self.name}: u: expected a standard uncertainty >= 0, got {u}.")
        _check_number(self.dof, f"{self.name}: dof", positive=True, allow_inf=True)
        _check_number(self.value, f"{self.name}: value")
        if self.c is not None:
            _check_number(self.c, f"{self.name}: c")

    @classmethod
    def from_half_width(cls, name: str, half_width: float, distribution: str = "rectangular",
                        *, k: float | None = None, **kwargs) -> Contribution:
        """Contribution from a half-width ``a`` (JCGM 100 4.3.7-4.3.9).

        ``u = a / sqrt(3)`` (rectangular), ``a / sqrt(6)`` (triangular), ``a / sqrt(2)``
        (U-shaped). For a normal input ``half_width`` is an expanded uncertainty and ``k``
        its coverage factor (JCGM 100 4.3.3), ``u = a / k``.
        """
        a = _check_number(half_width, f"{name}: half_width")
        if a < 0:
            raise ValueError(f"{name}: half_width: expected a value >= 0, got {a}.")
        if distribution == "normal":
            if k is None:
                raise ValueError(f"{name}: a normal input given by half_width needs its "
                                 "coverage factor 'k' (or give 'u').")
            u = a / _check_number(k, f"{name}: k", positive=True)
        else:
            u = a / half_width_divisor(distribution)
        return cls(name=name, u=u, distribution=distribution, **kwargs)

    @property
    def half_width(self) -> float | None:
        """Half-width of the distribution (None for a normal input)."""
        if self.distribution == "normal":
            return None
        return self.u * half_width_divisor(self.distribution)


@dataclass(frozen=True)
class GumResult:
    """Result of the GUM uncertainty framework (JCGM 100 clauses 5, 6 and annex G)."""

    y: float
    """Estimate of the measurand: f(x) or sum c_i x_i (JCGM 100 4.1.4)."""
    u_c: float
    """Combined standard uncertainty u_c(y) (JCGM 100 eq. 10)."""
    nu_eff: float
    """Effective degrees of freedom (Welch-Satterthwaite, JCGM 100 eq. G.2b), before rounding;
    inf when every contribution has infinite dof."""
    nu_used: float
    """Degrees of freedom used for k (nu_eff truncated to the next lower integer when
    dof_rounding='truncate', JCGM 100 G.4.1)."""
    k: float
    """Coverage factor t_p(nu_used) (JCGM 100 G.3.2, table G.2)."""
    U: float
    """Expanded uncertainty k u_c (JCGM 100 6.2.1)."""
    coverage_probability: float
    """Coverage probability p of the interval y +- U."""
    names: tuple[str, ...]
    """Contribution names, in budget order."""
    c: np.ndarray
    """Sensitivity coefficients used (given, 1, or numerical derivatives)."""
    u_y: np.ndarray
    """Uncertainty contributions |c_i| u(x_i) in the unit of the measurand (JCGM 100 5.1.3)."""
    shares: np.ndarray
    """Variance shares u_i(y)^2 / u_c^2 (sum to 1)."""
    dof: np.ndarray
    """Degrees of freedom of each contribution."""
    contributions: tuple[Contribution, ...] = field(repr=False)
    """The inputs as given."""

    def table(self) -> list[dict]:
        """Budget table rows: name, distribution, u, c, u_y, dof, share."""
        return [{"name": n, "distribution": ct.distribution, "u": ct.u, "value": ct.value,
                 "c": float(c), "u_y": float(uy), "dof": float(d), "share": float(s)}
                for n, ct, c, uy, d, s in zip(self.names, self.contributions, self.c,
                                              self.u_y, self.dof, self.shares, strict=True)]


def coverage_factor(coverage_probability: float, dof: float = math.inf) -> float:
    """Coverage factor ``t_p(nu)`` of the t distribution (JCGM 100 G.3.2, table G.2).

    ``nu = inf`` gives the normal quantile (1.96 for p = 0.95).
    """
    p = _check_number(coverage_probability, "coverage_probability")
    if not 0 < p < 1:
        raise ValueError(f"coverage_probability: expected a value in (0, 1), got {p}.")
    q = 0.5 * (1.0 + p)
    if math.isinf(dof):
        return float(stats.norm.ppf(q))
    return float(stats.t.ppf(q, dof))


def welch_satterthwaite(u_y: np.ndarray, dof: np.ndarray) -> float:
    """Effective degrees of freedom ``u_c^4 / sum(u_i^4 / nu_i)`` (JCGM 100 eq. G.2b)."""
    u_y = np.asarray(u_y, float)
    dof = np.asarray(dof, float)
    uc2 = float(np.sum(u_y**2))
    finite = np.isfinite(dof) & (u_y > 0)
    den = float(np.sum(u_y[finite] ** 4 / dof[finite]))
    if den == 0.0 or uc2 == 0.0:
        return math.inf
    return uc2**2 / den


def _as_contributions(contributions) -> tuple[Contribution, ...]:
    out = tuple(contributions)
    if not out:
        raise ValueError("contributions: expected at least one contribution, got none.")
    for i, ct in enumerate(out):
        if not isinstance(ct, Contribution):
            raise ValueError(f"contributions[{i}]: expected a Contribution, got "
                             f"{type(ct).__name__}.")
    return out


def sensitivity_coefficients(function: Callable, contributions: Sequence[Contribution]
                             ) -> np.ndarray:
    """Central-difference sensitivity coefficients of ``function`` (JCGM 100 5.1.3).

    ``c_i = [f(x + u_i e_i) - f(x - u_i e_i)] / (2 u_i)``: the step is the standard
    uncertainty of the input (the usual numerical practice, exact for a model linear in
    ``X_i`` and equal to the GUM first-order term when the model is linear over +-u_i);
    a relative step of 1e-6 is used where ``u_i = 0``.
    """
    x = np.array([ct.value for ct in contributions], float)
    c = np.empty(len(x))
    for i, ct in enumerate(contributions):
        h = ct.u if ct.u > 0 else 1e-6 * max(abs(ct.value), 1.0)
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        fp, fm = float(function(*xp)), float(function(*xm))
        c[i] = (fp - fm) / (2.0 * h)
    return c


def gum_combine(contributions: Sequence[Contribution], *, function: Callable | None = None,
                coverage_probability: float = 0.95, dof_rounding: str = "truncate"
                ) -> GumResult:
    """Combine a budget by the GUM uncertainty framework (JCGM 100 clauses 5-6, annex G).

    Parameters
    ----------
    contributions : sequence of Contribution
        Uncorrelated input quantities.
    function : callable, optional
        Measurement function ``f(x_1, ..., x_N)`` (positional, in budget order). When
        given, every ``c`` must be None and the coefficients are numerical derivatives.
        Without it the model is ``Y = sum c_i X_i``.
    coverage_probability : float
        p of the expanded uncertainty (0.95 gives k = 2 for large nu_eff).
    dof_rounding : {'truncate', 'none'}
        JCGM 100 G.4.1: nu_eff is truncated to the next lower integer (the conservative
        choice used in example H.1) or used as is.

    Returns
    -------
    GumResult
    """
    cts = _as_contributions(contributions)
    if dof_rounding not in ("truncate", "none"):
        raise ValueError(f"dof_rounding: expected 'truncate' or 'none', got {dof_rounding!r}.")
    u = np.array([ct.u for ct in cts], float)
    x = np.array([ct.value for ct in cts], float)
    if function is not None:
        for i, ct in enumerate(cts):
            if ct.c is not None:
                raise ValueError(f"contributions[{i}].c: expected None when a measurement "
                                 f"function is given (it is derived numerically), got {ct.c}.")
        c = sensitivity_coefficients(function, cts)
        y = float(function(*x))
    else:
        c = np.array([1.0 if ct.c is None else float(ct.c) for ct in cts])
        y = float(np.dot(c, x))
    u_y = np.abs(c) * u
    dof = np.array([float(ct.dof) for ct in cts])
    u_c = float(np.sqrt(np.sum(u_y**2)))
    nu = welch_satterthwaite(u_y, dof)
    nu_used = nu
    if dof_rounding == "truncate" and math.isfinite(nu) and nu >= 1.0:
        nu_used = float(math.floor(nu + 1e-9))
    k = coverage_factor(coverage_probability, nu_used)
    shares = u_y**2 / u_c**2 if u_c > 0 else np.zeros_like(u_y)
    return GumResult(y=y, u_c=u_c, nu_eff=nu, nu_used=nu_used, k=k, U=k * u_c,
                     coverage_probability=float(coverage_probability),
                     names=tuple(ct.name for ct in cts), c=c, u_y=u_y, shares=shares,
                     dof=dof, contributions=cts)


# --------------------------------------------------------------------------- Monte Carlo

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


def _sampler(cts: Sequence[Contribution], student_t: bool):
    """Draw ``m`` values of every input: list of arrays (JCGM 101 6.4)."""
    def draw(rng: np.random.Generator, m: int) -> list[np.ndarray]:
        out = []
        for ct in cts:
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
                bins: int = 100) -> MonteCarloResult:
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

    Returns
    -------
    MonteCarloResult
    """
    cts = _as_contributions(contributions)
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
    if rng is None:
        rng = np.random.default_rng(seed)
    else:
        seed = None
    draw = _sampler(cts, student_t_for_finite_dof)
    model = _model(cts, function)
    t0 = time.perf_counter()
    cancelled = False
    tol = None

    def run(m: int, out: np.ndarray, start: int) -> None:
        out[start:start + m] = model(draw(rng, m))

    if not adaptive:
        values = np.empty(int(trials))
        done = 0
        while done < trials:
            m = min(chunk_size, trials - done)
            run(m, values, done)
            done += m
            if progress is not None and progress(done / trials) is False and done < trials:
                cancelled = True
                break
        values = values[:done]
        status = "cancelled" if cancelled else "ok"
    else:
        m_seq = max(math.ceil(100.0 / (1.0 - p) - 1e-9), 10_000)     # JCGM 101 7.9.4 a)
        per_chunk = max(1, chunk_size // m_seq)
        h_max = max(2, max_trials // m_seq)
        buf = np.empty(min(h_max, 64) * m_seq)
        summaries = []                                # (y, u, low, high) per sequence
        fraction = 0.0
        status = "max_trials"
        h = 0
        while h < h_max:
            n_new = min(per_chunk, h_max - h)
            if buf.size < (h + n_new) * m_seq:
                buf = np.concatenate([buf, np.empty(max(buf.size, n_new * m_seq))])
            for _ in range(n_new):
                seg = buf[h * m_seq:(h + 1) * m_seq]
                seg[:] = model(draw(rng, m_seq))
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
                        status = "converged"
                        break
                    fraction = max(fraction, min(0.99, 1.0 / ratio**2), h / h_max)
            if status == "converged":
                break
            if progress is not None and progress(fraction) is False:
                cancelled = True
                status = "cancelled"
                break
        values = buf[:h * m_seq]
    if adaptive and progress is not None and not cancelled:
        progress(1.0)
    values = np.sort(values)
    n = values.size
    mean = float(np.mean(values)) if n else math.nan
    u = float(np.std(values, ddof=1)) if n >= 2 else math.nan
    sym, short = coverage_intervals(values, p)
    if n >= 2:
        lo, hi = np.quantile(values, [0.0005, 0.9995])
        if not hi > lo:
            lo, hi = lo - 0.5, hi + 0.5
        counts, edges = np.histogram(values, bins=bins, range=(lo, hi))
    else:
        counts, edges = np.zeros(bins, int), np.linspace(0.0, 1.0, bins + 1)
    return MonteCarloResult(mean=mean, u=u, interval_shortest=short, interval_symmetric=sym,
                            coverage_probability=p, trials=int(n), status=status,
                            tolerance=tol, seed=seed, elapsed_s=time.perf_counter() - t0,
                            hist_counts=counts, hist_edges=edges,
                            values=values if keep_values else None)


# --------------------------------------------------------------------------- CLI contract

_FIELDS = {"name", "u", "half_width", "distribution", "c", "dof", "k", "value", "unit"}


def contribution_from_dict(d: dict, index: int = 0) -> Contribution:
    """One SPEC budget contribution ``{"name", "u" | "half_width", "distribution", "c", "dof"}``.

    ``half_width`` of a normal input needs ``k`` (it is then an expanded uncertainty);
    ``dof`` null or absent means infinite; ``c`` absent means 1.
    """
    where = f"contributions[{index}]"
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected an object with 'name', 'u' or 'half_width', "
                         f"'distribution', 'c', 'dof', got {type(d).__name__}.")
    extra = sorted(set(d) - _FIELDS)
    if extra:
        raise ValueError(f"{where}: unknown field(s) {', '.join(extra)}; expected some of "
                         f"{', '.join(sorted(_FIELDS))}.")
    name = d.get("name", f"x{index + 1}")
    if not isinstance(name, str) or not name:
        raise ValueError(f"{where}.name: expected a non-empty string, got {name!r}.")
    where = f"{where} ({name!r})"
    dist = d.get("distribution", "normal")
    if dist not in DISTRIBUTIONS:
        raise ValueError(f"{where}.distribution: expected one of {', '.join(DISTRIBUTIONS)}, "
                         f"got {dist!r}.")
    has_u, has_a = "u" in d, "half_width" in d
    if has_u == has_a:
        raise ValueError(f"{where}: expected exactly one of 'u' or 'half_width', got "
                         f"{'both' if has_u else 'neither'}.")

    def num(key, *, default=None, positive=False, allow_inf=False, nonneg=False):
        v = d.get(key, default)
        try:
            x = _check_number(v, f"{where}.{key}", positive=positive, allow_inf=allow_inf)
        except ValueError as exc:
            raise ValueError(str(exc)) from None
        if nonneg and x < 0:
            raise ValueError(f"{where}.{key}: expected a number >= 0, got {v!r}.")
        return x

    c = num("c", default=1.0)
    dof = math.inf if d.get("dof") is None else num("dof", positive=True, allow_inf=True)
    value = num("value", default=0.0)
    unit = str(d.get("unit", ""))
    if has_u:
        return Contribution(name, num("u", nonneg=True), dist, c=c, dof=dof, value=value,
                            unit=unit)
    a = num("half_width", nonneg=True)
    if dist == "normal":
        if "k" not in d:
            raise ValueError(f"{where}: a normal contribution given by 'half_width' needs "
                             "'k' (its coverage factor); or give 'u'.")
        return Contribution.from_half_width(name, a, dist, k=num("k", positive=True), c=c,
                                            dof=dof, value=value, unit=unit)
    return Contribution.from_half_width(name, a, dist, c=c, dof=dof, value=value, unit=unit)


def _finite_or_none(x: float):
    return float(x) if math.isfinite(x) else None


def budget_from_dict(d: dict, *, progress: Callable | None = None) -> dict:
    """The ``budget`` command (SPEC): GUM result and optional JCGM 101 Monte Carlo result.

    Parameters
    ----------
    d : dict
        ``{"contributions": [...], "coverage_probability": 0.95, "monte_carlo_trials": N,
        "seed": S, "dof_rounding": "truncate"}`` (see :func:`contribution_from_dict`).
    progress : callable, optional
        Passed to :func:`monte_carlo`.

    Returns
    -------
    dict
        JSON-ready: ``y``, ``u_c``, ``nu_eff`` (null = infinite), ``nu_used``, ``k``, ``U``,
        ``coverage_probability``, ``contributions`` (each with ``u``, ``c``, ``u_y``,
        ``dof``, ``share``) and, when ``monte_carlo_trials`` > 0, ``mc`` with ``mean``,
        ``u``, ``interval`` (shortest), ``interval_symmetric``, ``trials``, ``status``,
        ``seed``.

    Raises
    ------
    ValueError
        One line naming the offending field and what was expected.
    """
    if not isinstance(d, dict):
        raise ValueError(f"budget: expected a JSON object with 'contributions', got "
                         f"{type(d).__name__}.")
    known = {"contributions", "coverage_probability", "monte_carlo_trials", "seed",
             "dof_rounding", "name", "unit", "description", "note", "source"}
    extra = sorted(set(d) - known)
    if extra:
        raise ValueError(f"budget: unknown field(s) {', '.join(extra)}; expected some of "
                         f"{', '.join(sorted(known))}.")
    raw = d.get("contributions")
    if not isinstance(raw, list) or not raw:
        raise ValueError("contributions: expected a non-empty list of contributions, got "
                         f"{raw!r:.60}.")
    cts = [contribution_from_dict(c, i) for i, c in enumerate(raw)]
    p = d.get("coverage_probability", 0.95)
    p = _check_number(p, "coverage_probability")
    if not 0 < p < 1:
        raise ValueError(f"coverage_probability: expected a value in (0, 1), got {p}.")
    rounding = d.get("dof_rounding", "truncate")
    if rounding not in ("truncate", "none"):
        raise ValueError(f"dof_rounding: expected 'truncate' or 'none', got {rounding!r}.")
    g = gum_combine(cts, coverage_probability=p, dof_rounding=rounding)
    out = {"y": g.y, "u_c": g.u_c, "nu_eff": _finite_or_none(g.nu_eff),
           "nu_used": _finite_or_none(g.nu_used), "k": g.k, "U": g.U,
           "coverage_probability": p,
           "contributions": [{"name": r["name"], "distribution": r["distribution"],
                              "u": r["u"], "c": r["c"], "u_y": r["u_y"],
                              "dof": _finite_or_none(r["dof"]), "share": r["share"]}
                             for r in g.table()]}
    n = d.get("monte_carlo_trials", 0)
    if n is None:
        n = 0
    if isinstance(n, bool) or not isinstance(n, int) or n < 0 or n == 1:
        raise ValueError(f"monte_carlo_trials: expected 0 (none) or an integer >= 2, "
                         f"got {n!r}.")
    if n > 50_000_000:
        raise ValueError(f"monte_carlo_trials: expected at most 50000000, got {n}.")
    if n:
        seed = d.get("seed", 1)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"seed: expected a non-negative integer, got {seed!r}.")
        mc = monte_carlo(cts, trials=n, coverage_probability=p, seed=seed, progress=progress)
        out["mc"] = {"mean": mc.mean, "u": mc.u, "interval": list(mc.interval_shortest),
                     "interval_symmetric": list(mc.interval_symmetric), "trials": mc.trials,
                     "status": mc.status, "seed": seed}
    return out

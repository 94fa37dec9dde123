"""The GUM uncertainty framework (JCGM 100:2008 clauses 5-6 and annex G).

:func:`gum_combine` applies the law of propagation of uncertainty for uncorrelated inputs
(JCGM 100 5.1.2, eq. 10) or, with correlation coefficients between named inputs, for
correlated inputs (JCGM 100 5.2.2, eq. 13 and 16), with sensitivity coefficients given,
1 (additive model) or
central differences of a measurement function (:func:`sensitivity_coefficients`, JCGM
100 5.1.3); the Welch-Satterthwaite effective degrees of freedom
(:func:`welch_satterthwaite`, JCGM 100 G.4.1, eq. G.2b; correlated inputs as in Willink,
Metrologia 44 (2007) 340-349); and the coverage factor from the
t distribution (:func:`coverage_factor`, JCGM 100 G.3, G.4, table G.2). The result is a
:class:`GumResult`.

See Also
--------
cmm_core.gum.mc : the Monte Carlo method of GUM Supplement 1 on the same inputs.
cmm_core.gum : re-exports these names.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.sparse.csgraph import connected_components

from .inputs import Contribution, _as_contributions, _check_number, correlation_matrix


@dataclass(frozen=True)
class GumResult:
    """Result of the GUM uncertainty framework (JCGM 100 clauses 5, 6 and annex G)."""

    y: float
    """Estimate of the measurand: f(x) or sum c_i x_i (JCGM 100 4.1.4)."""
    u_c: float
    """Combined standard uncertainty u_c(y) (JCGM 100 eq. 10; eq. 16 with correlations)."""
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
    """Variance shares u_i(y)^2 / u_c^2 (sum to 1 for independent inputs, to
    1 - correlation_share otherwise)."""
    dof: np.ndarray
    """Degrees of freedom of each contribution."""
    contributions: tuple[Contribution, ...] = field(repr=False)
    """The inputs as given."""
    correlation: np.ndarray | None = field(default=None, repr=False)
    """Correlation matrix r(x_i, x_j) of the inputs (JCGM 100 eq. 14); None when the
    inputs are independent."""
    correlation_share: float = 0.0
    """Share of u_c^2 from the correlation terms, 2 sum_{i<j} c_i c_j u_i u_j r_ij / u_c^2
    (JCGM 100 eq. 16); negative when they reduce u_c, 0 for independent inputs."""

    @property
    def correlated(self) -> bool:
        """True when correlations between inputs entered u_c (JCGM 100 5.2)."""
        return self.correlation is not None

    def correlation_terms(self) -> list[dict]:
        """The correlated pairs: names ``a``, ``b``, ``r`` and ``term``, their contribution
        ``2 c_a c_b u_a u_b r`` to u_c^2 (JCGM 100 eq. 16), in budget order."""
        if self.correlation is None:
            return []
        s = self.c * np.array([ct.u for ct in self.contributions], float)
        i, j = np.nonzero(np.triu(self.correlation, 1))
        return [{"a": self.names[a], "b": self.names[b], "r": float(self.correlation[a, b]),
                 "term": float(2.0 * s[a] * s[b] * self.correlation[a, b])}
                for a, b in zip(i, j, strict=True)]

    def table(self) -> list[dict]:
        """Budget table rows: name, distribution, u, c, u_y, dof, share.

        With correlated inputs every row also has ``correlated_with``, the inputs it is
        correlated with and r (empty when none), so the table says correlations were
        included; their terms are :meth:`correlation_terms`.
        """
        rows = [{"name": n, "distribution": ct.distribution, "u": ct.u, "value": ct.value,
                 "c": float(c), "u_y": float(uy), "dof": float(d), "share": float(s)}
                for n, ct, c, uy, d, s in zip(self.names, self.contributions, self.c,
                                              self.u_y, self.dof, self.shares, strict=True)]
        if self.correlation is not None:
            for i, row in enumerate(rows):
                row["correlated_with"] = "; ".join(
                    f"{self.names[j]} (r = {self.correlation[i, j]:g})"
                    for j in np.flatnonzero(self.correlation[i]) if j != i)
        return rows


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


def welch_satterthwaite(u_y: np.ndarray, dof: np.ndarray,
                        correlation: np.ndarray | None = None, *,
                        names: Sequence[str] | None = None) -> float:
    """Effective degrees of freedom ``u_c^4 / sum(u_i^4 / nu_i)`` (JCGM 100 eq. G.2b).

    Parameters
    ----------
    u_y : array
        Contributions ``c_i u(x_i)`` (signed; only their magnitude matters without
        correlations).
    dof : array
        Degrees of freedom nu_i (inf for an exactly known u).
    correlation : array, optional
        Correlation matrix of the inputs. ``u_c^2`` is then eq. 16 of JCGM 100. Eq. G.2b
        assumes independent components: correlated inputs with infinite dof add to
        ``u_c`` only; correlated inputs with finite dof must form ensembles of equal
        dof, each counted as one component of variance ``s_G^T R_GG s_G`` (Willink,
        Metrologia 44 (2007) 340-349, result 2, as GTC does).
    names : sequence of str, optional
        Input names, for the message of a refused correlation.

    Raises
    ------
    ValueError
        An input with finite dof correlated with one of other dof.
    """
    u_y = np.asarray(u_y, float)
    dof = np.asarray(dof, float)
    active = u_y != 0
    if correlation is None:
        uc2 = float(np.sum(u_y**2))
        finite = np.isfinite(dof) & active
        den = float(np.sum(u_y[finite] ** 4 / dof[finite]))
    else:
        R = np.asarray(correlation, float)
        uc2 = max(float(u_y @ R @ u_y), 0.0)
        linked = (R != 0) & active[:, None] & active[None, :]
        _, group = connected_components(linked, directed=False)
        den = 0.0
        for g in np.unique(group[active]):
            members = np.flatnonzero(group == g)
            nus = dof[members]
            if np.all(np.isinf(nus)):
                continue
            if not np.all(nus == nus[0]):
                who = (", ".join(repr(names[int(m)]) for m in members) if names is not None
                       else ", ".join(f"#{m}" for m in members))
                raise ValueError(
                    f"correlations: inputs {who} are correlated but have degrees of freedom "
                    f"{', '.join(f'{v:g}' for v in nus)}; expected equal degrees of freedom "
                    "within a correlated group (Welch-Satterthwaite, JCGM 100 G.4.1, "
                    "holds for independent components or such ensembles, Willink 2007). "
                    "Hint: give the correlated inputs the same dof, or inf.")
            s = u_y[members]
            v = max(float(s @ R[np.ix_(members, members)] @ s), 0.0)
            den += v**2 / float(nus[0])
    if den == 0.0 or uc2 == 0.0:
        return math.inf
    return uc2**2 / den



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
                coverage_probability: float = 0.95, dof_rounding: str = "truncate",
                correlations=None) -> GumResult:
    """Combine a budget by the GUM uncertainty framework (JCGM 100 clauses 5-6, annex G).

    The law of propagation of uncertainty, ``u_c^2 = sum_i c_i^2 u_i^2`` for independent
    inputs (JCGM 100 eq. 10) and
    ``u_c^2 = sum_i c_i^2 u_i^2 + 2 sum_{i<j} c_i c_j u_i u_j r_ij`` with correlation
    coefficients r_ij (JCGM 100 eq. 16, i.e. eq. 13 with ``u(x_i, x_j) = u_i u_j r_ij``,
    eq. 14), written ``s^T R s`` with ``s_i = c_i u_i``.

    Parameters
    ----------
    contributions : sequence of Contribution
        The input quantities (independent unless ``correlations`` says otherwise).
    function : callable, optional
        Measurement function ``f(x_1, ..., x_N)`` (positional, in budget order). When
        given, every ``c`` must be None and the coefficients are numerical derivatives.
        Without it the model is ``Y = sum c_i X_i``.
    coverage_probability : float
        p of the expanded uncertainty (0.95 gives k = 2 for large nu_eff).
    dof_rounding : {'truncate', 'none'}
        JCGM 100 G.4.1: nu_eff is truncated to the next lower integer (the conservative
        choice used in example H.1) or used as is.
    correlations : mapping or sequence, optional
        ``{(a, b): r}`` or ``[(a, b, r), ...]`` between inputs named ``a`` and ``b`` (see
        :func:`~cmm_core.gum.inputs.correlation_matrix`, which validates them: names
        exist and are unique, ``-1 <= r <= 1``, the matrix positive semidefinite).
        Correlated inputs with finite dof need equal dof (:func:`welch_satterthwaite`).

    Returns
    -------
    GumResult
        ``correlated`` is True and ``correlation_terms()`` lists the pairs when a
        coefficient other than 0 was given.
    """
    cts = _as_contributions(contributions)
    R = correlation_matrix(cts, correlations)
    R_used = R if np.any(R != np.eye(len(cts))) else None      # r = 0 is independence
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
    s = c * u
    u_y = np.abs(s)
    dof = np.array([float(ct.dof) for ct in cts])
    var_independent = float(np.sum(u_y**2))
    corr_var = 0.0 if R_used is None else float(s @ R_used @ s) - var_independent
    u_c = math.sqrt(max(var_independent + corr_var, 0.0))
    nu = welch_satterthwaite(s, dof, R_used, names=[ct.name for ct in cts])
    nu_used = nu
    if dof_rounding == "truncate" and math.isfinite(nu) and nu >= 1.0:
        nu_used = float(math.floor(nu + 1e-9))
    k = coverage_factor(coverage_probability, nu_used)
    shares = u_y**2 / u_c**2 if u_c > 0 else np.zeros_like(u_y)
    corr_share = corr_var / u_c**2 if u_c > 0 else 0.0
    return GumResult(y=y, u_c=u_c, nu_eff=nu, nu_used=nu_used, k=k, U=k * u_c,
                     coverage_probability=float(coverage_probability),
                     names=tuple(ct.name for ct in cts), c=c, u_y=u_y, shares=shares,
                     dof=dof, contributions=cts, correlation=R_used,
                     correlation_share=corr_share)

"""GUM uncertainty budgets (JCGM 100:2008) and GUM Supplement 1 Monte Carlo (JCGM 101:2008).

A budget is a sequence of :class:`Contribution` (one input quantity each: its estimate,
standard uncertainty, probability distribution, sensitivity coefficient and degrees of
freedom). :func:`gum_combine` applies the law of propagation of uncertainty for
uncorrelated inputs (JCGM 100 5.1.2, eq. 10) or, given correlation coefficients between
named inputs, for correlated ones (JCGM 100 5.2.2, eq. 16), the Welch-Satterthwaite formula (JCGM 100
G.4.1, eq. G.2b) and the coverage factor from the t distribution (JCGM 100 G.3, G.4).
:func:`monte_carlo` propagates the distributions themselves (JCGM 101 clause 7), with
probabilistically symmetric and shortest coverage intervals (JCGM 101 7.7) and the adaptive
procedure of JCGM 101 7.9 (correlated normal inputs jointly, JCGM 101 6.4.8).
:func:`budget_from_dict` is the ``budget`` command of the CLI
(docs/formats.md "Command line").

Without a measurement function the model is additive, ``Y = sum_i c_i X_i`` (``c_i``
default 1), as in a classical budget table whose rows are already expressed in the unit of
the measurand. With a measurement function ``Y = f(X_1, ..., X_N)`` the sensitivity
coefficients are central differences (JCGM 100 5.1.3) and the Monte Carlo method evaluates
``f`` on the sampled inputs.

The code is split by concept; this module holds the ``budget`` command's contract
(:func:`contribution_from_dict`, :func:`budget_from_dict`) and re-exports the public names
of the others, so that ``from cmm_core.gum import ...`` finds them all:

- ``cmm_core.gum.inputs``: :class:`Contribution`, ``DISTRIBUTIONS``,
  :func:`half_width_divisor`, :func:`correlation_matrix` (JCGM 100 4.1.5, 4.3.7-4.3.9,
  5.2.2);
- ``cmm_core.gum.framework``: :func:`gum_combine`, :class:`GumResult`,
  :func:`coverage_factor`, :func:`welch_satterthwaite`, :func:`sensitivity_coefficients`
  (JCGM 100 clauses 5-6, annex G);
- ``cmm_core.gum.mc``: :func:`monte_carlo`, :class:`MonteCarloResult`,
  :func:`coverage_intervals` (JCGM 101 clause 7).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from .framework import (
    gum_combine,
)
from .inputs import DISTRIBUTIONS, Contribution, _check_number
from .mc import monte_carlo

__all__ = ["budget_from_dict", "contribution_from_dict", "correlations_from_list"]


# --------------------------------------------------------------------------- CLI contract

_FIELDS = {"name", "u", "half_width", "distribution", "c", "dof", "k", "value", "unit"}


def contribution_from_dict(d: dict, index: int = 0) -> Contribution:
    """One budget contribution (docs/formats.md) ``{"name", "u" | "half_width", "distribution", "c", "dof"}``.

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


_MAX_U_Y = 1e30
"""Largest contribution ``|c·u|`` to a budget's result: no measurement's uncertainty comes
near it in any unit, and its fourth power (Welch-Satterthwaite, JCGM 100 G.4.1) stays
finite."""


def _min_trials(coverage_probability: float) -> int:
    """Fewest Monte Carlo trials a budget may ask for: ``max(10⁴, 100 / (1 − p))``.

    JCGM 101:2008 7.2.2 asks for M large compared with ``1 / (1 − p)``; with fewer than
    100 trials beyond the coverage interval its ends are order statistics of a handful of
    draws, and below 10⁴ trials the standard uncertainty itself is uncertain by more than
    0.7 % (``1 / sqrt(2 M)``). A budget of 3 trials would print an interval of noise.
    """
    return max(10_000, math.ceil(100 / (1 - coverage_probability)))


def correlations_from_list(raw) -> list[tuple[str, str, float]]:
    """The ``correlations`` of a budget (docs/formats.md): ``[{"between": [a, b], "r": r}]``.

    Returns ``(a, b, r)`` triples for :func:`~cmm_core.gum.framework.gum_combine`, which
    checks the names, the range of r and the matrix (JCGM 100 5.2.2, eq. 14).
    """
    if not isinstance(raw, list):
        raise ValueError(f"correlations: expected a list of {{\"between\": [a, b], \"r\": r}}, "
                         f"got {type(raw).__name__}.")
    out = []
    for i, item in enumerate(raw):
        where = f"correlations[{i}]"
        if not isinstance(item, dict) or set(item) != {"between", "r"}:
            raise ValueError(f"{where}: expected an object with exactly 'between' (two input "
                             f"names) and 'r' (a correlation coefficient), got {item!r:.80}.")
        pair = item["between"]
        if (not isinstance(pair, list) or len(pair) != 2
                or not all(isinstance(x, str) for x in pair)):
            raise ValueError(f"{where}.between: expected two input names [a, b], got "
                             f"{pair!r:.80}.")
        if isinstance(item["r"], bool) or not isinstance(item["r"], (int, float)):
            raise ValueError(f"{where}.r: expected a number in [-1, 1], got {item['r']!r:.40}.")
        out.append((pair[0], pair[1], float(item["r"])))
    return out


def budget_from_dict(d: dict, *, progress: Callable | None = None) -> dict:
    """The ``budget`` command (docs/formats.md): GUM result and optional JCGM 101 Monte Carlo result.

    Parameters
    ----------
    d : dict
        ``{"contributions": [...], "coverage_probability": 0.95, "monte_carlo_trials": N,
        "seed": S, "dof_rounding": "truncate", "correlations": [{"between": [a, b],
        "r": r}]}`` (see :func:`contribution_from_dict`, :func:`correlations_from_list`).
    progress : callable, optional
        Passed to :func:`monte_carlo`.

    Returns
    -------
    dict
        JSON-ready: ``y``, ``u_c``, ``nu_eff`` (null = infinite), ``nu_used``, ``k``, ``U``,
        ``coverage_probability``, ``contributions`` (each with ``u``, ``c``, ``u_y``,
        ``dof``, ``share``), with correlations ``correlated: true`` and ``correlations``
        (each pair's ``between``, ``r`` and ``term``, its part of u_c², JCGM 100 eq. 16)
        and, when ``monte_carlo_trials`` > 0, ``mc`` with ``mean``,
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
             "dof_rounding", "name", "unit", "description", "note", "source", "correlations"}
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
    for i, ct in enumerate(cts):
        u_y = abs((1.0 if ct.c is None else ct.c) * ct.u)
        if not u_y <= _MAX_U_Y:  # its fourth power in Welch-Satterthwaite would overflow
            raise ValueError(f"contributions[{i}]: c·u = {u_y:g}; expected a contribution "
                             f"of a measurement, at most {_MAX_U_Y:g} in the result's unit.")
    corr = correlations_from_list(d["correlations"]) if "correlations" in d else None
    g = gum_combine(cts, coverage_probability=p, dof_rounding=rounding, correlations=corr)
    if not g.u_c > 0:
        raise ValueError("contributions: every contribution is zero (u or half_width 0, or "
                         "c 0), so U = 0; expected at least one uncertainty above zero.")
    out = {"y": g.y, "u_c": g.u_c, "nu_eff": _finite_or_none(g.nu_eff),
           "nu_used": _finite_or_none(g.nu_used), "k": g.k, "U": g.U,
           "coverage_probability": p,
           "contributions": [{"name": r["name"], "distribution": r["distribution"],
                              "u": r["u"], "c": r["c"], "u_y": r["u_y"],
                              "dof": _finite_or_none(r["dof"]), "share": r["share"]}
                             for r in g.table()]}
    if g.correlated:
        out["correlated"] = True
        out["correlations"] = [{"between": [t["a"], t["b"]], "r": t["r"], "term": t["term"]}
                               for t in g.correlation_terms()]
    n = d.get("monte_carlo_trials", 0)
    if n is None:
        n = 0
    if isinstance(n, bool) or not isinstance(n, int) or n < 0 or n == 1:
        raise ValueError(f"monte_carlo_trials: expected 0 (none) or a whole number of "
                         f"at least {_min_trials(p)}, got {n!r}.")
    if n > 50_000_000:
        raise ValueError(f"monte_carlo_trials: expected at most 50000000, got {n}.")
    least = _min_trials(p)
    if 0 < n < least:
        raise ValueError(f"monte_carlo_trials: expected 0 (none) or at least {least} for "
                         f"a coverage probability of {p:g}, got {n}.")
    if n:
        seed = d.get("seed", 1)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"seed: expected a non-negative integer, got {seed!r}.")
        mc = monte_carlo(cts, trials=n, coverage_probability=p, seed=seed, progress=progress,
                         correlations=corr)
        out["mc"] = {"mean": mc.mean, "u": mc.u, "interval": list(mc.interval_shortest),
                     "interval_symmetric": list(mc.interval_symmetric), "trials": mc.trials,
                     "status": mc.status, "seed": seed}
    return out

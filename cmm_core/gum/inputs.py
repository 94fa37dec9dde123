"""Input quantities of an uncertainty budget: :class:`Contribution` and its distributions.

One :class:`Contribution` is one row of a GUM budget table: an input quantity's estimate,
standard uncertainty (JCGM 100:2008 4.1.5), probability distribution (normal,
rectangular, triangular or arc sine: JCGM 100 4.3.7-4.3.9, JCGM 101:2008 6.4),
sensitivity coefficient (JCGM 100 5.1.3) and degrees of freedom (JCGM 100 G.3, G.4.2).
A contribution may be given by a half-width instead of ``u``
(:meth:`Contribution.from_half_width`, :func:`half_width_divisor`). The distributions
of half-width 1 in ``_SHAPES`` are shared with the Monte Carlo sampler
(``cmm_core.gum.mc``). Inputs are independent unless correlation coefficients between named
inputs are given (:func:`correlation_matrix`, JCGM 100 5.2, eq. 14).

See Also
--------
cmm_core.gum : the GUM framework, Monte Carlo and the ``budget`` command (re-exports).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

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


def _as_contributions(contributions) -> tuple[Contribution, ...]:
    out = tuple(contributions)
    if not out:
        raise ValueError("contributions: expected at least one contribution, got none.")
    for i, ct in enumerate(out):
        if not isinstance(ct, Contribution):
            raise ValueError(f"contributions[{i}]: expected a Contribution, got "
                             f"{type(ct).__name__}.")
    return out


_PSD_TOLERANCE = 1e-10
"""Most negative eigenvalue of a correlation matrix still taken as >= 0 (rounding of the
coefficients as given, e.g. r = 1 written as 0.9999999999)."""


def _correlation_items(correlations) -> list[tuple[object, object, object]]:
    """``(a, b, r)`` triples from a mapping ``{(a, b): r}`` or an iterable of triples."""
    if isinstance(correlations, Mapping):
        items = []
        for key, r in correlations.items():
            if not (isinstance(key, tuple) and len(key) == 2):
                raise ValueError(f"correlations: expected keys that are pairs of input "
                                 f"names (a, b), got {key!r}.")
            items.append((key[0], key[1], r))
        return items
    if isinstance(correlations, (str, bytes)) or not isinstance(correlations, Iterable):
        raise ValueError(f"correlations: expected a mapping {{(a, b): r}} or a sequence of "
                         f"(a, b, r), got {type(correlations).__name__}.")
    items = []
    for i, item in enumerate(correlations):
        if isinstance(item, (str, bytes)) or not isinstance(item, Sequence) or len(item) != 3:
            raise ValueError(f"correlations[{i}]: expected (a, b, r): two input names and "
                             f"a correlation coefficient, got {item!r}.")
        items.append(tuple(item))
    return items


def correlation_matrix(contributions: Sequence[Contribution], correlations=None
                       ) -> np.ndarray:
    """The correlation matrix ``r(x_i, x_j)`` of a budget's inputs (JCGM 100 5.2.2, eq. 14).

    Parameters
    ----------
    contributions : sequence of Contribution
        The inputs, in budget order; a name an entry of ``correlations`` refers to must be
        unique among them.
    correlations : mapping or sequence, optional
        ``{(a, b): r}`` or ``[(a, b, r), ...]``: the correlation coefficient
        ``r(x_a, x_b) = u(x_a, x_b) / (u(x_a) u(x_b))`` (JCGM 100 eq. 14) between the
        inputs named ``a`` and ``b`` (e.g. two temperatures read from thermometers
        calibrated against the same reference, JCGM 100 5.2.4, 5.2.5). A covariance
        ``u(x_a, x_b)`` is entered as that ratio. Pairs not given are uncorrelated; None or
        empty means independent inputs.

    Returns
    -------
    numpy.ndarray
        Symmetric ``N x N`` matrix with unit diagonal.

    Raises
    ------
    ValueError
        A name that is not an input (or not unique), a pair of one input with itself, a
        pair given twice, a coefficient outside [-1, 1], or coefficients that together are
        not a correlation matrix (not positive semidefinite, so that some combination of
        the inputs would have a negative variance).
    """
    cts = _as_contributions(contributions)
    n = len(cts)
    R = np.eye(n)
    if correlations is None:
        return R
    names = [ct.name for ct in cts]
    index = {name: i for i, name in enumerate(names)}
    listed = ", ".join(repr(x) for x in names[:12]) + (", ..." if n > 12 else "")
    seen: dict[tuple[int, int], float] = {}
    for a, b, r_raw in _correlation_items(correlations):
        where = f"correlations[({a!r}, {b!r})]"
        for name in (a, b):
            if name not in index:
                raise ValueError(f"{where}: {name!r} is not an input of the budget; expected "
                                 f"one of {listed}.")
            if names.count(name) > 1:
                raise ValueError(f"{where}: {name!r} names {names.count(name)} inputs; "
                                 "expected a unique name (rename the inputs to correlate "
                                 "them).")
        if a == b:
            raise ValueError(f"{where}: expected two different inputs, got {a!r} twice (an "
                             "input's correlation with itself is 1).")
        r = _check_number(r_raw, where)
        if not -1.0 <= r <= 1.0:
            raise ValueError(f"{where}: expected a correlation coefficient in [-1, 1], got "
                             f"{r_raw!r}; a covariance u(a, b) is entered as "
                             "r = u(a, b) / (u(a) u(b)) (JCGM 100 eq. 14).")
        i, j = sorted((index[str(a)], index[str(b)]))
        if (i, j) in seen:
            raise ValueError(f"{where}: the pair is given twice (r = {seen[(i, j)]:g} and "
                             f"r = {r:g}); expected each pair once.")
        seen[(i, j)] = r
        R[i, j] = R[j, i] = r
    if seen:
        smallest = float(np.linalg.eigvalsh(R)[0])
        if smallest < -_PSD_TOLERANCE:
            raise ValueError(f"correlations: expected coefficients that together form a "
                             f"positive semidefinite correlation matrix, got one whose "
                             f"smallest eigenvalue is {smallest:.3g}; the coefficients "
                             "contradict each other (e.g. r(a, b) = r(b, c) = 0.9 with "
                             "r(a, c) = -0.9): check them together.")
    return R

"""Is the stated repeatability σ right? Estimate it, and test whether a misfit is uniform.

A χ² well above its degrees of freedom has two readings: the model misses an effect, or
σ is understated. They differ in where the misfit lives. A missing effect concentrates
it in some placements, probes, axes or regions; an understated σ spreads it evenly. This
module estimates σ (from repeated measurements of the same ball where the data have them,
else from the residuals of the most flexible model the data determine: the lack-of-fit
idea of regression, with that model standing in for pure error) and tests the misfit for
uniformity over placements, probes and axes (Bartlett's test of equal variances, with
each group's share of the degrees of freedom).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from ..model import ROUNDING, FitResult, NormalEquations, Problem, fit

_NominalFn = Callable[[Problem], NormalEquations | None]
"""``fit``'s ``nominal``: a problem's normal equations at its initial state, or None."""

UNIFORM_ALPHA = 0.01
"""Family level of the uniformity tests (Bonferroni over the groupings tried)."""


@dataclass(frozen=True)
class SigmaEstimate:
    """Repeatability estimated from the data.

    Attributes
    ----------
    value_um : float
        Estimated σ (µm).
    u_um : float
        Its standard uncertainty, ``σ / sqrt(2ν)`` (normal data).
    dof : int
        Degrees of freedom ``ν`` behind it.
    method : str
        ``repeats`` or ``model residuals``.
    detail : str
        What it was computed from, in words.
    """

    value_um: float
    u_um: float
    dof: int
    method: str
    detail: str

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"value_um": self.value_um, "u_um": self.u_um, "dof": self.dof,
                "method": self.method, "detail": self.detail}


@dataclass(frozen=True)
class Uniformity:
    """Is the misfit spread evenly over placements, probes and axes?

    Attributes
    ----------
    uniform : bool
        True when no grouping shows unequal scatter at ``UNIFORM_ALPHA``.
    tests : dict
        ``{grouping: {"p_value", "groups": {name: χ²/ν of the group}}}``.
    worst : str
        The grouping and group with the largest scatter ratio, in words.
    """

    uniform: bool
    tests: dict
    worst: str

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"uniform": self.uniform, "tests": self.tests, "worst": self.worst}


def _bartlett(chi2, nu):
    """Bartlett's test that groups with χ² values ``chi2`` on ``nu`` dof share one
    variance (Bartlett 1937; the form of ``scipy.stats.bartlett`` with given ν)."""
    chi2, nu = np.asarray(chi2, float), np.asarray(nu, float)
    keep = nu > 0
    chi2, nu = chi2[keep], nu[keep]
    if nu.size < 2:
        return 1.0
    v = np.maximum(chi2 / nu, 1e-300)
    s2 = chi2.sum() / nu.sum()
    t = nu.sum() * np.log(s2) - np.sum(nu * np.log(v))
    c = 1 + (np.sum(1 / nu) - 1 / nu.sum()) / (3 * (nu.size - 1))
    return float(stats.chi2.sf(t / c, nu.size - 1))


def axis_weights(result: FitResult) -> np.ndarray:
    """How much of each observation's residual each machine axis carries, (n, 3): the
    diagonal of the projector onto what the fit compares, ``I - n nᵀ`` for a hole plate
    (``hole_plate``: ``n`` the placement's fitted normal; a horizontal placement's z
    component is exactly zero) and ``I`` for a ball plate (ones). A row sums to the
    components it has (2 or 3): the share of the degrees of freedom and of χ² that an
    understated σ gives each axis and group."""
    o = result.problem.obs
    if getattr(o, "artefact", "ball_plate") != "hole_plate":
        return np.ones((len(o.pos), 3))
    n = result.state.R[o.pos][:, :, 2]
    w = 1.0 - n ** 2
    w[w < ROUNDING] = 0.0  # a normal along an axis up to rounding: that axis has nothing
    return w


def uniformity(result: FitResult) -> Uniformity:
    """Test the residual scatter of ``result`` for equality over placements, probes and
    the x, y, z components. Each group's degrees of freedom are its share of the fit's
    (its components times dof per component; per axis the :func:`axis_weights` of its
    observations, so a hole plate's axis along the normal has none): the fitted
    parameters spend them evenly enough for a test whose purpose is to tell a
    concentrated misfit from a spread one."""
    t = result.table
    z2 = (result.residuals_um / result.sigma_um) ** 2
    w = axis_weights(result)
    # for a ball plate every sum below is of integers, exact in floating point: the
    # numbers of the three-components-per-row form bit for bit
    per_row = result.dof / max(w.sum(), 1)
    groupings = {"placement": t["position"].to_numpy(), "probe": t["probe"].to_numpy(),
                 "ball": t["ball"].to_numpy()}
    # regions of the machine volume: quarters of each axis's stroke as measured (a local
    # error of one axis, a placement's own scale, concentrate there)
    o = result.problem.obs
    for a, name in enumerate("xyz"):
        u = (o.r_mm - o.p_mm)[:, a]
        if np.ptp(u) > 50.0:
            edges = np.quantile(u, [0.25, 0.5, 0.75])
            groupings[f"{name} region"] = np.array(
                [f"{name} quarter {k + 1}" for k in np.searchsorted(edges, u)])
    tests, ratios = {}, []
    c_row = z2.sum(axis=1)
    for name, key in groupings.items():
        codes, keys = pd.factorize(key)  # groups in order of appearance
        chi2 = np.bincount(codes, weights=c_row, minlength=len(keys))
        nu = np.bincount(codes, weights=w.sum(axis=1), minlength=len(keys)) * per_row
        if len(keys) >= 2:
            tests[name] = {"p_value": _bartlett(chi2, nu),
                           "groups": {str(k): float(chi2[i] / nu[i])
                                      for i, k in enumerate(keys)}}
    chi2 = z2.sum(axis=0)
    nu = w.sum(axis=0) * per_row
    tests["axis"] = {"p_value": _bartlett(chi2, nu),
                     "groups": {a: float(c / n) for a, c, n in zip("xyz", chi2, nu, strict=True)
                                if n > 0}}
    level = UNIFORM_ALPHA / len(tests)
    for name, t in tests.items():
        k = max(t["groups"], key=t["groups"].get)
        ratios.append((t["groups"][k] / max(np.mean(list(t["groups"].values())), 1e-300),
                       name, k))
    _, gname, k = max(ratios)
    worst = (f"{gname} {k} (χ²/ν {tests[gname]['groups'][k]:.2f} against "
             f"{result.chi2_dof:.2f} overall)")
    return Uniformity(all(t["p_value"] >= level for t in tests.values()), tests, worst)


def from_repeats(table: pd.DataFrame, normals: dict | None = None) -> SigmaEstimate | None:
    """σ from repeated measurements of the same ball (same position, probe and ball): the
    pooled within-group standard deviation of every coordinate. None without repeats.

    ``normals``: position -> unit plate normal in machine axes, for a hole plate. Only
    the coordinates in each placement's plane are pooled then, two degrees of freedom per
    repeat: the coordinate along the hole axis is the probing height, which may change
    between repeats without the hole moving (``hole_plate``)."""
    if "repeat" not in table or table["repeat"].isna().all():
        return None
    xyz = table[["mx_mm", "my_mm", "mz_mm"]].to_numpy() * 1e3
    g = table.groupby(["position", "probe", "ball"], sort=False).ngroup().to_numpy()
    counts = np.bincount(g)
    if (counts > 1).sum() == 0:
        return None
    means = np.stack([np.bincount(g, weights=xyz[:, a]) / counts for a in range(3)], axis=1)
    dev = xyz - means[g]
    per_repeat = 3
    if normals is not None:
        n = np.array([normals[p] for p in table["position"]], float)
        dev = dev - n * np.einsum("ni,ni->n", n, dev)[:, None]
        per_repeat = 2
    ss = float(np.sum(dev ** 2))
    dof = int(per_repeat * np.sum(counts - 1))
    s = float(np.sqrt(ss / dof))
    return SigmaEstimate(s, float(s / np.sqrt(2 * dof)), dof, "repeats",
                         f"{int((counts > 1).sum())} balls measured more than once "
                         f"({dof} degrees of freedom"
                         + (", in-plane coordinates of the holes)" if normals is not None
                            else ")"))


def _hole_normals(base: FitResult) -> dict | None:
    """Position -> fitted plate normal (machine axes) of a hole plate's fit, else None."""
    o = base.problem.obs
    if getattr(o, "artefact", "ball_plate") != "hole_plate":
        return None
    return {p: base.state.R[k][:, 2] for k, p in enumerate(o.positions)}


def flexible_spec(base: FitResult, tokens: Iterable[str]) -> str:
    """The most flexible model the diagnosis tries: the baseline with every candidate
    token of ``tokens`` added (one order up per function, every physical effect whose
    data are present)."""
    spec = base.problem.spec
    for t in tokens:
        spec = spec.with_token(t)
    return spec.to_string(explicit=True)


def from_residuals(base: FitResult, tokens: Iterable[str],
               nominal: _NominalFn | None = None) -> SigmaEstimate:
    """σ from the residuals of the most flexible model (:func:`flexible_spec`): what that
    model cannot explain stands in for pure error. Biased high if the truth is outside it."""
    flex = fit(base.problem.obs, flexible_spec(base, tokens), plate=base.plate,
               sigma_um=base.sigma_um, rank_rtol=base.rank_rtol, max_iter=2000,
               certificate_test=False, nominal=nominal)  # its χ²/dof is read, not its test
    best = flex if flex.status == "converged" and flex.dof > 0 else base
    s = best.sigma_um * float(np.sqrt(best.chi2_dof))
    return SigmaEstimate(s, float(s / np.sqrt(2 * max(best.dof, 1))), int(best.dof),
                         "model residuals",
                         f"residual scatter of {best.spec} ({best.rank} parameters, "
                         f"{best.dof} degrees of freedom)")


def estimate(base: FitResult, tokens: Iterable[str] = (),
         nominal: _NominalFn | None = None) -> SigmaEstimate:
    """σ from repeats when the data have them, else from the most flexible model
    (``nominal``: ``fit``'s, when the caller has the normal equations at the start)."""
    return (from_repeats(base.table, _hole_normals(base))
            or from_residuals(base, tokens, nominal))

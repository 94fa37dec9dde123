"""A machine's calibration history: what changed between its calibrations (issue 28).

Two or more stored models of one machine (``export.Model``), each with its date. The
calibrations are independent measurements, so the change of a parameter shared by two
consecutive calibrations has the variance ``u₁² + u₂²`` (JCGM 100 eq. 10) and
``z = (c₂ - c₁) / sqrt(u₁² + u₂²)`` is standard normal when nothing changed. The changes
are tested by its two-sided p-value at a family-wise level by Holm's step-down procedure
(Holm 1979) over every tested pair and parameter. The normalised error is stated as
laboratories read one (ISO/IEC 17043:2010 Annex B), with the expanded uncertainties
``U = k u`` at the coverage factor ``k`` (default 2, as EA-4/02 states them):
``E_n = (c₂ - c₁) / sqrt(U₁² + U₂²) = z / k``, ``|E_n| <= 1`` the usual acceptance; the
tests do not depend on ``k``. The error map's
change from the first to the last calibration is computed on a grid over the working
volume (ram reference point, probe offset 0), its uncertainty ``sqrt(diag(J₁V₁J₁ᵀ) +
diag(J₂V₂J₂ᵀ))`` (JCGM 100 eq. 13 for each model).
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy import stats

from .._blas import single_blas_thread
from ..export import Model
from ..io import DataError
from ..machine import kinematics as kin
from ..units import UM
from .changes import holm
from .explain import ChangeExplanation, difference_covariance, explain_difference
from .identity import refuse_mixed_machines
from .numbers import json_num

HISTORY_RULE = ("a parameter changed between two consecutive calibrations when the "
                "two-sided p-value of z = (c₂ − c₁) / sqrt(u₁² + u₂²) (standard normal if "
                "nothing changed) is rejected by Holm's step-down procedure at family_alpha "
                "over every pair and shared parameter; En is stated at the coverage factor "
                "k, E_n = (c₂ − c₁) / sqrt(U₁² + U₂²) = z / k with U = k u (ISO/IEC 17043 "
                "Annex B)")
"""The history's decision rule, as the results document states it."""

CALIBRATION_CHI2_ALPHA = 0.05
"""A calibration whose own χ² test (the model file's ``summary.chi2_p_value``) is below
this level does not fit its data to its stated noise: its covariance is inflated by the
square of its Birge ratio before it is compared, and the message says so."""

INFLATION_RULE = ("a calibration whose own χ² test fails (p < 0.05) has its covariance "
                  "multiplied by the square of its Birge ratio sqrt(χ²/dof) before it is "
                  "compared (Birge 1932; its uncertainties as the misfit says they are)")
"""The inflation rule, as the message and the results document state it."""

STYLUS_TOLERANCE_UM = 0.01
"""A stylus offset that differs by more than this (µm, any axis) between two model files
is listed as changed."""

MAX_MAP_NODES_PER_AXIS = 21
"""Largest grid of the error-map change (21³ = 9261 nodes)."""


@dataclass(frozen=True)
class History:
    """Outcome of :func:`compare_calibrations`.

    Attributes
    ----------
    message : str
        What changed significantly, at which family-wise level, and what could not be
        compared.
    names : list of str
        The models (file names), in date order.
    dates : list of str
        Their dates (ISO 8601), ascending.
    changes : DataFrame
        One row per consecutive pair and shared parameter: ``label``, ``unit``,
        ``date_from``, ``date_to``, ``value_from``, ``value_to``, ``change``,
        ``u_change``, ``En`` (``change / (k u_change)``, k the ``coverage_factor``),
        ``p_value`` (two-sided, of ``change / u_change``), ``significant`` (Holm).
    trend : DataFrame
        One row per model and parameter: ``label``, ``unit``, ``date``, ``value``, ``u``
        (for a trend plot per parameter).
    significant : list of str
        ``"label (date_from → date_to)"`` of the significant changes.
    only_in : dict
        Model name -> parameters no other model has (not compared).
    family_alpha : float
        Family-wise false-alarm level of the Holm procedure.
    map_change : DataFrame
        The error map's change from the first to the last calibration on a grid:
        ``x_mm, y_mm, z_mm``, ``dex_um, dey_um, dez_um`` (last minus first) and their
        standard uncertainties ``u_dex_um ...``.
    coverage_factor : float
        The k of the E_n stated (default 2).
    explanations : list of ChangeExplanation
        The fewest physical changes between each pair of consecutive calibrations
        (:func:`.explain.explain_difference`, full covariances), in date order.
    inflated : dict
        Model name -> the factor its uncertainties were multiplied by (its Birge ratio)
        because its own χ² test failed (:data:`INFLATION_RULE`).
    same_certificate : list of str
        The pairs (``"date → date"``) made with one certificate, whose shared errors are
        taken out of the difference's covariance (:func:`.explain.difference_covariance`).
    styli : list of dict
        Per consecutive pair: ``date_from``, ``date_to``, ``changed`` (stylus -> its
        offset's change, µm, x y z, where it is above :data:`STYLUS_TOLERANCE_UM`),
        ``only_in`` (styli in one of the two): compared by value only, as the model
        files give the offsets no uncertainty.
    """

    message: str
    names: list
    dates: list
    changes: pd.DataFrame
    trend: pd.DataFrame
    significant: list
    only_in: dict
    family_alpha: float
    map_change: pd.DataFrame
    coverage_factor: float = 2.0
    explanations: tuple = ()
    inflated: dict = field(default_factory=dict)
    styli: list = field(default_factory=list)
    same_certificate: list = field(default_factory=list)

    def results_section(self) -> dict:
        """The "history" section of the results document (``export.results_dict``): every
        shared parameter's change with its standard uncertainty and E_n, the decision
        rule, the error map's largest change; numbers JSON-safe (NaN: null)."""
        d = self.map_change
        return {"models": list(self.names), "dates": list(self.dates),
                "family_alpha": self.family_alpha, "method": "Holm",
                "decision_rule": HISTORY_RULE, "coverage_factor": self.coverage_factor,
                "message": self.message,
                "changes": [{"name": r.label, "unit": r.unit, "date_from": r.date_from,
                             "date_to": r.date_to, "value_from": json_num(r.value_from),
                             "value_to": json_num(r.value_to), "change": json_num(r.change),
                             "standard_uncertainty": json_num(r.u_change), "En": json_num(r.En),
                             "p_value": json_num(r.p_value), "significant": bool(r.significant)}
                            for r in self.changes.itertuples()],
                "only_in": {k: list(v) for k, v in self.only_in.items()},
                "explanations": [dict(e.to_dict(), date_from=a, date_to=b) for e, a, b in
                                 zip(self.explanations, self.dates, self.dates[1:],
                                     strict=False)],
                "inflated": dict(self.inflated), "inflation_rule": INFLATION_RULE,
                "styli": list(self.styli), "same_certificate": list(self.same_certificate),
                "map_change_max_um": {a: json_num(np.abs(d[f"de{a}_um"]).max()) for a in "xyz"},
                "map_change_u_max_um": {a: json_num(d[f"u_de{a}_um"].max()) for a in "xyz"}}

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        sig = self.changes[self.changes["significant"]]
        d = self.map_change
        worst = {a: float(np.abs(d[f"de{a}_um"]).max()) for a in "xyz"}
        return {"message": self.message, "models": list(self.names),
                "dates": list(self.dates), "family_alpha": self.family_alpha,
                "method": "Holm", "coverage_factor": self.coverage_factor,
                "n_tested": len(self.changes),
                "significant": [{k: (float(v) if isinstance(v, float | np.floating) else v)
                                 for k, v in r.items()} for r in sig.to_dict("records")],
                "only_in": {k: list(v) for k, v in self.only_in.items()},
                "explanations": [e.to_dict() for e in self.explanations],
                "inflated": dict(self.inflated), "styli": list(self.styli),
                "same_certificate": list(self.same_certificate),
                "map_change_max_um": worst}


@single_blas_thread
def compare_calibrations(models_with_dates: Sequence[tuple[Model, str]], *, family_alpha: float = 0.05,
                         nodes_per_axis: int = 5, coverage_factor: float = 2.0) -> History:
    """Every shared parameter's change between consecutive calibrations of one machine.

    Parameters
    ----------
    models_with_dates : sequence of (Model, str)
        Stored models and their calibration dates (ISO 8601, e.g. ``"2024-03-01"``), in
        any order; sorted by date.
    family_alpha : float
        Family-wise false-alarm level (Holm over all pairs and shared parameters).
    nodes_per_axis : int
        Grid of the error map's change (2 to :data:`MAX_MAP_NODES_PER_AXIS` per axis).
    coverage_factor : float
        k of the expanded uncertainties the E_n are stated with (ISO/IEC 17043:2010
        Annex B; default 2 as EA-4/02 states them). The tests do not depend on it.

    Returns
    -------
    History

    Raises
    ------
    DataError
        One line: fewer than two models, a date that is not ISO 8601, two models of
        one date, one calibration given twice (equal coefficients and covariance), two
        models of different machines (layout or strokes), an undetermined model, or
        models that share no parameter with an uncertainty (a parameter held fixed in
        both, u₁ = u₂ = 0, is not compared and the message says so).
    """
    if not 0 < family_alpha < 0.5:
        raise ValueError(f"family_alpha must be in (0, 0.5), got {family_alpha}.")
    if not 2 <= int(nodes_per_axis) <= MAX_MAP_NODES_PER_AXIS:
        raise ValueError(f"nodes_per_axis must be 2 to {MAX_MAP_NODES_PER_AXIS}, got "
                         f"{nodes_per_axis}.")
    cf = float(coverage_factor)
    if not (np.isfinite(cf) and cf > 0):
        raise ValueError(f"coverage_factor must be a positive number, got {coverage_factor}.")
    items = _checked(models_with_dates)
    inflated = {}
    for k, (m, d) in enumerate(items):
        p, birge = m.summary.get("chi2_p_value"), m.summary.get("birge_ratio")
        if isinstance(p, int | float) and isinstance(birge, int | float) and \
                p < CALIBRATION_CHI2_ALPHA and birge > 1:
            inflated[m.name] = float(birge)
            cert = None if m.certificate is None else {
                **m.certificate, "sensitivity": np.asarray(m.certificate["sensitivity"])
                * float(birge)}  # its part of the covariance inflated alike
            items[k] = (replace(m, cov=m.cov * float(birge) ** 2, certificate=cert), d)
    models = [m for m, _ in items]
    dates = [d.isoformat() for _, d in items]
    label_sets = [set(m.terms.labels) for m in models]
    only_in = {m.name: [lab for lab in m.terms.labels
                        if sum(lab in s for s in label_sets) == 1]
               for m in models}
    only_in = {k: v for k, v in only_in.items() if v}
    rows = []
    same_certificate: list[str] = []  # pairs made with one certificate
    held: dict[str, list] = {}  # shared parameters with no uncertainty in either model
    for (m1, d1), (m2, d2) in zip(items, items[1:], strict=False):
        common = [lab for lab in m1.terms.labels if lab in set(m2.terms.labels)]
        i1 = [m1.terms.labels.index(lab) for lab in common]
        i2 = [m2.terms.labels.index(lab) for lab in common]
        Vd, shared = difference_covariance(m1, m2, i1, i2)
        if shared:
            same_certificate.append(f"{d1.isoformat()} → {d2.isoformat()}")
        u = np.sqrt(np.clip(np.diag(Vd), 0, None))
        # a parameter both calibrations held fixed (u₁ = u₂ = 0) has no E_n (0/0 or
        # ±inf): not compared, and said so
        for lab in (c for c, ok in zip(common, u > 0, strict=True) if not ok):
            held.setdefault(lab, []).append(f"{d1.isoformat()} → {d2.isoformat()}")
        keep = [int(k) for k in np.flatnonzero(u > 0)]
        common = [common[k] for k in keep]
        i1, i2, u = [i1[k] for k in keep], [i2[k] for k in keep], u[keep]
        if not common:
            raise DataError(f"the models {m1.name} and {m2.name} share no parameter with an "
                            "uncertainty; nothing can be compared.", file=m2.name,
                            column="labels",
                            hint="compare calibrations fitted with the same model spec.")
        v1, v2 = m1.coef[i1], m2.coef[i2]
        for k, lab in enumerate(common):
            rows.append({"label": lab, "unit": m1.terms.unit(lab),
                         "date_from": d1.isoformat(), "date_to": d2.isoformat(),
                         "value_from": float(v1[k]), "value_to": float(v2[k]),
                         "change": float(v2[k] - v1[k]), "u_change": float(u[k])})
    changes = pd.DataFrame(rows)
    z = (changes["change"] / changes["u_change"]).to_numpy()  # N(0, 1) if unchanged
    changes["En"] = z / cf
    changes["p_value"] = 2 * stats.norm.sf(np.abs(z))
    changes["significant"] = holm(changes["p_value"].to_numpy(), len(changes), family_alpha)
    trend = pd.DataFrame([{"label": lab, "unit": m.terms.unit(lab), "date": d,
                           "value": float(m.coef[j]), "u": float(np.sqrt(m.cov[j, j]))}
                          for m, d in zip(models, dates, strict=True)
                          for j, lab in enumerate(m.terms.labels)])
    sig_rows = changes[changes["significant"]]
    significant = [f"{r.label} ({r.date_from} → {r.date_to})" for r in sig_rows.itertuples()]
    grid = _map_change(models[0], models[-1], int(nodes_per_axis))
    explanations = tuple(explain_difference(m1, m2, alpha=family_alpha)
                         for (m1, _), (m2, _) in zip(items, items[1:], strict=False))
    lead = (f"The fewest changes that explain each difference (the calibrations' full "
            f"covariances, nested tests at the family-wise level {100 * family_alpha:g} %): "
            + " ".join(f"{d1} → {d2}: {_lead(e)}" for e, d1, d2 in
                       zip(explanations, dates, dates[1:], strict=False)))
    warn = "".join(f" Warning: {name} fails its own χ² test (p = "
                   f"{models[names_index].summary['chi2_p_value']:.2g}); its uncertainties are "
                   f"multiplied by its Birge ratio {b:.2f} ({INFLATION_RULE})."
                   for name, b in inflated.items()
                   for names_index in [[m.name for m in models].index(name)])
    msg = (f"{lead}{warn} Parameter by parameter: "
           f"{len(models)} calibrations of one {models[0].terms.layout} machine "
           f"({dates[0]} to {dates[-1]}): {len(changes)} parameter changes between "
           f"consecutive calibrations tested (Holm, family-wise false-alarm level "
           f"{100 * family_alpha:g} %); "
           + (f"{len(significant)} significant: "
              + "; ".join(f"{r.label} {r.change:+.3g} ± {r.u_change:.2g} (E_n (k = {cf:g}) = "
                          f"{r.En:+.1f}, "
                          f"{r.date_from} → {r.date_to})" for r in sig_rows.itertuples())
              if significant else "none significant")
           + ". The error map changed by up to "
           + ", ".join(f"{np.abs(grid[f'de{a}_um']).max():.2f} µm in {a}" for a in "xyz")
           + " from the first to the last (grid of "
           f"{nodes_per_axis}³ nodes, ram reference point).")
    styli = [_stylus_changes(m1, m2, d1, d2)
             for (m1, _), (m2, _), d1, d2 in zip(items, items[1:], dates, dates[1:],
                                                  strict=False)]
    msg += " " + _stylus_text(styli)
    if same_certificate:
        msg += (" Made with one plate certificate (the same in both model files): "
                + ", ".join(same_certificate) + "; its errors move both calibrations "
                "alike, and their difference is counted without them.")
    if only_in:
        msg += " Not compared (in one model only): " + "; ".join(
            f"{k}: {', '.join(v)}" for k, v in only_in.items()) + "."
    if held:
        msg += (" Not compared (held fixed, no uncertainty in either calibration): "
                + ", ".join(held) + ".")
    return History(msg, [m.name for m in models], dates, changes, trend, significant,
                   only_in, float(family_alpha), grid, cf, explanations, inflated, styli,
                   same_certificate)


def _stylus_changes(m1: Model, m2: Model, d1: str, d2: str) -> dict:
    """The styli's offsets of two models compared by value (µm)."""
    shared = [q for q in m1.probes_mm if q in m2.probes_mm]
    changed = {}
    for q in shared:
        dv = (np.asarray(m2.probes_mm[q], float) - np.asarray(m1.probes_mm[q], float)) * 1e3
        if np.abs(dv).max() > STYLUS_TOLERANCE_UM:
            changed[q] = [float(v) for v in dv]
    only = sorted(set(m1.probes_mm) ^ set(m2.probes_mm))
    return {"date_from": d1, "date_to": d2, "changed": changed, "only_in": only}


def _stylus_text(styli: list) -> str:
    """What the styli's offsets did, said once for all pairs."""
    parts = []
    for s in styli:
        bits = [f"{q} by ({', '.join(f'{v:+.2f}' for v in dv)}) µm"
                for q, dv in s["changed"].items()]
        if s["only_in"]:
            bits.append(f"{', '.join(s['only_in'])} in one of the two only")
        if bits:
            parts.append(f"{s['date_from']} → {s['date_to']}: " + "; ".join(bits))
    head = ("Stylus offsets (compared by value: the model files give them no "
            "uncertainty): ")
    return head + (". ".join(parts) + "." if parts else "the same in every calibration.")


def _lead(e: ChangeExplanation) -> str:
    """One pair's fewest changes in a sentence (no change: said so)."""
    if not e.steps:
        return "no change of the geometry needed to explain the difference."
    return "; then ".join(s.text() for s in e.steps) + "."


def _checked(models_with_dates) -> list:
    """(model, date) pairs sorted by date, refused (one line) when they cannot be
    compared."""
    items = list(models_with_dates)
    if len(items) < 2:
        raise DataError(f"{len(items)} calibration(s) given; a history needs at least two.",
                        file="history", hint="give two or more model files with dates.")
    out = []
    for m, d in items:
        try:
            date = d if isinstance(d, dt.date) else dt.date.fromisoformat(str(d).strip())
        except ValueError:
            raise DataError(f"date {str(d)[:40]!r} is not an ISO 8601 date (expected "
                            "YYYY-MM-DD).", file=m.name, column="date") from None
        if m.undetermined:
            raise DataError("the model has combinations its data did not determine: its "
                            "parameters cannot be compared.", file=m.name,
                            column="undetermined")
        out.append((m, date))
    out.sort(key=lambda md: md[1])
    refuse_mixed_machines(m for m, _ in out)
    first = out[0][0]
    for m, _ in out[1:]:
        if m.terms.layout != first.terms.layout:
            raise DataError(f"the model is of a {m.terms.layout} machine, {first.name} of a "
                            f"{first.terms.layout}: different machines are not compared.",
                            file=m.name, column="layout")
        if not np.allclose(m.terms.range_mm, first.terms.range_mm, rtol=0, atol=1.0):
            raise DataError(f"strokes {list(m.terms.range_mm)} mm differ from {first.name}'s "
                            f"{list(first.terms.range_mm)} mm: different machines are not "
                            "compared.", file=m.name, column="range_mm")
    for (m1, d1), (m2, d2) in zip(out, out[1:], strict=False):
        if d1 == d2:
            raise DataError(f"two calibrations dated {d1.isoformat()} ({m1.name} and "
                            f"{m2.name}); a history needs one calibration per date.",
                            file=m2.name, column="date",
                            hint="give each model its own calibration date.")
    for i, (m1, _) in enumerate(out):
        for m2, _ in out[i + 1:]:
            if (m1.terms.labels == m2.terms.labels and np.array_equal(m1.coef, m2.coef)
                    and np.array_equal(m1.cov, m2.cov)):
                raise DataError(f"the same calibration as {m1.name} (equal coefficients and "
                                "covariance): one calibration given twice is not two "
                                "independent calibrations.", file=m2.name,
                                hint="give each calibration once.")
    return out


def _map_change(m1: Model, m2: Model, n: int) -> pd.DataFrame:
    """The error map of ``m2`` minus that of ``m1`` on an n³ grid, with its u."""
    axes = [np.linspace(0.0, r, n) for r in m1.terms.range_mm]
    x = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    p = np.zeros_like(x)
    e, var = [], []
    for m in (m1, m2):
        xs, J = kin.jacobian(m.terms, m.coef, x, p)
        Je = J / UM
        e.append((xs - x - p) / UM)
        var.append(np.clip(np.einsum("mik,kl,mil->mi", Je, m.cov, Je), 0, None))
    out = pd.DataFrame({"x_mm": x[:, 0], "y_mm": x[:, 1], "z_mm": x[:, 2]})
    for a, ax in enumerate("xyz"):
        out[f"de{ax}_um"] = e[1][:, a] - e[0][:, a]
        out[f"u_de{ax}_um"] = np.sqrt(var[0][:, a] + var[1][:, a])
    return out

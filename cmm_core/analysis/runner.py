"""One analysis record: what was analysed and how, shared by the app, the CLI and the report.

An :class:`AnalysisRecord` names the data, selection, exclusions, model (spec, order, plate
mode, σ) and the diagnosis, GP, MPE and report choices. It is read and written as JSON
(``ANALYSIS.json``, docs/report.md), built from the app session by the Export page and
carried by the project file; :func:`run` turns it into numbers, so the same record gives
the same numbers (and the same report) everywhere. Laser interferometer runs and step
gauges (docs/instruments.md) ride along as :class:`InstrumentFile` and are fitted jointly
with the plate in every fit of :func:`run`. Also defined once here: the sign of the
measured error (:data:`ERROR_CONVENTION`) and the outlier default
(:data:`DEFAULT_EXCLUDE_OUTLIERS`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
import pandas as pd

from ..diagnosis import Diagnosis, detect_outliers, diagnose, estimate_sigma
from ..export import Model, model_from_dict, model_from_result, results_dict
from ..gp import GPComponents, gp_components
from ..gum import MpeResult, check_dataset
from ..io import Dataset, read_json
from ..model import (
    FitResult,
    Observations,
    UncertaintySummary,
    check_selection,
    evaluate,
    fit,
    residuals_frame,
    select,
    summary,
)
from ..monitor import CheckOutcome, History, compare_calibrations, run_check
from .record import (
    AnalysisRecord,
    CheckChoices,
    DataFile,
    HistoryChoices,
    measured_error_from_residuals_um,
)
from .sources import load_sources

__all__ = ["load_data", "load_instruments", "with_instruments", "AnalysisResult", "run",
           "FitChoices", "fit_kwargs", "fit_record", "diagnose_record", "record_exclusions",
           "resolve_sigma",
           "load_stored_model", "results_document"]


def load_data(record: AnalysisRecord) -> Dataset:
    """The :class:`~cmm_core.io.Dataset` the record names (:func:`load_sources` of its
    data)."""
    return load_sources(record.data)


def load_instruments(record: AnalysisRecord) -> tuple:
    """The instrument readings the record names (``LaserRun``, ``StepGauge`` ...)."""
    return tuple(i.read() for i in record.data.instruments)


def with_instruments(ds: Dataset, instruments: Sequence, *, positions: Sequence[str] | None = None,
                 probes: Sequence[str] | None = None,
                 exclude: Iterable[tuple[str, str, int]] = ()) -> Dataset | Observations:
    """What the fits of an analysis take as data: ``ds`` itself without instruments, else
    its selected observations carrying them, so every model built from them (the
    diagnosis's scores and refits, the σ estimate) includes their rows
    (docs/instruments.md#python)."""
    if not instruments:
        return ds

    obs = select(ds, positions=positions and list(positions),
                 probes=probes and list(probes), exclude=list(exclude))
    return replace(obs, instruments=tuple(instruments))


@dataclass(frozen=True)
class AnalysisResult:
    """The numbers of one record (:func:`run`)."""

    record: AnalysisRecord
    """The record these numbers come from."""
    dataset: Dataset
    """The loaded :class:`~cmm_core.io.dataset.Dataset`."""
    fit: FitResult
    """The :class:`~cmm_core.model.result.FitResult` of the record's model."""
    exclusions: tuple
    """Observations left out: the record's and, with ``exclude_outliers``, the flagged."""
    flagged: tuple
    """``(position, probe, ball)`` the robust outlier check flags (excluded or not)."""
    sigma: dict
    """σ used: ``{"value_um", "auto"}`` plus the estimate's fields when auto."""
    uncertainty: UncertaintySummary | None
    """:class:`~cmm_core.model.uncertainty.UncertaintySummary`, or None when it failed."""
    history: tuple
    """History rows: spec, change, rms_um, chi2_dof, bic, n_params."""
    measured_error_um: np.ndarray
    """(n, 3) measured error at the fitted observations (µm, :data:`ERROR_CONVENTION`)."""
    diagnosis: Diagnosis | None = None
    """:class:`~cmm_core.diagnosis.Diagnosis` when the record asks for it."""
    mpe: MpeResult | None = None
    """:class:`~cmm_core.gum.mpe.MpeResult`, None without the certificate of a square plate."""
    gp: GPComponents | None = None
    """:class:`~cmm_core.gp.cmm.GPComponents` when the record names a GP mean."""
    instruments: tuple = ()
    """Per instrument file, its record of ``instruments.summary`` (kind, file, readings,
    rows, χ², rms_um, max_abs_z ...); empty without instruments."""
    instrument_residuals: pd.DataFrame | None = None
    """``instruments.residuals_frame`` of the fit (one row per reading), None without."""
    interim: CheckOutcome | None = None
    """The interim check of the record's data against its stored calibration
    (``record.interim_check``), None without."""
    calibration_history: History | None = None
    """The machine's calibrations compared (``record.calibration_history``), None
    without."""


class FitChoices(Protocol):
    """What decides one fit: an :class:`AnalysisRecord`, or anything with its fit fields
    (the app's cache key of a fit)."""

    @property
    def spec(self) -> str: ...
    @property
    def order(self) -> int: ...
    @property
    def plate(self) -> str: ...
    @property
    def sigma_um(self) -> float | str: ...
    @property
    def positions(self) -> Sequence[str] | None: ...
    @property
    def probes(self) -> Sequence[str] | None: ...
    @property
    def exclusions(self) -> Sequence[Sequence]: ...


def fit_kwargs(record: FitChoices, exclusions: Iterable[Sequence] | None = None,
               **more: Any) -> dict:
    """Keyword arguments of ``model.fit`` and ``diagnosis.diagnose`` but the spec: the
    record's order, plate mode, selection and exclusions (``exclusions`` instead, when
    given: the record's plus the flagged outliers it excludes), and ``more``
    (``sigma_um``). The one translation of the fit choices into a fit, for :func:`run`
    and the app alike."""
    excl = record.exclusions if exclusions is None else exclusions
    return {"order": record.order, "plate": None if record.plate == "auto" else record.plate,
            "positions": record.positions and list(record.positions),
            "exclude": [tuple(e) for e in excl],
            "probes": record.probes and list(record.probes), **more}


def _record_data(ds: Dataset, instruments: Sequence, kw: dict) -> Dataset | Observations:
    return with_instruments(ds, instruments, positions=kw["positions"], probes=kw["probes"],
                            exclude=kw["exclude"])


def fit_record(record: FitChoices, ds: Dataset, instruments: Sequence = (), *,
               spec: str | None = None, exclusions: Iterable[Sequence] | None = None,
               sigma_um: float | None = None) -> FitResult:
    """The fit of a record's choices to ``ds`` with ``instruments`` fitted jointly: the
    record's model (or ``spec``: a history step, the rigid placements) at its σ (or
    ``sigma_um``: an estimate resolved by the caller). What :func:`run` and the app fit.

    Raises
    ------
    ValueError
        σ is ``"auto"`` and no ``sigma_um`` is given (estimate it first:
        ``diagnosis.estimate_sigma``, as :func:`run` does).
    """
    sig = record.sigma_um if sigma_um is None else sigma_um
    if sig == "auto":
        raise ValueError("σ is 'auto' in the record: estimate it first and pass sigma_um.")
    kw = fit_kwargs(record, exclusions, sigma_um=float(sig))
    return fit(_record_data(ds, instruments, kw), spec or record.spec, **kw)


def diagnose_record(record: FitChoices, ds: Dataset, instruments: Sequence = (), *,
                    spec: str | None = None, exclusions: Iterable[Sequence] | None = None,
                    sigma_um: float | None = None,
                    progress: Callable[[float, str], None] | None = None,
                    baseline_fit: FitResult | None = None) -> Diagnosis:
    """The diagnosis of a record's fit (:func:`fit_record`'s arguments): every candidate
    scored and refitted with the record's instruments, ``spec`` (default the record's
    model) as the baseline. ``baseline_fit``: :func:`fit_record` of the same arguments
    when the caller holds it (the diagnosis then does not fit the baseline again;
    ``diagnosis.diagnose`` refuses a fit of other choices)."""
    sig = record.sigma_um if sigma_um is None else sigma_um
    if sig == "auto":
        raise ValueError("σ is 'auto' in the record: estimate it first and pass sigma_um.")
    kw = fit_kwargs(record, exclusions, sigma_um=float(sig))
    return diagnose(_record_data(ds, instruments, kw), baseline=spec or record.spec,
                    progress=progress, baseline_fit=baseline_fit, **kw)


def record_exclusions(record: AnalysisRecord, ds: Dataset) -> tuple[tuple, tuple]:
    """``(exclusions, flagged)``: the observations a record's fits leave out (its own
    exclusions, plus the robust outlier check's flags when ``exclude_outliers``), and the
    flagged ones whether excluded or not."""
    try:
        flagged = tuple(tuple(e) for e in detect_outliers(ds).exclusions)
    except ValueError:  # too few positions to compare: nothing flagged unless asked to
        if record.exclude_outliers:
            raise
        flagged = ()
    excl = tuple(sorted(set(map(tuple, record.exclusions))
                        | (set(flagged) if record.exclude_outliers else set())))
    return excl, flagged


def history_exclusions(record: AnalysisRecord, ds: Dataset, flagged: tuple
                       ) -> list[tuple | None]:
    """The exclusions each history step of ``record`` is fitted with: a step's own (with
    the flagged observations when the record's ``exclude_outliers`` says so, as its own
    ``exclusions`` get them), None for a step without its own (the record's
    ``exclusions``, :func:`record_exclusions`).

    Raises
    ------
    ValueError
        A step's own exclusions name an observation the data lack (the step named).
    """
    out: list[tuple | None] = []
    for _spec, change, *own in record.history:
        if not own:
            out.append(None)
            continue
        ex = tuple(sorted(set(map(tuple, own[0]))
                          | (set(flagged) if record.exclude_outliers else set())))
        check_selection(ds, record.positions, record.probes, ex,
                        f"analysis record, history step {change!r}")
        out.append(ex)
    return out


def resolve_sigma(record: AnalysisRecord, ds: Dataset, instruments: Sequence = (),
                  exclusions: Iterable[Sequence] | None = None) -> dict:
    """The σ a record's fits use: ``{"value_um", "auto"}``, plus the estimate's fields
    (``u_um``, ``method`` ...) when the record says ``"auto"`` (estimated from the
    record's data as selected, with its instruments and ``exclusions``)."""
    if record.sigma_um != "auto":
        return {"value_um": float(record.sigma_um), "auto": False}
    kw = fit_kwargs(record, exclusions)
    est = estimate_sigma(_record_data(ds, instruments, kw), record.spec, **kw)
    return {**est.to_dict(), "value_um": float(est.value_um), "auto": True}


def run(record: AnalysisRecord) -> AnalysisResult:
    """Dataset, fit, history, measured errors, uncertainty, and the optional diagnosis,
    MPE check and GP of a record, every fit with the record's instruments. The CLI and
    the report call this; the app, which computes one page's part at a time, calls its
    steps (:func:`fit_record`, :func:`diagnose_record`) with the same choices."""

    ds = load_data(record)
    check_selection(ds, record.positions, record.probes, record.exclusions,
                    "analysis record")
    excl, flagged = record_exclusions(record, ds)
    inst = load_instruments(record)
    sigma = resolve_sigma(record, ds, inst, excl)
    steps = {"exclusions": excl, "sigma_um": sigma["value_um"]}
    r = fit_record(record, ds, inst, **steps)
    history = []
    # a step made with exclusions of its own (an outlier exclusion is a step) is fitted
    # with them; any other with the record's
    for (spec, change, *_), own in zip(record.history,
                                       history_exclusions(record, ds, flagged),
                                       strict=True):
        ex = excl if own is None else own
        same = spec == record.spec and set(ex) == set(excl)
        history.append((r if same else fit_record(record, ds, inst, spec=spec, exclusions=ex,
                                                  sigma_um=steps["sigma_um"]))
                       .history_row(change))
    rigid = fit_record(record, ds, inst, spec="rigid", **steps)
    err = measured_error_from_residuals_um(rigid.residuals_um)
    try:
        unc = evaluate(r, n_random=record.uncertainty_points, seed=record.uncertainty_seed)
    except (ValueError, np.linalg.LinAlgError):
        unc = None
    # the record's fit is the diagnosis's baseline: not fitted twice
    diag = (diagnose_record(record, ds, inst, baseline_fit=r, **steps) if record.diagnose
            else None)
    mpe, _ = check_dataset(ds, u_source=record.mpe_u_source, sigma_um=r.sigma_um)
    gp = None
    if record.gp_mean is not None:

        obs = rigid.problem.obs
        kin = record.gp_mean == "kinematic"
        vals = measured_error_from_residuals_um(r.residuals_um) if kin else err
        gp = gp_components(obs.r_mm, vals, mean="zero" if kin else record.gp_mean,
                           kernel=record.gp_kernel, restarts=1, probe_mm=obs.p_mm)
    interim = None if record.interim_check is None else _interim(
        record.interim_check, ds, inst, record, excl)
    hist = None if record.calibration_history is None else _history(
        record.calibration_history, r, ds.name)
    return AnalysisResult(record=record, dataset=ds, fit=r, exclusions=excl, flagged=flagged,
                          sigma=sigma, uncertainty=unc, history=tuple(history),
                          measured_error_um=err, diagnosis=diag, mpe=mpe, gp=gp,
                          instruments=tuple(summary(r)) if inst else (),
                          instrument_residuals=residuals_frame(r) if inst else None,
                          interim=interim, calibration_history=hist)


def load_stored_model(f: DataFile) -> Model:
    """A stored calibration (a model file written by ``fit --save``) the record names;
    DataError naming the file when it is not one."""
    doc, _ = read_json(f.source_text().encode(), f.name)
    return model_from_dict(doc, name=f.name)


def _interim(c: CheckChoices, ds: Dataset, inst: tuple, record: AnalysisRecord,
             exclusions: Iterable[Sequence] = ()) -> CheckOutcome:
    """The interim check of the record's data as its fit takes them: its placements and
    styli, without ``exclusions`` (the record's own and its outlier rule's,
    :func:`record_exclusions`), with its instruments."""
    return run_check(load_stored_model(c.model), ds, instruments=inst, sigma_um=c.sigma_um,
                     alpha=c.alpha, family_alpha=c.family_alpha,
                     positions=record.positions and list(record.positions),
                     probes=record.probes and list(record.probes),
                     exclude=list(exclusions), mpe=c.mpe)


def _history(h: HistoryChoices, r: FitResult, name: str) -> History:
    """The calibration history: the model files, and this analysis's fit at its date."""
    models = [(load_stored_model(f), d) for f, d in h.models]
    if h.date is not None:
        own = model_from_result(r)
        models.append((replace(own, name=name), h.date))
    return compare_calibrations(models, family_alpha=h.family_alpha,
                                nodes_per_axis=h.nodes)


def results_document(res: AnalysisResult, **kw: Any) -> dict:
    """The results document (``export.results_dict``) of the record's fit with its
    sections "interim_check" and "history" when the record asks for them (``kw``: the
    coverage factor, source, created)."""
    return results_dict(res.fit, interim_check=None if res.interim is None else
                        res.interim.results_section(),
                        history=None if res.calibration_history is None else
                        res.calibration_history.results_section(), **kw)

"""The thin ``st.cache_data`` wrappers through which pages call the core: the fit of the
current settings (:class:`FitKey`), outliers, uncertainty, the diagnosis and its history,
and figures."""

from __future__ import annotations

import io
from dataclasses import dataclass, replace

import numpy as np
import streamlit as st

from cmm_core import analysis as A
from cmm_core.diagnosis import detect_outliers, discrepancy_gp
from cmm_core.model import evaluate, read_instrument
from pages.ui.calls import describe_error, safe
from pages.ui.state import dataset, held_steps, instruments_key


@st.cache_resource(show_spinner=False, max_entries=16)
def _read_instruments(key: str, _items) -> tuple:
    return tuple(read_instrument(io.StringIO(text), kind, name=name)
                 for kind, name, text in _items)


def instrument_data(key: FitKey | None = None) -> tuple:
    """The session's instrument readings (``LaserRun``, ``StepGauge`` ...) for a fit
    ``key`` (none when the key has none)."""
    s = st.session_state
    items = s.get("instruments") or []
    ikey = instruments_key(items)
    if not items or (key is not None and key.instruments != ikey):
        return ()
    return _read_instruments(ikey, items)


@dataclass(frozen=True)
class FitKey:
    """What decides one fit of the app, built by keyword from the session (:func:`fit_key`):
    the cache key of every cached core call, hashable, never indexed by position. It has
    the fit fields of an analysis record (``analysis.FitChoices``), so the core fits and
    diagnoses it as it does a record (``analysis.fit_record``, ``diagnose_record``)."""

    data: str
    """Key of the dataset's sources (``analysis.sources_key``)."""
    spec: str
    """Model spec."""
    order: int
    """Default polynomial order."""
    plate: str
    """Plate geometry: auto, fixed, prior or free."""
    sigma_um: float
    """Repeatability σ (µm)."""
    positions: tuple | None
    """Positions fitted (None: all)."""
    probes: tuple | None
    """Probes fitted (None: all)."""
    exclusions: tuple
    """``(position, probe, ball)`` observations left out."""
    instruments: str = ""
    """Key of the instrument files fitted with the plate (:func:`instruments_key`); "":
    none."""

    def fit_kwargs(self) -> dict:
        """Keyword arguments of ``model.fit`` (and ``diagnose``) but the spec: the core's
        one translation of an analysis's fit choices (``analysis.fit_kwargs``)."""
        return A.fit_kwargs(self, sigma_um=self.sigma_um)

    def with_spec(self, spec: str) -> FitKey:
        """The same fit of another model (the rigid placements, a history step)."""
        return replace(self, spec=spec)


@st.cache_data(show_spinner=False, max_entries=256)
def cached_fit(key: FitKey, _ds, _instruments=()):
    """The fit ``key`` names, with ``_instruments`` (the readings ``key.instruments``
    names) fitted jointly: ``analysis.fit_record``, the fit of an analysis record that
    ``analysis.run`` (the CLI, the report) makes of the same choices."""
    return A.fit_record(key, _ds, _instruments)


def fit_of(key: FitKey):
    """``cached_fit`` of ``key`` with the current dataset and the instruments it names."""
    return cached_fit(key, dataset(), instrument_data(key))


@st.cache_data(show_spinner=False, max_entries=16)
def cached_outliers(key, _ds):
    return detect_outliers(_ds)


def fit_key(spec=None, *, instruments: bool = True, exclusions=None) -> FitKey:
    """The :class:`FitKey` of the session's fit (of ``spec`` when given; without the
    instrument files when ``instruments`` is false; with ``exclusions`` in place of the
    session's: a history step's own)."""
    s = st.session_state
    return FitKey(
        data=s["ds_key"], spec=spec or s["spec"], order=int(s["order"]), plate=s["plate"],
        sigma_um=float(s["sigma_um"]),
        positions=tuple(s["positions"]) if s["positions"] is not None else None,
        probes=tuple(s["probes"]) if s["probes"] is not None else None,
        exclusions=tuple(tuple(e) for e in (s["exclusions"] if exclusions is None
                                            else exclusions)),
        instruments=(s.get("instruments_key") or "") if instruments else "")


def require_dataset():
    """The current dataset, or stop the page with the loading error shown."""
    ds = safe(dataset, what="Loading the dataset")
    if ds is None:
        st.stop()
    return ds


def require_fit():
    """``(dataset, fit of the current model)``, or stop the page with the error shown."""
    ds = require_dataset()
    r = current_fit()
    if r is None:
        st.stop()
    return ds, r


def current_fit(spec=None, *, show_error=True, instruments: bool = True, exclusions=None):
    """The fit of the current (or a given) model, with the session's instrument files
    unless ``instruments`` is false and its exclusions unless ``exclusions`` are given, or
    None with a message."""
    try:
        return fit_of(fit_key(spec, instruments=instruments, exclusions=exclusions))
    except Exception as exc:  # noqa: BLE001
        if show_error:
            st.error(f"The fit failed: {describe_error(exc)}")
        return None


@st.cache_data(show_spinner=False, max_entries=64)
def cached_uncertainty(key: FitKey, n_random, seed, _result):
    return evaluate(_result, n_random=n_random, seed=seed)


@st.cache_resource(show_spinner=False, max_entries=64)
def cached_gp_discrepancy(key: FitKey, _result) -> float:
    """GP discrepancy of a fit (µm): the structure a GP over its residuals finds, with the
    model's own design matrix as basis (``diagnosis.discrepancy_gp``)."""
    return float(discrepancy_gp(_result, restarts=1).rms_amplitude_um)


def run_diagnosis(show_progress: bool = False):
    """The current fit, its ranked candidates as a list of dicts (best first) and the
    core's plain-language conclusion (with aliases and skipped candidates).

    Each dict: effect, title, explanation, aliases, separate_by, rms_um, chi2_dof,
    delta_chi2, delta_bic, p_value, n_params, significant, confirmed, is_verdict (the
    core's verdict: none when the baseline did not converge), signature_um (n, 3).
    With ``show_progress`` a progress bar follows the scoring of the candidates. The
    fourth item holds the verdict and its headline (``Diagnosis.headline``: what the page
    draws first), the σ check, the certificate check, where the
    residual lives and the leave-one-placement-out checks (``holdout``, which
    "Measure next" reads through ``plan.open_pairs``) (``Diagnosis.to_dict``).
    """
    base = current_fit()
    if base is None:
        return None, None, "", {}
    key = fit_key()
    return (base, *cached_diagnosis(key, dataset(), instrument_data(key),
                                    show_progress, base))


@st.cache_data(show_spinner="Running the diagnosis…", max_entries=32)
def cached_diagnosis(key: FitKey, _ds, _instruments=(), _show_progress=False, _fit=None):
    """The diagnosis of ``key`` (:func:`run_diagnosis`'s rows, conclusion and info);
    ``_fit``: the cached fit of ``key`` (:func:`cached_fit`), its baseline, so the
    diagnosis does not fit it again."""
    # created inside the cached function so that a cache replay can recreate it
    bar = st.progress(0.0, text="Scoring candidate effects…") if _show_progress else None

    def report(frac, text):
        if bar is not None:
            bar.progress(frac, text=text)

    # the record's diagnosis (analysis.diagnose_record, as analysis.run): with
    # instruments, every model it scores or refits carries their rows
    d = A.diagnose_record(key, _ds, _instruments, progress=report, baseline_fit=_fit)
    # the core's own row of each candidate (the CLI's JSON), plus what only the page draws
    rows = [{**c.to_dict(), "aliases": ", ".join(c.aliases),
             "significant": bool(c.significant), "confirmed": bool(c.confirmed),
             "is_verdict": c.effect == d.verdict,
             "detectable_above": c.detectable_text(),
             "signature_um": np.asarray(c.signature_um, float),
             "would_leave_undetermined": list(c.would_leave_undetermined),
             "holdout": next((h.reason for h in d.holdout if h.effect == c.effect), "")}
            for c in d.candidates]
    if bar is not None:
        bar.empty()
    full = d.to_dict()
    info = {k: full[k] for k in ("verdict", "headline", "sigma_check", "certificate",
                                 "where", "blunders", "cannot_see", "evidence", "holdout")}
    return rows, A.diagnosis_conclusion(d), info


def history_rows() -> list:
    """The diagnosis history with each step's fit quality (computed from cached fits)."""
    s = st.session_state
    if not s["history"]:
        s["history"] = held_steps()  # the baseline, with the exclusions it is fitted with
    out = []
    for h in s["history"]:
        # each step with the exclusions it was made with (a step of an older record has
        # none of its own: the session's)
        own = h.get("exclusions")
        r = current_fit(h["spec"], show_error=False, exclusions=own)
        gp = None
        if r is not None and s.get("hist_gp"):
            try:
                gp = cached_gp_discrepancy(fit_key(h["spec"], exclusions=own), r)
            except Exception:  # noqa: BLE001
                gp = None
        row = ({"spec": h["spec"], "change": h["change"], "rms_um": None, "chi2_dof": None,
                "bic": None, "n_params": None} if r is None else
               {**r.history_row(h["change"]), "spec": h["spec"]})
        out.append({**row, "gp_amplitude_um": None if gp is None else round(gp, 3)})
    return out


def pending_outliers(ds) -> list:
    """Flagged outliers (position, probe, ball) that are still in the fit."""
    s = st.session_state
    try:
        flagged = cached_outliers(s["ds_key"], ds).exclusions
    except Exception:  # noqa: BLE001 - the flags are advice; the Data page shows errors
        return []
    done = {tuple(e) for e in s["exclusions"]}
    return [tuple(f) for f in flagged if tuple(f) not in done]


@st.cache_resource(show_spinner=False, max_entries=256)
def _cached_figure(kind: str, key: tuple, _builder, _args):
    return _builder(*_args)


def figure(kind: str, key: tuple, builder, *args):
    """``builder(*args)``, cached under ``(kind, key)``; key must identify the inputs."""
    return _cached_figure(kind, key, builder, args)

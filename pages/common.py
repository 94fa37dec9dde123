"""Shared app helpers: session state, cached core wrappers, the sidebar, safe calls.

Pages only gather inputs, call the core through the thin cached wrappers here, and draw.
Canonical session state lives under plain keys (``spec``, ``order`` ...); widgets use keys
prefixed ``w_`` and are re-initialised from the canonical state whenever a page renders
them, so values survive page switches.
"""

from __future__ import annotations

import hashlib
import html
import inspect
import io
import sys
from contextlib import contextmanager, nullcontext  # noqa: F401 - pages use C.nullcontext
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import streamlit as st

from cmm_core import analysis as A
from cmm_core import analysis as rep
from cmm_core.diagnosis import detect_outliers, estimate_sigma
from cmm_core.io import THESIS_DIR, THESIS_POSITIONS, DataError, load_dataset
from cmm_core.model import fit as core_fit
from cmm_core.model import parse_spec, read_instrument

DEFAULTS = {
    "spec": "kinematic21",
    "order": 2,
    "plate": "auto",
    "sigma_um": 0.5,
    "positions": None,
    "probes": None,
    "exclusions": [],
    "history": [],
    "magnification": 2000.0,
    "diag_on": False,
    "instruments": [],
}
INSTRUMENT_NAMES = {"laser": "laser interferometer", "step_gauge": "step gauge",
                    "ball_bar": "ball bar"}
"""Words for the instrument kinds (``analysis.instrument_kinds``) on screen."""
PLATE_CHOICES = {"auto": "default (certificate fixed if given, else self-calibrated)",
                 "fixed": "certificate fixed", "prior": "certificate as prior",
                 "free": "self-calibrated (free)"}


# ---------------------------------------------------------------------------------------
# Errors never become tracebacks
# ---------------------------------------------------------------------------------------

def describe_error(exc: Exception) -> str:
    if isinstance(exc, DataError):
        return str(exc)
    if isinstance(exc, (ValueError, KeyError)):
        return str(exc).strip("'\"")
    return f"{type(exc).__name__}: {exc}"


def safe(fn, *args, what: str = "", **kwargs):
    """Call a core function; on any exception show ``st.error`` and return None."""
    try:
        return fn(*args, **kwargs)
    except Exception as exc:  # noqa: BLE001 - every failure becomes a message
        st.error(f"{what + ': ' if what else ''}{describe_error(exc)}")
        return None


@contextmanager
def guarded(what: str):
    """``with guarded("Drawing"):`` shows a message instead of a traceback."""
    try:
        yield
    except Exception as exc:  # noqa: BLE001 - script control exceptions are BaseException
        st.error(f"{what}: {describe_error(exc)}")


# ---------------------------------------------------------------------------------------
# Dataset sources (always kept as file content so a project file can restore them)
# ---------------------------------------------------------------------------------------

def thesis_files() -> dict:
    meas = [(f"{p}.csv", (THESIS_DIR / f"{p}.csv").read_text()) for p in THESIS_POSITIONS]
    return {"name": "thesis tables 6.1-6.6", "kind": "thesis", "measurements": meas,
            "setup": (THESIS_DIR / "setup.json").read_text(),
            "certificate": ("certificate.csv", (THESIS_DIR / "certificate.csv").read_text()),
            "setup_source": "thesis setup (sample_data/thesis/setup.json)",
            "certificate_source": "thesis certificate (appendix 5)"}


# settings a new dataset starts from (the model list, selections and exclusions too)
RESET_ON_NEW_DATASET = ("spec", "order", "plate", "sigma_um")
_SETTING_NAMES = {"spec": "model", "order": "order", "plate": "plate geometry",
                  "sigma_um": "σ (µm)"}


def files_key(files: dict) -> str:
    h = hashlib.sha1()
    h.update(files["name"].encode())
    for n, c in files["measurements"]:
        h.update(n.encode() + b"\0" + c.encode() + b"\0")
    h.update(files["setup"].encode())
    if files.get("certificate"):
        h.update(b"cert" + files["certificate"][1].encode())
    return h.hexdigest()[:16]


@st.cache_data(show_spinner=False, max_entries=8)
def _load(key: str, _files: dict):
    f = _files
    meas = [(io.BytesIO(c.encode()), n) for n, c in f["measurements"]]
    cert = f.get("certificate")
    cert = (io.BytesIO(cert[1].encode()), cert[0]) if cert else None
    return load_dataset(meas, io.BytesIO(f["setup"].encode()), cert, name=f["name"])


def set_dataset(files: dict, *, reset_model: bool = True):
    """Make ``files`` the current dataset (raises DataError when it does not load)."""
    key = files_key(files)
    _load(key, files)  # validate first: a bad upload keeps the old dataset
    st.session_state["ds_files"] = files
    st.session_state["ds_key"] = key
    if reset_model:
        s = st.session_state
        changed = [f"{_SETTING_NAMES[k]} {s[k]} → {DEFAULTS[k]}" for k in RESET_ON_NEW_DATASET
                   if k in s and s[k] != DEFAULTS[k]]
        if s.get("exclusions"):
            changed.append(f"{len(s['exclusions'])} exclusion(s) cleared")
        if s.get("instruments"):  # they measured the previous machine
            changed.append(f"{len(s['instruments'])} instrument file(s) removed")
            set_instruments([])
        if s.get("positions") is not None or s.get("probes") is not None:
            changed.append("position/probe selection → all")
        for k in ("positions", "probes", "exclusions", "history", "diag_on"):
            s[k] = DEFAULTS[k] if not isinstance(DEFAULTS[k], list) else []
        for k in RESET_ON_NEW_DATASET:
            s[k] = DEFAULTS[k]
        s["reset_note"] = changed
        reset_widgets()
    return key


def reset_widgets():
    for k in list(st.session_state.keys()):
        if str(k).startswith("w_"):
            del st.session_state[k]


def init_state():
    """Defaults on first run; the thesis data loaded so a first-time user sees a model."""
    for k, v in DEFAULTS.items():
        if k not in st.session_state:
            st.session_state[k] = list(v) if isinstance(v, list) else v
    if "ds_files" not in st.session_state:
        set_dataset(thesis_files())


# ---------------------------------------------------------------------------------------
# Restoring an analysis: a project file, or the session kept on disk (survives a reload)
# ---------------------------------------------------------------------------------------

def restore_record(record, source: str) -> str:
    """Make the analysis ``record`` (an :class:`cmm_core.analysis.AnalysisRecord`, read from
    a project file or a saved session) the current one: data, instruments, model, σ,
    exclusions, history and the other choices. Raises with nothing changed when its data
    do not load, its exclusions name observations the data lack, or an instrument file
    does not fit the machine. Returns a note for the user ("" when there is nothing to
    add); ``source`` says where it came from ("the project file x.json")."""
    d = record.data
    files = {"name": d.name, "kind": "project",
             "measurements": [(f.name, f.text()) for f in d.measurements],
             "setup": d.setup.text(),
             "certificate": None if d.certificate is None else (d.certificate.name,
                                                                d.certificate.text()),
             "setup_source": f"from {source}",
             "certificate_source": f"from {source}" if d.certificate is not None else None}
    mapped = {f.name: (f.name, f.source_text(), f.mapping) for f in d.measurements
              if f.mapping is not None}
    if mapped:  # tables from other software keep their source and mapping (next save)
        files["mapped"] = mapped
    new_ds = _load(files_key(files), files)
    have = set(zip(new_ds.meas["position"].astype(str), new_ds.meas["probe"].astype(str),
                   new_ds.meas["ball"].astype(int), strict=True))
    unknown = [e for e in record.exclusions if tuple(e) not in have]
    if unknown:
        raise ValueError(f"{source}, column 'exclusions': it excludes observations its data "
                         "do not have: " + "; ".join(f"{p} probe {q} ball {b}"
                                                     for p, q, b in unknown[:10])
                         + ". Remove them from the file or restore it with its own data.")
    inst = [(i.kind, i.file.name, i.file.text()) for i in d.instruments]
    check_instruments(inst, new_ds)  # before anything changes
    set_dataset(files)
    s = st.session_state
    for k in ("spec", "order", "plate", "sigma_um", "magnification", "exclude_outliers"):
        s[k] = getattr(record, k)
    s["positions"] = None if record.positions is None else list(record.positions)
    s["probes"] = None if record.probes is None else list(record.probes)
    s["exclusions"] = [list(e) for e in record.exclusions]
    s["diag_on"] = bool(record.diagnose)
    s["history"] = [{"spec": spec, "change": change} for spec, change in record.history]
    if s["history"] and s["history"][-1]["spec"] != s["spec"]:
        # the model was edited by hand after the last recorded step
        s["history"].append({"spec": s["spec"], "change": "edited by hand"})
    s["reset_note"] = []  # the analysis's own settings, not defaults
    note = ""
    if s["sigma_um"] == "auto":  # a record written by the command line
        est = safe(estimate_sigma, dataset(), s["spec"], order=int(s["order"]),
                   plate=None if s["plate"] == "auto" else s["plate"],
                   exclude=[tuple(e) for e in s["exclusions"]], what="Estimating σ")
        s["sigma_um"] = 0.5 if est is None else round(float(est.value_um), 4)
        note = (f" Its σ is 'auto': estimated from the data as {s['sigma_um']:.4g} ± "
                f"{est.u_um:.2g} µm ({est.method})." if est is not None else
                " Its σ is 'auto' and could not be estimated: 0.5 µm is used; set it in "
                "the sidebar.")
    set_instruments(inst)
    reset_widgets()
    # the choices of other pages that the report reads, as their widgets would hold them
    s.update(w_mpe_u=record.mpe_u_source, w_u_npts=record.uncertainty_points,
             w_u_seed=record.uncertainty_seed, w_gp_kernel=record.gp_kernel,
             w_report_gp=record.gp_mean is not None)
    if record.gp_mean is not None:
        s["w_gp_mean"] = record.gp_mean
    return note


def restore_project(text, name: str) -> str:
    """Restore a project file (bytes or text named ``name``); see :func:`restore_record`."""
    return restore_record(A.record_from_project(text, name), f"the project file {name}")


SESSION_PARAM = "session"
"""The URL's query parameter naming the analysis (``?session=<32 hex digits>``)."""


def session_store() -> A.SessionStore:
    return A.SessionStore(A.default_session_folder())


def session_start():
    """First thing of every run (``app.py``): give this browser session its analysis.

    A new browser session whose URL names a saved analysis (a reload, or the URL opened in
    a new tab) restores it and says so; any other new session starts a new analysis (with
    the URL's id when it has a well-formed one, else a new id), saved once it differs from
    the defaults. The id is put back into the URL on every run, because moving between pages
    clears query parameters."""
    s = st.session_state
    if "session_id" not in s:
        asked = st.query_params.get(SESSION_PARAM)
        store = session_store()
        saved = store.load(asked) if asked else None
        s["session_id"] = saved.session_id if saved else A.new_session_id()
        if saved is not None:
            init_state()
            try:
                note = restore_record(A.record_from_project(saved.text, saved.path.name),
                                      f"the saved session {saved.path.name}")
            except Exception as exc:  # noqa: BLE001 - the new analysis goes on regardless
                s["session_id"] = A.new_session_id()
                s["restore_note"] = ("error", f"The analysis saved at {saved.path} could not "
                                     f"be restored ({describe_error(exc)}); a new analysis "
                                     "was started on the thesis data. The file is kept.")
            else:
                s["restore_note"] = ("info", f"Restored from {saved.path} (saved "
                                     f"{saved.saved_text}).{note}")
                s["saved_fingerprint"] = session_fingerprint()
        else:
            if A.valid_session_id(asked):
                s["session_id"] = asked  # nothing saved under it yet: the link stays
            # a new analysis is saved only once it differs from the defaults
            init_state()
            s["saved_fingerprint"] = session_fingerprint()
            try:
                store.prune()
            except OSError:  # a read-only or shared folder: pruning is a courtesy
                pass
    if st.query_params.get(SESSION_PARAM) != s["session_id"]:
        st.query_params[SESSION_PARAM] = s["session_id"]


def session_query() -> dict:
    """Query parameters that keep the analysis's id in links between pages."""
    return {SESSION_PARAM: st.session_state["session_id"]}


def session_fingerprint() -> str:
    """A cheap hash of everything the saved analysis holds (the record's inputs), so it is
    written only when one of them changed."""
    s = st.session_state
    keys = ("ds_key", "instruments_key", "spec", "order", "plate", "sigma_um", "positions",
            "probes", "exclusions", "history", "diag_on", "magnification",
            "exclude_outliers", "w_mpe_u", "w_u_npts", "w_u_seed", "w_gp_kernel",
            "w_gp_mean", "w_report_gp")
    return hashlib.sha1(repr([s.get(k) for k in keys]).encode()).hexdigest()


def autosave():
    """Write the analysis to its session file when it changed since the last write."""
    s = st.session_state
    fp = session_fingerprint()
    if s.get("saved_fingerprint") == fp or "ds_files" not in s:
        return
    try:
        text = A.record_to_project_json(A.record_from_session(s))
        s["saved_path"] = str(session_store().save(s["session_id"], text))
        s.pop("save_error", None)
    except Exception as exc:  # noqa: BLE001 - a failed save must not stop the page
        s["save_error"] = describe_error(exc)
    s["saved_fingerprint"] = fp


def start_afresh():
    """Button callback: forget this analysis and start a new one on the thesis data."""
    s = st.session_state
    session_store().forget(s.get("session_id", ""))
    for k in list(s.keys()):
        del s[k]
    s["session_id"] = A.new_session_id()
    s["_via_app"] = True


def restore_banner():
    """The note of a restored (or not restored) analysis, with the one-click way out."""
    note = st.session_state.get("restore_note")
    if not note:
        return
    kind, text = note
    box = st.container(border=True)
    (box.error if kind == "error" else box.info)(text)
    c1, c2 = box.columns([1, 4])
    c1.button("Start afresh", key="start_afresh", on_click=start_afresh,
              help="Forget this analysis (its saved file is removed) and start a new one "
                   "on the thesis data.")
    if c2.button("Dismiss", key="dismiss_restore"):
        st.session_state.pop("restore_note", None)
        st.rerun()


KEEP_PREFIXES = ("sim_", "w_gp_")
KEEP_KEYS = ("hist_gp", "w_mpe_u", "w_u_npts", "w_u_seed",  # the report reads these
             "w_kin_tab")  # the open tab of the Kinematic page, as the user left it


def keep_widget_state():
    """Keep the simulator form, the GP page's choices, the history's GP option and the
    MPE uncertainty choice when the user visits another page (every page calls this
    first, through ``page_start``): Streamlit drops a widget's state once a run does not
    draw it; writing the value back through the Session State API keeps it (Streamlit's
    documented remedy; the duplication warning it would raise is off in config.toml)."""
    s = st.session_state
    for k in list(s.keys()):
        if k.startswith(KEEP_PREFIXES) or k in KEEP_KEYS:
            s[k] = s[k]


def sync_from_widgets():
    """Copy widget values (already updated before this run) into the canonical state, so
    the sidebar, drawn first, shows the settings the page is about to use."""
    s = st.session_state
    for k in ("order", "spec", "plate", "sigma_um", "magnification"):
        if "w_" + k in s:
            s[k] = s["w_" + k]
    try:
        ds = dataset()
    except Exception:  # noqa: BLE001
        return
    for k, allv in (("positions", ds.positions), ("probes", ds.probes)):
        if "w_" + k in s:
            sel = list(s["w_" + k])
            s[k] = None if set(sel) == set(allv) else sel


def page_start():
    """Every page calls this first: state defaults, widget sync, the sidebar."""
    if not st.session_state.get("_via_app"):
        # Opened by a deep link before app.py ever ran on this server, Streamlit runs the
        # page from its automatic pages/ list, without app.py's navigation and layout
        # (that list stays hidden: client.showSidebarNavigation = false): go through
        # app.py, which installs them and then opens the page asked for.
        st.session_state["_deep_link"] = Path(sys._getframe(1).f_globals.get(
            "__file__", "data.py")).name
        st.switch_page("app.py", query_params=st.query_params.to_dict())
    session_start()
    init_state()
    keep_widget_state()
    sync_from_widgets()
    autosave()
    sidebar()
    restore_banner()


def toggle_exclusion(trip, widget_key):
    """Checkbox callback: include or exclude one observation."""
    s = st.session_state
    cur = [tuple(e) for e in s["exclusions"] if tuple(e) != tuple(trip)]
    if s.get(widget_key):
        cur.append(tuple(trip))
    s["exclusions"] = sorted(cur)


def set_exclusions(trips, on: bool):
    """Button callback: exclude (or include) all the given observations."""
    s = st.session_state
    trips = {tuple(t) for t in trips}
    cur = {tuple(e) for e in s["exclusions"]}
    s["exclusions"] = sorted(cur | trips if on else cur - trips)
    for t in trips:
        s.pop(f"w_ex_{t[0]}_{t[1]}_{t[2]}", None)


def dataset():
    s = st.session_state
    return _load(s["ds_key"], s["ds_files"])


# ---------------------------------------------------------------------------------------
# Instrument files (laser runs, step gauges): kept as (kind, file name, text) triples in
# ``st.session_state["instruments"]``, like the dataset, so the project file restores them
# ---------------------------------------------------------------------------------------

def instruments_key(items) -> str:
    """Key of a list of instrument files; "" for none."""
    if not items:
        return ""
    h = hashlib.sha1()
    for kind, name, text in items:
        h.update(f"{kind}\0{name}\0".encode() + text.encode() + b"\0")
    return h.hexdigest()[:16]


@st.cache_resource(show_spinner=False, max_entries=16)
def _read_instruments(key: str, _items) -> tuple:
    return tuple(read_instrument(io.StringIO(text), kind, name=name)
                 for kind, name, text in _items)


def read_instrument_file(kind: str, name: str, text: str):
    """Validate one instrument file with the core reader (raises DataError naming file,
    row and column)."""
    return read_instrument(io.StringIO(text), kind, name=name)


def set_instruments(items):
    """Make ``items`` ((kind, name, text) triples) the instrument files of the session."""
    s = st.session_state
    s["instruments"] = [tuple(i) for i in items]
    s["instruments_key"] = instruments_key(s["instruments"])


def check_instruments(items, ds=None) -> None:
    """Raise DataError unless every instrument file of ``items`` reads and lies within the
    machine of ``ds`` (default: the current dataset): the rigid fit builds their rows."""
    data = [read_instrument_file(*i) for i in items]
    if data:
        core_fit(dataset() if ds is None else ds, "rigid", instruments=data)


def remove_instrument(index: int):
    """Button callback: remove the ``index``-th instrument file."""
    items = list(st.session_state.get("instruments") or [])
    if 0 <= index < len(items):
        kind, name, _ = items.pop(index)
        set_instruments(items)
        st.session_state["flash"] = ("success", f"Removed {name} "
                                                f"({INSTRUMENT_NAMES.get(kind, kind)}).")


def instrument_data(key: FitKey | None = None) -> tuple:
    """The session's instrument readings (``LaserRun``, ``StepGauge`` ...) for a fit
    ``key`` (none when the key has none)."""
    s = st.session_state
    items = s.get("instruments") or []
    ikey = instruments_key(items)
    if not items or (key is not None and key.instruments != ikey):
        return ()
    return _read_instruments(ikey, items)


# ---------------------------------------------------------------------------------------
# Cached core wrappers (hashable inputs; the dataset travels as an unhashed argument)
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FitKey:
    """What decides one fit of the app, built by keyword from the session (:func:`fit_key`):
    the cache key of every cached core call, hashable, never indexed by position."""

    data: str
    """Key of the dataset files (:func:`files_key`)."""
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
        """Keyword arguments of ``cmm_core.fit.fit`` (and ``diagnose``) but the spec."""
        return {"order": self.order, "plate": None if self.plate == "auto" else self.plate,
                "sigma_um": self.sigma_um,
                "positions": None if self.positions is None else list(self.positions),
                "probes": None if self.probes is None else list(self.probes),
                "exclude": list(self.exclusions)}

    def with_spec(self, spec: str) -> FitKey:
        """The same fit of another model (the rigid placements, a history step)."""
        return replace(self, spec=spec)


@st.cache_data(show_spinner=False, max_entries=256)
def cached_fit(key: FitKey, _ds, _instruments=()):
    """The fit ``key`` names, with ``_instruments`` (the readings ``key.instruments``
    names) fitted jointly."""
    return core_fit(_ds, key.spec, instruments=list(_instruments) or None,
                    **key.fit_kwargs())


def fit_of(key: FitKey):
    """``cached_fit`` of ``key`` with the current dataset and the instruments it names."""
    return cached_fit(key, dataset(), instrument_data(key))


@st.cache_data(show_spinner=False, max_entries=16)
def cached_outliers(key, _ds):
    return detect_outliers(_ds)


def fit_key(spec=None, *, instruments: bool = True) -> FitKey:
    """The :class:`FitKey` of the session's fit (of ``spec`` when given; without the
    instrument files when ``instruments`` is false)."""
    s = st.session_state
    return FitKey(
        data=s["ds_key"], spec=spec or s["spec"], order=int(s["order"]), plate=s["plate"],
        sigma_um=float(s["sigma_um"]),
        positions=tuple(s["positions"]) if s["positions"] is not None else None,
        probes=tuple(s["probes"]) if s["probes"] is not None else None,
        exclusions=tuple(tuple(e) for e in s["exclusions"]),
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


def current_fit(spec=None, *, show_error=True, instruments: bool = True):
    """The fit of the current (or a given) model, with the session's instrument files
    unless ``instruments`` is false, or None with a message."""
    try:
        return fit_of(fit_key(spec, instruments=instruments))
    except Exception as exc:  # noqa: BLE001
        if show_error:
            st.error(f"The fit failed: {describe_error(exc)}")
        return None


@st.cache_data(show_spinner=False, max_entries=64)
def cached_uncertainty(key: FitKey, n_random, seed, _result):
    from cmm_core.model import evaluate
    return evaluate(_result, n_random=n_random, seed=seed)


@st.cache_resource(show_spinner=False, max_entries=64)
def cached_gp_discrepancy(key: FitKey, _result) -> float:
    """GP discrepancy of a fit (µm): the structure a GP over its residuals finds, with the
    model's own design matrix as basis (``diagnose.discrepancy_gp``)."""
    from cmm_core.diagnosis import discrepancy_gp

    return float(discrepancy_gp(_result, restarts=1).rms_amplitude_um)


# ---------------------------------------------------------------------------------------
# Diagnosis (cmm_core.diagnose: score test, refit of the best, ΔBIC, F-test, aliases)
# ---------------------------------------------------------------------------------------

def run_diagnosis(show_progress: bool = False):
    """The current fit, its ranked candidates as a list of dicts (best first) and the
    core's plain-language conclusion (with aliases and skipped candidates).

    Each dict: effect, title, explanation, aliases, separate_by, rms_um, chi2_dof,
    delta_chi2, delta_bic, p_value, n_params, significant, confirmed, is_verdict (the
    core's verdict: none when the baseline did not converge), signature_um (n, 3).
    With ``show_progress`` a progress bar follows the scoring of the candidates. The
    fourth item holds the verdict, the σ check, the certificate check and where the
    residual lives (``Diagnosis.to_dict``).
    """
    base = current_fit()
    if base is None:
        return None, None, "", {}
    key = fit_key()
    return (base, *_cached_core_diagnosis(key, dataset(), instrument_data(key),
                                          show_progress))


@st.cache_data(show_spinner="Running the diagnosis…", max_entries=32)
def _cached_core_diagnosis(key: FitKey, _ds, _instruments=(), _show_progress=False):
    from cmm_core.diagnosis import diagnose

    kw = key.fit_kwargs()
    # with instruments, every model the diagnosis scores or refits carries their rows
    data = A.with_instruments(_ds, _instruments, positions=kw["positions"],
                              probes=kw["probes"], exclude=kw["exclude"])
    # created inside the cached function so that a cache replay can recreate it
    bar = st.progress(0.0, text="Scoring candidate effects…") if _show_progress else None

    def report(frac, text):
        if bar is not None:
            bar.progress(frac, text=text)

    d = diagnose(data, baseline=key.spec, progress=report, **kw)
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
    info = {k: full[k] for k in ("verdict", "sigma_check", "certificate", "where",
                                 "blunders", "cannot_see", "evidence")}
    return rows, rep.diagnosis_conclusion(d), info


def history_rows() -> list:
    """The diagnosis history with each step's fit quality (computed from cached fits)."""
    s = st.session_state
    if not s["history"]:
        s["history"] = [{"spec": s["spec"], "change": "baseline"}]
    out = []
    for h in s["history"]:
        r = current_fit(h["spec"], show_error=False)
        gp = None
        if r is not None and s.get("hist_gp"):
            try:
                gp = cached_gp_discrepancy(fit_key(h["spec"]), r)
            except Exception:  # noqa: BLE001
                gp = None
        row = ({"spec": h["spec"], "change": h["change"], "rms_um": None, "chi2_dof": None,
                "bic": None, "n_params": None} if r is None else
               {**r.history_row(h["change"]), "spec": h["spec"]})
        out.append({**row, "gp_amplitude_um": None if gp is None else round(gp, 3)})
    return out


chi2_test_numbers = rep.chi2_test_numbers  # one definition: the report's


def misfit_banner(r) -> None:
    """Next to any uncertainty: the fit's χ² test, and when it fails, by how much the
    σ-based values understate the observed scatter (Birge ratio)."""
    if r is None:
        return
    val, dof, note = chi2_test_numbers(r)
    if r.fails_chi2_test:
        st.warning(f"The model fails its χ² test: χ²/dof {val:.2f} at {dof} degrees "
                   f"of freedom (p = {r.chi2_p_value:.2g}){note}. Uncertainties from σ = "
                   f"{r.sigma_um:.3g} µm alone are too small by the Birge ratio "
                   f"×{r.birge_ratio:.2f}; multiply them by it (inflated values are shown "
                   "beside them where listed). Neither is trustworthy until the diagnosis "
                   "explains the misfit.")
    else:
        st.caption(f"χ² test passed: χ²/dof {val:.2f} at {dof} degrees of freedom "
                   f"(p = {r.chi2_p_value:.2g}){note}; the σ-based uncertainties stand.")


def set_sigma(sigma_um: float):
    """Button callback: use ``sigma_um`` as the repeatability (widget and state)."""
    s = st.session_state
    s["sigma_um"] = s["w_sigma_um"] = float(min(max(sigma_um, 0.01), 100.0))


def set_plate(mode: str):
    """Button callback: plate geometry ``fixed``, ``prior`` or ``free``."""
    s = st.session_state
    s["plate"] = s["w_plate"] = mode


def spec_tokens(spec: str) -> list:
    """The tokens of a model spec as the user wrote them (blanks around commas dropped)."""
    return [t.strip() for t in str(spec or "").split(",") if t.strip()] or ["rigid"]


def spec_text(spec: str) -> str:
    """The spec as written, one blank after each comma: a table cell wraps there rather
    than inside a name (the blank parses the same)."""
    return ", ".join(spec_tokens(spec))


def spec_expansion(spec: str, order: int | None = None) -> str | None:
    """The explicit form of ``spec`` (``ModelSpec.to_string``) when it differs from what was
    written (``translational,squareness`` names nine functions), else None."""
    try:
        full = parse_spec(spec, default_order=int(order or st.session_state.get("order", 2)))
    except ValueError:
        return None
    full = full.to_string()
    return None if spec_tokens(full) == spec_tokens(spec) else full


def spec_markup(spec: str, order: int | None = None) -> str:
    """HTML (for ``st.markdown(..., unsafe_allow_html=True)``): the spec as the user wrote
    it, breakable after each comma and never inside a name, the full text and its
    expansion on hover."""
    toks = spec_tokens(spec)
    hover = ",".join(toks)
    full = spec_expansion(spec, order)
    if full:
        hover += f"\n= {full}"
    body = ",<wbr>".join(html.escape(t) for t in toks)
    return (f'<code class="cmm-spec" title="{html.escape(hover, quote=True)}" '
            'style="white-space: normal; word-break: normal; overflow-wrap: normal">'
            f"{body}</code>")


def compose_spec(spec: str, token: str, order: int) -> str:
    """``spec`` with ``token`` applied, in the user's own words: the token is appended
    (shorthand such as ``translational`` stays as written, it is not expanded into nine
    names); a token that undoes an earlier one (``-plate_sag`` after ``plate_sag``)
    removes it instead when the model is the same either way. Raises ValueError for a
    token the grammar refuses."""
    toks = [t for t in spec_tokens(spec) if t.lower() != "rigid"]
    new = ",".join([*toks, token.strip()])
    target = parse_spec(new, default_order=order)
    tok = token.strip().lower()
    undo = tok[1:] if tok.startswith("-") else f"-{tok}"
    for i in range(len(toks) - 1, -1, -1):
        if toks[i].lower() == undo:
            short = ",".join(toks[:i] + toks[i + 1:]) or "rigid"
            if parse_spec(short, default_order=order) == target:
                return short
            break
    return new


def apply_change(token: str):
    """Button callback: apply a model token (add/remove an effect) and record it."""
    s = st.session_state
    if not s["history"]:
        s["history"] = [{"spec": s["spec"], "change": "baseline"}]
    try:
        new = compose_spec(s["spec"], token, int(s["order"]))
    except ValueError as exc:
        s["flash"] = ("error", str(exc))
        return
    s["spec"] = new
    s["history"] = [*s["history"], {"spec": new, "change": token}]
    s.pop("w_spec", None)
    s["flash"] = ("success", f"Model is now {new}")


def apply_selected(widget_key: str):
    """Button callback: apply the token currently chosen in a selectbox."""
    tok = st.session_state.get(widget_key)
    if tok:
        apply_change(tok)


def undo_change():
    s = st.session_state
    if len(s["history"]) > 1:
        s["history"] = s["history"][:-1]
        s["spec"] = s["history"][-1]["spec"]
        s.pop("w_spec", None)


def flash():
    """Show the one-off message of the last action in a slot that is always present, so the
    elements below keep their place (a tab set below would otherwise reset)."""
    slot = st.container()
    msg = st.session_state.pop("flash", None)
    if msg:
        getattr(slot, msg[0])(msg[1])


# ---------------------------------------------------------------------------------------
# Widgets bound to canonical state
# ---------------------------------------------------------------------------------------

def bind(state_key: str, widget_fn, label: str, **kwargs):
    """A widget (``w_<state_key>``) initialised from and written back to the state."""
    wk = "w_" + state_key
    if wk not in st.session_state:
        st.session_state[wk] = st.session_state[state_key]
    val = widget_fn(label, key=wk, **kwargs)
    st.session_state[state_key] = val
    return val


# ---------------------------------------------------------------------------------------
# Sidebar and page header
# ---------------------------------------------------------------------------------------

def sidebar():
    s = st.session_state
    sb = st.sidebar
    sb.markdown("### Current analysis")
    try:
        ds = dataset()
    except Exception as exc:  # noqa: BLE001
        sb.error(describe_error(exc))
        return
    n_ex = len(s["exclusions"])
    sb.markdown(f"**Dataset:** {ds.name}  \n{len(ds.meas)} probed ball centres"
                + (f" ({n_ex} excluded)" if n_ex else "")
                + f", {len(ds.positions)} positions, {len(ds.probes)} probes")
    files = s.get("ds_files", {})
    sb.caption(f"Setup: {files.get('setup_source', 'setup of the dataset')}.  \n"
               f"Certificate: {files.get('certificate_source') or _cert_words(ds)}."
               + (f"  \nCertificate uncertainty: {ds.certificate.u_source}."
                  if ds.certificate is not None else "")
               + ("  \nInstruments fitted with the plate: " + ", ".join(
                   f"{n} ({INSTRUMENT_NAMES.get(k, k)})" for k, n, _ in s["instruments"])
                  + "." if s.get("instruments") else ""))
    if s.get("reset_note"):
        sb.caption("New dataset, settings reset to its defaults: "
                   + "; ".join(s["reset_note"]) + ".")
    sb.markdown(f"**Model:** {spec_markup(s['spec'])}  \norder {s['order']}, plate "
                f"{s['plate']}, σ = {s['sigma_um']:g} µm", unsafe_allow_html=True)
    r = current_fit(show_error=False)
    if r is None:
        sb.warning("No fit for these settings.")
    else:
        c1, c2 = sb.columns(2)
        c1.metric("RMS (µm)", f"{r.rms_um:.3f}")
        c2.metric("χ²/dof", f"{r.chi2_dof:.2f}")
        if r.fails_chi2_test:
            sb.warning(f"Fails the χ² test (p = {r.chi2_p_value:.2g}, "
                       f"{chi2_test_numbers(r)[1]} dof): "
                       f"uncertainties from σ are too small by ×{r.birge_ratio:.2f}.")
        status = {"converged": "converged", "max_iterations": "NOT converged",
                  "failed": "fit failed"}.get(r.status, r.status)
        sb.caption(f"{status}; {r.n_obs} observations in the fit; rank {r.rank}"
                   + (f"; {len(r.null_combinations)} undetermined combination(s) of "
                      f"{len(r.unidentifiable)} parameters" if r.unidentifiable else ""))
    if n_ex:
        sb.caption(f"{n_ex} observation(s) excluded as outliers.")
    pending = pending_outliers(ds)
    if pending:
        sb.warning(f"{len(pending)} flagged outlier(s) still in the fit (see Data).")
    if s.get("save_error"):
        sb.caption(f"Not kept for a reload: {s['save_error']} (the last good state is).")


def _cert_words(ds) -> str:
    if ds.certificate is None:
        return "none (plate geometry self-calibrated)"
    return "given with the dataset"


def pending_outliers(ds) -> list:
    """Flagged outliers (position, probe, ball) that are still in the fit."""
    s = st.session_state
    try:
        flagged = cached_outliers(s["ds_key"], ds).exclusions
    except Exception:  # noqa: BLE001 - the flags are advice; the Data page shows errors
        return []
    done = {tuple(e) for e in s["exclusions"]}
    return [tuple(f) for f in flagged if tuple(f) not in done]

# ---------------------------------------------------------------------------------------
# Figures: plotly figure construction is slow (validation), so built figures are cached
# (cache_resource: shared objects, not copied; Streamlit only serialises them).
# ---------------------------------------------------------------------------------------

@st.cache_resource(show_spinner=False, max_entries=256)
def _cached_figure(kind: str, key: tuple, _builder, _args):
    return _builder(*_args)


def figure(kind: str, key: tuple, builder, *args):
    """``builder(*args)``, cached under ``(kind, key)``; key must identify the inputs."""
    return _cached_figure(kind, key, builder, args)


def beside_map(fig):
    """A map (``report.fig_surface_grid``) drawn in a column: the colour bar right beside
    the map (the equal-scale axes shrink the plot area; anchored right, it sits next to
    the bar) and slim."""
    fig.update_traces(colorbar={"thickness": 14, "xpad": 4, "len": 0.9},
                      selector={"type": "heatmap"})
    fig.update_xaxes(constraintoward="right")
    fig.update_layout(margin={"l": 60, "r": 10, "t": 60, "b": 50})
    return fig


_DF_PLACEHOLDER = "placeholder" in inspect.signature(st.dataframe).parameters


def dataframe(data, **kwargs):
    """``st.dataframe`` showing missing values as "—" rather than "None" (a metrologist
    reads "None" as a value), where this Streamlit has the ``placeholder`` option."""
    if _DF_PLACEHOLDER:
        kwargs.setdefault("placeholder", "—")
    return st.dataframe(data, **kwargs)

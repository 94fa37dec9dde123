"""The app's session state: the canonical keys (``spec``, ``order`` ...) and everything
that changes them: the dataset (the core's ``DataSources`` under ``sources``, where they
came from under ``ds_origin``), the instrument files, exclusions, σ, the
plate mode and the model spec with its history. Widgets use keys prefixed ``w_`` and are
re-initialised from the canonical state whenever a page renders them, so values survive
page switches."""

from __future__ import annotations

import hashlib
import io

import streamlit as st

from cmm_core import analysis as A
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


# settings a new dataset starts from (the model list, selections and exclusions too)
RESET_ON_NEW_DATASET = ("spec", "order", "plate", "sigma_um")


_SETTING_NAMES = {"spec": "model", "order": "order", "plate": "plate geometry",
                  "sigma_um": "σ (µm)"}


@st.cache_data(show_spinner=False, max_entries=8)
def load_sources(key: str, _sources: A.DataSources):
    """The dataset of ``_sources`` (``A.load_sources``), cached under their ``key``
    (``A.sources_key``)."""
    return A.load_sources(_sources)


def set_dataset(sources: A.DataSources, origin: dict | None = None, *,
                reset_model: bool = True):
    """Make ``sources`` the current dataset (raises DataError when it does not load, and
    nothing changes). ``origin``: ``{"kind", "setup_source", "certificate_source"}``, how
    the sidebar states where the files came from."""
    key = A.sources_key(sources)
    load_sources(key, sources)  # validate first: a bad upload keeps the old dataset
    st.session_state["sources"] = sources
    st.session_state["ds_origin"] = dict(origin or {})
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


def loaded(message: str) -> None:
    """After any successful load: the old upload report no longer applies; the message is
    shown at the top of the page after the rerun this starts."""
    st.session_state.pop("upload_report", None)
    st.session_state.pop("instrument_errors", None)
    st.session_state["flash"] = ("success", message)
    st.rerun()


def reset_widgets():
    for k in list(st.session_state.keys()):
        if str(k).startswith("w_"):
            del st.session_state[k]


def init_state():
    """Defaults on first run; the thesis data loaded so a first-time user sees a model."""
    for k, v in DEFAULTS.items():
        if k not in st.session_state:
            st.session_state[k] = list(v) if isinstance(v, list) else v
    if "sources" not in st.session_state:
        set_dataset(A.thesis_sources(), A.THESIS_ORIGIN)


KEEP_PREFIXES = ("sim_", "w_gp_")


KEEP_KEYS = ("hist_gp", "w_mpe_u", "w_u_npts", "w_u_seed",  # the report reads these
             "w_kin_tab", "w_diag_tab", "data_tab", "chk_tab",  # the open tabs, as left
             # the sidebar's figure switch; it and the Data page's tab are no w_ keys, so a
             # new dataset (reset_widgets) leaves them as they are
             "interactive_plots")


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


HAND_EXCLUSIONS = "exclusions edited by hand"
"""The history step of exclusions ticked one by one (consecutive ticks are one step)."""


def _exclusions_step(new: list, change: str) -> None:
    """Make ``new`` the exclusions and record it as a step of the diagnosis history (issue
    41: excluding outliers is a step, its fit beside the others), every step holding the
    exclusions it was fitted with."""
    s = st.session_state
    old = [list(e) for e in s["exclusions"]]
    hist = held_steps()
    step = {"spec": s["spec"], "change": change, "exclusions": [list(e) for e in new]}
    if change == HAND_EXCLUSIONS and hist[-1]["change"] == HAND_EXCLUSIONS:
        hist[-1] = step  # a run of ticks is one step
        if len(hist) > 1 and _same(hist[-2]["exclusions"], new):
            hist.pop()  # ticked and unticked again: no step
    elif not _same(old, new):
        hist.append(step)
    s["history"] = hist
    s["exclusions"] = sorted(tuple(e) for e in new)


def _same(a, b) -> bool:
    """Two lists of exclusions hold the same observations."""
    return sorted(map(tuple, a)) == sorted(map(tuple, b))


def held_steps() -> list:
    """The session's history steps (a baseline when there are none), each holding the
    exclusions it is fitted with: a step of an older record that has none gets the
    exclusions in force now, which it was being fitted with, before they change."""
    s = st.session_state
    now = [list(e) for e in s["exclusions"]]
    hist = [dict(h) for h in s["history"]] or [{"spec": s["spec"], "change": "baseline"}]
    for h in hist:
        h.setdefault("exclusions", now)
    return hist


def toggle_exclusion(trip, widget_key):
    """Checkbox callback: include or exclude one observation."""
    s = st.session_state
    cur = [tuple(e) for e in s["exclusions"] if tuple(e) != tuple(trip)]
    if s.get(widget_key):
        cur.append(tuple(trip))
    _exclusions_step(sorted(cur), HAND_EXCLUSIONS)


def set_exclusions(trips, on: bool):
    """Button callback: exclude (or include) all the given observations, a step of the
    history ("exclude 3 flagged outlier(s)")."""
    s = st.session_state
    trips = {tuple(t) for t in trips}
    cur = {tuple(e) for e in s["exclusions"]}
    new = cur | trips if on else cur - trips
    n = len(new - cur) if on else len(cur - new)
    _exclusions_step(sorted(new), f"{'exclude' if on else 'include'} {n} flagged "
                                  f"outlier{'s' if n != 1 else ''}"
                                  + ("" if on else " again"))
    _reset_exclusion_boxes(trips)


def _reset_exclusion_boxes(trips) -> None:
    """The Data page's checkboxes of ``trips`` follow the exclusions at their next draw."""
    for t in trips:
        st.session_state.pop(f"w_ex_{t[0]}_{t[1]}_{t[2]}", None)


def dataset():
    s = st.session_state
    return load_sources(s["ds_key"], s["sources"])


def instruments_key(items) -> str:
    """Key of a list of instrument files; "" for none."""
    if not items:
        return ""
    h = hashlib.sha1()
    for kind, name, text in items:
        h.update(f"{kind}\0{name}\0".encode() + text.encode() + b"\0")
    return h.hexdigest()[:16]


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
    try:
        new = compose_spec(s["spec"], token, int(s["order"]))
    except ValueError as exc:
        s["flash"] = ("error", str(exc))
        return
    s["spec"] = new
    s["history"] = [*held_steps(), {"spec": new, "change": token,
                                     "exclusions": [list(e) for e in s["exclusions"]]}]
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
        gone = s["history"][-1]
        s["history"] = s["history"][:-1]
        s["spec"] = s["history"][-1]["spec"]
        if "exclusions" in s["history"][-1]:  # an exclusion step undone: the ones before
            before = {tuple(e) for e in s["exclusions"]}
            s["exclusions"] = sorted(tuple(e) for e in s["history"][-1]["exclusions"])
            _reset_exclusion_boxes(before | {tuple(e) for e in gone.get("exclusions", [])})
        s.pop("w_spec", None)

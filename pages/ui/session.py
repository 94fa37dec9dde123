"""An analysis that survives a reload: the URL's session id, the project file kept for it
in a per-user folder (``cmm_core.analysis.sessions``), and restoring an analysis record,
from that file or from a project file the user uploads."""

from __future__ import annotations

import hashlib

import streamlit as st

from cmm_core import analysis as A
from pages.ui.calls import describe_error, safe
from pages.ui.state import (
    check_instruments,
    init_state,
    load_sources,
    reset_widgets,
    set_dataset,
    set_instruments,
)

SESSION_CHOICES = {"spec": "spec", "order": "order", "plate": "plate",
                   "sigma_um": "sigma_um", "positions": "positions", "probes": "probes",
                   "exclusions": "exclusions", "history": "history", "diagnose": "diag_on",
                   "exclude_outliers": "exclude_outliers", "magnification": "magnification",
                   "uncertainty_points": "w_u_npts", "uncertainty_seed": "w_u_seed",
                   "gp_kernel": "w_gp_kernel", "mpe_u_source": "w_mpe_u"}
"""Each field of the analysis record and the session key (canonical or widget) holding it:
the app's keys stay in the app, the core reads record fields only."""


def session_record(state) -> A.AnalysisRecord:
    """The analysis record of an app session (``st.session_state``, or a mapping with its
    keys): the Export page's downloads, the report and the session kept for a reload."""
    choices = {field: state.get(key) for field, key in SESSION_CHOICES.items()}
    choices["gp_mean"] = state.get("w_gp_mean") if state.get("w_report_gp") else None
    return A.record_from_sources(state["sources"], state.get("instruments") or (),
                                 **choices)


def restore_record(record, source: str) -> str:
    """Make the analysis ``record`` (an :class:`cmm_core.analysis.AnalysisRecord`, read from
    a project file or a saved session) the current one: data, instruments, model, σ,
    exclusions, history and the other choices. Raises with nothing changed when its data
    do not load, its exclusions name observations the data lack, or an instrument file
    does not fit the machine. Returns a note for the user ("" when there is nothing to
    add); ``source`` says where it came from ("the project file x.json")."""
    A.refuse_paths(record, source)  # an upload never makes the server read a path
    d = record.data
    # the files' text is read once, here, and travels with the session (no file is read
    # again later); tables from other software keep their source and mapping; the
    # instruments are the session's own list, checked below against the new data
    sources = A.inline_sources(d)
    # the files' own names with where they came from (issue 41: a restored analysis said
    # "from the saved session" and lost the names of the files the user had uploaded)
    origin = {"kind": "project", "setup_source": f"{sources.setup.name}, from {source}",
              "certificate_source": None if sources.certificate is None
              else f"{sources.certificate.name}, from {source}"}
    new_ds = load_sources(A.sources_key(sources), sources)
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
    # what analysis.run leaves out and the σ it uses, so the app fits what the report does
    excl, flagged = A.record_exclusions(record, new_ds)
    # each history step with the exclusions the report fits it with (refused, before
    # anything changes, when a step's own name observations the data lack)
    step_excl = A.history_exclusions(record, new_ds, flagged)
    sigma = (safe(A.resolve_sigma, record, new_ds, A.load_instruments(record), excl,
                  what="Estimating σ") if record.sigma_um == "auto"
             else A.resolve_sigma(record, new_ds))
    set_dataset(sources, origin)
    s = st.session_state
    for k in ("spec", "order", "plate", "magnification", "exclude_outliers"):
        s[k] = getattr(record, k)
    s["positions"] = None if record.positions is None else list(record.positions)
    s["probes"] = None if record.probes is None else list(record.probes)
    s["exclusions"] = [list(e) for e in excl]
    s["diag_on"] = bool(record.diagnose)
    s["history"] = [{"spec": spec, "change": change,
                     **({} if own is None else {"exclusions": [list(e) for e in own]})}
                    for (spec, change, *_), own in zip(record.history, step_excl,
                                                       strict=True)]
    if s["history"] and s["history"][-1]["spec"] != s["spec"]:
        # the model was edited by hand after the last recorded step
        s["history"].append({"spec": s["spec"], "change": "edited by hand"})
    s["reset_note"] = []  # the analysis's own settings, not defaults
    names = [f.name for f in sources.files]
    note = (f" Data: {sources.name} ({', '.join(names[:6])}"
            + (f" and {len(names) - 6} more file(s)" if len(names) > 6 else "") + ").")
    if len(excl) > len(record.exclusions):
        note += (f" Its outlier rule excludes the {len(excl) - len(record.exclusions)} "
                 "flagged observation(s), as the report does.")
    if record.sigma_um != "auto":
        s["sigma_um"] = sigma["value_um"]
    elif sigma is None:
        s["sigma_um"] = 0.5
        note += (" Its σ is 'auto' and could not be estimated: 0.5 µm is used; set it in "
                 "the sidebar.")
    else:  # a record written by the command line: σ as analysis.run estimates it
        s["sigma_um"] = sigma["value_um"]
        note += (f" Its σ is 'auto': estimated from the data as {s['sigma_um']:.4g} ± "
                 f"{sigma['u_um']:.2g} µm ({sigma['method']}).")
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
    a new tab) restores it and says so; any other new session starts a new analysis with a
    new id from the server, saved once it differs from the defaults. An id the server has
    not saved is never adopted (session fixation: whoever sent a link with an id of their
    choosing could later open the analysis of whoever used it), and the note says a new
    analysis was started. No server path is shown. The id is put back into the URL on
    every run, because moving between pages clears query parameters."""
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
                s["restore_note"] = ("error", f"The saved analysis {saved.session_id} could "
                                     f"not be restored ({describe_error(exc)}); a new "
                                     "analysis was started on the thesis data. Its file is "
                                     "kept on the server.")
            else:
                s["restore_note"] = ("info", f"Restored from the saved analysis "
                                     f"{saved.session_id} (saved {saved.saved_text}).{note}")
                s["saved_fingerprint"] = session_fingerprint()
                s["saved_digest"] = saved.digest  # what the next save expects on disk
        else:
            if asked:
                s["restore_note"] = ("info", "The link names no analysis saved on this "
                                     "server: a new analysis was started on the thesis "
                                     "data, with an id of its own (see the address bar).")
            # a new analysis is saved only once it differs from the defaults
            init_state()
            s["saved_fingerprint"] = session_fingerprint()
            s["saved_digest"] = None  # no file yet: the first save expects none
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
    # the files by their keys, then every key session_record reads
    keys = ("ds_key", "instruments_key", *SESSION_CHOICES.values(), "w_gp_mean",
            "w_report_gp")
    return hashlib.sha1(repr([s.get(k) for k in keys]).encode()).hexdigest()


def autosave():
    """Write the analysis to its session file when it changed since the last write."""
    s = st.session_state
    fp = session_fingerprint()
    if s.get("saved_fingerprint") == fp or "sources" not in s:
        return
    try:
        text = A.record_to_project_json(session_record(s))
        s["saved_path"] = str(session_store().save(s["session_id"], text,
                                                   expected=s.get("saved_digest", True)))
        s["saved_digest"] = A.text_digest(text)
        s.pop("save_error", None)
    except A.SessionConflict as exc:  # another tab saved: this one is not written over it
        s["save_conflict"] = str(exc)
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

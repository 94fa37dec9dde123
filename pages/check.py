"""Interim check against a stored calibration, and a machine's calibration history."""

import dataclasses
import io
import json
from datetime import date
from pathlib import Path

import numpy as np
import pandas as pd
import streamlit as st

from cmm_core import analysis as A
from cmm_core import export as ex
from cmm_core import io as cio
from cmm_core import monitor as mon
from cmm_core.io import SAMPLE_DIR
from cmm_core.model import INSTRUMENT_KINDS, read_instrument
from cmm_core.units import P_FLOOR, p_text
from cmm_core.units import label as unit_label
from pages.ui import cached, calls, state, widgets

st.title("Interim check")
st.write("Between calibrations: does the machine still behave as its stored calibration "
         "says, and if not, what changed (docs/monitoring.md)? And how has it changed over "
         "its calibrations?")

HISTORY = SAMPLE_DIR / "history"
SAMPLE_CHECKS = {"after a crash (2025-02-10, four placements)": "check_2025-02-10_after_crash",
                 "quiet (2024-06-17, one placement)": "check_2024-06-17"}
SAMPLE_MODEL = "calibration_2024-03-04.json"
# the check tab's choices as a session starts: a value changed from these keeps the tab
# drawn while the History is looked at (widgets.held)
CHECK_DEFAULTS = {"chk_src": "Sample history", "chk_sample": next(iter(SAMPLE_CHECKS)),
                  "chk_alpha": 0.05, "chk_family": 0.05, "chk_mpe": "0.6,600",
                  "chk_k": 2.0, "chk_kind": next(iter(INSTRUMENT_KINDS)),
                  "chk_stored": "This analysis's fit"}


def _model(name: str, text: str):
    """The stored model as ``analysis.load_stored_model`` reads one: a bad file is a
    one-line DataError naming it (not the JSON parser's bare "Expecting value")."""
    doc, _ = cio.read_json(text.encode("utf-8"), name)
    return ex.model_from_dict(doc, name=name)


@st.cache_data(show_spinner=False, max_entries=8)
def run_check(model_name, model_text, meas, setup, cert, alpha, family_alpha, mpe,
              instruments=(), coverage_factor=2.0):
    """The check, what changed, the new effect the diagnosis names and (with an MPE)
    conformity, as plain tables and dicts (``monitor.run_check``, E_n at
    ``coverage_factor``); ``meas`` None: the instruments (``(kind, name, bytes)``) alone
    are the check."""
    model = _model(model_name, model_text)
    data = None if meas is None else cio.load_dataset(
        [(io.BytesIO(meas[1]), meas[0])], io.BytesIO(setup[1]),
        None if cert is None else (io.BytesIO(cert[1]), cert[0]), name=meas[0])
    inst = [read_instrument(io.BytesIO(b), kind, name=n) for kind, n, b in instruments]
    out = mon.run_check(model, data, instruments=inst, alpha=alpha,
                        family_alpha=family_alpha, mpe=mpe, coverage_factor=coverage_factor)
    return (out.to_dict(), out.check.table, out.changes.table, ex.results_json(
        model, source=model_name, interim_check=out.results_section()), out.check.readings,
        mon.version_notes([model]))


@st.cache_data(show_spinner=False, max_entries=8)
def run_history(named_texts, dates, family_alpha):
    """The calibration history of the models, as plain tables and a dict (E_n at k = 2)."""
    models = [_model(n, t) for n, t in named_texts]
    h = mon.compare_calibrations(list(zip(models, dates, strict=True)),
                                 family_alpha=family_alpha)
    return h.to_dict(), h.changes, h.trend, h.map_change, mon.version_notes(models)


def _read(path: Path) -> tuple:
    return path.name, path.read_bytes()


# the sample history's calibrations and their dates (its model files state none); a
# comment, not a string: Streamlit's "magic" would write a bare string onto the page
SAMPLE_DATES = json.loads((HISTORY / "dates.json").read_text())


def _dataset_or_none():
    """The analysis's dataset, or None with the reason shown (the History tab stays
    drawn)."""
    try:
        return state.dataset()
    except Exception as exc:  # noqa: BLE001 - said here, not a traceback
        st.error(f"This analysis has no data that load ({calls.describe_error(exc)}): "
                 "choose a model file as the stored calibration.")
        return None


@st.cache_data(show_spinner=False, max_entries=8)
def _analysis_model_text(key, day: str, _result, _sources) -> str:
    """The fit of ``key`` as a model file's text with its provenance and the calibration
    date ``day``: made once per fit and date, so that the check cached on the model's
    text is not run again at every rerun (the provenance's time would change it)."""
    prov = dataclasses.replace(_sources.provenance(), calibration_date=day or None)
    return json.dumps(ex.model_to_dict(_result, prov))


def _analysis_model(ds, day: str) -> tuple[str, str] | None:
    """The current analysis's fit as the stored calibration: ``(name, model file text)``;
    None when there is no fit (the fit's error shown)."""
    r = cached.current_fit()
    if r is None:
        return None
    return (f"{ds.name} (this analysis)",
            _analysis_model_text(cached.fit_key(), day, r, st.session_state["sources"]))


def _stated_date(text: str) -> str | None:
    """The calibration date a model file states (its provenance), or None."""
    try:
        return (json.loads(text).get("provenance") or {}).get("calibration_date")
    except (ValueError, AttributeError):
        return None  # the check itself says what is wrong with the file


def _en_columns(table: pd.DataFrame, k: float) -> pd.DataFrame:
    """A table with its E_n columns headed with their coverage factor (``En`` ->
    ``E_n (k = 2)``, ``En_alone`` -> ``E_n alone (k = 2)``, ``rms_En`` -> ``RMS E_n (k =
    2)``...), so no E_n is shown without its k."""
    tag = f"(k = {k:g})"
    names = {"En": f"E_n {tag}", "En_alone": f"E_n alone {tag}",
             "En_x": f"E_n x {tag}", "En_y": f"E_n y {tag}", "En_z": f"E_n z {tag}",
             "rms_En": f"RMS E_n {tag}", "max_abs_En": f"largest |E_n| {tag}"}
    return table.rename(columns={c: n for c, n in names.items() if c in table})


# lazy tabs (issue 27): each tab's widgets, tables and figures are drawn only while it is
# open, so the page's first visit draws the check alone
t_check, t_hist = st.tabs(["Interim check", "History"], key="chk_tab", on_change="rerun",
                          bind="query-params")

with t_check:
    # drawn while open, or while its fields hold the user's files or choices (so that
    # looking at the history loses nothing)
    if t_check.open or widgets.held("chk_model", "chk_meas", "chk_setup", "chk_cert",
                                  "chk_inst", text=("chk_cal_date",),
                                  changed=CHECK_DEFAULTS):
        src = st.radio("Data", ["Sample history", "Upload files"], horizontal=True,
                       key="chk_src")
        files = None
        if src == "Sample history":
            which = st.selectbox("Sample check", list(SAMPLE_CHECKS), key="chk_sample")
            folder = HISTORY / SAMPLE_CHECKS[which]
            st.caption(f"Stored calibration: {SAMPLE_MODEL}, calibrated "
                       f"{SAMPLE_DATES[SAMPLE_MODEL]}.")
            files = ((SAMPLE_MODEL, (HISTORY / SAMPLE_MODEL).read_text()),
                     _read(folder / "measurements.csv"), _read(folder / "setup.json"),
                     _read(folder / "certificate.csv"), ())
        else:
            stored = st.radio("Stored calibration", ["This analysis's fit", "A model file"],
                              horizontal=True, key="chk_stored",
                              help="This analysis: the model fitted on the Kinematic model "
                                   "page to the data loaded now, as if it had been saved "
                                   "at its calibration. A model file: one a fit saved "
                                   "(Compensate and export, model file).")
            model_file = None
            ds_now = _dataset_or_none() if stored == "This analysis's fit" else None
            if ds_now is not None:
                day = st.text_input("Calibration date (YYYY-MM-DD)",
                                    ds_now.setup.calibration_date or "",
                                    key="chk_cal_date",
                                    help="The date of the calibration this fit stands for "
                                         "(the setup's calibration_date when it states "
                                         "one); recorded in the check's results.")
                try:
                    day = date.fromisoformat(day.strip()).isoformat() if day.strip() else ""
                except ValueError:
                    st.error(f"Calibration date: expected YYYY-MM-DD, got {day.strip()!r}.")
                    day = ""
                model_file = _analysis_model(ds_now, day)
                if model_file is not None:
                    st.caption(f"Stored calibration: {model_file[0]}, "
                               + (f"calibrated {day}." if day else
                                  "calibration date not stated."))
            elif stored == "A model file":
                up_model = st.file_uploader("Stored calibration (the model file a fit saved, "
                                            ".json)", type=["json"], key="chk_model")
                if up_model is not None:
                    model_file = (up_model.name,
                                  up_model.getvalue().decode("utf-8", "replace"))
                    day = _stated_date(model_file[1])
                    st.caption(f"Stored calibration: {up_model.name}, "
                               + (f"calibrated {day}." if day else "its file states no "
                                  "calibration date."))
            up_meas = st.file_uploader("New measurements (CSV)", type=["csv", "txt"],
                                       key="chk_meas")
            up_setup = st.file_uploader("Setup (JSON)", type=["json"], key="chk_setup")
            up_cert = st.file_uploader("Certificate (CSV)", type=["csv", "txt"], key="chk_cert")
            kind = st.selectbox("Instrument files are", list(INSTRUMENT_KINDS), key="chk_kind",
                                help="laser runs, step gauges or ball bars of the check "
                                     "(docs/instruments.md): alone, or beside the plate")
            up_inst = st.file_uploader("Instrument files (CSV, optional)", type=["csv", "txt"],
                                       accept_multiple_files=True, key="chk_inst")
            plate = all(u is not None for u in (up_meas, up_setup, up_cert))
            if model_file is not None and (plate or up_inst):
                files = (model_file,
                         (up_meas.name, up_meas.getvalue()) if plate else None,
                         (up_setup.name, up_setup.getvalue()) if plate else None,
                         (up_cert.name, up_cert.getvalue()) if plate else None,
                         tuple((kind, u.name, u.getvalue()) for u in up_inst or ()))
            else:
                st.info("Choose the stored calibration and upload the new data: the "
                        "measurements with their setup and the plate's certificate, or "
                        "instrument files, or both.")
        c1, c2, c3, c4 = st.columns(4)
        alpha = c1.number_input("Check level", 0.001, 0.2, 0.05, 0.01, key="chk_alpha",
                                help="at most the fraction of checks of an unchanged machine "
                                     "that say 'changed': half to the χ² test of all the new "
                                     "data, half to the fewest physical changes (Bonferroni)")
        family = c2.number_input("Family-wise level of the changes", 0.001, 0.2, 0.05, 0.01,
                                 key="chk_family", help="Holm over the parameters tested")
        mpe_text = c3.text_input("MPE 'A,D' (A µm + L/D)", "0.6,600", key="chk_mpe",
                                 help="empty: no conformity statement")
        k_en = c4.number_input("Coverage factor k of the E_n", 1.0, 3.0, 2.0, 0.5,
                               key="chk_k",
                               help="E_n = residual / (k u), ISO/IEC 17043: |E_n| ≤ 1 is "
                                    "the usual acceptance at k = 2; the tests do not "
                                    "depend on it")
        mpe = None
        if mpe_text.strip():
            try:
                mpe = mon.parse_mpe(mpe_text)  # the CLI's --mpe rule
            except ValueError as e:
                st.error(f"MPE: {e}.")
        if files is not None:
            out = calls.safe(run_check, files[0][0], files[0][1], files[1], files[2], files[3],
                             float(alpha), float(family), mpe, files[4], float(k_en),
                             what="Interim check")
            if out is not None:
                res, table, chg_table, results, readings, notes = out
                chk, chg, eff, conf = (res["check"], res["changes"], res["new_effects"],
                                       res["conformity"])
                k = float(chk["coverage_factor"])
                en = f"E_n (k = {k:g})"
                m1, m2, m3, m4 = st.columns(4)
                m1.metric("χ² / dof", f"{chk['chi2']:.1f} / {chk['dof']}")
                p = chk["p_value"]  # None: not computed (JSON null)
                m2.metric("p-value", "–" if p is None else f"{p:.3g}" if p >= P_FLOOR
                          else f"< {P_FLOOR:g}")
                m3.metric("Within 95 % intervals", f"{100 * chk['coverage_95']:.1f} %")
                worst = np.abs(np.concatenate([table["En"].to_numpy(float),
                                               readings["En"].to_numpy(float)]))
                worst = worst[np.isfinite(worst)]
                m4.metric(f"Largest |{en}|", f"{worst.max():.2f}" if worst.size else "–",
                          help="E_n = residual / (k u): the residual over its expanded "
                               "uncertainty (ISO/IEC 17043); |E_n| ≤ 1 is the usual "
                               "acceptance")
                # a changed machine is a result, not a failure of the page: a warning; a
                # partial check says what it could not see
                show = {"no change seen": st.success, "changed": st.warning}.get(
                    res["verdict"], st.info)
                show(f"**Verdict: {res['verdict']}.** {res['message']}")
                st.caption(chk["message"] + "".join(f"  \n{n}" for n in notes))
                if len(table):
                    with calls.guarded("E_n map"):
                        widgets.show(A.fig_en_map(table, "Normalised errors of the new "
                                                         f"observations: {en}, the largest "
                                                         "of x, y, z at each place",
                                                  coverage_factor=k),
                                     chart_key="chk_map")
                        st.caption(f"One marker per place on the machine's x, y: "
                                   f"{len(table)} observations (every stylus and placement) "
                                   "at the places shown, each coloured by its largest |E_n|; "
                                   "hover a marker for each observation there.")
                if chk.get("instruments"):
                    widgets.dataframe(_en_columns(pd.DataFrame(chk["instruments"]), k),
                                      hide_index=True, key="chk_instruments")
                    with st.expander(f"{en} of each instrument reading (file row)"):
                        widgets.dataframe(_en_columns(readings, k), hide_index=True,
                                          key="chk_readings")
                if eff is not None:
                    st.subheader("New effect")
                    st.write(eff["message"])
                    if eff["named"]:
                        widgets.dataframe(pd.DataFrame([
                            {"effect": e["effect"], "title": e["title"],
                             "size": "; ".join(f"{k} {v['value']:+.3g} ± {v['u']:.2g} "
                                               f"{unit_label(v['unit'])}"
                                               for k, v in e["fitted"].items()),
                             "p-value": p_text(e["p_value"]).removeprefix("p = "),
                             "confirmed": e["confirmed"]}
                            for e in eff["named"]]), hide_index=True, key="chk_effects")
                st.subheader("What changed")
                st.write(chg["message"])
                shown = chg_table[chg_table["tested"]].copy()
                widgets.dataframe(_en_columns(shown[[
                    "label", "unit", "change", "u_updated", "u_null", "En", "significant",
                    "change_alone", "u_change_alone", "En_alone", "significant_alone",
                    "resolved"]], k), hide_index=True, key="chk_changes")
                if chg["unseen"]:
                    with st.expander(f"{len(chg['unseen'])} combination(s) the new data cannot "
                                     "see"):
                        st.write("\n".join(
                            f"- {u}" + (f" ({n} combinations)" if n > 1 else "")
                            for u, n in mon.distinct_words(chg["unseen"])))
                        st.caption("A change of any of these would pass unnoticed. The "
                                   "combinations as weights are in the results document "
                                   "(unseen_combinations).")
                st.subheader("Conformity")
                if conf is None:
                    st.caption("Give the machine's MPE for a conformity statement.")
                else:
                    # a machine out of its specification is a result, not a failure of the
                    # page: a warning (st.error is for what went wrong)
                    (st.success if conf["statement"] == "conforms" else
                     st.warning if conf["statement"] == "does not conform" else st.info)(
                        f"**{conf['statement']}**: {conf['message']}")
                st.download_button(
                    "Download the results (JSON)", results, file_name=ex.download_name(Path(files[0][0]).stem,
                                              "interim_check_results.json"),
                    mime="application/json", key="chk_results",
                    help="the stored model's parameters and the section interim_check: the "
                         "test, each parameter's change with its uncertainty, the new effect, "
                         "conformity, each with its decision rule (docs/monitoring.md)")

with t_hist:
    if t_hist.open or widgets.held("hist_models", changed={"hist_src": "Sample history",
                                                         "hist_family": 0.05}):
        hsrc = st.radio("Calibrations", ["Sample history", "Upload model files"],
                        horizontal=True, key="hist_src")
        named, dates = None, None
        if hsrc == "Sample history":
            named = tuple((n, (HISTORY / n).read_text()) for n in SAMPLE_DATES)
            dates = tuple(SAMPLE_DATES.values())
            st.caption(", ".join(f"{n} ({d})" for n, d in SAMPLE_DATES.items()))
        else:
            ups = st.file_uploader("Calibrations (the model files fits saved, .json)", type=["json"],
                                   accept_multiple_files=True, key="hist_models")
            if ups:
                # each file's own date where its provenance states one
                stated = [_stated_date(u.getvalue().decode("utf-8", "replace")) or ""
                          for u in ups]
                table = st.data_editor(pd.DataFrame({"model": [u.name for u in ups],
                                                     "date": stated}),
                                       disabled=["model"], hide_index=True, key="hist_dates")
                if table["date"].str.strip().all():
                    named = tuple((u.name, u.getvalue().decode("utf-8", "replace")) for u in ups)
                    dates = tuple(table["date"].str.strip())
                else:
                    st.info("Give each model its calibration date (YYYY-MM-DD).")
        hfam = st.number_input("Family-wise level", 0.001, 0.2, 0.05, 0.01, key="hist_family",
                               help="Holm over every pair of consecutive calibrations and "
                                    "shared parameter")
        if named is not None:
            hout = calls.safe(run_history, named, dates, float(hfam), what="Calibration history")
            if hout is not None:
                summary, changes, trend, grid, notes = hout
                st.write(summary["message"])
                if notes:
                    st.caption("  \n".join(notes))
                widgets.dataframe(_en_columns(changes, summary["coverage_factor"]),
                                  hide_index=True, key="hist_changes")
                with calls.guarded("Trend"):
                    labels = list(dict.fromkeys(trend["label"]))
                    default = summary["significant"][0]["label"] if summary["significant"] \
                        else labels[0]
                    lab = st.selectbox("Parameter", labels, index=labels.index(default),
                                       key="hist_label")
                    tr = trend[trend["label"] == lab]
                    st.plotly_chart(A.fig_parameter_trend(trend, lab), key="hist_trend")
                with calls.guarded("Error map change"):
                    comp = st.selectbox("Component", ["x", "y", "z"], key="hist_comp")
                    st.plotly_chart(A.fig_error_map_change(grid, comp), key="hist_map")

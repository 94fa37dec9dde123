"""Plan page: evaluate, compare and design measurement plans before measuring.

Thin over ``cmm_core.plan``: the page gathers the plan file (the sample, an upload or an
edit), calls the core through cached wrappers and draws."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import streamlit as st

from cmm_core import analysis as A
from cmm_core.export import download_name
from cmm_core.model import distinct_words, rigid_removed_error_u
from cmm_core.plan import check_plans, design_fit, design_from_file, evaluate, read_plan
from cmm_core.units import label as unit_label
from pages.ui import calls, widgets
from pages.ui.panels.task import PLANS_DIR

SAMPLES = {"thesis layout: location 0 and all six": "thesis_plan.json",
           "thesis pool with a design target": "thesis_design.json"}


# --- cached thin wrappers (inputs: the plan text; outputs: plain records) --------------

@st.cache_data(show_spinner=False, max_entries=16)
def _plan_file(text: str):

    return read_plan(json.loads(text), name="plan", base_dir=PLANS_DIR)


@st.cache_data(show_spinner="Evaluating the plans from their design…", max_entries=16)
def evaluate_plans(text: str) -> list:
    """Every strategy of the plan, evaluated (JSON records)."""

    return [evaluate(p).to_dict() for p in _plan_file(text).strategies]


@st.cache_data(show_spinner="Designing…", max_entries=8)
def design_plan(text: str) -> dict:
    """The design section's result (JSON record)."""

    return design_from_file(_plan_file(text)).to_dict()


@st.cache_data(show_spinner="Computing the uncertainty map…", max_entries=32)
def u_map(text: str, name: str, z_mm: float, n: int = 25):
    """U (k = 1, rigid part removed) of the error over an XY grid at height ``z_mm``."""

    plan = next(p for p in _plan_file(text).strategies if p.name == name)
    r = design_fit(plan)
    rng = np.asarray(r.problem.obs.range_mm, float)
    gx, gy = np.linspace(0, rng[0], n), np.linspace(0, rng[1], n)
    X, Y = np.meshgrid(gx, gy)
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z_mm)])
    return gx, gy, rigid_removed_error_u(r, pts).reshape(n, n, 3)


def _download_name(text: str) -> str:
    """``<name>_<date>_plan.json`` from the plan's own name, by the downloads' one rule
    (``export.download_name``)."""
    try:
        name = str(json.loads(text).get("name") or "plan")
    except (json.JSONDecodeError, AttributeError):
        name = "plan"
    return download_name(name, "plan.json")


def _fmt(v, digits=3):
    return "—" if v is None else f"{v:.{digits}g}"


def proposal() -> dict | None:
    """The measurement the Diagnose page handed over as a plan ("Use as the plan"), for
    the current dataset: ``{data, name, outcome, text, fresh}``; None without one."""
    prop = st.session_state.get("plan_proposal")
    if not prop or prop.get("data") != st.session_state.get("ds_key"):
        return None
    return prop


def proposal_label(prop: dict) -> str:
    return f"measure next: {prop['name']} (from the Diagnose page)"


def _plan_text() -> str | None:
    s = st.session_state
    prop = proposal()
    options = ([proposal_label(prop)] if prop else []) + list(SAMPLES)
    if prop and prop.get("fresh"):  # just handed over: shown as the plan
        s["w_plan_sample"] = options[0]
        s["plan_proposal"] = {**prop, "fresh": False}
    if s.get("w_plan_sample") not in options:  # a proposal of a previous dataset
        s.pop("w_plan_sample", None)
    c1, c2 = st.columns([2, 3])
    sample = c1.selectbox("Start from", options, key="w_plan_sample")
    up = c2.file_uploader("…or upload a PLAN.json (a setup given by file name is read "
                          "from sample_data/plans)", type="json", key="w_plan_upload")
    from_proposal = prop is not None and up is None and sample == options[0]
    default = (up.getvalue().decode("utf-8-sig") if up is not None
               else prop["text"] if from_proposal
               else (PLANS_DIR / SAMPLES[sample]).read_text())
    source = (sample, up.name if up else None, prop["text"] if from_proposal else None)
    # a new dataset resets every widget (state.reset_widgets), the text box too: refill it
    if s.get("plan_source") != source or "w_plan_text" not in s:
        s["plan_source"] = source
        s["w_plan_text"] = default
    if from_proposal:
        st.info(f"The plan is the measurement proposed on the Diagnose page: "
                f"{prop['outcome']}. Its two strategies: the current placements, and with "
                "the proposed one.")
    with st.expander("Plan file (edit and press Ctrl+Enter)", expanded=False):
        text = st.text_area("PLAN.json", key="w_plan_text", height=320,
                            help="Format: docs/planning.md. Lengths in mm, σ and "
                                 "certificate uncertainty in µm, times in minutes.")
    try:
        json.loads(text)
    except json.JSONDecodeError as exc:
        st.error(f"The plan is not valid JSON: {exc.msg} at line {exc.lineno}.")
        return None
    return text


def _comparison(evals: list) -> None:
    rows = []
    for e in evals:
        rows.append({"strategy": e["name"], "probings": e["n_obs"],
                     "time (min)": e["time_min"],
                     "undetermined": len(e["undetermined"]),
                     # undetermined: no U at all, said in words rather than a blank
                     **{f"U{k} {a} (µm)": _fmt((e[f"U{k}_um"] or {}).get(a), 3)
                        .replace("—", "undetermined") for k in (2, 3) for a in "xyz"}})
    st.dataframe(pd.DataFrame(rows), hide_index=True)
    for i, e in enumerate(evals):
        if e["undetermined"]:
            # lazy (issue 27): the code block's highlighter (1.6 MB of script, half a second
            # of the page's first visit) loads only when a user opens one
            with st.expander(f"{e['name']}: {len(e['undetermined'])} undetermined "
                             "combination(s)", key=f"w_plan_undet_{i}",
                             on_change="rerun") as box:
                if not box.open:
                    continue
                st.markdown("\n".join(f"- {w}" + (f" ({n} combinations)" if n > 1 else "")
                                       for w, n in distinct_words(e["undetermined_words"])))
                st.write("Parameters involved: " + ", ".join(e["undetermined_parameters"]))
                st.code("\n".join(e["undetermined"]), language=None)
                st.caption("Any basis of these combinations is as valid; the fit names the "
                           "same space on real data of this design.")


def _detection_plot(evals: list) -> None:
    effects = list(dict.fromkeys(k for e in evals for k in e["detection_limits"]))
    physical = [k for k in effects if ":" not in k or k.startswith("periodic")]
    pick = st.multiselect("Effects", effects, default=physical, key="w_plan_effects")
    # grouped bars on log axes: Plotly (widgets.show falls back to it for bars)
    widgets.show(A.fig_detection_limits(evals, pick), chart_key="plan_limits", width="stretch")
    rows = [{"strategy": e["name"], "effect": k, "expected": v["expected"],
             "detection limit": _fmt(v["limit"]), "unit": unit_label(v["unit"]),
             "seen": "yes" if v["detectable"] else "no"}
            for e in evals for k, v in e.get("expected_effects", {}).items()]
    if rows:
        st.dataframe(pd.DataFrame(rows), hide_index=True)
    st.caption("Size the diagnosis names with 80 % probability at its own false-alarm "
               "level (non-central F power). A missing bar: the design cannot see that "
               "effect (the baseline absorbs its pattern). Units and shapes: "
               "docs/planning.md.")


def _u_map(text: str, evals: list) -> None:
    ok = [e["name"] for e in evals if e["U3_um"] is not None]
    if not ok:
        st.info("No strategy determines every parameter: no uncertainty map.")
        return
    c1, c2, c3 = st.columns(3)
    name = c1.selectbox("Strategy", ok, key="w_plan_map_strategy")
    z = c2.slider("Z of the XY plane (mm)", 0.0, 700.0, 350.0, step=50.0, key="w_plan_map_z")
    comp = c3.radio("Component", ["x", "y", "z"], horizontal=True, key="w_plan_map_comp")
    res = calls.safe(u_map, text, name, float(z), what="Uncertainty map")
    if res is None:
        return
    gx, gy, u = res
    fig = A.fig_surface_grid(gx, gy, u[:, :, "xyz".index(comp)], colorscale="Viridis",
                             title=f"u of e{comp} at Z = {z:g} mm ({name})", unit="µm")
    widgets.show(fig, chart_key="plan_u_map", width="stretch")
    st.caption("Standard uncertainty (k = 1) of the predicted CMM error with the rigid part "
               "of the plane removed, from the design alone (as U2/U3).")


def plan_page() -> None:
    """The Plan page."""
    st.title("Plan")
    st.caption("Before measuring: what a ball-plate plan will determine, how well, what it "
               "can detect and how long it takes, from the design alone (noise-free virtual "
               "data fitted by the real fit). Format and method: docs/planning.md.")
    text = _plan_text()
    if text is None:
        return
    st.download_button("Download the plan (PLAN.json)", text, _download_name(text),
                       "application/json", key="w_plan_download",
                       help="The plan file as shown (and edited) above: `plan PLAN.json` "
                            "on the command line evaluates it the same way.")
    evals = calls.safe(evaluate_plans, text, what="Plan")
    if not evals:
        return
    st.subheader("Strategies side by side")
    _comparison(evals)
    st.subheader("Detection limits")
    _detection_plot(evals)
    st.subheader("Uncertainty map")
    _u_map(text, evals)
    pf = calls.safe(_plan_file, text, what="Plan")
    if pf is not None and pf.design is not None:
        st.subheader("Design")
        st.write(f"Target: `{json.dumps(pf.design.get('target'))}`, criterion "
                 f"{pf.design.get('criterion', 'D')}.")
        if st.button("Find the cheapest plan", key="w_plan_design"):
            st.session_state["plan_design_for"] = text
        if st.session_state.get("plan_design_for") == text:
            d = calls.safe(design_plan, text, what="Design")
            if d is not None:
                st.success(d["message"])
                st.write("Units: " + ", ".join(d["units"]))
                st.json(d["achieved"], expanded=False)
    _check_section(text, evals)


def _check_section(text: str, evals: list) -> None:
    st.subheader("Monte Carlo check (Dask)")
    c1, c2 = st.columns(2)
    trials = c1.number_input("Data sets per strategy and effect", 2, 1000, 20,
                             key="w_plan_trials")
    address = c2.text_input("Dask scheduler address (empty: a local cluster)", "",
                            key="w_plan_scheduler")
    if not st.button("Run the check", key="w_plan_check"):
        return

    bar = st.progress(0.0, "starting the Dask cluster…")
    with calls.guarded("Monte Carlo check"):
        full = [evaluate(p) for p in _plan_file(text).strategies]
        res = check_plans(full, trials=int(trials), scheduler=address or None,
                          processes=False,
                          progress=lambda f, t: bar.progress(min(f, 1.0), t)).to_dict()
        for p in res["plans"]:
            st.markdown(f"**{p['name']}**: {p['trials']} clean data sets")
            if "max_relative_difference" in p:
                st.write(f"U2/U3 observed vs predicted: largest relative difference "
                         f"{p['max_relative_difference']:.1e}; RMS of normalised coefficient "
                         f"errors {p['z_rms']:.2f} (1 when the uncertainties hold).")
            if p["detection"]:
                st.dataframe(pd.DataFrame([{"effect": k, "limit": v["size"], "unit": unit_label(v["unit"]),
                                            "detected": v["rate"], "±SE": v["se"]}
                                           for k, v in p["detection"].items()]),
                             hide_index=True)


if __name__ == "__main__":  # run as a page (st.Page executes it as __main__), not on import
    plan_page()

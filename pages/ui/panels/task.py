"""Task-specific uncertainty (the Compensate page's panel): a distance, circle or plane
measured with the current fit or a saved model, by Monte Carlo beside the law of
propagation (``cmm_core.plan.task_uncertainty``)."""

from __future__ import annotations

import json

import pandas as pd
import streamlit as st

from cmm_core.export import model_from_dict, model_to_dict
from cmm_core.io import SAMPLE_DIR
from cmm_core.plan import read_task, task_uncertainty
from cmm_core.units import label as unit_label
from pages.ui import cached, calls

PLANS_DIR = SAMPLE_DIR / "plans"
"""The sample plans and tasks shipped with the app."""
TASKS = {"distance": "task_distance.json", "circle": "task_circle.json",
         "plane": "task_plane.json"}
"""The sample task of each kind (in :data:`PLANS_DIR`)."""


@st.cache_data(show_spinner="Monte Carlo of the task…", max_entries=16)
def task_result(model_json: str, task_text: str, trials: int) -> dict:
    """The task's result and uncertainty (JSON record)."""
    model = model_from_dict(json.loads(model_json), name="model")
    return task_uncertainty(model, read_task(json.loads(task_text), name="task"),
                            trials=trials).to_dict()


def sample_task(kind: str, styli: list[str]) -> str:
    """The sample task of ``kind`` with its points on the model's own styli: a point's
    stylus the model does not know becomes the model's first (the sample's stylus "1" is
    the thesis's; another dataset names its own)."""
    doc = json.loads((PLANS_DIR / TASKS[kind]).read_text())
    if styli:
        for p in doc.get("points", []):
            if str(p.get("probe")) not in styli:
                p["probe"] = styli[0]
    return json.dumps(doc, indent=1)


def task_section() -> None:
    """Task-specific uncertainty of a distance, circle or plane measured with the current
    fit (or an uploaded saved model): Monte Carlo beside the law of propagation."""
    st.subheader("Task-specific uncertainty")
    st.caption("Points as the CMM reports them (tip centres, machine frame, mm) with their "
               "stylus; corrected with the model, reported at 20 °C. Influences: the model's "
               "covariance, probing noise, optional discrepancy, temperature and scale "
               "(docs/planning.md).")
    up = st.file_uploader("A stored calibration (model file, from this page's downloads); "
                          "default: the current fit", type="json", key="w_task_model")
    if up is not None:
        model_json = up.getvalue().decode("utf-8-sig")
    else:
        r = cached.current_fit()
        if r is None:
            return
        if not r.identifiable:
            st.info("The task's uncertainty needs a model the data determine: this one "
                    "leaves parameter combinations undetermined (see the sidebar).")
            return
        model_json = json.dumps(model_to_dict(r), default=float)
    kind = st.radio("Task", list(TASKS), horizontal=True, key="w_task_kind")
    try:
        styli = [str(k) for k in json.loads(model_json).get("probes_mm") or {}]
    except (ValueError, AttributeError):  # the model's own reader says what is wrong
        styli = []
    first = styli[0] if styli else ""
    text = st.text_area("TASK.json", sample_task(kind, styli), height=220,
                        key=f"w_task_text_{kind}_{first}")
    trials = st.number_input("Monte Carlo trials", 1000, 200000, 20000, step=1000,
                             key="w_task_trials")
    res = calls.safe(task_result, model_json, text, int(trials), what="Task")
    if res is None:
        return
    # a flatness's interval is the spread of a repeat measurement, not a coverage interval
    # for the true flatness (the task's message says why)
    p_cov = f"{100 * res['coverage_probability']:g} %"
    rows = [{"quantity": q, "value": v["value"], "unit": unit_label(v["unit"]),
             "U = 2u, Monte Carlo (µm)": 2 * v["u_mc_um"],
             "U = 2u, law of propagation (µm)": 2 * v["u_lpu_um"],
             "Monte Carlo interval": ("spread of a repeat: " if "flatness" in q else
                                      f"{p_cov}: ") + "[{0:.{2}f}, {1:.{2}f}] {3}".format(
                 *v["interval"], 5 if v["unit"] == "mm" else 3,
                 unit_label(v["unit"])),
             **{f"u {k} (µm)": c for k, c in v["contributions_um"].items()}}
            for q, v in res["results"].items()]
    st.dataframe(pd.DataFrame(rows), hide_index=True)
    st.caption(res["message"])

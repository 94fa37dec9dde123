"""CMM error lab: the Streamlit app (``make run``). Six pages over ``cmm_core``.

The thesis ball-plate data are loaded and fitted on first run, so a first-time user sees a
model and plots without touching anything. The sidebar states the dataset, the model and
the fit quality on every page.
"""

from pathlib import Path

import streamlit as st

from pages import common

ROOT = Path(__file__).resolve().parent

# the favicon is a local file, served by Streamlit itself: nothing is fetched from the
# internet (an emoji or icon name would be, and fails offline)
st.set_page_config(page_title="CMM error lab", page_icon=str(ROOT / ".streamlit" / "favicon.png"),
                   layout="wide")
common.init_state()

PAGES = [
    st.Page("pages/data.py", title="Data", icon=":material/dataset:", url_path="data", default=True),
    st.Page("pages/kinematic.py", title="Kinematic model", icon=":material/show_chart:", url_path="kinematic"),
    st.Page("pages/gaussian_process.py", title="Gaussian process", icon=":material/blur_on:", url_path="gp"),
    st.Page("pages/diagnose.py", title="Compare and diagnose", icon=":material/troubleshoot:", url_path="diagnose"),
    st.Page("pages/uncertainty.py", title="Uncertainty", icon=":material/gps_fixed:", url_path="uncertainty"),
    st.Page("pages/export.py", title="Compensate and export", icon=":material/download:", url_path="export"),
]
page = st.navigation(PAGES)
st.session_state["_via_app"] = True  # pages check it (common.page_start)
deep_link = st.session_state.pop("_deep_link", None)
if deep_link and deep_link != "data.py" and (ROOT / "pages" / deep_link).is_file():
    st.switch_page(f"pages/{deep_link}")
st.sidebar.title("CMM error lab")
page.run()


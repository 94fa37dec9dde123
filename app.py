"""CMM error lab: the Streamlit app (``make run``). Six pages over ``cmm_core``.

The thesis ball-plate data are loaded and fitted on first run, so a first-time user sees a
model and plots without touching anything. The sidebar states the dataset, the model and
the fit quality on every page.
"""

import streamlit as st

from pages import common

st.set_page_config(page_title="CMM error lab", page_icon=":material/straighten:", layout="wide")
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
st.sidebar.title("CMM error lab")
page.run()


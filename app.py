"""CMM error lab: the Streamlit app (``make run``). Seven pages over ``cmm_core``.

The thesis ball-plate data are loaded and fitted on first run, so a first-time user sees a
model and plots without touching anything. The sidebar states the dataset, the model and
the fit quality on every page.

Navigation. The pages live in ``pages/`` (the design requires that folder), which Streamlit
also reads as a legacy page list: on a fresh server its first run shows that raw list of
files in the sidebar until ``st.navigation`` replaces it. ``client.showSidebarNavigation =
false`` (.streamlit/config.toml) hides every automatic navigation menu, the legacy one
included, so the app draws its own with ``st.page_link``. Every page has its own URL
(``/data``, ``/kinematic`` ...): Streamlit serves its default page at ``/`` only, not at
its ``url_path``, so the default page is a small redirect to the Data page rather than the
Data page itself (``/data`` then opens it directly instead of "page not found").

A session survives a reload: the URL carries the analysis's id (``?session=...``), every
link between pages keeps it, and the analysis is saved as a project file in a per-user
folder whenever it changes (``session.session_start``, ``session.autosave``,
``cmm_core.analysis.sessions``); F5, or the URL in a new tab, restores it with a note and a
"Start afresh" button.
"""

import json
import os
import time
from pathlib import Path

import streamlit as st

from pages import session, state

ROOT = Path(__file__).resolve().parent
# When set, a file each script run appends its page and wall time to (bench/browser.py
# reads it: the server's share of what a person waits for). A comment, not a string under
# the name: Streamlit's "magic" writes a bare string of a script onto every page.
RUN_LOG = os.environ.get("CMM_LAB_RUN_LOG")
_t0 = time.perf_counter()

# the favicon is a local file, served by Streamlit itself: nothing is fetched from the
# internet (an emoji or icon name would be, and fails offline)
st.set_page_config(page_title="CMM error lab", page_icon=str(ROOT / ".streamlit" / "favicon.png"),
                   layout="wide")
session.session_start()
state.init_state()

PAGES = [
    st.Page("pages/data.py", title="Data", icon=":material/dataset:", url_path="data"),
    st.Page("pages/kinematic.py", title="Kinematic model", icon=":material/show_chart:",
            url_path="kinematic"),
    st.Page("pages/gaussian_process.py", title="Gaussian process", icon=":material/blur_on:",
            url_path="gp"),
    st.Page("pages/diagnose.py", title="Compare and diagnose", icon=":material/troubleshoot:",
            url_path="diagnose"),
    st.Page("pages/uncertainty.py", title="Uncertainty", icon=":material/gps_fixed:",
            url_path="uncertainty"),
    st.Page("pages/export.py", title="Compensate and export", icon=":material/download:",
            url_path="export"),
    st.Page("pages/plan.py", title="Plan", icon=":material/route:", url_path="plan"),
    st.Page("pages/check.py", title="Interim check", icon=":material/fact_check:", url_path="check"),
]


def _home():
    """The app's root URL opens the Data page (at its own URL, /data)."""
    st.switch_page(PAGES[0], query_params=session.session_query())


HOME = st.Page(_home, title="CMM error lab", url_path="home", default=True,
               visibility="hidden")
page = st.navigation([HOME, *PAGES], position="hidden")
st.session_state["_via_app"] = True  # pages check it (frame.page_start)
deep_link = st.session_state.pop("_deep_link", None)
if deep_link and (ROOT / "pages" / deep_link).is_file():
    # a deep link opened on a fresh server, before this script ever ran (see
    # frame.page_start): open the page asked for, now inside the app
    st.switch_page(f"pages/{deep_link}", query_params=session.session_query())
st.sidebar.title("CMM error lab")
with st.sidebar.container(key="app_nav"):
    for p in PAGES:
        st.page_link(p, label=p.title, icon=p.icon, width="stretch",
                     query_params=session.session_query())
st.sidebar.divider()
try:
    page.run()
    # what the page changed without a rerun (a button's direct effect) is saved now
    session.autosave()
finally:
    if RUN_LOG:  # a rerun or stop ends the run here too: it is timed all the same
        with open(RUN_LOG, "a", encoding="utf-8") as log:
            log.write(json.dumps({"page": page.url_path, "t_end": time.time(),
                                  "s": time.perf_counter() - _t0}) + "\n")

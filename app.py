"""CMM error lab: the Streamlit app's frame (``cmm-error-lab app``, ``make run``).

This script is the frame every page sits in, run on every rerun before the page: the page
config, the session (``pages.ui.session``), the state (``pages.ui.state``), the sidebar,
the navigation and the autosave. The page scripts in ``pages/`` draw their page only; the
UI they share is the package ``pages/ui/`` (with its panels), which Streamlit does not scan
for pages.

The thesis ball-plate data are loaded and fitted on first run, so a first-time user sees a
model and plots without touching anything.

Navigation. Every page has its own URL (``/data``, ``/kinematic`` ...): Streamlit serves
its default page at ``/`` only, not at its ``url_path``, so the default page is a small
redirect to the Data page rather than the Data page itself (``/data`` then opens it
directly instead of "page not found"). Streamlit runs the scripts of ``pages/*.py`` as
pages of their own (its legacy multipage list) until the first ``st.navigation`` of the
server: the server's start (``serve.py``) turns that list off before any session opens,
so a deep link on a fresh server runs this frame too. ``client.showSidebarNavigation =
false`` (.streamlit/config.toml) hides the automatic menu; the app draws its own with
``st.page_link``.

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

from pages.ui import session, sidebar, state

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
st.sidebar.title("CMM error lab")
with st.sidebar.container(key="app_nav"):
    for p in PAGES:
        st.page_link(p, label=p.title, icon=p.icon, width="stretch",
                     query_params=session.session_query())
st.sidebar.divider()
# the frame's state for the page about to run: widget values kept across pages and copied
# into the canonical state, the analysis saved, the sidebar drawn, a restore's note shown
state.keep_widget_state()
state.sync_from_widgets()
session.autosave()
sidebar.sidebar()
session.restore_banner()
try:
    page.run()
    # what the page changed without a rerun (a button's direct effect) is saved now
    session.autosave()
finally:
    if RUN_LOG:  # a rerun or stop ends the run here too: it is timed all the same
        with open(RUN_LOG, "a", encoding="utf-8") as log:
            log.write(json.dumps({"page": page.url_path, "t_end": time.time(),
                                  "s": time.perf_counter() - _t0}) + "\n")

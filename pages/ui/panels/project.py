"""The Data page's project panel: a project file restores a whole analysis."""

from __future__ import annotations

import streamlit as st

from pages.ui import calls, session, state


def project_section():
    """The project tab: a project file restores a whole analysis."""
    st.write("A project file (JSON, from *Compensate and export*) restores the dataset, model, "
             "exclusions and diagnosis history.")
    up_proj = st.file_uploader("Project file (JSON)", type=["json"], key="up_project")
    if st.button("Restore project", key="restore_project", disabled=up_proj is None):
        # the core reads the whole file (analysis.record_from_project: every part's shape
        # and value, one line naming the key) before anything of the session changes
        try:
            note = session.restore_project(up_proj.getvalue(), up_proj.name)
        except Exception as exc:  # noqa: BLE001 - a message, never a traceback
            st.error(f"The project does not restore: {calls.describe_error(exc)}")
        else:
            state.loaded(f"Restored project '{st.session_state['sources'].name}'.{note}")

"""A tiny app around the foreign-file panel, for tests/test_browser_mapping.py."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import streamlit as st  # noqa: E402

from pages.ui.panels.mapping import mapping_panel  # noqa: E402

st.title("Mapping panel")
table = mapping_panel("map")
if table is not None:
    st.session_state["mapped"] = (table.name, len(table.meas))
if "mapped" in st.session_state:
    name, n = st.session_state["mapped"]
    st.success(f"Loaded {n} rows from {name}.")

"""The UI the app's pages share (Streamlit runs ``pages/*.py`` as pages and never scans
this package).

``state`` holds the session's canonical keys and what changes them (the data as the
core's ``DataSources``), ``session`` the analysis kept for a reload, ``cached`` the thin
``st.cache_data`` wrappers of the core's calls, ``calls`` the one way errors become
messages, ``widgets`` the display helpers (figures as the core's SVG or Plotly, tables,
bound widgets), ``sidebar`` the sidebar the frame (``app.py``) draws; ``panels`` holds the
Data and Compensate pages' larger parts. Imports run downhill: panels use the modules,
never the other way round (``tests/test_wings.py``).
"""

__all__ = ["cached", "calls", "panels", "session", "sidebar", "state", "widgets"]

"""Errors never become tracebacks: the app's one way of calling the core and of
showing what went wrong (the core's one-line messages, other exceptions by type)."""

from __future__ import annotations

from contextlib import contextmanager

import streamlit as st

from cmm_core.io import describe_error

__all__ = ["describe_error", "guarded", "safe"]


def safe(fn, *args, what: str = "", **kwargs):
    """Call a core function; on any exception show ``st.error`` and return None."""
    try:
        return fn(*args, **kwargs)
    except Exception as exc:  # noqa: BLE001 - every failure becomes a message
        st.error(f"{what + ': ' if what else ''}{describe_error(exc)}")
        return None


@contextmanager
def guarded(what: str):
    """``with guarded("Drawing"):`` shows a message instead of a traceback."""
    try:
        yield
    except Exception as exc:  # noqa: BLE001 - script control exceptions are BaseException
        st.error(f"{what}: {describe_error(exc)}")

"""JSON-safe numbers for the monitor's results documents (one rule for the interim
check and the history: RFC 8259 has no NaN or infinity, so they are written null)."""

from __future__ import annotations

import numpy as np


def json_num(v: object) -> float | None:
    """A JSON number: None for NaN, infinity or None."""
    if v is None:
        return None
    f = float(v)  # type: ignore[arg-type]
    return f if np.isfinite(f) else None

"""What every written table shares: text cells safe to open in a spreadsheet (CSV formula
injection neutralised) and the largest grid a download may hold."""

from __future__ import annotations

import io
from collections.abc import Iterable

import pandas as pd

_DANGEROUS = ("=", "+", "-", "@", "\t", "\r")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def neutralise(value: object) -> object:
    """A cell value safe for a spreadsheet: dangerous text gets a leading apostrophe."""
    if isinstance(value, str) and value.startswith(_DANGEROUS) and not _is_number(value):
        return "'" + value
    return value


def safe_frame(df: pd.DataFrame) -> pd.DataFrame:
    """Copy of ``df`` with every text cell (and column name) neutralised."""
    out = df.copy()
    out.columns = [neutralise(str(c)) for c in out.columns]
    for c in out.columns:
        if not (pd.api.types.is_numeric_dtype(out[c]) or pd.api.types.is_bool_dtype(out[c])):
            out[c] = out[c].map(neutralise)
    return out


def safe_csv(df: pd.DataFrame, *, float_format: str = "%.6g", header_lines: Iterable[str] = ()
         ) -> str:
    """CSV text of ``df`` safe against formula injection, optional ``#`` comment lines first.

    Lines end in CRLF (RFC 4180), so a carriage return inside a text cell is quoted.
    """
    buf = io.StringIO()
    for line in header_lines:
        buf.write("# " + str(line).replace("\n", " ").replace("\r", " ") + "\r\n")
    safe_frame(df).to_csv(buf, index=False, float_format=float_format, lineterminator="\r\n")
    return buf.getvalue()


MAX_GRID_NODES = 100_000
"""Largest error-map grid (nodes); 100 000 nodes take a few seconds with uncertainties."""

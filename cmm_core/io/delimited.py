"""Reading raw files: CSV tables as text cells, numbers out of them, and JSON documents.

Holds the layer under every reader: :func:`read_bytes` (path, bytes or file-like, size
cap :data:`MAX_BYTES`), :func:`read_csv_text` (separator from the header, decimal commas,
blank lines and trailing separators tolerated, file rows kept for messages),
:func:`numeric_column` and :func:`_names` (cells checked one by one), :func:`require_columns` and
:func:`require_rows` (the columns and rows a file must have) and :func:`read_json`.
Nothing here knows what a measurement, setup or certificate is; the points readers of
:mod:`cmm_core.export.correction` and :mod:`cmm_core.export` use it too.
"""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any, TypeAlias

import numpy as np
import pandas as pd

from .errors import DataError, Problems, cut_repr

MAX_BYTES = 50 * 1024 * 1024
MAX_MEASUREMENT_ROWS = 200_000
"""Most readings a measurement file (long form, thesis form, a mapped table, DMIS spheres)
may hold: ten times a large calibration (a 100-hole plate in 20 placements with five
styli, ten repeats each). The fit's Jacobian holds three rows per reading, so 10⁶ readings
would cost gigabytes before any answer; beyond the limit the file is refused as soon as the
reader meets the row after it, before the rest is parsed."""
_NAN_WORDS = {"nan", "+nan", "-nan"}
_DELIM_NAMES = {",": "comma", ";": "semicolon", "\t": "tab"}
# A number written with a decimal comma ("-1,25", "3,5e-2"); only rewritten in files whose
# columns are not separated by commas, where the comma cannot be a column separator.
_DECIMAL_COMMA = re.compile(r"^(\s*[+-]?\d*),(\d+(?:[eE][+-]?\d+)?\s*)$")


FileSource: TypeAlias = str | Path | bytes | IO[bytes] | IO[str]
"""What the readers accept as a file: a path (``str`` or ``Path``), the file's bytes, or an
open file-like object (binary or text, e.g. an upload)."""


_COLUMNS_HINT = ("Columns: position,probe,ball,x_mm,y_mm,z_mm (long form) or "
                 "ball,x_mm,y_mm,z_mm (one file per position), optional time_min, temp_C, "
                 "repeat, temp_x_C, temp_y_C, temp_z_C (scale temperatures); lengths in mm, time in minutes, temperature in °C.")


def read_bytes(source: FileSource, name: str | None) -> tuple[bytes, str]:
    """The raw bytes of a path, bytes or file-like object, refusing oversized files.

    A path must name a regular file: a device (``/dev/zero``), a pipe (which would block
    until someone writes to it) or a socket is refused before it is opened. At most
    :data:`MAX_BYTES` + 1 bytes are ever read, so an endless upload stream is refused at
    the limit instead of filling the memory.
    """
    if isinstance(source, (str, Path)):
        path = Path(source)
        name = name or path.name
        if not path.exists():
            raise DataError("file not found.", file=name, hint="check the path.")
        if path.is_dir():
            raise DataError("is a folder; expected a file.", file=name,
                            hint="name the file inside the folder.")
        if not path.is_file():
            raise DataError("is not a regular file (a device, a pipe or a socket); expected "
                            "a file.", file=name, hint="name the file itself.")
        _refuse_size(path.stat().st_size, name)
        try:
            with path.open("rb") as fh:
                data = fh.read(MAX_BYTES + 1)
        except OSError as exc:
            raise DataError(f"cannot read ({exc.strerror}).", file=name,
                            hint="check the path and that it is a file.") from None
    elif isinstance(source, bytes):
        data = source
    else:
        raw = source.read(MAX_BYTES + 1)
        data = raw.encode() if isinstance(raw, str) else raw
    name = name or "uploaded file"
    _refuse_size(len(data), name)
    return data, name


def _refuse_size(size: int, name: str) -> None:
    """Refuse a file of more than :data:`MAX_BYTES` (``size`` may be the cap + 1 read)."""
    if size > MAX_BYTES:
        raise DataError(f"file is more than {MAX_BYTES / 1e6:.0f} MB (the limit of every "
                        "reader)." if size == MAX_BYTES + 1 else
                        f"file is {size / 1e6:.0f} MB; the limit is {MAX_BYTES / 1e6:.0f} MB.",
                        file=name, hint="split the data into several files, or thin them "
                        "out (docs/formats.md#size-limits).")


def _delimiter(header: str) -> str:
    """The column separator of a file, judged from its header line.

    Column names never contain commas, so a header without commas but with semicolons or
    tabs (a spreadsheet export in a locale with decimal commas) names its separator
    unambiguously; ``csv.Sniffer`` is not used because it guesses from the data rows, where
    decimal commas and spaces mislead it.
    """
    if "," in header:
        return ","
    counts = {d: header.count(d) for d in (";", "\t")}
    best = max(counts, key=lambda d: counts[d])
    return best if counts[best] else ","


def _too_many_fields(header, bad, delim, name) -> DataError:
    """Rows with more fields than the header, as one DataError naming every such row."""
    hint = ("a decimal comma (1,5) splits a number into two fields: use a point as "
            "decimal separator, or quote cells that contain commas." if delim == "," else
            f"remove the extra {_DELIM_NAMES[delim]}s or quote cells that contain them.")
    found = Problems(name, [r for r, _ in bad])
    found.add(np.ones(len(bad), bool), None, lambda i: f"expected {len(header)} fields "
              f"({cut_repr(','.join(header), 80)}), found {bad[i][1]}.", hint=hint)
    return DataError.collect(found.found, found.total)


def blank_leading_comments(text: str) -> str:
    """``text`` with each line before its first table line that starts with ``#`` made
    blank: the comment header this product writes above its own tables (their provenance,
    docs/formats.md) is read past, and blank lines keep their place in the row numbers.
    A ``#`` after the header is a cell like any other. Only the lines before the header
    are looked at (a 10⁶-line file is not split into lines here)."""
    out, pos, changed = [], 0, False
    while pos < len(text):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        line = text[pos:end]
        if line.lstrip().startswith("#"):
            out.append("")
            changed = True
        elif line.strip(" \t,;"):
            return "\n".join([*out, text[pos:]]) if changed else text
        else:
            out.append(line)
        pos = end + 1
    return "\n".join(out + [""] * text.endswith("\n")) if changed else text


def _lines(text: str):
    """The lines of ``text`` with their line ends, one at a time: the CSV reader holds
    one line, where a StringIO of the text would hold four bytes per character."""
    pos = 0
    while pos < len(text):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end + 1
        yield text[pos:end]
        pos = end


def read_csv_text(source: FileSource, name: str | None, *,
                  max_rows: int | None = None) -> tuple[pd.DataFrame, str]:
    """Read a CSV from a path, bytes or file-like object into strings (nothing coerced).

    The separator is taken from the header line (see :func:`_delimiter`); in a file
    separated by semicolons or tabs, numbers written with a decimal comma are read as
    decimals. Tolerated alike in every file: a UTF-8 byte-order mark, CRLF or CR line
    ends, blank lines (they keep their place in the row numbering), ``#`` comment lines
    before the header (:func:`blank_leading_comments`), and a separator at
    the end of every line (a common export) as long as nothing follows it. A row with
    more fields than the header, a header naming a column twice, or cells the CSV
    grammar cannot read are refused with their rows. With ``max_rows``, a file of more
    data rows is refused as soon as the row after the limit is met (the rest is never
    parsed into cells: a 10⁶-row log costs no more than the limit).

    Returns
    -------
    df : DataFrame of str
        ``df.attrs`` holds ``delimiter``, ``decimal_comma`` (whether any cell was
        rewritten) and ``rows`` (the file row of each data row; see :func:`file_rows`).
    name : str
    """
    data, name = read_bytes(source, name)
    try:
        text = data.decode("utf-8-sig")
        del data  # the text is what is read from here on
    except UnicodeDecodeError as exc:
        raise DataError("is not UTF-8 text (a binary file, or another encoding).", file=name,
                        hint="export the table as CSV (UTF-8).") from exc
    if not text.strip():
        raise DataError("file is empty.", file=name)
    if "\x00" in text:
        raise DataError("contains NUL bytes; it is not a text table.", file=name,
                        hint="export the table as CSV (UTF-8).")
    # one line end everywhere: a bare CR (old Mac export, or a stray one in a cell) would
    # otherwise end a line for one reader and not for another
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    text = blank_leading_comments(text)
    if not text.strip():
        raise DataError("holds comment lines only; expected a header line with column "
                        "names after them.", file=name)
    first_line = next(line for line in _lines(text) if line.strip()).rstrip("\n")
    delim = _delimiter(first_line)
    reader = csv.reader(_lines(text), delimiter=delim, skipinitialspace=True)
    header, records, rows, bad = None, [], [], []
    try:
        while True:
            start = reader.line_num + 1
            rec = next(reader, None)
            if rec is None:
                break
            if not any(c.strip() for c in rec):
                continue  # blank line: no row, but it keeps its number
            if header is None:
                header = [c.strip() for c in rec]
                continue
            if len(rec) > len(header):
                if any(c.strip() for c in rec[len(header):]):
                    bad.append((start, len(rec)))
                    continue
                rec = rec[:len(header)]  # a trailing separator with nothing after it
            records.append(rec + [""] * (len(header) - len(rec)))
            rows.append(start)
            if max_rows is not None and len(records) > max_rows:
                raise DataError(f"has more than {max_rows} data rows (row {start} is beyond "
                                "the limit for this kind of file).", file=name,
                                hint="thin the data out or split them into several files "
                                     "(docs/formats.md#size-limits).")
    except csv.Error as exc:
        big = "field larger" in str(exc)
        raise DataError(f"cannot be read as a CSV table ({cut_repr(str(exc), 80)}).", file=name,
                        row=reader.line_num,
                        hint=(f"a cell is longer than {csv.field_size_limit()} characters: is "
                              "this a CSV table?") if big else
                        "check the quotes in that row.") from None
    if header is None:  # only quotes and separators
        raise DataError("has no header line; expected column names such as "
                        "ball,x_mm,y_mm,z_mm.", file=name, row=1, hint=_COLUMNS_HINT)
    # a separator ending the header line too: drop the nameless columns it made, when empty
    while header and header[-1] == "" and all(r[len(header) - 1].strip() == "" for r in records):
        header.pop()
        records = [r[:len(header)] for r in records]
    if bad:
        raise _too_many_fields(header, bad, delim, name)
    names = [h or f"Unnamed: {k}" for k, h in enumerate(header)]
    twice = sorted({h for h in names if names.count(h) > 1})
    if twice:
        raise DataError(f"the header names column {cut_repr(twice[0], 40)} twice; expected each "
                        "column once.", file=name, row=1, column=twice[0],
                        hint="rename or delete the repeated column.")
    df = pd.DataFrame(records, columns=names, dtype=object)
    decimal_comma = False
    if delim != ",":
        for col in df.columns.difference(["position", "probe"]):
            fixed = df[col].str.replace(_DECIMAL_COMMA, r"\1.\2", regex=True)
            decimal_comma |= bool((fixed != df[col]).any())
            df[col] = fixed
    df.attrs.update(delimiter=delim, decimal_comma=decimal_comma)
    df.attrs["rows"] = np.asarray(rows, int)
    return df, name


def file_rows(df: pd.DataFrame) -> np.ndarray:
    """File row of each data row of a :func:`read_csv_text` frame (header = row 1)."""
    rows = df.attrs.get("rows")
    return np.arange(2, len(df) + 2) if rows is None else np.asarray(rows)


def numeric_column(df: pd.DataFrame, column: str, name: str | None, *, integer: bool = False,
                   allow_missing: bool = False,
                   problems: Problems | None = None) -> np.ndarray:
    """The cells of ``column`` as numbers, every unreadable cell reported with its row.

    Parameters
    ----------
    df : DataFrame
        As read by :func:`read_csv_text`.
    column, name : str
        Column to convert; file name for messages.
    integer : bool
        Cells must be whole numbers (ball numbers).
    allow_missing : bool
        Empty cells are NaN rather than problems.
    problems : Problems, optional
        Collector for the problems. Without one, the problems of this column are raised
        here as one :class:`DataError`.

    Returns
    -------
    ndarray
        Floats, NaN where a cell was reported; ints for ``integer`` when raising here.
    """
    own = problems is None
    if problems is None:
        problems = Problems(name, file_rows(df), df.columns)
    text = df[column].fillna("").astype(str).str.strip()
    vals = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float, copy=True)
    blank = (text == "").to_numpy()
    word = text.str.lower().isin(_NAN_WORDS).to_numpy()
    nonfinite = word | np.isinf(vals)
    nonnum = np.isnan(vals) & ~blank & ~word
    problems.add(blank & (not allow_missing), column,
                 lambda i: "expected a number, found an empty cell.",
                 hint="fill in the value or delete the row.")
    problems.add(nonnum, column, lambda i: f"expected a number, found {cut_repr(text.iat[i])}.",
                 hint="use a point as decimal separator and no units.")
    problems.add(nonfinite, column, lambda i: f"found {cut_repr(text.iat[i])}, which is not a "
                 "finite number; expected a measured value.",
                 hint="write the measured value or delete the row.")
    vals[nonfinite] = np.nan
    if integer:
        frac = np.isfinite(vals) & (vals != np.round(vals))
        problems.add(frac, column, lambda i: f"expected a whole ball number, found "
                     f"{cut_repr(text.iat[i])}.")
        vals[frac] = np.nan
    if not own:
        return vals
    problems.raise_if_any()
    return vals.astype(int) if integer and not np.isnan(vals).any() else vals


def _names(df, column, problems):
    """Stripped names of ``column``; empty cells reported."""
    names = df[column].fillna("").astype(str).str.strip()
    problems.add((names == "").to_numpy(), column,
                 lambda i: f"expected a {column} name, found an empty cell.")
    return names


def require_columns(df: pd.DataFrame, columns: Iterable[str], name: str | None,
                    form: str) -> None:
    missing = [c for c in columns if c not in df.columns]
    if not missing:
        return
    if len(df.columns) == 1:
        # One column named like "ball x_mm y_mm": the separator is neither comma,
        # semicolon nor tab, so listing missing columns would only confuse.
        raise DataError(f"found a single column {cut_repr(df.columns[0])}; expected {form} columns "
                        f"{','.join(columns)} separated by commas.", file=name, row=1,
                        hint="save the table as CSV with commas (or semicolons or tabs) "
                             "between the columns.")
    raise DataError(f"missing column(s) {', '.join(missing)}; expected {form} columns "
                    f"{','.join(columns)}, found {','.join(df.columns)}.", file=name,
                    row=1, column=missing[0],
                    hint=_COLUMNS_HINT)


def require_rows(df: pd.DataFrame, name: str | None, what: str) -> None:
    """A file with a header but no data would load as an empty dataset: refuse it."""
    if len(df) == 0:
        raise DataError(f"has no data rows; expected a header followed by one row per "
                        f"{what}.", file=name,
                        hint="export the measured values, not only the column names.")


def read_json(source: FileSource, name: str | None = None) -> tuple[Any, str]:
    """Parse JSON from a path, bytes, text or file-like object; every failure a DataError.

    A UTF-8 byte-order mark is tolerated as in CSV files; binary or non-UTF-8 content,
    invalid JSON and absurdly nested documents are refused naming the file.

    Returns
    -------
    obj, name
        The parsed document and the file name used in messages.
    """
    if isinstance(source, (str, Path)) and not (isinstance(source, str)
                                                and source.lstrip()[:1] in ("{", "[")):
        data, name = read_bytes(source, name)
    elif isinstance(source, str):
        data = source.encode()
    else:
        data, name = read_bytes(source, name)
    name = name or "uploaded file"
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DataError("is not UTF-8 text (a binary file, or another encoding); expected "
                        "a JSON document.", file=name) from None
    if not text.strip():
        raise DataError("file is empty; expected a JSON document.", file=name)
    try:
        return json.loads(text), name
    except json.JSONDecodeError as exc:
        raise DataError(f"is not valid JSON: {exc.msg} at line {exc.lineno}, column "
                        f"{exc.colno}.", file=name,
                        hint="check the quotes, commas and brackets near that place.") from None
    except (RecursionError, ValueError) as exc:
        raise DataError(f"is not valid JSON ({cut_repr(str(exc), 80)}).", file=name) from None

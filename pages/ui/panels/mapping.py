"""The Data page's panel for foreign files: any delimited table through a column mapping,
or a DMIS output file (.dmo) or a QIF 3.0 results document (.qif, or .xml that is one)
through a label pattern, previewed before anything is loaded.

:func:`mapping_panel` only gathers inputs, calls the core (:mod:`cmm_core.io.table_mapping`,
:mod:`cmm_core.io.dmis`, :mod:`cmm_core.io.qif`) and draws; every core error is one
``st.error`` line.
"""

from __future__ import annotations

import hashlib

import streamlit as st

from cmm_core.io import (
    DECIMALS,
    DMIS_SUFFIXES,
    LENGTH_UNITS_MM,
    QIF_LABEL_PATTERN,
    QIF_SUFFIXES,
    TIME_UNITS_MIN,
    DataError,
    ForeignTable,
    TableMapping,
    apply_mapping,
    inspect_table,
    is_qif,
    preview,
    read_dmis,
    read_qif,
)

NONE = "(none)"
PREVIEW_ROWS = 10
PROBLEMS_SHOWN = 8
DEFAULT_PATTERN = r"(?P<position>BP\d+)_(?P<ball>\d+)"
_DELIMS = {"auto": "auto", ",": "comma", ";": "semicolon", "\t": "tab"}
_UNIT_WORDS = {"mm": "mm", "um": "µm", "inch": "inch"}


def _message(exc: Exception) -> str:
    """One line for any failure: a DataError as the core words it."""
    return str(exc) if isinstance(exc, DataError) else f"{type(exc).__name__}: {exc}"


def _errors(lines) -> None:
    """The first problems, one st.error line each, and how many are not shown."""
    for line in lines[:PROBLEMS_SHOWN]:
        st.error(line)
    if len(lines) > PROBLEMS_SHOWN:
        st.caption(f"... and {len(lines) - PROBLEMS_SHOWN} more problem(s): fix these and "
                   "the preview shows the rest.")


def _notes(notes) -> None:
    for note in notes:
        st.caption(note)


def _pick(label, columns, key, default=None, help=None):
    """A selectbox over the table's columns, ``(none)`` first; None when none is picked."""
    options = [NONE, *columns]
    index = options.index(default) if default in options else 0
    value = st.selectbox(label, options, index=index, key=key, help=help)
    return None if value == NONE else value


_SPHERE_FILES = {
    "dmis": ("DMIS label pattern", DEFAULT_PATTERN, read_dmis,
             "(?P<position>BP\\d+)_(?P<ball>\\d+) reads BP111_5 as position BP111, ball 5."),
    "qif": ("QIF label pattern", QIF_LABEL_PATTERN, read_qif,
            "the default reads the labels this program's QIF export writes, BP111/1/5 as "
            "position BP111, probe 1, ball 5."),
}
"""Kind -> (pattern label, default pattern, core reader, the example in the help) of the
files whose spheres are labelled (the pattern maps a label to position, probe, ball)."""


def _sphere_panel(data: bytes, name: str, key: str, kind: str):
    """Pattern inputs, the preview of the spheres read, and the table (or None), for a
    DMIS file or a QIF document (``kind``)."""
    label, default, reader, example = _SPHERE_FILES[kind]
    c1, c2, c3 = st.columns([3, 1, 1])
    pattern = c1.text_input(
        label, value=default, key=f"{key}_pattern",
        help="A regular expression a whole sphere label must match, with named groups "
             f"ball and optionally position and probe: {example}")
    probe = c2.text_input("Default probe", value="1", key=f"{key}_probe",
                          help="Probe of spheres whose label has no probe group.")
    position = c3.text_input("Default position", value="", key=f"{key}_position",
                             help="Position of spheres whose label has no position group "
                                  "(one file per placement).")
    try:
        table = reader(data, name=name, pattern=pattern, default_probe=probe.strip() or "1",
                       default_position=position.strip() or None)
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        st.error(_message(exc))
        return None
    st.dataframe(table.meas.drop(columns="source").head(PREVIEW_ROWS), hide_index=True,
                 key=f"{key}_preview")
    st.caption(f"{len(table.meas)} sphere(s) read; the first {min(PREVIEW_ROWS, len(table.meas))} "
               "shown (mm).")
    _notes(table.notes)
    return table


_COLUMN_PICKERS = (
    ("x", "x column", "x", None), ("y", "y column", "y", None), ("z", "z column", "z", None),
    ("ball", "Ball column", "ball",
     "Ball numbers 1..N; or leave (none) and read them from a label."),
    ("position", "Position column", "pos", None), ("probe", "Probe column", "probe", None))
"""(TableMapping field, picker label, widget key suffix, help) of the column pickers."""


def _mapping_inputs(info, key: str):
    """The column pickers, unit, decimal and delimiter inputs: a TableMapping or None."""
    cols, sug = info.columns, info.suggestion
    picked = {}
    for k, (field, label, suffix, hint) in enumerate(_COLUMN_PICKERS):
        if k % 3 == 0:
            c = st.columns(3)
        with c[k % 3]:
            picked[field] = _pick(label, cols, f"{key}_{suffix}", sug.get(field), help=hint)
    x, y, z, ball, position, probe = (picked[f] for f in ("x", "y", "z", "ball", "position",
                                                          "probe"))
    c = st.columns(3)
    with c[0]:
        label = _pick("Label column", cols, f"{key}_label", sug.get("label"),
                      help="Feature names such as BP111_5, read with the pattern.")
    pattern = c[1].text_input("Label pattern", value=DEFAULT_PATTERN, key=f"{key}_pattern",
                              disabled=label is None,
                              help="Named groups ball and optionally position and probe.")
    const_pos = c[2].text_input("Constant position", value="", key=f"{key}_cpos",
                                help="Position of every row when no column or label gives it.")
    c = st.columns(3)
    with c[0]:
        time_col = _pick("Time column (optional)", cols, f"{key}_time", sug.get("time"))
    time_unit = c[1].radio("Time unit", list(TIME_UNITS_MIN), key=f"{key}_tunit",
                           horizontal=True)
    with c[2]:
        temp = _pick("Plate temperature column, °C (optional)", cols, f"{key}_temp",
                     sug.get("temperature"))
    c = st.columns(4)
    const_probe = c[0].text_input("Constant probe", value="1", key=f"{key}_cprobe",
                                  help="Probe of every row when no column or label gives it.")
    unit = c[1].radio("Length unit", list(LENGTH_UNITS_MM), key=f"{key}_unit",
                      format_func=_UNIT_WORDS.get, horizontal=True)
    decimal = c[2].radio("Decimal separator", list(DECIMALS), key=f"{key}_dec",
                         index=DECIMALS.index(info.decimal), horizontal=True)
    delimiter = c[3].selectbox("Field delimiter", list(_DELIMS), key=f"{key}_delim",
                               format_func=_DELIMS.get)
    try:
        return TableMapping(
            x=x, y=y, z=z, position=position, probe=probe, ball=ball,
            label=label, pattern=pattern if label is not None else None,
            time=time_col, temperature=temp, constant_position=const_pos.strip() or None,
            constant_probe=const_probe.strip() or None, unit=unit, time_unit=time_unit,
            decimal=decimal, delimiter=delimiter)
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        st.error(_message(exc))
        return None


def _table_panel(data: bytes, name: str, key: str):
    """Mapping inputs and the preview; the mapping when the preview has no problem."""
    try:
        info = inspect_table(data, name=name)
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        st.error(_message(exc))
        return None
    st.caption(f"{name}: {info.n_rows} row(s), columns {', '.join(info.columns)}.")
    mapping = _mapping_inputs(info, key)
    if mapping is None:
        return None
    pv = preview(data, mapping, name=name, n=PREVIEW_ROWS)
    st.dataframe(pv.rows, hide_index=True, key=f"{key}_preview")
    st.caption(f"Preview: {pv.n_rows} row(s) parsed, the first {len(pv.rows)} shown in the "
               "long form (mm, minutes, °C); nothing is loaded yet.")
    _notes(pv.notes)
    _errors(list(pv.problems))
    return mapping if pv.ok else None


def mapping_panel(key_prefix: str) -> ForeignTable | None:
    """Draw the foreign-file panel; the converted table when "Load mapped table" is pressed.

    Parameters
    ----------
    key_prefix : str
        Prefix of every widget key (the panel may be drawn more than once).

    Returns
    -------
    ForeignTable or None
        The file in the long form (``.meas``, ``.csv_text``, ``.as_source()``) in the run
        in which the button was pressed and the file converted; None otherwise.
    """
    st.write("A table from other software (any columns, mm, µm or inch, decimal point or "
             "comma), a DMIS output file (.dmo) or a QIF 3.0 results document (.qif, .xml): "
             "pick what each column (or sphere label) means, check the preview, then load "
             "(docs/foreign-formats.md; QIF: docs/formats.md).")
    upload = st.file_uploader("Table (CSV/TXT), DMIS output (.dmo) or QIF 3.0 (.qif, .xml)",
                              type=["csv", "txt", "tsv", *(s[1:] for s in DMIS_SUFFIXES),
                                    *(s[1:] for s in QIF_SUFFIXES), "xml"],
                              key=f"{key_prefix}_file")
    if upload is None:
        return None
    data, name = upload.getvalue(), upload.name
    # widgets keyed by the file: another file starts from its own suggestions
    key = f"{key_prefix}_{hashlib.sha1(data).hexdigest()[:10]}"
    # by content too: a CMM's software often names its QIF results .xml
    kind = "qif" if is_qif(data, name) else \
        "dmis" if name.lower().endswith(DMIS_SUFFIXES) else None
    if kind is not None:
        table = _sphere_panel(data, name, key, kind)
        ready = table is not None
    else:
        mapping = _table_panel(data, name, key)
        ready = mapping is not None
    pressed = st.button("Load mapped table", key=f"{key}_load", type="primary",
                        disabled=not ready)
    if not (pressed and ready):
        return None
    if kind is not None:
        return table
    try:
        return apply_mapping(data, mapping, name=name)
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        st.error(_message(exc))
        return None

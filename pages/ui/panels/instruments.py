"""The Data page's instrument panel: laser runs, step gauges and ball bars fitted jointly
with the plate (each file checked by the core's reader, then together against the
machine's strokes)."""

from __future__ import annotations

import streamlit as st

from cmm_core import analysis as A
from cmm_core import model as M
from pages.ui import cached, calls, state


def _instrument_columns(kind: str) -> str | None:
    """The columns of an instrument file of ``kind`` (``model.instrument_files``), for the help."""

    need = getattr(M, f"{kind.upper()}_COLUMNS", None)
    opt = getattr(M, f"{kind.upper()}_OPTIONAL", ())
    if not need:
        return None
    return (f"Columns {', '.join(need)}" + (f"; optional {', '.join(opt)}" if opt else "")
            + ". Machine axes, mm; errors and u in µm (docs/instruments.md).")


def _read_instrument_uploads(uploads, have):
    """(kind, name, text) of every uploaded instrument file that reads, and the one-line
    problem of each that does not (the core reader's: file, row, column)."""
    new, errors = [], []
    names = {n for _, n, _ in have}
    for kind, files in uploads.items():
        for f in files or []:
            if f.name in names:
                errors.append(f"{f.name}: a file of this name is already loaded; remove it "
                              "first (the residual tables name instruments by file).")
                continue
            try:
                text = f.getvalue().decode("utf-8-sig")
                state.read_instrument_file(kind, f.name, text)
            except UnicodeDecodeError:
                errors.append(f"{f.name}: is not UTF-8 text; save it as UTF-8 CSV.")
            except Exception as exc:  # noqa: BLE001 - a message, never a traceback
                errors.append(calls.describe_error(exc))
            else:
                new.append((kind, f.name, text))
                names.add(f.name)
    if new and not errors:
        try:  # together, against this machine's strokes
            state.check_instruments(have + new)
        except Exception as exc:  # noqa: BLE001
            errors.append(calls.describe_error(exc))
    return new, errors


def instruments_section():
    """Instrument files fitted jointly with the plate, in an expander drawn only while open
    (its three file fields are the first screen's heaviest widgets, issue 27); it opens by
    itself when instruments are added, removed or refused."""
    s = st.session_state
    items = s.get("instruments") or []
    # opened once by new instruments or a new refusal, then as the user leaves it; the
    # label stays the same (a new label is a new expander, closed)
    now = (len(items), tuple(s.get("instrument_errors") or ()))
    if now != s.get("instruments_shown", (0, ())):
        s["w_instruments_open"] = True
    s["instruments_shown"] = now
    with st.expander("Instruments fitted jointly with the plate (laser, step gauge, ball bar)",
                     key="w_instruments_open", on_change="rerun") as box:
        if box.open:
            _instruments_body(s)
    if items and not box.open:
        st.caption(f"{len(items)} instrument file(s) in every fit: "
                   + ", ".join(n for _, n, _ in items) + ".")


def _instruments_body(s):
    kinds = list(A.instrument_kinds())
    st.write(f"Instrument files ({', '.join(state.INSTRUMENT_NAMES.get(k, k) for k in kinds)}) "
             "observe the machine's errors directly; their readings become rows of every "
             "fit, beside the plate's "
             "(docs/instruments.md). Machine axes, mm; errors and u in µm. Loading another "
             "dataset removes them (they measured the previous machine); a project file "
             "keeps them.")
    gen = s.get("inst_gen", 0)
    sfx = "" if gen == 0 else f"_{gen}"
    cols = st.columns(len(kinds))
    uploads = {}
    for col, kind in zip(cols, kinds, strict=True):
        uploads[kind] = col.file_uploader(
            f"{state.INSTRUMENT_NAMES.get(kind, kind).capitalize()} (CSV)", type=["csv", "txt"],
            accept_multiple_files=True, key=f"up_{kind}{sfx}", help=_instrument_columns(kind))
    if st.button("Add instrument files", key="add_instruments"):
        have = list(s.get("instruments") or [])
        new, errors = _read_instrument_uploads(uploads, have)
        s["instrument_errors"] = errors
        if not new and not errors:
            st.info("Choose instrument files above first.")
        elif not errors:
            state.set_instruments(have + new)
            s["inst_gen"] = gen + 1
            state.loaded(f"Added {len(new)} instrument file(s): "
                    + ", ".join(n for _, n, _ in new) + ". Every fit now includes them.")
    for e in s.get("instrument_errors") or []:
        st.error(e)
    if s.get("instrument_errors"):
        st.caption("Nothing was added: the dataset and the instrument files loaded are "
                   "unchanged.")
    items = s.get("instruments") or []
    if not items:
        st.caption("No instrument files: the fits use the ball plate alone.")
        return
    data = calls.safe(cached.instrument_data, what="Reading the instrument files") or ()
    for i, (kind, name, _) in enumerate(items):
        c1, c2 = st.columns([5, 1])
        n = f", {len(data[i].rows)} readings" if i < len(data) else ""
        c1.markdown(f"**{name}**: {state.INSTRUMENT_NAMES.get(kind, kind)}{n}")
        c2.button("Remove", key=f"rm_instrument_{i}", on_click=state.remove_instrument,
                  args=(i,))

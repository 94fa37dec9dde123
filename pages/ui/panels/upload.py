"""The Data page's upload panel: measurement, setup and certificate files (or a mapped
table from other software), assembled and checked by the core
(``analysis.assemble_upload``: every problem of every file), and loaded as the dataset."""

from __future__ import annotations

import pandas as pd
import streamlit as st

from cmm_core import analysis as A
from pages.ui import state, widgets
from pages.ui.panels.mapping import mapping_panel

HELD = dict(prefixes=("up_meas", "up_setup", "up_cert", "map", "upload_report"),
            text=("up_label",))
"""What keeps the panel drawn while its tab is closed (``widgets.held``)."""


def _dataset_name(label: str, meas: list, mapped) -> str:
    """The user's label, else the file names with the upload's number, so that two
    uploads of files with the same names (measurements.csv) are told apart."""
    if label and label.strip():
        return label.strip()[:80]
    names = [f.name for f in meas] + ([mapped[0]] if mapped else [])
    n = st.session_state.get("upload_count", 0) + 1
    return f"{', '.join(names)[:60]} (upload {n})"


# how the upload states the certificate's uncertainty (issue 24: never assumed); comments,
# not strings under the names: Streamlit's "magic" writes a page script's bare strings
CERT_U_CHOICES = ("As the certificate's u columns or the setup state it",
                  "U(k) = a ⊕ b·L, entered here", "Exact (a noise-free simulation)")


def _certificate_statement_inputs(sfx):
    """The certificate statement of the setup's ``certificate`` section, as entered (None:
    the file's u columns or the setup's own statement)."""
    choice = st.radio("Certificate uncertainty (for a certificate without u_x_um, u_y_um, "
                      "u_z_um columns)", CERT_U_CHOICES, key=f"up_cert_u{sfx}",
                      help="No fit assumes a certificate uncertainty: it comes from the "
                           "file's u columns, the setup's certificate statement, or what "
                           "you enter here (it replaces the setup's statement).")
    if choice == CERT_U_CHOICES[2]:
        return {"exact": True, "source": "entered on the Data page"}
    if choice != CERT_U_CHOICES[1]:
        return None
    c1, c2, c3, c4 = st.columns(4)
    a = c1.number_input("a (µm)", min_value=0.0, max_value=100.0, value=0.0, step=0.01,
                        format="%.3f", key=f"up_cert_a{sfx}",
                        help="constant part of the expanded uncertainty U, µm")
    b = c2.number_input("b (µm per mm)", min_value=0.0, max_value=1.0, value=0.0,
                        step=1e-4, format="%.5f", key=f"up_cert_b{sfx}",
                        help="length part of U, µm per mm of the distance L from ball 1")
    k = c3.number_input("k", min_value=1.0, max_value=3.0, value=2.0, step=0.5,
                        key=f"up_cert_k{sfx}", help="coverage factor of U")
    combine = c4.selectbox("⊕", ("quadrature", "linear"), key=f"up_cert_combine{sfx}",
                           help="quadrature: U = sqrt(a² + (b·L)²); linear: U = a + b·L")
    return {"U_um": [float(a), float(b)], "k": float(k), "combine": combine,
            "source": "entered on the Data page"}


def _show_upload_report():
    """The last failed upload's problems, kept until the next load attempt or success
    (a table drawn only in the run of the button click vanished at the next interaction)."""
    report = st.session_state.get("upload_report")
    if not report:
        return
    files = list(dict.fromkeys(p["file"] for p in report["problems"] if p["file"]))
    st.error(f"Validation found {report['count']} problem(s); the current dataset is "
             "unchanged. The fields keep your files: "
             + (f"replace {', '.join(files)} (× removes a file) and load again."
                if files else "correct what is said below and load again."))
    # every problem and hint in full, open: a table cell cuts long text ("did you mea…")
    st.markdown("\n".join(
        "- " + ", ".join(x for x in (f"**{p['file']}**" if p["file"] else "",
                                     f"row {p['row']}" if p["row"] is not None else "",
                                     f"column {p['column']}" if p["column"] else "")
                         if x)
        + f": {p['problem']}" + (f" *{p['hint']}*" if p["hint"] else "")
        for p in report["problems"]))
    with st.expander("The problems as a table (sortable by file, row, column)"):
        table = pd.DataFrame(report["problems"])
        table["row"] = table["row"].astype("Int64")  # whole row numbers, blank when none
        widgets.dataframe(table, hide_index=True, key="upload_problems")


def upload_section():
    """The upload tab: measurement, setup and certificate files, checked and loaded."""
    st.write("Long form: `position,probe,ball,x_mm,y_mm,z_mm[,time_min,temp_C,repeat]` in one "
             "file, or thesis form `ball,x_mm,y_mm,z_mm`, one file per position (named by the "
             "position). Plus the setup JSON and, optionally, the certificate.")
    # after each successful load the uploaders start empty (new keys): the next upload
    # replaces the files instead of adding to them
    gen = st.session_state.get("upload_gen", 0)
    sfx = "" if gen == 0 else f"_{gen}"
    up_meas = st.file_uploader("Measurement CSV file(s)", type=["csv", "txt"],
                               accept_multiple_files=True, key=f"up_meas{sfx}")
    with st.expander("A table from other software or a DMIS output file (.dmo), mapped"):
        mapped_now = mapping_panel(f"map{sfx}")
    if mapped_now is not None:
        st.session_state["mapped_meas"] = (mapped_now.csv_name, mapped_now.csv_text,
                                           mapped_now.name, mapped_now.source_text,
                                           mapped_now.mapping)
    if st.session_state.get("mapped_meas"):
        st.caption(f"Mapped table ready: {st.session_state['mapped_meas'][0]} (loaded with "
                   "the setup below by 'Load uploaded files').")
    c1, c2 = st.columns(2)
    up_setup = c1.file_uploader("Setup (JSON)", type=["json"], key=f"up_setup{sfx}")
    up_cert = c2.file_uploader("Certificate (CSV, optional)", type=["csv", "txt"],
                               key=f"up_cert{sfx}")
    cert_statement = _certificate_statement_inputs(sfx)
    up_label = st.text_input("Dataset name (optional)", key=f"up_label{sfx}",
                             placeholder="e.g. the folder or job name",
                             help="Shown in the sidebar, the report and the project file. "
                                  "Empty: the file names and the upload's number.")
    use_thesis = st.checkbox("Use the thesis setup for a setup not uploaded (and the thesis "
                             "certificate with it)", value=True, key="use_thesis_setup",
                             help="With a setup of your own, the thesis certificate is never "
                                  "used: your plate is another plate. Without a certificate "
                                  "the plate is self-calibrated.")
    if st.button("Load uploaded files", key="load_upload", type="primary"):
        st.session_state.pop("upload_report", None)
        got = A.assemble_upload(
            [(f.name, f.getvalue()) for f in up_meas or []],
            None if up_setup is None else (up_setup.name, up_setup.getvalue()),
            None if up_cert is None else (up_cert.name, up_cert.getvalue()),
            use_thesis=use_thesis, name=_dataset_name(up_label, up_meas or [],
                                                      st.session_state.get("mapped_meas")),
            mapped=st.session_state.get("mapped_meas"),
            certificate_statement=cert_statement,
            foreign_hint="use the 'Other tools' tab or the mapped import below.",
            load=lambda src: state.load_sources(A.sources_key(src), src))
        if not got.ok:
            # the fields keep the files (issue 41: a refusal that emptied every field lost
            # the good files with the bad); the report names the files to replace
            st.session_state["upload_report"] = {
                "problems": [p.to_dict() for p in got.problems], "count": got.n_problems}
        else:
            state.set_dataset(got.sources, got.origin)
            st.session_state["upload_count"] = st.session_state.get("upload_count", 0) + 1
            st.session_state["upload_gen"] = gen + 1
            st.session_state.pop("mapped_meas", None)
            state.loaded(" ".join([f"Loaded {len(got.sources.measurements)} uploaded "
                                   f"file(s) as '{got.sources.name}'.", *got.notes]
                             + ["The upload fields are cleared: the next upload replaces "
                                "these files."]))
    _show_upload_report()


def held() -> bool:
    """Whether the panel's fields hold something the user put there."""
    return widgets.held(*HELD["prefixes"], text=HELD["text"],
                        changed={"up_cert_u": CERT_U_CHOICES[0], "use_thesis_setup": True})

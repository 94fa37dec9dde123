"""The Data page's tab for the MSL cmm-error-map project's files: plate and ball-bar
snapshots with their metadata, read with that project's conventions
(``docs/msl-format.md``).

Only gathers inputs, calls :func:`cmm_core.io.read_msl_files` (the command line's reader
of ``--msl``, ``--msl-bar`` and ``--msl-metadata``) and draws; every core error is one
line. The plates become the dataset, each bar a step gauge fitted jointly with them.
"""

from __future__ import annotations

import json
from collections import Counter

import streamlit as st

from cmm_core import analysis as A
from cmm_core import io as cio
from pages.ui import calls, state

KINDS = {"simulated": "Simulated (nominal + deviation; the certificate is exact)",
         "measured": "Measured (the coordinates as the CMM reported them)"}

MSL_APP_NAMES = cio.MslNames(
    kind="what the files hold (simulated or measured)", measured="'Measured'",
    simulated="'Simulated'", certificate_u="the certificate U(k=2) a and b",
    certificate_example="a = 0.26 µm, b = 0.0019 µm per mm",
    metadata="the metadata.csv saved with it under Metadata file(s)", machine="",
    plate="upload it under Plate snapshot(s)", bar="upload it under Bar snapshot(s)",
    pairing="upload the metadata.csv saved with it (each metadata file is paired with the "
            "snapshot whose header it repeats)",
    files="upload MSL snapshots under Plate or Bar snapshot(s) and their metadata under "
          "Metadata file(s)", metadata_flag="metadata file", lead_plate="plate snapshot",
    lead_bar="bar snapshot", lead_metadata="metadata file")
"""The MSL readers' refusals in this page's words: its fields, not the keywords of
``io.read_msl_plate`` or the command line's flags."""


def _labelled(*groups) -> list:
    """``[(name, bytes), ...]`` of each group of uploads. MSL saves every snapshot as
    snapshot.csv and every metadata file as metadata.csv, so a name that repeats is told
    apart by the measurement's name in the file's header (``snapshot.csv (XZ)``), or a
    number when that repeats too: messages, notes and step gauges then name one file
    each."""
    uploads = [[(f.name, f.getvalue()) for f in g or []] for g in groups]
    names = Counter(n for g in uploads for n, _ in g)
    taken: set = set()
    out = []
    for g in uploads:
        labelled = []
        for name, data in g:
            label = name
            if names[name] > 1:
                try:
                    label = f"{name} ({cio.msl_header(data, name)[0]})"
                except cio.DataError:  # the reader names the file's problem
                    pass
            base, k = label, 1
            while label in taken:
                k += 1
                label = f"{base} ({k})"
            taken.add(label)
            labelled.append((label, data))
        out.append(labelled)
    return out


def _read(plates, bars, metadata, kind, certificate_u) -> cio.MslFiles:
    """The snapshots read with their metadata, each metadata file paired with the snapshot
    whose header it repeats (``io.msl_header``), in any order, exactly as the command line
    reads them (``io.read_msl_files``)."""
    p, b, m = _labelled(plates, bars, metadata)
    return cio.read_msl_files(p, b, m, kind=kind, certificate_u=certificate_u,
                              names=MSL_APP_NAMES)


def _load(files: cio.MslFiles, kind: str) -> A.DataSources:
    """Make the plates the dataset and the bars its step gauges: both checked first (the
    dataset loads, every bar lies within its machine), so a refusal changes nothing."""
    fd = files.plate()
    sources = A.DataSources(
        name=f"MSL {kind}: {fd.name}",
        measurements=(A.DataFile(f"{fd.name} (as measurements.csv)",
                                 content=fd.measurements_csv),),
        setup=A.DataFile("setup.json", content=json.dumps(fd.setup)),
        certificate=A.DataFile("certificate.csv", content=fd.certificate_csv))
    gauges = [("step_gauge", name, text) for name, text in files.step_gauges()]
    if gauges:
        state.check_instruments(gauges, state.load_sources(A.sources_key(sources), sources))
    key = state.set_dataset(sources, {"kind": "upload",
                                      "setup_source": f"from the MSL files ({fd.name})",
                                      "certificate_source": "MSL's nominal plate"})
    state.set_instruments(gauges)
    if gauges:  # the files bring their own: "instrument files removed" would mislead
        st.session_state["reset_note"] = [n for n in st.session_state.get("reset_note", [])
                                          if "instrument file" not in n]
    st.session_state["msl_notes"] = (key, list(files.notes))
    return sources


def msl_section() -> None:
    """Upload MSL plate and bar snapshots with their metadata, say what they hold, load
    them as the dataset (the plates) and its step gauges (the bars); the reader's notes
    stay under the button while that dataset is loaded."""
    st.write("Snapshots of the MSL cmm-error-map app (each `snapshot.csv` with its "
             "`metadata.csv`), plates and ball bars: ball numbering, origin = location + "
             "probe offset, the artefact's angles, the layout flags and the sign of "
             "simulated deviations are applied as that project defines them "
             "(docs/msl-format.md). The plates are the dataset; each bar is fitted with "
             "them as a step gauge, as `cmm-error-lab fit --msl ... --msl-bar ...` does.")
    c1, c2, c3 = st.columns(3)
    snaps = c1.file_uploader("Plate snapshot(s)", type=["csv"], accept_multiple_files=True,
                             key="msl_snapshots", help="One plate placement each.")
    bars = c2.file_uploader("Bar snapshot(s)", type=["csv"], accept_multiple_files=True,
                            key="msl_bars",
                            help="Ball bars (MSL's step gauges, n × 1 balls), one placement "
                                 "each: one length per ball from ball 1, fitted with the "
                                 "plates as a step gauge.")
    metas = c3.file_uploader("Metadata file(s)", type=["csv"], accept_multiple_files=True,
                             key="msl_metadata",
                             help="The metadata.csv saved with each snapshot, plate or bar, "
                                  "in any order: each is paired with the snapshot whose "
                                  "header it repeats.")
    kind = st.radio("What the files hold (they do not say)", list(KINDS),
                    format_func=KINDS.get, index=None, key="msl_kind", horizontal=True)
    cu = None
    if kind == "measured":
        a, b = st.columns(2)
        u_a = a.number_input("Certificate U(k=2): a (µm)", 0.0, 100.0, None, key="msl_ua",
                             help="U = sqrt(a² + (b·L)²), L in mm from ball 1: the "
                                  "certificate of the one plate all these snapshots "
                                  "measured (snapshots of another plate are refused: "
                                  "load each plate on its own, with its statement). A "
                                  "measured bar's lengths take the same statement, as on "
                                  "the command line.")
        u_b = b.number_input("Certificate U(k=2): b (µm per mm)", 0.0, 1.0, None,
                             format="%.5f", key="msl_ub")
        if u_a is not None and u_b is not None:
            cu = {"U_um": [float(u_a), float(u_b)], "k": 2, "combine": "quadrature"}
    if st.button("Load MSL files", key="load_msl", type="primary"):
        _on_load(snaps, bars, metas, kind, cu)
    shown = st.session_state.get("msl_notes")
    if shown and shown[0] == st.session_state.get("ds_key"):
        st.caption("How the MSL files were read (the reader's notes: what it applied, "
                   "assumed or left out):")
        for note in shown[1]:
            st.caption(note)


def _on_load(snaps, bars, metas, kind, cu) -> None:
    if not snaps and not bars:
        st.error("No snapshot file given: upload at least one MSL plate snapshot.")
        return
    if kind is None:
        st.error("Say what the files hold (simulated or measured): the files do not say, "
                 "and the sign of their deviations depends on it.")
        return
    if not snaps:
        st.error("A bar alone has no plate: upload the plate snapshot(s) it is fitted with "
                 "too, or fit the bar alone from the command line (cmm-error-lab fit "
                 "--msl-bar SNAPSHOT.csv --msl-kind KIND).")
        return
    try:
        files = _read(snaps, bars, metas, kind, cu)
        sources = _load(files, kind)
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        st.error(calls.describe_error(exc))
        return
    st.success(f"Loaded the MSL files as '{sources.name}'"
               + (f", with {len(files.bars)} bar(s) as step gauge(s) fitted jointly"
                  if files.bars else "") + ".")

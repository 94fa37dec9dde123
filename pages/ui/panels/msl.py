"""The Data page's tab for the MSL cmm-error-map project's files: plate snapshots with
their metadata, read with that project's conventions (``docs/msl-format.md``).

Only gathers inputs, calls :func:`cmm_core.io.read_msl_plate` and
:func:`cmm_core.io.combine_plates`, and draws; every core error is one line.
"""

from __future__ import annotations

import json

import streamlit as st

from cmm_core import analysis as A
from cmm_core import io as cio
from pages.ui import calls, state

KINDS = {"simulated": "Simulated (nominal + deviation; the certificate is exact)",
         "measured": "Measured (the coordinates as the CMM reported them)"}


def _read(snapshots, metadata, kind, certificate_u):
    """The combined dataset files of the snapshots, each paired with the metadata file
    whose header it repeats (``io.msl_header``), in any order, as the command line
    pairs them."""
    by_header = {}
    for m in metadata:
        by_header.setdefault(cio.msl_header(m.getvalue(), m.name), m)
    pairs = [(s, by_header.get(cio.msl_header(s.getvalue(), s.name))) for s in snapshots]
    unpaired = [m.name for m in metadata if all(m is not p for _, p in pairs)]
    if unpaired:
        raise cio.DataError("no snapshot has the header of this metadata file (its name, "
                            "artefact, location and rotation); expected the metadata.csv "
                            "saved with one of the snapshots.", file=unpaired[0])
    plates = [cio.read_msl_plate(s.getvalue(), None if m is None else m.getvalue(),
                                 kind=kind, certificate_u=certificate_u,
                                 snapshot_name=s.name,
                                 metadata_name=None if m is None else m.name)
              for s, m in pairs]
    return cio.combine_plates(plates)


def msl_section() -> None:
    """Upload MSL snapshot + metadata files, say what they hold, load them as the dataset."""
    st.write("Plate snapshots of the MSL cmm-error-map app (`snapshot.csv` with its "
             "`metadata.csv`): ball numbering, origin = location + probe offset, the plate's "
             "angles, the layout flags and the sign of simulated deviations are applied as "
             "that project defines them (docs/msl-format.md).")
    c1, c2 = st.columns(2)
    snaps = c1.file_uploader("Snapshot file(s)", type=["csv"], accept_multiple_files=True,
                             key="msl_snapshots", help="One plate placement each.")
    metas = c2.file_uploader("Metadata file(s)", type=["csv"], accept_multiple_files=True,
                             key="msl_metadata",
                             help="The metadata.csv saved with each snapshot, in any "
                                  "order: each is paired with the snapshot whose header "
                                  "it repeats.")
    kind = st.radio("What the files hold (they do not say)", list(KINDS),
                    format_func=KINDS.get, index=None, key="msl_kind", horizontal=True)
    cu = None
    if kind == "measured":
        a, b = st.columns(2)
        u_a = a.number_input("Certificate U(k=2): a (µm)", 0.0, 100.0, None, key="msl_ua",
                             help="U = sqrt(a² + (b·L)²), L in mm from ball 1: the "
                                  "certificate of the one artefact all these snapshots "
                                  "measured (snapshots of another artefact are refused: "
                                  "load each artefact on its own, with its statement).")
        u_b = b.number_input("Certificate U(k=2): b (µm per mm)", 0.0, 1.0, None,
                             format="%.5f", key="msl_ub")
        if u_a is not None and u_b is not None:
            cu = {"U_um": [float(u_a), float(u_b)], "k": 2, "combine": "quadrature"}
    if not st.button("Load MSL files", key="load_msl", type="primary"):
        return
    if not snaps:
        st.error("No snapshot file given: upload at least one MSL snapshot.")
        return
    if kind is None:
        st.error("Say what the files hold (simulated or measured): the files do not say, "
                 "and the sign of their deviations depends on it.")
        return
    try:
        fd = _read(snaps, metas, kind, cu)
        sources = A.DataSources(
            name=f"MSL {kind}: {fd.name}",
            measurements=(A.DataFile(f"{fd.name} (as measurements.csv)",
                                     content=fd.measurements_csv),),
            setup=A.DataFile("setup.json", content=json.dumps(fd.setup)),
            certificate=A.DataFile("certificate.csv", content=fd.certificate_csv))
        state.set_dataset(sources, {"kind": "upload",
                                    "setup_source": f"from the MSL files ({fd.name})",
                                    "certificate_source": "MSL's nominal plate"})
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        st.error(calls.describe_error(exc))
        return
    st.success(f"Loaded the MSL files as '{sources.name}'.")
    for note in fd.notes:
        st.caption(note)

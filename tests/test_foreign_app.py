"""Other tools' files in the app (issue 24): MSL snapshots on their own tab, a DMIS file
through the mapped import on the upload tab, each loaded as the dataset and fitted, and a
foreign file given to the plain uploader named with the reader that takes it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from conftest import open_data_tab
from conftest import uploader as _uploader
from streamlit.testing.v1 import AppTest
from test_foreign_tables import PATTERN, _dmo, _vendor_feature_csv
from test_msl import msl_files_of, simulated_machine

from cmm_core import analysis as A
from cmm_core.io import TableMapping, apply_mapping
from cmm_core.model import simulate
from pages.ui.session import session_record

ROOT = Path(__file__).resolve().parents[1]
APP = str(ROOT / "app.py")


def _new():
    at = AppTest.from_file(APP, default_timeout=90)
    at.run()
    return at


def _ok(at):
    assert not at.exception, [e.message for e in at.exception]
    assert not at.error, [e.value for e in at.error]


def _files(paths):
    return [(Path(p).name, Path(p).read_bytes(), "text/csv") for p in paths]


def _cert_csv(cert) -> str:
    """The simulated certificate as a certificate CSV with 0.1 µm per coordinate."""
    return "ball,x_mm,y_mm,z_mm,u_x_um,u_y_um,u_z_um\n" + "\n".join(
        f"{b},{x:.6f},{y:.6f},{z:.6f},0.1,0.1,0.1"
        for b, (x, y, z) in zip(cert.balls, cert.xyz_mm, strict=True))


def _load_mapped(at, name, content, mime, pattern, sim):
    """On the Data page: a foreign file through the mapped import with ``pattern``, then
    the simulation's setup and certificate uploaded and everything loaded."""
    at.switch_page("pages/data.py")
    open_data_tab(at, "Upload CSVs")
    at.file_uploader(key="map_file").set_value((name, content, mime))
    at.run()
    next(t for t in at.text_input if t.key.endswith("_pattern")).set_value(pattern)
    at.run()
    _ok(at)
    next(b for b in at.button if b.key.endswith("_load") and b.key.startswith("map")).click()
    at.run()
    _ok(at)
    setup = json.dumps(sim.dataset.setup.raw).encode()
    _uploader(at, "Setup").set_value(("setup.json", setup, "application/json"))
    _uploader(at, "Certificate").set_value(
        ("cert.csv", _cert_csv(sim.dataset.certificate).encode(), "text/csv"))
    at.button(key="load_upload").click()
    at.run()
    _ok(at)


def test_msl_snapshots_load_on_their_tab_and_fit(tmp_path):
    sim, _coef = simulated_machine("fixed_bridge_xfyz")
    pairs = msl_files_of(sim, tmp_path, "simulated", "fixed_bridge_xfyz")
    at = _new()
    at.switch_page("pages/data.py")
    at.session_state["data_tab"] = "Other tools (MSL)"  # drawn only while open (issue 27)
    at.run()
    at.file_uploader(key="msl_snapshots").set_value(_files([s for s, _m in pairs]))
    # in the reverse order: each metadata file is paired with the snapshot whose header it
    # repeats, as the command line pairs them (issue 42)
    at.file_uploader(key="msl_metadata").set_value(_files([m for _s, m in pairs][::-1]))
    at.button(key="load_msl").click()
    at.run()
    # the kind is not guessed: nothing loads until the user says what the files hold
    assert any("simulated or measured" in e.value for e in at.error)
    at.radio(key="msl_kind").set_value("simulated")
    at.button(key="load_msl").click()
    at.run()
    _ok(at)
    assert at.session_state["sources"].name.startswith("MSL simulated")
    at.run()  # the sidebar is drawn before the page: the next run shows the new dataset
    assert any("exact" in c.value for c in at.sidebar.caption)  # where u came from
    at.switch_page("pages/kinematic.py")
    at.run()
    _ok(at)


def test_a_dmis_file_loads_through_the_mapped_import_and_fits():
    sim = simulate({"seed": 4, "noise_um": 0.3})
    meas = sim.dataset.meas[["position", "probe", "ball", "time_min", "x_mm", "y_mm", "z_mm"]]
    at = _new()
    _load_mapped(at, "run.dmo", _dmo(meas), "text/plain",
                 r"(?P<position>BP\d+)_P(?P<probe>\w+)_B(?P<ball>\d+)", sim)
    assert "run.dmo" in at.session_state["sources"].name
    at.switch_page("pages/kinematic.py")
    at.run()
    _ok(at)
    rms = [m.value for m in at.metric if "RMS" in m.label]
    assert rms and float(str(rms[0]).split()[0]) < 0.6  # σ 0.3 µm simulated


def test_an_msl_file_given_to_the_plain_uploader_is_named(tmp_path):
    sim, _coef = simulated_machine("fixed_bridge_xfyz")
    snapshot, _meta = msl_files_of(sim, tmp_path, "simulated", "fixed_bridge_xfyz")[0]
    at = _new()
    at.switch_page("pages/data.py")
    at.run()
    _uploader(at, "Measurement CSV").set_value(_files([snapshot]))
    at.button(key="load_upload").click()
    at.run()
    assert not at.exception
    probs = next(d.value for d in at.dataframe if "hint" in d.value.columns)
    assert "MSL" in probs.iloc[0]["problem"] and "Other tools" in probs.iloc[0]["hint"]
    assert np.all(probs["file"] == Path(snapshot).name)


def test_a_mapped_vendor_table_keeps_its_mapping_in_the_record():
    """A vendor table through the column mapping: the session keeps the source table and
    its mapping, so the analysis record and the project file reload it through them."""
    from test_foreign_tables import PATTERN, _vendor_feature_csv

    from cmm_core import analysis as A

    sim = simulate({"seed": 4, "noise_um": 0.3})
    meas = sim.dataset.meas[["position", "probe", "ball", "x_mm", "y_mm", "z_mm"]]
    table = _vendor_feature_csv(meas)
    at = _new()
    _load_mapped(at, "vendor.csv", table, "text/csv", PATTERN, sim)
    files = at.session_state["sources"]
    (f,) = files.measurements
    source, source_text, mapping = f.name, f.source_text(), f.mapping
    assert source == "vendor.csv" and source_text == table.decode()
    assert mapping["label"] == "Feature" and mapping["pattern"] == PATTERN
    rec = session_record({"sources": files})
    assert rec.data.measurements[0].mapping == mapping
    back = A.load_data(A.record_from_project(A.record_to_project_json(rec)))
    np.testing.assert_allclose(back.meas[["x_mm", "y_mm", "z_mm"]].to_numpy(),
                               meas[["x_mm", "y_mm", "z_mm"]].to_numpy(), atol=1e-6, rtol=0)


def test_restored_mapped_project_keeps_the_mapping():
    """A vendor table loaded through a column mapping, saved in a project file and
    restored on the Data page keeps its source and mapping, so the next save (or the
    session kept for a reload) still carries them (issue 24)."""
    sim = simulate({"seed": 4, "noise_um": 0.3})
    meas = sim.dataset.meas[["position", "probe", "ball", "x_mm", "y_mm", "z_mm"]]
    m = TableMapping(x="X", y="Y", z="Z", label="Feature", pattern=PATTERN)
    t = apply_mapping(_vendor_feature_csv(meas), m, name="vendor.csv")
    ctext = _cert_csv(sim.dataset.certificate)
    files = A.DataSources("v", (A.DataFile(t.name, content=t.source_text, mapping=t.mapping),),
                          A.DataFile("setup.json", content=json.dumps(sim.dataset.setup.raw)),
                          A.DataFile("c.csv", content=ctext))
    rec = session_record({"sources": files})
    text = A.record_to_project_json(rec)
    at = AppTest.from_file(APP, default_timeout=90)
    at.run()
    at.switch_page("pages/data.py")
    at.run()
    _uploader(at, "Project file").set_value(("p.json", text.encode(), "application/json"))
    at.run()
    at.button(key="restore_project").click()
    at.run()
    assert not at.exception and not at.error, [e.value for e in at.error]
    again = session_record({"sources": at.session_state["sources"]})
    assert again.data.measurements[0].mapping == m.to_dict()

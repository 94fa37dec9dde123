"""MSL ball bars in the app (issue 42, "MSL files both ways"): the Data page's "Other tools
(MSL)" tab loads plate and bar snapshots together with their metadata, as the command
line's ``--msl ... --msl-bar ...`` does (both call ``io.read_msl_files``): the plates
become the dataset, each bar a step gauge fitted with them, and the reader's notes are
shown. A bad bar file is one line naming the file. The files are written here in MSL's
format from this project's simulator (none of MSL's own files)."""

from __future__ import annotations

import io
from pathlib import Path

from streamlit.testing.v1 import AppTest
from test_msl import msl_files_of, simulated_machine
from test_msl_both_ways import LAYOUT, write_bar

from cmm_core import analysis as A
from cmm_core.model import read_instrument

ROOT = Path(__file__).resolve().parents[1]
APP = str(ROOT / "app.py")


def _files(paths):
    """Uploads as MSL saves them: every snapshot is snapshot.csv, every metadata file
    metadata.csv (the page tells the uploads apart)."""
    return [(Path(p).name, Path(p).read_bytes(), "text/csv") for p in paths]


def _msl_tab():
    at = AppTest.from_file(APP, default_timeout=120)
    at.run()
    at.switch_page("pages/data.py")
    at.session_state["data_tab"] = "Other tools (MSL)"  # drawn only while open (issue 27)
    at.run()
    return at


def _load(at, plates, bars, metas, kind="simulated"):
    at.file_uploader(key="msl_snapshots").set_value(_files(plates))
    at.file_uploader(key="msl_bars").set_value(_files(bars))
    at.file_uploader(key="msl_metadata").set_value(_files(metas))
    at.radio(key="msl_kind").set_value(kind)
    at.button(key="load_msl").click()
    at.run()


def test_a_plate_and_a_bar_load_together_with_the_readers_notes(tmp_path):
    sim, _truth = simulated_machine(LAYOUT)
    pairs = msl_files_of(sim, tmp_path, "simulated", LAYOUT)
    plate, plate_meta = next((s, m) for s, m in pairs if s.parent.name == "XZ")
    bar = write_bar(sim, tmp_path / "bar")
    at = _msl_tab()
    # the bar's metadata first: each file is paired by the header it repeats
    _load(at, [plate], [bar], [bar.with_name("metadata.csv"), plate_meta])
    assert not at.exception, [e.message for e in at.exception]
    assert not at.error, [e.value for e in at.error]
    # the dataset is the plate ...
    sources = at.session_state["sources"]
    assert sources.name.startswith("MSL simulated")
    ds = A.load_sources(sources)
    assert set(ds.positions) == {"XZ"} and len(ds.meas) == 25
    # ... and the bar its step gauge, 30 lengths from ball 1, fitted with it
    (kind, name, text), = at.session_state["instruments"]
    assert kind == "step_gauge" and "as a step gauge" in name
    gauge = read_instrument(io.StringIO(text), "step_gauge", name=name)
    assert len(gauge.rows) == 30
    # the reader's notes, each convention once for both snapshots, the bar's own too
    captions = [c.value for c in at.caption]
    assert any(c.startswith("every MSL snapshot: kind: simulated") for c in captions)
    assert any(": lengths: from ball 1 to balls 2-31" in c for c in captions)
    assert any(": u_um: " in c for c in captions)
    assert any("1 bar(s) as step gauge(s)" in s.value for s in at.success)
    at.run()  # the notes stay while this dataset is loaded
    assert any(c.value.startswith("every MSL snapshot: kind:") for c in at.caption)
    at.switch_page("pages/kinematic.py")  # the plate and the bar fit together
    at.run()
    assert not at.exception, [e.message for e in at.exception]
    assert not at.error, [e.value for e in at.error]


def test_a_bad_bar_file_is_one_line_naming_the_file(tmp_path):
    sim, _truth = simulated_machine(LAYOUT)
    pairs = msl_files_of(sim, tmp_path, "simulated", LAYOUT)
    plate, plate_meta = next((s, m) for s, m in pairs if s.parent.name == "XZ")
    bar = write_bar(sim, tmp_path / "bar")
    lines = bar.read_text().splitlines()
    lines[11] = "2,40.00005,abc,0.00000"  # ball id 2 (file row 12): y not a number
    bad = tmp_path / "bad_bar.csv"
    bad.write_text("\n".join(lines) + "\n")
    at = _msl_tab()
    before = at.session_state["sources"].name
    _load(at, [plate], [bad], [plate_meta, bar.with_name("metadata.csv")])
    assert not at.exception, [e.message for e in at.exception]
    (err,) = at.error
    assert "bad_bar.csv" in err.value and "row 12" in err.value and "mmt_y" in err.value
    assert "bar snapshot" in err.value and "\n" not in err.value
    assert "Traceback" not in err.value
    assert at.session_state["sources"].name == before  # nothing loaded
    assert not at.session_state["instruments"]
    # a plate given as a bar is sent to the plate field, in the page's words
    xy, xy_meta = next((s, m) for s, m in pairs if s.parent.name == "XY")
    _load(at, [xy], [plate], [xy_meta, plate_meta])
    (err,) = at.error
    assert "snapshot.csv" in err.value and "Plate snapshot(s)" in err.value
    assert "read_msl" not in err.value and "--msl" not in err.value

"""The Compensate and export page with models whose blocks read more than coordinates."""

from pathlib import Path

import pytest

pytest.importorskip("streamlit")
from conftest import uploader as _uploader  # noqa: E402
from streamlit.testing.v1 import AppTest  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def test_export_page_corrects_its_example_points_with_a_machine_thermal_model(tmp_path):
    """A fit with machine_thermal: the example points (the fit's own rows) carry their
    scale temperatures, so the page corrects them as it opens (it failed: "needs
    temp_x_C"), and the upload caption names the columns a points file needs."""
    from cmm_core.model import simulate

    d = tmp_path / "thermal"
    simulate({"seed": 2, "effects": {"machine_thermal": {
        "x_cte_per_K": 4e-6, "y_cte_per_K": -3e-6, "z_cte_per_K": 2e-6}}}).write(d)
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.run()
    at.switch_page("pages/data.py")
    at.run()
    _uploader(at, "Measurement CSV").set_value(
        [("measurements.csv", (d / "measurements.csv").read_bytes(), "text/csv")])
    _uploader(at, "Setup").set_value(
        [("setup.json", (d / "setup.json").read_bytes(), "application/json")])
    at.button(key="load_upload").click()
    at.run()
    at.switch_page("pages/kinematic.py")
    at.run()
    at.text_input(key="w_spec").input("kinematic21,machine_thermal")
    at.run()
    assert not at.exception, [e.message for e in at.exception]
    at.switch_page("pages/export.py")
    at.run()
    assert not at.exception, [e.message for e in at.exception]
    assert not at.error, [e.value for e in at.error]
    keys = {b.key for b in at.get("download_button")}
    assert "dl_corrected" in keys
    table = next(t.value for t in at.dataframe if "xc_mm" in t.value.columns)
    assert {"temp_x_C", "temp_y_C", "temp_z_C"} <= set(table.columns)
    assert table["xc_mm"].notna().all()
    cap = " ".join(c.value for c in at.caption)
    assert "temp_x_C" in cap and "machine_thermal" in cap


@pytest.mark.parametrize("dataset, expected", [
    ("thesis tables 6.1-6.6", "thesis_tables_6.1-6.6_2026-11-26_cmm_model.json"),
    ("../../etc/passwd", "etc_passwd_2026-11-26_cmm_model.json"),  # never leaves the folder
    ("C:\\lab\\run 3", "C_lab_run_3_2026-11-26_cmm_model.json"),
    ("", "2026-11-26_cmm_model.json"),
    ("x" * 100, "x" * 40 + "_2026-11-26_cmm_model.json"),
])
def test_download_names_carry_the_dataset_and_date(dataset, expected):
    """Issue 27: every download was named the same for every dataset, so two datasets'
    downloads overwrote each other; the name now starts with the dataset's and the date,
    made safe for any file system (no separators or spaces, at most 40 characters of
    dataset name)."""
    from cmm_core.export import download_name

    assert download_name(dataset, "cmm_model.json", "2026-11-26") == expected


def test_download_name_defaults_to_today():
    from datetime import datetime

    from cmm_core.export import download_name

    today = datetime.now().strftime("%Y-%m-%d")
    assert download_name("run", "a.csv") in (f"run_{today}_a.csv",
                                             f"run_{datetime.now():%Y-%m-%d}_a.csv")


def test_the_task_section_opens_on_the_loaded_datas_own_styli():
    """Issue 41: with an uploaded dataset whose styli are not the thesis's "1".."6", the
    Compensate page's task section opened on a red error ("stylus '1' is not in the
    model"): its sample task now takes the model's own styli, and the Monte Carlo runs."""
    import json

    from cmm_core.io import THESIS_DIR

    setup = json.loads((THESIS_DIR / "setup.json").read_text())
    setup["probes"] = {f"T{k}": v for k, v in setup["probes"].items()}
    for pos in setup["positions"].values():
        pos["probe"] = f"T{pos['probe']}"
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.run()
    at.switch_page("pages/data.py")
    at.run()
    _uploader(at, "Measurement CSV").set_value(
        [(f"{p}.csv", (THESIS_DIR / f"{p}.csv").read_bytes(), "text/csv")
         for p in setup["positions"]])
    _uploader(at, "Setup").set_value(
        [("setup.json", json.dumps(setup).encode(), "application/json")])
    at.button(key="load_upload").click()
    at.run()
    assert sorted(at.session_state["sources"].name.split(", ")[:1]) == ["BP111.csv"]
    at.switch_page("pages/export.py")
    at.run()
    assert not at.exception, [e.message for e in at.exception]
    assert not at.error, [e.value for e in at.error]
    task = json.loads(next(t.value for t in at.text_area if t.label == "TASK.json"))
    assert {p["probe"] for p in task["points"]} == {"T1"}
    assert any("U = 2u, Monte Carlo (µm)" in d.value.columns for d in at.dataframe)

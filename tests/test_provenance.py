"""Every record names what made it: the software's version and commit, the time, each input
file's SHA-256 and the machine (ISO/IEC 17025 7.5, 7.11). Each kind of output is written
from the thesis data, read back, and its provenance compared with the files themselves
(hashlib over their bytes) and with the setup's machine."""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import re
import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest

import cmm_core
from cmm_core import analysis as A
from cmm_core import export as ex
from cmm_core import monitor as mon
from cmm_core.cli import main
from cmm_core.io import (
    THESIS_DIR,
    THESIS_POSITIONS,
    DataError,
    load_dataset,
    provenance_from_dict,
    software_identity,
)
from cmm_core.model import fit

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "Brown & Sharpe (Leitz) PMM-C700P, S/N 161"
"""The thesis setup's machine.id (thesis appendix 5, the CMM's plate)."""
FILES = [THESIS_DIR / f"{p}.csv" for p in THESIS_POSITIONS]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def thesis():
    ds = load_dataset(FILES, THESIS_DIR / "setup.json", THESIS_DIR / "certificate.csv",
                      name="thesis")
    return ds, fit(ds)


def _expected_inputs():
    paths = [*FILES, THESIS_DIR / "setup.json", THESIS_DIR / "certificate.csv"]
    return [(p.name, _sha(p)) for p in paths]


def _check(prov: dict, inputs=None):
    """The standard part of any record's provenance."""
    ident = software_identity()
    assert prov["software"] == "cmm-error-lab" and prov["version"] == cmm_core.__version__
    assert prov["commit"] == ident["commit"] and prov["dirty"] == ident["dirty"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", prov["created"])
    assert prov["machine"] == MACHINE
    if inputs is not None:
        assert [(f["name"], f["sha256"]) for f in prov["inputs"]] == inputs
    provenance_from_dict(prov)  # it reads back


def test_the_commit_is_the_checkouts_own():
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                          text=True, check=True).stdout.strip()
    assert software_identity()["commit"] == head


def test_a_dataset_knows_the_digest_of_every_file_it_was_read_from(thesis):
    ds, _ = thesis
    assert [(f.name, f.sha256) for f in ds.inputs] == _expected_inputs()
    assert ds.setup.machine_id == MACHINE


def test_the_model_file_carries_it_and_reads_it_back(thesis, tmp_path):
    ds, r = thesis
    ex.save_model(r, tmp_path / "model.json", ds.provenance())
    _check(json.loads((tmp_path / "model.json").read_text())["provenance"], _expected_inputs())
    m = ex.load_model(tmp_path / "model.json")
    assert m.provenance.machine == MACHINE and len(m.provenance.inputs) == 8
    assert m.source.sha256 == _sha(tmp_path / "model.json")


def test_results_json_and_xml_of_a_model_file_name_the_file_and_the_machine(thesis, tmp_path):
    ds, r = thesis
    ex.save_model(r, tmp_path / "model.json", ds.provenance())
    m = ex.load_model(tmp_path / "model.json")
    doc = json.loads(ex.results_json(m))
    _check(doc["provenance"], [("model.json", _sha(tmp_path / "model.json"))])
    head = ET.fromstring(ex.results_xml(m).encode()).find("Header/Provenance")
    assert head.find("Machine").text == MACHINE
    assert head.find("Software").get("version") == cmm_core.__version__
    (inp,) = head.findall("Input")
    assert inp.text == "model.json" and inp.get("sha256") == _sha(tmp_path / "model.json")


def test_compensation_tables_and_the_error_map_say_it_in_their_headers(thesis, tmp_path):
    ds, r = thesis
    prov = ds.provenance()
    g = ex.compensation_grid(r, 200.0)
    texts = [ex.grid_csv(r, g, None, "model.json", prov),
             ex.error_map_csv(r, ex.error_map_grid(r, step_mm=200.0), None, prov)]
    with zipfile.ZipFile(io.BytesIO(ex.axis_tables_zip(r, 100.0, "m.json",
                                                       provenance=prov))) as z:
        texts += [z.read(n).decode() for n in z.namelist()]
    for text in texts:
        head = "\n".join(line for line in text.splitlines() if line.startswith("#"))
        assert f"cmm-error-lab {cmm_core.__version__}" in head and MACHINE in head
        for name, sha in _expected_inputs():
            assert f"input: {name} sha256:{sha}" in head


def test_the_analysis_record_the_project_file_and_the_report(thesis, tmp_path):
    record = A.read_record(ROOT / "sample_data" / "thesis" / "analysis.json")
    inputs = [(f.name, hashlib.sha256(Path(f.path).read_bytes()).hexdigest())
              for f in record.data.files]
    _check(json.loads(A.record_to_json(record))["provenance"], inputs)
    project = json.loads(A.record_to_project_json(record))
    _check(project["provenance"], inputs)
    A.record_from_project(json.dumps(project))  # a project with provenance loads
    html = A.analysis_report(dataclasses.replace(record, diagnose=False))
    section = html[html.index("id='provenance'"):]
    assert MACHINE.replace("&", "&amp;") in section and cmm_core.__version__ in section
    for _, sha in inputs:
        assert sha in section


@pytest.mark.parametrize(("key", "value", "needle"), [
    ("version", 7, "provenance.version"),
    ("dirty", "yes", "provenance.dirty"),
    ("inputs", [{"name": "a.csv", "sha256": "abc", "bytes": 3}], "provenance.inputs[0]"),
    ("machine", ["x"], "provenance.machine"),
])
def test_an_edited_provenance_is_refused_naming_the_key(thesis, key, value, needle):
    ds, _ = thesis
    d = {**ds.provenance().to_dict(), key: value}
    with pytest.raises(DataError, match=re.escape(needle)):
        provenance_from_dict(d, "model.json")


def _setup_of(machine: str) -> dict:
    raw = json.loads((THESIS_DIR / "setup.json").read_text())
    raw["machine"]["id"] = machine
    return raw


def test_a_check_of_another_machines_data_is_refused_in_one_line(thesis, tmp_path):
    ds, r = thesis
    ex.save_model(r, tmp_path / "model.json", ds.provenance())
    m = ex.load_model(tmp_path / "model.json")
    other = load_dataset(FILES[:1], _setup_of("Zeiss Prismo, S/N 7"),
                         THESIS_DIR / "certificate.csv", name="other.csv")
    with pytest.raises(DataError, match="machine.id") as exc:
        mon.interim_check(m, other)
    assert "\n" not in str(exc.value) and "Zeiss Prismo" in str(exc.value)
    same = load_dataset(FILES[:1], _setup_of(MACHINE), THESIS_DIR / "certificate.csv")
    assert mon.interim_check(m, same).dof > 0  # its own machine is checked


def test_a_history_of_two_machines_is_refused_and_an_older_model_is_noted(thesis, tmp_path):
    ds, r = thesis
    ex.save_model(r, tmp_path / "model.json", ds.provenance())
    m = ex.load_model(tmp_path / "model.json")
    other = dataclasses.replace(m, name="other.json", provenance=dataclasses.replace(
        m.provenance, machine="Zeiss Prismo, S/N 7"))
    with pytest.raises(DataError, match="different machines"):
        mon.compare_calibrations([(m, "2024-03-04"), (other, "2025-03-04")])
    old = dataclasses.replace(m, name="old.json", provenance=dataclasses.replace(
        m.provenance, version="0.7.0"))
    legacy = dataclasses.replace(m, name="legacy.json", provenance=None)
    notes = mon.version_notes([m, old, legacy])
    assert len(notes) == 2 and "old.json was made by cmm-error-lab 0.7.0" in notes[0]
    assert "legacy.json" in notes[1] and "before 0.8.0" in notes[1]


HISTORY = ROOT / "sample_data" / "history"


def test_the_command_lines_records_name_their_inputs(tmp_path, capsys):
    """``fit --save``, ``check --results-json`` and ``compare --results-json``: each
    record lists the files the command read, by the SHA-256 of their bytes."""
    model = tmp_path / "model.json"
    args = [*map(str, FILES), "--setup", str(THESIS_DIR / "setup.json"),
            "--certificate", str(THESIS_DIR / "certificate.csv")]
    assert main(["fit", *args, "--save", str(model)]) == 0
    _check(json.loads(model.read_text())["provenance"], _expected_inputs())
    res = tmp_path / "check.json"
    assert main(["check", str(model), *args[:1], *args[6:], "--results-json", str(res)]) == 0
    prov = json.loads(res.read_text())["provenance"]
    names = [f["name"] for f in prov["inputs"]]
    assert names[0] == "model.json" and "BP111.csv" in names and "setup.json" in names
    assert prov["inputs"][0]["sha256"] == _sha(model) and prov["machine"] == MACHINE
    capsys.readouterr()
    cals = sorted(HISTORY.glob("calibration_*.json"))
    dates = [p.stem.split("_")[1] for p in cals]
    out = tmp_path / "history.json"
    assert main(["compare", *map(str, cals), "--dates", *dates, "--results-json",
                 str(out)]) == 0
    err = capsys.readouterr().err
    # the sample calibrations were written before files named their software
    assert err.count("note: ") == len(cals) and "before 0.8.0" in err
    made = json.loads(out.read_text())["provenance"]
    assert sorted(f["sha256"] for f in made["inputs"]) == sorted(_sha(p) for p in cals)


def test_every_commands_json_says_what_made_it(tmp_path, capsys):
    """The printed result of any command names the software and the files it read."""
    budget = ROOT / "sample_data" / "budget" / "ballplate_budget.json"
    assert main(["--json", str(tmp_path / "b.json"), "budget", str(budget)]) == 0
    prov = json.loads((tmp_path / "b.json").read_text())["provenance"]
    assert prov["version"] == cmm_core.__version__
    assert prov["inputs"] == [{"name": budget.name, "sha256": _sha(budget),
                               "bytes": budget.stat().st_size}]
    assert main(["air", "--t-C", "20", "--p-Pa", "101325", "--rh-percent", "50",
                 "--wavelength-nm", "632.99"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["provenance"]["software"] == "cmm-error-lab" and out["provenance"]["inputs"] == []


def _header(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if line.startswith("#"))


def test_the_apps_parameter_residual_and_corrected_point_tables_name_it(thesis):
    ds, r = thesis
    prov = ds.provenance()
    points = ex.read_points(ROOT / "sample_data" / "compensate" / "points.csv")
    corrected = ex.compensate_points(r, points)
    texts = [ex.parameters_csv(r, prov), ex.residuals_csv(r, prov),
             ex.corrected_csv(corrected, prov)]
    for text in texts:
        head = _header(text)
        assert f"cmm-error-lab {cmm_core.__version__}" in head and MACHINE in head
        for name, sha in _expected_inputs():
            assert f"input: {name} sha256:{sha}" in head
    # the product reads its own table back past the comment lines, every row kept
    back = ex.read_points(io.BytesIO(texts[2].encode()), name="corrected.csv")
    assert len(back) == len(points) and list(back["xc_mm"].astype(float)) == pytest.approx(
        list(corrected["xc_mm"]), abs=5e-7)  # written to 6 decimals (1 nm)


def test_compensate_out_names_the_model_and_the_points_file(thesis, tmp_path):
    ds, r = thesis
    model, out = tmp_path / "model.json", tmp_path / "corrected.csv"
    ex.save_model(r, model, ds.provenance())
    points = ROOT / "sample_data" / "compensate" / "points.csv"
    assert main(["compensate", str(model), str(points), "--out", str(out)]) == 0
    head = _header(out.read_text())
    assert f"input: model.json sha256:{_sha(model)}" in head
    assert f"input: points.csv sha256:{_sha(points)}" in head and MACHINE in head
    assert len(ex.read_points(out)) == len(ex.read_points(points))


def test_a_simulations_files_name_the_configuration_that_made_them(tmp_path, capsys):
    cfg = ROOT / "sample_data" / "simulated" / "config.json"
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "sim")]) == 0
    for name in ("setup.json", "truth.json"):
        prov = json.loads((tmp_path / "sim" / name).read_text())["provenance"]
        assert prov["version"] == cmm_core.__version__
        assert prov["inputs"] == [{"name": cfg.name, "sha256": _sha(cfg),
                                   "bytes": cfg.stat().st_size}]
        provenance_from_dict(prov)
    sim = tmp_path / "sim"
    ds = load_dataset([sim / "measurements.csv"], sim / "setup.json", sim / "certificate.csv")
    assert len(ds.meas) > 0  # the setup's provenance key is left alone by the reader

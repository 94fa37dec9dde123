"""QIF 3.0 out and in, wired (issue 42): ``export --qif`` writes the document of a saved
model and the data it was fitted to, the app's Export page offers it for download, and a
QIF document is read wherever foreign measurement files are (``fit`` on the command line,
``io.read_foreign``, the Data page's mapped import). The document itself and its schema
are tests/test_qif.py's.

Tolerances: the document writes every centre as the shortest decimal that reads back as
the same double, and the reader's long form keeps 6 decimals (1 nm); the thesis files have
5 decimals, so every centre read back is the number written, and a fit of it the same fit.
The centres are therefore compared to half a unit in the long form's last place
(0.5e-6 mm), and the parameters to what floating-point summation can change (1e-9)."""

from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from conftest import THESIS, open_data_tab
from conftest import uploader as _uploader
from streamlit.testing.v1 import AppTest

from cmm_core.cli import main
from cmm_core.cli.options import _QIF_LABEL_PATTERN
from cmm_core.export import characteristics, download_name, load_model, qif_document
from cmm_core.io import (
    QIF_LABEL_PATTERN,
    QIF_NS,
    DataError,
    is_qif,
    read_foreign,
    read_qif,
    thesis_dataset,
)
from cmm_core.model import fit

ROOT = Path(__file__).resolve().parents[1]
Q = f"{{{QIF_NS}}}"
LONG_FORM_HALF_DIGIT_MM = 0.5e-6
"""Half a unit in the 6th decimal the reader's long form keeps (see the module)."""
KEYS = ["position", "probe", "ball"]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """The thesis data copied (an output test must never risk the sample files), fitted
    with ``fit --save``: ``(folder, data arguments, model path)``."""
    d = tmp_path_factory.mktemp("thesis")
    for f in THESIS.iterdir():
        if f.suffix in (".csv", ".json"):
            shutil.copy(f, d / f.name)
    data = [*sorted(map(str, d.glob("BP*.csv"))), "--setup", str(d / "setup.json"),
            "--certificate", str(d / "certificate.csv")]
    model = d / "model.json"
    assert main(["fit", *data, "--save", str(model), "--json", str(d / "fit.json")]) == 0
    return d, data, model


def _export(model, data, qif, capsys):
    code = main(["export", str(model), *data, "--qif", str(qif)])
    return code, capsys.readouterr()


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    return lines[0]


def test_export_qif_reads_back_to_the_measured_centres(fitted, capsys, tmp_path):
    d, data, model = fitted
    out = tmp_path / "thesis.qif"
    code, io = _export(model, data, out, capsys)
    assert code == 0, io.err
    assert json.loads(io.out)["qif"] == str(out)
    back = read_qif(out).meas
    ds = thesis_dataset()
    assert back[KEYS].astype(str).values.tolist() == ds.meas[KEYS].astype(str).values.tolist()
    xyz = ["x_mm", "y_mm", "z_mm"]
    assert np.abs(back[xyz].to_numpy() - ds.meas[xyz].to_numpy()).max() \
        <= LONG_FORM_HALF_DIGIT_MM
    # provenance as every other output of export carries it: the model file and, for the
    # document's centres, every data file read, each with its SHA-256
    root = ET.parse(out).getroot()
    attrs = {a.get("name"): a.get("value") for a in root.find(f"{Q}Attributes")}
    assert attrs["software"] == "cmm-error-lab"
    assert attrs["machine"] == ds.setup.machine_id
    names = {k.removeprefix("input ") for k in attrs if k.startswith("input ")}
    assert names == {"model.json", *(f.name for f in ds.inputs)}
    # the model file's characteristics, as its other results files (export --results-json)
    params = root.find(".//{urn:cmm-error-lab:qif:1}Parameters")
    names = [p.get("name") for p in params]
    assert names == [c.name for c in characteristics(load_model(model))]


@pytest.mark.parametrize("target", ["BP111.csv", "setup.json", "model.json"])
def test_export_qif_never_replaces_an_input(fitted, capsys, target):
    d, data, model = fitted
    before = (d / target).read_bytes()
    code, io = _export(model, data, d / target, capsys)
    assert code == 2
    line = _one_error_line(io.err)
    assert "--qif" in line and target in line
    assert (d / target).read_bytes() == before


def test_export_qif_refuses_data_the_model_was_not_fitted_to(fitted, capsys, tmp_path):
    """A document pairing one fit's parameters with other measurements would be a false
    record: the data files must be among the model's recorded inputs, and all of the
    fitted placements must be given."""
    d, data, model = fitted
    other = tmp_path / "BP111.csv"
    text = (d / "BP111.csv").read_text().replace("133.00493", "133.00494")
    other.write_text(text)
    swapped = [str(other) if Path(a).name == "BP111.csv" else a for a in data]
    code, io = _export(model, swapped, tmp_path / "x.qif", capsys)
    assert code == 2
    line = _one_error_line(io.err)
    assert "BP111.csv" in line and "not one of the files model.json was fitted to" in line
    part = [a for a in data if not Path(a).name.startswith(("BP2", "BP3"))]
    code, io = _export(model, part, tmp_path / "x.qif", capsys)
    assert code == 2 and "lacks placement(s) BP211" in _one_error_line(io.err)
    code, io = _export(model, [], tmp_path / "x.qif", capsys)
    assert code == 2 and "needs the data the model was fitted to" in _one_error_line(io.err)
    assert not (tmp_path / "x.qif").exists()


def test_export_data_without_qif_is_refused(fitted, capsys, tmp_path):
    d, data, model = fitted
    code = main(["export", str(model), *data, "--grid", str(tmp_path / "g.csv")])
    assert code == 2
    assert "for --qif only" in _one_error_line(capsys.readouterr().err)


@pytest.fixture(scope="module")
def thesis_qif():
    ds = thesis_dataset()
    r = fit(ds)
    return ds, r, qif_document(r, ds)


def test_a_cli_fit_of_a_qif_document_is_the_fit_of_its_data(fitted, thesis_qif, tmp_path,
                                                             capsys):
    d, data, _ = fitted
    _, _, doc = thesis_qif
    # a CMM's software often names its QIF results .xml: routed by content
    for name in ("thesis.qif", "results.xml"):
        (tmp_path / name).write_bytes(doc)
    ref = json.loads((d / "fit.json").read_text())["parameters"]
    for name in ("thesis.qif", "results.xml"):
        code = main(["fit", str(tmp_path / name), *data[-4:]])
        io = capsys.readouterr()
        assert code == 0, io.err
        got = json.loads(io.out)
        assert got["n_obs"] == 150
        assert set(got["parameters"]) == set(ref)
        for k, v in ref.items():
            assert got["parameters"][k]["value"] == pytest.approx(v["value"], rel=1e-9,
                                                                  abs=1e-9), k
            assert got["parameters"][k]["u"] == pytest.approx(v["u"], rel=1e-9), k


def test_a_bad_qif_file_in_a_fit_is_one_line_naming_file_and_element(fitted, thesis_qif,
                                                                     tmp_path, capsys):
    _, data, _ = fitted
    _, _, doc = thesis_qif
    root = ET.fromstring(doc)
    loc = root.find(f".//{Q}SphereFeatureMeasurement/{Q}Location")
    loc.text = "1.0 two 3.0"
    bad = tmp_path / "bad.qif"
    bad.write_bytes(ET.tostring(root))
    assert main(["fit", str(bad), *data[-4:]]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "bad.qif" in line and "SphereFeatureMeasurement" in line and "Location" in line


def test_read_foreign_routes_qif_by_name_and_content(thesis_qif, tmp_path):
    _, _, doc = thesis_qif
    assert is_qif(doc) and is_qif(b"", "x.QIF") and not is_qif(b"<a/>", "x.xml")
    assert len(read_foreign(doc, name="results.xml").meas) == 150
    p = tmp_path / "plain.qif"
    p.write_bytes(doc)
    t = read_foreign(p, qif_pattern=r"(?P<position>BP1\d+)/(?P<probe>[^/]+)/(?P<ball>\d+)")
    assert set(t.meas["position"]) == {"BP111", "BP112"} and t.unmatched
    with pytest.raises(DataError, match="column mapping"):  # XML, not QIF: a table
        read_foreign(b"<a/>", name="other.xml")


def test_the_help_texts_copy_of_the_qif_label_pattern_is_the_readers():
    assert _QIF_LABEL_PATTERN == QIF_LABEL_PATTERN


def _ok(at):
    assert not at.exception, [e.message for e in at.exception]
    assert not at.error, [e.value for e in at.error]


def test_the_export_page_offers_the_qif_document(downloads):
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=90)
    at.run()
    at.switch_page("pages/export.py")
    at.run()
    _ok(at)
    button = next(b for b in at.get("download_button") if b.key == "dl_qif")
    assert button.proto.label == "QIF 3.0 (.qif)"
    name = download_name(at.session_state["sources"].name, "cmm_calibration.qif")
    assert name in downloads  # named as every other download
    back = read_qif(downloads[name]).meas
    ds = thesis_dataset()
    xyz = ["x_mm", "y_mm", "z_mm"]
    assert np.abs(back[xyz].to_numpy() - ds.meas[xyz].to_numpy()).max() \
        <= LONG_FORM_HALF_DIGIT_MM


def test_the_data_pages_mapped_import_loads_a_qif_document(thesis_qif):
    _, _, doc = thesis_qif
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=90)
    at.run()
    at.switch_page("pages/data.py")
    open_data_tab(at, "Upload CSVs")
    at.file_uploader(key="map_file").set_value(("results.xml", doc, "application/xml"))
    at.run()
    _ok(at)
    pattern = next(t for t in at.text_input if t.key.endswith("_pattern"))
    assert pattern.label == "QIF label pattern" and pattern.value == QIF_LABEL_PATTERN
    next(b for b in at.button if b.key.endswith("_load") and b.key.startswith("map")).click()
    at.run()
    _ok(at)
    # the thesis setup and certificate stand in (the checkbox's default)
    _uploader(at, "Setup")  # the upload tab is drawn
    at.button(key="load_upload").click()
    at.run()
    _ok(at)
    assert "results.xml" in at.session_state["sources"].name

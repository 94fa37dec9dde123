"""QIF 3.0 export (cmm_core.export.qif) validated against the standard's schema, and the
QIF reader (cmm_core.io.qif): round trip and refusals."""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cmm_core.export import EXTENSION_NS, qif_document
from cmm_core.io import QIF_LABEL_PATTERN, QIF_NS, DataError, read_qif, thesis_dataset
from cmm_core.model import fit

ROOT = Path(__file__).resolve().parents[1]
QIF_SCHEMA = ROOT.parent / "shared" / "qif3" / "schema" / "QIFDocument.xsd"
DSIG_NS = "http://www.w3.org/2000/09/xmldsig#"
Q = f"{{{QIF_NS}}}"
X = f"{{{EXTENSION_NS}}}"
FIXED_TIME = "2026-11-24T10:00:00+00:00"


@pytest.fixture(scope="module")
def calibration():
    ds = thesis_dataset()
    return ds, fit(ds)


@pytest.fixture(scope="module")
def full_doc(calibration):
    """Every optional part: nominals (a ball diameter), an MPE, temperature compensation."""
    ds, r = calibration
    return qif_document(r, ds, ball_diameter_mm=30.0, mpe=(0.6, 1 / 600),
                        temperature_compensation="DEVICE_ONLY", created=FIXED_TIME)


@pytest.fixture(scope="module")
def plain_doc(calibration):
    ds, r = calibration
    return qif_document(r, ds, created=FIXED_TIME)


def _complete_substitution_groups(xmlschema, schema) -> None:
    """xmlschema finds the elements an identity constraint's selector picks from the
    declarations, so ``t:FeatureItems/t:*`` picks the abstract head ``FeatureItem`` and
    not the ``SphereFeatureItem`` substituted for it: the key stays empty and every keyref
    to it fails. Give each identity the members of its elements' substitution groups, as
    XSD 1.0 §3.11.4 (the selector selects element nodes of the instance) requires."""
    field_value = xmlschema.validators.identities.FieldValueSelector
    groups = schema.maps.substitution_groups
    for ident in list(schema.maps.identities.values()):
        todo = list(ident.elements)
        while todo:
            head = todo.pop()
            for sub in groups.get(head.name, ()):
                if sub not in ident.elements:
                    ident.elements[sub] = [field_value(f, sub) for f in ident.fields]
                    sub.selected_by.add(ident)
                    todo.append(sub)


@pytest.fixture(scope="module")
def qif_schema():
    """The QIF 3.0 schema, built once (tens of seconds), offline: its import of the W3C
    signature schema by URL is mapped to the copy xmlschema ships."""
    xmlschema = pytest.importorskip("xmlschema", reason="xmlschema (test extra) not installed")
    if not QIF_SCHEMA.is_file():
        pytest.skip(f"the QIF 3.0 schema is not beside this checkout ({QIF_SCHEMA})")
    dsig = Path(os.path.dirname(xmlschema.__file__)) / "schemas" / "DSIG" / \
        "xmldsig-core-schema.xsd"
    schema = xmlschema.XMLSchema(str(QIF_SCHEMA), locations=[(DSIG_NS, str(dsig))],
                                 allow="local")
    _complete_substitution_groups(xmlschema, schema)
    return schema


def _errors(schema, doc: bytes) -> list[str]:
    return [str(e).split("\n\n")[1] if "\n\n" in str(e) else str(e)
            for e in schema.iter_errors(doc.decode("utf-8"))][:5]


@pytest.mark.slow
def test_the_export_of_the_thesis_calibration_is_schema_valid(qif_schema, full_doc, plain_doc):
    assert _errors(qif_schema, full_doc) == []
    assert _errors(qif_schema, plain_doc) == []


@pytest.mark.slow
def test_the_schema_check_catches_a_dangling_reference(qif_schema, full_doc):
    """The key/keyref constraints are live (the substitution-group repair above): a
    measurement naming a feature item that does not exist is refused."""
    root = ET.fromstring(full_doc)
    first = root.find(f".//{Q}SphereFeatureMeasurement/{Q}FeatureItemId")
    first.text = "999999"
    errs = _errors(qif_schema, ET.tostring(root))
    assert errs and "FeatureItemIdKey" in " ".join(errs)


def test_the_document_says_machine_calibration_and_provenance(calibration, full_doc):
    ds, r = calibration
    root = ET.fromstring(full_doc)
    assert root.tag == f"{Q}QIFDocument" and root.get("versionQIF") == "3.0.0"
    ids = [int(e.get("id")) for e in root.iter() if e.get("id") is not None]
    assert len(ids) == len(set(ids)) and int(root.get("idMax")) == max(ids)
    cmm = root.find(f"{Q}MeasurementResources/{Q}MeasurementDevices/{Q}CartesianCMM")
    assert cmm.findtext(f"{Q}Name") == "Brown & Sharpe (Leitz) PMM-C700P, S/N 161"
    assert cmm.findtext(f"{Q}SerialNumber") == "161"
    assert cmm.findtext(f"{Q}CMMGeometry/{Q}CartesianCMMGeometryEnum") == "MOVING_BRIDGE"
    vol = cmm.find(f"{Q}CartesianWorkingVolume")
    assert [float(vol.findtext(f"{Q}{a}AxisLength")) for a in "XYZ"] == [1200, 1000, 700]
    lin = cmm.find(f"{Q}Accuracies/{Q}CartesianCMMAccuracy/{Q}CartesianCMMISO10360Test/"
                   f"{Q}LinearError")
    assert float(lin.findtext(f"{Q}BaseError")) == pytest.approx(0.0006)
    assert float(lin.findtext(f"{Q}ErrorRate")) == pytest.approx(1e-3 / 600)
    assert cmm.findtext(f"{Q}TemperatureCompensation/{Q}TemperatureCompensationEnum") == \
        "DEVICE_ONLY"
    # the thesis setup states no calibration date: no Calibration (QIF needs its dates)
    assert cmm.find(f"{Q}Calibrations") is None
    head = root.find(f"{Q}Header")
    assert head.findtext(f"{Q}Application/{Q}Name") == "cmm-error-lab"
    desc = head.findtext(f"{Q}Description")
    attrs = {a.get("name"): a.get("value") for a in root.find(f"{Q}Attributes")}
    assert attrs["created"] == FIXED_TIME
    assert root.findtext(f"{Q}Version/{Q}TimeCreated") == FIXED_TIME
    for f in ds.inputs:
        assert f.sha256 in desc and attrs[f"input {f.name}"].startswith(f"sha256:{f.sha256}")
    assert len(ds.inputs) == 8  # six tables, the setup, the certificate
    units = root.find(f"{Q}FileUnits/{Q}PrimaryUnits/{Q}LinearUnit")
    assert units.findtext(f"{Q}UnitName") == "mm"


def test_a_calibration_date_gives_a_calibration_with_its_expiry(calibration):
    ds, r = calibration
    raw = {**ds.setup.raw, "calibration_date": "2025-11-30"}
    ds2 = replace(ds, setup=replace(ds.setup, raw=raw))
    root = ET.fromstring(qif_document(r, ds2, calibration_interval_months=3,
                                      created=FIXED_TIME))
    cal = root.find(f".//{Q}CartesianCMM/{Q}Calibrations/{Q}Calibration")
    assert cal.findtext(f"{Q}CalibrationDate") == "2025-11-30T00:00:00"
    assert cal.findtext(f"{Q}ExpirationDate") == "2026-02-28T00:00:00"
    temps = [float(t.text) for t in cal.iterfind(f"{Q}Temperatures/{Q}Temperature/"
                                                 f"{Q}Temperature")]
    assert temps == [t for p in ds.setup.positions.values() for t in p.temp_C]


def test_results_hold_every_centre_with_its_nominal_and_uncertainty(calibration, full_doc):
    ds, r = calibration
    root = ET.fromstring(full_doc)
    results = root.findall(f"{Q}Results/{Q}MeasurementResultsSet/{Q}MeasurementResults")
    assert len(results) == len(ds.positions) == 6
    meas = root.findall(f".//{Q}SphereFeatureMeasurement")
    assert len(meas) == len(ds.meas) == 150
    items = {e.get("id"): e for e in root.iter(f"{Q}SphereFeatureItem")}
    noms = {e.get("id"): e for e in root.iter(f"{Q}SphereFeatureNominal")}
    cert = dict(zip(ds.certificate.balls.tolist(), ds.certificate.xyz_mm, strict=True))
    rx = re.compile(QIF_LABEL_PATTERN)
    for m, row in zip(meas, ds.meas.itertuples(), strict=True):
        g = rx.fullmatch(m.findtext(f"{Q}FeatureName"))
        assert (g["position"], g["probe"], int(g["ball"])) == (row.position, row.probe,
                                                               row.ball)
        loc = m.find(f"{Q}Location")
        assert [float(v) for v in loc.text.split()] == [row.x_mm, row.y_mm, row.z_mm]
        assert float(loc.get("xCombinedUncertainty")) == pytest.approx(r.sigma_um / 1000)
        nominal = noms[items[m.findtext(f"{Q}FeatureItemId")].findtext(f"{Q}FeatureNominalId")]
        assert np.array_equal([float(v) for v in nominal.findtext(f"{Q}Location").split()],
                              cert[row.ball])


def test_the_extension_holds_the_error_model_and_the_certificate(calibration, plain_doc):
    ds, r = calibration
    root = ET.fromstring(plain_doc)
    assert root.find(f"{Q}Features") is None  # no ball diameter: no QIF nominals
    em = root.find(f"{Q}UserDataXML/{X}ErrorModel")
    assert em.get("spec") == r.spec and em.get("layout") == "moving_bridge_fxyz"
    params = em.findall(f"{X}Parameters/{X}Parameter")
    assert [p.get("name") for p in params] == list(r.labels)
    p = next(p for p in params if p.get("name") == "sxy")
    i = list(r.labels).index("sxy")
    assert float(p.findtext(f"{X}Value")) == r.values[i]
    assert float(p.findtext(f"{X}StandardUncertainty")) == r.u[i]
    assert float(p.findtext(f"{X}ExpandedUncertainty")) == pytest.approx(2 * r.u[i])
    balls = em.findall(f"{X}Certificate/{X}Ball")
    assert len(balls) == 25
    assert float(balls[1].get("ux")) == ds.certificate.u_um[1, 0]
    assert float(balls[1].get("x")) == ds.certificate.xyz_mm[1, 0]


def test_bad_keywords_are_refused(calibration):
    ds, r = calibration
    with pytest.raises(ValueError, match="temperature_compensation"):
        qif_document(r, ds, temperature_compensation="SOMETIMES")
    with pytest.raises(ValueError, match="mpe"):
        qif_document(r, ds, mpe=(0.6,))


@pytest.mark.parametrize("which", ["full", "plain"])
def test_export_then_read_gives_back_the_same_centres(calibration, full_doc, plain_doc, which):
    """With nominals (labels on the measurements) and without: every centre, position,
    probe and ball as measured, to the last bit (the writer's digits round-trip)."""
    ds, _ = calibration
    table = read_qif(full_doc if which == "full" else plain_doc, name="thesis.qif")
    got = table.meas
    assert len(got) == len(ds.meas)
    assert got["position"].tolist() == ds.meas["position"].tolist()
    assert got["probe"].tolist() == ds.meas["probe"].tolist()
    assert got["ball"].astype(int).tolist() == ds.meas["ball"].astype(int).tolist()
    for c in ("x_mm", "y_mm", "z_mm"):
        assert np.array_equal(got[c].to_numpy(), ds.meas[c].to_numpy())


def test_labels_from_feature_items_units_and_a_pattern(full_doc):
    """A measurement without FeatureName is named by its feature item; a document in
    inches is read in mm; a pattern without position takes the default position."""
    root = ET.fromstring(full_doc)
    m = root.find(f".//{Q}SphereFeatureMeasurement")
    m.remove(m.find(f"{Q}FeatureName"))
    loc = m.find(f"{Q}Location")
    x_mm = [float(v) for v in loc.text.split()]
    loc.text = " ".join(repr(v / 25.4) for v in x_mm)
    loc.set("linearUnit", "inch")
    table = read_qif(ET.tostring(root), name="edited.qif")
    assert table.meas.iloc[0][["x_mm", "y_mm", "z_mm"]].tolist() == pytest.approx(x_mm)
    assert table.meas.iloc[0]["position"] == "BP111"
    one = read_qif(full_doc, name="thesis.qif", pattern=r"BP111/(?P<probe>\w+)/(?P<ball>\d+)",
                   default_position="A")
    assert set(one.meas["position"]) == {"A"} and len(one.meas) == 25


def _edited(doc: bytes, edit) -> bytes:
    root = ET.fromstring(doc)
    edit(root)
    return ET.tostring(root)


def _drop_location(root):
    m = root.findall(f".//{Q}SphereFeatureMeasurement")[3]
    m.remove(m.find(f"{Q}Location"))


def _unknown_unit(root):
    root.find(f"{Q}FileUnits/{Q}PrimaryUnits/{Q}LinearUnit/{Q}UnitName").text = "parsec"
    conv = root.find(f"{Q}FileUnits/{Q}PrimaryUnits/{Q}LinearUnit")
    conv.remove(conv.find(f"{Q}UnitConversion"))


def _bad_location(root):
    root.findall(f".//{Q}SphereFeatureMeasurement")[0].find(f"{Q}Location").text = "1 2"


@pytest.mark.parametrize("edit, words", [
    (_drop_location, ["SphereFeatureMeasurement id=", "(BP111/1/4)", "no Location",
                      "measured centre"]),
    (_unknown_unit, ["FileUnits/PrimaryUnits/LinearUnit/UnitName", "'parsec'",
                     "expected a length unit"]),
    (_bad_location, ["SphereFeatureMeasurement id=", "Location '1 2'",
                     "expected three numbers"]),
])
def test_bad_documents_are_refused_naming_the_element(plain_doc, edit, words):
    with pytest.raises(DataError) as exc:
        read_qif(_edited(plain_doc, edit), name="bad.qif")
    text = str(exc.value)
    assert "bad.qif" in text
    for w in words:
        assert w in text


def test_a_missing_centre_names_its_line(plain_doc):
    bad = _edited(plain_doc, _drop_location)
    with pytest.raises(DataError) as exc:
        read_qif(bad, name="bad.qif")
    line = bad.decode().split("\n")[exc.value.row - 1]
    assert "SphereFeatureMeasurement" in line


def test_a_wrong_root_or_no_results_is_refused(plain_doc):
    with pytest.raises(DataError, match=r"root element <MeasurementResults> without a "
                       r"namespace: expected <QIFDocument>"):
        read_qif(b"<MeasurementResults/>", name="old.xml")
    with pytest.raises(DataError, match=r"root element <QIFDocument> in namespace urn:x"):
        read_qif(b'<QIFDocument xmlns="urn:x"/>', name="other.xml")
    no_results = _edited(plain_doc, lambda r: r.remove(r.find(f"{Q}Results")))
    with pytest.raises(DataError, match=r"has no <Results>"):
        read_qif(no_results, name="plan.qif")
    with pytest.raises(DataError, match="not well-formed XML"):
        read_qif(b"<QIFDocument", name="cut.qif")
    with pytest.raises(DataError, match="matches the pattern"):
        read_qif(plain_doc, name="thesis.qif", pattern=r"P(?P<position>\d)_(?P<ball>\d+)")

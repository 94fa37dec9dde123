"""The analysis record (issue 12): one frozen record read and written as JSON, built from
the app session or a project file, and the conventions defined once in the core (the
sign of the measured error, the outlier default)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest
from scenarios import perturb, simulated

from cmm_core import analysis as A
from cmm_core.io import DataError
from cmm_core.model import fit
from pages.ui.session import session_record

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "thesis" / "analysis.json"


def _session(**state):
    from pages.ui import state as C

    return {**{k: list(v) if isinstance(v, list) else v for k, v in C.DEFAULTS.items()},
            "sources": A.thesis_sources(), **state}


def test_sample_record_reads_and_round_trips():
    rec = A.read_record(SAMPLE)
    assert rec.spec == "kinematic21" and rec.order == 2 and rec.sigma_um == 0.5
    assert len(rec.exclusions) == 3 and rec.exclude_outliers is False
    assert [f.name for f in rec.data.measurements][0] == "BP111.csv"
    assert A.record_from_dict(A.record_to_dict(rec)) == rec
    # written relative to its folder, the paths are the sample's own
    again = json.loads(A.record_to_json(rec, relative_to=SAMPLE.parent))
    prov = again.pop("provenance")  # what wrote it: the rest is the sample's own
    assert again == json.loads(SAMPLE.read_text())
    # each input named with the SHA-256 of its bytes on disk
    assert [(i["name"], i["sha256"]) for i in prov["inputs"]] == [
        (f.name, hashlib.sha256(Path(f.path).read_bytes()).hexdigest())
        for f in rec.data.files]


def test_session_record_round_trips_through_json_and_the_project_file():
    rec = session_record(_session(exclusions=[("BP112", "2", 7)], diag_on=True,
                                         w_mpe_u="cmm_spec", magnification=1500.0))
    assert rec.diagnose and rec.mpe_u_source == "cmm_spec" and rec.magnification == 1500.0
    assert rec.history == (("kinematic21", "baseline"),)
    assert A.read_record(A.record_to_json(rec)) == rec
    assert A.record_from_project(A.record_to_project_json(rec)) == rec
    with pytest.raises(dataclasses.FrozenInstanceError):
        rec.spec = "rigid"


def test_a_record_with_sigma_auto_round_trips_through_the_project_file():
    """A command-line record may say σ "auto": its project file keeps it (it was refused
    before, so such a record could not be saved as a project)."""
    rec = dataclasses.replace(session_record(_session()), sigma_um="auto")
    assert A.record_from_project(A.record_to_project_json(rec)) == rec


def test_session_defaults_are_the_record_defaults():
    """The app's defaults and a record file's defaults agree (one outlier rule)."""
    rec = session_record(_session())
    default = A.AnalysisRecord(rec.data, history=rec.history)
    assert rec == default
    assert A.DEFAULT_EXCLUDE_OUTLIERS is False and rec.exclude_outliers is False


@pytest.mark.parametrize("patch, column, needle", [
    ({"sigma": 0.5}, "sigma", "did you mean 'sigma_um'"),
    ({"exclude_outlier": True}, "exclude_outlier", "did you mean 'exclude_outliers'"),
    ({"magnifiction": 10}, "magnifiction", "did you mean 'magnification'"),
    ({"order": 9}, "order", "whole number 1-5, found 9"),
    ({"plate": "wobbly"}, "plate", "one of auto, fixed, prior, free, found \"wobbly\""),
    ({"sigma_um": -1}, "sigma_um", "between 0 and 1000"),
    ({"spec": "kinematic21,wobble"}, "spec", "wobble"),
    ({"positions": "BP111"}, "positions", "list of names"),
    ({"exclusions": [["BP111", "1"]]}, "exclusions", "triples"),
    ({"format": "cmm-error-lab-project"}, "format", "not an analysis record"),
    ({"version": 99}, "version", "newer cmm_core"),
])
def test_bad_records_are_refused_naming_file_and_key(patch, column, needle):
    doc = {**json.loads(SAMPLE.read_text()), **patch}
    with pytest.raises(DataError, match=needle.replace("(", r"\(")) as exc:
        A.record_from_dict(doc, "ANALYSIS.json", SAMPLE.parent)
    assert exc.value.column == column and "ANALYSIS.json" in str(exc.value)


def test_unknown_data_key_is_refused_with_did_you_mean():
    doc = json.loads(SAMPLE.read_text())
    doc["data"]["certificat"] = doc["data"].pop("certificate")
    with pytest.raises(DataError, match="did you mean 'certificate'") as exc:
        A.record_from_dict(doc, "ANALYSIS.json")
    assert exc.value.column == "data.certificat"


def test_outlier_rule_excludes_only_what_the_record_says():
    rec = A.read_record(SAMPLE)
    none = dataclasses.replace(rec, exclusions=())
    kept = A.run(none)
    assert len(kept.flagged) == 3 and kept.exclusions == ()
    dropped = A.run(dataclasses.replace(none, exclude_outliers=True))
    assert dropped.exclusions == kept.flagged
    assert dropped.fit.chi2_dof == pytest.approx(A.run(rec).fit.chi2_dof)


def test_measured_error_sign_is_the_compensation_convention():
    """true = reported + error: readings that are too long give a negative error, and the
    report's measured error has that sign."""
    sim = simulated("pitch100_4pos", 2, noise_um=0.05)
    xyz = sim.dataset.meas[["mx_mm", "my_mm", "mz_mm"]].to_numpy()
    scale = np.zeros_like(xyz)
    scale[:, 0] = 2e-5 * (xyz[:, 0] - xyz[:, 0].mean())  # x reads 20 ppm long
    long = perturb(sim.dataset, scale)
    e = A.measured_error_from_residuals_um(fit(long, "rigid").residuals_um)
    assert np.corrcoef(e[:, 0], scale[:, 0])[0, 1] < -0.9
    assert np.allclose(A.measured_error_um([[1.0, 2.0, 3.0]], [[1.001, 2.0, 2.999]]),
                       [[1.0, 0.0, -1.0]])


@pytest.mark.parametrize("change, column, needle", [
    ({"positions": ("BP111", "BP11x")}, "positions.BP11x", "unknown position 'BP11x'; did you"),
    ({"probes": ("1", "9")}, "probes.9", "unknown probe '9'"),
    ({"exclusions": (("BP999", "2", 7),)}, "exclusions", "not in the data"),
])
def test_names_the_data_lack_are_refused_not_dropped(change, column, needle):
    """A position, probe or excluded observation the data do not have would silently
    select or exclude nothing (a 25-observation report from a typo): refused, naming the
    field."""
    rec = dataclasses.replace(A.read_record(SAMPLE), **change)
    with pytest.raises(DataError, match=needle) as exc:
        A.run(rec)
    assert exc.value.column == column


# --- instruments (laser runs, step gauges) in the record ---------------------------------

INSTRUMENTS = ROOT / "sample_data" / "instruments"


def _with_instruments(rec, *kinds_files):
    files = tuple(A.InstrumentFile(k, A.DataFile(f.name, str(f))) for k, f in kinds_files)
    return dataclasses.replace(rec, data=dataclasses.replace(rec.data, instruments=files))


def test_record_with_instruments_round_trips_through_json_session_and_project():
    laser = (INSTRUMENTS / "laser_x.csv").read_text()
    rec = session_record(_session(instruments=[("laser", "laser_x.csv", laser)]))
    (inst,) = rec.data.instruments
    assert inst.kind == "laser" and inst.file.name == "laser_x.csv"
    assert inst.file.text() == laser
    assert A.read_record(A.record_to_json(rec)) == rec
    assert A.record_from_project(A.record_to_project_json(rec)) == rec
    by_path = _with_instruments(A.read_record(SAMPLE), ("step_gauge", INSTRUMENTS /
                                                        "step_gauge.csv"))
    doc = json.loads(A.record_to_json(by_path, relative_to=SAMPLE.parent))
    assert doc["data"]["instruments"] == [{"kind": "step_gauge",
                                           "path": "../instruments/step_gauge.csv"}]
    (back,) = A.record_from_dict(doc, base=SAMPLE.parent).data.instruments
    assert back.kind == "step_gauge"
    assert back.file.text() == by_path.data.instruments[0].file.text()
    # without instruments the file is written as before
    assert "instruments" not in A.record_to_dict(A.read_record(SAMPLE))["data"]


@pytest.mark.parametrize("entry, column, needle", [
    ({"kind": "lazer", "path": "x.csv"}, "data.instruments[0].kind",
     "unknown instrument kind 'lazer'; did you mean 'laser'? expected one of laser, "
     "step_gauge"),
    ({"kind": "laser", "path": "x.csv", "contnet": "a"}, "data.instruments[0].contnet",
     "did you mean 'content'"),
    ({"path": "x.csv"}, "data.instruments[0]", "kind"),
])
def test_bad_instrument_entries_are_refused_naming_the_key(entry, column, needle):
    doc = {**json.loads(SAMPLE.read_text())}
    doc["data"] = {**doc["data"], "instruments": [entry]}
    with pytest.raises(DataError, match=re.escape(needle)) as exc:
        A.record_from_dict(doc, "ANALYSIS.json", SAMPLE.parent)
    assert exc.value.column == column


def test_record_run_with_instruments_equals_a_direct_joint_fit():
    from cmm_core.model import instruments as ins
    from cmm_core.model import read_laser, read_step_gauge

    rec = _with_instruments(A.read_record(SAMPLE), ("laser", INSTRUMENTS / "laser_x.csv"),
                            ("step_gauge", INSTRUMENTS / "step_gauge.csv"))
    res = A.run(rec)
    direct = fit(A.load_data(rec), rec.spec, exclude=list(rec.exclusions), sigma_um=0.5,
                 instruments=[read_laser(INSTRUMENTS / "laser_x.csv"),
                              read_step_gauge(INSTRUMENTS / "step_gauge.csv")])
    assert res.fit.chi2 == pytest.approx(direct.chi2, rel=1e-10)
    assert np.allclose(res.fit.values, direct.values, atol=1e-9)
    assert np.allclose(res.fit.u, direct.u, rtol=1e-8, equal_nan=True)
    assert list(res.instruments) == ins.summary(direct)
    assert [s["kind"] for s in res.instruments] == ["laser", "step_gauge"]
    assert res.instrument_residuals.equals(ins.residuals_frame(direct))
    assert not A.run(A.read_record(SAMPLE)).instruments  # none: nothing added


def test_the_app_fits_and_diagnoses_through_the_records_own_steps():
    """The app's cache key of a fit (pages.cached.FitKey) is fitted and diagnosed by the
    same core steps as an analysis record in analysis.run (the CLI, the report): the same
    numbers to the last digit, with instruments and exclusions (issue 23)."""
    from pages.ui.cached import FitKey

    rec = _with_instruments(A.read_record(SAMPLE), ("laser", INSTRUMENTS / "laser_x.csv"))
    rec = dataclasses.replace(rec, diagnose=True, spec="kinematic21", history=(
        ("kinematic21", "baseline"), ("rigid", "rigid placements")))
    res = A.run(rec)
    key = FitKey(data="any", spec=rec.spec, order=rec.order, plate=rec.plate,
                 sigma_um=float(rec.sigma_um), positions=rec.positions, probes=rec.probes,
                 exclusions=tuple(tuple(e) for e in res.exclusions))
    inst = A.load_instruments(rec)
    app_fit = A.fit_record(key, res.dataset, inst)
    assert app_fit.chi2 == res.fit.chi2 and np.array_equal(app_fit.values, res.fit.values)
    rigid = A.fit_record(key.with_spec("rigid"), res.dataset, inst)
    assert rigid.history_row("rigid placements") == res.history[1]
    d = A.diagnose_record(key, res.dataset, inst)
    same = [json.dumps(x.to_dict(), sort_keys=True, default=str)  # NaN u: compared as text
            for x in (d, res.diagnosis)]
    assert same[0] == same[1]
    with pytest.raises(ValueError, match="auto"):
        A.fit_record(dataclasses.replace(rec, sigma_um="auto"), res.dataset)


# --- a table from other software, kept with its column mapping (issue 24) ---------------

_VENDOR_PATTERN = r"(?P<position>BP\d+)_P(?P<probe>\w+)_B(?P<ball>\d+)"


def _mapped_session():
    """An app session whose measurements came through the column mapping: a vendor table
    (Feature;X;Y;Z in µm, decimal commas) of the thesis files' coordinates, converted as
    the Data page does it (``mapping_panel`` -> ``ForeignTable``)."""
    from cmm_core.io import TableMapping, apply_mapping

    thesis = A.thesis_sources()
    ds = A.load_data(session_record(_session()))
    lines = ["Feature;X;Y;Z"] + [
        f"{r.position}_P{r.probe}_B{r.ball};" + ";".join(
            f"{v * 1e3:.3f}".replace(".", ",") for v in (r.x_mm, r.y_mm, r.z_mm))
        for r in ds.meas.itertuples()]
    table_text = "\n".join(lines) + "\n"
    mapping = TableMapping(x="X", y="Y", z="Z", label="Feature", pattern=_VENDOR_PATTERN,
                           unit="um", decimal=",", delimiter=";")
    t = apply_mapping(table_text.encode(), mapping, name="vendor.csv")
    files = dataclasses.replace(thesis, measurements=(
        A.DataFile(t.name, content=t.source_text, mapping=t.mapping),))
    return _session(sources=files), ds, table_text, mapping


def test_a_mapped_table_round_trips_with_its_mapping_and_reloads():
    state, ds, table_text, mapping = _mapped_session()
    rec = session_record(state)
    (f,) = rec.data.measurements
    assert f.name == "vendor.csv" and f.content == table_text
    assert f.mapping == mapping.to_dict()
    assert A.read_record(A.record_to_json(rec)) == rec
    doc = json.loads(A.record_to_json(rec))
    assert doc["data"]["measurements"][0]["mapping"]["unit"] == "um"
    project = A.record_to_project_json(rec)
    assert A.record_from_project(project) == rec
    # the project's measurements are the long form (any reader loads them), the source
    # table and its mapping ride under extra.analysis.mappings
    pdoc = json.loads(project)
    assert pdoc["extra"]["analysis"]["mappings"][0]["mapping"] == mapping.to_dict()
    # reloaded through the mapping: the thesis coordinates to the table's 1 nm
    again = A.load_data(A.record_from_project(project))
    xyz = ["x_mm", "y_mm", "z_mm"]  # as the file gives them (the thesis's plate frame)
    np.testing.assert_allclose(again.meas[xyz].to_numpy(), ds.meas[xyz].to_numpy(),
                               atol=0.5e-6, rtol=0)
    assert again.meas["position"].tolist() == ds.meas["position"].tolist()


def test_a_bad_mapping_in_a_record_is_refused_naming_the_key():
    state, *_ = _mapped_session()
    doc = A.record_to_dict(session_record(state))
    doc["data"]["measurements"][0]["mapping"]["unit"] = "furlong"
    with pytest.raises(DataError, match="unit") as exc:
        A.record_from_dict(doc, "a.json")
    assert exc.value.column.startswith("data.measurements[0].mapping")
    doc["data"]["measurements"][0]["mapping"] = {"x": "X", "y": "Y"}
    with pytest.raises(DataError, match="missing key 'z'"):
        A.record_from_dict(doc, "a.json")
    del doc["data"]["measurements"][0]["mapping"]
    doc["data"]["measurements"][0]["mappnig"] = {}
    with pytest.raises(DataError, match="did you mean 'mapping'"):
        A.record_from_dict(doc, "a.json")


@pytest.mark.parametrize("path, value, column", [
    (("dataset", "measurements"), 5, "dataset.measurements"),
    (("dataset", "measurements"), True, "dataset.measurements"),
    (("dataset", "setup"), [5], "dataset.setup"),
    (("history",), 5, "history"),
    (("history",), [5], "history"),
    (("history",), [{"spec": 5}], "history"),
    (("extra",), [5], "extra"),
    (("extra",), "x", "extra"),
    (("extra", "analysis"), 5, "extra.analysis"),
    (("extra", "analysis", "instruments"), 5, "data.instruments"),
    (("extra", "analysis", "mappings"), [{"index": 9}], "extra.analysis.mappings[0]"),
    (("model",), [1], "model"),
])
def test_a_project_file_of_the_wrong_shape_is_one_line_naming_the_key(path, value, column):
    """Issue 25: a wrong type anywhere in a project file is a DataError naming the key,
    never a Python TypeError or AttributeError (the app shows the same line)."""
    doc = json.loads(A.record_to_project_json(session_record(_session())))
    parent = doc
    for key in path[:-1]:
        parent = parent.setdefault(key, {})
    parent[path[-1]] = value
    with pytest.raises(DataError) as exc:
        A.record_from_project(json.dumps(doc), "p.json")
    assert exc.value.column.startswith(column) and "\n" not in str(exc.value)
    assert str(exc.value).startswith("p.json")


def test_an_exclusion_is_a_history_step_fitted_with_its_own_exclusions():
    """Issue 41: a history step carries the exclusions it was made with; the report's
    history refits each step with them (a step without its own, with the record's), and
    the record keeps them through its JSON and project forms."""
    rec = A.read_record(SAMPLE)
    flagged = A.run(dataclasses.replace(rec, exclusions=(), diagnose=False)).flagged
    steps = (("kinematic21", "baseline", ()),
             ("kinematic21", "exclude 3 flagged outliers", tuple(flagged)),
             ("kinematic21", "the record's own exclusions"))
    rec = dataclasses.replace(rec, spec="kinematic21", exclusions=tuple(flagged),
                              exclude_outliers=False, diagnose=False, history=steps)
    assert A.read_record(A.record_to_json(rec)) == rec
    assert A.record_from_project(A.record_to_project_json(rec)).history == steps
    res = A.run(rec)
    kept = A.fit_record(rec, A.load_data(rec), exclusions=(), sigma_um=res.fit.sigma_um)
    rms = [h["rms_um"] for h in res.history]
    # history rows round the RMS to 4 decimals: equal to within half of 1e-4 µm
    assert rms[0] == pytest.approx(kept.rms_um, abs=5e-5)
    assert rms[1] == pytest.approx(res.fit.rms_um, abs=5e-5) and rms[2] == rms[1]
    assert rms[1] < rms[0] - 0.01
    # a step naming an observation the data lack is refused, naming the step
    bad = dataclasses.replace(rec, history=(("kinematic21", "x", (("BP111", "9", 99),)),))
    with pytest.raises(ValueError, match="history step 'x'"):
        A.run(bad)


def test_a_step_with_its_own_exclusions_gets_the_flagged_ones_when_the_record_says_so():
    """Review of issue 41: with ``exclude_outliers`` the flagged observations join every
    fit of the record, a history step's own exclusions included (its RMS is the record's
    fit's, not that of the flagged data)."""
    rec = dataclasses.replace(A.read_record(SAMPLE), spec="kinematic21", exclusions=(),
                              exclude_outliers=True, diagnose=False,
                              history=(("kinematic21", "baseline", ()),))
    res = A.run(rec)
    assert res.history[0]["rms_um"] == pytest.approx(res.fit.rms_um, abs=5e-5)
    assert A.history_exclusions(rec, A.load_data(rec), res.flagged) == [tuple(res.flagged)]

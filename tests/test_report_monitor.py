"""The interim check and the calibration history in the analysis record, the HTML report
and the results document (issue 28 point 3), on the sample history
(``sample_data/history``: the check after a simulated crash that moved sxy by 12 µrad)."""

from __future__ import annotations

import functools
import html
import json
import re
from pathlib import Path

import pytest

from cmm_core.analysis import (
    read_record,
    record_from_dict,
    record_from_project,
    record_to_dict,
    record_to_project_json,
    render,
    results_document,
    run,
    write_report,
)
from cmm_core.export import load_model, results_json
from cmm_core.io import DataError
from cmm_core.monitor import CHANGE_RULE, HISTORY_RULE, TEST_RULE, run_check

H = Path(__file__).resolve().parents[1] / "sample_data" / "history"
RECORD = H / "analysis_after_crash.json"


@functools.cache
def result():
    return run(read_record(RECORD))


@functools.cache
def report() -> str:
    return render(result(), generated="2026-01-01 00:00 UTC")


def test_record_round_trips_its_check_and_history():
    rec = read_record(RECORD)
    assert rec.interim_check.model.name == "calibration_2024-03-04.json"
    assert rec.interim_check.mpe == (0.6, 600.0)
    assert [d for _, d in rec.calibration_history.models] == [
        "2023-03-01", "2024-03-04", "2025-03-03"]
    assert record_from_dict(record_to_dict(rec)) == rec
    # a project file carries the model files' text: it reloads without the folder
    back = record_from_project(record_to_project_json(rec))
    assert back.interim_check.model.content == (H / "calibration_2024-03-04.json").read_text()
    assert [f.content is not None for f, _ in back.calibration_history.models] == [True] * 3


def test_record_refuses_a_bad_check_block_in_one_line():
    doc = json.loads(RECORD.read_text())
    for key, bad, where in (("interim_check", {"alpha": 0.05}, "interim_check"),
                            ("interim_check", {"model": "m.json", "mpe": [0.6]},
                             "interim_check.mpe"),
                            ("calibration_history", {"models": [{"path": "a.json",
                                                                 "date": "2024-02-30"}]},
                             "calibration_history.models[0].date")):
        with pytest.raises(DataError) as e:
            record_from_dict({**doc, key: bad}, base=H)
        assert e.value.column == where and "\n" not in str(e.value)


def test_report_has_the_interim_check_with_its_numbers():
    res, text = result(), report()
    c = res.interim.check
    assert res.interim.verdict == "changed"
    sec = text[text.index("<h2>Interim check</h2>"):text.index("<h2>History</h2>")]
    # the numbers as the check computed them, and the decision rules stated
    assert f"<td>{c.chi2:.2f}</td>" in sec and f"<td>{c.dof}</td>" in sec
    assert f"<td>{c.p_value:.3g}</td>" in sec
    assert html.escape(TEST_RULE) in sec and html.escape(CHANGE_RULE) in sec
    # the crash's squareness: named by the diagnosis and moved beyond its uncertainty
    assert "names squareness XY (sxy" in sec
    row = res.interim.changes.table.set_index("label").loc["sxy"]
    assert row.significant_alone
    # the change with its posterior sd (u_updated), not the null sd u_null (review 2 #4)
    assert f"sxy by {row.change:+.3g} ± {row.u_updated:.2g}" in sec
    # one largest |E_n| (review 2 #12): the table's En column, the check's message and
    # the report's list of the 10 largest are the same numbers
    top = c.largest_En(10)
    assert (c.table["En"] == c.table[["En_x", "En_y", "En_z"]].abs().max(axis=1)).all()
    assert top["En"].iloc[0] == c.table["En"].max() and len(top) == 10
    assert f"Largest |E_n| (k = 2) = {top['En'].iloc[0]:.2f}" in c.message
    assert all(f"<td>{v:.4g}</td>" in sec for v in top["dx_um"])
    # the E_n map is a figure of the report, and the conformity statement with its rule
    assert "id='mon1'" in sec
    assert "<h3>Conformity</h3>" in sec and "ISO 14253-1" in sec


def test_report_has_the_history_with_its_numbers():
    res, text = result(), report()
    h = res.calibration_history
    sec = text[text.index("<h2>History</h2>"):]
    assert html.escape(HISTORY_RULE) in sec
    # sxy changed between the last two calibrations (the crash): significant, in the table
    ch = h.changes[(h.changes.label == "sxy") & (h.changes.date_to == "2025-03-03")].iloc[0]
    assert ch.significant
    assert f"{ch.change:.4g}" in sec and f"{ch.En:.4g}" in sec
    assert "id='mon2'" in sec  # the trend plot


def test_results_document_has_both_sections():
    res = result()
    doc = json.loads(json.dumps(results_document(res, created="x"), allow_nan=False))
    ic, hi = doc["interim_check"], doc["history"]
    c = res.interim.check
    assert ic["verdict"] == "changed" and ic["test"]["chi2"] == c.chi2
    assert ic["test"]["dof"] == c.dof and ic["test"]["decision_rule"] == TEST_RULE
    sxy = next(p for p in ic["changes"]["parameters"] if p["name"] == "sxy")
    row = res.interim.changes.table.set_index("label").loc["sxy"]
    assert sxy["change"] == row.change and sxy["standard_uncertainty"] == row.u_updated
    assert sxy["u_null"] == row.u_null
    assert ic["new_effects"]["named"][0]["effect"] == "sxy"
    assert ic["conformity"]["rule"].startswith("ISO 14253-1")
    assert hi["decision_rule"] == HISTORY_RULE and hi["dates"][-1] == "2025-03-03"
    assert any(r["name"] == "sxy" and r["significant"] for r in hi["changes"])
    # a record without them: the document as before
    assert "interim_check" not in json.loads(results_json(res.fit, created="x"))


def test_write_report_prints_the_verdict(tmp_path):
    out = write_report(RECORD, tmp_path / "r.html")
    assert out["interim_check"]["verdict"] == "changed"
    assert out["interim_check"]["new_effects"][0] == "sxy"
    assert any(s.startswith("sxy") for s in out["history"]["significant"])
    assert re.search(r"<h2>Interim check</h2>", (tmp_path / "r.html").read_text())


def test_the_records_check_takes_its_styli_and_exclusions():
    # review 2 #5: the record's interim check took its placements only; its styli and
    # exclusions (the fit's data) were dropped, so an excluded outlier came back into the
    # check's χ². Now the check tests the data the record's fit used: styli A, B, C (not
    # D, E: 150 of the 200 ball centres) and without H0/A ball 7, and its χ² is
    # run_check's with the same selection
    doc = {k: v for k, v in json.loads(RECORD.read_text()).items()
           if k != "calibration_history"}
    rec = record_from_dict({**doc, "probes": ["A", "B", "C"],
                            "exclusions": [["H0", "A", 7]]}, base=H)
    res = run(rec)
    t = res.interim.check.table
    assert set(t["probe"]) == {"A", "B", "C"} and len(t) == 150 - 1
    assert not ((t.position == "H0") & (t.probe == "A") & (t.ball == 7)).any()
    assert ("H0", "A", 7) in res.exclusions
    same = run_check(load_model(H / "calibration_2024-03-04.json"), res.dataset,
                     probes=["A", "B", "C"], exclude=[("H0", "A", 7)], name_effects=False)
    assert res.interim.check.chi2 == pytest.approx(same.check.chi2, rel=1e-9)
    assert res.interim.check.dof == same.check.dof == 3 * 149 - 6 * 4

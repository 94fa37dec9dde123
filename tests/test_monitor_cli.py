"""The ``check`` and ``compare`` commands (issue 28) on the sample history, through the
CLI's own entry point."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from cmm_core.cli import build_parser, main

H = Path(__file__).resolve().parents[1] / "sample_data" / "history"
CRASH = H / "check_2025-02-10_after_crash"
QUIET = H / "check_2024-06-17"


def _run(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def _check_args(folder, *extra):
    return ["check", str(H / "calibration_2024-03-04.json"), str(folder / "measurements.csv"),
            "--setup", str(folder / "setup.json"), "--certificate",
            str(folder / "certificate.csv"), *extra]


def test_check_after_the_crash_fails_and_names_the_squareness(capsys):
    # the sample's crash moved sxy by 12 µrad (sample_data/history/make_history.py)
    code, out, _ = _run(_check_args(CRASH, "--mpe", "0.6,600"), capsys)
    assert code == 0
    d = json.loads(out)
    assert d["check"]["status"] == "fails" and d["check"]["dof"] == 3 * 200 - 6 * 4
    assert d["changes"]["significant_alone"][0] == "sxy"
    assert d["conformity"]["statement"] in ("does not conform", "cannot say")


def test_quiet_one_placement_check_passes_and_says_what_it_cannot_see(capsys, tmp_path):
    out_file = tmp_path / "check.json"
    code, out, _ = _run(["--json", str(out_file), *_check_args(QUIET)], capsys)
    assert code == 0 and out == ""
    d = json.loads(out_file.read_text())
    assert d["check"]["status"] == "passes" and d["check"]["positions"] == ["H0"]
    assert d["changes"]["unseen"] and d["conformity"] is None


def test_compare_names_the_crash_between_the_last_two(capsys):
    models = sorted(str(p) for p in H.glob("calibration_*.json"))
    code, out, _ = _run(["compare", *models, "--dates", "2023-03-01", "2024-03-04",
                         "2025-03-03"], capsys)
    assert code == 0
    d = json.loads(out)
    assert [s["label"] for s in d["significant"]] == ["sxy"]
    assert d["significant"][0]["date_to"] == "2025-03-03"


@pytest.mark.parametrize("argv, text", [
    (["compare", str(H / "calibration_2023-03-01.json"), str(H / "calibration_2024-03-04.json"),
      "--dates", "2023-03-01"], "2 model(s) but 1 date(s)"),
    (["compare", str(H / "calibration_2023-03-01.json"), str(H / "calibration_2024-03-04.json"),
      "--dates", "2023-03-01", "March"], "not an ISO 8601 date"),
])
def test_refusals_are_one_line_with_status_2(argv, text, capsys):
    code, out, err = _run(argv, capsys)
    assert code == 2 and out == "" and text in err and err.count("\n") == 1


def test_check_help_states_the_decision_rule():
    """Every option's help is checked for all commands by tests/test_cli_help.py; the
    check's help also names the conformity rule it applies."""
    sub = next(a for a in build_parser()._actions
               if isinstance(a, argparse._SubParsersAction))
    text = sub.choices["check"].format_help()
    assert "--mpe" in text and "ISO 14253-1" in text


def test_check_names_the_new_effect_and_writes_report_and_results(capsys, tmp_path):
    rep, res = tmp_path / "check.html", tmp_path / "results.json"
    code, out, _ = _run(_check_args(CRASH, "--mpe", "0.6,600", "--report", str(rep),
                                    "--results-json", str(res)), capsys)
    assert code == 0
    d = json.loads(out)
    assert d["verdict"] == "changed"
    assert d["new_effects"]["named"][0]["effect"] == "sxy"
    assert d["report"] == str(rep) and d["results_json"] == str(res)
    text = rep.read_text()
    assert "<h2>Interim check</h2>" in text and "names squareness XY (sxy" in text
    doc = json.loads(res.read_text())
    # the stored model's parameters, and the check's section with the same numbers
    assert doc["model"]["name"] == "calibration_2024-03-04.json"
    assert doc["interim_check"]["test"]["chi2"] == d["check"]["chi2"]


def test_check_with_a_ball_bar_alone_is_partial(capsys, tmp_path):
    # two ball-bar lengths (indicated centres exactly 500 mm apart): two rows see a few
    # combinations of 33; whatever the test says, the verdict is never "no change seen"
    bar = tmp_path / "bar.csv"
    bar.write_text("bar,x1_mm,y1_mm,z1_mm,x2_mm,y2_mm,z2_mm,certified_mm,u_um\n"
                   "B1,250,400,300,750,400,300,500.0,0.3\n"
                   "B2,500,150,300,500,650,300,500.0,0.3\n")
    code, out, err = _run(["check", str(H / "calibration_2024-03-04.json"), "--ball-bar",
                           str(bar), "--mpe", "0.6,600"], capsys)
    assert code == 0, err
    d = json.loads(out)
    assert d["check"]["dof"] == 2 and d["check"]["instruments"][0]["kind"] == "ball_bar"
    assert d["verdict"] != "no change seen"
    assert d["conformity"]["statement"] == "cannot say"


@pytest.mark.parametrize("extra, text", [
    ([], "nothing to check"),
    (["--setup", "s.json"], "--setup and --certificate describe plate measurements"),
])
def test_check_without_new_data_is_refused_in_one_line(extra, text, capsys):
    code, out, err = _run(["check", str(H / "calibration_2024-03-04.json"), *extra], capsys)
    assert code == 2 and out == "" and text in err and err.count("\n") == 1


def test_compare_writes_the_history_into_the_results(capsys, tmp_path):
    res = tmp_path / "history.json"
    models = sorted(str(p) for p in H.glob("calibration_*.json"))
    code, out, _ = _run(["compare", *models, "--dates", "2023-03-01", "2024-03-04",
                         "2025-03-03", "--results-json", str(res)], capsys)
    assert code == 0
    doc = json.loads(res.read_text())
    assert doc["model"]["name"] == "calibration_2025-03-03.json"
    assert doc["history"]["dates"] == ["2023-03-01", "2024-03-04", "2025-03-03"]
    assert [r["name"] for r in doc["history"]["changes"] if r["significant"]] == ["sxy"]


def test_compare_takes_the_latest_by_date_not_by_string_and_refuses_one_model_twice(
        capsys, tmp_path):
    # review 2 #11: "20241105" sorts after "2024-12-01" as a string but is the earlier
    # date; the results document holds the latest calibration's parameters
    res = tmp_path / "history.json"
    a, b = str(H / "calibration_2024-03-04.json"), str(H / "calibration_2025-03-03.json")
    code, _, _ = _run(["compare", a, b, "--dates", "2024-12-01", "20241105",
                       "--results-json", str(res)], capsys)
    assert code == 0
    doc = json.loads(res.read_text())
    assert doc["history"]["dates"] == ["2024-11-05", "2024-12-01"]
    assert doc["model"]["name"] == "calibration_2024-03-04.json"
    code, out, err = _run(["compare", a, a, "--dates", "2024-01-01", "2025-01-01"], capsys)
    assert code == 2 and "same calibration" in err and err.count("\n") == 1


@pytest.mark.parametrize(("text", "needle"), [
    ("600,0.6", "did you mean 0.6,600?"),   # the terms swapped
    ("0.6,0.6", "not a CMM's MPE"),         # L/0.6: 1.7 mm per metre
    ("250,600", "not a CMM's MPE"),         # 250 µm constant term
])
def test_an_mpe_that_is_no_cmms_is_refused_in_one_line(text, needle, capsys):
    with pytest.raises(SystemExit) as exc:  # a usage error: argparse's exit status 2
        main(_check_args(CRASH, "--mpe", text))
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and needle in err

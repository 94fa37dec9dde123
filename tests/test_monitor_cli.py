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

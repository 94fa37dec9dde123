"""The ``next`` command (issue 29), exercised through its own parser: the sub-command is
registered by ``cli`` (not here), so the tests build a parser with ``add_parser``."""

import argparse
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from scenarios import simulated  # noqa: E402

from cmm_core.cli.commands import main  # noqa: E402
from cmm_core.cli.proposals import add_parser  # noqa: E402
from cmm_core.plan import read_plan  # noqa: E402


def _parser():
    ap = argparse.ArgumentParser(prog="cmm_core")
    add_parser(ap.add_subparsers(dest="command"))
    return ap


@pytest.fixture
def files(rxz4_files):
    return rxz4_files


def test_every_option_has_help_text():
    sub = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    p = sub.choices["next"]
    missing = [a.dest for a in p._actions if not a.help and a.dest != "help"]
    assert not missing, missing


def test_next_lists_proposals_as_json_and_writes_a_plan(files, tmp_path):
    plan = tmp_path / "next_plan.json"
    args = _parser().parse_args(
        ["next", str(files / "measurements.csv"), "--setup", str(files / "setup.json"),
         "--certificate", str(files / "certificate.csv"), "--baseline", "kinematic21,-sxy",
         "--rivals", "rxz:4,sxy", "--top", "3", "--plan-out", str(plan)])
    out = args.func(args)
    json.dumps(out)  # JSON-ready
    assert out["rivals"] == ["rxz:4", "sxy"] and len(out["proposals"]) == 3
    best = out["proposals"][0]
    assert best["power_min"] >= out["target_power"]
    assert best["outcome"].startswith("with ") and best["time_min"] > 0
    pf = read_plan(plan)
    assert [s.name for s in pf.strategies][0] == "current data"
    # what wrote it, kept by the plan reader (docs/planning.md)
    assert json.loads(plan.read_text())["provenance"]["software"] == "cmm-error-lab"


@pytest.mark.parametrize("bad", ["sxy", "sxy,sxy", "a,b,a", ","])
def test_rivals_must_be_two_different_tokens(bad, capsys):
    """Two or more (an alias set of three is one question), each once."""
    with pytest.raises(SystemExit):
        _parser().parse_args(["next", "m.csv", "--rivals", bad])
    assert "two or more different effect tokens" in capsys.readouterr().err


def test_instruments_are_scored_on_request(files):
    args = _parser().parse_args(
        ["next", str(files / "measurements.csv"), "--setup", str(files / "setup.json"),
         "--certificate", str(files / "certificate.csv"), "--baseline", "kinematic21,-sxy",
         "--rivals", "rxz:4,sxy", "--top", "30", "--instruments"])
    out = args.func(args)
    kinds = {p["instrument"].get("kind") for p in out["proposals"]}
    assert {"laser", "step_gauge", "ball_bar", None} <= kinds
    json.dumps(out)


def _inputs(files) -> list:
    return [str(files / "measurements.csv"), "--setup", str(files / "setup.json"),
            "--certificate", str(files / "certificate.csv")]


def test_next_with_a_plate_prior_runs(files, capsys):
    """``--plate prior`` (review 2, #1: it ended in an internal error, rc 3)."""
    rc = main(["next", *_inputs(files), "--baseline", "kinematic21,-sxy", "--rivals",
               "rxz:4,sxy", "--plate", "prior", "--top", "2"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    doc = json.loads(out.out)
    assert len(doc["proposals"]) == 2 and doc["proposals"][0]["power_min"] > 0


def test_a_rival_already_in_the_baseline_is_refused_in_one_line(files, capsys):
    """sxy in the default kinematic21 (review 2, #6): not scored as "0 % power"."""
    rc = main(["next", *_inputs(files), "--rivals", "sxy,rxz:4"])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("error: ")
    assert "sxy is already in the baseline kinematic21; give a baseline without it" in err


@pytest.fixture(scope="module")
def drift_files(tmp_path_factory):
    """Drift hidden with styli in blocks (seed 1003 of bench/proposals.py's drift case)."""
    out = tmp_path_factory.mktemp("drift")
    simulated("pitch80_3pos", 1003, noise_um=0.5,
              effects={"drift": {"sd_um_per_h": 1.0}}).write(out)
    return out


def test_next_proposes_a_repeat_where_styli_are_measured_in_blocks(drift_files, tmp_path):
    """The repeat at the end of a placement is among the default candidates, in the JSON
    with its placements, stylus, balls and times, and simulated; the plan file is the
    repeat's: the same placements and styli, its balls measured again (``repeat_at_end``)
    at the proposal's times with its set-up."""
    plan = tmp_path / "repeat_plan.json"
    args = _parser().parse_args(
        ["next", *_inputs(drift_files), "--rivals", "drift,probe_offset", "--top", "30",
         "--simulate", "--plan-out", str(plan)])
    out = args.func(args)
    json.dumps(out)
    best = out["proposals"][0]
    assert best["name"].startswith("repeat_") and best["positions"] == {}
    for p, r in best["repeat"].items():
        assert p in ("H", "D1", "D2") and r["probe"] in ("1", "2", "3")
        assert len(r["balls"]) == len(r["time_min"]) > 0
    assert out["simulated"]["drift"]["verdict"] == "drift"
    assert out["plan_file"]["proposal"] == best["name"]
    now, more = read_plan(plan).strategies
    assert now.probes_of == more.probes_of and now.repeat_at_end == {}
    # timed as proposed: after the data's last reading, a re-placement's set-up stated
    assert more.repeat_at_end == {p: {"probe": r["probe"], "balls": r["balls"],
                                      "time_min": r["time_min"], "setup_min": r["setup_min"]}
                                  for p, r in best["repeat"].items()}

"""Outputs never destroy inputs (issue 25): an output that is an input, a folder or another
output is refused in one line before any work; every file is written to a temporary file
in its folder and renamed into place, so a failed run leaves the old file intact; usage
errors are one line; numbers are range-checked where they enter."""

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys

import pytest
from conftest import ROOT

from cmm_core.cli import COMMANDS, MAX_MESSAGE, build_parser, main
from cmm_core.io import DataError, atomic_write_bytes, atomic_write_text, check_outputs
from cmm_core.io import output as output_module

SIM = ROOT / "sample_data" / "simulated"
GOOD_MODEL = ROOT / "tests" / "corpus" / "good_model.json"
POINTS = "probe,x_mm,y_mm,z_mm\n1,500,400,100\n2,650,420,300\n"
AIR = ["air", "--t-C", "20", "--p-Pa", "101325", "--rh-percent", "50",
       "--wavelength-nm", "632.99"]


def _run(argv):
    """(exit status, stderr lines, stdout) of the CLI in this process."""
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        rc = main([str(a) for a in argv])
    return rc, err.getvalue().strip().splitlines(), out.getvalue()


def _usage(argv, capsys):
    """The one stderr line of a usage error (exit status 2)."""
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in argv])
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("error: ") and lines[0].endswith("--help"), lines[0]
    return lines[0]


def _refused(rc, lines, *needles):
    assert rc == 2, (rc, lines)
    assert len(lines) == 1, lines
    assert len(lines[0]) <= MAX_MESSAGE + len("error: ")
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


@pytest.fixture
def model(tmp_path):
    m = tmp_path / "model.json"
    shutil.copy(GOOD_MODEL, m)
    return m


@pytest.fixture
def points(tmp_path):
    p = tmp_path / "points.csv"
    p.write_text(POINTS)
    return p


def _leftovers(folder):
    return [p.name for p in folder.iterdir() if p.name.endswith(".tmp")]


# --- an output that is an input --------------------------------------------------------

def test_export_refuses_the_model_as_its_own_grid(model):
    before = model.read_bytes()
    line = _refused(*_run(["export", model, "--grid", model])[:2], "--grid", "model.json",
                    "input")
    assert "destroy" in line
    assert model.read_bytes() == before
    for opt in ("--results-json", "--results-xml"):
        _refused(*_run(["export", model, opt, model])[:2], opt)
    assert model.read_bytes() == before


def test_export_standalone_refuses_too(model, capsys):
    from cmm_core.cli import run

    args = build_parser().parse_args(["export", str(model), "--results-json", str(model)])
    before = model.read_bytes()
    assert run(args) == 2
    assert "--results-json" in capsys.readouterr().err
    assert model.read_bytes() == before


def test_compensate_refuses_its_own_inputs_as_out(model, points):
    before_m, before_p = model.read_bytes(), points.read_bytes()
    _refused(*_run(["compensate", model, points, "--out", points])[:2], "--out", "points.csv")
    _refused(*_run(["compensate", model, points, "--out", model])[:2], "--out", "model.json")
    # the same file by another spelling, and through a hard link
    other = points.parent / "sub"
    other.mkdir()
    _refused(*_run(["compensate", model, points, "--out", other / ".." / "points.csv"])[:2],
             "--out")
    os.link(points, points.parent / "link.csv")
    _refused(*_run(["compensate", model, points, "--out", points.parent / "link.csv"])[:2],
             "--out")
    assert model.read_bytes() == before_m and points.read_bytes() == before_p


def test_json_and_save_refuse_inputs(tmp_path, model, points):
    before = model.read_bytes()
    _refused(*_run(["--json", model, "compensate", model, points, "--out",
                    tmp_path / "c.csv"])[:2], "--json", "input")
    _refused(*_run(["task", model, ROOT / "sample_data" / "plans" / "task_distance.json",
                    "--json", model])[:2], "--json")
    assert model.read_bytes() == before
    setup = tmp_path / "setup.json"
    shutil.copy(SIM / "setup.json", setup)
    before = setup.read_bytes()
    _refused(*_run(["fit", SIM / "measurements.csv", "--setup", setup, "--save", setup])[:2],
             "--save", "setup.json")
    assert setup.read_bytes() == before


def test_report_refuses_a_data_file_of_its_record(tmp_path):
    shutil.copytree(ROOT / "sample_data" / "thesis", tmp_path / "thesis")
    record = tmp_path / "thesis" / "analysis.json"
    target = tmp_path / "thesis" / "BP111.csv"
    before = target.read_bytes()
    _refused(*_run(["report", record, "--out", target])[:2], "--out", "BP111.csv")
    _refused(*_run(["report", record, "--out", record])[:2], "--out", "analysis.json")
    assert target.read_bytes() == before


def test_simulate_refuses_a_config_it_would_overwrite(tmp_path):
    cfg = tmp_path / "setup.json"
    cfg.write_text(json.dumps({"seed": 3}))
    _refused(*_run(["simulate", cfg, "--out", tmp_path])[:2], "--out", "setup.json")
    assert json.loads(cfg.read_text()) == {"seed": 3}


# --- two outputs, one file ------------------------------------------------------------

def test_two_outputs_naming_one_file_are_refused(tmp_path, model, points):
    out = tmp_path / "out.csv"
    _refused(*_run(["compensate", model, points, "--out", out, "--json", out])[:2],
             "--out", "--json", "same file")
    _refused(*_run(["export", model, "--grid", out, "--results-json", out])[:2],
             "--grid", "--results-json")
    _refused(*_run(["export", model, "--axis-tables", tmp_path / "ax", "--grid",
                    tmp_path / "ax" / "axis_x.csv"])[:2], "--axis-tables", "axis_x.csv")
    assert not out.exists() and not (tmp_path / "ax").exists()


# --- folders ---------------------------------------------------------------------------

@pytest.mark.parametrize("after", [False, True], ids=["before", "after"])
def test_json_naming_a_folder_is_refused_in_one_line(tmp_path, after):
    argv = [*AIR, "--json", tmp_path] if after else ["--json", tmp_path, *AIR]
    line = _refused(*_run(argv)[:2], "--json", "folder")
    assert "Traceback" not in line


def test_folders_given_as_files_and_files_as_folders(tmp_path, model, points):
    _refused(*_run(["compensate", model, points, "--out", tmp_path])[:2], "--out", "folder")
    _refused(*_run(["export", model, "--grid", tmp_path])[:2], "--grid", "folder")
    _refused(*_run(["export", model, "--axis-tables", points])[:2], "--axis-tables",
             "not a folder")
    _refused(*_run(["compensate", model, points, "--out", tmp_path / "no" / "c.csv"])[:2],
             "--out", "does not exist")
    with pytest.raises(DataError, match="folder"):
        atomic_write_text(tmp_path, "x")


# --- atomic writes ---------------------------------------------------------------------

def test_atomic_write_replaces_whole_and_keeps_the_mode(tmp_path):
    f = tmp_path / "a.txt"
    atomic_write_text(f, "one\r\ntwo\n")
    assert f.read_bytes() == b"one\r\ntwo\n"  # written as given
    f.chmod(0o640)
    atomic_write_bytes(f, b"new")
    assert f.read_bytes() == b"new" and (f.stat().st_mode & 0o777) == 0o640
    assert _leftovers(tmp_path) == []


def test_a_reader_sees_the_old_file_until_the_rename(tmp_path, monkeypatch):
    f = tmp_path / "a.json"
    f.write_text("old")
    seen = []
    real = os.fsync

    def fsync(fd):
        seen.append(f.read_text())  # mid-write: the new data are in the temporary file
        return real(fd)

    monkeypatch.setattr(output_module.os, "fsync", fsync)
    atomic_write_text(f, "new")
    assert seen[0] == "old" and f.read_text() == "new"


def _fail_mid_write(monkeypatch):
    def fsync(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(output_module.os, "fsync", fsync)


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    f = tmp_path / "a.json"
    f.write_text("old")
    _fail_mid_write(monkeypatch)
    with pytest.raises(OSError) as exc:
        atomic_write_text(f, "new" * 1000)
    assert exc.value.filename == str(f)  # named as the user named it, not the temp file
    assert f.read_text() == "old" and _leftovers(tmp_path) == []


def test_a_failed_run_leaves_existing_outputs_intact(tmp_path, model, points, monkeypatch):
    out, js = tmp_path / "c.csv", tmp_path / "r.json"
    out.write_text("previous result\n")
    js.write_text("{}")
    _fail_mid_write(monkeypatch)
    _refused(*_run(["compensate", model, points, "--out", out])[:2], "c.csv", "No space")
    _refused(*_run([*AIR, "--json", js])[:2], "r.json", "No space")
    _refused(*_run(["export", model, "--results-json", js])[:2], "r.json")
    assert out.read_text() == "previous result\n" and js.read_text() == "{}"
    assert _leftovers(tmp_path) == []
    monkeypatch.undo()
    rc, lines, _ = _run(["compensate", model, points, "--out", out, "--json", js])
    assert rc == 0, lines
    table = [ln for ln in out.read_text().splitlines() if not ln.startswith("# ")]
    assert table[0].startswith("probe,x_mm") and json.loads(js.read_text())["n_points"] == 2


def test_export_writes_every_file_atomically(tmp_path, model):
    rc, lines, stdout = _run(["export", model, "--grid", tmp_path / "g.csv", "--axis-tables",
                              tmp_path / "ax", "--results-json", tmp_path / "r.json",
                              "--json", tmp_path / "summary.json"])
    assert rc == 0, lines
    assert stdout == ""
    assert json.loads((tmp_path / "summary.json").read_text())["grid"]["nodes"] > 0
    assert sorted(p.name for p in (tmp_path / "ax").iterdir()) == [
        "axis_x.csv", "axis_y.csv", "axis_z.csv", "squareness.csv"]
    assert _leftovers(tmp_path) == [] and _leftovers(tmp_path / "ax") == []


def test_check_outputs_directly(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.write_text("x")
    check_outputs({"--o": b, "--p": None}, [a, None])
    with pytest.raises(DataError, match="--o names an input"):
        check_outputs({"--o": a}, [a])
    (tmp_path / "ln").symlink_to(a)
    with pytest.raises(DataError, match="--o names an input"):
        check_outputs({"--o": tmp_path / "ln"}, [a])
    with pytest.raises(DataError, match="--o and --p name the same file"):
        check_outputs({"--o": b, "--p": tmp_path / "." / "b"})
    check_outputs({"--o": [tmp_path / "new" / "f"]}, folders={"--o": tmp_path / "new"})


# --- the command line: usage errors, --json after the command, ranges -----------------

def test_usage_errors_are_one_line(capsys):
    assert "invalid choice" in _usage(["bogus"], capsys)
    assert "required" in _usage(["compensate"], capsys)
    line = _usage(["fit", "--plate", "loose"], capsys)
    assert "--plate" in line and "python -m cmm_core fit --help" in line
    assert "unrecognized arguments: --nope" in _usage([*AIR, "--nope"], capsys)


def test_usage_error_exit_status_from_the_shell():
    p = subprocess.run([sys.executable, "-m", "cmm_core", "task", "m.json", "t.json",
                        "--trials", "0"], cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr.count("\n") == 1 and "100 to 10000000" in p.stderr


def test_json_after_the_command_and_in_every_help(tmp_path):
    rc, lines, stdout = _run([*AIR, "--json", tmp_path / "air.json"])
    assert rc == 0, lines
    assert stdout == "" and json.loads((tmp_path / "air.json").read_text())["n"] > 1
    # after wins over before: the one given last on the line
    rc, _, _ = _run(["--json", tmp_path / "x.json", *AIR, "--json", tmp_path / "y.json"])
    assert rc == 0 and (tmp_path / "y.json").exists()
    ap = build_parser()
    sub = next(a for a in ap._actions if a.dest == "command")
    for name, p in sub.choices.items():  # every command that ends in a result
        assert ("--json FILE" in p.format_help()) is not COMMANDS[name].serves, name


@pytest.mark.parametrize("option,command", [("--model", "fit"), ("--baseline", "diagnose")])
@pytest.mark.parametrize("spec", ["", " ", ","])
def test_an_empty_model_spec_is_refused(option, command, spec, capsys):
    line = _usage([command, SIM / "measurements.csv", "--setup", SIM / "setup.json",
                   option, spec], capsys)
    assert option in line and "empty" in line


@pytest.mark.parametrize("argv,needle", [
    (["task", "m.json", "t.json", "--trials", "0"], "100 to 10000000"),
    (["task", "m.json", "t.json", "--trials", "x"], "whole number"),
    (["plan", "p.json", "--workers", "0"], "1 to 1024"),
    (["plan", "p.json", "--check-trials", "-1"], "0 to 100000"),
    (["gp", "--order", "9"], "1 to 5"),
    (["air", "--t-C", "90", "--p-Pa", "1e5", "--rh-percent", "50", "--wavelength-nm", "633"],
     "0 to 40"),
    (["air", "--t-C", "nan", "--p-Pa", "1e5", "--rh-percent", "50", "--wavelength-nm",
      "633"], "0 to 40"),
])
def test_numbers_are_range_checked_where_they_enter(argv, needle, capsys):
    assert needle in _usage(argv, capsys)


def test_help_states_the_allowed_ranges():
    ap = build_parser()
    sub = next(a for a in ap._actions if a.dest == "command")
    helps = {n: " ".join(p.format_help().split()) for n, p in sub.choices.items()}
    assert "100 to 10000000" in helps["task"]
    assert "1 to 1024" in helps["plan"] and "0 to 100000" in helps["plan"]
    assert "1 to 5" in helps["gp"]
    assert "0 to 40" in helps["air"] and "60000 to 120000" in helps["air"]


@pytest.mark.parametrize("target", ["interim", "history"])
def test_report_never_writes_over_a_calibration_its_record_reads(tmp_path, target):
    """The record's stored model (its interim check) and its history's models are inputs:
    ``report --out`` or ``--json`` naming one is refused before any work, the file kept."""
    src = ROOT / "sample_data" / "history"
    for p in src.rglob("*"):
        if p.is_file():
            dest = tmp_path / p.relative_to(src)
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(p.read_bytes())
    doc = json.loads((tmp_path / "analysis_after_crash.json").read_text())
    victim = tmp_path / (doc["interim_check"]["model"]["path"] if target == "interim" else
                         doc["calibration_history"]["models"][-1]["path"])
    before = victim.read_bytes()
    for opt in ("--out", "--json"):
        argv = ["report", tmp_path / "analysis_after_crash.json", "--out",
                victim if opt == "--out" else tmp_path / "r.html",
                *(["--json", victim] if opt == "--json" else [])]
        rc, lines, _ = _run(argv)
        assert rc == 2 and len(lines) == 1 and victim.name in lines[0], lines
        assert victim.read_bytes() == before


def test_check_and_compare_refuse_one_file_for_two_of_their_outputs(tmp_path):
    h = ROOT / "sample_data" / "history"
    crash = h / "check_2025-02-10_after_crash"
    same = tmp_path / "out.json"
    check = ["check", h / "calibration_2024-03-04.json", crash / "measurements.csv",
             "--setup", crash / "setup.json", "--certificate", crash / "certificate.csv"]
    cals = sorted(h.glob("calibration_*.json"))
    compare = ["compare", *cals, "--dates", *[p.stem.split("_")[1] for p in cals]]
    for argv in ([*check, "--json", same, "--results-json", same],
                 [*check, "--json", same, "--report", same],
                 [*compare, "--json", same, "--results-json", same]):
        rc, lines, _ = _run(argv)
        assert rc == 2 and len(lines) == 1 and "out.json" in lines[0], lines
        assert not same.exists()


# --- two runs, one output -------------------------------------------------------------

def test_an_output_written_by_another_run_meanwhile_is_not_replaced(tmp_path):
    """Between a command's start (``check_outputs``) and its write, another run wrote the
    output: the later write keeps that file, puts its own result beside it as
    ``NAME.conflict-XXXX`` and says so in one line (it was "the last rename wins")."""
    out = tmp_path / "result.json"
    check_outputs({"--json": out})
    out.write_text("the other run's result")  # another process, after this one started
    with pytest.raises(DataError) as exc:
        atomic_write_text(out, "this run's result")
    assert out.read_text() == "the other run's result"
    kept = [p for p in tmp_path.iterdir() if p.name.startswith("result.json.conflict-")]
    assert len(kept) == 1 and kept[0].read_text() == "this run's result"
    assert kept[0].name in str(exc.value) and "another run" in str(exc.value)
    output_module.forget_outputs()


def test_a_set_of_outputs_is_refused_whole_when_one_was_written_meanwhile(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    b.write_text("old b")
    check_outputs({"--grid": a, "--tables": b})
    b.write_text("b from another run")
    with pytest.raises(DataError):
        output_module.atomic_write_all({a: "new a", b: "new b"})
    assert not a.exists() and b.read_text() == "b from another run"  # all or none
    output_module.forget_outputs()


def test_the_cli_tells_the_later_run_and_exits_non_zero(tmp_path, model, points,
                                                        monkeypatch):
    """``compensate --out`` whose output another run writes while it works: exit 2, one
    line naming the file and where this run's result went; the other run's file stays,
    and a run after both writes normally (the states are forgotten at the end)."""
    out = tmp_path / "corrected.csv"
    real = output_module._Temp.finish

    def meanwhile(f):  # as this run's table reaches the disk, another run's lands
        out.write_text("another run's table")
        real(f)

    monkeypatch.setattr(output_module._Temp, "finish", staticmethod(meanwhile))
    rc, lines, _ = _run(["compensate", model, points, "--out", out])
    monkeypatch.undo()
    assert rc == 2 and len(lines) == 1 and "another run" in lines[0] and "conflict-" in lines[0]
    assert out.read_text() == "another run's table"
    rc, lines, _ = _run(["compensate", model, points, "--out", out])
    assert rc == 0 and out.read_text() != "another run's table"

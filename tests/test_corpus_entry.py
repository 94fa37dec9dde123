"""Bad inputs over the entry points added since the first hardening (issue 25).

A corpus generated from good files, one defect per input, each fed to the command line in
this process (``cli.main``): instrument files (laser, step gauge, ball bar), hole-plate and
layout setups, plan and task JSON, export options, analysis records for ``report``,
project files (through the core reader the app uses) and path tricks. The good file
behind each kind is first shown to be accepted, so a refusal of a mutant is due to its
defect. Every input must end in:

- no exception other than the project's :class:`~cmm_core.io.DataError` (an argparse
  usage error for option values), recorded where ``main`` turns it into its line;
- exit status 2 with **one** stderr line naming the file;
- no NaN or inf in any file the run wrote;
- no input file changed (SHA-256 before and after).

The mutations are generated deterministically (``random.Random(CORPUS_SEED)`` where
sampled), so the corpus is the same on every run and serves as regression tests; each
kind's generator states why each of its mutations is bad by construction.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import json
import random
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT
from hypothesis import given, settings
from hypothesis import strategies as st

from cmm_core.cli import MAX_MESSAGE, main
from cmm_core.cli import commands as cli_commands
from cmm_core.export import project_from_json
from cmm_core.io import DataError
from cmm_core.model import read_instrument

CORPUS_SEED = 25
SIM = ROOT / "sample_data" / "simulated"
INS = ROOT / "sample_data" / "instruments"
PLANS = ROOT / "sample_data" / "plans"
GOOD_MODEL = ROOT / "tests" / "corpus" / "good_model.json"
_NONFINITE = re.compile(r"(?<![A-Za-z_])(nan|inf|infinity)(?![A-Za-z_])", re.IGNORECASE)

# Cells no numeric column may hold: junk, non-finite, a unit, a decimal comma, overflow.
_BAD_CELLS = ["nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e999", "", "abc", "12 mm",
              '"1,5"', "0x1F", "\x00"]


def _laser_text():
    return (INS / "laser_x.csv").read_text()


def _step_gauge_text():
    return (INS / "step_gauge.csv").read_text()


def _ball_bar_text():
    """A good ball-bar file from the step gauge's probed points: the certified length is
    the centres' distance rounded to 0.1 µm (within the reader's 1 mm)."""
    lines = _step_gauge_text().splitlines()
    head = lines[0].split(",")
    out = ["bar,x1_mm,y1_mm,z1_mm,x2_mm,y2_mm,z2_mm,certified_mm,u_um"]
    for ln in lines[1:]:
        f = dict(zip(head, ln.split(","), strict=True))
        a = np.array([float(f[c]) for c in ("x1_mm", "y1_mm", "z1_mm")])
        b = np.array([float(f[c]) for c in ("x2_mm", "y2_mm", "z2_mm")])
        out.append(",".join([f["gauge"], *(f[c] for c in head[1:7]),
                             f"{np.linalg.norm(b - a):.4f}", "0.3"]))
    return "\n".join(out) + "\n"


_INSTRUMENTS = {
    # kind: (good text, numeric columns, column -> values bad by meaning there)
    "laser": (_laser_text, ("x_mm", "y_mm", "z_mm", "error_um", "u_um"),
              {"u_um": ["0", "-0.2", "1e-12", "5000"], "error_um": ["5000", "-2e4"],
               "axis": ["w", "", "1", "xy"], "component": ["q", "7"], "run": [""]}),
    "step_gauge": (_step_gauge_text, ("x1_mm", "y1_mm", "z1_mm", "x2_mm", "y2_mm", "z2_mm",
                                      "measured_mm", "certified_mm", "u_um", "offset_x_mm",
                                      "offset_y_mm", "offset_z_mm"),
                   {"u_um": ["0", "-0.3", "1e-12", "5000"], "certified_mm": ["-100", "0"],
                    "measured_mm": ["-5", "1e6"], "offset_z_mm": ["-0.15", "-5000"]}),
    "ball_bar": (_ball_bar_text, ("x1_mm", "y1_mm", "z1_mm", "x2_mm", "y2_mm", "z2_mm",
                                  "certified_mm", "u_um"),
                 {"u_um": ["0", "-0.3", "1e-12", "5000"], "certified_mm": ["-100", "0", "5"]}),
}


def _csv_edit(text, row, col, value):
    """``text`` with the cell of data row ``row`` (0-based) in column ``col`` replaced."""
    lines = text.splitlines()
    head = lines[0].split(",")
    f = lines[row + 1].split(",")
    f[head.index(col)] = value
    lines[row + 1] = ",".join(f)
    return "\n".join(lines) + "\n"


def _scaled(text, cols, factor):
    """Every cell of ``cols`` multiplied by ``factor`` (a unit slip of the whole file)."""
    lines = text.splitlines()
    head = lines[0].split(",")
    out = [lines[0]]
    for ln in lines[1:]:
        f = ln.split(",")
        for c in cols:
            f[head.index(c)] = f"{float(f[head.index(c)]) * factor:.9g}"
        out.append(",".join(f))
    return "\n".join(out) + "\n"


def _without(text, col):
    lines = [ln.split(",") for ln in text.splitlines()]
    k = lines[0].index(col)
    return "\n".join(",".join(x for j, x in enumerate(f) if j != k) for f in lines) + "\n"


def _instrument_cases(rng):
    """(kind, description, file bytes) of instrument files, each bad by construction:
    a bad cell in each numeric column (non-finite, junk, a unit, overflow beyond every
    range), values out of each column's range, the whole file in metres or µm, each
    required column missing, an unknown or doubled column, a truncated row, binary,
    empty, header only, NUL, too many rows, a lone temperature column."""
    out = []
    required = {"laser": ("axis", "x_mm", "y_mm", "z_mm", "error_um", "u_um"),
                "step_gauge": ("x1_mm", "y1_mm", "z1_mm", "x2_mm", "y2_mm", "z2_mm",
                               "measured_mm", "certified_mm", "u_um"),
                "ball_bar": ("x1_mm", "y1_mm", "z1_mm", "x2_mm", "y2_mm", "z2_mm",
                             "certified_mm", "u_um")}
    for kind, (good, numeric, meaning) in _INSTRUMENTS.items():
        text = good()
        n = len(text.splitlines()) - 1
        for col in numeric:  # five of the bad cells per column, every cell in some
            for cell in rng.sample(_BAD_CELLS, 5):
                out.append((kind, f"{col}={cell[:8]!r}", _csv_edit(text, rng.randrange(n),
                                                                   col, cell)))
        for col, cells in meaning.items():
            for cell in cells:
                out.append((kind, f"{col}={cell!r}", _csv_edit(text, rng.randrange(n), col,
                                                               cell)))
        points = [c for c in numeric if c[0] in "xyz" and c.endswith("_mm")]
        out.append((kind, "points in metres", _scaled(text, points, 1e-3)))
        out.append((kind, "points in µm", _scaled(text, points, 1e3)))
        if "offset_x_mm" in text.splitlines()[0]:
            out.append((kind, "offsets in metres", _scaled(
                text, ["offset_x_mm", "offset_y_mm", "offset_z_mm"], 1e-3)))
        for col in required[kind]:
            out.append((kind, f"no column {col}", _without(text, col)))
        lines = text.splitlines()
        out += [
            (kind, "unknown column", "\n".join([lines[0] + ",colour"]
                                               + [ln + ",red" for ln in lines[1:]]) + "\n"),
            (kind, "misspelt column u_mm", text.replace("u_um", "u_mm", 1)),
            (kind, "column twice", "\n".join([lines[0] + ",u_um"]
                                             + [ln + ",0.3" for ln in lines[1:]]) + "\n"),
            (kind, "truncated in a row", "\n".join(lines[:-1]) + "\n"
             + ",".join(lines[-1].split(",")[:3])),
            (kind, "binary", bytes(rng.randrange(128, 256) for _ in range(400))),
            (kind, "empty", b""),
            (kind, "header only", lines[0] + "\n"),
            (kind, "NUL", text[:60] + "\x00" + text[60:]),
            (kind, "extra field with data", "\n".join(lines[:2] + [lines[2] + ",9"]
                                                      + lines[3:]) + "\n"),
        ]
        if kind != "laser":
            out.append((kind, "temp_C without cte_per_K", "\n".join(
                [lines[0] + ",temp_C"] + [ln + ",20.5" for ln in lines[1:]]) + "\n"))
            out.append((kind, "temp_C in kelvin", "\n".join(
                [lines[0] + ",temp_C,cte_per_K"]
                + [ln + ",293.65,11.5e-6" for ln in lines[1:]]) + "\n"))
    # more rows than an instrument file may hold: a continuous-mode laser log
    xs = np.arange(25_000) * 0.04
    out.append(("laser", "25 000 readings", "axis,x_mm,y_mm,z_mm,error_um,u_um\n" + "".join(
        f"x,{x:.2f},100,50,0.1,0.2\n" for x in xs)))
    return [(k, d, t if isinstance(t, bytes) else t.encode()) for k, d, t in out]


# ---------------------------------------------------------------------------------------
# JSON inputs: one leaf or key broken at a time
# ---------------------------------------------------------------------------------------

def _leaves(doc, path=()):
    """Paths of every leaf (numbers, strings, booleans; list entries included)."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _leaves(v, path + (i,))
    else:
        yield path


def _set(doc, path, value):
    bad = copy.deepcopy(doc)
    parent = bad
    for k in path[:-1]:
        parent = parent[k]
    parent[path[-1]] = value
    return bad


def _wrong(old):
    """Values wrong for a leaf whatever it means: non-finite and overflowing numbers for a
    number, another JSON type for anything (null excepted: several fields take null for
    "default")."""
    if isinstance(old, bool):
        return ["yes", 2, []]
    if isinstance(old, int | float):
        return [float("nan"), float("inf"), -float("inf"), 1e308, "abc", [], {}]
    if isinstance(old, str):
        return [12, [], {}, True]
    return ["abc", 5]


def _json_cases(kind, doc, rng, n, skip=(), misplaced=()):
    """``n`` mutants of ``doc`` sampled from every (leaf, wrong value), plus keys moved to
    the wrong level (``misplaced``: (path of the key, new path)), a misspelt key at each
    object level, truncated, binary, empty and not-an-object documents. ``skip``: paths
    (as text) of free text fields, whose value is never checked."""
    pool = [(p, v) for p in _leaves(doc) if not any(s in map(str, p) for s in skip)
            for v in _wrong(_get(doc, p))]
    out = [(kind, f"{'.'.join(map(str, p))}={v!r}"[:80], json.dumps(_set(doc, p, v)))
           for p, v in rng.sample(pool, min(n, len(pool)))]
    for src, dst in misplaced:
        bad = copy.deepcopy(doc)
        parent = bad
        for k in src[:-1]:
            parent = parent[k]
        value = parent.pop(src[-1])
        target = bad
        for k in dst[:-1]:
            target = target.setdefault(k, {})
        target[dst[-1]] = value
        out.append((kind, f"{'.'.join(src)} moved to {'.'.join(dst)}", json.dumps(bad)))
    for p in {p[:-1] + (p[-1],) for p in _leaves(doc) if isinstance(p[-1], str)
              and not any(s in map(str, p) for s in skip)}:
        out.append((kind, f"misspelt {'.'.join(map(str, p))}",
                    json.dumps(_rename(doc, p, p[-1][:-1] + p[-1][-1].upper() + "x"))))
    text = json.dumps(doc)
    out += [(kind, "truncated", text[:len(text) // 2]),
            (kind, "binary", bytes(rng.randrange(128, 256) for _ in range(300))),
            (kind, "empty", ""), (kind, "not an object", "[1, 2, 3]"),
            (kind, "NaN literal document", "NaN")]
    return [(k, d, t if isinstance(t, bytes) else t.encode()) for k, d, t in out]


def _get(doc, path):
    for k in path:
        doc = doc[k]
    return doc


def _rename(doc, path, new):
    bad = copy.deepcopy(doc)
    parent = _get(bad, path[:-1])
    parent[new] = parent.pop(path[-1])
    return bad


def _plan_doc():
    doc = json.loads((PLANS / "thesis_plan.json").read_text())
    doc["setup"] = str(ROOT / "sample_data" / "thesis" / "setup.json")
    return doc


def _task_doc():
    return json.loads((PLANS / "task_distance.json").read_text())


def _hole_setup():
    doc = json.loads((SIM / "setup.json").read_text())
    doc["artefact"] = "hole_plate"
    return doc


def _layout_setup():
    doc = json.loads((SIM / "setup.json").read_text())
    doc.setdefault("machine", {})["layout"] = "fixed_bridge_xfyz"
    return doc


def _record_doc():
    doc = json.loads((ROOT / "sample_data" / "thesis" / "analysis.json").read_text())
    base = ROOT / "sample_data" / "thesis"
    data = doc["data"]
    for f in (*data["measurements"], data["setup"], data["certificate"]):
        f["path"] = str((base / f["path"]).resolve())
    return doc


def _json_inputs(rng):
    """Every JSON mutant: (kind, description, bytes)."""
    out = []
    out += _json_cases("plan", _plan_doc(), rng, 70, skip=("name", "note", "description"))
    out += _json_cases("task", _task_doc(), rng, 50)
    setup_moves = [(("machine", "layout"), ("layout",)), (("machine", "range_mm"),
                                                          ("range_mm",)),
                   (("machine", "layout"), ("positions", "BP111", "layout")),
                   (("artefact",), ("machine", "artefact"))]
    # a setup's probe and position names are the user's to choose (a renamed one is
    # another name, not a misspelling), and "probe" values name them
    out += _json_cases("hole_setup", _hole_setup(), rng, 50,
                       skip=("probes", "probe", "positions"), misplaced=setup_moves)
    out += _json_cases("layout_setup", _layout_setup(), rng, 25,
                       skip=("probes", "probe", "positions"), misplaced=setup_moves[:2])
    out += [("hole_setup", f"artefact {v!r}", json.dumps(_set(_hole_setup(), ("artefact",),
                                                              v)).encode())
            for v in ("hole", "Hole_Plate ", "ballplate", "", "hole plate")]
    out += [("layout_setup", f"layout {v!r}", json.dumps(_set(_layout_setup(),
                                                              ("machine", "layout"),
                                                              v)).encode())
            for v in ("banana", "fixed_bridge", "moving-bridge", "FIXED_BRIDGE_XFYZ ", "")]
    # a budget (issue 25: 3 trials or U = 0 were accepted); a dof of 1e308 or inf is
    # infinite degrees of freedom, which a budget may state
    budget = json.loads((ROOT / "sample_data" / "budget" / "ballplate_budget.json").read_text())
    out += [c for c in _json_cases("budget", budget, rng, 40,
                                   skip=("name", "unit", "description"))
            if not re.search(r"dof=(1e\+308|inf)", c[1])]
    zero = copy.deepcopy(budget)
    for c in zero["contributions"]:
        c.update({k: 0 for k in ("u", "half_width") if k in c})
    out += [("budget", "every u zero", json.dumps(zero).encode())]
    out += [("budget", f"monte_carlo_trials={n}", json.dumps({**budget,
                                                            "monte_carlo_trials": n}).encode())
            for n in (1, 3, 999, -5, 1.5, 10**9)]
    # an analysis record: its data files, model choices and options
    # the history's "change" is a free description of each step
    out += _json_cases("record", _record_doc(), rng, 50,
                       skip=("name", "note", "description", "change", "exclusions"))
    return out


# ---------------------------------------------------------------------------------------
# Running one input
# ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A folder with the good files every command needs besides the input under test."""
    d = tmp_path_factory.mktemp("corpus25")
    lines = (SIM / "measurements.csv").read_text().splitlines()
    (d / "meas.csv").write_text("\n".join(lines[:151]) + "\n")  # three placements
    return d


def _argv(kind, path, work, out):
    """The command that feeds ``path`` as an input of ``kind`` (the rest valid)."""
    fit = ["fit", work / "meas.csv", "--setup", SIM / "setup.json", "--certificate",
           SIM / "certificate.csv", "--model", "translational", "--json", out / "fit.json"]
    return {
        "laser": [*fit, "--laser", path],
        "step_gauge": [*fit, "--step-gauge", path],
        "ball_bar": [*fit, "--ball-bar", path],
        "hole_setup": [*fit[:3], path, *fit[4:]],
        "layout_setup": [*fit[:3], path, *fit[4:]],
        "plan": ["plan", path, "--no-detection", "--json", out / "plan.json"],
        "task": ["task", GOOD_MODEL, path, "--trials", "1000", "--json", out / "task.json"],
        # the corpus's records name the sample data by absolute path (outside their folder)
        "record": ["report", path, "--out", out / "report.html", "--json", out / "r.json",
                   "--any-path"],
        "budget": ["budget", path, "--json", out / "budget.json"],
    }[kind]


def _run(argv):
    """``main`` in this process: (exit status, stderr lines, exception types that main
    turned into its line). An exception escaping ``main`` propagates (a traceback)."""
    seen: list[type] = []
    one_line = cli_commands._one_line

    def spy(exc, name):
        seen.append(type(exc))
        return one_line(exc, name)

    err, out = io.StringIO(), io.StringIO()
    cli_commands._one_line = spy
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                rc = main([str(a) for a in argv])
            except SystemExit as exc:  # argparse: a usage error, one line (checked below)
                rc = exc.code
                seen.append(SystemExit)
    finally:
        cli_commands._one_line = one_line
    # a warning is printed on stderr by the command line: two more lines for the user
    lines = err.getvalue().strip().splitlines()
    lines += [f"{w.category.__name__}: {w.message}" for w in caught]
    return rc, lines, seen


def _digest(paths):
    return {str(p): hashlib.sha256(Path(p).read_bytes()).hexdigest() for p in paths
            if Path(p).is_file()}


def _nonfinite_outputs(out):
    """Data files written (JSON, CSV, XML) holding a NaN or inf token (an HTML report
    carries plotly's code, where such words are code, not numbers)."""
    return [p.name for p in out.rglob("*") if p.suffix in (".json", ".csv", ".xml")
            and _NONFINITE.search(p.read_text(errors="replace"))]


def _judge(argv, name, out):
    """One verdict string per failure of the four rules ('' when the input passed)."""
    inputs = [a for a in argv if isinstance(a, Path) and a.parent != out]
    before = _digest(inputs)
    try:
        rc, lines, seen = _run(argv)
    except BaseException as exc:  # noqa: BLE001 - anything escaping main is a traceback
        return f"traceback {type(exc).__name__}: {str(exc)[:120]}"
    problems = []
    if rc == 0:
        problems.append("accepted")
    elif rc != 2:
        problems.append(f"exit {rc} {lines[:1]}")
    foreign = [t.__name__ for t in seen if not issubclass(t, DataError | SystemExit)]
    if foreign:
        problems.append(f"raised {foreign} {lines[:1]}")
    if rc != 0 and (len(lines) != 1 or name not in lines[0]
                    or len(lines[0]) > MAX_MESSAGE + len("error: ")):
        problems.append(f"not one line naming {name}: {lines[:2]}")
    if _digest(inputs) != before:
        problems.append("an input changed")
    bad_out = _nonfinite_outputs(out)
    if bad_out:
        problems.append(f"NaN/inf in {bad_out}")
    return "; ".join(problems)


def _corpus():
    rng = random.Random(CORPUS_SEED)
    return _instrument_cases(rng) + _json_inputs(rng)


CASES = _corpus()
_SUFFIX = {"laser": "csv", "step_gauge": "csv", "ball_bar": "csv"}


def test_the_good_file_behind_each_kind_is_accepted(work, tmp_path):
    """Every kind's starting file passes: a refusal of a mutant is due to its defect."""
    good = {"laser": _laser_text().encode(), "step_gauge": _step_gauge_text().encode(),
            "ball_bar": _ball_bar_text().encode(),
            "hole_setup": json.dumps(_hole_setup()).encode(),
            "layout_setup": json.dumps(_layout_setup()).encode(),
            "plan": json.dumps(_plan_doc()).encode(), "task": json.dumps(_task_doc()).encode(),
            "record": json.dumps(_record_doc()).encode(),
            "budget": (ROOT / "sample_data" / "budget" / "ballplate_budget.json").read_bytes()}
    for kind, data in good.items():
        out = tmp_path / kind
        out.mkdir()
        path = work / f"good_{kind}.{_SUFFIX.get(kind, 'json')}"
        path.write_bytes(data)
        rc, lines, _ = _run(_argv(kind, path, work, out))
        assert rc == 0, (kind, lines)
        assert not _nonfinite_outputs(out), kind


def _check_cases(cases, work, tmp_path):
    failures = []
    for k, (kind, desc, data) in enumerate(cases):
        name = f"bad{k:03d}_{kind}.{_SUFFIX.get(kind, 'json')}"
        path = work / name
        path.write_bytes(data)
        out = tmp_path / f"out{k:03d}"
        out.mkdir()
        verdict = _judge(_argv(kind, path, work, out), name, out)
        if verdict:
            failures.append(f"{kind} [{desc}]: {verdict}")
    return failures


_FAST_KINDS = ("laser", "step_gauge", "ball_bar", "plan", "task")


def test_instrument_plan_and_task_corpus_is_refused_in_one_line(work, tmp_path):
    """Instrument files, plans and tasks: 0 tracebacks, 0 silent acceptances, 0 inputs
    changed, no NaN/inf written, every refusal one line naming the file."""
    cases = [c for c in CASES if c[0] in _FAST_KINDS]
    failures = _check_cases(cases, work, tmp_path)
    assert len(cases) >= 350
    assert failures == []


def test_setup_and_record_corpus_is_refused_in_one_line(work, tmp_path):
    """Hole-plate and layout setups, analysis records (``report``): the same rules."""
    cases = [c for c in CASES if c[0] not in _FAST_KINDS]
    failures = _check_cases(cases, work, tmp_path)
    assert len(cases) >= 150
    assert failures == []


# ---------------------------------------------------------------------------------------
# Path tricks, option values and repeated files: each case its own command line
# ---------------------------------------------------------------------------------------

def _path_cases(work, out):
    """(description, argv, what the one line must name). Outputs onto inputs or folders,
    folders and devices as inputs, missing and oversized files, a file given twice (by
    path, by another path, by copy), option values out of their range."""
    laser = work / "laser.csv"
    laser.write_text(_laser_text())
    copy_ = work / "laser_copy.csv"
    copy_.write_text(_laser_text())
    link = work / "laser_link.csv"
    if not link.exists():
        link.symlink_to(laser)
    huge = work / "huge_laser.csv"
    with huge.open("wb") as fh:  # sparse: 60 MB on paper, nothing on the disk
        fh.truncate(60 * 1024 * 1024)
    folder = work / "a_folder"
    folder.mkdir(exist_ok=True)
    task = work / "task.json"
    task.write_text(json.dumps(_task_doc()))
    plan = work / "plan.json"
    plan.write_text(json.dumps(_plan_doc()))
    record = work / "record.json"
    record.write_text(json.dumps(_record_doc()))
    fit = ["fit", work / "meas.csv", "--setup", SIM / "setup.json", "--certificate",
           SIM / "certificate.csv", "--model", "translational"]
    diag = ["diagnose", *fit[1:6]]
    model = GOOD_MODEL
    return [
        ("--json onto the measurements", [*fit, "--json", work / "meas.csv"], "meas.csv"),
        ("--save onto an instrument", [*fit, "--laser", laser, "--save", laser],
         "laser.csv"),
        ("--json onto an instrument", [*fit, "--laser", laser, "--json", laser], "laser.csv"),
        ("--json a folder", [*fit, "--json", folder], "a_folder"),
        ("--json in a missing folder", [*fit, "--json", work / "nope" / "o.json"], "o.json"),
        ("--laser a folder", [*fit, "--laser", folder], "a_folder"),
        ("--laser missing", [*fit, "--laser", work / "missing.csv"], "missing.csv"),
        ("--laser /dev/zero", [*fit, "--laser", "/dev/zero"], "zero"),
        ("--laser 60 MB", [*fit, "--laser", huge], "huge_laser.csv"),
        ("--laser twice", [*fit, "--laser", laser, "--laser", laser], "laser.csv"),
        ("--laser and a copy", [*fit, "--laser", laser, "--laser", copy_], "laser_copy.csv"),
        ("--laser and a link to it", [*fit, "--laser", laser, "--laser", link],
         "laser_link.csv"),
        ("--step-gauge a laser file", [*fit, "--step-gauge", laser], "laser.csv"),
        ("--ball-bar a laser file", [*fit, "--ball-bar", laser], "laser.csv"),
        ("--laser the setup JSON", [*fit, "--laser", SIM / "setup.json"], "setup.json"),
        ("--setup a folder", ["fit", work / "meas.csv", "--setup", folder], "a_folder"),
        ("--setup /dev/zero", ["fit", work / "meas.csv", "--setup", "/dev/zero"], "zero"),
        ("--model ''", [*fit[:-2], "--model", ""], "--model"),
        ("--model ' , '", [*fit[:-2], "--model", " , "], "--model"),
        ("--baseline ''", [*diag, "--baseline", ""], "--baseline"),
        ("--order 0", [*fit, "--order", "0"], "--order"),
        ("--order 9", [*fit, "--order", "9"], "--order"),
        ("--sigma-um 0", [*fit, "--sigma-um", "0"], "--sigma-um"),
        ("--sigma-um nan", [*fit, "--sigma-um", "nan"], "--sigma-um"),
        ("--sigma-um 1e308", [*fit, "--sigma-um", "1e308"], "--sigma-um"),
        ("task --trials 0", ["task", model, task, "--trials", "0"], "--trials"),
        ("task --trials 3", ["task", model, task, "--trials", "3"], "--trials"),
        ("task --trials 1e9", ["task", model, task, "--trials", "1e9"], "--trials"),
        ("task --json onto the task", ["task", model, task, "--json", task], "task.json"),
        ("task --json onto the model", ["task", model, task, "--json", model],
         "good_model.json"),
        ("plan --workers 0", ["plan", plan, "--workers", "0"], "--workers"),
        ("plan --workers -1", ["plan", plan, "--workers", "-1"], "--workers"),
        ("plan --check-trials -1", ["plan", plan, "--check-trials", "-1"], "--check-trials"),
        ("plan --check-trials nan", ["plan", plan, "--check-trials", "nan"], "--check-trials"),
        ("plan --json onto the plan", ["plan", plan, "--no-detection", "--json", plan],
         "plan.json"),
        ("export --grid onto the model", ["export", model, "--grid", model],
         "good_model.json"),
        ("export --results-json a folder", ["export", model, "--results-json", folder],
         "a_folder"),
        ("export one file twice", ["export", model, "--grid", out / "a.csv",
                                   "--results-json", out / "a.csv"], "a.csv"),
        ("export --axis-tables a file", ["export", model, "--axis-tables", model],
         "good_model.json"),
        ("export --grid-step-mm 0", ["export", model, "--grid", out / "g.csv",
                                     "--grid-step-mm", "0"], "--grid-step-mm"),
        ("export --grid-step-mm nan", ["export", model, "--grid", out / "g.csv",
                                       "--grid-step-mm", "nan"], "--grid-step-mm"),
        ("export --grid-step-mm 1,2", ["export", model, "--grid", out / "g.csv",
                                       "--grid-step-mm", "1,2"], "--grid-step-mm"),
        ("export --coverage-factor 0", ["export", model, "--results-json", out / "r.json",
                                        "--coverage-factor", "0"], "--coverage-factor"),
        ("export --coverage-factor inf", ["export", model, "--results-json", out / "r.json",
                                          "--coverage-factor", "inf"], "--coverage-factor"),
        ("export nothing asked", ["export", model], "good_model.json"),
        ("export a missing model", ["export", work / "nomodel.json", "--grid",
                                    out / "g.csv"], "nomodel.json"),
        ("export the task as a model", ["export", task, "--grid", out / "g.csv"],
         "task.json"),
        ("report --out onto the record", ["report", record, "--out", record, "--any-path"],
         "record.json"),
        ("report --out onto its measurement file",
         ["report", record, "--out", Path(_record_doc()["data"]["measurements"][0]["path"]),
          "--any-path"], "BP111.csv"),
        ("report --out a folder", ["report", record, "--out", folder, "--any-path"],
         "a_folder"),
        ("report a record naming files outside its folder",
         ["report", record, "--out", out / "r.html"], "data.measurements[0]"),
        ("report a folder", ["report", folder, "--out", out / "r.html"], "a_folder"),
        ("report /dev/zero", ["report", "/dev/zero", "--out", out / "r.html"], "zero"),
        ("air --t-C nan", ["air", "--t-C", "nan", "--p-Pa", "101325", "--rh-percent", "50",
                           "--wavelength-nm", "633"], "--t-C"),
        ("gp --order 0", ["gp", *fit[1:6], "--order", "0"], "--order"),
        ("--json '' after the command", [*fit, "--json", ""], "--json"),
    ]


def test_path_tricks_and_option_values_are_refused_in_one_line(work, tmp_path):
    """Outputs onto inputs, folders, devices, missing and oversized files, files given
    twice, option values out of range: one line naming the file or option, exit 2, no
    input changed, nothing non-finite written."""
    failures = []
    cases = _path_cases(work, tmp_path)
    for desc, argv, name in cases:
        verdict = _judge(argv, name, tmp_path)
        if verdict:
            failures.append(f"[{desc}]: {verdict}")
    assert len(cases) >= 50
    assert failures == []


# ---------------------------------------------------------------------------------------
# Project files (the app's Save/Load; read by the core's export.project_from_json)
# ---------------------------------------------------------------------------------------

def _project_doc():
    from cmm_core.export import project_to_json

    meas = (SIM / "measurements.csv").read_text().splitlines()
    text = project_to_json(
        dataset_name="sim", measurements=[("meas.csv", "\n".join(meas[:151]) + "\n")],
        setup=(SIM / "setup.json").read_text(),
        certificate=("certificate.csv", (SIM / "certificate.csv").read_text()),
        model={"spec": "kinematic21", "order": 2, "plate": "auto", "sigma_um": 0.5,
               "positions": None, "probes": None},
        exclusions=[("BP111", "1", 3)], history=[{"spec": "kinematic21",
                                                  "change": "baseline"}])
    return json.loads(text)


def _project_cases():
    doc = _project_doc()
    rng = random.Random(CORPUS_SEED)
    # free text (names, the session's notes) and the record of the history are not read
    return _json_cases("project", doc, rng, 60, skip=("name", "created", "cmm_core",
                                                      "change", "history", "extra"))


def test_project_file_corpus_raises_only_data_errors_naming_the_file():
    """Every mutant either loads or raises DataError naming the file, one line."""
    doc_ok = project_from_json(json.dumps(_project_doc()), name="p.json")
    assert doc_ok["measurements"]
    failures = []
    cases = _project_cases()
    for _, desc, data in cases:
        try:
            project_from_json(data, name="p.json")
        except DataError as exc:
            if "p.json" not in str(exc) or "\n" in str(exc):
                failures.append(f"[{desc}]: {str(exc)[:120]}")
        except Exception as exc:  # noqa: BLE001 - what the app would show raw
            failures.append(f"[{desc}]: {type(exc).__name__} {str(exc)[:80]}")
    assert len(cases) >= 40
    assert failures == []


def test_record_exclusions_of_the_wrong_type_are_refused_naming_the_file(work, tmp_path):
    doc = _record_doc()
    doc["exclusions"][0][1] = {}
    path = work / "excl_record.json"
    path.write_text(json.dumps(doc))
    assert _judge(_argv("record", path, work, tmp_path), "excl_record.json", tmp_path) == ""


# ---------------------------------------------------------------------------------------
# Property test of the instrument readers (hypothesis)
# ---------------------------------------------------------------------------------------

_cell = st.one_of(st.text(max_size=10), st.floats(allow_nan=True, allow_infinity=True).map(str),
                  st.integers(-10**9, 10**9).map(str), st.sampled_from(_BAD_CELLS))
_KIND_TEXT = {"laser": _laser_text, "step_gauge": _step_gauge_text, "ball_bar": _ball_bar_text}


@settings(max_examples=80, deadline=None)
@given(kind=st.sampled_from(sorted(_KIND_TEXT)),
       cells=st.lists(st.tuples(st.integers(0, 10), st.integers(0, 12), _cell), max_size=4))
def test_instrument_readers_refuse_in_one_line_or_read_every_row_finite(kind, cells):
    """Any cells of a good instrument file replaced by anything: the reader raises a
    DataError naming the file in one line, or returns every row with finite numbers and
    every u in the documented range."""
    lines = _KIND_TEXT[kind]().splitlines()
    rows = [ln.split(",") for ln in lines]
    for i, j, v in cells:
        r = rows[1 + i % (len(rows) - 1)]
        r[j % len(r)] = v.replace(",", "").replace("\n", "").replace("\r", "").replace('"', "")
    text = "\n".join(",".join(r) for r in rows) + "\n"
    try:
        item = read_instrument(io.BytesIO(text.encode()), kind, name="inst.csv")
    except DataError as exc:
        assert "inst.csv" in str(exc) and "\n" not in str(exc)
        return
    assert len(item.u_um) == len(rows) - 1
    assert np.all((item.u_um >= 1e-3) & (item.u_um <= 100))
    for arr in (item.u_um, *(getattr(item, a) for a in ("r_mm", "r1_mm", "r2_mm", "p_mm",
                                                          "error_um", "certified_mm")
                             if hasattr(item, a))):
        assert np.isfinite(arr).all()


@pytest.mark.slow  # the model reader's own corpus is in test_hardening
def test_model_file_corpus_through_export_is_refused_in_one_line(work, tmp_path):
    """Model files with one leaf broken, fed to ``export``: the same four rules (the
    model reader's range checks live in ``export/model_file.py``)."""
    doc = json.loads(GOOD_MODEL.read_text())
    cases = _json_cases("model", doc, random.Random(CORPUS_SEED), 60, skip=("summary",))
    failures = []
    for k, (_, desc, data) in enumerate(cases):
        path = work / f"model{k:03d}.json"
        path.write_bytes(data)
        out = tmp_path / f"m{k:03d}"
        out.mkdir()
        verdict = _judge(["export", path, "--grid", out / "g.csv", "--results-json",
                          out / "r.json"], path.name, out)
        if verdict:
            failures.append(f"[{desc}]: {verdict}")
    assert len(cases) >= 60
    assert failures == []


def test_a_model_covariance_of_1e308_is_refused_naming_the_file(work, tmp_path):
    doc = json.loads(GOOD_MODEL.read_text())
    doc["cov"][13][13] = 1e308
    path = work / "model_cov_1e308.json"
    path.write_text(json.dumps(doc))
    assert _judge(["export", path, "--grid", tmp_path / "g.csv"], path.name, tmp_path) == ""

"""Bad input never passes silently (issue 13).

Three layers:

- the committed corpus ``tests/corpus/`` (one file per defect the issue lists, described
  in ``manifest.json``): each goes through the command line and must end in exit status
  2 with one stderr line naming the file and the problem;
- a deterministic mutation fuzzer: every valid sample input (measurements, setup,
  certificate, simulation config, model, points, budget) broken in ways that are bad by
  construction (a cell of junk, a unit slip, a missing key, a wrong type, a truncation)
  and fed to the command line: no traceback (exit 3 or an escaping exception), no
  silent acceptance (exit 0), every refusal one line naming the file;
- hypothesis property tests of the readers, the simulator config and the model file:
  nothing but :class:`DataError` is raised, accepted data hold no NaN, and no data row
  is dropped without a word.
"""

import contextlib
import copy
import io
import json
import random

import numpy as np
import pytest
from conftest import ROOT, THESIS
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cmm_core.cli import MAX_MESSAGE, main
from cmm_core.export import model_from_dict
from cmm_core.io import DataError, read_certificate, read_measurements, read_setup
from cmm_core.model import simulate

CORPUS = ROOT / "tests" / "corpus"
SIM = ROOT / "sample_data" / "simulated"
MANIFEST = json.loads((CORPUS / "manifest.json").read_text())
GOOD_MODEL = CORPUS / "good_model.json"
GOOD_POINTS = "probe,x_mm,y_mm,z_mm\n1,500,400,100\n2,650,420,300\n"
FUZZ_SEED = 13


def _argv(kind, path, tmp):
    """The command that feeds a file of ``kind`` to the program (the rest valid)."""
    th = sorted(THESIS.glob("BP*.csv"))
    return {
        "meas": ["fit", path, "--setup", SIM / "setup.json", "--certificate",
                 SIM / "certificate.csv"],
        "setup": ["fit", SIM / "measurements.csv", "--setup", path, "--certificate",
                  SIM / "certificate.csv"],
        "setup_thesis": ["fit", *th, "--setup", path, "--certificate",
                         THESIS / "certificate.csv"],
        "cert": ["fit", SIM / "measurements.csv", "--setup", SIM / "setup.json",
                 "--certificate", path],
        "sim": ["simulate", path, "--out", tmp / "sim"],
        "model": ["compensate", path, tmp / "good_points.csv", "--out", tmp / "c.csv"],
        "points": ["compensate", GOOD_MODEL, path, "--out", tmp / "c.csv"],
        "budget": ["budget", path],
    }[kind]


def _run(argv):
    """The CLI in this process: (exit status, stderr lines, stdout). An exception that
    escapes ``main`` is a traceback the user would see."""
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        rc = main([str(a) for a in argv])
    return rc, err.getvalue().strip().splitlines(), out.getvalue()


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    d = tmp_path_factory.mktemp("hardening")
    (d / "good_points.csv").write_text(GOOD_POINTS)
    return d


def _assert_refused(rc, lines, name, needle=""):
    assert rc == 2, (name, rc, lines)
    assert len(lines) == 1, lines
    line = lines[0]
    assert len(line) <= MAX_MESSAGE + len("error: "), len(line)
    assert name in line, line
    assert needle in line, line


@pytest.mark.parametrize("entry", MANIFEST, ids=[e["file"] for e in MANIFEST])
def test_corpus_file_is_refused_in_one_line_naming_it(entry, tmp):
    """Each file of the corpus reproduces one defect of issue 13 (``issue`` field)."""
    path = CORPUS / entry["file"]
    rc, lines, _ = _run(_argv(entry["kind"], path, tmp))
    _assert_refused(rc, lines, entry["file"], entry["needle"])


def test_the_good_inputs_behind_the_fuzzer_are_accepted(tmp):
    """The fuzzer's starting points pass: a refusal of a mutant is due to the mutation."""
    for kind, path in (("points", tmp / "good_points.csv"), ("model", GOOD_MODEL),
                       ("budget", ROOT / "sample_data" / "budget" / "ballplate_budget.json")):
        rc, lines, _ = _run(_argv(kind, path, tmp))
        assert rc == 0, lines
    rc, lines, _ = _run(["fit", SIM / "measurements.csv", "--setup", SIM / "setup.json",
                         "--certificate", SIM / "certificate.csv", "--model", "translational"])
    assert rc == 0, lines


# ---------------------------------------------------------------------------------------
# Mutation fuzzer: inputs that are bad by construction
# ---------------------------------------------------------------------------------------

_JUNK_CELLS = ["abc", "", "nan", "inf", "-inf", "1e999", "0x1F", "12 mm", "1.2.3", "--5",
               "NaN", "∞", "1,5", "\x00", "é", "9" * 200_000, "'", '"', "None", "true"]


def _csv_mutants(text, rng, name, numeric_cols):
    """(description, bytes) of a CSV broken in ways no reader may accept."""
    lines = text.splitlines()
    head = lines[0].split(",")
    cols = [head.index(c) for c in numeric_cols if c in head]
    out = []
    for junk in _JUNK_CELLS:
        i = rng.randrange(1, len(lines))
        f = lines[i].split(",")
        f[rng.choice(cols)] = junk if "," not in junk else f'"{junk}"'
        out.append((f"cell {junk[:10]!r}", "\n".join(lines[:i] + [",".join(f)] + lines[i + 1:])))
    for c in [c for c in numeric_cols if c in ("x_mm", "y_mm", "z_mm")]:
        k = head.index(c)
        out.append((f"drop column {c}", "\n".join(",".join(x for j, x in enumerate(
            ln.split(",")) if j != k) for ln in lines)))
    for _ in range(4):
        i = rng.randrange(1, len(lines))
        out.append(("extra field with data", "\n".join(
            lines[:i] + [lines[i] + rng.choice([",5", ",\r7", ",x", ';"q"'])] + lines[i + 1:])))
    out.append(("binary", bytes(rng.randrange(128, 256) for _ in range(300))))
    out.append(("header only", lines[0] + "\n"))
    out.append(("empty", ""))
    out.append(("NUL", text[:200] + "\x00" + text[200:]))
    out.append(("duplicate header", lines[0] + "," + head[-1] + "\n" + "\n".join(
        ln + ",0" for ln in lines[1:])))
    out.append(("unclosed quote", lines[0] + '\n"' + "\n".join(lines[1:])))
    ball = head.index("ball") if "ball" in head else None
    for bad in ("0", "-3", "1.5", "x") if ball is not None else ():
        i = rng.randrange(1, len(lines))
        f = lines[i].split(",")
        f[ball] = bad
        out.append((f"ball {bad}", "\n".join(lines[:i] + [",".join(f)] + lines[i + 1:])))
    for factor, unit in ((1 / 25.4, "inches"), (1e-3, "metres"), (1e3, "µm"))[
            (name == "points"):]:  # points in inches lie in the machine: undetectable
        rows = [lines[0]]
        for ln in lines[1:]:
            f = ln.split(",")
            for k in (head.index(c) for c in ("x_mm", "y_mm", "z_mm")):
                f[k] = f"{float(f[k]) * factor:.9g}"
            rows.append(",".join(f))
        out.append((unit, "\n".join(rows)))
    return [(f"{name} [{d}]", t if isinstance(t, bytes) else t.encode()) for d, t in out]


def _bad_values(old):
    """Values of another JSON type than ``old`` (or NaN): wrong whatever the field means.
    No null for numbers (several numeric fields take null for "none", e.g. dof)."""
    if isinstance(old, bool):
        return ["yes", 1, [], None]
    if isinstance(old, int | float):
        return ["abc", "1", [], {}, float("nan"), True]
    if isinstance(old, str):
        return [None, 12, [], {}, True]
    if isinstance(old, list):
        return ["abc", None, {}, 5]
    if old is None:
        return ["abc", [], {}]
    return ["abc", None, [], 5]


def _json_mutants(doc, rng, name, n, skip=(), free=()):
    """``n`` copies of a JSON document with one leaf or object replaced by a value of
    another type, or a key misspelt, plus truncated and binary versions. ``skip``: keys
    of free text (never checked); ``free``: objects whose keys are names the user
    chooses (a renamed probe is another probe, not a misspelling)."""
    paths = []

    def walk(obj, path):
        if isinstance(obj, dict):
            for k, v in obj.items():
                paths.append(path + (k,))
                walk(v, path + (k,))
        elif isinstance(obj, list) and obj and not isinstance(obj[0], list | float | int):
            for i, v in enumerate(obj):
                walk(v, path + (i,))
    walk(doc, ())
    paths = [p for p in paths if not any(s in map(str, p) for s in skip)]
    out = []
    while len(out) < n:
        p = rng.choice(paths)
        bad = copy.deepcopy(doc)
        parent = bad
        for k in p[:-1]:
            parent = parent[k]
        if rng.random() < 0.2 and isinstance(p[-1], str) and str(p[-2:-1]) not in map(
                str, [(k,) for k in free]):
            parent[p[-1] + "x"] = parent.pop(p[-1])  # misspelt: "rangex" for "range"
            desc = f"key {p[-1]}x"
        else:
            val = rng.choice(_bad_values(parent[p[-1]]))
            parent[p[-1]] = val
            desc = f"{'.'.join(map(str, p))} = {val!r}"
        out.append((f"{name} [{desc}]", json.dumps(bad).encode()))
    text = json.dumps(doc).encode()
    out += [(f"{name} [truncated]", text[:len(text) // 2]),
            (f"{name} [binary]", bytes(rng.randrange(128, 256) for _ in range(200))),
            (f"{name} [not an object]", b"[1, 2, 3]"), (f"{name} [empty]", b"")]
    return out


def _fuzz_inputs():
    """Every mutant with the command kind that reads it: (kind, description, bytes)."""
    rng = random.Random(FUZZ_SEED)
    meas = "\n".join((SIM / "measurements.csv").read_text().splitlines()[:151])
    cert = (SIM / "certificate.csv").read_text()
    setup = json.loads((SIM / "setup.json").read_text())
    model = json.loads(GOOD_MODEL.read_text())
    budget = json.loads((ROOT / "sample_data" / "budget" / "ballplate_budget.json").read_text())
    sim = {"seed": 3, "plate": {"rows": 3, "cols": 3, "pitch_mm": 200.0, "form_um": 1.0},
           "kinematic": {"spec": "translational", "order": 2, "coefficients": {"dxx[1]": 1.0}},
           "effects": {"plate_sag": {"uu": 1.0}, "drift": {"sd_um_per_h": 1.0}},
           "order": "serpentine", "minutes_per_ball": 0.5, "repeats": 1, "noise_um": 0.5}
    out = []
    out += [("meas", d, b) for d, b in _csv_mutants(meas, rng, "measurements",
                                                    ["x_mm", "y_mm", "z_mm", "time_min",
                                                     "temp_C"])]
    out += [("cert", d, b) for d, b in _csv_mutants(cert, rng, "certificate",
                                                    ["x_mm", "y_mm", "z_mm"])]
    out += [("points", d, b) for d, b in _csv_mutants(
        GOOD_POINTS + "".join(f"1,{300 + 7 * i},{250 + 5 * i},{50 + 3 * i}\n"
                              for i in range(40)), rng, "points", ["x_mm", "y_mm", "z_mm"])]
    # setup: the position fields, machine and probes; free notes excepted (they are free)
    out += [("setup", d, b) for d, b in _json_mutants(setup, rng, "setup", 120,
                                                      skip=("probe",),
                                                      free=("positions", "probes"))]
    out += [("sim", d, b) for d, b in _json_mutants(sim, rng, "sim", 120,
                                                    free=("coefficients",))]
    out += [("model", d, b) for d, b in _json_mutants(model, rng, "model", 90,
                                                      skip=("summary",), free=("probes_mm",))]
    # the budget reader takes numbers written as strings ("1"): not mutated into
    out += [("budget", d, b) for d, b in _json_mutants(budget, rng, "budget", 60,
                                                       skip=("name", "unit", "description"))
            if "= '1'" not in d]
    return out


@pytest.mark.slow
def test_fuzzed_inputs_are_refused_in_one_line_naming_the_file(tmp):
    """Over 500 bad inputs across every entry point: 0 tracebacks, 0 silent acceptances,
    every refusal one line naming the file."""
    cases = _fuzz_inputs()
    tracebacks, accepted, badline = [], [], []
    for k, (kind, desc, data) in enumerate(cases):
        name = f"fuzz{k:03d}.{'json' if kind in ('setup', 'sim', 'model', 'budget') else 'csv'}"
        path = tmp / name
        path.write_bytes(data)
        try:
            rc, lines, _ = _run(_argv(kind, path, tmp))
        except BaseException as exc:  # noqa: B036 - anything escaping main is a traceback
            tracebacks.append((desc, repr(exc)[:200]))
            continue
        if rc == 3:
            tracebacks.append((desc, lines))
        elif rc == 0:
            accepted.append(desc)
        elif len(lines) != 1 or name not in lines[0] or len(lines[0]) > MAX_MESSAGE + 7:
            badline.append((desc, lines))
    print(f"fuzzed {len(cases)} inputs: {len(tracebacks)} tracebacks, {len(accepted)} "
          f"accepted, {len(badline)} bad lines")
    assert len(cases) >= 500
    assert tracebacks == []
    assert accepted == []
    assert badline == []


# ---------------------------------------------------------------------------------------
# Property tests (hypothesis)
# ---------------------------------------------------------------------------------------

_FAST = settings(max_examples=60, deadline=None,
                 suppress_health_check=[HealthCheck.function_scoped_fixture])
_PLATE = [(1, 0, 0, 0), (2, 133, 0, 0), (3, 266, 0, 0), (4, 0, 133, 0), (5, 133, 133, 0)]
_cell = st.one_of(st.text(max_size=12), st.floats(allow_nan=True, allow_infinity=True).map(str),
                  st.integers(-10**6, 10**6).map(str), st.sampled_from(_JUNK_CELLS[:-6]))


def _data_lines(text):
    """Data rows a reader must account for: non-blank lines after the header."""
    lines = [ln for ln in text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
             if ln.strip(" \t,;")]
    return len(lines) - 1


@_FAST
@given(cells=st.lists(st.tuples(st.integers(0, 4), st.integers(0, 3), _cell), max_size=4),
       sep=st.sampled_from([",", ";", "\t"]), bom=st.booleans(),
       eol=st.sampled_from(["\n", "\r\n"]))
def test_measurement_reader_refuses_or_keeps_every_row_finite(cells, sep, bom, eol):
    """Any cell of a small thesis-form table replaced by anything: the reader raises
    DataError or returns every data row, with finite coordinates and the cells' values."""
    rows = [list(map(str, r)) for r in _PLATE]
    for i, j, v in cells:
        rows[i][j] = v.replace(sep, "").replace("\n", "").replace("\r", "").replace('"', "")
    text = eol.join([sep.join(["ball", "x_mm", "y_mm", "z_mm"])] +
                    [sep.join(r) for r in rows]) + eol
    data = ("\ufeff" if bom else "") + text
    try:
        df = read_measurements(io.BytesIO(data.encode()), name="BP1.csv")
    except DataError as exc:
        assert "BP1.csv" in str(exc) and "\n" not in str(exc)
        return
    assert len(df) == _data_lines(text)  # no row dropped without a word
    xyz = df[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    assert np.isfinite(xyz).all()


@_FAST
@given(blob=st.binary(max_size=400))
def test_readers_raise_only_data_errors_on_arbitrary_bytes(blob):
    for reader in (read_measurements, read_certificate, read_setup):
        try:
            out = reader(io.BytesIO(blob), name="x.bin")
        except DataError as exc:
            assert "x.bin" in str(exc) or "setup" in str(exc)
            continue
        if reader is read_measurements:
            assert np.isfinite(out[["x_mm", "y_mm", "z_mm"]].to_numpy(float)).all()


_json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-10**4, 10**4),
                       st.floats(allow_nan=True), st.text(max_size=8))
_json = st.recursive(_json_leaf, lambda c: st.one_of(
    st.lists(c, max_size=3), st.dictionaries(st.text(max_size=8), c, max_size=3)),
    max_leaves=8)
_SIM_KEYS = ["seed", "plate", "kinematic", "effects", "noise_um", "order", "repeats",
             "minutes_per_ball", "probes_interleaved", "probes_per_position"]
_SMALL = {"plate": {"rows": 2, "cols": 3, "pitch_mm": 200.0},
          "kinematic": {"spec": "translational"}}


@settings(max_examples=40, deadline=None)
@given(key=st.sampled_from(_SIM_KEYS), value=_json)
def test_simulator_config_refuses_or_simulates_finite_data(key, value):
    cfg = copy.deepcopy(_SMALL)
    cfg[key] = value
    try:
        sim = simulate(cfg, name="c.json")
    except DataError as exc:
        assert "c.json" in str(exc)
        return
    xyz = sim.dataset.meas[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    assert np.isfinite(xyz).all() and len(xyz) > 0


_MODEL = json.loads(GOOD_MODEL.read_text())


@settings(max_examples=60, deadline=None)
@given(key=st.sampled_from(sorted(_MODEL)), value=_json, index=st.integers(0, 40))
def test_model_file_refuses_or_holds_finite_numbers(key, value, index):
    d = copy.deepcopy(_MODEL)
    if isinstance(d[key], list) and d[key] and not isinstance(value, list):
        d[key][index % len(d[key])] = value  # one entry of a vector or row
    else:
        d[key] = value
    try:
        m = model_from_dict(d, name="m.json")
    except DataError as exc:
        assert "m.json" in str(exc)
        return
    assert np.isfinite(m.coef).all() and np.isfinite(m.cov).all()
    assert all(np.isfinite(p).all() for p in m.probes_mm.values())

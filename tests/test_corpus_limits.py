"""The ranges issue 25 asks for, at their boundaries: each limit accepts its edge and
refuses just beyond it, so a limit moved by mistake fails here (the corpus in
``test_corpus_entry.py`` only shows that far-out values are refused).

Limits and their sources: instrument ``u_um`` 0.001-100 µm and at most 20 000 rows
(``docs/instruments.md#limits``), offsets 0 or 1-2000 mm as for the setup's probes,
points within 2 mm in every axis are metres as for the measurement files; budget trials
``max(1e4, 100 / (1 - p))`` (JCGM 101 7.2.2), plan priors from 0.01 µm; setup keys at
the wrong level (``docs/formats.md#setup``).
"""

import contextlib
import copy
import io
import json
import os

import numpy as np
import pytest
from conftest import ROOT
from hypothesis import given, settings
from hypothesis import strategies as st

from cmm_core.cli import main
from cmm_core.gum import budget_from_dict
from cmm_core.io import SETUP_KEYS, DataError, read_setup
from cmm_core.model import read_instrument, read_laser, read_step_gauge
from cmm_core.plan import read_plan, read_task

INS = ROOT / "sample_data" / "instruments"
SIM = ROOT / "sample_data" / "simulated"
LASER = (INS / "laser_x.csv").read_text()
STEP_GAUGE_PATH = INS / "step_gauge.csv"
STEP_GAUGE = STEP_GAUGE_PATH.read_text()
SETUP = json.loads((SIM / "setup.json").read_text())
BUDGET = json.loads((ROOT / "sample_data" / "budget" / "ballplate_budget.json").read_text())


def _column(text, col, value):
    """``text`` with every cell of ``col`` set to ``value``."""
    lines = text.splitlines()
    k = lines[0].split(",").index(col)
    out = [lines[0]]
    for ln in lines[1:]:
        f = ln.split(",")
        f[k] = value
        out.append(",".join(f))
    return ("\n".join(out) + "\n").encode()


@pytest.mark.parametrize("u, ok", [("0.001", True), ("0.0009", False), ("100", True),
                                   ("100.1", False), ("1e-12", False), ("0", False)])
def test_instrument_u_range_edges(u, ok):
    for text, kind in ((LASER, "laser"), (STEP_GAUGE, "step_gauge")):
        data = io.BytesIO(_column(text, "u_um", u))
        if ok:
            assert np.all(read_instrument(data, kind, name="f.csv").u_um == float(u))
        else:
            with pytest.raises(DataError, match=r"f\.csv, row 2, column 'u_um'.*0\.001 to 100"):
                read_instrument(data, kind, name="f.csv")


def test_a_laser_run_in_metres_is_refused_and_the_same_run_in_mm_read():
    """The sample's runs span 1200 mm along x; in metres (1.2) every axis spans < 2."""
    run = read_laser(io.BytesIO(LASER.encode()), name="l.csv")
    assert np.ptp(run.r_mm[:, 0]) == pytest.approx(1200)
    lines = LASER.splitlines()
    metres = [lines[0]] + [",".join(f[:3] + [f"{float(v) / 1000:.9g}" for v in f[3:6]] + f[6:])
                           for f in (ln.split(",") for ln in lines[1:])]
    with pytest.raises(DataError, match="look like metres"):
        read_laser(io.BytesIO("\n".join(metres).encode()), name="l.csv")


@pytest.mark.parametrize("z, ok", [("-150", True), ("0", True), ("-1", True),
                                   ("-0.999", False), ("-0.15", False), ("-2000", True),
                                   ("-2000.1", False)])
def test_step_gauge_stylus_offset_edges(z, ok):
    """Offsets are 0 or 1 to 2000 mm long (the setup's probe rule): 0.15 is 150 mm in m."""
    data = io.BytesIO(_column(STEP_GAUGE, "offset_z_mm", z))
    if ok:
        assert np.all(read_step_gauge(data, name="s.csv").p_mm[:, 2] == float(z))
    else:
        with pytest.raises(DataError, match="offset_x_mm.*0, or 1 to 2000"):
            read_step_gauge(data, name="s.csv")


def _laser_rows(n):
    """A positioning run of ``n`` readings along x, 0.05 mm apart."""
    return ("axis,x_mm,y_mm,z_mm,error_um,u_um\n" + "".join(
        f"x,{0.05 * i:.2f},100,50,0.1,0.2\n" for i in range(n))).encode()


def test_instrument_row_limit_edges():
    assert len(read_laser(io.BytesIO(_laser_rows(20_000)), name="l.csv").u_um) == 20_000
    with pytest.raises(DataError, match=r"l\.csv: has more than 20000 data rows"):
        read_laser(io.BytesIO(_laser_rows(20_001)), name="l.csv")


def test_a_device_or_a_pipe_is_refused_before_it_is_read(tmp_path):
    """/dev/zero would read until the size limit, a FIFO would block until written."""
    with pytest.raises(DataError, match="zero: is not a regular file"):
        read_laser("/dev/zero")
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp_path / "pipe.csv")
        with pytest.raises(DataError, match="pipe.csv: is not a regular file"):
            read_laser(tmp_path / "pipe.csv")


def _cli(argv):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main([str(a) for a in argv])
    return rc, err.getvalue().strip().splitlines()


def test_an_instrument_file_given_twice_or_copied_is_refused_naming_both(tmp_path):
    copy_ = tmp_path / "copy.csv"
    copy_.write_text(LASER)
    fit = ["fit", SIM / "measurements.csv", "--setup", SIM / "setup.json", "--certificate",
           SIM / "certificate.csv", "--model", "translational"]
    rc, lines = _cli([*fit, "--laser", INS / "laser_x.csv", "--laser", INS / "laser_x.csv"])
    assert rc == 2 and len(lines) == 1 and "laser_x.csv: is given twice" in lines[0]
    rc, lines = _cli([*fit, "--laser", INS / "laser_x.csv", "--step-gauge", STEP_GAUGE_PATH,
                      "--laser", copy_])
    assert rc == 2 and len(lines) == 1
    assert "copy.csv: holds the same readings as" in lines[0] and "laser_x.csv" in lines[0]


def test_the_fit_itself_refuses_the_same_readings_twice(tmp_path):
    """The check lives in the model, so the app, the analysis record and code calling
    ``fit`` get it too; the same positions with other readings (a repeat run) pass."""
    from cmm_core.io import load_dataset
    from cmm_core.model import fit, read_instrument

    ds = load_dataset([SIM / "measurements.csv"], SIM / "setup.json", SIM / "certificate.csv")
    a = read_instrument(INS / "laser_x.csv", "laser")
    b = read_instrument(io.StringIO(LASER), "laser", name="renamed.csv")
    with pytest.raises(DataError, match=r"renamed.csv.*holds the same readings as laser_x.csv"):
        fit(ds, "translational", instruments=[a, b])
    lines = LASER.splitlines()
    head, rows = lines[0], lines[1:]
    col = head.split(",").index("error_um")
    bumped = [",".join(f"{float(v) + 0.01:.4f}" if i == col else v
                       for i, v in enumerate(r.split(","))) for r in rows]
    c = read_instrument(io.StringIO("\n".join([head, *bumped])), "laser", name="repeat.csv")
    assert fit(ds, "translational", instruments=[a, c]).status == "converged"



@pytest.mark.parametrize("edit, where, home", [
    (lambda d: d.update(layout="gantry_fxyz"), "'layout'", "'machine.layout'"),
    (lambda d: d.update(layot="gantry_fxyz"), "'layot'", "'machine.layout'"),
    (lambda d: d.update(range_mm=[1200, 1000, 700]), "'range_mm'", "'machine.range_mm'"),
    (lambda d: d["machine"].update(cte_per_K=1e-6), "'machine.cte_per_K'",
     "'plate.cte_per_K'"),
    (lambda d: d["positions"]["BP111"].update(layout="gantry_fxyz"),
     "'positions.BP111.layout'", "'machine.layout'"),
    (lambda d: d["machine"].update(units="mm"), "'machine.units'", "the top-level 'units'"),
])
def test_a_setup_key_at_the_wrong_level_gets_did_you_mean_its_home(edit, where, home):
    d = copy.deepcopy(SETUP)
    edit(d)
    with pytest.raises(DataError, match=f"s.json, column {where}.*did you mean {home}"):
        read_setup(d, name="s.json")


def test_notes_stay_free_at_every_level():
    d = copy.deepcopy(SETUP)
    d.update(note="room 2", source="calibration 2026", operator="A. B.")
    d["machine"]["name"] = "CMM 3"
    assert read_setup(d, name="s.json").name == "s.json"


def test_budget_trials_and_zero_uncertainty_edges():
    """At p = 0.95 the floor is 10⁴ (100 / 0.05 = 2000 is below it); at p = 0.999 it is
    100 / 0.001 = 10⁵."""
    assert budget_from_dict({**BUDGET, "monte_carlo_trials": 10_000})["mc"]["trials"] == 10_000
    with pytest.raises(ValueError, match="at least 10000"):
        budget_from_dict({**BUDGET, "monte_carlo_trials": 9_999})
    with pytest.raises(ValueError, match="at least 100000"):
        budget_from_dict({**BUDGET, "coverage_probability": 0.999,
                          "monte_carlo_trials": 99_999})
    zero = copy.deepcopy(BUDGET)
    for c in zero["contributions"]:
        c.update({k: 0 for k in ("u", "half_width") if k in c})
    with pytest.raises(ValueError, match="U = 0"):
        budget_from_dict(zero)
    big = copy.deepcopy(BUDGET)
    big["contributions"][0]["c"] = 1e150  # was an OverflowError in Welch-Satterthwaite
    with pytest.raises(ValueError, match=r"contributions\[0\]: c·u"):
        budget_from_dict(big)


@pytest.mark.parametrize("prior, ok", [(0.01, True), (0.0099, False), (0, False)])
def test_plan_prior_edges(tmp_path, prior, ok):
    plan = json.loads((ROOT / "sample_data" / "plans" / "thesis_plan.json").read_text())
    plan["setup"] = str(ROOT / "sample_data" / "thesis" / "setup.json")
    plan["model"]["prior_um"] = prior
    path = tmp_path / "p.json"
    path.write_text(json.dumps(plan))
    if ok:
        assert read_plan(path).strategies
    else:
        with pytest.raises(DataError, match="model.prior_um.*from 0.01"):
            read_plan(path)


def test_a_task_with_every_influence_zero_is_refused(tmp_path):
    task = json.loads((ROOT / "sample_data" / "plans" / "task_distance.json").read_text())
    task.update(include_model=False, probing_sigma_um=0.0)
    task["temperature"].update(u_temp_C=0.0, u_cte_per_K=0.0)
    path = tmp_path / "t.json"
    path.write_text(json.dumps(task))
    with pytest.raises(DataError, match="t.json, column 'include_model'.*U = 0"):
        read_task(path)
    task["probing_sigma_um"] = 0.2
    path.write_text(json.dumps(task))
    assert read_task(path).sigma_um == 0.2


# ---------------------------------------------------------------------------------------
# Property test: any value at any key of a setup (hypothesis)
# ---------------------------------------------------------------------------------------

_leaf = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                  st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8))
_value = st.recursive(_leaf, lambda c: st.one_of(st.lists(c, max_size=4),
                                                 st.dictionaries(st.text(max_size=8), c,
                                                                 max_size=3)), max_leaves=8)
_KEYS = [(), ("machine",), ("plate",), ("positions", "BP111"), ("probes",), ("certificate",)]
_NAMES = sorted({k for keys in SETUP_KEYS.values() for k in keys} | {"note", "x"})


@settings(max_examples=150, deadline=None)
@given(where=st.sampled_from(_KEYS), key=st.sampled_from(_NAMES), value=_value)
def test_any_value_anywhere_in_a_setup_is_refused_naming_it_or_read_finite(where, key, value):
    """A key of the format (or a note) set to any JSON value at any level: a DataError
    naming the file in one line, or a setup whose numbers are finite and in mm."""
    d = copy.deepcopy(SETUP)
    d.setdefault("certificate", {"U_um": [0.26, 0.0019], "k": 2})
    parent = d
    for k in where:
        parent = parent.setdefault(k, {})
    parent[key] = value
    try:
        s = read_setup(d, name="s.json")
    except DataError as exc:
        assert str(exc).startswith("s.json") and "\n" not in str(exc)
        return
    assert np.isfinite(s.range_mm).all() and (s.range_mm >= 10).all()
    for pl in s.positions.values():
        assert np.isfinite(pl.origin_mm).all() and np.isfinite(pl.rotation).all()
    for p in s.probes.values():
        assert np.isfinite(p).all()
    assert np.isfinite(s.cte_per_K)


def test_files_of_one_run_are_written_all_or_none(tmp_path):
    """A failure at the second of two outputs (its folder has gone) leaves the first as
    it was, no mix of new and old files, and no temporary file behind; without a
    failure both are replaced."""
    from cmm_core.io import atomic_write_all

    a, b = tmp_path / "grid.csv", tmp_path / "tables" / "results.json"
    a.write_text("old grid")
    with pytest.raises(DataError, match="folder"):
        atomic_write_all({a: "new grid", b: b"new results"})
    assert a.read_text() == "old grid"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grid.csv"]
    b.parent.mkdir()
    atomic_write_all({a: "new grid", b: b"new results"})
    assert a.read_text() == "new grid" and b.read_bytes() == b"new results"


def test_a_write_failing_on_disk_leaves_every_old_file(tmp_path, monkeypatch):
    """The failure that small files meet: the data reach the disk only at the flush, and
    the fsync of the first file fails (a full disk). Nothing is renamed: both old files
    stay, and no temporary file is left."""
    import os

    from cmm_core.io import atomic_write_all

    a, b = tmp_path / "grid.csv", tmp_path / "results.json"
    a.write_text("old grid")
    b.write_text("old results")
    real_fsync, calls = os.fsync, []

    def fsync(fd):
        calls.append(fd)
        if len(calls) == 1:
            raise OSError(28, "No space left on device")
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(OSError, match="No space left") as exc:
        atomic_write_all({a: "new grid", b: "new results"})
    assert exc.value.filename == str(a)  # the output, not its temporary file
    monkeypatch.undo()
    assert a.read_text() == "old grid" and b.read_text() == "old results"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grid.csv", "results.json"]


def test_running_the_design_of_a_plan_without_one_is_one_line():
    from cmm_core.plan import design_from_file, read_plan

    pf = read_plan(ROOT / "sample_data" / "plans" / "thesis_plan.json")
    assert pf.design is None
    with pytest.raises(DataError, match=r"thesis_plan.json.*no 'design' section") as exc:
        design_from_file(pf)
    assert "\n" not in str(exc.value)

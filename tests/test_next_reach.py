"""Measure next on other machines (issue 40): proposals only where the machine reaches,
instruments on every setup the fit accepts, and a plain word when nothing decides.

The cases are simulated on layouts of ``cmm_core.machine`` other than the moving bridge
(a gantry, a horizontal arm), their seeds drawn once from a seeded generator."""

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from scenarios import (  # noqa: E402
    arm_config,
    gantry_config,
    proposal_scale_readings,
    simulated,
)

from cmm_core.cli.commands import main  # noqa: E402
from cmm_core.io import load_dataset  # noqa: E402
from cmm_core.model import simulate  # noqa: E402
from cmm_core.plan.proposals import (  # noqa: E402
    DECIDE_POWER,
    FAMILIES,
    append,
    instrument_candidates,
    instrument_of,
    measurement_candidates,
    measurement_observations,
    propose,
)

SEEDS = np.random.default_rng(40).integers(1, 10_000, size=3)
"""Simulation seeds of the three cases (gantry, horizontal arm, no effect)."""

HIDDEN = {"kinematic": {"spec": "kinematic21,rxz:4", "coefficients": {"rxz[4]": 3.0}}}
"""A high-order yaw of the X carriage hidden from a baseline without squareness: the
rivals sxy and rxz:4 (tests/test_proposals.py)."""

BASE = "kinematic21,-sxy"
def _per_row(folder: Path) -> None:
    """The setup file of ``folder`` naming no stylus per placement: each measurement row
    names its own (the fit accepts it)."""
    path = folder / "setup.json"
    setup = json.loads(path.read_text())
    for pl in setup["positions"].values():
        pl.pop("probe", None)
    path.write_text(json.dumps(setup))


def _inputs(folder: Path) -> list:
    return [str(folder / "measurements.csv"), "--setup", str(folder / "setup.json"),
            "--certificate", str(folder / "certificate.csv")]


@pytest.fixture(scope="module")
def gantry():
    return simulate(gantry_config(SEEDS[0], **HIDDEN)).dataset


def test_a_gantry_s_proposals_are_all_within_its_strokes(gantry):
    """The plate stood in XZ (and YZ) near B1 needs the ram at z = 960 mm on a 900 mm
    stroke: the simulator (100 mm of slack) accepts it, the proposals skip it with the
    ball, stylus and reading; every proposal left has every probed ball of every stylus
    inside the strokes."""
    by = {c.name: c for c in measurement_candidates(gantry)}
    measurement_observations(gantry, [by["xz"]])  # the old check let it through
    assert "960.0 mm of axis z" in append.out_of_reach(gantry, by["xz"])
    pr = propose(gantry, ("sxy", "rxz:4"), baseline=BASE)
    skipped = {s.name: s for s in pr.infeasible}
    assert {"xz", "yz"} <= set(skipped)
    assert "ball 21 with stylus T needs the scale reading 960.0 mm of axis z, outside the " \
        "machine's stroke 0 to 900 mm" == skipped["xz"].reason
    assert skipped["xz"].family == "orientation" and pr.skipped["xz"] == skipped["xz"].reason
    rng = np.asarray(gantry.setup.range_mm, float)
    plates = [p.candidate for p in pr.ranked if p.candidate.positions]
    assert plates and not {c.name for c in plates} & set(skipped)
    for c in plates:
        x = proposal_scale_readings(gantry, c)
        assert ((x >= 0.0) & (x <= rng)).all(), (c.name, x.min(axis=0), x.max(axis=0))
    # the moves to the ends of the strokes are the ram's: within 5 % of each end
    low = proposal_scale_readings(gantry, by["low_x"])
    assert low[:, 0].min() == pytest.approx(0.05 * rng[0], abs=0.01)


def test_next_lists_what_it_skipped_on_a_gantry(gantry, tmp_path, capsys):
    """The command names each candidate out of reach on stderr (``note: skipped: ...``)
    and in the JSON's ``skipped`` records, and proposes none of them."""
    simulate(gantry_config(SEEDS[0], **HIDDEN)).write(tmp_path)
    rc = main(["next", *_inputs(tmp_path), "--baseline", BASE, "--rivals", "sxy,rxz:4",
               "--top", "30"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    doc = json.loads(out.out)
    names = {s["name"] for s in doc["skipped"]}
    assert {"xz", "yz"} <= names
    assert not names & {p["name"] for p in doc["proposals"]}
    lines = [ln for ln in out.err.splitlines() if ln.startswith("note: skipped: ")]
    assert len(lines) == len(doc["skipped"])
    assert any(ln.startswith("note: skipped: xz (the plate stood in XZ near B1): ball 21")
               for ln in lines), lines


@pytest.fixture(scope="module")
def arm_files(tmp_path_factory):
    out = tmp_path_factory.mktemp("arm")
    simulate(arm_config(SEEDS[1], **HIDDEN)).write(out)
    _per_row(out)
    return out


def test_instruments_run_on_a_setup_naming_the_stylus_per_row(arm_files, capsys):
    """``next --instruments`` on a horizontal arm whose setup names no stylus per
    placement (it ended in "missing key 'probe'"): every instrument scored, each laid
    out from the stylus measured first at the reference (X, 155 mm along X), every point
    inside the strokes."""
    rc = main(["next", *_inputs(arm_files), "--baseline", BASE, "--rivals", "rxz:4,sxy",
               "--instruments", "--top", "100"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    doc = json.loads(out.out)
    tools = [p for p in doc["proposals"] if p["instrument"]]
    assert {p["name"] for p in tools} == {"laser_x", "laser_y", "laser_z", "step_gauge_x",
                                          "step_gauge_y", "ball_bar_xy"}, doc["skipped"]
    assert "instrument" in doc["families"]
    rng = np.asarray(json.loads((arm_files / "setup.json").read_text())["machine"]
                     ["range_mm"], float)
    for p in tools:
        assert p["instrument"]["offset_mm"] == [155.0, -60.0, 0.0]
    data = simulate(arm_config(SEEDS[1], **HIDDEN)).dataset
    sim0 = append._machine(data)
    for c in instrument_candidates(data):
        for x, _ in instrument_of(c, sim0).points():
            assert ((x >= 0.0) & (x <= rng)).all(), c.name


def test_an_instrument_out_of_reach_is_skipped_not_fatal():
    """A step gauge whose first face needs the X scale at -155 mm is skipped with the
    reading, the other instruments scored (it aborted the whole command)."""
    data = simulate(arm_config(SEEDS[1], **HIDDEN)).dataset
    tools = instrument_candidates(data)
    gauge = next(c for c in tools if c.name == "step_gauge_x")
    start = list(gauge.instrument["start_mm"])
    start[0] = -155.0 + gauge.instrument["offset_mm"][0]
    far = replace(gauge, name="step_gauge_off", instrument={**gauge.instrument,
                                                            "start_mm": start})
    pr = propose(data, ("rxz:4", "sxy"), baseline=BASE, cands=[*tools, far])
    assert pr.skipped["step_gauge_off"] == ("the scale reading -155.0 mm of axis x is "
                                            "outside the machine's stroke 0 to 1200 mm")
    assert {p.candidate.name for p in pr.ranked} == {c.name for c in tools}


@pytest.fixture(scope="module")
def no_effect():
    """The 80 mm layout with nothing hidden: squareness and the yaw are both noise."""
    return simulated("pitch80_3pos", int(SEEDS[2]), noise_um=0.5).dataset


def test_when_nothing_decides_the_conclusion_says_so_first(no_effect):
    pr = propose(no_effect, ("sxy", "rxz:4"), baseline=BASE)
    best = max(p.power_min for p in pr.ranked)
    assert best < DECIDE_POWER and not pr.decided
    assert pr.message.startswith(f"No candidate decides between sxy and rxz:4: the best "
                                 f"reaches {100 * best:.0f} % power (")
    assert "Best next measurement" not in pr.message
    # instruments were not searched; the plate stood up was (its styli point up from
    # plates at z = 0: readings below the zero this machine already made), and nothing
    # was out of reach
    assert f"Not searched, and might decide: {FAMILIES['instrument']}." in pr.message
    assert "orientation" in pr.families and not pr.skipped
    assert "Out of the machine's reach" not in pr.message
    assert "another stylus length" not in pr.message  # searched: stylus_long
    top = pr.ranked[0]
    assert "too little to decide" in top.outcome and "decided with" not in top.outcome


def test_next_says_first_that_nothing_decides(no_effect, tmp_path, capsys):
    """The command's JSON opens with the conclusion; with the instruments searched, they
    are not named as a family to try."""
    simulated("pitch80_3pos", int(SEEDS[2]), noise_um=0.5).write(tmp_path)
    rc = main(["next", *_inputs(tmp_path), "--baseline", BASE, "--rivals", "sxy,rxz:4",
               "--instruments"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    doc = json.loads(out.out)
    assert next(iter(doc)) == "message" and doc["decided"] is False
    assert doc["message"].startswith("No candidate decides between sxy and rxz:4: the best "
                                     "reaches ")
    assert "Best next measurement" not in doc["message"]
    assert "instrument runs" not in doc["message"]


def test_readings_the_data_already_made_stay_reachable():
    """Plates at z = 0 probed with an upward stylus (the sample data, after the thesis):
    the z reading -50 mm was measured, so moves of that plate are proposed, while the
    stylus 100 mm longer (reading -150 mm, beyond anything measured) is skipped with its
    reading; every plate proposal stays within what the data reached."""
    root = Path(__file__).resolve().parents[1] / "sample_data" / "simulated"
    data = load_dataset([root / "measurements.csv"], root / "setup.json",
                        root / "certificate.csv")
    lo, hi = append.reached_range(data)
    assert lo[2] == pytest.approx(-50.0, abs=0.1) and (hi >= data.setup.range_mm).all()
    cands = measurement_candidates(data)
    reasons = {c.name: append.out_of_reach(data, c) for c in cands}
    assert reasons["stylus_long"].startswith("ball 1 with stylus next_stylus_long needs "
                                             "the scale reading -150.0 mm of axis z")
    assert reasons["low_x"] == reasons["xz"] == ""
    for c in cands:
        if c.positions and not reasons[c.name]:
            x = proposal_scale_readings(data, c)
            assert ((x >= lo - 1e-9) & (x <= hi + 1e-9)).all(), c.name

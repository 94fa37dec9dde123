"""Instrument-only fits from the command line (issue 24, point 4): a step gauge and laser
runs with a setup that names only the machine; the JSON names what they cannot see."""

import json

import numpy as np
import pytest

from cmm_core.cli import main
from cmm_core.model import (
    simulate,
    simulate_laser,
    simulate_step_gauge,
    write_laser,
    write_step_gauge,
)


@pytest.fixture
def files(tmp_path):
    sim = simulate({"seed": 1, "plate": {"form_um": 0.0, "certificate_u_um": 0.0}})
    sg = simulate_step_gauge(sim, [100, 300, 200], [1100, 300, 200],
                             np.arange(1, 11) * 100.0, u_um=0.1, seed=2)
    run = simulate_laser(sim, "y", [600, 0, 350], np.linspace(0, 1000, 21), u_um=0.2,
                         seed=3)
    write_step_gauge(sg, tmp_path / "sg.csv")
    write_laser(run, tmp_path / "laser.csv")
    (tmp_path / "machine.json").write_text(json.dumps(
        {"machine": {"layout": "moving_bridge_fxyz",
                     "range_mm": sim.dataset.setup.range_mm.tolist()}}))
    return tmp_path


def test_fit_and_diagnose_without_a_plate(files, capsys):
    args = ["--setup", str(files / "machine.json"), "--step-gauge", str(files / "sg.csv"),
            "--laser", str(files / "laser.csv")]
    assert main(["fit", *args]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["plate"] == "none" and out["n_obs"] == 0 and out["rms_um"] is None
    assert {"sxy", "syz", "dzz[1]"} <= set(out["unidentifiable"])
    assert len(out["instruments"]) == 2
    assert main(["diagnose", *args]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["certificate_u_source"] == "no plate: instruments only"
    assert "instrument-only" in out["skipped"]["plate_sag"]


def test_instrument_only_refusals(files, capsys):
    assert main(["fit", "--step-gauge", str(files / "sg.csv")]) == 2
    assert "needs the machine" in capsys.readouterr().err
    assert main(["fit", "--setup", str(files / "machine.json"), "--step-gauge",
                 str(files / "sg.csv"), "--sigma-um", "auto"]) == 2
    assert "no plate" in capsys.readouterr().err


def test_an_msl_bar_alone_from_the_command_line(tmp_path, capsys):
    """An MSL bar with its metadata and nothing else: the machine from the metadata, and
    the bar's x scale back as MSL's validation bar gives it, dxx[1]·2000/R = −1.2 µm/m
    (docs/msl-format.md: MSL's Txx = +1.2e-6 is the same scale in its own sign)."""
    from test_msl import write_msl

    from cmm_core.io import msl

    xyz = msl._grid(31, 1, 20.0)
    xyz[:, 0] *= 1 + 1.2e-6  # MSL's simulated deviation, true − indicated
    s, m = write_msl(tmp_path, "bar", np.round(xyz, 5), 31, 1, 20.0, (0, 0, 0), (0, 0, 0),
                     "fixed_bridge_xfyz", (0.0, 0.0, 0.0), {"Txx": [0.0, 1.2e-6]})
    assert main(["fit", "--msl-bar", str(s), "--msl-metadata", str(m), "--msl-kind",
                 "simulated", "--model", "dxx", "--order", "1", "--sigma-um", "0.003"]) == 0
    out = json.loads(capsys.readouterr().out)
    p = out["parameters"]["dxx[1]"]
    # RANGE x = 800 mm: the scale s (µm/m) is dxx[1]·2000/800; rounding u 0.0029 µm/length
    assert p["value"] * 2000 / 800 == pytest.approx(-1.2, abs=4 * p["u"] * 2000 / 800)


def test_an_instrument_only_model_is_saved_with_the_region_its_instruments_saw(files):
    """``fit --save`` of instruments alone: the model file's region is the span of the
    instruments' scale readings (there are no plate readings), here the gauge's line
    x 100-1100 mm at y = 300 mm and the laser's y 0-1000 mm at x = 600 mm."""
    out = files / "model.json"
    assert main(["fit", "--setup", str(files / "machine.json"), "--model", "dxx,dyy",
                 "--step-gauge", str(files / "sg.csv"), "--laser", str(files / "laser.csv"),
                 "--save", str(out), "--json", str(files / "fit.json")]) == 0
    lo, hi = json.loads(out.read_text())["summary"]["region_mm"]
    assert lo[0] == pytest.approx(100, abs=0.01) and hi[0] == pytest.approx(1100, abs=0.01)
    assert lo[1] == pytest.approx(0, abs=0.01) and hi[1] == pytest.approx(1000, abs=0.01)

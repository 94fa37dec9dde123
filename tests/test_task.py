"""Task-specific uncertainty (issue 14 part 3, ISO/TS 15530-4 style): a distance, a circle
and a plane measured with the fitted machine, Monte Carlo against the law of
propagation and against closed forms."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cmm_core import kinematics as kin
from cmm_core.compensate import Model, load_model, save_model
from cmm_core.fit import fit
from cmm_core.io import DataError
from cmm_core.task import read_task, task_uncertainty

ROOT = Path(__file__).resolve().parents[1]
PLANS = ROOT / "sample_data" / "plans"


@pytest.fixture(scope="module")
def model_file(tmp_path_factory, thesis_clean):
    """The thesis fit (six tables, flagged blunders excluded), saved as 'fit --save' does."""
    data, exclude = thesis_clean
    path = tmp_path_factory.mktemp("task") / "model.json"
    save_model(fit(data, "kinematic21", exclude=exclude), path)
    return path


def _task(name, **changes):
    raw = json.loads((PLANS / name).read_text())
    raw.update(changes)
    return read_task(raw, name=name)


def test_linear_task_agrees_with_the_law_of_propagation(model_file):
    """A length along x between two points is linear in the point errors to first order
    (the transverse errors enter as e²/L, 1e-9 µm here). Its variance by the law of
    propagation, written out here independently of the module: the x-error difference
    through the model covariance, two probing variances, and the length times the
    thermal relative uncertainty sqrt((α u_T)² + (ΔT u_α)²) (JCGM 100 eq. 10). The Monte
    Carlo standard deviation over M = 40000 trials has relative standard error
    1/sqrt(2(M-1)) = 0.35 %: asserted within 4 of them (1.4 %)."""
    model = load_model(model_file)
    task = _task("task_distance.json", trials=40000)
    res = task_uncertainty(model, task).values["length_mm"]
    p = model.probes_mm["1"]
    x = task.points_mm - p
    _, J = kin.jacobian(model.terms, model.coef, x, np.broadcast_to(p, x.shape))
    g = (J[1, 0] - J[0, 0]) / kin.UM  # µm of length per coefficient unit
    L_mm = 500.0
    u_thermal = L_mm * 1e3 * math.hypot(11.5e-6 * 0.1, 0.5 * 1e-6)
    u_expected = math.sqrt(g @ model.cov @ g + 2 * 0.5 ** 2 + u_thermal ** 2)
    assert res["u_lpu_um"] == pytest.approx(u_expected, rel=1e-6)
    assert res["u_mc_um"] == pytest.approx(u_expected, rel=4 / math.sqrt(2 * 39999))
    assert res["contributions_um"]["probing"] == pytest.approx(0.5 * math.sqrt(2), rel=1e-6)
    lo, hi = res["interval"]
    assert lo < res["value"] < hi


def _perfect_model(sigma_um=0.5):
    """No machine error and no model uncertainty: only the task's own influences."""
    terms = kin.KinematicTerms((("dxx", 2),), (1200.0, 1000.0, 700.0))
    return Model("dxx", terms, np.zeros(terms.n), np.zeros((terms.n, terms.n)),
                 {"1": np.array([0.0, 0.0, -100.0])}, False, {"sigma_um": sigma_um})


def test_circle_diameter_against_its_closed_form():
    """N points equally spaced on a circle with independent noise σ per coordinate: the
    least-squares radius has variance σ²/N to first order (only the radial components
    count), so u(D) = 2σ/sqrt(N) = 0.354 µm for σ = 0.5 µm and N = 8. With no machine
    error the circle is recovered exactly (diameter 200 mm, centre (600, 500, 300) mm).
    Monte Carlo relative standard error 0.5 % at 20000 trials; asserted within 3 %
    (4 SE plus the second-order bias of a range of 0.35 µm on 100 mm, negligible)."""
    task = _task("task_circle.json", discrepancy={"sd_um": 0.0, "length_mm": 200.0})
    res = task_uncertainty(_perfect_model(), task).values
    # the sample points are written to 1e-9 mm
    assert res["diameter_mm"]["value"] == pytest.approx(200.0, abs=1e-8)
    assert [res[f"centre_{a}_mm"]["value"] for a in "xyz"] == pytest.approx(
        [600.0, 500.0, 300.0], abs=1e-8)
    u_closed = 2 * 0.5 / math.sqrt(8)
    assert res["diameter_mm"]["u_lpu_um"] == pytest.approx(u_closed, rel=1e-4)
    assert res["diameter_mm"]["u_mc_um"] == pytest.approx(u_closed, rel=0.03)


def test_discrepancy_adds_its_share_in_quadrature(model_file):
    model = load_model(model_file)
    base = task_uncertainty(model, _task("task_circle.json", trials=2000,
                                         discrepancy={"sd_um": 0.0, "length_mm": 200.0}))
    more = task_uncertainty(model, _task("task_circle.json", trials=2000))
    d0, d1 = base.values["diameter_mm"], more.values["diameter_mm"]
    assert "discrepancy" not in d0["contributions_um"]
    assert d1["contributions_um"]["discrepancy"] > 0
    assert d1["u_lpu_um"] ** 2 == pytest.approx(
        d0["u_lpu_um"] ** 2 + d1["contributions_um"]["discrepancy"] ** 2, rel=1e-9)


def test_plane_flatness_of_a_perfect_plane_is_zero():
    res = task_uncertainty(_perfect_model(), _task("task_plane.json", trials=2000))
    f = res.values["flatness_um"]
    assert f["value"] == pytest.approx(0.0, abs=1e-9)
    # the range of noisy residuals is never negative: the interval lies above zero
    assert f["interval"][0] > 0 and f["u_mc_um"] > 0


def test_undetermined_model_refused(thesis_clean, tmp_path):
    data, exclude = thesis_clean
    path = tmp_path / "loc0.json"
    save_model(fit(data, "kinematic21", positions=["BP111", "BP112"], exclude=exclude), path)
    with pytest.raises(ValueError, match="undetermined"):
        task_uncertainty(load_model(path), _task("task_distance.json", trials=200))


def test_task_cli(model_file, tmp_path, capsys):
    from cmm_core.cli import main

    out = tmp_path / "task.json"
    assert main(["--json", str(out), "task", str(model_file),
                 str(PLANS / "task_distance.json"), "--trials", "2000"]) == 0
    res = json.loads(out.read_text())
    assert res["task"] == "distance" and res["trials"] == 2000
    assert {"value", "unit", "u_mc_um", "u_lpu_um", "interval"} <= set(
        res["results"]["length_mm"])
    bad = tmp_path / "bad_task.json"
    raw = json.loads((PLANS / "task_distance.json").read_text())
    raw["points"].append(raw["points"][0])
    bad.write_text(json.dumps(raw))
    with pytest.raises(DataError, match="points"):
        read_task(bad)
    assert main(["task", str(model_file), str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad_task.json" in err and "points" in err
    raw = json.loads((PLANS / "task_distance.json").read_text())
    raw["points"][1]["probe"] = "9"
    bad.write_text(json.dumps(raw))
    assert main(["task", str(model_file), str(bad)]) == 2
    assert "points[1].probe" in capsys.readouterr().err


def test_a_model_that_failed_its_chi2_test_is_flagged(model_file):
    """The thesis model fails its χ² test (χ²/dof about 45 against σ = 0.5 µm): the task
    result says its share is too small by about the Birge ratio the model file records."""
    model = load_model(model_file)
    assert model.summary["fails_chi2_test"] and model.summary["birge_ratio"] > 5
    res = task_uncertainty(model, _task("task_distance.json", trials=2000))
    assert "failed its χ² test" in res.message
    assert f"{model.summary['birge_ratio']:.2f}" in res.message

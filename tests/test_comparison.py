"""The chapter-7 comparison (``cmm_core.analysis.comparison``): kinematic model vs GP vs
measurement at the measured balls, the plate-plane grid, and the GP coverage reasons."""

import numpy as np
import pandas as pd
import pytest

from cmm_core.analysis import (
    compare_models,
    coverage_reasons,
    measured_error_from_residuals_um,
    placement_plane_grid,
    plate_coordinates_mm,
)
from cmm_core.model import error_at, fit, residual_u
from tests.scenarios import simulated

LAYOUTS = ["pitch100_4pos", "pitch80_3pos", "pitch150_5pos"]


@pytest.fixture(scope="module", params=LAYOUTS)
def fitted(request):
    """A clean simulated layout (σ = 0.5 µm, the simulator's default noise), its
    kinematic fit, the rigid-only fit's measured errors and the model's prediction."""
    sim = simulated(request.param, seed=11)
    r = fit(sim.dataset, sigma_um=0.5)
    rig = fit(sim.dataset, "rigid", sigma_um=0.5)
    err = measured_error_from_residuals_um(rig.residuals_um)
    return r, rig, err, err + r.residuals_um


@pytest.mark.parametrize("comp", ["x", "y", "z"])
def test_kinematic_difference_is_the_fit_residual_and_its_z_has_unit_variance(fitted, comp):
    """Kinematic − measured at a fitted ball is that ball's residual (the rigid fit's
    placements are a subset of the full model's parameters), and dividing by the residual's
    sd σ√(1 − h_ii) gives z with E[z²] = 1 on clean data: mean z² within 4 standard errors
    of 1 (sd of a mean of n χ²₁ values, √(2/n)), a bound that fails at one in ~30,000."""
    r, rig, err, pred = fitted
    a = "xyz".index(comp)
    meta = rig.table[["position", "probe", "ball"]]
    ch = compare_models(r, err, pred, residual_u(r), comp, points_mm=r.problem.obs.r_mm,
                        meta=meta)
    t = ch.table
    assert np.allclose(t["kin_minus_meas_um"], r.residuals_um[:, a], atol=1e-9)
    z2 = float(np.mean(t["kin_z"] ** 2))
    assert abs(z2 - 1) < 4 * np.sqrt(2 / len(t)), z2
    assert ch.summary_dict()["kin. RMS z"] == pytest.approx(np.sqrt(z2))
    assert not ch.has_gp and "gp_um" not in t


def test_thesis_percentage_by_hand(fitted):
    """Eq. 7.1 on one row by hand: |Δ| (µm → mm) over the ball's plate coordinate × 100."""
    r, rig, err, pred = fitted
    meta = rig.table[["position", "probe", "ball"]]
    ch = compare_models(r, err, pred, residual_u(r), "x", points_mm=r.problem.obs.r_mm,
                        meta=meta)
    coord = np.abs(plate_coordinates_mm(r, r.problem.obs.r_mm)[:, 0])
    i = int(np.argmax(coord))
    want = abs(r.residuals_um[i, 0]) * 1e-3 / coord[i] * 100
    assert ch.table["thesis_pct_kin"].iloc[i] == pytest.approx(want, rel=1e-12)
    # below 1 mm of plate coordinate the ratio is left blank, never a huge percentage
    assert ch.table["thesis_pct_kin"][coord <= 1.0].isna().all()


def test_plate_coordinates_recover_the_fitted_plate(fitted):
    """Each placed ball's tip, taken back through its placement, lands within the fit's
    noise (a few µm) of its fitted plate coordinate: Rᵀ(x − t) undoes x = R c + t."""
    r, *_ = fitted
    obs = r.problem.obs
    c = plate_coordinates_mm(r, obs.r_mm)
    assert np.max(np.abs(c - r.state.c[obs.ball])) < 0.01


def test_gp_columns_and_leave_one_out_z(fitted):
    """With GP arrays given, the GP columns are their differences from the measurement,
    the z the leave-one-out difference over its sd."""
    r, rig, err, pred = fitted
    rng = np.random.default_rng(4)
    gp = err + rng.normal(0, 0.1, err.shape)
    loo = err + rng.normal(0, 0.3, err.shape)
    sd = np.full(err.shape, 0.3)
    ch = compare_models(r, err, pred, residual_u(r), "y", points_mm=r.problem.obs.r_mm,
                        meta=rig.table[["position", "probe", "ball"]], gp_mean_um=gp,
                        gp_loo_mean_um=loo, gp_loo_sd_um=sd)
    t = ch.table
    assert np.allclose(t["gp_minus_meas_um"], gp[:, 1] - err[:, 1])
    assert np.allclose(t["gp_loo_z"], (loo[:, 1] - err[:, 1]) / 0.3)
    assert [f.label for f in ch.summary][2:] == ["GP RMS Δ (µm)", "GP LOO RMS Δ (µm)",
                                                  "GP LOO RMS z"]
    with pytest.raises(ValueError, match="expected 'x', 'y' or 'z'"):
        compare_models(r, err, pred, residual_u(r), "w", points_mm=r.problem.obs.r_mm,
                       meta=rig.table)


def test_plane_grid_lies_in_the_plate_plane_and_is_aligned_like_the_data(fitted):
    """The grid spans the fitted plate's u, v extent in its plane (w = 0 in the plate
    frame), and the aligned kinematic surface differs from ``error_at`` by the one constant
    that makes its mean at the placement's balls equal the model's rigid-aligned
    prediction there."""
    r, rig, err, pred = fitted
    obs = r.problem.obs
    pos = obs.positions[-1]
    g = placement_plane_grid(r, pos, pred, n=9)
    k = obs.positions.index(pos)
    back = (g.machine_mm - r.state.t[k]) @ r.state.R[k]
    assert np.allclose(back[:, 2], 0, atol=1e-9)
    assert back[:, 0].min() == pytest.approx(r.state.c[:, 0].min())
    assert back[:, 1].max() == pytest.approx(r.state.c[:, 1].max())
    raw, _ = error_at(r, g.machine_mm - g.probe_mm, g.probe)
    shift = g.kinematic_um - raw
    assert np.allclose(shift, shift[0], atol=1e-9)
    at_balls, _ = error_at(r, obs.r_mm[g.selected] - g.probe_mm, g.probe)
    assert np.allclose(np.mean(at_balls + shift[0], axis=0),
                       np.mean(pred[g.selected], axis=0), atol=1e-9)
    with pytest.raises(ValueError, match="expected one of"):
        placement_plane_grid(r, "nowhere", pred)


def test_coverage_reasons_name_the_cause_from_the_numbers():
    """The caption that explains a leave-one-out coverage outside 95 ± 2 %: each reason
    appears when its numbers say so, and only then."""




    rng = np.random.default_rng(3)
    meta = pd.DataFrame({"position": np.repeat(["P1", "P2", "P3"], 50),
                         "probe": np.repeat(["1", "2", "3"], 50),
                         "ball": np.tile(np.arange(1, 51), 3)})
    # non-stationary: P3's errors three times the others'
    z = rng.standard_normal(150) * np.repeat([0.7, 0.7, 2.1], 50)
    text = " ".join(coverage_reasons(85.0, z, meta))
    assert "not stationary" in text and "at P3" in text
    assert "4 leave-one-out sd" not in text or (np.abs(z) > 4).any()
    # one blunder, stationary otherwise
    z = rng.standard_normal(150) * 0.9
    z[17] = 9.0
    text = " ".join(coverage_reasons(92.0, z, meta, noise_by_probe=(0.5, 0.6, 0.5),
                                     probe_names=("1", "2", "3")))
    assert "1 point(s) lie more than 4" in text and "P1 probe 1 ball 18" in text
    assert "not stationary" not in text and "differs between styli" not in text
    # styli of very different noise; too wide intervals overall
    z = rng.standard_normal(150) * 0.5
    text = " ".join(coverage_reasons(99.5, z, meta, noise_by_probe=(0.2, 3.0, 0.3),
                                     probe_names=("1", "2", "3")))
    assert "0.20 µm for 1 to 3.00 µm for 2" in text and "wider than" in text
    # just outside the band by less than a point: said to be chance
    text = " ".join(coverage_reasons(92.9, rng.standard_normal(150), meta))
    assert "chance alone" in text




def test_detection_limit_chart_has_one_axis_per_unit_and_room_above_the_tallest_bar():
    """Issue 27: µm and 10⁻⁶/K shared one axis and the tallest bar's label was cut. Each
    unit now has its own log panel reaching a factor 4 above its tallest bar."""
    from cmm_core.analysis import fig_detection_limits

    evals = [{"name": "A", "detection_limits": {"dzz:3": {"size": 0.6, "unit": "um"},
                                                "plate_thermal": {"size": 2.5,
                                                                  "unit": "1e-6/K"}}},
             {"name": "B", "detection_limits": {"dzz:3": {"size": 1.8, "unit": "um"}}}]
    fig = fig_detection_limits(evals, ["dzz:3", "plate_thermal"])
    assert len(fig.layout.annotations) == 2  # one titled panel per unit
    ranges = [fig.layout.yaxis.range, fig.layout.yaxis2.range]
    assert ranges[0][1] == pytest.approx(np.log10(1.8 * 4))
    assert ranges[1][1] == pytest.approx(np.log10(2.5 * 4))
    panel = {t.xaxis: [t.name for t in fig.data if t.xaxis == t.xaxis] for t in fig.data}
    assert set(panel) == {"x", "x2"}
    b_thermal = [t for t in fig.data if t.name == "B" and t.xaxis == "x2"][0]
    assert b_thermal.y == (None,) and b_thermal.text == ("—",)  # B cannot see it

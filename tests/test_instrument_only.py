"""Instrument-only fits (issue 24, point 4): step gauges and laser runs without a plate
file (``instrument_observations`` into ``fit``), what they determine and what they name.

Reference values are computed by hand, independently of the fit's code: with the
positioning function ``dxx(x) = c1·(T1(s) + 1) = c1·2x/R`` at order 1 (``machine.terms.
basis``, s = 2x/R − 1), a step gauge along x with lengths ``L_k`` from one face reads
``measured − certified = −2 c1 L_k / R`` (true = indicated + dxx: the kinematic model's
sign), a regression through the origin: ``ĉ1 = −(R/2)·ΣL·y/ΣL²`` and
``u(ĉ1) = (R/2)·u/√ΣL²`` (µm, u the length's standard uncertainty in µm, L in mm).
"""

import numpy as np
import pytest

from cmm_core.diagnosis import diagnose
from cmm_core.io import DataError, read_machine
from cmm_core.model import (
    fit,
    instrument_observations,
    simulate,
    simulate_ball_bar,
    simulate_laser,
    simulate_step_gauge,
    summary,
)

RANGE = np.array([1200.0, 1000.0, 700.0])
LENGTHS = np.arange(1, 11) * 100.0
KIN = {"spec": "kinematic21", "order": 2}


def _sim(coefficients=None, seed=1):
    """The simulator's machine: random kinematic21 errors (order 2), or exactly
    ``coefficients`` when given (every other error zero)."""
    km = dict(KIN) if coefficients is None else {
        **KIN, "coefficients": coefficients, "random_um": 0.0, "random_urad": 0.0}
    return simulate({"seed": seed, "kinematic": km,
                     "plate": {"form_um": 0.0, "certificate_u_um": 0.0}})


def _gauge_along_x(sim, seed, u_um=0.1, offset=(0.0, 0.0, -150.0)):
    return simulate_step_gauge(sim, [100, 300, 200], [1100, 300, 200], LENGTHS,
                               offset_mm=offset, u_um=u_um, seed=seed)


def test_a_step_gauge_along_x_determines_the_x_scale_by_the_hand_formula():
    c1 = 2.4  # µm at the end of the stroke: 4 µm/m
    sim = _sim({"dxx[1]": c1})
    sg = _gauge_along_x(sim, seed=5, offset=(0.0, 0.0, 0.0))
    res = fit(instrument_observations([sg], RANGE), "dxx", order=1, sigma_um=0.5)
    assert res.status == "converged" and res.plate == "none"
    got = dict(zip(res.labels, zip(res.values, res.u, strict=True), strict=True))
    y_um = (sg.measured_mm - sg.certified_mm) * 1e3
    hand = -(RANGE[0] / 2) * (LENGTHS @ y_um) / (LENGTHS @ LENGTHS)
    u_hand = (RANGE[0] / 2) * 0.1 / np.sqrt(LENGTHS @ LENGTHS)
    # the same estimator, except that the fit's regressor is the indicated length, not
    # the certified one: they differ by the scale error itself (4 µm/m), so the two
    # agree to 1e-5 relative, not to rounding
    assert got["dxx[1]"][0] == pytest.approx(hand, rel=1e-5)
    assert got["dxx[1]"][1] == pytest.approx(u_hand, rel=1e-5)
    assert abs(got["dxx[1]"][0] - c1) < 4 * u_hand  # the noise: 4 u (p ≈ 6e-5)
    assert res.dof == len(LENGTHS) - 1 and not res.unidentifiable


def test_monte_carlo_z_scores_of_the_x_scale_are_standard():
    """200 seeds of the gauge's noise: the fitted dxx[1]'s z-scores against the truth
    have mean 0 and standard deviation 1 within their sampling error (4 standard errors:
    mean ± 4/√200, sd ± 4/√400)."""
    c1 = 2.4
    sim = _sim({"dxx[1]": c1, "dxx[2]": -0.8})
    z = []
    for seed in range(200):
        sg = _gauge_along_x(sim, seed=1000 + seed, offset=(0.0, 0.0, 0.0))
        res = fit(instrument_observations([sg], RANGE), "dxx", order=2, sigma_um=0.5)
        i = res.labels.index("dxx[1]")
        z.append((res.values[i] - c1) / res.u[i])
    z = np.array(z)
    assert abs(z.mean()) < 4 / np.sqrt(200)
    assert abs(z.std(ddof=1) - 1) < 4 / np.sqrt(400)


def test_kinematic21_from_a_step_gauge_along_x_names_all_but_dxx_and_its_abbe_terms():
    sim = _sim()
    res = fit(instrument_observations([_gauge_along_x(sim, seed=2)], RANGE), "kinematic21",
              order=2, sigma_um=0.5)
    assert res.status == "converged"
    assert res.rank == 2  # the gauge's lengths at order 2: two functions of x
    seen = {"dxx[1]", "dxx[2]", "rxy[1]", "rxy[2]", "rxz[1]", "rxz[2]"}
    kin = [lab for lab in res.labels if "[" in lab or lab.startswith("s")]
    # every error function the gauge does not see is named on its own
    alone = {c.split("·")[1] for c in res.null_combinations if c.count("·") == 1}
    assert alone == set(kin) - seen
    # dxx and the Abbe terms of the x carriage (rotations about y and z, arms of the
    # gauge's line) only in combinations: none of them is determined alone
    mixed = [c for c in res.null_combinations if c.count("·") > 1]
    assert mixed and all({t.split("·")[1] for t in c.replace("−", "+").split(" + ")}
                         <= seen for c in mixed)
    assert set(res.unidentifiable) == set(kin)
    assert np.isnan(res.u).all()
    assert res.dof == len(LENGTHS) - 2
    assert "instruments only" in res.message and "RMS nan" not in res.message
    # the model at the fit explains the gauge: its χ² share is all of the fit's
    assert summary(res)[0]["chi2_share"] == pytest.approx(1.0)


def test_laser_runs_on_three_axes_recover_the_three_scales():
    truth = {"dxx[1]": 2.4, "dxx[2]": -0.6, "dyy[1]": -1.5, "dyy[2]": 0.4,
             "dzz[1]": 0.9, "dzz[2]": 0.3}
    sim = _sim(truth)
    runs = [simulate_laser(sim, "x", [0, 500, 350], np.linspace(0, 1200, 25), u_um=0.2,
                           seed=11, run="x"),
            simulate_laser(sim, "y", [600, 0, 350], np.linspace(0, 1000, 21), u_um=0.2,
                           seed=12, run="y"),
            simulate_laser(sim, "z", [600, 500, 0], np.linspace(0, 700, 15), u_um=0.2,
                           seed=13, run="z")]
    res = fit(instrument_observations(runs, RANGE), "dxx,dyy,dzz", order=2, sigma_um=0.5)
    assert res.status == "converged" and not res.unidentifiable
    assert res.dof == 25 + 21 + 15 - 3 - 6  # readings minus the runs' zeros and the fit
    for lab, v, u in zip(res.labels, res.values, res.u, strict=True):
        assert abs(v - truth[lab]) < 4 * u, (lab, v, truth[lab], u)
        # a run of 15-25 readings of 0.2 µm determines a coefficient to 0.05-0.2 µm
        assert 0.02 < u < 0.3
    # the same runs against the 21 errors: the three scales are seen, the rest named
    full = fit(instrument_observations(runs, RANGE), "kinematic21", order=2, sigma_um=0.5)
    named = {c.split("·")[1] for c in full.null_combinations if c.count("·") == 1}
    assert {"sxy", "sxz", "syz", "dxy[2]", "dzx[2]", "rzz[1]"} <= named


def test_instrument_only_refusals_are_one_line():
    with pytest.raises(DataError, match="nothing to fit"):
        instrument_observations([], RANGE)
    sg = _gauge_along_x(_sim(), seed=2)
    with pytest.raises(DataError, match="machine.layout"):
        instrument_observations([sg], RANGE, "gantry_typo")
    with pytest.raises(DataError, match="range_mm"):
        instrument_observations([sg], [1200.0, 0.0, 700.0])
    with pytest.raises(ValueError, match="no plate"):
        fit(instrument_observations([sg], RANGE), "kinematic21", plate="free")
    with pytest.raises(DataError, match="outside the machine's stroke"):
        fit(instrument_observations([sg], [800.0, 1000.0, 700.0]), "dxx")


def test_the_machine_of_a_setup_without_positions():
    rng, layout = read_machine({"machine": {"layout": "fixed_bridge_xfyz",
                                            "range_mm": [800, 600, 500]}})
    assert rng.tolist() == [800.0, 600.0, 500.0] and layout == "fixed_bridge_xfyz"
    with pytest.raises(DataError, match="machine.layout"):
        read_machine({"machine": {"layout": "fixed_bridge"}})
    with pytest.raises(DataError, match="range_mm"):
        read_machine({"machine": {"range_mm": [1.2, 1.0, 0.7]}})  # metres


def test_the_diagnosis_runs_on_instruments_alone_and_names_what_they_cannot_see():
    sim = _sim()
    runs = [simulate_laser(sim, "x", [0, 500, 350], np.linspace(0, 1200, 21), u_um=0.2,
                           seed=3, run="x"), _gauge_along_x(sim, seed=4)]
    d = diagnose(instrument_observations(runs, RANGE), "kinematic21", order=2,
                 sigma_um=0.5)
    out = d.to_dict()
    assert d.baseline.plate == "none"
    for token in ("plate_sag", "drift", "probe_offset"):
        assert "instrument-only" in out["skipped"][token]
    assert out["verdict"] is None  # the true machine is kinematic21: nothing missing


def test_ball_bars_in_the_xy_plane_recover_the_two_scales_and_the_squareness():
    """A 400 mm bar along x, y and both diagonals of the xy plane, at two places each:
    its lengths see the two scales and the xy squareness (docs/instruments.md), which
    come back within 4 u; the z errors are named."""
    truth = {"dxx[1]": 1.8, "dyy[1]": -1.2, "sxy": 3.0}
    sim = _sim(truth)
    dirs = np.array([[1, 0, 0], [0, 1, 0], [1, 1, 0], [1, -1, 0]], float)
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    centres = np.array([[450.0, 400.0, 300.0], [750.0, 600.0, 300.0]])
    start = np.array([c - 200 * d for c in centres for d in dirs])
    end = np.array([c + 200 * d for c in centres for d in dirs])
    bar = simulate_ball_bar(sim, start, end, u_um=0.1, seed=7)
    obs = instrument_observations([bar], RANGE)
    res = fit(obs, "dxx:1,dyy:1,sxy", order=1, sigma_um=0.5)
    assert res.status == "converged" and not res.unidentifiable
    assert res.dof == len(start) - 3
    for lab, v, u in zip(res.labels, res.values, res.u, strict=True):
        assert abs(v - truth[lab]) < 4 * u, (lab, v, truth[lab], u)
    full = fit(obs, "kinematic21", order=1, sigma_um=0.5)
    alone = {c.split("·")[1] for c in full.null_combinations if c.count("·") == 1}
    assert {"dzz[1]", "sxz", "syz"} <= alone

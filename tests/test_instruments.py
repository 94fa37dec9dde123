"""Laser interferometer runs and step gauges fitted with the ball plate
(cmm_core.model.instruments).

Tolerances. Finite differences: central differences with a step of 1e-3 coefficient units;
the model's second derivatives are of order arm × 1e-12 mm per µrad² (rotations of µrad),
so truncation is below 1e-12 µm and rounding (x* ~ 1e3 mm, eps 1e-16) about 1e-7 µm per
unit step: 1e-5 bounds both with room. Monte Carlo: see the test.
"""

import dataclasses
import json

import numpy as np
import pytest

from cmm_core.cli import main
from cmm_core.diagnosis import score
from cmm_core.io import SAMPLE_DIR, DataError
from cmm_core.machine import KinematicTerms
from cmm_core.machine import kinematics as kin
from cmm_core.model import (
    LaserRun,
    Normal,
    Problem,
    StepGauge,
    fit,
    read_laser,
    read_step_gauge,
    select,
    simulate,
    weighted_residual,
    write_laser,
    write_step_gauge,
)
from cmm_core.model import instruments as ins
from cmm_core.model import normal as _normal

EXACT = {"plate": {"form_um": 2.0, "certificate_u_um": 0.0}}
SAMPLES = SAMPLE_DIR / "instruments"
XS = np.linspace(0.0, 1200.0, 25)


def _sim(seed=1, **extra):
    return simulate({"seed": seed, **EXACT, **extra})


def _kit(sim, seed=3):
    """A positioning and a straightness run along x (offset reflector) and a step gauge
    across the table diagonal."""
    pos = ins.simulate_laser(sim, "x", [0, 100, 50], XS, offset_mm=(0, 20, -80), u_um=0.2,
                             seed=seed)
    straight = ins.simulate_laser(sim, "x", [0, 100, 50], XS, component="y", u_um=0.3,
                                  seed=seed + 1)
    sg = ins.simulate_step_gauge(sim, [100, 150, 100], [1100, 850, 400],
                                 np.arange(1, 12) * 100.0, offset_mm=(0, 0, -150), u_um=0.3,
                                 seed=seed + 2)
    return [pos, straight, sg]


def _problem(sim, items, spec="kinematic21", plate="fixed", layout=None):
    obs = select(sim.dataset)
    obs = dataclasses.replace(obs, instruments=tuple(items),
                              **({"layout": layout} if layout else {}))
    from cmm_core.model import parse_spec

    return Problem(obs, parse_spec(spec), plate)


# --- the observation model ------------------------------------------------------------

def fd_rows_jacobian(inst, state, h=1e-3):
    """Central differences (step ``h`` µm or µrad) of the instruments' weighted rows with
    respect to their kinematic columns: the independent check of ``rows(..., True)``."""
    k = inst.cols
    fd = np.empty((inst.rows(state)[0].size, k.stop - k.start))
    for j in range(fd.shape[1]):
        up, dn = state.with_x(state.x.copy()), state.with_x(state.x.copy())
        up.x[k.start + j] += h
        dn.x[k.start + j] -= h
        fd[:, j] = (inst.rows(up)[0] - inst.rows(dn)[0]) / (2 * h)
    return fd


def plate_and_joint_with_predicted_u(sim, item):
    """Fits of the plate alone and with ``item``, and the joint u the information matrix
    predicts: (N_plate + Jᵀ J of the item's rows)⁻¹ under the joint fit's constraints. The
    information of the noise alone: the certificate's own uncertainty, which a fit with
    the certificate fixed adds (model.certificate_prior), is left out on both sides."""
    plate = fit(sim.dataset, "kinematic21", certificate_test=False)
    joint = fit(sim.dataset, "kinematic21", instruments=[item], certificate_test=False)
    prob0 = Problem(plate.problem.obs, joint.problem.spec, "fixed")
    ne = prob0.normal_equations(joint.state, 0.5)
    _, Ji = joint.problem.instruments.rows(joint.state, True)
    N = ne.N.copy()
    k = joint.problem.instruments.cols
    N[k, k] += Ji.T @ Ji
    C = joint.problem.constraints()
    u_pred = np.sqrt(np.diag(Normal(None, None, C, joint.rank_rtol, normal=(N, ne.g)).cov()))
    return plate, joint, u_pred


@pytest.mark.parametrize("layout", ["moving_bridge_fxyz", "fixed_bridge_xfyz"])
def test_rows_and_jacobian_match_finite_differences(layout):
    sim = _sim()
    prob = _problem(sim, _kit(sim), layout=layout)
    inst = prob.instruments
    state = prob.initial_state()
    k = inst.cols
    rng = np.random.default_rng(0)
    state.x[k] = rng.normal(0, 3.0, k.stop - k.start)  # µm / µrad: a bent machine
    r, J = inst.rows(state, True)
    assert J.shape == (r.size, k.stop - k.start)
    np.testing.assert_allclose(J, fd_rows_jacobian(inst, state), rtol=1e-6, atol=1e-5)
    # the residual itself against the model evaluated independently (kinematics.error is
    # true minus indicated; the instruments' error is indicated minus true)
    coef = state.x[k]
    pos, straight, sg = prob.obs.instruments
    for run in (pos, straight):
        e = -kin.error(prob.terms, coef, run.r_mm - run.p_mm, run.p_mm)
        d = e[np.arange(len(e)), run.component] - run.error_um
        assert np.allclose(run.predict(prob.terms, coef, False)[0], d, atol=1e-9)
    s1 = kin.model_point(prob.terms, coef, sg.r1_mm - sg.p_mm, sg.p_mm)
    s2 = kin.model_point(prob.terms, coef, sg.r2_mm - sg.p_mm, sg.p_mm)
    naive = (sg.measured_mm + np.linalg.norm(s2 - s1, axis=1)
             - np.linalg.norm(sg.r2_mm - sg.r1_mm, axis=1) - sg.certified_mm) * 1e3
    # the naive difference of two ~1 m lengths loses ~1e-13 m: 1e-6 µm
    assert np.allclose(sg.predict(prob.terms, coef, False)[0], naive, atol=1e-6)


def test_run_zero_and_straightness_slope_are_eliminated_exactly():
    """The rows of a run equal fitting its offset (and slope) as parameters: same χ², one
    row fewer per nuisance."""
    sim = _sim()
    pos, straight, _ = _kit(sim)
    terms, coef = ins.truth_of(sim)
    for run, n_nuis in ((pos, 1), (straight, 2)):
        T, Q = run.transform
        assert T.shape == (len(run.rows) - n_nuis, len(run.rows))
        d = run.predict(terms, coef * 0.7, False)[0]  # a wrong machine: rows not at noise
        w = 1.0 / run.u_um
        V = np.column_stack([np.ones_like(d), run.r_mm[:, 0]])[:, :n_nuis]
        a = np.linalg.lstsq(w[:, None] * V, -w * d, rcond=None)[0]
        explicit = np.sum((w * (d + V @ a)) ** 2)
        assert np.isclose(np.sum((T @ d) ** 2), explicit, rtol=1e-10)
        # per-reading residuals: the nuisances removed
        assert np.allclose(run.u_um * (Q @ (T @ d)), d + V @ a, atol=1e-9)


def test_sign_convention_a_machine_that_runs_long():
    """dxx[1] = 1 µm: at the far end of x the carriage is 2 µm beyond its reading (the
    basis T1(s) + 1 is 2 there), so the laser reads -2 µm (indicated minus true), the
    compensation adds +2 µm, and a 1000 mm gauge along x measures 1000 - 0.001667 mm."""
    terms = KinematicTerms((("dxx", 1),), (1200.0, 1000.0, 700.0))
    x = np.column_stack([XS, np.zeros((XS.size, 2))])
    assert np.allclose(kin.error(terms, [1.0], x, np.zeros(3))[:, 0], 2 * XS / 1200)
    m = XS.size
    run = LaserRun("t.csv", np.arange(2, m + 2), np.zeros(m, int), ("r",), np.zeros(m, int),
                   np.zeros(m, int), x, np.zeros_like(x), -2 * XS / 1200, np.full(m, 0.1))
    assert np.allclose(run.predict(terms, np.array([1.0]), False)[0], 0, atol=1e-9)
    r1, r2 = np.array([[100.0, 0, 0]]), np.array([[1100.0, 0, 0]])
    sg = StepGauge("g.csv", np.array([2]), ("L1000",), r1, r2, np.zeros((1, 3)),
                   np.array([1000 - 1000 * 2 / 1200 * 1e-3]), np.array([1000.0]),
                   np.array([0.1]))
    assert np.allclose(sg.predict(terms, np.array([1.0]), False)[0], 0, atol=1e-9)


# --- the joint fit ----------------------------------------------------------------------

def test_blocked_normal_equations_include_the_instrument_rows():
    """normal.accumulate (blocks of 40 observations, plate prior) equals JᵀJ, Jᵀr of the
    weighted residual that model.weighted_residual builds with the instrument rows."""
    sim = _sim()
    prob = _problem(sim, _kit(sim), spec="kinematic21,probe_offset", plate="prior")
    st = prob.initial_state()
    st.x[prob.instruments.cols] = 0.5
    _, r, J = weighted_residual(prob, st, 0.5, True)
    ne = _normal.accumulate(prob, st, 0.5, rows=40)
    Jd = J.toarray()
    assert ne.rows == r.size == 3 * prob.n_obs + prob.obs.cert_u_um.size + 24 + 23 + 11
    np.testing.assert_allclose(ne.N, Jd.T @ Jd, rtol=1e-9, atol=1e-9 * np.abs(ne.N).max())
    np.testing.assert_allclose(ne.g, Jd.T @ r, rtol=1e-9, atol=1e-9 * np.abs(ne.g).max())
    assert np.isclose(ne.cost, r @ r, rtol=1e-12)
    assert np.isclose(_normal.cost_of(prob, st, 0.5)[1], r @ r, rtol=1e-12)


def test_fit_reports_each_instrument_and_its_chi2_share():
    sim = _sim()
    items = _kit(sim)
    r0 = fit(sim.dataset, "kinematic21")
    r = fit(sim.dataset, "kinematic21", instruments=items)
    assert r.status == "converged" and r.identifiable
    assert r.dof == r0.dof + 24 + 23 + 11  # readings minus the eliminated zeros and slope
    rep = ins.summary(r)
    assert [(s["kind"], s["readings"], s["rows"]) for s in rep] == [
        ("laser", 25, 24), ("laser", 25, 23), ("step_gauge", 11, 11)]
    # each instrument's χ² about its rows (χ² with ~rows dof: within 4 sd), shares sum to
    # what the plate leaves
    for s in rep:
        assert abs(s["chi2"] - s["rows"]) < 4 * np.sqrt(2 * s["rows"])
    plate_chi2 = np.sum((r.residuals_um / r.sigma_um) ** 2)
    assert np.isclose(plate_chi2 + sum(s["chi2"] for s in rep), r.chi2, rtol=1e-9)
    res = ins.residuals_frame(r)
    assert len(res) == 61 and set(res["kind"]) == {"laser", "step_gauge"}


def test_a_fit_with_instruments_pickles_and_keeps_its_numbers():
    """The app caches fits with st.cache_data, which pickles them: the instruments' linear
    maps (Householder reflectors, diagonal weights) must be plain data, not closures (a
    laser upload failed with "Can't pickle local object" after they became closures)."""
    import pickle

    from cmm_core.model import simulate_ball_bar

    sim = _sim()
    bar = simulate_ball_bar(sim, [[300, 300, 200]], [[700, 500, 200]], seed=3)
    r = fit(sim.dataset, "kinematic21", instruments=[*_kit(sim), bar])
    back = pickle.loads(pickle.dumps(r))
    assert back.chi2 == r.chi2
    assert [s["chi2"] for s in ins.summary(back)] == [s["chi2"] for s in ins.summary(r)]


def test_a_self_calibrated_plate_gets_its_scale_from_a_step_gauge():
    """Without a certificate the plate is free and its isotropic scale a gauge freedom,
    held at the starting (mean measured, so machine-scaled) plate; a step gauge measures
    scale, so the constraint is released and the machine's positioning errors come out
    unbiased (z within 3.5), where without it they are far off (beyond 5 u)."""
    coef = {"dxx[1]": 6.0, "dyy[1]": 5.0, "dzz[1]": 3.5}  # 10 ppm on every axis (T1 + 1 = 2)
    sim = _sim(seed=7, kinematic={"coefficients": coef})
    data = dataclasses.replace(sim.dataset, certificate=None)
    sg = ins.simulate_step_gauge(sim, [100, 150, 100], [1100, 850, 400],
                                 np.arange(1, 12) * 100.0, u_um=0.3, seed=1)
    free0 = fit(data, "kinematic21")
    free = fit(data, "kinematic21", instruments=[sg])
    assert free0.plate == free.plate == "free"
    assert free.problem.constraints().shape[0] == free0.problem.constraints().shape[0] - 1
    assert free.identifiable, free.message
    for lab, true in coef.items():
        i = free.labels.index(lab)
        assert abs(free.values[i] - true) < 3.5 * free.u[i], (lab, free.values[i], free.u[i])
        assert abs(free0.values[i] - true) > 5 * free0.u[i], (lab, free0.values[i])


def test_points_outside_the_machine_are_refused():
    sim = _sim()
    run = ins.simulate_laser(sim, "x", [0, 100, 50], np.linspace(0, 1400, 8))
    with pytest.raises(DataError, match=r"row 9: the scale reading 1400.0 mm of axis x"):
        fit(sim.dataset, "kinematic21", instruments=[run])


# --- what the laser adds: predicted and Monte Carlo uncertainties ---------------------------

def test_a_laser_run_lowers_u_of_dxx_as_the_information_matrix_predicts():
    """u from (N_plate + J_laserᵀ J_laser)⁻¹ under the fit's constraints equals the joint
    fit's u; the laser divides u(dxx[1]), u(dxx[2]) of this plate by more than 4."""
    sim = _sim()
    run = ins.simulate_laser(sim, "x", [0, 100, 50], XS, u_um=0.2, seed=3)
    plate, joint, u_pred = plate_and_joint_with_predicted_u(sim, run)
    np.testing.assert_allclose(u_pred, joint.u, rtol=1e-6)
    for lab in ("dxx[1]", "dxx[2]"):
        i = joint.labels.index(lab)
        assert joint.u[i] < plate.u[plate.labels.index(lab)] / 4


def test_monte_carlo_z_scores_of_dxx_with_the_laser_are_standard():
    """100 simulations (fresh truth, plate noise, laser noise; ~6 s): the RMS of (estimate -
    truth)/u of dxx[1] and of dxx[2] is within 3.5 standard errors of 1. For N independent
    standard normal z, RMS(z) has a standard error of about 1/sqrt(2N) = 0.071."""
    z = {"dxx[1]": [], "dxx[2]": []}
    for seed in range(200, 300):
        sim = _sim(seed)
        run = ins.simulate_laser(sim, "x", [0, 100, 50], XS, u_um=0.2, seed=seed + 1000)
        r = fit(sim.dataset, "kinematic21", instruments=[run])
        for lab in z:
            i = r.labels.index(lab)
            z[lab].append((r.values[i] - sim.truth[lab]) / r.u[i])
    for lab, zs in z.items():
        rms = float(np.sqrt(np.mean(np.square(zs))))
        assert abs(rms - 1) < 3.5 / np.sqrt(2 * len(zs)), (lab, rms)


# --- the diagnosis ------------------------------------------------------------------------

def test_the_diagnosis_scores_a_candidate_the_laser_sees():
    """A cubic positioning error of x (dxx[3] = 1.5 µm) under a kinematic21 baseline: the
    score of dxx:3 with the laser run counts the laser's rows (they ride on the fit's
    observations into the augmented problems) and is far larger than without them."""
    sim = _sim(seed=4, kinematic={"spec": "kinematic21,dxx:3", "coefficients": {"dxx[3]": 1.5}})
    run = ins.simulate_laser(sim, "x", [0, 100, 50], XS, u_um=0.2, seed=8)
    base0 = fit(sim.dataset, "kinematic21")
    base = fit(sim.dataset, "kinematic21", instruments=[run])
    d0 = score(base0, "dxx:3")[0]
    d1, dk, *_ = score(base, "dxx:3")
    assert dk == 1 and d1 > 10 * max(d0, 1.0) and d1 > 100
    from cmm_core.diagnosis import diagnose

    dg = diagnose(base.problem.obs, "kinematic21", candidates=["dxx:3", "dyy:3", "plate_sag"])
    assert dg.verdict == "dxx:3", dg.message


# --- readers and the command line -----------------------------------------------------------

def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_readers_round_trip(tmp_path):
    sim = _sim()
    pos, straight, sg = _kit(sim)
    for item, write, read in ((pos, write_laser, read_laser), (sg, write_step_gauge,
                                                               read_step_gauge)):
        write(item, tmp_path / "f.csv")
        back = read(tmp_path / "f.csv")
        for f in dataclasses.fields(item):
            a, b = getattr(item, f.name), getattr(back, f.name)
            if f.name != "source":
                assert np.allclose(a, b, atol=2e-6) if isinstance(a, np.ndarray) else a == b


LASER_HEAD = "run,axis,component,x_mm,y_mm,z_mm,error_um,u_um\n"


@pytest.mark.parametrize("text,where", [
    (LASER_HEAD + "a,x,x,0,10,10,0,0.1\na,w,x,100,10,10,1,0.1\n", "row 3, column 'axis'"),
    (LASER_HEAD + "a,x,x,0,10,10,0,0.1\na,x,x,100,10,10,1,0\n", "row 3, column 'u_um'"),
    (LASER_HEAD + "a,x,x,0,10,10,0,0.1\na,x,x,100,10,10,2500,0.1\n", "row 3, column 'error_um'"),
    (LASER_HEAD + "a,x,x,0,10,10,0,0.1\na,x,x,100,12,10,1,0.1\n", "row 3, column 'y_mm'"),
    (LASER_HEAD + "a,x,y,0,10,10,0,0.1\na,x,y,100,10,10,1,0.1\n", "row 2, column 'run'"),
    (LASER_HEAD + "a,x,x,0,10,10,0,0.1\na,x,y,100,10,10,1,0.1\n", "row 3, column 'component'"),
    ("axis,x_mm,y_mm,z_mm,eror_um,u_um\nx,0,0,0,0,0.1\n", "row 1, column 'eror_um'"),
    ("axis,x_mm,y_mm,z_mm,u_um\nx,0,0,0,0.1\n", "row 1, column 'error_um'"),
])
def test_bad_laser_files_are_refused_naming_row_and_column(tmp_path, text, where):
    with pytest.raises(DataError, match="laser.csv, " + where.replace("(", r"\(")):
        read_laser(_write(tmp_path, "laser.csv", text))


SG_HEAD = "x1_mm,y1_mm,z1_mm,x2_mm,y2_mm,z2_mm,measured_mm,certified_mm,u_um"


@pytest.mark.parametrize("text,where", [
    (SG_HEAD + "\n0,0,0,100,0,0,100.0001,100,0.2\n0,0,0,200,0,0,200.0001,0.2,0.2\n",
     "row 3, column 'measured_mm'"),
    (SG_HEAD + "\n0,0,0,100,0,0,100.0001,100,0.2\n0,0,0,300,0,0,200.0001,200,0.2\n",
     "row 3, column 'measured_mm'"),
    (SG_HEAD + "\n0,0,0,100,0,0,100.0001,100,-1\n", "row 2, column 'u_um'"),
    (SG_HEAD + ",temp_C\n0,0,0,100,0,0,100.0001,100,0.2,20.5\n", "row 1, column 'temp_C'"),
    (SG_HEAD + "\n0,0,0,100,0,abc,100.0001,100,0.2\n", "row 2, column 'z2_mm'"),
])
def test_bad_step_gauge_files_are_refused_naming_row_and_column(tmp_path, text, where):
    with pytest.raises(DataError, match="sg.csv, " + where):
        read_step_gauge(_write(tmp_path, "sg.csv", text))


def test_runs_without_a_run_column_split_where_the_line_changes(tmp_path):
    text = ("axis,component,x_mm,y_mm,z_mm,error_um,u_um\n"
            + "".join(f"x,x,{x},10,10,0.1,0.1\n" for x in (0, 100, 200))
            + "".join(f"x,x,{x},10,300,0.1,0.1\n" for x in (0, 100, 200)))
    run = read_laser(_write(tmp_path, "l.csv", text))
    assert run.runs == ("run1", "run2") and list(run.run) == [0, 0, 0, 1, 1, 1]


def test_step_gauge_certified_length_is_expanded_to_the_measuring_temperature(tmp_path):
    sg = read_step_gauge(_write(tmp_path, "sg.csv", SG_HEAD + ",temp_C,cte_per_K\n"
                                "0,0,0,500,0,0,500.001,500,0.2,21,11.5e-6\n"))
    assert np.isclose(sg.certified_mm[0], 500 * (1 + 11.5e-6))


def test_cli_fit_with_laser_and_step_gauge(capsys):
    sim_dir = SAMPLE_DIR / "simulated"
    rc = main(["fit", str(sim_dir / "measurements.csv"), "--setup", str(sim_dir / "setup.json"),
               "--certificate", str(sim_dir / "certificate.csv"), "--model",
               "kinematic21,plate_sag", "--laser", str(SAMPLES / "laser_x.csv"),
               "--step-gauge", str(SAMPLES / "step_gauge.csv")])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    kinds = [s["kind"] for s in out["instruments"]]
    assert kinds == ["laser", "step_gauge"]
    assert all(0 < s["chi2_share"] < 1 and s["rows"] > 0 for s in out["instruments"])
    assert not out["fails_chi2_test"], out["message"]


def test_cli_refuses_a_bad_instrument_file(tmp_path, capsys):
    sim_dir = SAMPLE_DIR / "simulated"
    bad = _write(tmp_path, "bad.csv", LASER_HEAD + "a,x,x,0,10,10,0,0.1\na,q,x,1,1,1,1,1\n")
    rc = main(["fit", str(sim_dir / "measurements.csv"), "--setup", str(sim_dir / "setup.json"),
               "--laser", str(bad)])
    assert rc == 2
    assert "bad.csv, row 3, column 'axis'" in capsys.readouterr().err


def test_cli_diagnose_counts_the_instrument_rows(capsys):
    sim_dir = SAMPLE_DIR / "simulated"
    args = ["diagnose", str(sim_dir / "measurements.csv"), "--setup",
            str(sim_dir / "setup.json"), "--certificate", str(sim_dir / "certificate.csv")]
    assert main(args) == 0
    plain = json.loads(capsys.readouterr().out)
    assert main(args + ["--laser", str(SAMPLES / "laser_x.csv"), "--step-gauge",
                        str(SAMPLES / "step_gauge.csv")]) == 0
    joint = json.loads(capsys.readouterr().out)
    # 50 laser readings less 2 zeros and 1 slope, 11 lengths
    assert joint["baseline"]["dof"] == plain["baseline"]["dof"] + 47 + 11
    assert joint["verdict"] == plain["verdict"] == "plate_sag"  # the sample's hidden effect


def test_two_instrument_files_of_the_same_name_keep_their_own_statistics():
    """Review finding: the report grouped readings by file name, so two runs.csv from
    different folders showed one pooled RMS residual/u. Each instrument's own RMS of
    residual/u comes from its own readings."""
    from cmm_core.analysis import instrument_tables
    from cmm_core.model import fit

    sim = _sim()
    a = dataclasses.replace(ins.simulate_laser(sim, "x", [0, 100, 50], XS, u_um=0.2, seed=5),
                            source="runs.csv")
    b = dataclasses.replace(a, u_um=a.u_um * 5.0)  # the same readings, a 5x looser u
    r = fit(dataclasses.replace(select(sim.dataset), instruments=(a, b)), "kinematic21")
    table, _ = instrument_tables(ins.summary(r), ins.residuals_frame(r))
    z = table["RMS residual/u"].to_numpy()
    assert list(table["file"]) == ["runs.csv", "runs.csv"]
    # the same readings: equal residuals, so the ratio is exactly that of their u
    assert z[0] == pytest.approx(5.0 * z[1], rel=1e-9)

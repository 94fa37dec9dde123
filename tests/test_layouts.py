"""Machine layouts (docs/layouts.md): chains, sign conventions, analytic Jacobians against
finite differences, an independent first-order derivation, simulate-then-fit per layout,
and the layout carried by setups and saved models."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from cmm_core.diagnosis import diagnose
from cmm_core.export import compensate, model_from_dict, model_to_dict
from cmm_core.io import DataError, read_setup
from cmm_core.machine import (
    DEFAULT_LAYOUT,
    ERROR_NAMES,
    LAYOUTS,
    SQUARENESS,
    KinematicTerms,
    axis_of,
    forward_block,
    split_chain,
)
from cmm_core.machine import kinematics as kin
from cmm_core.model import (
    evaluate,
    fit,
    parse_spec,
    rigid_body_projector,
    simulate,
    thesis_machine_setup,
)
from cmm_core.units import UM, URAD

RANGE_MM = (1200.0, 1000.0, 700.0)
# one layout per distinct chain (the gantries share the moving bridges' chains)
CHAINS = {"moving_bridge_fxyz": "Fxyz", "moving_bridge_fyxz": "Fyxz",
          "fixed_bridge_xfyz": "xFyz", "fixed_bridge_yfxz": "yFxz",
          "horizontal_arm_fxzy": "Fxzy", "horizontal_arm_fyzx": "Fyzx"}
MOVING_TABLE = ("fixed_bridge_xfyz", "fixed_bridge_yfxz")
EXACT_PLATE = {"plate": {"form_um": 2.0, "certificate_u_um": 0.0}}


def _terms(layout, order=2, spec="kinematic21"):
    m = parse_spec(spec, default_order=order)
    return KinematicTerms(m.active, RANGE_MM, m.periods, layout)


def _setup(layout):
    raw = thesis_machine_setup()
    raw["machine"]["layout"] = layout
    return raw


# --- the list of layouts -------------------------------------------------------------

def test_every_layout_is_a_chain_of_the_three_axes_with_the_moving_bridge_first():
    assert next(iter(LAYOUTS)) == DEFAULT_LAYOUT == "moving_bridge_fxyz"
    for name, chain in LAYOUTS.items():
        assert sorted(chain) == sorted("Fxyz"), name
        table, tool = split_chain(chain)
        assert tool[-1] == "z" or name.startswith("horizontal_arm"), name
        assert bool(table) == name.startswith("fixed_bridge"), name
    assert set(CHAINS.items()) <= set(LAYOUTS.items())
    assert KinematicTerms((), RANGE_MM).layout == DEFAULT_LAYOUT


def test_unknown_layout_is_refused_with_the_list_and_a_suggestion():
    with pytest.raises(ValueError, match="did you mean 'fixed_bridge_xfyz'") as exc:
        _terms("fixed_bridge_xfy")
    assert all(name in str(exc.value) for name in LAYOUTS)
    with pytest.raises(DataError, match="did you mean 'horizontal_arm_fxzy'") as exc:
        read_setup(_setup("horizontal-arm_fxzy"))
    assert exc.value.column == "machine.layout"
    assert all(name in str(exc.value) for name in LAYOUTS)
    with pytest.raises(DataError, match="banana.*expected one of: moving_bridge_fxyz"):
        read_setup(_setup("banana"))
    for name in LAYOUTS:
        assert read_setup(_setup(name)).raw["machine"]["layout"] == name


# --- the forward model -----------------------------------------------------------------

@pytest.mark.parametrize("layout", list(LAYOUTS))
@pytest.mark.parametrize("order", [1, 3])
def test_jacobian_matches_central_differences(layout, order):
    rng = np.random.default_rng(order)
    terms = _terms(layout, order, "kinematic21,periodic_y:90")
    # Large coefficients (50 µm, 50 µrad) exercise the rotations' nonlinearity; the step
    # and tolerances are those of test_kinematics (round-off 1e-12 mm over 2h = 0.2).
    coef = rng.normal(0, 50, terms.n)
    x = rng.uniform(0, 1, (20, 3)) * RANGE_MM
    p = rng.normal(0, 100, (20, 3))
    _, J = kin.jacobian(terms, coef, x, p)
    h = 0.1
    for j in range(terms.n):
        step = np.zeros(terms.n)
        step[j] = h
        fd = (kin.model_point(terms, coef + step, x, p)
              - kin.model_point(terms, coef - step, x, p)) / (2 * h)
        np.testing.assert_allclose(J[:, :, j], fd, atol=1e-11, rtol=1e-7,
                                   err_msg=f"{layout} {terms.labels[j]}")


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_probe_jacobian_matches_central_differences_and_is_a_rotation(layout):
    rng = np.random.default_rng(4)
    terms = _terms(layout, 3)
    coef = rng.normal(0, 50, terms.n)
    x = rng.uniform(0, 1, (20, 3)) * RANGE_MM
    p = rng.normal(0, 100, (20, 3))
    Jp = kin.probe_jacobian(terms, coef, x)
    h_mm = 1e-3  # x* is linear in p up to rotation terms: the difference is exact to
    for c in range(3):  # round-off, 1e-13 mm / 2e-3 mm = 5e-11
        step = np.zeros(3)
        step[c] = h_mm
        fd = (kin.model_point(terms, coef, x, p + step)
              - kin.model_point(terms, coef, x, p - step)) / (2 * h_mm)
        np.testing.assert_allclose(Jp[:, :, c], fd, atol=1e-9)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", Jp, Jp), np.eye(3)[None] + 0 * Jp,
                               atol=1e-12)


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_invert_reaches_the_target(layout):
    rng = np.random.default_rng(5)
    terms = _terms(layout, 3)
    coef = rng.normal(0, 20, terms.n)
    s = rng.uniform(0, 1, (50, 3)) * RANGE_MM
    p = rng.normal(0, 80, (50, 3))
    x = kin.invert(terms, coef, s, p)
    assert np.abs(kin.model_point(terms, coef, x, p) - s).max() < 1e-10


def test_moving_bridge_default_is_the_thesis_model_and_the_generic_chain_reproduces_it():
    """The default evaluates thesis eq. 4.13 by its own code (unchanged); the generic chain
    evaluator on the same chain agrees to round-off, and a gantry of the same axis order
    is the same model, bit for bit."""
    rng = np.random.default_rng(6)
    terms = _terms(DEFAULT_LAYOUT, 3)
    coef = rng.normal(0, 50, terms.n)
    x = rng.uniform(0, 1, (40, 3)) * RANGE_MM
    p = rng.normal(0, 100, (40, 3))
    xs, J = kin.jacobian(terms, coef, x, p)
    xs_g, J_g = np.empty_like(xs), np.empty_like(J)
    forward_block(terms, terms.slices, coef, x, p, xs_g, J_g)
    np.testing.assert_allclose(xs_g, xs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(J_g, J, rtol=0, atol=1e-15)
    gantry = _terms("gantry_fxyz", 3)
    assert np.array_equal(kin.model_point(gantry, coef, x, p), xs)


# --- sign conventions --------------------------------------------------------------------

def _single(layout, label, value, x, p):
    terms = _terms(layout)
    coef = np.zeros(terms.n)
    coef[terms.labels.index(label)] = value
    return kin.error(terms, coef, np.atleast_2d(x), np.atleast_2d(p))[0], terms


def test_sign_conventions_of_a_moving_table():
    """A table's errors are its own motion in the foundation frame: a table displaced by
    +d moves the workpiece, so the tip lands at -d on it; a table rotation turns the
    workpiece about the table's reference point, with the lever from there to the tip,
    which holds the table's own coordinate. The same errors of a moving bridge enter with
    the opposite sign and without that coordinate in the lever."""
    x = np.array([800.0, 300.0, 200.0])
    p = np.array([20.0, -30.0, -150.0])
    tip = x + p
    # rotations are exact: the first-order expectations below are off by ε²|lever|,
    # (7 µrad)² × 0.9 m = 4e-5 µm, hence atol 1e-4 µm
    e, terms = _single("fixed_bridge_xfyz", "dxx[1]", 2.0, x, p)
    dxx = terms.design("dxx", x[:1])[0, 0] * 2.0
    np.testing.assert_allclose(e, [-dxx, 0, 0], atol=1e-9)
    e, terms = _single("fixed_bridge_xfyz", "rxz[1]", 5.0, x, p)
    yaw_rad = terms.design("rxz", x[:1])[0, 0] * 5.0 * URAD
    np.testing.assert_allclose(e, np.array([tip[1], -tip[0], 0]) * yaw_rad / UM,
                               atol=1e-4)
    e_bridge, _ = _single("moving_bridge_fxyz", "rxz[1]", 5.0, x, p)
    np.testing.assert_allclose(e_bridge, np.array([-tip[1], p[0], 0]) * yaw_rad / UM,
                               atol=1e-4)
    e, terms = _single("fixed_bridge_yfxz", "dyz[2]", 1.5, x, p)
    dyz = terms.design("dyz", x[1:2])[0, 0] * 1.5
    np.testing.assert_allclose(e, [0, 0, -dyz], atol=1e-9)
    e, terms = _single("fixed_bridge_yfxz", "ryx[1]", 5.0, x, p)
    roll_rad = terms.design("ryx", x[1:2])[0, 0] * 5.0 * URAD
    np.testing.assert_allclose(e, np.array([0, tip[2], -tip[1]]) * roll_rad / UM,
                               atol=1e-4)


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_squareness_means_the_same_in_every_layout(layout):
    """Squareness is the angle between the measured axes: sxy adds sxy*y to x, sxz*z to x,
    syz*z to y, whichever carriage moves."""
    x = np.array([400.0, 600.0, 300.0])
    p = np.array([0.0, 0.0, -100.0])
    for label, expected in (("sxy", [x[1], 0, 0]), ("sxz", [x[2], 0, 0]),
                            ("syz", [0, x[2], 0])):
        e, _ = _single(layout, label, 10.0, x, p)
        np.testing.assert_allclose(e, np.array(expected) * 10.0 * URAD / UM,
                                   atol=1e-9, err_msg=label)


# --- an independent first-order derivation (docs/layouts.md, eq. F) -------------------

def _first_order_error_um(terms, coef, x_mm, p_mm):
    """docs/layouts.md eq. (F), written from the derivation, not from the chain code:

        e = Σ_tool [ d_a + ε_a × (p + Σ_(c after a) c e_c) ]
            + Σ_table [ -d_b - ε_b × (x + p) ] + squareness,

    with d in µm, ε in rad and levers in mm, so ε × lever / UM is in µm."""
    n = len(x_mm)
    val = {}
    for name in ERROR_NAMES:
        sl = terms.slices.get(name)
        val[name] = (terms.design(name, x_mm[:, axis_of(name)]) @ coef[sl]
                     if sl is not None else np.zeros(n))
    chain = terms.chain
    f = chain.index("F")
    table, tool = chain[:f], chain[f + 1:]
    e = np.zeros((n, 3))
    for a in "xyz":
        d = np.column_stack([val[f"d{a}x"], val[f"d{a}y"], val[f"d{a}z"]])
        eps_rad = np.column_stack([val[f"r{a}x"], val[f"r{a}y"], val[f"r{a}z"]]) * 1e-6
        if a in tool:
            lever = p_mm.copy()
            for c in tool[tool.index(a) + 1:]:
                lever[:, "xyz".index(c)] += x_mm[:, "xyz".index(c)]
            e += d + np.cross(eps_rad, lever) * 1e3
        else:
            assert a in table
            e += -d - np.cross(eps_rad, x_mm + p_mm) * 1e3
    e[:, 0] += (val["sxy"] + val["sxz"]) * 1e-3  # µrad mm -> µm
    e[:, 1] += val["syz"] * 1e-3
    return e


@pytest.mark.parametrize("layout", list(CHAINS))
def test_exact_model_agrees_with_the_first_order_derivation(layout):
    """Errors of a poor machine (5 µm, 5 µrad per coefficient at order 3: functions up to
    37 µm and 25 µrad; squareness 20 µrad): the terms eq. (F) drops are products of two
    errors, ε²|lever| = (25 µrad)² × 1.8 m = 1.1e-3 µm and ε·d = 25 µrad × 57 µm =
    1.4e-3 µm per pair of carriages; 2e-3 µm is observed, 0.01 µm is the requirement."""
    rng = np.random.default_rng(7)
    terms = _terms(layout, 3)
    coef = rng.normal(0, 5, terms.n)
    for s in SQUARENESS:
        coef[terms.slices[s]] = 20.0 * rng.choice([-1, 1])
    x = rng.uniform(0, 1, (500, 3)) * RANGE_MM
    p = rng.normal(0, 100, (500, 3))
    e = kin.error(terms, coef, x, p)
    assert np.abs(e - _first_order_error_um(terms, coef, x, p)).max() < 0.01
    if layout in MOVING_TABLE:
        # the test discriminates: the same errors on a moving bridge are microns away
        bridge = KinematicTerms(terms.orders, RANGE_MM, terms.periods)
        assert np.abs(e - kin.error(bridge, coef, x, p)).max() > 5.0


# --- simulate, then fit ------------------------------------------------------------------

def _z_scores(result, truth):
    labs, vals, u = result.block("kinematic")
    return (vals - np.array([truth[lab] for lab in labs])) / u


@pytest.mark.parametrize("layout", list(CHAINS))
def test_simulate_then_fit_recovers_the_truth(layout):
    """Per layout: one simulation (seed 2) recovers all 33 coefficients within 3 u with
    χ²/dof in [0.75, 1.3]. With 33 scores a single fit has an 8 % chance of one beyond
    3 u (1 - 0.9973^33), so the statistical check is the pooled one: 30 simulations, 990
    correlated scores, whose fraction within 1 u (0.683 expected; 0.65-0.68 observed) and
    mean square (1; 1.00-1.08 observed over 60 seeds) must be those of unit normals."""
    sim = simulate({"seed": 2, "setup": _setup(layout), **EXACT_PLATE})
    r = fit(sim.dataset, "kinematic21")
    assert r.terms.layout == layout and r.status == "converged" and r.identifiable
    z = _z_scores(r, sim.truth)
    assert len(z) == 33 and np.abs(z).max() < 3, np.round(z, 2)
    assert 0.75 <= r.chi2_dof <= 1.3
    zs = []
    for seed in range(100, 130):
        sim = simulate({"seed": seed, "setup": _setup(layout), **EXACT_PLATE})
        r = fit(sim.dataset, "kinematic21")
        assert 0.75 <= r.chi2_dof <= 1.3
        zs.append(_z_scores(r, sim.truth))
    z = np.concatenate(zs)
    assert 0.6 <= np.mean(np.abs(z) <= 1) <= 0.76
    assert 0.8 <= np.mean(z**2) <= 1.25


def test_a_moving_table_fitted_as_a_moving_bridge_gets_its_errors_wrong():
    """A fixed-bridge machine (table in x) with errors of 1 µm and 5 µrad: the right layout
    recovers them; fitted as a moving bridge, the table's errors come out with the wrong
    sign and its pitch and yaw are mixed into straightness (x·ε(x) terms), tens of u from
    the truth, although χ²/dof does not show it on these placements: the plate spans
    less than half the x stroke, where the difference is mostly straightness and
    placement. The layout has to be declared; the fit cannot detect it."""
    cfg = {"seed": 3, **EXACT_PLATE, "kinematic": {"random_um": 1.0, "random_urad": 5.0}}
    sim = simulate({**cfg, "setup": _setup("fixed_bridge_xfyz")})
    right = fit(sim.dataset, "kinematic21")
    assert 0.75 <= right.chi2_dof <= 1.3
    assert np.abs(_z_scores(right, sim.truth)).max() < 3
    raw = sim.dataset.setup.raw | {"machine": {**sim.dataset.setup.raw["machine"],
                                                "layout": "moving_bridge_fxyz"}}
    wrong = fit(replace(sim.dataset, setup=read_setup(raw)), "kinematic21")
    assert wrong.terms.layout == "moving_bridge_fxyz"
    assert np.abs(_z_scores(wrong, sim.truth)).max() > 10


# --- uncertainty, diagnosis, compensation with a layout ---------------------------------

@pytest.mark.parametrize("layout", MOVING_TABLE)
def test_saved_model_carries_the_layout_and_compensates(layout):
    sim = simulate({"seed": 4, "setup": _setup(layout), **EXACT_PLATE})
    r = fit(sim.dataset, "kinematic21")
    d = model_to_dict(r)
    assert d["layout"] == layout
    m = model_from_dict(d)
    assert m.terms == r.terms
    old = {k: v for k, v in d.items() if k != "layout"}  # a file from before layouts
    assert model_from_dict(old).terms.layout == DEFAULT_LAYOUT
    with pytest.raises(DataError, match="layout 'banana' is not a known machine layout"):
        model_from_dict({**d, "layout": "banana"})
    # corrected points against the true errors of this layout
    truth = np.array([sim.truth[lab] for lab in r.terms.labels])
    rng = np.random.default_rng(4)
    obs = r.problem.obs
    x = rng.uniform((obs.r_mm - obs.p_mm).min(0), (obs.r_mm - obs.p_mm).max(0), (200, 3))
    probe = obs.probes[0]
    p = np.broadcast_to(sim.dataset.setup.probes[probe], x.shape)
    pts = pd.DataFrame(x + p, columns=["x_mm", "y_mm", "z_mm"]).assign(probe=probe)
    out = compensate(m, pts)
    e_fit = out[["ex_um", "ey_um", "ez_um"]].to_numpy()
    e_true = kin.error(r.terms, truth, x, p)
    # up to a rigid motion (placements are free): compare point-to-point differences
    diff = rigid_body_projector(x) @ (e_fit - e_true).ravel()
    assert np.sqrt(np.mean(diff**2)) < 0.2
    assert np.isfinite(out[["u_x_um", "u_y_um", "u_z_um"]].to_numpy()).all()


def test_uncertainty_and_diagnosis_follow_the_layout():
    layout = "fixed_bridge_yfxz"
    sim = simulate({"seed": 1, "setup": _setup(layout), **EXACT_PLATE})
    r = fit(sim.dataset, "kinematic21")
    s = evaluate(r, n_random=50)
    assert s.U2_um is not None and s.U3_um is not None, s.message
    u_um = [v for d in (s.U2_um, s.U3_um) for v in d.values()]
    assert np.isfinite(u_um).all() and 0 < min(u_um) and max(u_um) < 5
    hidden = simulate({"seed": 1, "setup": _setup(layout), **EXACT_PLATE,
                       "kinematic": {"coefficients": {"ryx[1]": 5.0, "ryx[2]": 2.0}}})
    d = diagnose(hidden.dataset, "kinematic21,-ryx")  # the table's roll, left out
    assert d.verdict == "ryx", [(c.effect, round(c.delta_bic, 1)) for c in d.candidates[:4]]

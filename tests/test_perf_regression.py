"""Regression pins of the fit through the performance work of issue 25.

The reference values below were computed at commit 5ede1e1 (before the fit's speed-ups:
cached Chebyshev bases and block sub-problems, the coefficient-major kinematic Jacobian,
``select`` by factorised codes, the certificate terms from the fit's own normal
equations) by ``fit`` on the thesis tables (``thesis_dataset``, the flagged blunders of
``detect_outliers`` excluded) in the three plate modes and with three effect blocks, and
on a seeded simulation of 9000 observations (more than ``normal.ROWS``: the blocked
accumulation).

Only the order of floating-point sums changes (the normal equations agree to 6e-16 of
their scaled entries), but the fit's result is not that stable: at 5ede1e1 itself,
σ multiplied by (1 + 4e-16) moves the fixed-plate values by up to 1.1e-8 of their u
(4.7e-7 relative for a value near zero), through the Gauss-Newton stop at ``tol`` = 1e-9
of the cost. So values are pinned to 1e-6 of their u (100 times that), uncertainties and
residuals to 1e-7 relative, χ² (stationary at the solution) to 1e-9 relative.
"""


import dataclasses

import numpy as np
import pytest

from cmm_core.model import Normal, Plate, Problem, fit, parse_spec, select, simulate
from cmm_core.model import normal as normal_module
from cmm_core.model.certificate_prior import certificate_terms

NAN = float("nan")  # u of a parameter the design cannot determine

SPECS = {"fixed": ("kinematic21", "fixed"), "prior": ("kinematic21", "prior"),
         "free": ("kinematic21", "free"),
         "effects": ("kinematic21,plate_thermal,drift,probe_offset", None)}

REFERENCE = {
    'fixed': {
        'chi2': 16631.759980120525, 'chi2_test': 7662.185042249021, 'rank': 69, 'iterations': 3,
        'residuals_um': [[-0.43445434079103507, -1.1156167913952686, -8.227279652516284], [-0.557736089831451, -2.141357944765332, -1.1806651996124629], [-0.17521801771636092, -1.1954870897170622, 3.345763728361817]],
        'values': {
            'dxx[1]': (-10.15545666300527, 0.9937153612003043),
            'dxx[2]': (-10.072503672029153, 1.8719198764225047),
            'dyx[2]': (-2.738279658601552, 0.5134070347208698),
            'rzz[1]': (-57.22209475005782, 4.1989503645371355),
            'ryx[2]': (-4.048828472719046, 1.1268037403201332),
            'sxy': (57.77135683420117, 6.150548232657382),
            'syz': (1.8877572521406067, 2.279192819915582),
            'BP111.rz': (2.6422306777607734, 0.6455657222595573),
        }},
    'prior': {
        'chi2': 7662.1784430958005, 'chi2_test': 7662.1784430958005, 'rank': 137, 'iterations': 3,
        'residuals_um': [[-0.5548716952716859, 0.06308741816951624, -7.084532285108348], [-1.1428506026049945, -1.7251772840722879, -0.8416957241621503], [-0.36999060807829665, -0.8817627298185471, 1.24959052561735]],
        'values': {
            'dxx[1]': (-10.380821142722981, 0.7167275628123259),
            'dxx[2]': (-8.380667165957334, 1.3797061307001823),
            'dyx[2]': (-0.4763179842645387, 0.4173957980550607),
            'rzz[1]': (-53.52360932491194, 3.9943020868222927),
            'ryx[2]': (-4.783359181758273, 1.0358610850408774),
            'sxy': (41.27359751718423, 4.541134425932055),
            'syz': (1.1602778100681945, 2.059105070746969),
            'BP111.rz': (1.1381102193268908, 0.5018119120597786),
        }},
    'free': {
        'chi2': 4862.892691979194, 'chi2_test': 4862.892691979194, 'rank': 137, 'iterations': 3,
        'residuals_um': [[-0.7805965090028621, -0.12547514302241325, -5.768332171204458], [-1.406347793022178, -1.2086131139881218, -0.24791723059536253], [-0.9800749483019899, -1.2366747914711596, 0.6952740654924128]],
        'values': {
            'dxx[1]': (-9.405634558931563, 0.8684655988240777),
            'dxx[2]': (-3.759794945889137, 1.5263023703192045),
            'dyx[2]': (0.7238825501639984, 0.4477305802085667),
            'rzz[1]': (-62.82999297799932, 4.148202804752199),
            'ryx[2]': (-5.084550463849677, 1.052320831127579),
            'sxy': (16.827314334930303, 4.963513105831204),
            'syz': (-0.6491624222924302, 2.095741283150026),
            'BP111.rz': (2.494045627725418, 0.54822642362234),
        }},
    'effects': {
        'chi2': 15204.141574979356, 'chi2_test': 6726.813826107556, 'rank': 82, 'iterations': 3,
        'residuals_um': [[-0.9189700975665538, -0.9907490571610582, -8.885070289394935], [-0.009872527332221992, -1.467438269879075, -1.0094910198927103], [0.5005211692603524, -2.0887466790336013, 4.242977256830237]],
        'values': {
            'dxx[1]': (-4.3592745938096655, 1.491539634601574),
            'dxx[2]': (-8.585194491855301, 1.8871113150364849),
            'dyx[2]': (-2.790425726525485, 0.5149386052142131),
            'rzz[1]': (54.33536497535991, NAN),
            'ryx[2]': (-0.06228224839220843, 1.4900910426433787),
            'sxy': (87.57042078727179, 10.79672259513176),
            'syz': (150.4506890917702, NAN),
            'BP111.rz': (6.342359398985055, 2.2865535909950196),
        }},
    'sim': {
        'chi2': 27478.055682892078, 'chi2_test': 26690.20352632665, 'rank': 69, 'iterations': 2,
        'residuals_um': [[0.19809198749953794, 1.2524609304023215, 0.8047554882197849], [0.4801811894594721, 0.5552712154894834, 0.32705811079493236], [-0.37813864832969557, -0.00038941982438700506, -0.16445929304609308]],
        'values': {
            'dxx[1]': (-0.7601777981216846, 0.19980523880680656),
            'dxx[2]': (1.1532239416023347, 0.3336372310022244),
            'dyx[2]': (-1.7734996006282864, 0.07675368815021376),
            'rzz[1]': (0.7754459791806878, 0.29181135664867064),
            'ryx[2]': (-1.2337095549400299, 0.13051745663566522),
            'sxy': (0.9122167994304594, 1.0776655066323975),
            'syz': (0.7424710699161352, 0.25099893628971603),
            'BP111.rz': (-0.01676265980006967, 0.10728919278943731),
        }},
}


TOL = 1e-9
"""The fit's stop (``fit(tol=...)``'s default): it ends when the predicted decrease of χ²
is below ``TOL·χ²``."""


def _check(r, ref):
    """The fit against the values before the speed-ups, to what the solver's stop leaves
    open. Two correct implementations (or one on two CPUs: other BLAS kernels, other
    summation orders) agree on χ² to the stop, ``TOL·χ²``; the whitened residual vector of
    their minima to ``√(TOL·χ²)`` (the distance the stop leaves to the minimum), so every
    residual to ``σ·√(TOL·χ²)`` µm, every determined parameter to ``√(TOL·χ²)`` of its u
    and u itself relatively (N is linearised that close); an undetermined parameter
    (u = NaN, the minimum-norm solution's component) relative to itself."""
    assert r.rank == ref["rank"] and r.iterations == ref["iterations"]
    np.testing.assert_allclose([r.chi2, r.chi2_test], [ref["chi2"], ref["chi2_test"]],
                               rtol=TOL)
    s = np.sqrt(TOL * max(ref["chi2"], 1.0))
    np.testing.assert_allclose(r.residuals_um[[0, 100, -1]], ref["residuals_um"], rtol=0,
                               atol=r.sigma_um * s)
    value, u = np.array(list(ref["values"].values())).T
    got = np.array([(r.values[r.labels.index(lab)], r.u[r.labels.index(lab)])
                    for lab in ref["values"]])
    scale = np.where(np.isnan(u), np.abs(value), u)
    assert np.all(np.abs(got[:, 0] - value) <= s * scale), (got[:, 0] - value) / scale
    np.testing.assert_allclose(got[:, 1], u, rtol=s, equal_nan=True)


@pytest.mark.parametrize("tag", list(SPECS))
def test_thesis_fits_match_the_values_before_the_speed_ups(thesis_clean, tag):
    data, exclusions = thesis_clean
    spec, plate = SPECS[tag]
    _check(fit(data, spec, plate=plate, exclude=exclusions), REFERENCE[tag])


def test_blocked_simulated_fit_matches_the_values_before_the_speed_ups():
    _check(fit(simulate({"seed": 3, "repeats": 30}).dataset, "kinematic21"),
           REFERENCE["sim"])


@pytest.mark.parametrize("shuffled", [False, True])
@pytest.mark.parametrize("plate", ["fixed", "prior", "free"])
def test_normal_equations_do_not_depend_on_the_block_size(thesis_clean, plate, shuffled):
    """The blocked accumulation equals one block of every row, with the observations in
    file order (blocks are runs of one placement: views) and shuffled (runs of one row:
    the blocks' rows are picked from the table)."""
    data, exclusions = thesis_clean
    if shuffled:
        order = np.random.default_rng(7).permutation(len(data.meas))
        data = dataclasses.replace(data, meas=data.meas.iloc[order].reset_index(drop=True))
    prob = Problem(select(data, exclude=exclusions), parse_spec("kinematic21,drift"), plate)
    state = prob.initial_state()
    whole = normal_module.accumulate(prob, state, 0.5, rows=10**6)
    for rows in (37, 100):
        for _ in range(2):  # the second call reuses the problem's block order
            part = normal_module.accumulate(prob, state, 0.5, rows=rows)
            np.testing.assert_allclose(part.N, whole.N, rtol=1e-12,
                                       atol=1e-12 * np.abs(whole.N).max())
            np.testing.assert_allclose(part.g, whole.g, rtol=1e-12,
                                       atol=1e-12 * np.abs(whole.g).max())
            np.testing.assert_allclose(part.d, whole.d, rtol=0, atol=1e-12)
            assert part.rows == whole.rows
            assert part.cost == pytest.approx(whole.cost, rel=1e-12)


def test_normal_columns_are_those_of_the_full_accumulation(thesis_clean):
    """The certificate's plate columns (``normal._normal_columns``) equal the same
    columns of the prior problem's full normal equations (without its prior rows)."""
    data, exclusions = thesis_clean
    prob = Problem(select(data, exclude=exclusions), parse_spec("kinematic21"), "prior")
    state = prob.initial_state()
    whole = normal_module.accumulate(prob, state, 0.5, rows=100)
    rp, Jp = prob.block(Plate).prior_rows(state, True)
    Jp = Jp.toarray()
    s = prob.layout.blocks["plate"]
    cols = np.arange(s.start, s.stop)
    # blocks along the balls (one ball's columns in every row) and along the placements
    # (every ball's: the sparse rows), as the certificate cuts them
    for key in (None, prob.obs.pos):
        Nc, gc = normal_module._normal_columns(prob, state, 0.5, cols, rows=100, key=key)
        np.testing.assert_allclose(Nc, (whole.N - Jp.T @ Jp)[:, cols], rtol=1e-12,
                                   atol=1e-12 * np.abs(whole.N).max())
        np.testing.assert_allclose(gc, (whole.g - Jp.T @ rp)[cols], rtol=1e-12,
                                   atol=1e-12 * np.abs(whole.g).max())


def test_certificate_terms_from_the_fit_equal_a_second_accumulation(thesis_clean):
    """The certificate's χ² test and covariance from the fit's last accumulation (its plate
    columns kept beside it) equal those of the prior problem accumulated afresh."""
    data, exclusions = thesis_clean
    r = fit(data, "kinematic21", exclude=exclusions)
    prob, state = r.problem, r.state
    # whether the fit's own last accumulation was at its final state depends on its path
    # (a last step within the stop is evaluated for its cost alone, and other BLAS kernels
    # can put a step on either side of the stop): accumulating there keeps the columns
    ne = prob.normal_equations(state, r.sigma_um)
    assert normal_module._plate_cross(prob, state) is not None
    held = r.design_null
    fast = certificate_terms(prob, state, held, r.sigma_um, r.rank_rtol, r.covariance_noise,
                             normal=(ne.cost, ne.N, ne.g, ne.rows))
    slow = certificate_terms(prob, state, held, r.sigma_um, r.rank_rtol, r.covariance_noise)
    assert fast[1] == slow[1]
    assert fast[0] == pytest.approx(slow[0], rel=1e-10)
    np.testing.assert_allclose(fast[2], slow[2], rtol=1e-9, atol=1e-12 * np.abs(slow[2]).max())


def test_cost_alone_does_not_depend_on_the_block_size(thesis_clean):
    """``cost_of`` evaluated block by block (the fit's last step on large data) equals one
    evaluation of every row."""
    data, exclusions = thesis_clean
    prob = Problem(select(data, exclude=exclusions), parse_spec("kinematic21,drift"), "prior")
    state = prob.initial_state()
    d_whole, cost_whole = normal_module.cost_of(prob, state, 0.5, rows=10**6)
    d_part, cost_part = normal_module.cost_of(prob, state, 0.5, rows=37)
    np.testing.assert_allclose(d_part, d_whole, rtol=0, atol=1e-12)
    assert cost_part == pytest.approx(cost_whole, rel=1e-12)
    assert cost_whole == pytest.approx(normal_module.accumulate(prob, state, 0.5).cost,
                                       rel=1e-12)


def test_a_last_step_taken_for_its_cost_alone_leaves_the_uncertainties():
    """When the fit's last step is evaluated for its cost alone (its predicted decrease is
    below the stop), the covariance and the certificate's χ² come from the linearisation
    one step back: they equal those of a fresh accumulation at the solution to far below
    any reported digit (1e-9 relative; the step moves the cost by < 1e-9 of itself)."""
    r = fit(simulate({"seed": 3, "repeats": 30}).dataset, "kinematic21")
    prob, state = r.problem, r.state
    # this fit ends so (its solution is not where its normal equations were taken)
    assert normal_module._plate_cross(prob, state) is None
    ne = prob.normal_equations(state, r.sigma_um)
    fresh = certificate_terms(prob, state, r.design_null, r.sigma_um, r.rank_rtol,
                              r.covariance_noise, normal=(ne.cost, ne.N, ne.g, ne.rows))
    assert r.chi2 == pytest.approx(ne.cost, rel=1e-12)
    # the σ-only covariance itself against the one of a fresh linearisation at the
    # solution (1.8e-11 relative measured)
    C = np.vstack([prob.constraints(), r.design_null])
    cov_fresh = Normal(None, None, C, r.rank_rtol, normal=(ne.N, ne.g)).cov()
    np.testing.assert_allclose(r.covariance_noise, cov_fresh, rtol=1e-9,
                               atol=1e-9 * np.abs(cov_fresh).max())
    assert r.chi2_test == pytest.approx(fresh[0], rel=1e-9)
    np.testing.assert_allclose(r.covariance, fresh[2], rtol=1e-9,
                               atol=1e-9 * np.abs(fresh[2]).max())

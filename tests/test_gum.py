"""GUM framework and GUM-S1 Monte Carlo against the published JCGM examples.

References
----------
- JCGM 100:2008 (GUM), example H.1 (end-gauge calibration), table H.1: u_c = 32 nm,
  nu_eff = 16, U99 = t_99(16) u_c = 2.92 x 32 nm = 93 nm; table G.2 for t_p(nu).
- JCGM 101:2008 (GUM-S1) 9.2, additive model Y = X1 + X2 + X3 + X4: 9.2.2 normal inputs
  N(0, 1): u(y) = 2.00, 95 % interval [-3.92, 3.92]; 9.2.3 rectangular inputs with
  standard deviation 1: u(y) = 2.00, interval [-3.88, 3.88] (10^6 trials).
"""

import math
import time

import numpy as np
import pytest
from scipy import stats

from cmm_core.gum import (
    Contribution,
    budget_from_dict,
    coverage_factor,
    coverage_intervals,
    gum_combine,
    half_width_divisor,
    monte_carlo,
)

# JCGM 100 table H.1 (nm, °C): u(x_i), c_i, nu_i. c(δα) = -l_s θ = -50 mm x (-0.1 °C)
# = 5e6 nm °C; c(δθ) = -l_s α_s = -50e6 nm x 11.5e-6 /°C = -575 nm/°C; α_s and θ have c = 0.
H1 = [
    Contribution("l_s calibration of standard", 25.0, dof=18),
    Contribution("d measured difference", 9.7, dof=25.6),
    Contribution("alpha_s", 1.2e-6, c=0.0),
    Contribution("theta", 0.41, c=0.0),
    Contribution("delta_alpha", 0.58e-6, "rectangular", c=5.0e6, dof=50),
    Contribution("delta_theta", 0.029, "rectangular", c=-575.0, dof=2),
]


def test_gum_h1_end_gauge_table():
    g = gum_combine(H1, coverage_probability=0.99)
    # GUM quotes u_c = 32 nm (2 significant digits): sqrt(25² + 9.7² + 2.9² + 16.7²) = 31.7
    assert round(g.u_c) == 32
    assert g.u_c == pytest.approx(31.71, abs=0.01)
    # GUM: nu_eff = 16 (eq. G.2b gives 16.7, truncated to the next lower integer, G.4.1)
    assert 16 < g.nu_eff < 17
    assert g.nu_used == 16
    assert g.k == pytest.approx(2.92, abs=0.005)          # table G.2: t_99(16) = 2.92
    # GUM multiplies the rounded u_c: 2.92 x 32 = 93 nm; unrounded u_c gives 92.6 nm, so
    # the tolerance is the rounding of u_c to 2 digits (±0.5 nm x 2.92 = ±1.5 nm).
    assert g.U == pytest.approx(93.0, abs=1.5)
    assert g.shares.sum() == pytest.approx(1.0, rel=1e-12)
    assert g.shares[0] == pytest.approx(25.0**2 / g.u_c**2)


def test_gum_h1_with_measurement_function_numerical_derivatives():
    # l = l_s + d - l_s (δα θ + α_s δθ), JCGM 100 eq. H.3 (nm); estimates of H.1.
    ls = 50_000_623.6

    def f(l_s, d, alpha_s, theta, dalpha, dtheta):
        return l_s + d - l_s * (dalpha * theta + alpha_s * dtheta)

    cts = [Contribution("l_s", 25.0, dof=18, value=ls),
           Contribution("d", 9.7, dof=25.6, value=215.0),
           Contribution("alpha_s", 1.2e-6, value=11.5e-6),
           Contribution("theta", 0.41, value=-0.1),
           Contribution("delta_alpha", 0.58e-6, "rectangular", dof=50, value=0.0),
           Contribution("delta_theta", 0.029, "rectangular", dof=2, value=0.0)]
    g = gum_combine(cts, function=f, coverage_probability=0.99)
    assert g.y == pytest.approx(50_000_838.6, abs=0.01)   # GUM: l = 50.000 838 mm
    # c_i exact for this bilinear model (central difference); tolerance = float rounding
    np.testing.assert_allclose(g.c, [1.0, 1.0, 0.0, 0.0, ls * 0.1, -ls * 11.5e-6],
                               rtol=1e-6, atol=1e-6)
    assert g.u_c == pytest.approx(31.7, abs=0.05)
    assert g.nu_used == 16


def test_divisors_and_coverage_factors():
    # JCGM 100 4.3.7 (sqrt 3), 4.3.9 (sqrt 6), JCGM 101 6.4.6 (arc sine, sqrt 2)
    assert half_width_divisor("rectangular") == pytest.approx(math.sqrt(3), rel=1e-12)
    assert half_width_divisor("triangular") == pytest.approx(math.sqrt(6), rel=1e-12)
    assert half_width_divisor("u_shaped") == pytest.approx(math.sqrt(2), rel=1e-12)
    assert coverage_factor(0.95) == pytest.approx(1.96, abs=0.005)            # table G.2
    assert coverage_factor(0.95, 10) == pytest.approx(2.23, abs=0.005)        # table G.2
    assert coverage_factor(0.9545, 2) == pytest.approx(4.53, abs=0.005)       # table G.2
    with pytest.raises(ValueError, match="coverage_probability"):
        coverage_factor(1.2)


def test_contribution_validation():
    with pytest.raises(ValueError, match="distribution"):
        Contribution("a", 1.0, "gauss")
    with pytest.raises(ValueError, match="u: expected a standard uncertainty >= 0"):
        Contribution("a", -1.0)
    with pytest.raises(ValueError, match="dof"):
        Contribution("a", 1.0, dof=0)
    with pytest.raises(ValueError, match="needs its coverage factor"):
        Contribution.from_half_width("a", 1.0, "normal")
    assert Contribution.from_half_width("a", 2.0, "normal", k=2).u == 1.0
    with pytest.raises(ValueError, match=r"contributions\[0\]\.c"):
        gum_combine([Contribution("a", 1.0, c=2.0)], function=lambda a: a)


def test_coverage_intervals_order_statistics():
    ys = np.arange(1.0, 101.0)           # M = 100, p = 0.9 -> q = 90
    sym, short = coverage_intervals(ys, 0.9)
    assert sym == (5.0, 95.0)             # r = (M - q)/2 = 5 -> [y_(5), y_(95)] 1-based
    assert short[1] - short[0] == 90.0
    skew = np.sort(np.r_[np.zeros(95), np.linspace(1, 50, 5)])
    _, short = coverage_intervals(skew, 0.9)
    assert short == (0.0, 0.0)


# JCGM 101 9.2 reproduced with M = 10^6 trials. Standard errors at M = 10^6 (measured over
# 12 seeds): symmetric-interval endpoints 0.005, shortest-interval endpoints 0.023 (the
# shortest interval of a symmetric PDF is flat in its position), its length 0.008, and
# u(y) 2/sqrt(2M) = 0.0014. Tolerances are 4 standard errors plus the 0.005 rounding of the
# published 3-digit values.
@pytest.mark.parametrize("dist,half,u_ref,end_ref", [
    ("normal", None, 2.00, 3.92),
    ("rectangular", math.sqrt(3.0), 2.00, 3.88),
])
def test_jcgm101_additive_model(dist, half, u_ref, end_ref):
    if half is None:
        cts = [Contribution(f"X{i}", 1.0, dist) for i in range(1, 5)]
    else:
        cts = [Contribution.from_half_width(f"X{i}", half, dist) for i in range(1, 5)]
    g = gum_combine(cts)
    assert g.u_c == pytest.approx(2.0, rel=1e-12)
    assert g.U == pytest.approx(3.92, abs=0.005)       # GUF interval in JCGM 101 9.2.2/9.2.3
    mc = monte_carlo(cts, trials=1_000_000, seed=20081)
    assert mc.status == "ok" and mc.trials == 1_000_000
    assert mc.mean == pytest.approx(0.0, abs=4 * 2.0 / 1000 + 0.005)
    assert mc.u == pytest.approx(u_ref, abs=0.006 + 0.005)
    lo, hi = mc.interval_symmetric
    assert lo == pytest.approx(-end_ref, abs=0.025) and hi == pytest.approx(end_ref, abs=0.025)
    lo, hi = mc.interval_shortest
    assert hi - lo == pytest.approx(2 * end_ref, abs=0.04)
    assert lo == pytest.approx(-end_ref, abs=0.1) and hi == pytest.approx(end_ref, abs=0.1)
    assert mc.hist_counts.sum() > 0.99 * mc.trials


def test_rectangular_distinguished_from_normal():
    """The 3.88 vs 3.92 difference of JCGM 101 9.2.3 is resolved (same seed, 10^6 trials)."""
    rect = [Contribution.from_half_width(f"X{i}", math.sqrt(3.0)) for i in range(4)]
    norm = [Contribution(f"X{i}", 1.0) for i in range(4)]
    hi_r = monte_carlo(rect, trials=1_000_000, seed=5).interval_symmetric[1]
    hi_n = monte_carlo(norm, trials=1_000_000, seed=5).interval_symmetric[1]
    assert hi_n - hi_r == pytest.approx(0.04, abs=0.02)


def test_adaptive_jcgm101_7_9():
    cts = [Contribution(f"X{i}", 1.0) for i in range(4)]
    mc = monte_carlo(cts, adaptive=True, n_dig=2, seed=3)
    assert mc.status == "converged"
    assert mc.tolerance == pytest.approx(0.05)         # u = 2.0 to 2 digits: delta = 0.05
    assert mc.trials % 10_000 == 0 and mc.trials >= 20_000     # h >= 2 sequences of 10^4
    assert mc.u == pytest.approx(2.0, abs=mc.tolerance)
    assert mc.interval_shortest[1] == pytest.approx(3.92, abs=2 * mc.tolerance)
    fine = monte_carlo(cts, adaptive=True, n_dig=3, seed=3, max_trials=20_000)
    assert fine.status == "max_trials" and fine.trials == 20_000


def test_progress_and_cancel():
    cts = [Contribution("a", 1.0), Contribution.from_half_width("b", 1.0, "triangular")]
    seen = []
    mc = monte_carlo(cts, trials=100_000, chunk_size=10_000, seed=1, progress=seen.append)
    assert seen == pytest.approx([i / 10 for i in range(1, 11)])
    assert mc.status == "ok"
    calls = []

    def cancel_after_three(fraction):
        calls.append(fraction)
        return len(calls) < 3

    part = monte_carlo(cts, trials=100_000, chunk_size=10_000, seed=1,
                       progress=cancel_after_three)
    assert part.status == "cancelled" and part.trials == 30_000
    assert part.u == pytest.approx(math.sqrt(1 + 1 / 6), rel=0.03)
    ad = monte_carlo(cts, adaptive=True, seed=1, chunk_size=10_000, progress=lambda f: False)
    assert ad.status == "cancelled" and ad.trials == 10_000     # one sequence done


def test_reproducible_and_function_model():
    cts = [Contribution("x1", 0.1, value=2.0), Contribution("x2", 0.2, value=3.0)]
    a = monte_carlo(cts, function=lambda x1, x2: x1 * x2, trials=200_000, seed=9)
    b = monte_carlo(cts, function=lambda x1, x2: x1 * x2, trials=200_000, seed=9)
    assert a.mean == b.mean and a.interval_shortest == b.interval_shortest
    # product of independent normals: Var = m1² s2² + m2² s1² + s1² s2² = 0.2504;
    # tolerance 5 standard errors u/sqrt(2M) = 0.0008
    assert a.u == pytest.approx(math.sqrt(0.2504), abs=0.004)
    assert a.mean == pytest.approx(6.0, abs=5 * 0.5 / math.sqrt(200_000))
    g = gum_combine(cts, function=lambda x1, x2: x1 * x2)
    assert g.u_c == pytest.approx(0.5, rel=1e-9)       # first order: sqrt(0.09 + 0.16)
    with pytest.raises(ValueError, match="vectorised"):
        monte_carlo(cts, function=lambda x1, x2: 1.0, trials=10, seed=1)


def test_student_t_inputs_jcgm101_6_4_9():
    cts = [Contribution("a", 1.0, dof=4)]
    mc = monte_carlo(cts, trials=400_000, seed=2, student_t_for_finite_dof=True)
    # t_4 scaled by u has standard deviation sqrt(4/2) = 1.414; its 97.5 % point 2.776
    assert mc.u == pytest.approx(math.sqrt(2.0), rel=0.03)
    assert mc.interval_symmetric[1] == pytest.approx(stats.t.ppf(0.975, 4), abs=0.03)


def test_one_million_trials_fast():
    cts = [Contribution("a", 1.0), Contribution.from_half_width("b", 1.0),
           Contribution.from_half_width("c", 1.0, "triangular"),
           Contribution.from_half_width("d", 1.0, "u_shaped")]
    monte_carlo(cts, trials=10_000, seed=0)
    t = time.perf_counter()
    monte_carlo(cts, trials=1_000_000, seed=0)
    assert time.perf_counter() - t < 2.0


def test_budget_from_dict_spec_contract():
    d = {"contributions": [
        {"name": "rep", "u": 0.3, "distribution": "normal", "c": 1, "dof": 9},
        {"name": "res", "half_width": 0.05, "distribution": "rectangular"},
        {"name": "temp", "half_width": 0.5, "distribution": "u_shaped", "c": -8.6, "dof": None},
        {"name": "cal", "half_width": 0.4, "distribution": "normal", "k": 2},
    ], "coverage_probability": 0.95, "monte_carlo_trials": 50_000, "seed": 4}
    out = budget_from_dict(d)
    u = [0.3, 0.05 / math.sqrt(3), 8.6 * 0.5 / math.sqrt(2), 0.2]
    assert out["u_c"] == pytest.approx(math.sqrt(sum(x * x for x in u)), rel=1e-12)
    assert sum(c["share"] for c in out["contributions"]) == pytest.approx(1.0)
    assert out["nu_eff"] > 9          # W-S: dominated by the infinite-dof temperature term
    assert out["k"] == pytest.approx(stats.t.ppf(0.975, math.floor(out["nu_eff"])), rel=1e-12)
    assert out["U"] == pytest.approx(out["k"] * out["u_c"])
    assert set(out["mc"]) >= {"mean", "u", "interval"} and out["mc"]["trials"] == 50_000
    assert out["mc"]["u"] == pytest.approx(out["u_c"], rel=0.02)
    assert "mc" not in budget_from_dict({"contributions": d["contributions"]})
    assert budget_from_dict({"contributions": [{"u": 1.0}]})["nu_eff"] is None


@pytest.mark.parametrize("bad,match", [
    ([], "budget: expected a JSON object"),
    ({"contributions": []}, "contributions: expected a non-empty list"),
    ({"contributions": [{"name": "a"}]}, r"contributions\[0\].*exactly one of 'u' or"),
    ({"contributions": [{"u": 1}, {"u": "x"}]}, r"contributions\[1\].*\.u: expected a number"),
    ({"contributions": [{"u": 1, "half_width": 2}]}, "got both"),
    ({"contributions": [{"u": 1, "distribution": "gauss"}]}, r"\.distribution: expected one"),
    ({"contributions": [{"half_width": 1, "distribution": "normal"}]}, "needs 'k'"),
    ({"contributions": [{"u": -1}]}, r"\.u: expected a number >= 0"),
    ({"contributions": [{"u": 1, "dof": 0}]}, r"\.dof: expected a positive number"),
    ({"contributions": [{"u": 1, "sigma": 2}]}, "unknown field"),
    ({"contributions": [{"u": 1}], "coverage_probability": 95}, "coverage_probability"),
    ({"contributions": [{"u": 1}], "monte_carlo_trials": 1.5}, "monte_carlo_trials"),
])
def test_budget_from_dict_errors(bad, match):
    with pytest.raises(ValueError, match=match) as err:
        budget_from_dict(bad)
    assert "\n" not in str(err.value)


"""Correlated inputs of a GUM budget (JCGM 100:2008 5.2, eq. 13, 14 and 16).

``u_c² = Σ c_i² u_i² + 2 Σ_{i<j} c_i c_j u_i u_j r_ij``. Checked against the formula by
hand, against a Monte Carlo written here with numpy (multivariate Gaussian, 10⁶ draws) and
through the product's own Monte Carlo (JCGM 101 6.4.8); the validation at the entry (names,
range of r, positive semidefinite matrix) and the budget JSON's ``correlations``. The GTC
cross-check of the same models is in tests/test_gum_gtc.py.

Monte Carlo tolerance: the standard deviation of N normal draws has standard error
``u / sqrt(2 (N - 1))`` (0.07 % at N = 10⁶); the tests allow 5 of them. The models below are
bilinear with a second-order variance term ``(α l u(l) u(θ))²`` below 1e-12 of u_c², so the
first-order u_c is the Monte Carlo's target.
"""

import math

import numpy as np
import pytest

from cmm_core.gum import (
    Contribution,
    ballplate_budget,
    budget_from_dict,
    budget_spec_dict,
    correlation_matrix,
    gum_combine,
    monte_carlo,
)

N_MC = 1_000_000
ALPHA = 11.5e-6
L_A_UM, L_B_UM = 100_000.0, 250_000.0
TWO_LENGTHS = [Contribution("l_a", 0.10, value=L_A_UM), Contribution("l_b", 0.15, value=L_B_UM),
               Contribution("theta_a", 0.02, value=0.5), Contribution("theta_b", 0.03, value=0.3)]


def lengths(sign):
    """``Y = l_a (1 - α θ_a) ± l_b (1 - α θ_b)`` (µm): two lengths, one thermometer certificate."""
    def f(l_a, l_b, th_a, th_b):
        return l_a * (1 - ALPHA * th_a) + sign * l_b * (1 - ALPHA * th_b)
    return f


@pytest.mark.parametrize("sign", [1, -1], ids=["sum", "difference"])
@pytest.mark.parametrize("r", [0.8, -0.5, 1.0])
def test_law_of_propagation_with_correlation_eq16(r, sign):
    g = gum_combine(TWO_LENGTHS, function=lengths(sign),
                    correlations={("theta_a", "theta_b"): r})
    c = np.array([1 - ALPHA * 0.5, sign * (1 - ALPHA * 0.3), -ALPHA * L_A_UM,
                  -sign * ALPHA * L_B_UM])
    u = np.array([0.10, 0.15, 0.02, 0.03])
    by_hand = np.sum((c * u) ** 2) + 2 * c[2] * c[3] * u[2] * u[3] * r     # JCGM 100 eq. 16
    assert g.u_c == pytest.approx(math.sqrt(by_hand), rel=1e-9)
    assert g.shares.sum() + g.correlation_share == pytest.approx(1.0, rel=1e-12)
    independent = gum_combine(TWO_LENGTHS, function=lengths(sign))
    assert not independent.correlated and independent.correlation_share == 0.0
    # positive r between inputs whose sensitivities have equal signs adds variance
    assert (g.u_c > independent.u_c) == (r * c[2] * c[3] > 0)


@pytest.mark.parametrize("sign", [1, -1], ids=["sum", "difference"])
@pytest.mark.parametrize("r", [0.8, -0.5, 1.0])
def test_correlated_budget_against_numpy_monte_carlo(r, sign):
    g = gum_combine(TWO_LENGTHS, function=lengths(sign),
                    correlations={("theta_a", "theta_b"): r})
    x = np.array([ct.value for ct in TWO_LENGTHS])
    u = np.array([ct.u for ct in TWO_LENGTHS])
    R = np.eye(4)
    R[2, 3] = R[3, 2] = r
    rng = np.random.default_rng(20240542)
    draws = rng.multivariate_normal(x, R * np.outer(u, u), size=N_MC)
    y = lengths(sign)(*draws.T)
    se = g.u_c / math.sqrt(2 * (N_MC - 1))
    assert np.std(y, ddof=1) == pytest.approx(g.u_c, abs=5 * se)
    # the product's Monte Carlo (JCGM 101 6.4.8) on the same budget
    mc = monte_carlo(TWO_LENGTHS, function=lengths(sign), trials=N_MC, seed=7,
                     correlations={("theta_a", "theta_b"): r})
    assert mc.u == pytest.approx(g.u_c, abs=5 * se)


def test_additive_budget_monte_carlo_and_json():
    """The budget command: correlations in, stated in the output, used by both methods."""
    d = {"contributions": [{"name": "t_air", "u": 0.01, "c": 0.7},
                           {"name": "t_plate", "u": 0.01, "c": -8.65},
                           {"name": "rep", "u": 0.2, "dof": 4}],
         "correlations": [{"between": ["t_air", "t_plate"], "r": 1.0}],
         "monte_carlo_trials": 200_000, "seed": 3}
    out = budget_from_dict(d)
    s = np.array([0.007, -0.0865, 0.2])
    assert out["u_c"] == pytest.approx(math.sqrt(0.2**2 + (0.007 - 0.0865) ** 2), rel=1e-12)
    assert out["correlated"] is True
    assert out["correlations"] == [{"between": ["t_air", "t_plate"], "r": 1.0,
                                    "term": pytest.approx(2 * s[0] * s[1])}]
    assert out["mc"]["u"] == pytest.approx(out["u_c"], abs=5 * out["u_c"] / math.sqrt(4e5))
    # W-S: the correlated pair has infinite dof, only rep counts (JCGM 100 eq. G.2b)
    assert out["nu_eff"] == pytest.approx(4 * out["u_c"] ** 4 / 0.2**4, rel=1e-12)
    plain = budget_from_dict({k: v for k, v in d.items() if k != "correlations"})
    assert "correlated" not in plain and "correlations" not in plain


def test_table_states_the_correlations():
    g = gum_combine(TWO_LENGTHS, function=lengths(1), correlations=[("theta_a", "theta_b", 0.8)])
    rows = {r["name"]: r for r in g.table()}
    assert rows["theta_a"]["correlated_with"] == "theta_b (r = 0.8)"
    assert rows["l_a"]["correlated_with"] == ""
    assert "correlated_with" not in gum_combine(TWO_LENGTHS).table()[0]
    # r = 0 is independence: nothing to state
    assert not gum_combine(TWO_LENGTHS, correlations={("l_a", "l_b"): 0.0}).correlated


def test_ballplate_budget_thermometer_correlation():
    base = ballplate_budget()
    one = ballplate_budget({"thermometer_correlation": 1.0})
    assert base.correlations == () and not base.gum.correlated
    assert one.gum.correlated and len(one.correlations) == 1
    # c(air temperature) > 0 and c(plate temperature) < 0: one thermometer cancels a little
    assert one.gum.u_c < base.gum.u_c
    assert any(r["correlated_with"] for r in one.table())
    spec = budget_spec_dict(one)
    assert len(spec["correlations"]) == 1
    out = budget_from_dict({**spec, "monte_carlo_trials": 0})
    assert out["u_c"] == pytest.approx(one.gum.u_c, rel=1e-12) and out["correlated"]
    assert ballplate_budget({"thermometer_correlation": 1.0,
                             "include_air": False}).correlations == ()
    with pytest.raises(ValueError, match=r"thermometer_correlation: expected a correlation "
                                         r"coefficient in \[-1, 1\], got 1.5"):
        ballplate_budget({"thermometer_correlation": 1.5})


@pytest.mark.parametrize("corr,match", [
    ({("l_a", "x"): 0.5}, r"'x' is not an input of the budget; expected one of 'l_a'"),
    ({("l_a", "l_b"): 1.2}, r"expected a correlation coefficient in \[-1, 1\], got 1.2"),
    ({("l_a", "l_b"): -1.0001}, r"in \[-1, 1\]"),
    ({("l_a", "l_b"): float("nan")}, "expected a finite number"),
    ({("l_a", "l_a"): 1.0}, "expected two different inputs"),
    ([("l_a", "l_b", 0.5), ("l_b", "l_a", 0.4)], "the pair is given twice"),
    ([("l_a", "l_b", 0.9), ("l_b", "theta_a", 0.9), ("l_a", "theta_a", -0.9)],
     "positive semidefinite"),
    ([("l_a", "l_b")], r"correlations\[0\]: expected \(a, b, r\)"),
    ({"l_a": 0.5}, "expected keys that are pairs"),
    ("l_a", "expected a mapping"),
])
def test_correlation_validation(corr, match):
    with pytest.raises(ValueError, match=match) as err:
        gum_combine(TWO_LENGTHS, correlations=corr)
    assert "\n" not in str(err.value)


def test_correlation_validation_names_dof_and_monte_carlo():
    dup = [Contribution("a", 1.0), Contribution("a", 2.0), Contribution("b", 1.0)]
    with pytest.raises(ValueError, match="'a' names 2 inputs; expected a unique name"):
        correlation_matrix(dup, {("a", "b"): 0.5})
    mixed = [Contribution("a", 1.0, dof=4), Contribution("b", 1.0)]
    with pytest.raises(ValueError, match=r"'a', 'b' are correlated but have degrees of "
                                         r"freedom 4, inf.*Hint"):
        gum_combine(mixed, correlations={("a", "b"): 0.3})
    rect = [Contribution("a", 1.0), Contribution.from_half_width("b", 1.0)]
    with pytest.raises(ValueError, match="'b' is rectangular; expected normal inputs only"):
        monte_carlo(rect, trials=100, correlations={("a", "b"): 0.3})
    with pytest.raises(ValueError, match="student_t_for_finite_dof"):
        monte_carlo([Contribution("a", 1.0, dof=4), Contribution("b", 1.0, dof=4)],
                    trials=100, correlations={("a", "b"): 0.3}, student_t_for_finite_dof=True)
    # r = 1 and r = -1 (semidefinite) are accepted; equal and opposite inputs cancel
    cancel = gum_combine([Contribution("a", 1.0), Contribution("b", 1.0)],
                         correlations={("a", "b"): -1.0})
    assert cancel.u_c == 0.0 and cancel.correlation_share == 0.0


@pytest.mark.parametrize("bad,match", [
    ({"correlations": {"a": 1}}, "correlations: expected a list"),
    ({"correlations": [{"between": ["a"], "r": 0.5}]}, r"correlations\[0\]\.between"),
    ({"correlations": [{"between": ["a", "b"]}]}, r"exactly 'between'.*and 'r'"),
    ({"correlations": [{"between": ["a", "b"], "r": "high"}]}, r"correlations\[0\]\.r"),
    ({"correlations": [{"between": ["a", "z"], "r": 0.5}]}, "'z' is not an input"),
    ({"correlations": [{"between": ["a", "b"], "r": 2}]}, r"in \[-1, 1\], got 2"),
])
def test_budget_json_correlation_errors(bad, match):
    d = {"contributions": [{"name": "a", "u": 1.0}, {"name": "b", "u": 1.0}], **bad}
    with pytest.raises(ValueError, match=match) as err:
        budget_from_dict(d)
    assert "\n" not in str(err.value)

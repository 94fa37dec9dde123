"""The GUM budget cross-checked against GTC, the GUM Tree Calculator (issue 42 item 4).

GTC (Measurement Standards Laboratory of New Zealand, https://gtc.readthedocs.io) propagates
uncertainty by automatic differentiation of the measurement model written with its
uncertain real numbers (``ureal``). Here every budget is written again as such a model, from
the same inputs but with none of the product's code for sensitivities or contributions: the
ball-plate model of thesis eq. 3.14 (with the modified Edlén equation written out with GTC
arithmetic), GUM example H.1 (JCGM 100:2008 annex H.1, eq. H.3) and models with correlated
inputs (``ureal(..., independent=False)`` and ``set_correlation``, JCGM 100 eq. 16).

Tolerances: both sides are first-order (linear) propagation of the same model in double
precision, so they agree to rounding. The product's coefficients are central differences
(exact for the additive and bilinear models; for the air terms the refractive index is
differenced near n = 1, which costs about 1e-7 relative), so ``rtol = 1e-6`` is far above
what they differ by and far below anything a budget would notice. Published values are
checked to their printed rounding.

References
----------
- JCGM 100:2008, 5.1.2 (eq. 10), 5.2.2 (eq. 13, 14, 16), G.4.1 (eq. G.2b), annex H.1.
- R. Willink, "A generalization of the Welch-Satterthwaite formula for use with correlated
  uncertainty components", Metrologia 44 (2007) 340-349.
- B. D. Hall, "The GUM Tree Calculator", https://gtc.readthedocs.io.
"""

import math

import pytest

GTC = pytest.importorskip("GTC", reason="GTC (GUM Tree Calculator, a test-only dependency) "
                                        "is not installed: pip install GTC")

from cmm_core.gum import (  # noqa: E402  (after the skip: nothing to test without GTC)
    Contribution,
    ballplate_budget,
    budget_vs_length,
    coverage_factor,
    gum_combine,
    inputs_from_record,
    thesis_budgets,
)
from cmm_core.gum.ballplate import THESIS_ENVIRONMENT  # noqa: E402

ureal = GTC.ureal
RTOL = 1e-6

# ----------------------------------------------------------------- the Edlén equation in GTC

# IAPWS-IF97 region 4 (saturation line), n1..n10 (Wagner et al., IAPWS 1997).
IF97 = (0.11670521452767e4, -0.72421316703206e6, -0.17073846940092e2, 0.12020824702470e5,
        -0.32325550322333e7, 0.14915108613530e2, -0.48232657361591e4, 0.40511340542057e6,
        -0.23855557567849, 0.65017534844798e3)


def p_sv(t):
    """Saturation vapour pressure (Pa) of IAPWS-IF97 for a GTC temperature t (°C)."""
    n1, n2, n3, n4, n5, n6, n7, n8, n9, n10 = IF97
    T = t + 273.15
    om = T + n9 / (T - n10)
    a = om * om + n1 * om + n2
    b = n3 * om * om + n4 * om + n5
    c = n6 * om * om + n7 * om + n8
    x = 2.0 * c / (-b + GTC.sqrt(b * b - 4.0 * a * c))
    return 1e6 * x**4


def edlen(t, p, rh, wavelength_nm):
    """Modified Edlén equation (Birch and Downs 1993, 1994) in GTC arithmetic, 450 µmol/mol CO2."""
    s2 = (1e3 / wavelength_nm) ** 2
    ns = (8342.54 + 2406147.0 / (130.0 - s2) + 15998.0 / (38.9 - s2)) * 1e-8
    ntp = p * ns / 96095.43 * (1.0 + 1e-8 * (0.601 - 0.00972 * t) * p) / (1.0 + 0.0036610 * t)
    f = rh / 100.0 * p_sv(t)
    return 1.0 + ntp - f * (3.7345 - 0.0401 * s2) * 1e-10


# ------------------------------------------------------------- the ball-plate model in GTC

def ballplate_gtc(inp, r_thermometers=0.0):
    """Thesis eq. 3.14 as a GTC model, from the budget's inputs (thesis §3.8.2 read directly).

    ``l_x = δl_rep + δl_vm + δl_is + δl_cal + δl_RP - l_0 n(t, p, RH) - δl_Ax
    - l_0 [α δt_m + α δt_d + Δt δα]`` in µm; every correction has estimate 0; the air
    quantities are their operating point plus a calibration and a resolution error.
    Returns ``(l, {equation: ureal})``.
    """
    L_um = inp.length_mm * 1e3
    rect = math.sqrt(3.0)
    corr = r_thermometers != 0.0
    x = {
        "3.15": ureal(0.0, inp.s_lx_um / math.sqrt(inp.n_repeats), df=inp.n_repeats - 1),
        "3.16": ureal(0.0, inp.verification_um / rect),
        "3.17": ureal(0.0, inp.cmm_resolution_um / 2 / rect),
        "app. 1": ureal(0.0, math.sqrt(0.52**2 + (1.4e-3 * inp.length_mm) ** 2) / 2),
        "3.18": ureal(0.0, inp.probe_reproducibility_um / rect),
        "3.20": ureal(0.0, inp.rh_U_percent / 2),
        "3.21": ureal(0.0, inp.rh_resolution_percent / 2 / rect),
        "3.22": ureal(0.0, inp.p_U_Pa / 2),
        "3.23": ureal(0.0, inp.p_resolution_Pa / 2 / rect),
        "3.24": ureal(0.0, inp.t_air_U_C / 2, independent=not corr),
        "3.25": ureal(0.0, inp.t_resolution_C / 2 / rect),
        "3.26": ureal(0.0, L_um * (1.0 - math.cos(math.asin(inp.alignment_mm
                                                             / inp.alignment_length_mm)))
                      / rect),
        "3.27": ureal(0.0, inp.t_plate_U_C / 2, independent=not corr),
        "3.28": ureal(0.0, inp.t_distribution_C / rect),
        "3.29": ureal(0.0, inp.cte_half_width_per_K / rect),
    }
    if corr:
        GTC.set_correlation(r_thermometers, x["3.24"], x["3.27"])
    t = inp.t_C + x["3.24"] + x["3.25"]
    p = inp.p_Pa + x["3.22"] + x["3.23"]
    rh = inp.rh_percent + x["3.20"] + x["3.21"]
    n = edlen(t, p, rh, inp.wavelength_nm)
    alpha = inp.cte_per_K
    l_x = (x["3.15"] + x["3.16"] + x["3.17"] + x["app. 1"] + x["3.18"] - L_um * n - x["3.26"]
           - L_um * (alpha * x["3.27"] + alpha * x["3.28"] + inp.dt_from_20_C * x["3.29"]))
    return l_x, x


def _check_against_gtc(budget, r_thermometers=0.0):
    l_x, x = ballplate_gtc(budget.inputs, r_thermometers)
    rows = {r["equation"]: r for r in budget.table()}
    assert set(rows) == set(x)
    assert budget.gum.u_c == pytest.approx(GTC.uncertainty(l_x), rel=RTOL)
    for eq, xi in x.items():
        assert rows[eq]["u_y"] == pytest.approx(abs(GTC.component(l_x, xi)), rel=RTOL), eq
    assert budget.gum.nu_eff == pytest.approx(GTC.dof(l_x), rel=RTOL)


@pytest.mark.parametrize("position", [*(r.position for r in THESIS_ENVIRONMENT), "average"])
def test_thesis_ballplate_budget_agrees_with_gtc(position):
    """Each thesis budget (tables 6.1-6.6 records and their average, L = 752.4 mm)."""
    _check_against_gtc(thesis_budgets()[position])


@pytest.mark.parametrize("length_mm", [133.0, 532.0])
def test_ballplate_budget_at_other_lengths_agrees_with_gtc(length_mm):
    _check_against_gtc(ballplate_budget({"length_mm": length_mm}))
    ld = budget_vs_length(lengths_mm=[length_mm])
    l_x, _ = ballplate_gtc(ballplate_budget({"length_mm": length_mm}).inputs)
    assert ld.u_c_um[0] == pytest.approx(GTC.uncertainty(l_x), rel=RTOL)


@pytest.mark.parametrize("r", [1.0, 0.8, -0.5, -1.0])
def test_ballplate_budget_with_correlated_thermometers_agrees_with_gtc(r):
    """The air and plate thermometers of one certificate (eq. 3.24 and 3.27) correlated."""
    inp = inputs_from_record(THESIS_ENVIRONMENT[0], thermometer_correlation=r)
    b = ballplate_budget(inp)
    assert b.gum.correlated and b.gum.correlation_share != 0.0
    _check_against_gtc(b, r)
    # the correlation term, 2 c_a c_b u_a u_b r (JCGM 100 eq. 16), from GTC's components
    l_x, x = ballplate_gtc(inp, r)
    u_i = GTC.reporting.u_component            # signed c_i u(x_i)
    term = 2 * u_i(l_x, x["3.24"]) * u_i(l_x, x["3.27"]) * r
    [t] = b.gum.correlation_terms()
    assert t["term"] == pytest.approx(term, rel=RTOL)
    assert {r_["correlated_with"] != "" for r_ in b.table()} == {True, False}


# ----------------------------------------------------------------- GUM H.1, end gauge

# JCGM 100 H.1 (nm, °C): l = l_s + d - l_s (δα θ + α_s δθ) (eq. H.3), estimates of table H.1.
H1_LS_NM = 50_000_623.6


def h1_gtc():
    l_s = ureal(H1_LS_NM, 25.0, df=18)
    d = ureal(215.0, 9.7, df=25.6)
    alpha_s = ureal(11.5e-6, 1.2e-6)
    theta = ureal(-0.1, 0.41)
    d_alpha = ureal(0.0, 0.58e-6, df=50)
    d_theta = ureal(0.0, 0.029, df=2)
    return l_s + d - l_s * (d_alpha * theta + alpha_s * d_theta)


def h1_product():
    def f(l_s, d, alpha_s, theta, dalpha, dtheta):
        return l_s + d - l_s * (dalpha * theta + alpha_s * dtheta)

    cts = [Contribution("l_s", 25.0, dof=18, value=H1_LS_NM),
           Contribution("d", 9.7, dof=25.6, value=215.0),
           Contribution("alpha_s", 1.2e-6, value=11.5e-6),
           Contribution("theta", 0.41, value=-0.1),
           Contribution("delta_alpha", 0.58e-6, "rectangular", dof=50),
           Contribution("delta_theta", 0.029, "rectangular", dof=2)]
    return gum_combine(cts, function=f, coverage_probability=0.99)


def test_gum_h1_product_and_gtc_against_the_published_values():
    g, l_gtc = h1_product(), h1_gtc()
    for u_c, nu in ((g.u_c, g.nu_eff), (GTC.uncertainty(l_gtc), GTC.dof(l_gtc))):
        assert round(u_c) == 32                       # JCGM 100 H.1.4: u_c(l) = 32 nm
        assert u_c == pytest.approx(32.0, abs=0.5)
        assert nu == pytest.approx(16.7, abs=0.05)    # H.1.6: eq. G.2b gives 16.7 ...
        assert math.floor(nu) == 16                   # ... taken as nu_eff = 16
    assert g.nu_used == 16
    # t_99(16) = 2.92 (table G.2), U99 = 2.92 x 32 nm = 93 nm (to the rounding of u_c)
    k_gtc = GTC.reporting.k_factor(math.floor(GTC.dof(l_gtc)), 99)
    assert g.k == pytest.approx(2.92, abs=0.005) and k_gtc == pytest.approx(2.92, abs=0.005)
    assert g.U == pytest.approx(93.0, abs=1.5)
    assert GTC.value(l_gtc) == pytest.approx(50_000_838.6, abs=0.05)   # l = 50.000 838 mm


def test_gum_h1_product_agrees_with_gtc():
    g, l_gtc = h1_product(), h1_gtc()
    assert g.y == pytest.approx(GTC.value(l_gtc), rel=1e-12)
    assert g.u_c == pytest.approx(GTC.uncertainty(l_gtc), rel=RTOL)
    assert g.nu_eff == pytest.approx(GTC.dof(l_gtc), rel=RTOL)
    assert g.k == pytest.approx(GTC.reporting.k_factor(g.nu_used, 99), rel=RTOL)
    # each component u_i(l) (table H.1: 25, 9.7, 0, 0, 2.9, 16.6 nm) against GTC's
    l_s = ureal(H1_LS_NM, 25.0, df=18)
    d = ureal(215.0, 9.7, df=25.6)
    alpha_s, theta = ureal(11.5e-6, 1.2e-6), ureal(-0.1, 0.41)
    d_alpha, d_theta = ureal(0.0, 0.58e-6, df=50), ureal(0.0, 0.029, df=2)
    length = l_s + d - l_s * (d_alpha * theta + alpha_s * d_theta)
    gtc_u = [abs(GTC.component(length, xi)) for xi in (l_s, d, alpha_s, theta, d_alpha, d_theta)]
    for mine, theirs in zip(g.u_y, gtc_u, strict=True):
        assert mine == pytest.approx(theirs, rel=RTOL, abs=1e-9)


# ------------------------------------------------------ correlated inputs against GTC

L_A_UM, L_B_UM = 100_000.0, 250_000.0
ALPHA = 11.5e-6


def _two_lengths(r, sign):
    """Two lengths, each corrected to 20 °C with a thermometer; one certificate makes the
    thermometers' errors correlated (JCGM 100 5.2.4). ``Y = l_a (1 - α θ_a) ± l_b (1 - α θ_b)``
    in µm, θ the temperature offsets from 20 °C."""
    def f(l_a, l_b, th_a, th_b):
        return l_a * (1 - ALPHA * th_a) + sign * l_b * (1 - ALPHA * th_b)

    cts = [Contribution("l_a", 0.10, value=L_A_UM), Contribution("l_b", 0.15, value=L_B_UM),
           Contribution("theta_a", 0.02, value=0.5), Contribution("theta_b", 0.03, value=0.3)]
    g = gum_combine(cts, function=f, correlations={("theta_a", "theta_b"): r})
    l_a, l_b = ureal(L_A_UM, 0.10), ureal(L_B_UM, 0.15)
    th_a = ureal(0.5, 0.02, independent=False)
    th_b = ureal(0.3, 0.03, independent=False)
    GTC.set_correlation(r, th_a, th_b)
    return g, f(l_a, l_b, th_a, th_b)


@pytest.mark.parametrize("sign", [1, -1], ids=["sum", "difference"])
@pytest.mark.parametrize("r", [0.8, -0.5, 1.0])
def test_correlated_inputs_agree_with_gtc_set_correlation(r, sign):
    g, y = _two_lengths(r, sign)
    assert g.correlated
    assert g.y == pytest.approx(GTC.value(y), rel=1e-12)
    assert g.u_c == pytest.approx(GTC.uncertainty(y), rel=RTOL)
    assert math.isinf(g.nu_eff) and math.isinf(GTC.dof(y))
    [t] = g.correlation_terms()
    assert (t["a"], t["b"], t["r"]) == ("theta_a", "theta_b", r)


def test_correlated_ensemble_with_finite_dof_agrees_with_gtc():
    """Correlated inputs of equal dof count as one Welch-Satterthwaite component (Willink
    2007, result 2), as GTC's ``multiple_ureal`` ensembles do."""
    cts = [Contribution("a", 0.3, c=2.0, dof=5), Contribution("b", 0.4, c=-1.0, dof=5),
           Contribution("c", 0.5, dof=12), Contribution("d", 0.2)]
    g = gum_combine(cts, correlations=[("a", "b", 0.6)])
    a, b = GTC.multiple_ureal([0.0, 0.0], [0.3, 0.4], 5)
    GTC.set_correlation(0.6, a, b)
    y = 2.0 * a - b + ureal(0.0, 0.5, df=12) + ureal(0.0, 0.2)
    assert g.u_c == pytest.approx(GTC.uncertainty(y), rel=RTOL)
    assert g.nu_eff == pytest.approx(GTC.dof(y), rel=RTOL)
    assert g.k == pytest.approx(coverage_factor(0.95, math.floor(g.nu_eff)), rel=1e-12)

"""The certificate's own errors in the diagnosis's F-test and in the detection limits
(issue 26): the distribution of a quadratic form in normal variables (Imhof 1961), the
test's p-value under a fixed certificate, and the limits stated for that same test."""

import numpy as np
import pytest
import scenarios as sc
from scipy import stats

from cmm_core.diagnosis import (
    candidate_noise,
    certificate_noise,
    critical_ratio,
    diagnose,
    null_p_value,
    quadratic_form_sf,
    rejection_probability,
)
from cmm_core.model import fit


def test_imhof_is_scipys_noncentral_f_for_white_noise():
    """Equal weights: P(χ²(k, λ) − a χ²_ν > 0) is the non-central F's tail at
    F = a ν/k (reference: scipy.stats.ncf). 200 seeded random cases over the ranges the
    diagnosis uses (k 1-7, ν 20-2000, levels 1e-7-0.1, λ 0-80); tolerance 1e-9, the
    quadrature's error being below 1e-13 here."""
    rng = np.random.default_rng(11)
    for _ in range(200):
        k, nu = int(rng.integers(1, 8)), int(rng.integers(20, 2000))
        level, lam = 10 ** rng.uniform(-7, -1), rng.uniform(0, 80)
        got = rejection_probability(np.ones(k), np.full(k, lam / k), nu, level)
        want = stats.ncf.sf(stats.f.isf(level, k, nu), k, nu, lam)
        assert got == pytest.approx(want, abs=1e-9), (k, nu, level, lam)


def test_imhof_matches_a_monte_carlo_of_an_uneven_form():
    """Unequal weights (the certificate's errors loading one direction more): the tail
    against 400 000 seeded draws of the form itself; binomial standard error ≤ 8e-4,
    tolerance 4 SE."""
    w, d2, nu, a = np.array([1.06, 1.23, 1.29]), np.array([4.0, 9.0, 2.0]), 300, 0.05
    rng = np.random.default_rng(3)
    n = 400_000
    z = rng.standard_normal((n, 3))
    q = ((z + np.sqrt(d2)) ** 2 * w).sum(axis=1) - a * rng.chisquare(nu, n)
    mc = float(np.mean(q > 0))
    got = quadratic_form_sf(np.r_[w, -a], np.r_[1, 1, 1, nu], np.r_[d2, 0.0])
    assert got == pytest.approx(mc, abs=4 * np.sqrt(mc * (1 - mc) / n))


def test_too_few_dof_are_refused_not_cut():
    with pytest.raises(ValueError, match="fewer than"):
        quadratic_form_sf(np.array([1.0, -0.1]), np.array([1, 5]), np.zeros(2))


def test_the_p_value_counts_the_certificate_and_inverts_its_critical_value():
    """k = 1: the null is c1/c2 times F(1, ν) exactly; uneven k: the critical ratio is
    where the p-value equals the level."""
    assert null_p_value(9.0, np.array([1.2]), 1.05, 300) == pytest.approx(
        stats.f.sf(9.0 * 1.05 / 1.2, 1, 300), rel=1e-12)
    assert null_p_value(9.0, np.ones(2), 1.0, 300) == pytest.approx(
        stats.f.sf(9.0, 2, 300), rel=1e-12)
    w, c2, nu, level = np.array([1.02, 1.1, 1.3]), 1.04, 378, 6.7e-4
    a = critical_ratio(w, c2, nu, level)
    assert null_p_value(a * nu / 3, w, c2, nu) == pytest.approx(level, rel=1e-5)
    # a heavier-loaded direction needs a larger statistic than white noise does
    assert a * nu / 3 > stats.f.isf(level, 3, nu) * 1.0


def test_the_diagnosis_tests_candidates_with_the_certificates_noise():
    """On a scenario layout (plate fixed to a certificate of 0.1 µm): the certificate's
    errors load dzz:3 more than the residual (c1 > c2, as ``plan.detect.cert_scales``
    finds), and the candidate's p-value is the null's tail with them, larger than the
    plain F-test's."""
    data = sc.simulated("pitch100_4pos", 999).dataset
    base = fit(data, "kinematic21")
    cn = certificate_noise(base)
    assert cn is not None
    w, c2, each = candidate_noise(cn, base, "dzz:3", 1)
    assert w[0] > c2 > 1.0 and each[0] == pytest.approx(w[0], rel=1e-6)
    d = diagnose(data, "kinematic21")
    c = next(c for c in d.candidates if c.effect == "dzz:3")
    F = (c.delta_chi2 / 1) / c.chi2_dof
    assert c.p_value == pytest.approx(null_p_value(F, w, c2, base.dof - 1), rel=1e-6)
    assert c.p_value > stats.f.sf(F, 1, base.dof - 1)
    # ... and the size it "would see" counts the same inflation, sqrt(c1/c2)
    lab = next(iter(c.detectable))
    assert np.isfinite(c.detectable[lab][1])


def test_no_certificate_no_change():
    """A self-calibrated plate (``plate="free"``): no certificate errors, the plain F."""
    data = sc.simulated("pitch80_3pos", 999).dataset
    base = fit(data, "kinematic21", plate="free")
    assert certificate_noise(base) is None

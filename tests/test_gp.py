"""Gaussian-process error model (cmm_core.gp, cmm_core.gp.cmm): thesis chapter 5, appendix 3.

References: Rasmussen & Williams (2006), *Gaussian Processes for Machine Learning* (R&W),
§2.2 (eq. 2.23-2.30), §2.7 (eq. 2.41-2.45), §5.4 (eq. 5.9, 5.12); scikit-learn's
GaussianProcessRegressor as an independent implementation (test-only dependency).
"""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from cmm_core.gp import (
    appendix3_workflow,
    box_grid,
    fit_gp,
    gp_components,
    log_marginal_likelihood,
    plate_grid,
    polynomial_basis,
    predict_grid,
)

ROOT = Path(__file__).resolve().parents[1]


def _surface(X):
    """A smooth error surface (µm) over mm inputs, a few µm in amplitude."""
    return 3 * np.sin(X[:, 0] / 120) + 2 * np.cos(X[:, 1] / 90)


@pytest.fixture
def data2d(rng):
    X = rng.uniform(0, 500, (60, 2))
    return X, _surface(X) + 0.3 * rng.standard_normal(60)


def _se(A, B, ell, sf):
    return sf**2 * np.exp(-0.5 * cdist(A / ell, B / ell, "sqeuclidean"))


def _gauss_logpdf(C, y):
    L = np.linalg.cholesky(C)
    a = np.linalg.solve(L, y)
    return -0.5 * a @ a - np.log(np.diag(L)).sum() - 0.5 * len(y) * np.log(2 * np.pi)


# ----------------------------------------------------------------- against scikit-learn

def test_matches_sklearn(data2d, rng):
    """Same kernel (C × RBF + White), zero mean, 3 restarts: our log ML is no lower than
    scikit-learn's and the predictions agree. Tolerances: both optimisers stop on a
    projected-gradient test, so the optimum agrees to ~1e-6 in log ML and to 1e-4 µm
    (µm-scale data) in the predictions."""
    sk = pytest.importorskip("sklearn.gaussian_process")
    kernels = pytest.importorskip("sklearn.gaussian_process.kernels")
    X, y = data2d
    ours = fit_gp(X, y, mean="zero", kernel="se_iso", restarts=3, seed=0)
    k = kernels.ConstantKernel(1.0) * kernels.RBF(100.0) + kernels.WhiteKernel(0.1)
    ref = sk.GaussianProcessRegressor(k, n_restarts_optimizer=3, random_state=0).fit(X, y)
    assert ours.status == "converged"
    assert ours.log_marginal_likelihood >= ref.log_marginal_likelihood_value_ - 1e-6
    # sklearn's value of its own likelihood at our hyperparameters: the same function
    theta = np.log([ours.signal_sd_um**2, ours.length_scale_mm[0], ours.noise_sd_um**2])
    assert ref.log_marginal_likelihood(theta) == pytest.approx(
        ours.log_marginal_likelihood, abs=1e-8)
    Xt = rng.uniform(0, 500, (40, 2))
    mu, var = ours.predict(Xt)
    mu_ref, sd_ref = ref.predict(Xt, return_std=True)  # std includes the white noise
    np.testing.assert_allclose(mu, mu_ref, atol=1e-4)
    np.testing.assert_allclose(var + ours.noise_sd_um**2, sd_ref**2, atol=1e-4)


def test_matches_sklearn_ard_3d(rng):
    """3-D inputs with ARD against scikit-learn's anisotropic RBF."""
    sk = pytest.importorskip("sklearn.gaussian_process")
    kernels = pytest.importorskip("sklearn.gaussian_process.kernels")
    X = rng.uniform(0, 600, (50, 3))
    # every input matters, so that the optimum is interior for both (no bound effects)
    y = (2 * np.sin(X[:, 0] / 150) + np.cos(X[:, 1] / 200) + 0.5 * np.sin(X[:, 2] / 100)
         + 0.2 * rng.standard_normal(50))
    ours = fit_gp(X, y, kernel="se_ard", restarts=3, seed=1)
    k = (kernels.ConstantKernel(1.0) * kernels.RBF([200.0] * 3, (1e-2, 1e6))
         + kernels.WhiteKernel(0.1))
    ref = sk.GaussianProcessRegressor(k, n_restarts_optimizer=3, random_state=0).fit(X, y)
    # ARD likelihoods have local optima: sklearn may stop in a worse one, never a better one
    assert ours.log_marginal_likelihood >= ref.log_marginal_likelihood_value_ - 1e-6
    # the same model: sklearn's likelihood at our hyperparameters, and its predictions with
    # them fixed, equal ours (round-off level)
    ls = list(ours.length_scale_mm)
    theta = np.log([ours.signal_sd_um**2, *ls, ours.noise_sd_um**2])
    assert ref.log_marginal_likelihood(theta) == pytest.approx(
        ours.log_marginal_likelihood, abs=1e-8)
    fixed = (kernels.ConstantKernel(ours.signal_sd_um**2) * kernels.RBF(ls)
             + kernels.WhiteKernel(ours.noise_sd_um**2))
    same = sk.GaussianProcessRegressor(fixed, optimizer=None).fit(X, y)
    Xt = rng.uniform(0, 600, (20, 3))
    mu, var = ours.predict(Xt)
    mu_ref, sd_ref = same.predict(Xt, return_std=True)
    np.testing.assert_allclose(mu, mu_ref, atol=1e-8)
    np.testing.assert_allclose(var + ours.noise_sd_um**2, sd_ref**2, atol=1e-8)


# ----------------------------------------------------------------- the likelihood

@pytest.mark.parametrize("mean,kernel", [("zero", "se_iso"), ("quadratic", "se_iso"),
                                         ("linear", "se_ard"), ("zero", "se_ard")])
def test_gradient_matches_finite_differences(data2d, mean, kernel):
    """Analytic ∂ log p/∂ log θ (R&W eq. 5.9 with P) against central differences,
    step 1e-5 in log θ: truncation error ~1e-10 × third derivative, so 1e-5 relative."""
    X, y = data2d
    hyp = {"length_scale_mm": 150.0 if kernel == "se_iso" else [150.0, 110.0],
           "signal_sd_um": 2.5, "noise_sd_um": 0.4}
    f0, g = log_marginal_likelihood(X, y, hyp, mean=mean, kernel=kernel)
    keys = [("length_scale_mm", i) for i in range(1 if kernel == "se_iso" else 2)]
    keys += [("signal_sd_um", None), ("noise_sd_um", None)]
    h = 1e-5
    for j, (k, i) in enumerate(keys):
        vals = []
        for s in (+1, -1):
            hp = {kk: np.atleast_1d(np.array(v, dtype=float)) for kk, v in hyp.items()}
            if i is None:
                hp[k] = hp[k] * np.exp(s * h)
            else:
                hp[k][i] *= np.exp(s * h)
            vals.append(log_marginal_likelihood(X, y, hp, mean=mean, kernel=kernel)[0])
        fd = (vals[0] - vals[1]) / (2 * h)
        assert g[j] == pytest.approx(fd, rel=1e-5, abs=1e-6), (k, i)


def test_zero_mean_lml_is_gaussian_density(data2d):
    """Without a basis, log p(y) = log N(y; 0, K + σ_n² I) (R&W eq. 2.30) exactly."""
    X, y = data2d
    hyp = {"length_scale_mm": 130.0, "signal_sd_um": 2.0, "noise_sd_um": 0.3}
    lml, _ = log_marginal_likelihood(X, y, hyp)
    C = _se(X, X, 130.0, 2.0) + 0.09 * np.eye(len(X))
    assert lml == pytest.approx(_gauss_logpdf(C, y), abs=1e-9)


def test_basis_mean_is_limit_of_wide_gaussian_prior(rng):
    """R&W §2.7: with β ~ N(0, b² I) the GP has covariance K + b² H Hᵀ. As b → ∞ its
    predictions converge to the marginalised-basis ones (eq. 2.42) and its log ML, after
    adding ½ log|B| = m log b and m/2 log 2π, converges to eq. 2.45 without the divergent
    terms. Error is O(1/b²) (b = 1e3: ~1e-6 relative), round-off O(eps b² |H|²) (~1e-7)."""
    X = rng.uniform(400, 600, (30, 2))
    y = 5 + 0.02 * X[:, 0] + np.sin(X[:, 1] / 40) + 0.2 * rng.standard_normal(30)

    def h(Z):  # a well-scaled quadratic basis, so that one b suits all columns
        return polynomial_basis((Z - 500) / 100, "quadratic")[0]

    hyp = {"length_scale_mm": 80.0, "signal_sd_um": 1.0, "noise_sd_um": 0.2}
    res = fit_gp(X, y, mean=h, initial=hyp, optimize=False)
    assert res.status == "fixed"
    H, Xt = h(X), rng.uniform(400, 600, (5, 2))
    Ht = h(Xt)
    m = H.shape[1]
    K = _se(X, X, 80.0, 1.0)
    Ks = _se(Xt, X, 80.0, 1.0)
    mu, var = res.predict(Xt)
    errs = []
    for b in (1e1, 1e2, 1e3):
        Kb = K + b**2 * H @ H.T + 0.04 * np.eye(30)
        lml_b = _gauss_logpdf(Kb, y) + m * np.log(b) + 0.5 * m * np.log(2 * np.pi)
        Ksb = Ks + b**2 * Ht @ H.T
        mu_b = Ksb @ np.linalg.solve(Kb, y)
        var_b = 1 + b**2 * np.sum(Ht**2, 1) - np.einsum("ij,ji->i", Ksb,
                                                        np.linalg.solve(Kb, Ksb.T))
        errs.append((abs(lml_b - res.log_marginal_likelihood), np.abs(mu_b - mu).max(),
                     np.abs(var_b - var).max()))
    errs = np.array(errs)
    assert np.all(np.diff(errs, axis=0) < 0)  # converging
    assert errs[-1, 0] < 1e-3 and errs[-1, 1] < 1e-5 and errs[-1, 2] < 1e-6
    # the same model with the basis given as a design matrix and H_new at the test points
    res2 = fit_gp(X, y, mean=H, initial=hyp, optimize=False)
    assert res2.log_marginal_likelihood == pytest.approx(res.log_marginal_likelihood, abs=1e-9)
    np.testing.assert_allclose(res2.predict(Xt, Ht)[0], mu, atol=1e-10)
    with pytest.raises(ValueError, match="H_new"):
        res2.predict(Xt)


def test_loo_closed_form_matches_refits(rng):
    """R&W eq. 5.12 (with P for a basis) against n brute-force refits leaving each point
    out, hyperparameters fixed: identical models, so agreement to round-off (1e-8 µm)."""
    X = rng.uniform(400, 600, (15, 2))
    y = _surface(X) + 0.02 * X[:, 0] + 0.3 * rng.standard_normal(15)
    hyp = {"length_scale_mm": 70.0, "signal_sd_um": 1.5, "noise_sd_um": 0.3}
    for mean in ("zero", "linear"):
        res = fit_gp(X, y, mean=mean, initial=hyp, optimize=False)
        for i in range(len(y)):
            keep = np.arange(len(y)) != i
            r_i = fit_gp(X[keep], y[keep], mean=mean, initial=hyp, optimize=False)
            mu, var = r_i.predict(X[[i]])
            assert res.loo_mean_um[i] == pytest.approx(mu[0], abs=1e-8)
            assert res.loo_sd_um[i] ** 2 == pytest.approx(var[0] + 0.09, abs=1e-8)
        rms = np.sqrt(np.mean((y - res.loo_mean_um) ** 2))
        assert res.loo_rms_um == pytest.approx(rms)


# ----------------------------------------------------------------- fitting behaviour

def test_seeded_restarts_reproducible_and_reported(data2d):
    X, y = data2d
    a = fit_gp(X, y, restarts=2, seed=5)
    b = fit_gp(X, y, restarts=2, seed=5)
    assert a.log_marginal_likelihood == b.log_marginal_likelihood
    assert len(a.start_log_ml) == 3
    assert a.log_marginal_likelihood == pytest.approx(max(a.start_log_ml))
    assert a.jitter_um2 == 0 and "jitter" not in a.message
    assert a.noise_sd_um == pytest.approx(0.3, rel=0.3)  # the simulated noise
    lo, hi = a.bounds["noise_sd_um"]
    assert lo < a.noise_sd_um < hi


def test_jitter_only_when_cholesky_fails_and_reported(rng):
    """Duplicated inputs with a noise of 1e-9 σ_f: K_y is singular to working precision,
    so the factorisation needs jitter, which the result reports."""
    X = np.repeat(rng.uniform(0, 100, (10, 1)), 2, axis=0)
    y = np.sin(X[:, 0] / 20)
    hyp = {"length_scale_mm": 500.0, "signal_sd_um": 1.0, "noise_sd_um": 1e-9}
    res = fit_gp(X, y, initial=hyp, optimize=False)
    assert res.jitter_um2 > 0 and "jitter" in res.message
    assert res.n_jitter_events >= 1
    assert np.all(np.isfinite(res.predict(np.array([[50.0]]))[0]))


def test_ard_finds_irrelevant_input(rng):
    """y depends on x1 only: the ARD length scale of x2 and x3 ends much longer."""
    X = rng.uniform(0, 500, (80, 3))
    y = 2 * np.sin(X[:, 0] / 60) + 0.1 * rng.standard_normal(80)
    res = fit_gp(X, y, kernel="se_ard", restarts=1, seed=0)
    ls = np.array(res.length_scale_mm)
    assert ls[1] > 5 * ls[0] and ls[2] > 5 * ls[0]
    assert res.hyperparameters["length_scale_mm"] == list(res.length_scale_mm)


def test_rank_deficient_basis_dropped_by_name(rng):
    """A horizontal plate in machine coordinates (z constant): the quadratic mean's z terms
    are not determined by the data and are reported as dropped, not silently kept."""
    P = np.column_stack([rng.uniform(300, 900, 30), rng.uniform(200, 800, 30),
                         np.full(30, 100.0)])
    y = 0.01 * P[:, 0] + 0.5 * rng.standard_normal(30)
    res = fit_gp(P, y, mean="quadratic", restarts=0)
    assert set(res.basis_dropped) >= {"x3"} and len(res.mean_terms) == 6
    assert np.isfinite(res.log_marginal_likelihood)
    assert np.all(np.isfinite(res.predict(P[:3])[0]))


def test_thesis_quadratic_is_eq_5_11():
    X = np.array([[1.0, 7.0], [2.0, 8.0]])
    H, names = polynomial_basis(X, "thesis_quadratic")
    np.testing.assert_array_equal(H, [[1, 1, 1], [1, 2, 4]])
    assert names == ("1", "x1", "x1^2")
    assert polynomial_basis(X, "quadratic")[1] == ("1", "x1", "x2", "x1^2", "x1*x2", "x2^2")


@pytest.mark.parametrize("call,match", [
    (lambda: fit_gp(np.zeros((5, 2)) + np.arange(5)[:, None], np.zeros(4)), "expected"),
    (lambda: fit_gp(np.zeros((5, 7)), np.zeros(5)), "d = 1 to 6"),
    (lambda: fit_gp(np.arange(10.0).reshape(5, 2), np.zeros(5), groups=(0, 2)), "labels"),
    (lambda: fit_gp(np.arange(10.0).reshape(5, 2), np.arange(5.0), groups=(0, 1),
                    discrete_groups=(2,)), "discrete_groups"),
    (lambda: fit_gp(np.arange(5.0), [0, 1, np.nan, 2, 3]), "NaN"),
    (lambda: fit_gp(np.arange(5.0), np.arange(5.0), kernel="matern"), "expected one of"),
    (lambda: fit_gp(np.arange(5.0), np.arange(5.0), mean="cubic"), "expected one of"),
    (lambda: fit_gp(np.ones(5), np.arange(5.0)), "coincide"),
    (lambda: fit_gp(np.arange(4.0), np.arange(4.0), mean="quadratic"), "at least"),
    (lambda: fit_gp(np.arange(5.0), np.arange(5.0), bounds={"noise_sd_um": (2, 1)}),
     "low <= high"),
    (lambda: gp_components(np.zeros((5, 3)), np.zeros((4, 3))), "expected"),
    (lambda: gp_components(np.zeros((5, 3)), np.zeros((5, 3)), mean="linear",
                           basis=np.ones((5, 1))), "one of them"),
])
def test_bad_input_raises_with_hint(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# ----------------------------------------------------------------- CMM wrappers

def test_components_grid_and_summary(rng):
    """One GP per component on 3-D machine coordinates of two plate placements, predicted
    on a plate grid and a box; summary is JSON-ready with the spec's fields."""
    pl = plate_grid((-200, 200), (-200, 200), 5, origin_mm=(600, 500, 100))
    pv = plate_grid((-200, 200), (-200, 200), 5, origin_mm=(600, 500, 350),
                    u_axis=(1, -1, 0), v_axis=(0, 0, 1))
    P = np.vstack([pl.points_mm, pv.points_mm])
    E = np.column_stack([_surface(P[:, :2]), 0.005 * (P[:, 1] - 500), 1e-5 * P[:, 0] ** 2])
    E = E + 0.2 * rng.standard_normal(E.shape)
    comps = gp_components(P, E, mean="linear", kernel="se_iso", restarts=1, seed=3)
    s = comps.summary()
    assert set(s) == {"x", "y", "z"}
    for c in s.values():
        assert {"length_scale_mm", "signal_sd_um", "noise_sd_um", "log_marginal_likelihood",
                "loo_rms_um"} <= set(c)
    json.dumps(s)
    g = plate_grid((-200, 200), (-200, 200), 11, origin_mm=(600, 500, 100))
    mean, sd = predict_grid(comps, g.points_mm)
    assert mean.shape == sd.shape == (121, 3) and np.all(sd >= 0)
    assert g.surface(mean[:, 0]).shape == (11, 11)
    # at the measured points the posterior mean follows the data to about the noise
    m_obs, _ = predict_grid(comps, P)
    assert np.sqrt(np.mean((m_obs - E) ** 2)) < 0.3
    b = box_grid((400, 300, 100), (800, 700, 350), (3, 4, 5))
    assert b.points_mm.shape == (60, 3) and b.shape == (5, 4, 3)
    mb, sb = predict_grid(comps, b.points_mm)
    assert np.all(np.isfinite(mb)) and np.all(sb > 0)


def test_components_over_kinematic_residuals(rng):
    """Residuals of a (here: linear-in-coordinates) model with its design matrix as the
    GP basis, per component as cmm_core.cli passes it; on a grid without the basis the
    GP part alone (discrepancy) is returned, with the basis the full prediction."""
    P = rng.uniform(0, 400, (40, 2))
    J = np.column_stack([np.ones(40), P / 400])
    E = np.column_stack([np.sin(P[:, 0] / 80), np.cos(P[:, 1] / 70)])
    E = E - J @ np.linalg.lstsq(J, E, rcond=None)[0] + 0.05 * rng.standard_normal(E.shape)
    comps = gp_components(P, E, basis=[J, J], restarts=1)
    assert comps.mean == "basis" and comps.names == ("x", "y")
    assert comps["x"].mean == "matrix" and comps.summary()["x"]["mean_coefficients"] is None
    G = plate_grid((0, 400), (0, 400), 6).points_mm
    Jg = np.column_stack([np.ones(len(G)), G / 400])
    m_gp, s_gp = predict_grid(comps, G)
    m_full, s_full = predict_grid(comps, G, basis_grid=[Jg, Jg])
    beta = np.array([r.mean_coefficients for r in comps.results]).T
    np.testing.assert_allclose(m_full - m_gp, Jg @ beta, atol=1e-9)
    assert np.all(s_full >= s_gp - 1e-12)  # coefficient uncertainty adds variance


def test_appendix3_workflow():
    """Thesis appendix 3 (figures 5.4-5.6): 3×3 plate, zero mean then eq. 5.11 mean, on
    the 21×21 grid over 400..600 mm (step 10 mm as the thesis's z grid)."""
    a = appendix3_workflow(seed=0)
    assert a.points_mm.shape == (9, 2)
    assert a.grid.axes_mm[0][1] - a.grid.axes_mm[0][0] == pytest.approx(10.0)
    for arr in (a.mean_zero_um, a.sd_zero_um, a.mean_quadratic_um, a.sd_quadratic_um,
                a.difference_um):
        assert arr.shape == (21, 21, 3) and np.all(np.isfinite(arr))
    assert a.quadratic["x"].mean_terms == ("1", "x1", "x1^2")
    for comp in (a.zero, a.quadratic):
        for r in comp.results:
            assert r.success and np.isfinite(r.log_marginal_likelihood)
    # balls are grid nodes 0, 10, 20 along each axis; with zero mean the latent posterior
    # variance at a measured point is at most (1/σ_f² + 1/σ_n²)⁻¹ < σ_n², and it grows
    # between the balls. The variance is sf² - vᵀv: when the noise runs to its lower bound
    # that difference cancels to ~1e-8 of sf², so allow 100 eps·sf² of rounding in it.
    balls = a.sd_zero_um[::10, ::10].reshape(9, 3)
    for c, r in enumerate(a.zero.results):
        slack = 100 * np.finfo(float).eps * r.signal_sd_um**2
        assert np.all(balls[:, c] ** 2 <= r.noise_sd_um**2 + slack)
    np.testing.assert_allclose(a.difference_um,
                               np.abs(a.mean_zero_um - a.mean_quadratic_um))


def test_thesis_data_components(thesis):
    """Thesis table 6.1 (BP111) minus the certificate, in plate coordinates: the deviations
    are a few µm (table 6.8), so the GPs' LOO RMS must be finite and at that level."""
    cert = thesis.certificate.xyz_mm
    E = (thesis.plate_frame_table("BP111") - cert) * 1e3
    ok = np.all(np.isfinite(E), axis=1)
    comps = gp_components(cert[ok, :2], E[ok], mean="zero", restarts=1)
    for r in comps.results:
        assert np.isfinite(r.loo_rms_um) and r.loo_rms_um < 20
    mean, sd = predict_grid(comps, plate_grid((0, 400), (0, 400), 9).points_mm)
    assert np.all(np.isfinite(mean)) and np.all(np.isfinite(sd))


def test_paths_from_file():
    assert (ROOT / "cmm_core" / "gp" / "regression.py").exists()


# ----------------------------------------------------------------- length-scale and noise groups

def test_grouped_length_scales_and_noise_groups_match_sklearn(rng):
    """Ram position and probe offset with one length scale each, and one noise level per
    probe: at fixed hyperparameters the model equals scikit-learn's anisotropic RBF with
    the lengths repeated within a group and a per-point noise variance (``alpha``)."""
    sk = pytest.importorskip("sklearn.gaussian_process")
    kernels = pytest.importorskip("sklearn.gaussian_process.kernels")
    probes = np.array([[0, 0, 50], [0, 0, -50], [50, 0, 0.0]])
    which = rng.integers(0, 3, 45)
    which[:3] = (0, 1, 2)
    X = np.column_stack([rng.uniform(0, 500, (45, 3)), probes[which]])
    y = _surface(X) + 0.01 * X[:, 3] + 0.2 * rng.standard_normal(45)
    hyp = {"length_scale_mm": [140.0, 60.0], "signal_sd_um": 2.0,
           "noise_sd_um": [0.2, 0.5, 0.3]}
    groups = (0, 0, 0, 1, 1, 1)
    ours = fit_gp(X, y, groups=groups, noise_groups=which, initial=hyp, optimize=False)
    lml, _ = log_marginal_likelihood(X, y, hyp, groups=groups, noise_groups=which)
    ls = [140.0] * 3 + [60.0] * 3
    alpha = np.array([0.2, 0.5, 0.3])[which] ** 2
    ref = sk.GaussianProcessRegressor(kernels.ConstantKernel(4.0) * kernels.RBF(ls),
                                      alpha=alpha, optimizer=None).fit(X, y)
    assert ours.log_marginal_likelihood == pytest.approx(ref.log_marginal_likelihood_value_,
                                                         abs=1e-8)
    assert lml == pytest.approx(ours.log_marginal_likelihood, abs=1e-10)
    Xt = np.column_stack([rng.uniform(0, 500, (10, 3)), probes[rng.integers(0, 3, 10)]])
    mu, var = ours.predict(Xt)
    mu_ref, sd_ref = ref.predict(Xt, return_std=True)  # alpha is not added at new points
    np.testing.assert_allclose(mu, mu_ref, atol=1e-8)
    np.testing.assert_allclose(var, sd_ref**2, atol=1e-8)
    assert ours.noise_sd_by_group_um == pytest.approx((0.2, 0.5, 0.3))
    assert ours.hyperparameters["noise_sd_um"] == pytest.approx([0.2, 0.5, 0.3])


def test_gradient_with_groups_matches_finite_differences(rng):
    """∂ log p/∂ log θ for two length-scale groups and three noise groups, against
    central differences (step 1e-5 in log θ, 1e-5 relative)."""
    X = np.column_stack([rng.uniform(0, 500, (40, 3)),
                         np.repeat([[0, 0, 50], [0, 0, -50], [0, 50, 0.0]], [14, 13, 13], 0)])
    noise = np.repeat([0, 1, 2], [14, 13, 13])
    y = _surface(X) + 0.3 * rng.standard_normal(40)
    hyp = {"length_scale_mm": [150.0, 80.0], "signal_sd_um": 2.5,
           "noise_sd_um": [0.4, 0.7, 0.3]}
    kw = {"groups": (0, 0, 0, 1, 1, 1), "noise_groups": noise, "mean": "linear"}
    _, g = log_marginal_likelihood(X, y, hyp, **kw)
    flat = [("length_scale_mm", 0), ("length_scale_mm", 1), ("signal_sd_um", None),
            ("noise_sd_um", 0), ("noise_sd_um", 1), ("noise_sd_um", 2)]
    h = 1e-5
    for j, (k, i) in enumerate(flat):
        vals = []
        for sgn in (+1, -1):
            hp = {kk: (list(v) if isinstance(v, list) else v) for kk, v in hyp.items()}
            if i is None:
                hp[k] = hp[k] * np.exp(sgn * h)
            else:
                hp[k][i] = hp[k][i] * np.exp(sgn * h)
            vals.append(log_marginal_likelihood(X, y, hp, **kw)[0])
        assert g[j] == pytest.approx((vals[0] - vals[1]) / (2 * h), rel=1e-5, abs=1e-7)


def test_loo_z_and_coverage_with_noise_groups_match_refits(rng):
    """The standardised LOO residuals with per-group noise against brute-force refits
    (hyperparameters fixed), and the coverage is the share of |z| <= 1.96."""
    X = rng.uniform(0, 400, (24, 2))
    noise = np.repeat([0, 1], 12)
    y = _surface(X) + np.where(noise == 1, 1.0, 0.2) * rng.standard_normal(24)
    hyp = {"length_scale_mm": 90.0, "signal_sd_um": 2.0, "noise_sd_um": [0.2, 1.0]}
    res = fit_gp(X, y, noise_groups=noise, initial=hyp, optimize=False)
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        r_i = fit_gp(X[keep], y[keep], noise_groups=noise[keep], initial=hyp, optimize=False)
        mu, var = r_i.predict(X[[i]])
        z = (y[i] - mu[0]) / np.sqrt(var[0] + [0.2, 1.0][noise[i]] ** 2)
        assert res.loo_z[i] == pytest.approx(z, abs=1e-8)
    assert res.loo_coverage(0.95) == pytest.approx(np.mean(np.abs(res.loo_z) <= 1.959964))


# ----------------------------------------------------------------- degenerate fits (issue 11.6)

def test_collapsed_length_scale_is_degenerate_with_the_next_best_offered(rng):
    """A checkerboard (neighbours anti-correlated, which no SE kernel can say) on a 100 mm
    grid: the likelihood's best length scale runs to its lower bound (the GP is white
    noise). The fit is reported as degenerate, never as converged, and the next-best
    optimum is offered, with a length scale above half the spacing and a lower
    likelihood."""
    g = np.arange(0.0, 600.0, 100.0)
    X = np.array([(a, b) for a in g for b in g])
    y = (-1.0) ** (X.sum(axis=1) / 100) + 0.1 * rng.standard_normal(len(X))
    res = fit_gp(X, y, restarts=2, seed=0)
    assert res.status == "degenerate" and not res.success and res.degenerate
    assert res.smallest_spacing_mm == pytest.approx(100.0)
    assert res.length_scale_mm[0] < 50.0
    assert "white noise" in res.degenerate_reason and "degenerate" in res.message
    alt = res.alternative
    assert alt is not None and alt.alternative is None
    assert alt.length_scale_mm[0] >= 50.0
    # it has no signal either (σ_f at its bound): flagged too, so a page can say so
    assert alt.degenerate and "no signal" in alt.degenerate_reason
    assert alt.log_marginal_likelihood <= res.log_marginal_likelihood + 1e-9
    assert "next-best" in alt.message
    assert res.summary()["alternative"]["length_scale_mm"] == alt.length_scale_mm[0]


def test_thesis_collapsed_gp_is_not_reported_converged(thesis):
    """Issue 11: on the thesis data the Y-error GP over tip coordinates collapsed to
    0.6 mm (the lower bound) against a 133 mm pitch and was reported as converged."""
    from cmm_core.model import fit

    ex = [("BP112", "2", 7), ("BP112", "2", 10), ("BP312", "6", 16)]
    rig = fit(thesis, "rigid", exclude=ex)
    r = gp_components(rig.problem.obs.r_mm, -rig.residuals_um[:, [1]], restarts=1).results[0]
    assert r.length_scale_mm[0] < 1.0
    assert r.status == "degenerate" and "lower bound" in r.degenerate_reason
    # 17 mm: the closest distinct tip positions (balls of different placements); tips
    # closer than 0.6 mm (one ball seen by two placements) count as one location
    assert 15 < r.smallest_spacing_mm < 20
    assert r.alternative is not None and r.alternative.length_scale_mm[0] > 8


def test_smooth_fits_are_not_degenerate(data2d):
    """A smooth surface sampled at random: an interior optimum, status converged."""
    X, y = data2d
    res = fit_gp(X, y, restarts=1)
    assert res.status == "converged" and not res.degenerate and res.alternative is None


def test_thesis_probe_input_loo_coverage_per_component(thesis):
    """Issue 16: with the probe offset as input (ram position and offset, one length
    scale each, one noise level per stylus) the GPs' 95 % leave-one-out intervals cover
    95 ± 2 % of the thesis points in every component (tip coordinates alone: x 93.9,
    z 93.2 % with the y GP collapsed). 147 points: one point is 0.7 %."""
    from cmm_core.model import fit

    ex = [("BP112", "2", 7), ("BP112", "2", 10), ("BP312", "6", 16)]
    rig = fit(thesis, "rigid", exclude=ex)
    o = rig.problem.obs
    comps = gp_components(o.r_mm, -rig.residuals_um, restarts=1, probe_mm=o.p_mm)
    assert comps.probe_input and comps.noise_per_probe
    assert comps.input_dim == 3 and comps.results[0].input_dim == 6
    cov = comps.loo_coverage(0.95)
    assert all(0.93 <= v <= 0.97 for v in cov.values()), cov
    assert not any(r.degenerate for r in comps.results)
    # the styli's noise levels differ several-fold (why one level left points outside);
    # BP112 (probe 2, offset (0, 0, -50)) is the noisiest in x
    k = [tuple(p) for p in comps.probe_offsets_mm].index((0.0, 0.0, -50.0))
    for r in comps.results:
        assert len(r.noise_sd_by_group_um) == 6
        assert max(r.noise_sd_by_group_um) > 3 * min(r.noise_sd_by_group_um)
    assert max(comps["x"].noise_sd_by_group_um) == comps["x"].noise_sd_by_group_um[k]
    # predictions need the stylus; with it they are finite
    with pytest.raises(ValueError, match="probe_mm"):
        predict_grid(comps, o.r_mm[:5])
    mean, sd = predict_grid(comps, o.r_mm[:5], probe_mm=o.p_mm[:5])
    assert np.all(np.isfinite(mean)) and np.all(sd > 0)


def test_one_probe_keeps_tip_inputs(rng):
    X = rng.uniform(0, 500, (30, 3))
    comps = gp_components(X, _surface(X)[:, None], probe_mm=[0, 0, 50], restarts=0)
    assert not comps.probe_input and comps.results[0].input_dim == 3


# ----------------------------------------------------------------- issue 18: speed paths

def test_likelihood_and_gradient_equal_the_dense_textbook_formulas(rng):
    """The likelihood and gradient (one Cholesky, K⁻¹'s lower triangle, the basis part of
    P as WᵀW never formed) against R&W eq. 2.45 and 5.9 written with the full matrices:
    P = K⁻¹ - K⁻¹H A⁻¹ HᵀK⁻¹, ∂/∂θ_j = ½ tr((ααᵀ - P) ∂K_j). Both are exact; the
    difference is round-off of n = 40 dense solves (1e-10 relative)."""
    from cmm_core.gp import regression as gp

    X = rng.uniform(0, 500, (40, 2))
    y = _surface(X) + 0.3 * rng.standard_normal(40)
    groups = rng.integers(0, 2, 40)
    groups[:2] = [0, 1]
    ctx = gp._prepare(X, y, "linear", "se_ard", None, groups)
    p = ctx.prob
    theta = np.array([np.log(0.3), np.log(0.5), 0.2, np.log(0.1), np.log(0.2)])
    f, g = p.objective(theta)

    ell, sf2, sn2 = np.exp(theta[:2]), np.exp(2 * theta[2]), np.exp(2 * theta[3:])
    Kf = sf2 * np.exp(-0.5 * cdist(p.Xs / ell, p.Xs / ell, "sqeuclidean"))
    Ky = Kf + np.diag(sn2[groups])
    Ki = np.linalg.inv(Ky)
    H = p.Q
    A = H.T @ Ki @ H
    P = Ki - Ki @ H @ np.linalg.solve(A, H.T @ Ki)
    a = P @ p.ys
    n, m = p.n, H.shape[1]
    lml = (-0.5 * p.ys @ a - 0.5 * np.linalg.slogdet(Ky)[1] - 0.5 * np.linalg.slogdet(A)[1]
           - 0.5 * (n - m) * np.log(2 * np.pi))
    dK = [Kf * (X[:, [i]] - X[:, i]) ** 2 / (ctx.x_scale * ell[i]) ** 2 for i in range(2)]
    dK += [2 * Kf] + [np.diag(2 * sn2[k] * (groups == k)) for k in range(2)]
    M = np.outer(a, a) - P
    grad = np.array([0.5 * np.sum(M * D) for D in dK])
    assert -f == pytest.approx(lml, rel=1e-10)
    np.testing.assert_allclose(-g, grad, rtol=1e-9, atol=1e-10 * np.abs(grad).max())


def test_restarts_are_a_latin_hypercube_over_the_whole_bounds(data2d, monkeypatch):
    """Each restart coordinate falls in its own one of ``restarts`` equal strata of the
    (log) bounds: the short and long ends of every range are searched."""
    from cmm_core.gp import regression as gp

    seen = {}
    real = gp._optimise

    def spy(prob, sub, lo, hi, points):
        seen.update(lo=lo, hi=hi, points=np.array(points))
        return real(prob, sub, lo, hi, points)

    monkeypatch.setattr(gp, "_optimise", spy)
    X, y = data2d
    fit_gp(X, y, restarts=8, seed=2)
    u = (seen["points"][1:] - seen["lo"]) / (seen["hi"] - seen["lo"])
    assert u.shape == (8, 3)
    for col in u.T:
        assert sorted(np.floor(col * 8).astype(int)) == list(range(8))


def test_subset_then_polish_finds_the_direct_optimum(rng, monkeypatch):
    """n = 700 > 600: the starts run on 300 points and the optimum is polished on all
    700. Against L-BFGS-B from every start on all points (the subset switched off): the
    same optimum, log ML no lower (1e-9: both stop on a gradient of 1e-5 where the
    Hessian is ~1e3, a log ML error ~1e-13), hyperparameters to 1e-5 relative (step
    ~g/H = 1e-8 in log units, with margin for the flat σ_f-length direction), in fewer
    evaluations on all the points."""
    from cmm_core.gp import regression as gp

    X = rng.uniform(0, 500, (700, 2))
    y = _surface(X) + 0.3 * rng.standard_normal(700)
    fast = fit_gp(X, y, restarts=1, seed=0)
    monkeypatch.setattr(gp, "_PREFIT_POINTS", 10**6)
    direct = fit_gp(X, y, restarts=1, seed=0)
    assert fast.status == direct.status == "converged"
    assert fast.log_marginal_likelihood >= direct.log_marginal_likelihood - 1e-9
    for k in ("length_scale_mm", "signal_sd_um", "noise_sd_um"):
        np.testing.assert_allclose(fast.hyperparameters[k], direct.hyperparameters[k],
                                   rtol=1e-5, err_msg=k)
    assert fast.n_evaluations < direct.n_evaluations


"""Coverage of the stated uncertainties of the predicted error over simulated data sets.

Issue 13: nominal 95 % intervals of the model-minus-measurement difference at the fitted
balls covered 97.2 %. The cause was the combination ``√(u_model² + σ²)``, which treats
prediction and measurement as independent; at a ball the model was fitted to they share
its noise and the difference is the fit's residual, of standard deviation
``σ √(1 − h_ii)`` (``uncertainty.residual_u``).

Reference values: a 95 % interval covers 95 %; 60 data sets × 450 balls × 3 components
with the plate free. Residuals of one fit are nearly independent, so the standard error
of the coverage is about √(0.95·0.05/(60·1350)) ≈ 0.08 %; the issue's ±1.5 % band is
loose. The predicted error against the true error at random points is strongly
correlated within a data set (about 4 independent values per set, as the issue's
±0.55 % over 200 sets shows), so 200 sets give a standard error of about 0.5 %.
"""

import numpy as np
import pytest

from cmm_core.machine import kinematics as kin
from cmm_core.model import aligned_error_u, error_at, fit, residual_u, simulate

EXACT = {"plate": {"form_um": 2.0, "certificate_u_um": 0.0}}
K95 = 1.959964  # two-sided 95 % quantile of the standard normal


@pytest.fixture(scope="module")
def free_fits():
    return [fit(simulate({"seed": 1000 + s, **EXACT}).dataset, "kinematic21", plate="free")
            for s in range(60)]


def test_model_minus_measurement_at_fitted_balls_covers_95_percent(free_fits):
    new, old = [], []
    for r in free_fits:
        d = r.residuals_um  # = rigid-aligned prediction minus rigid-aligned measurement
        new.append(np.abs(d) <= K95 * residual_u(r))
        old.append(np.abs(d) <= K95 * np.hypot(aligned_error_u(r), r.sigma_um))
    cover = 100 * np.mean(np.concatenate(new))
    print(f"coverage {cover:.2f} %")
    assert 93.5 <= cover <= 96.5, cover
    # the old combination over-covers: the reason for the issue (97.1 % measured)
    assert 100 * np.mean(np.concatenate(old)) > 96.5


def test_residual_u_matches_the_spread_of_residuals_over_noise_draws():
    """Same truth, fresh noise: the standard deviation of each residual over 60 data sets
    agrees with σ√(1 − h) to the sampling error of a 60-draw sd (9 %); the median ratio
    over all residuals to 2 %."""
    truth = simulate({"seed": 0, **EXACT}).truth
    cfg = {"kinematic": {"coefficients": truth, "random_um": 0, "random_urad": 0},
           "plate": {"form_um": 0.0, "certificate_u_um": 0.0}}
    res = []
    for s in range(60):
        r = fit(simulate({"seed": 500 + s, **cfg}).dataset, "kinematic21")
        res.append(r.residuals_um)
    sd = np.std(res, axis=0, ddof=1)
    ratio = sd / residual_u(r)
    assert np.median(ratio) == pytest.approx(1.0, abs=0.02)
    assert (residual_u(r) < r.sigma_um).all()


@pytest.mark.slow
def test_predicted_error_covers_the_true_error_95_percent():
    """error_at's u against the true error at 50 random points of the measured region,
    200 data sets with random true errors (plate fixed to an exact certificate)."""
    hits = []
    for s in range(200):
        sim = simulate({"seed": 1000 + s, **EXACT})
        r = fit(sim.dataset, "kinematic21")
        labs, _, _ = r.block("kinematic")
        true = np.array([sim.truth[lab] for lab in labs])
        obs = r.problem.obs
        x = obs.r_mm - obs.p_mm
        pts = np.random.default_rng(s).uniform(x.min(0), x.max(0), (50, 3))
        e, u = error_at(r, pts, obs.probes[0])
        p = np.broadcast_to(sim.dataset.setup.probes[obs.probes[0]], pts.shape)
        hits.append(np.abs(e - kin.error(r.terms, true, pts, p)) <= K95 * u)
    cover = 100 * np.mean(np.concatenate(hits))
    print(f"coverage {cover:.2f} %")
    assert 93.5 <= cover <= 96.5, cover

"""The forward model: analytic Jacobian against finite differences, basis constraints."""

import numpy as np
import pytest

from cmm_core.machine import ERROR_NAMES, SQUARENESS, STRAIGHTNESS, KinematicTerms, axis_of, basis
from cmm_core.machine import kinematics as kin
from cmm_core.model import parse_spec

RANGE = (1200.0, 1000.0, 700.0)


def _terms(order, spec="kinematic21"):
    m = parse_spec(spec, default_order=order)
    return KinematicTerms(m.active, RANGE, m.periods)


@pytest.mark.parametrize("order", [1, 2, 3, 5])
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("spec", ["kinematic21", "kinematic21,-dyy,periodic_x:150,periodic_y:90"])
def test_jacobian_matches_central_differences(order, seed, spec):
    rng = np.random.default_rng(seed)
    terms = _terms(order, spec)
    # Large coefficients (50 µm, 50 µrad) so that rotation nonlinearity is exercised.
    coef = rng.normal(0, 50, terms.n)
    x = rng.uniform(0, 1, (20, 3)) * RANGE
    p = rng.normal(0, 100, (20, 3))
    _, J = kin.jacobian(terms, coef, x, p)
    # Step 0.1 µm or µrad: round-off of coordinates near 1000 mm (2e-13 mm) over 2h is
    # 1e-12 mm, and the truncation error (h² times third derivatives of rotations) is smaller.
    h = 0.1
    for j in range(terms.n):
        e = np.zeros(terms.n)
        e[j] = h
        fd = (kin.model_point(terms, coef + e, x, p) - kin.model_point(terms, coef - e, x, p))
        fd /= 2 * h
        np.testing.assert_allclose(J[:, :, j], fd, atol=1e-11, rtol=1e-7,
                                   err_msg=terms.labels[j])


def test_error_functions_are_zero_at_origin_and_straightness_at_both_ends():
    for name in ERROR_NAMES:
        if name in SQUARENESS:
            continue
        stroke = RANGE[axis_of(name)]
        B = basis(name, np.array([0.0, stroke]), 4, stroke)
        assert np.allclose(B[0], 0, atol=1e-12)
        if name in STRAIGHTNESS:
            assert np.allclose(B[1], 0, atol=1e-12)  # no linear term
        else:
            assert not np.allclose(B[1], 0)


def test_single_errors_act_as_the_spec_says():
    """Squareness sxy adds sxy*y to x; positioning dxx adds to x; a z-yaw moves the tip by
    rzz × probe lever arm (thesis fig. 4.10)."""
    terms = _terms(2)
    x = np.array([[100.0, 500.0, 300.0]])
    p = np.array([[50.0, 0.0, -100.0]])
    coef = np.zeros(terms.n)
    coef[terms.slices["sxy"]] = 10.0  # µrad
    e = kin.error(terms, coef, x, p)
    np.testing.assert_allclose(e, [[10e-6 * 500 * 1e3, 0, 0]], atol=1e-9)
    coef[:] = 0
    coef[terms.slices["rzz"].start] = 5.0  # first Chebyshev coefficient, µrad
    ang = terms.design("rzz", x[:, 2]) @ coef[terms.slices["rzz"]] * 1e-6
    e = kin.error(terms, coef, x, p)
    np.testing.assert_allclose(e[0, 1], ang[0] * 50 * 1e3, rtol=1e-6)


def test_invert_reaches_the_target(rng):
    terms = _terms(3)
    coef = rng.normal(0, 20, terms.n)
    s = rng.uniform(0, 1, (50, 3)) * RANGE
    p = rng.normal(0, 80, (50, 3))
    x = kin.invert(terms, coef, s, p)
    assert np.abs(kin.model_point(terms, coef, x, p) - s).max() < 1e-10


def test_periodic_scale_error_acts_along_its_axis():
    """periodic_x:200 adds s·sin(2πx/200) + c·(cos(2πx/200) - 1) µm to x (zero at the
    origin), with labels by period; dyy absent still carries its periodic term."""
    terms = _terms(2, "kinematic21,-dyy,periodic_x:200,periodic_y:50")
    assert "dxx[sin200]" in terms.labels and "dyy[cos50]" in terms.labels
    assert not any(lab.startswith("dyy[1") for lab in terms.labels)
    coef = np.zeros(terms.n)
    coef[terms.labels.index("dxx[sin200]")] = 2.0
    coef[terms.labels.index("dxx[cos200]")] = 1.0
    x = np.array([[0.0, 10.0, 10.0], [50.0, 10.0, 10.0], [100.0, 10.0, 10.0]])
    e = kin.error(terms, coef, x, np.zeros((3, 3)))
    np.testing.assert_allclose(e[:, 0], [0.0, 2.0 - 1.0, 0.0 - 2.0], atol=1e-9)
    np.testing.assert_allclose(e[:, 1:], 0.0, atol=1e-9)


def _reference_point(terms, coef, x, p):
    """x*(x, p) of the module docstring, one point at a time with explicit 3×3 matrices."""
    def rot(a, b, c):
        ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
        Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
        Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
        Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
        return Rz @ Ry @ Rx

    out = np.empty_like(x)
    sl = terms.slices
    for i in range(len(x)):
        c = coef[i] if coef.ndim == 2 else coef

        def v(name, i=i, c=c):
            if name not in sl:
                return 0.0
            return float(terms.design(name, x[i:i + 1, axis_of(name)])[0] @ c[sl[name]])
        R = {a: rot(*(v(f"r{a}{b}") * 1e-6 for b in "xyz")) for a in "xyz"}
        X = np.array([x[i, 0] + v("dxx") * 1e-3, v("dxy") * 1e-3, v("dxz") * 1e-3])
        Y = np.array([v("dyx") * 1e-3 + v("sxy") * 1e-6, x[i, 1] + v("dyy") * 1e-3,
                      v("dyz") * 1e-3])
        Z = np.array([v("dzx") * 1e-3 + v("sxz") * 1e-6, v("dzy") * 1e-3 + v("syz") * 1e-6,
                      x[i, 2] + v("dzz") * 1e-3])
        out[i] = X + R["x"] @ (Y + R["y"] @ (Z + R["z"] @ p[i]))
    return out


def test_blocked_forward_model_equals_point_by_point_reference(rng):
    """The forward model (rotation component arrays, blocks of 4096 points) against the
    module docstring's formula evaluated point by point with 3×3 matrices, on 9000 points
    (three blocks) and with one coefficient set per point (Monte Carlo). Tolerance 1e-11
    mm: round-off of a few operations on coordinates up to 1200 mm (2.7e-13 mm each)."""
    terms = _terms(3, "kinematic21,periodic_x:150")
    x = rng.uniform(0, 1, (9000, 3)) * RANGE
    p = rng.normal(0, 100, (9000, 3))
    coef = rng.normal(0, 50, terms.n)
    got = kin.model_point(terms, coef, x, p)
    pick = np.r_[0:5, 4094:4099, 8995:9000]  # around the block boundaries
    np.testing.assert_allclose(got[pick], _reference_point(terms, coef, x[pick], p[pick]),
                               atol=1e-11, rtol=0)
    xs, _ = kin.jacobian(terms, coef, x, p)
    np.testing.assert_array_equal(xs, got)
    many = rng.normal(0, 50, (12, terms.n))
    np.testing.assert_allclose(kin.model_point(terms, many, x[:12], p[:12]),
                               _reference_point(terms, many, x[:12], p[:12]), atol=1e-11, rtol=0)
    Rp = kin.probe_jacobian(terms, coef, x[pick])
    np.testing.assert_allclose(Rp @ np.swapaxes(Rp, 1, 2), np.broadcast_to(np.eye(3), Rp.shape),
                               atol=1e-15)

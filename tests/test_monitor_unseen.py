"""What an interim check cannot see, in words (``monitor.unseen``): constructed null
spaces named by the errors that carry them, and real one-placement checks whose words
name the axis normal to the plate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg
from test_monitor import calibrated

from cmm_core.machine import KinematicTerms
from cmm_core.monitor import (
    MIN_RESOLVED,
    combination_text,
    distinct_words,
    interim_check,
    remeasured,
    run_check,
    unseen_words,
    what_changed,
)

# the labels of kinematic21 at order 2 (the sample models' and the tests' spec)
LABELS = KinematicTerms(tuple((n, 2) for n in (
    "dxx", "dxy", "dxz", "dyx", "dyy", "dyz", "dzx", "dzy", "dzz", "rxx", "rxy", "rxz",
    "ryx", "ryy", "ryz", "rzx", "rzy", "rzz", "sxy", "sxz", "syz")),
    (1000.0, 800.0, 600.0)).labels


def _direction(**weights) -> np.ndarray:
    """A direction over LABELS from ``label=weight`` (``dzz_1`` for ``dzz[1]``)."""
    v = np.zeros(len(LABELS))
    for key, w in weights.items():
        base, _, k = key.partition("_")
        v[LABELS.index(f"{base}[{k}]" if k else base)] = w
    return v


def test_a_direction_along_one_parameter_is_that_error():
    words = unseen_words(np.vstack([_direction(dzz_1=1.0), _direction(sxy=-3.0),
                                    _direction(ryy_1=0.5), _direction(dxy_2=1.0),
                                    _direction(rzx_2=2.0)]), LABELS)
    assert words[0] == "the z scale (dzz linear)"
    assert words[1] == "the xy squareness (sxy)"  # sign and scale do not matter
    assert words[2] == "the y carriage's roll (ryy linear)"
    assert words[3] == "the x straightness in y (dxy[2])"
    assert words[4] == "the curvature of the z carriage's tilt about x (rzx[2])"
    # weights below a quarter of the largest do not carry the direction
    assert unseen_words([_direction(dzz_1=1.0, sxy=0.1)], LABELS) == words[:1]


def test_a_mix_of_functions_of_one_axis_is_anything_that_varies_only_with_it():
    (w,) = unseen_words([_direction(dzz_1=1.0, dzy_2=-0.6, rzx_1=0.5)], LABELS)
    assert w.startswith("anything that varies only with z: "), w
    assert "the z scale (dzz linear)" in w and "the z straightness in y (dzy[2])" in w
    assert "the z carriage's tilt about x (rzx linear)" in w
    # sxz (x readings in proportion to z) varies with z alone too
    (w,) = unseen_words([_direction(dzz_2=1.0, sxz=0.8)], LABELS)
    assert w.startswith("anything that varies only with z: ") and "xz squareness" in w
    # the orders of one function are one error: the scale and its curvature
    (w,) = unseen_words([_direction(dzz_2=1.0, dzz_1=-0.9)], LABELS)
    assert w == "the z scale and its curvature (dzz linear, dzz[2])"


def test_a_mix_of_axes_names_each_error_and_the_numbers_stay_for_experts():
    v = _direction(syz=1.0, ryx_2=-0.4)
    (w,) = unseen_words([v], LABELS)
    assert w == ("the yz squareness (syz) together with the curvature of the y carriage's "
                 "pitch about x (ryx[2])")
    assert combination_text(-v, LABELS) == "1.00 syz - 0.40 ryx[2]"
    # a label outside the 21 errors is named as it is; a periodic term by its period
    (w,) = unseen_words([[1.0, 0.5]], ["drift_x", "dxx[sin200]"])
    assert w == "drift_x together with the periodic error of 200 mm of the x scale " \
                "(dxx[sin200])"
    with pytest.raises(ValueError, match="3 weights"):
        unseen_words([[1.0, 0.0]], LABELS[:3])
    assert distinct_words(["a", "b", "a"]) == [("a", 2), ("b", 1)]


@pytest.mark.parametrize("position, normal", [("H0", "z"), ("V1", "y"), ("V2", "x")])
def test_one_placement_cannot_see_its_normal_axis_and_says_so_in_words(position, normal):
    # one plate placement at one height (H0: the xy plane at z = 50 mm; V1 the xz plane,
    # V2 the yz plane) hardly sees an error that varies only with the coordinate normal
    # to it: each is a constant over the plate, taken up by the pose
    cal, model = calibrated("pitch100_4pos", 1)
    data = remeasured(cal, 41, probes_per_position={
        position: cal.config["probes_per_position"][position]}).dataset
    check = interim_check(model, data)
    ch = what_changed(model, check)
    assert ch.unseen and len(ch.unseen) == len(ch.unseen_combinations)
    assert ch.unseen_directions.shape == (len(ch.unseen), len(model.coef))
    assert any(f"the {normal} scale" in w or f"varies only with {normal}" in w
               for w in ch.unseen), ch.unseen
    # the words are the message's; no basis vector is printed there
    assert "e.g. " + ch.unseen[0] in ch.message
    assert not any(c in ch.message for c in ch.unseen_combinations)
    # every direction (varimax-rotated within the unseen subspace) is still unseen: the
    # new data resolve less than MIN_RESOLVED of its prior variance
    V = model.cov
    sd = np.sqrt(np.diag(V))
    sys, g = check.system, check.gls
    SiA, SiJ = linalg.cho_solve(g.factor, sys.A), linalg.cho_solve(g.factor, sys.J)
    PiJ = SiJ - SiA @ np.linalg.solve(sys.A.T @ SiA, sys.A.T @ SiJ)
    H = sys.J.T @ PiJ
    for v in ch.unseen_directions:
        # the direction in the parameters' own units; in the prior's whitened coordinates
        # (V = L Lᵀ, w = L⁻¹ δ) the fraction resolved is wᵀ Lᵀ H L w / wᵀ w
        delta = v * sd
        assert delta @ H @ delta / (delta @ np.linalg.solve(V, delta)) < MIN_RESOLVED


def test_the_results_carry_words_and_combinations():
    cal, model = calibrated("pitch100_4pos", 1)
    data = remeasured(cal, 41, probes_per_position={"H0": ["A", "B"]}).dataset
    out = run_check(model, data, mpe=(0.6, 600))
    sec = out.results_section()["changes"]
    assert sec["unseen"] == out.changes.unseen
    assert sec["unseen_combinations"] == out.changes.unseen_combinations
    assert all(any(ch.isdigit() for ch in c) for c in sec["unseen_combinations"])
    d = out.to_dict()
    assert d["changes"]["unseen_combinations"] and d["changes"]["unseen"]
    assert out.verdict.startswith("partial") and "e.g. " + out.changes.unseen[0] in out.message
    assert out.conformity is not None and out.conformity.unseen == out.changes.unseen

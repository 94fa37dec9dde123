"""The fit's undetermined combinations in words (issue 41): what a metrologist reads in
place of "−1.00·B2.tz − 1.00·B1.tz − 1.00·probeG1.z"."""

import numpy as np
import pytest

from cmm_core.io import thesis_dataset
from cmm_core.machine import ROTATIONAL
from cmm_core.model import (
    direction_phrase,
    distinct_words,
    fit,
    null_carriers,
    null_words,
    parameter_name,
    simulate,
)

LABELS = ["B1.tz", "B2.tz", "probeG1.z", "probeG2.z", "dzz[1]", "dzz[2]", "ryz[1]", "sxy",
          "B10.tz", "B1.rx", "B1.drift_z", "plate_sag.uu", "probeG10.z"]




@pytest.mark.parametrize(("weights", "said"), [
    # the styli's offsets and the placements' heights, each group once, in natural order
    ({"B2__tz": -1.0, "B1__tz": -1.0, "probeG1__z": -1.0, "B10__tz": 0.9},
     "The z positions of placements B1, B2 and B10 and the z offset of stylus G1 cannot "
     "be told apart."),
    ({"probeG10__z": 1.0, "probeG2__z": 0.8, "B1__tz": 0.5},
     "The z offsets of styli G2 and G10 and the z position of placement B1 cannot be told "
     "apart."),
    # one parameter alone
    ({"ryz[1]": 1.0, "sxy": 0.1}, "The y carriage's yaw about z (ryz linear) is not "
                                  "determined."),
    # one function, two terms; then functions of one axis only say so
    ({"dzz[1]": 1.0, "dzz[2]": -0.7}, "The z scale and its curvature (dzz linear, dzz[2]) "
                                      "cannot be told apart."),
    # a rotation of a placement, a drift and another effect's parameter by its title
    ({"B1__rx": 1.0, "B1__drift_z": 0.6, "plate_sag__uu": 0.5},
     "The rotation about x of placement B1, the z drift of placement B1 and the plate sag "
     "(gravity bending) (plate_sag.uu) cannot be told apart."),
])
def test_a_combination_is_said_in_words(weights, said):
    v = np.zeros(len(LABELS))
    for lab, x in weights.items():
        v[LABELS.index(lab.replace("__", "."))] = x
    assert null_words(v.reshape(-1, 1), LABELS) == [said]
    # the sign and the scale of a null vector do not matter
    assert null_words(-3.0 * v.reshape(-1, 1), LABELS) == [said]


def test_a_weight_below_a_quarter_of_the_largest_is_not_a_carrier():
    v = np.zeros(len(LABELS))
    v[LABELS.index("sxy")], v[LABELS.index("ryz[1]")] = 1.0, 0.24
    assert direction_phrase(v, LABELS) == "the xy squareness (sxy)"
    v[LABELS.index("ryz[1]")] = 0.26
    assert "ryz linear" in direction_phrase(v, LABELS)


def test_a_combination_of_many_parameters_counts_those_it_does_not_name():
    """One stylus aliased with twenty placements: twelve named, the rest counted."""
    labels = ["probe1.z"] + [f"B{i}.tz" for i in range(1, 21)]
    [said] = null_words(np.ones((21, 1)), labels)
    assert said.endswith("and 9 more parameters cannot be told apart."), said
    assert "B11" in said and "B12" not in said
    # the carriers of a sentence are the labels it names
    assert null_carriers(np.ones((21, 1)), labels) == [tuple(labels[:12])]


def test_a_periodic_error_s_two_terms_are_its_phase():
    labels = ["dxx[sin200]", "dxx[cos200]"]
    assert null_words(np.array([[1.0], [0.8]]), labels) == [
        "The periodic error of 200 mm of the x scale (dxx[cos200], dxx[sin200]): its sine "
        "and cosine terms cannot be told apart."]


def test_an_interim_check_s_phrase_puts_functions_of_one_axis_side_by_side():
    """The interim check's words as before they moved into the model wing (checked then
    against the old code on 20 000 random directions): the z functions together, then
    the x scale, whatever their weights' order."""
    v = np.array([1.0, 0.9, 0.8])
    assert direction_phrase(v, ["dzz[1]", "dxx[1]", "rzx[1]"]) == (
        "the z scale (dzz linear) together with the z carriage's tilt about x (rzx linear) "
        "and the x scale (dxx linear)")


def test_functions_of_one_axis_say_so():
    labels = ["dzz[2]", "rzx[1]", "dxx[1]"]
    v = np.array([1.0, 0.8, 0.0])
    assert null_words(v.reshape(-1, 1), labels) == [
        "The curvature of the z scale (dzz[2]) and the z carriage's tilt about x (rzx "
        "linear) cannot be told apart (each varies only with z)."]
    assert direction_phrase(v, labels).startswith("anything that varies only with z: ")


def test_the_fit_says_its_undetermined_combinations_in_words():
    """A probe offset on styli measured one after another per placement (the sample's
    design): the offsets and the placements' positions alias; every combination is said in
    words naming styli and placements, and the fit's message uses the words."""
    r = fit(simulate({"seed": 3}).dataset, "kinematic21,probe_offset")
    assert r.null_combinations and len(r.null_words) == len(r.null_combinations)
    for w in r.null_words:
        assert "·" not in w and w.endswith("cannot be told apart.")
        assert "offset" in w and ("stylus" in w or "styli" in w)
        assert "placement" in w
    assert r.null_words[0] in r.message and "·" not in r.message


def test_a_single_placement_names_the_functions_it_cannot_see():
    r = fit(thesis_dataset(), "kinematic21", positions=["BP111"])
    words = [w for w, _ in distinct_words(r.null_words)]
    # the z axis's own functions: a plate at one height sees none of them
    assert "The z scale and its curvature (dzz linear, dzz[2]) cannot be told apart." in words
    assert all("·" not in w for w in words)


def test_distinct_words_count_repeats_in_order():
    assert distinct_words(["a", "b", "a"]) == [("a", 2), ("b", 1)]


@pytest.mark.parametrize(("label", "name"), [
    ("dzz[1]", "z scale"), ("dzz[2]", "z scale, degree 2"),
    ("ryz[1]", "y carriage's yaw about z"), ("ryx[1]", "y carriage's pitch about x"),
    ("ryy[1]", "y carriage's roll"), ("rzx[1]", "z carriage's tilt about x"),
    ("sxy", "xy squareness"), ("probeA.y", "y offset of stylus A"),
    ("B1.tz", "z position of placement B1"), ("B1.drift_x", "x drift of placement B1"),
    ("plate_sag.uu", "plate sag (gravity bending): uu"), ("no_such", "no_such"),
    ("dxx[3]", "x scale, degree 3"), ("dxy[2]", "x straightness in y, degree 2"),
    ("dxx[sin50]", "x scale, sine of period 50 mm"),
    ("dxx[cos50]", "x scale, cosine of period 50 mm"),
    ("dxx[0]", "x scale (dxx[0])"), ("dxx", "x scale (dxx)"),
])
def test_every_parameter_has_a_name(label, name):
    """The Kinematic page's parameter table names each code (one naming of rotations:
    ISO 230-1's roll, pitch, yaw and tilt, never two rotations called the same)."""
    assert parameter_name(label) == name


def test_no_two_rotations_share_a_name():
    names = [parameter_name(f"{r}[1]") for r in ROTATIONAL]
    assert len(set(names)) == len(names) == 9

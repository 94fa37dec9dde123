"""A non-rigid effect added as one block and one registry line (issue 26): the bridge's
roll under the moving carriage (``blocks.bridge_twist``), simulated, fitted, diagnosed and
compensated on the layouts with a moving bridge."""

import numpy as np
import pytest
import scenarios as sc
from conftest import part_correction

from cmm_core.diagnosis import diagnose
from cmm_core.export import model_from_dict, model_to_dict
from cmm_core.model import catalogue_entry, fit, simulate

TWIST = {"lin_urad": 8.0, "quad_urad": 4.0, "cub_urad": -3.0}
"""Roll at the strokes' corners (µrad): a few µrad, as a bridge of a 1 m CMM rolls when
its carriage crosses it."""


def _sim(layout, seed, effects=None, name="pitch100_4pos"):
    cfg = sc.layout_config(name, seed=seed,
                           effects={"bridge_twist": TWIST} if effects is None else effects)
    cfg["setup"]["machine"]["layout"] = layout
    return simulate(cfg)


@pytest.mark.parametrize("layout", ["moving_bridge_fxyz", "gantry_fyxz"])
def test_the_twist_is_recovered_within_3u(layout):
    sim = _sim(layout, 5)
    r = fit(sim.dataset, "kinematic21,bridge_twist")
    lab, v, u = r.block("bridge_twist")
    truth = np.array([sim.truth[k] for k in lab])
    assert list(lab) == ["bridge_twist.lin", "bridge_twist.quad", "bridge_twist.cub",
                         "bridge_twist.lin_h", "bridge_twist.quad_h", "bridge_twist.cub_h"]
    assert np.all(np.abs(v - truth) < 3 * u), (v, truth, u)
    assert not r.fails_chi2_test


@pytest.mark.parametrize("layout", ["moving_bridge_fxyz", "gantry_fxyz", "gantry_fyxz"])
@pytest.mark.parametrize("seed", [3, 4])
def test_the_diagnosis_names_the_twist_not_a_higher_rigid_order(layout, seed):
    """A kinematic21 baseline on twisted data: the verdict is bridge_twist, not a higher
    order of a rigid function (rzy:3, rzx:4 ...) that the coupling of two axes would
    otherwise be bent into."""
    d = diagnose(_sim(layout, seed).dataset, "kinematic21")
    assert d.verdict == "bridge_twist", [(c.effect, c.p_value) for c in d.candidates[:4]]


def test_a_fixed_bridge_has_no_twist_and_says_why():
    sim = _sim("fixed_bridge_xfyz", 3, effects={})
    d = diagnose(sim.dataset, "kinematic21")
    assert "fixed_bridge_xfyz" in d.skipped["bridge_twist"]


@pytest.mark.parametrize("token, layout", [
    ("bridge_twist", "fixed_bridge_xfyz"), ("column_bend", "moving_bridge_fxyz"),
    ("column_bend", "gantry_fxyz"), ("column_bend", "fixed_bridge_xfyz")])
def test_a_layout_block_on_a_layout_without_it_fits_nothing_and_saves_no_part(token,
                                                                                layout):
    """``blocks.LayoutBlock``: the spec may name the block on any layout; where the machine
    has none it adds no column, says so in the fit's message, and the saved model has no
    part (read back as such)."""
    sim = _sim(layout, 3, effects={})
    r = fit(sim.dataset, f"kinematic21,{token}")
    assert token not in r.problem.layout.blocks
    assert f"{token} adds nothing determinable" in r.message
    m = model_from_dict(model_to_dict(r))
    assert token not in m.parts


def test_the_twist_needs_both_strokes_covered():
    sim = _sim("moving_bridge_fxyz", 3, effects={}, name="pitch80_3pos")
    sub = fit(sim.dataset, "kinematic21", positions=["H"])
    from cmm_core.model import BY_TOKEN
    why = BY_TOKEN["bridge_twist"].needs(sub.problem.obs)
    assert why is None or "stroke" in why


def test_new_points_are_corrected_for_the_twist():
    """Compensated points: the correction's twist part is the fitted term at the points'
    readings, through the saved model file."""
    sim = _sim("moving_bridge_fxyz", 6)
    r, m, delta, r_mm, p = part_correction(sim.dataset, "bridge_twist")
    part = m.parts["bridge_twist"]
    assert part.context["layout"] == "moving_bridge_fxyz"
    np.testing.assert_allclose(part.values, r.block("bridge_twist")[1])
    from cmm_core.model.blocks.bridge_twist import basis, direction_um
    u = r_mm - p
    B = basis(u, m.terms.range_mm, "moving_bridge_fxyz")
    # the roll about x through z = 0, and the height terms' shear e_x × (−1 m e_z) =
    # +1000 mm e_y per rad: 1 µm along y per µrad
    want = (B @ part.values[:3])[:, None] * direction_um(r_mm, u, "moving_bridge_fxyz") + \
        (B @ part.values[3:])[:, None] * np.array([0.0, 1.0, 0.0])
    np.testing.assert_allclose(delta, want, atol=1e-9)
    assert np.abs(want).max() > 1.0  # the twist moves points by µm


def test_a_model_file_of_the_first_two_shapes_still_corrects_with_them():
    """Files saved before the cubic family (issue 26) hold 4 twists of the shapes s·v and
    (1 − s²)² v with their height terms: read with those labels and corrected with those
    shapes, not the new ones."""
    from cmm_core.model.blocks.bridge_twist import (
        OLD_LABELS,
        BridgeTwist,
        basis,
        direction_um,
    )

    sim = _sim("moving_bridge_fxyz", 6)
    r = fit(sim.dataset, "kinematic21,bridge_twist")
    d = model_to_dict(r)
    n_before = len(d["bridge_twist"]["cov_joint"]) - 6
    old_t = [5.0, -2.0, 1.0, 0.5]
    cov = np.asarray(d["bridge_twist"]["cov_joint"])[: n_before + 4, : n_before + 4]
    part = BridgeTwist.part_from_file({**d, "bridge_twist": {
        "twist_urad": old_t, "cov_joint": cov.tolist()}}, n_before, "old.json")
    assert part.labels == OLD_LABELS
    pts = sim.dataset.meas[["probe", "mx_mm", "my_mm", "mz_mm"]].rename(
        columns={"mx_mm": "x_mm", "my_mm": "y_mm", "mz_mm": "z_mm"}).iloc[:20]
    r_mm = pts[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    u = r_mm - np.array([r.problem.obs.p_mm[0]] * len(pts))
    B = basis(u, part.context["range_mm"], "moving_bridge_fxyz", old=True)
    assert B.shape == (20, 2)
    want = (B @ old_t[:2])[:, None] * direction_um(r_mm, u, "moving_bridge_fxyz") + \
        (B @ old_t[2:])[:, None] * np.array([0.0, 1.0, 0.0])
    got = BridgeTwist.correct(part, pts, u, "old.json")
    np.testing.assert_allclose(got.delta_um, want, atol=1e-9)
    # the old shapes move the points by tenths of µm here, and not as the new ones would
    assert np.abs(want).max() > 0.2
    new = basis(u, part.context["range_mm"], "moving_bridge_fxyz")[:, :2] @ old_t[:2]
    assert np.abs(new - B @ old_t[:2]).max() > 0.1


def test_the_catalogue_says_what_it_is_confused_with():
    e = catalogue_entry("bridge_twist")
    assert "rigid" in e.explanation and "rxx" in e.confused_with and e.separate_by


@pytest.mark.parametrize("layout,name", [("gantry_fxyz", "pitch150_5pos"),
                                         ("moving_bridge_fxyz", "pitch100_4pos")])
def test_a_roll_about_a_raised_line_is_the_twist_with_its_height(layout, name):
    """A gantry rolls on rails at the top of its stroke (900 mm above the machine's
    z = 0): the same roll about that line. Its height terms recover t·z0/1 m (within 3 u)
    and the diagnosis names the twist (it named plate_sag before the height terms)."""
    sim = _sim(layout, 7, effects={"bridge_twist": {**TWIST, "axis_height_mm": 900.0}},
               name=name)
    r = fit(sim.dataset, "kinematic21,bridge_twist")
    lab, v, u = r.block("bridge_twist")
    truth = np.array([sim.truth[k] for k in lab])
    np.testing.assert_allclose(truth[3:], 0.9 * truth[:3])
    assert np.all(np.abs(v - truth) < 3 * u), (v, truth, u)
    assert diagnose(sim.dataset, "kinematic21").verdict == "bridge_twist"


@pytest.mark.parametrize("layout,name,shape,height", [
    ("gantry_fxyz", "pitch150_5pos", "s2", 900.0),
    ("gantry_fxyz", "pitch150_5pos", "sin", 900.0),
    ("moving_bridge_fxyz", "pitch100_4pos", "s2", 0.0),
    ("moving_bridge_fxyz", "pitch100_4pos", "sin", 900.0),
])
def test_a_twist_of_another_shape_is_never_a_high_order_rigid_term(layout, name, shape,
                                                                    height):
    """Issue 26: a beam twist whose shape along the travel is none of the block's
    (``scenarios.bridge_roll``: s², sin(πs/2), evaluated at the tips, about a raised line)
    is named as the twist, or outside the catalogue; never as a rigid function's higher
    order (``ryy:3`` ...) nor as the plate's sag. 30 µrad at the corners."""
    sim = sc.layout_data(name, layout, 1)
    data = sc.bridge_roll(sim.dataset, layout, sc.LAYOUTS[name]["range_mm"], 30.0, shape,
                          height)
    d = diagnose(data, "kinematic21")
    assert d.verdict in ("bridge_twist", "outside_catalogue"), \
        [(c.effect, c.p_value) for c in d.candidates[:4]]


def test_a_twist_asked_of_a_layout_without_a_moving_bridge_is_refused():
    """The simulator used to drop it without a word on a fixed bridge."""
    from cmm_core.io import DataError

    with pytest.raises(DataError, match=r"effects.bridge_twist.*no moving bridge") as e:
        _sim("fixed_bridge_xfyz", 1, effects={"bridge_twist": {"lin_urad": 10.0}})
    assert "\n" not in str(e.value)
    # no twist asked (a roll line's height alone): nothing is dropped, nothing refused
    _sim("fixed_bridge_xfyz", 1, effects={"bridge_twist": {"axis_height_mm": 900.0}})


@pytest.mark.parametrize("layout,name,shape,rigid", [
    ("moving_bridge_fxyz", "pitch100_4pos", "s3", "rxx"),
    ("moving_bridge_fyxz", "pitch80_3pos", "s2", "rzy"),
])
def test_a_twist_of_shape_s2_or_s3_is_the_twist_not_the_rigid_term_it_was(layout, name,
                                                                           shape, rigid):
    """The two loops of ``bench/nonrigid.py`` (seed 700, 30 µrad, about z = 0) that named
    ``rxx:3`` and ``rzy:3`` first while the block had the shapes s·v and (1 − s²)²·v only:
    with the cubic family the twist removes more than twice the rigid term's χ² (50 against
    19, 73 against 18, block docstring) and is named; the rigid term is still significant
    on its own (it was the verdict), so this is the ranking, not a weaker rival."""
    sim = sc.layout_data(name, layout, 700)
    data = sc.bridge_roll(sim.dataset, layout, sc.LAYOUTS[name]["range_mm"], 30.0, shape)
    d = diagnose(data, "kinematic21")
    by = {c.effect: c for c in d.candidates}
    assert d.verdict == "bridge_twist", [(c.effect, c.p_value) for c in d.candidates[:4]]
    assert by[f"{rigid}:3"].significant
    assert by["bridge_twist"].delta_chi2 > 2 * by[f"{rigid}:3"].delta_chi2


@pytest.mark.parametrize("layout,name,token,size", [
    ("moving_bridge_fxyz", "pitch100_4pos", "rxx:3", 7.3),
    ("moving_bridge_fyxz", "pitch80_3pos", "rzy:3", 4.7),
])
def test_a_real_rigid_third_order_is_not_taken_by_the_twist(layout, name, token, size):
    """The converse: the rigid terms the twist was named as, real and at twice their
    detection limit on these layouts (3.64 and 2.37 µrad, ``bench/nonrigid.py`` item 4,
    where over 420 draws at 1x the twist was never named first), are named as
    themselves, the wider block notwithstanding."""
    fn = token.partition(":")[0]
    sim = sc.layout_data(name, layout, 3100, kinematic={
        "spec": f"kinematic21,{token}", "coefficients": {f"{fn}[3]": size}})
    d = diagnose(sim.dataset, "kinematic21")
    assert d.verdict is not None and d.verdict.partition(":")[0] == fn, \
        [(c.effect, c.p_value) for c in d.candidates[:4]]

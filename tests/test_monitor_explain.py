"""The fewest changes that explain an interim check (issue 39 item 1): a pure scale
change is told as a scale in ppm, a squareness or a rotation as itself with its size and
u, and nothing is named on an unchanged machine beyond the stated level.

Simulated machines of ``tests/scenarios.py`` (not the sample data's), kinematic21
calibrations with the plate fixed; the machine measured again by ``monitor.remeasured``.
The level is checked without any simulation too: under "nothing changed" the check's
score is exactly ``N(0, H)`` (``monitor.changes``), so draws from it give the selection's
false-alarm rate with no noise model in between.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
import scenarios as sc

from cmm_core.export import model_from_result
from cmm_core.model import fit
from cmm_core.monitor import (
    change_system,
    hypotheses,
    remeasured,
    run_check,
    select_changes,
)

LAYOUTS = ("pitch100_4pos", "pitch80_3pos", "pitch150_5pos")
PPM = 17.0  # steel scales 1.5 K warm (11.5 ppm/K)


@functools.cache
def calibrated(layout: str):
    cal = sc.simulated(layout, 3)
    return cal, model_from_result(fit(cal.dataset, "kinematic21", plate="fixed"))


def _warm(model) -> dict:
    """dAA[1] of a common scale of ``PPM``: T₁(s) - T₁(-1) = 2u/stroke, so c = ppm ·
    stroke / 2000 µm (machine.terms.basis)."""
    return {f"d{a}{a}[1]": PPM * r / 2000.0 for a, r in zip("xyz", model.terms.range_mm,
                                                             strict=True)}


def _one_placement(layout: str) -> dict:
    p, (_, styli) = next(iter(sc.LAYOUTS[layout]["positions"].items()))
    return {p: styli}


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("one", [False, True], ids=["full plate", "one placement"])
def test_warm_scales_are_one_scale_change_in_ppm(layout, one):
    """The issue's case: one placement of a machine whose scales are 17 ppm long was told
    as 9 parameters moved (squareness and rotations among them); the explanation names
    the common scale alone, with its size within 4 u of 17 ppm (u: the explanation's
    own, which counts the stored model's uncertainty), and no squareness or rotation."""
    cal, model = calibrated(layout)
    new = remeasured(cal, 7_001, changes=_warm(model),
                     probes_per_position=_one_placement(layout) if one else None)
    out = run_check(model, new.dataset, name_effects=False)
    assert out.verdict == "changed"
    e = out.explanation
    assert e is not None and len(e.steps) == 1, e.message
    first = e.first
    assert first.hypothesis.key == "scale" and first.hypothesis.units == ("ppm",)
    assert abs(first.values[0] - PPM) <= 4 * first.u[0], (first.values, first.u)
    assert e.p_left >= 0.01  # nothing left for another change to explain
    assert out.message.startswith("The machine changed. The fewest changes that explain")
    assert "common scale change of the x, y and z scales" in out.message
    head = out.message.split(" Parameter by parameter:")[0]
    assert "squareness" not in head and "yaw" not in head and "pitch" not in head


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("label, key", [("sxy", "sxy"), ("rxz[1]", "rxz_linear")])
def test_a_3u_squareness_or_yaw_is_named_first_with_its_size(layout, label, key):
    cal, model = calibrated(layout)
    j = model.terms.labels.index(label)
    step = 3 * float(np.sqrt(model.cov[j, j]))
    out = run_check(model, remeasured(cal, 7_002, changes={label: step}).dataset,
                    name_effects=False)
    assert out.verdict == "changed"
    first = out.explanation.first
    assert first is not None and first.hypothesis.key == key, out.explanation.message
    # the estimate is of the true step on top of the stored model's own error (sd u_j):
    # its u counts both, 4 of them hold 99.99 %
    assert abs(first.values[0] - step) <= 4 * first.u[0], (first.values, step, first.u)
    assert first.hypothesis.units == ("µrad",)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_nothing_is_named_beyond_the_level_when_nothing_changed(layout):
    """Under "nothing changed" the score is N(0, H) exactly: 1000 draws of the check's
    residuals from its own covariance (seeded), each scored as the check's data are,
    give the share of checks that would name a change; Bonferroni over the first step's
    hypotheses bounds it by alpha = 5 %, with 3 binomial standard errors of slack
    (0.021 at 1000 draws). It is also not far below (> 1 %): the rule is not vacuous."""
    cal, model = calibrated(layout)
    out = run_check(model, remeasured(cal, 7_003).dataset, name_effects=False)
    cs = change_system(model, out.check)
    assert any(h.function == "stylus" for h in cs.hypotheses)  # the styli are tried too
    # d ~ N(0, Σ) (the check's full covariance) gives the score Wᵀ d ~ N(0, H) exactly
    L = np.tril(out.check.gls.factor[0])
    rng = np.random.default_rng(39)
    n, named = 1000, 0
    for _ in range(n):
        g = cs.weights.T @ (L @ rng.standard_normal(L.shape[0]))
        e = select_changes(g, cs.information, cs.prior, list(cs.hypotheses))
        named += bool(e.steps)
    rate = named / n
    assert 0.01 < rate <= 0.05 + 3 * np.sqrt(0.05 * 0.95 / n), rate


def test_the_hypotheses_are_physical_first_and_in_the_stored_labels():
    _, model = calibrated("pitch100_4pos")
    hs = hypotheses(model)
    keys = [h.key for h in hs]
    assert keys[:4] == ["scale", "x_scale", "y_scale", "z_scale"]
    assert {"sxy", "sxz", "syz", "rxz_linear", "rxz", "dxy"} <= set(keys)
    n = len(model.terms.labels)
    for h in hs:
        assert h.columns.shape[0] == n and len(h.units) == h.columns.shape[1]
    # one ppm of the common scale is stroke/2000 µm of each dAA[1]
    scale = hs[0].columns[:, 0]
    for a, r in zip("xyz", model.terms.range_mm, strict=True):
        assert scale[model.terms.labels.index(f"d{a}{a}[1]")] == pytest.approx(r / 2000)


def test_the_explanation_is_in_the_results_and_the_json():
    cal, model = calibrated("pitch80_3pos")
    out = run_check(model, remeasured(cal, 7_004, changes=_warm(model)).dataset,
                    name_effects=False)
    d = out.to_dict()["explanation"]
    assert d["steps"][0]["change"] == "scale" and d["steps"][0]["parameters"][0]["unit"] == "ppm"
    assert out.results_section()["explanation"] == d
    # an unchanged machine whose check passes carries none
    quiet = run_check(model, remeasured(cal, 7_005).dataset, name_effects=False)
    assert quiet.check.passes  # this seed's check of the unchanged machine passes
    assert quiet.explanation is None and quiet.to_dict()["explanation"] is None


def _with_scale_temps(data, t_C: float):
    m = data.meas.copy()
    for a in "xyz":
        m[f"temp_{a}_C"] = t_C
    return dataclasses.replace(data, meas=m)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_recorded_scale_temperatures_name_the_change_as_thermal(layout):
    """The same warm machine with its scales' temperatures in the file (21.48 °C, 1.48 K
    warm): the change is named as the scales' thermal expansion (machine_thermal) with
    κ within 4 u of 17 ppm / 1.48 K; without them, as the common scale (the test above).
    A squareness step on the same warm-recorded file is not told as thermal."""
    cal, model = calibrated(layout)
    warm = _with_scale_temps(remeasured(cal, 7_006, changes=_warm(model)).dataset, 21.48)
    out = run_check(model, warm, name_effects=False)
    first = out.explanation.first
    assert first.hypothesis.key == "machine_thermal" and first.hypothesis.units == ("ppm/K",)
    assert abs(first.values[0] - PPM / 1.48) <= 4 * first.u[0], (first.values, first.u)
    assert "machine_thermal" in out.message and "21.48" in out.message
    j = model.terms.labels.index("sxy")
    step = 3 * float(np.sqrt(model.cov[j, j]))
    square = _with_scale_temps(remeasured(cal, 7_007, changes={"sxy": step}).dataset, 21.48)
    first = run_check(model, square, name_effects=False).explanation.first
    assert first.hypothesis.key == "sxy"


def _misprobed(data, k: int, dx_mm: float):
    """The data with reading ``k`` off by ``dx_mm`` in x (a misprobe)."""
    m = data.meas.copy()
    i = m.index[k]
    for c in ("x_mm", "mx_mm"):
        if c in m:
            m.loc[i, c] += dx_mm
    return dataclasses.replace(data, meas=m), tuple(m.loc[i, ["position", "probe", "ball"]])


@pytest.mark.parametrize("layout", LAYOUTS)
def test_a_misprobe_is_a_probable_blunder_not_25_moved_parameters(layout):
    """Issue 38: a 0.3 mm blunder in an interim check was told as 25 parameters moved.
    It is now named as a probable blunder with its ball, stylus and size, left out, and
    the check of the rest passes: no change is named. The seed is one whose check of
    the unchanged machine passes (a false alarm would be the check's own 5 %)."""
    cal, model = calibrated(layout)
    clean = remeasured(cal, 7_008).dataset
    assert run_check(model, clean, name_effects=False).check.passes
    bad, (pos, probe, ball) = _misprobed(clean, 11, 0.3)
    out = run_check(model, bad, name_effects=False)
    assert [b.key for b in out.blunders] == [(str(pos), str(probe), int(ball))]
    b = out.blunders[0]
    assert abs(b.residual_um[0]) > 200 and b.z > 10
    assert out.check.passes and out.explanation is None
    assert out.message.startswith(f"Probable blunder: ball {int(ball)} of {pos} with stylus "
                                  f"{probe}, off by (")
    assert "without it the check passes" in out.message
    assert out.to_dict()["blunders"][0]["ball"] == int(ball)


def test_a_crash_is_not_called_a_blunder():
    """The sample crash (a 12 µrad squareness) leaves residuals beyond the single-outlier
    bound too; left out, they leave a failing check: no blunder is named, the squareness
    is."""
    cal, model = calibrated("pitch100_4pos")
    j = model.terms.labels.index("sxy")
    out = run_check(model, remeasured(cal, 7_009, changes={
        "sxy": 5 * float(np.sqrt(model.cov[j, j]))}).dataset, name_effects=False)
    assert out.verdict == "changed" and not out.blunders
    assert out.explanation.first.hypothesis.key == "sxy"


@pytest.mark.parametrize("layout, stylus", [("pitch100_4pos", "B"), ("pitch80_3pos", "2"),
                                            ("pitch150_5pos", "R")])
def test_a_bent_stylus_is_named_as_the_stylus_with_its_offset_error(layout, stylus):
    """Issue 39: a stylus change is named as the stylus that moved, with its offset error
    and u (the probe_offset convention of the diagnosis: +3, 0, -2 µm simulated), not as
    the rotations that mimic it."""
    cal, model = calibrated(layout)
    new = remeasured(cal, 7_012, effects={"probe_offset": {stylus: [3.0, 0.0, -2.0]}})
    out = run_check(model, new.dataset, name_effects=False)
    first = out.explanation.first
    assert first is not None and first.hypothesis.key == f"stylus_{stylus}", \
        out.explanation.message
    truth = np.array([3.0, 0.0, -2.0])
    assert (np.abs(np.array(first.values) - truth) <= 4 * np.array(first.u)).all(), \
        (first.values, first.u)
    assert f"stylus {stylus}'s offset" in out.message


@pytest.mark.parametrize("event, n, at_least", [("yaw", 20, 19), ("stylus", 10, 10)])
def test_the_targeted_half_sees_what_the_chi2_test_dilutes(event, n, at_least):
    """The check's two tests (``monitor.TARGETED_SHARE``): on pitch80_3pos a 3 u yaw
    (rxz[1]) failed the χ² test alone in 78 % of seeds and a stylus bent by 1 µm (7 u of
    the check's own u of its offset) in 38 % (bench/explain.py, 60 seeds); with the
    fewest-changes test beside it both are seen in every one of 60 seeds. Here the
    verdict is "changed" with the truth named first in at least ``at_least`` of ``n``
    seeds (at the χ² test's 78 % and 38 %, 19 of 20 and 10 of 10 have chances of 7 % and
    6e-5); in some of them the χ² test passes, so the targeted half did the seeing."""
    layout = "pitch80_3pos"
    cal, model = calibrated(layout)
    j = model.terms.labels.index("rxz[1]")
    kw, truth = (({"changes": {"rxz[1]": 3 * float(np.sqrt(model.cov[j, j]))}},
                  ("rxz_linear", "rxz")) if event == "yaw" else
                 ({"effects": {**cal.config.get("effects", {}),
                               "probe_offset": {"2": [1.0, 0.0, 0.0]}}}, ("stylus_2",)))
    seen = chi2_passed = 0
    for s in range(n):
        out = run_check(model, remeasured(cal, 39_100 + s, **kw).dataset,
                        name_effects=False)
        seen += (out.verdict == "changed" and out.explanation is not None
                 and out.explanation.first.hypothesis.key in truth)
        chi2_passed += out.check.passes
    assert seen >= at_least, (seen, n)
    assert chi2_passed >= 1

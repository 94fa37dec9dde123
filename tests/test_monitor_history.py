"""Calibration history (issue 28): changes between calibrations of one machine with E_n,
Holm's family-wise level, the error map's change, and the refusals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scenarios as sc
from conftest import ROOT
from scipy import stats
from test_monitor import LAYOUTS, calibrated

from cmm_core.export import load_model, model_from_dict, model_from_result, model_to_dict
from cmm_core.io import DataError
from cmm_core.model import fit
from cmm_core.monitor import compare_calibrations, holm, remeasured


def _recalibrated(cal, seed, changes=None):
    new = remeasured(cal, seed, changes=changes)
    return model_from_result(fit(new.dataset, "kinematic21", plate="fixed"))


def test_holm_against_a_hand_computed_case():
    # p sorted 0.001, 0.01, 0.02, 0.5 at 0.05 with m = 4 (Holm 1979): 0.001 <= 0.0125,
    # 0.01 <= 0.0167, 0.02 <= 0.025 reject, 0.5 > 0.05 stops. [0.03, 0.026]: the smallest
    # exceeds 0.05/2, nothing is rejected (Bonferroni would not either); [0.03, 0.02]:
    # 0.02 <= 0.025, then 0.03 <= 0.05 (Bonferroni would keep 0.03)
    assert holm(np.array([0.5, 0.02, 0.001, 0.01]), 4, 0.05).tolist() == \
        [False, True, True, True]
    assert holm(np.array([0.03, 0.026]), 2, 0.05).tolist() == [False, False]
    assert holm(np.array([0.03, 0.02]), 2, 0.05).tolist() == [True, True]


@pytest.mark.slow
def test_unchanged_machine_family_wise_false_alarms():
    # recalibrations of an unchanged machine: runs with any significant change at most
    # Binomial(2 x 8, 0.2) in distribution (Holm); bound its 99.9 % quantile
    alpha, hits = 0.2, 0
    for layout in LAYOUTS:
        for s in range(8):
            cal, model = calibrated(layout, s)
            h = compare_calibrations([(model, "2024-01-10"),
                                      (_recalibrated(cal, 300 + s), "2025-01-12")],
                                     family_alpha=alpha)
            hits += bool(h.significant)
    assert hits <= stats.binom.ppf(0.999, 16, alpha), hits


def test_large_squareness_change_is_significant_and_maps():
    # 25 µrad of sxy between calibrations: u of the change is about 4 µrad at pitch100
    # (2.8 µrad per calibration), E_n about 6, past Holm's bound over 33 (|E_n| > 3.2)
    cal, m1 = calibrated("pitch100_4pos", 4)
    m2 = _recalibrated(cal, 44, {"sxy": 25.0})
    h = compare_calibrations([(m2, "2025-06-01"), (m1, "2024-06-01")])
    assert h.dates == ["2024-06-01", "2025-06-01"]
    assert any(s.startswith("sxy") for s in h.significant), h.message
    row = h.changes.set_index("label").loc["sxy"]
    assert abs(row.change - 25.0) < 3 * row.u_change
    # the map: sxy turns y into x (x error ∝ y), so the x change spans ~25 µrad · 800 mm
    span = np.ptp(h.map_change["dex_um"])
    assert 10 < span < 40, span
    assert set(h.trend["date"]) == {"2024-06-01", "2025-06-01"}


def test_refusals():
    _, m1 = calibrated("pitch100_4pos", 0)
    _, other = calibrated("pitch80_3pos", 0)
    with pytest.raises(DataError, match="strokes .* different machines"):
        compare_calibrations([(m1, "2024-01-01"), (other, "2025-01-01")])
    with pytest.raises(DataError, match="at least two"):
        compare_calibrations([(m1, "2024-01-01")])
    with pytest.raises(DataError, match="not an ISO 8601 date"):
        compare_calibrations([(m1, "2024-01-01"), (m1, "1st of May")])
    gantry = replace(m1, terms=replace(m1.terms, layout="gantry_fxyz"), name="gantry.json")
    with pytest.raises(DataError, match="gantry.json.*gantry_fxyz machine.*different machines"):
        compare_calibrations([(m1, "2024-01-01"), (gantry, "2025-01-01")])


def test_models_of_different_specs_compare_what_they_share_and_say_the_rest():
    cal, full = calibrated("pitch100_4pos", 5)
    new = remeasured(cal, 55)
    reduced = replace(model_from_result(fit(new.dataset, "kinematic21,-sxy", plate="fixed")),
                      name="reduced.json")
    h = compare_calibrations([(full, "2024-01-01"), (reduced, "2025-01-01")])
    assert "sxy" not in set(h.changes["label"])
    assert len(h.changes) == len(full.terms.labels) - 1
    assert h.only_in == {full.name: ["sxy"]}
    assert "Not compared (in one model only)" in h.message and "sxy" in h.message


def test_one_calibration_twice_or_one_date_twice_is_refused():
    # review 2 #11: compare M M ran and took the two as independent calibrations
    _, m1 = calibrated("pitch100_4pos", 0)
    copy = replace(m1, name="copy.json")
    with pytest.raises(DataError, match="same calibration as") as e:
        compare_calibrations([(m1, "2024-01-01"), (copy, "2025-01-01")])
    assert e.value.file == "copy.json" and "\n" not in str(e.value)
    _, m2 = calibrated("pitch100_4pos", 1)
    with pytest.raises(DataError, match="two calibrations dated 2024-01-01"):
        compare_calibrations([(m1, "2024-01-01"), (m2, "20240101")])


def test_a_parameter_held_fixed_in_both_is_not_compared():
    # review 2 #9: u₁ = u₂ = 0 gave E_n = 0/0 (NaN) or ±inf, and Holm marked NaN
    # significant; now such a parameter is left out, and the message names it
    _, m1 = calibrated("pitch100_4pos", 0)
    _, m2 = calibrated("pitch100_4pos", 1)
    j = m1.terms.labels.index("sxy")

    def held(m, name):
        cov = m.cov.copy()
        cov[j, :] = cov[:, j] = 0.0
        return replace(m, cov=cov, name=name)

    h = compare_calibrations([(held(m1, "a.json"), "2024-01-01"),
                              (held(m2, "b.json"), "2025-01-01")])
    assert "sxy" not in set(h.changes["label"])
    assert len(h.changes) == len(m1.terms.labels) - 1
    assert np.isfinite(h.changes["En"]).all()
    assert "held fixed" in h.message and "sxy" in h.message


def test_history_En_is_stated_at_k_2_and_the_tests_do_not_depend_on_it():
    # E_n = (c₂ − c₁) / sqrt(U₁² + U₂²) with U = 2 u (ISO/IEC 17043 Annex B): the k = 1
    # value over 2; the p-values and Holm's rejections are those of the standard scores
    cal, m1 = calibrated("pitch100_4pos", 4)
    m2 = _recalibrated(cal, 44, {"sxy": 25.0})
    pairs = [(m1, "2024-06-01"), (m2, "2025-06-01")]
    h2, h1 = compare_calibrations(pairs), compare_calibrations(pairs, coverage_factor=1.0)
    assert h2.coverage_factor == 2.0
    assert np.allclose(h2.changes["En"], h1.changes["En"] / 2, rtol=1e-12, atol=0)
    assert np.allclose(h1.changes["En"], h1.changes["change"] / h1.changes["u_change"])
    assert np.array_equal(h1.changes["p_value"], h2.changes["p_value"])
    assert h1.significant == h2.significant and h2.significant
    assert "(E_n (k = 2) = " in h2.message
    assert h2.results_section()["coverage_factor"] == 2.0
    with pytest.raises(ValueError, match="coverage_factor"):
        compare_calibrations(pairs, coverage_factor=-1.0)


def _sample_history():
    h = ROOT / "sample_data" / "history"
    return [(load_model(h / f"calibration_{d}.json"), d)
            for d in ("2023-03-01", "2024-03-04", "2025-03-03")]


def test_the_sample_crash_is_the_one_change_named_between_the_calibrations():
    """sample_data/history: the machine's sxy moved by 12 µrad between the 2024 and the
    2025 calibrations (make_history.py's truth). The fewest changes between 2024 and
    2025 are that squareness alone, within 3 of its u of 12 µrad (u with the full
    covariances of both calibrations); nothing is needed between 2023 and 2024; the
    message says so first."""
    h = compare_calibrations(_sample_history())
    first, second = h.explanations
    assert not first.steps
    assert [s.hypothesis.key for s in second.steps] == ["sxy"], second.message
    step = second.first
    assert abs(step.values[0] - 12.0) <= 3 * step.u[0], (step.values, step.u)
    assert h.message.startswith("The fewest changes that explain each difference")
    assert "2024-03-04 → 2025-03-03: the xy squareness (sxy): +" in h.message
    assert h.results_section()["explanations"][1]["steps"][0]["change"] == "sxy"


def test_a_calibration_failing_its_own_chi2_test_is_inflated_and_said():
    models = _sample_history()
    bad, d = models[1]
    summary = {**bad.summary, "chi2_p_value": 1e-6, "birge_ratio": 1.7}
    models[1] = (replace(bad, summary=summary), d)
    h = compare_calibrations(models)
    assert h.inflated == {bad.name: 1.7}
    assert f"Warning: {bad.name} fails its own χ² test" in h.message and "1.70" in h.message
    plain = compare_calibrations(_sample_history())
    row = h.changes.set_index(["label", "date_to"]).loc[("sxy", "2024-03-04")]
    ref = plain.changes.set_index(["label", "date_to"]).loc[("sxy", "2024-03-04")]
    j = bad.terms.labels.index("sxy")
    u0 = models[0][0].cov[j, j]
    # the change's u grows as the inflated calibration's variance does: u₁² + 1.7² u₂²
    assert row.u_change == pytest.approx(np.sqrt(u0 + 1.7**2 * bad.cov[j, j]), rel=1e-12)
    assert ref.u_change == pytest.approx(np.sqrt(u0 + bad.cov[j, j]), rel=1e-12)


def test_stylus_offsets_are_compared_by_value_and_said():
    models = _sample_history()
    m, d = models[2]
    probes = {**m.probes_mm, "B": np.asarray(m.probes_mm["B"], float) + [0.003, 0.0, -0.002]}
    probes.pop("E")
    models[2] = (replace(m, probes_mm=probes), d)
    h = compare_calibrations(models)
    assert h.styli[0]["changed"] == {} and h.styli[0]["only_in"] == []
    second = h.styli[1]
    assert list(second["changed"]) == ["B"] and second["only_in"] == ["E"]
    assert np.allclose(second["changed"]["B"], [3.0, 0.0, -2.0], atol=1e-9)
    assert "2024-03-04 → 2025-03-03: B by (+3.00, +0.00, -2.00) µm; E in one of the two " \
        "only." in h.message


@pytest.fixture(scope="module")
def one_plate():
    """A calibration (certificate u 0.5 µm, comparable to σ) and the same machine
    recalibrated on the same plate and certificate, unchanged."""
    cal = sc.simulated("pitch100_4pos", 301, plate={"certificate_u_um": 0.5})
    m1 = model_from_result(fit(cal.dataset, "kinematic21", plate="fixed"))
    again = remeasured(cal, 9001, same_plate=True)
    m2 = model_from_result(fit(again.dataset, "kinematic21", plate="fixed"))
    return cal, m1, m2


def test_the_certificate_sensitivity_is_the_certificate_part_of_the_covariance(one_plate):
    """``S Sᵀ`` is what the certificate adds to the σ-only covariance (the fit's
    sandwich, certificate_prior), to rounding; it survives the model file."""
    cal, m1, _ = one_plate
    r = fit(cal.dataset, "kinematic21", plate="fixed")
    s = r.problem.layout.blocks["kinematic"]
    S = m1.certificate["sensitivity"]
    part = r.covariance[s, s] - r.covariance_noise[s, s]
    np.testing.assert_allclose(S @ S.T, part, rtol=1e-9, atol=1e-12 * np.abs(part).max())
    back = model_from_dict(model_to_dict(m1))
    assert back.certificate["digest"] == m1.certificate["digest"]
    np.testing.assert_array_equal(back.certificate["sensitivity"], S)


def test_one_certificate_is_counted_in_the_difference(one_plate):
    """Both calibrations carry the same certificate's digest: the difference's variance
    is V₁ + V₂ less the shared part (smaller for sxy, whose certificate part is a large
    share here), and the message says so; without the sensitivities the calibrations are
    treated as independent."""
    _, m1, m2 = one_plate
    assert m1.certificate["digest"] == m2.certificate["digest"]
    h = compare_calibrations([(m1, "2024-01-01"), (m2, "2025-01-01")])
    assert h.same_certificate == ["2024-01-01 → 2025-01-01"]
    assert "Made with one plate certificate" in h.message
    plain = compare_calibrations([(replace(m1, certificate=None), "2024-01-01"),
                                  (replace(m2, certificate=None), "2025-01-01")])
    assert plain.same_certificate == []
    u = h.changes.set_index("label").loc["sxy", "u_change"]
    u_ind = plain.changes.set_index("label").loc["sxy", "u_change"]
    S = m1.certificate["sensitivity"]
    j = m1.terms.labels.index("sxy")
    assert S[j] @ S[j] > 0.3 * m1.cov[j, j]  # the case: the certificate matters
    assert u < 0.9 * u_ind


@pytest.mark.parametrize("field, value, words", [
    ("digest", "xyz", "SHA-256"), ("balls", [1, 1], "distinct ball numbers"),
    ("sensitivity", [[True]], "JSON numbers"), ("sensitivity", [[0.0]], "rows of")])
def test_a_bad_certificate_block_is_refused_in_one_line(one_plate, field, value, words):
    d = model_to_dict(one_plate[1])
    d["certificate"][field] = value
    with pytest.raises(DataError) as exc:
        model_from_dict(d, name="m.json")
    assert words in str(exc.value) and "m.json" in str(exc.value)
    assert "\n" not in str(exc.value)

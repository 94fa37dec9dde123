"""One headline per verdict (issue 41): computed in the core from the diagnosis, the same
words in the app, the report and ``diagnose --json``. Simulated on the scenario layouts
(other pitches, placements, styli and seeds than the sample data): aliases named as a
set with no ``nan``, blunders first, "explained to noise" with the significant terms
(squareness first), σ too small, outside the catalogue, and every branch's condition; the
number formatters (``p < 1e-16``, no ``-0.0``, a u not determinable says why)."""

from __future__ import annotations

import dataclasses
import html
import json
import math
import re

import numpy as np
import pytest
import scenarios as sc

import cmm_core.diagnosis.search as search
from cmm_core import analysis as A
from cmm_core.diagnosis import (
    BLUNDERS,
    HEADLINE_LEVELS,
    HEADLINE_VERDICTS,
    OUTSIDE,
    Headline,
    diagnose,
    headline_of,
    significant_terms,
)
from cmm_core.model import catalogue_entry, simulate
from cmm_core.units import number, p_text, value_u

# --- the cases -------------------------------------------------------------------------

ALIASES = {
    # each placement measures its styli one after the other: a probe offset is an alias
    # of drift (tests/test_verdict_numbers.py)
    "probe_offset_drift_80mm_s4": (lambda: sc.simulated(
        "pitch80_3pos", 4, effects={"probe_offset": {"sd_um": 2.0}}).dataset,
        "kinematic21", {"probe_offset", "drift"}),
    "probe_offset_drift_80mm_s6": (lambda: sc.simulated(
        "pitch80_3pos", 6, effects={"probe_offset": {"sd_um": 2.0}}).dataset,
        "kinematic21", {"probe_offset", "drift"}),
    # a fourth-order yaw hidden from a baseline without squareness: sxy and rxz:4 are one
    # pattern on this design (tests/test_app_proposals.py)
    "squareness_yaw_80mm_s7": (lambda: sc.simulated(
        "pitch80_3pos", 7, kinematic={"spec": "kinematic21,rxz:4",
                                      "coefficients": {"rxz[4]": 3.0}}).dataset,
        "kinematic21,-sxy", {"sxy", "rxz:4"}),
}


def _with_blunder(layout, name, seed, row=17, axis=1, size_um=40.0):
    """A 40 µm blunder (80 σ) in one reading of a clean simulation."""
    cfg = sc.layout_config(name, seed=seed)
    cfg["setup"]["machine"]["layout"] = layout
    ds = simulate(cfg).dataset
    delta = np.zeros((len(ds.meas), 3))
    delta[row, axis] = size_um * 1e-3
    return sc.perturb(ds, delta)


BLUNDER_CASES = [("moving_bridge_fxyz", "pitch100_4pos", 12),
                 ("gantry_fyxz", "pitch150_5pos", 13)]

CLEAN = [
    # (layout, seed, simulated squareness token and size in µrad, or None)
    ("pitch100_4pos", 5, ("sxy", 12.0)),
    ("pitch150_5pos", 21, ("syz", 15.0)),
    ("pitch80_3pos", 11, None),
]


ZERO_P = re.compile(r"p = 0(?![.\d])|p = 0\.0*(?!\d)")
"""``p = 0`` (or ``p = 0.00``), not ``p = 0.49``."""
SIGNED_ZERO = re.compile(r"(?<![\w.])[-+]0(\.0*)?(?![\d.])")
"""``-0``, ``-0.0``, ``+0.00``, not ``-0.62``."""


def _no_nan(h: Headline):
    words = " ".join((h.title, h.text, h.action))
    assert "nan" not in words.lower() and "± inf" not in words
    assert not ZERO_P.search(words) and not SIGNED_ZERO.search(words), words
    json.dumps(h.to_dict(), allow_nan=False)


def _check_level(h: Headline):
    assert h.level in HEADLINE_LEVELS and HEADLINE_VERDICTS[h.verdict] == h.level
    assert h.title and "\n" not in h.title and h.text and h.action


# --- the verdicts ----------------------------------------------------------------------

@pytest.mark.parametrize("case", list(ALIASES))
def test_an_alias_pair_is_named_as_a_set_without_nan(case):
    make, baseline, pair = ALIASES[case]
    d = diagnose(make(), baseline)
    h = d.headline()
    _check_level(h)
    _no_nan(h)
    best = d.candidates[0]
    assert {best.effect, *best.aliases} >= pair, (best.effect, best.aliases)
    assert h.verdict == "named" and h.level == "success"
    assert set(h.alias_of) == set(best.aliases) and set(h.alias_of) & pair
    # the title names the set, not the first alone; the text both tokens
    for tok in pair:
        assert catalogue_entry(tok).title in h.title, (tok, h.title)
        assert tok in h.text
    assert "this data cannot decide" in h.title and "Measure next" in h.title
    assert f"ΔBIC {best.delta_bic:.1f}" in h.text and "p < 1e-16" in h.text
    # the size with its unit: µm (a stylus's offset vector) or µrad (a squareness)
    assert " µm" in h.text or " µrad" in h.text
    assert "Measure next" in h.action
    assert d.to_dict()["headline"] == h.to_dict()


def test_a_u_that_is_not_determinable_says_why():
    """The sample-like design with its styli measured in blocks: the model with the probe
    offset leaves combinations of it with the placements undetermined, so its u is NaN;
    the headline (and the conclusion) give the values and why, never ``± nan``."""
    d = diagnose(simulate({"seed": 3, "effects": {"probe_offset": {"sd_um": 2.0}}}).dataset,
                 "kinematic21")
    best = d.candidates[0]
    assert best.effect == "probe_offset"
    assert all(math.isnan(u) for _, _, u in best.fitted.values())
    h = d.headline()
    _no_nan(h)
    # why, in words: the stylus's offsets and the placements cannot be told apart
    assert "u not determinable: in this design the " in h.text
    assert "offsets of styli" in h.text and "cannot be told apart" in h.text
    assert "± nan" not in d.message and "u not determinable" in d.message


@pytest.mark.parametrize(("layout", "name", "seed"), BLUNDER_CASES)
def test_a_dominant_blunder_gives_the_outliers_first_headline(layout, name, seed):
    d = diagnose(_with_blunder(layout, name, seed), "kinematic21")
    assert d.verdict == BLUNDERS, d.message
    h = d.headline()
    _check_level(h)
    _no_nan(h)
    assert (h.verdict, h.level) == ("flagged_outliers", "error")
    assert h.title == "Flagged outlier(s) first"
    assert f"{len(d.blunders.exclusions)} observation(s)" in h.text
    assert "Exclude the flagged outliers" in h.action and "--exclude-outliers" in h.action
    assert h.alias_of == ()


@pytest.mark.parametrize(("name", "seed", "square"), CLEAN)
def test_a_clean_fit_is_explained_to_noise_with_its_significant_terms(name, seed, square):
    extra = {} if square is None else {"kinematic": {"coefficients": {square[0]: square[1]}}}
    d = diagnose(sc.simulated(name, seed, **extra).dataset, "kinematic21")
    assert d.verdict is None and not d.baseline.fails_chi2_test, d.message
    h = d.headline()
    _check_level(h)
    _no_nan(h)
    assert (h.verdict, h.level, h.title) == ("explained_to_noise", "info", "Explained to noise")
    assert "explained to noise" in h.text
    terms = significant_terms(d.baseline)
    assert all(abs(v) >= 3 * u for _, _, v, u in terms)
    if square is None:
        assert not any(t[0].startswith("squareness") for t in terms)
        return
    title = catalogue_entry(square[0]).title
    # the simulated squareness is significant and listed first, with its u and unit
    assert terms[0][0] == title and terms[0][1] == "urad"
    assert abs(terms[0][2] - square[1]) < 3 * terms[0][3]
    assert f"Significant in the model: {title} {value_u(*terms[0][2:], 'urad')}" in h.text
    assert " ± " in h.text and " µrad" in h.text


def test_an_understated_sigma_gives_the_sigma_headline():
    """Noise of 1 µm diagnosed at the default σ = 0.5 µm (150 mm plate, five placements):
    nothing significant, the misfit spread evenly: σ is the suspect, with its estimate."""
    d = diagnose(sc.simulated("pitch150_5pos", 9, noise_um=1.0).dataset, "kinematic21",
                 sigma_um=0.5)
    h = d.headline()
    _check_level(h)
    _no_nan(h)
    assert h.verdict == "sigma_too_small" and h.level == "warning"
    assert value_u(d.sigma.value_um, d.sigma.u_um, "um") in h.text
    assert h.action.startswith(f"Refit with σ = {number(d.sigma.value_um)} µm")


def test_a_placement_scale_is_outside_the_catalogue():
    ds = sc.placement_scale(sc.simulated("pitch100_4pos", 13).dataset,
                            np.random.default_rng(3), sd_ppm=8.0)
    d = diagnose(ds, "kinematic21")
    assert d.verdict == OUTSIDE, d.message
    h = d.headline()
    _check_level(h)
    _no_nan(h)
    assert (h.verdict, h.title) == ("outside_catalogue", "Outside the catalogue")
    assert "Where the residual lives" in h.text


def test_an_unconverged_baseline_names_no_effect(monkeypatch):
    """Every fit stopped after one iteration (as tests/test_diagnose.py): the best
    candidate is significant, yet no effect is named."""
    real = search.fit
    monkeypatch.setattr(search, "fit", lambda *a, **k: real(*a, **{**k, "max_iter": 1}))
    ds = sc.simulated("pitch100_4pos", 14, effects={"plate_sag": {"uu": -2.0, "uv": 0.5,
                                                                  "vv": -1.5}}).dataset
    d = search.diagnose(ds, "kinematic21")
    assert d.baseline.status != "converged" and d.verdict is None
    h = d.headline()
    _no_nan(h)
    assert h.verdict == ("not_converged" if d.candidates[0].significant else "unexplained")
    assert "did not converge" in h.title + h.text


# --- every branch, in the page's order and on its conditions ---------------------------

@pytest.fixture(scope="module")
def named():
    """A named effect (plate sag on the 100 mm plate) to vary the conditions on."""
    ds = sc.simulated("pitch100_4pos", 5, effects={"plate_sag": {"uu": -3.0, "uv": 0.5,
                                                                 "vv": -2.0}}).dataset
    d = diagnose(ds, "kinematic21")
    assert d.verdict == "plate_sag"
    return d


def _expected(d) -> str:
    """The Diagnose page's if-chain as it was (pages/diagnose.py before issue 41)."""
    if not d.candidates:
        return "no_candidates"
    best = d.candidates[0]
    is_verdict = best.effect == d.verdict
    sigma = d.to_dict()["sigma_check"]
    if d.verdict == BLUNDERS:
        return "flagged_outliers"
    if d.verdict == "outside_catalogue":
        return "outside_catalogue"
    if best.significant and not is_verdict and d.verdict is None:
        return "not_converged"
    if is_verdict:
        return "named"
    if not d.baseline.fails_chi2_test:
        return "explained_to_noise"
    if sigma and sigma.get("uniform"):
        return "sigma_too_small"
    return "unexplained"


def test_every_branch_follows_the_pages_conditions(named):
    base = named.baseline
    fails = dataclasses.replace(base, chi2_test=10.0 * base.dof, dof_test=base.dof)
    passes = dataclasses.replace(base, chi2_test=float(base.dof), dof_test=base.dof)
    quiet = [dataclasses.replace(c, significant=False) for c in named.candidates]
    other = next(c for c in named.candidates if c.effect != "plate_sag")
    sig = search.repeatability.SigmaEstimate(0.8, 0.03, 400, "model residuals", "scatter")
    uni = search.repeatability.Uniformity(True, {}, "")
    variants = {
        "no_candidates": dict(candidates=[]),
        "flagged_outliers": dict(verdict=BLUNDERS, baseline=fails),
        "outside_catalogue": dict(verdict=OUTSIDE),
        "not_converged": dict(verdict=None),
        "named": {},
        "explained_to_noise": dict(verdict=None, candidates=quiet, baseline=passes),
        "sigma_too_small": dict(verdict=None, candidates=quiet, baseline=fails, sigma=sig,
                                uniformity=uni),
        "unexplained": dict(verdict=None, candidates=quiet, baseline=fails),
        # the named effect is not the first candidate: the chain goes on past "named"
        "explained_to_noise ": dict(verdict=other.effect, candidates=quiet, baseline=passes),
    }
    for want, change in variants.items():
        d = dataclasses.replace(named, **change)
        h = headline_of(d)
        assert h.verdict == _expected(d) == want.strip(), (want, h)
        assert d.headline() == h and d.to_dict()["headline"] == h.to_dict()
        _check_level(h)
        _no_nan(h)
    assert set(HEADLINE_VERDICTS) == {w.strip() for w in variants}


def test_the_named_headline_gives_size_evidence_and_action(named):
    h = named.headline()
    best = named.candidates[0]
    _no_nan(h)
    assert h.title == f"Most likely missing: {best.title}" and h.alias_of == ()
    assert f"ΔBIC {best.delta_bic:.1f}" in h.text and p_text(best.p_value) in h.text
    assert "Size: plate_sag." in h.text and " ± " in h.text and " µm" in h.text
    assert h.action.startswith("Add plate_sag to the model")


def test_the_json_and_the_report_carry_the_same_headline(named, tmp_path):
    out = named.to_dict()
    assert out["headline"] == named.headline().to_dict()
    assert set(out["headline"]) == {"verdict", "level", "title", "text", "action", "alias_of"}
    json.dumps(out["headline"], allow_nan=False)
    text = A.headline_html(named.headline())
    h = named.headline()
    assert html.escape(h.title) in text and html.escape(h.text) in text
    assert f"class='headline {h.level}'" in text


def test_the_report_shows_the_diagnosis_headline(tmp_path):
    sim = sc.simulated("pitch100_4pos", 5, effects={"plate_sag": {"uu": -3.0, "uv": 0.5,
                                                                  "vv": -2.0}})
    sim.write(tmp_path)
    record = A.AnalysisRecord(data=A.DataSources(
        "simulated", (A.DataFile("measurements.csv", str(tmp_path / "measurements.csv")),),
        A.DataFile("setup.json", str(tmp_path / "setup.json")),
        A.DataFile("certificate.csv", str(tmp_path / "certificate.csv"))), diagnose=True)
    res = A.run(record)
    assert res.diagnosis is not None
    page = A.render(res)
    assert A.headline_html(res.diagnosis.headline()) in page
    assert page.index("class='headline") < page.index(html.escape(res.diagnosis.message[:40]))


# --- the formatters --------------------------------------------------------------------

@pytest.mark.parametrize(("p", "text"), [(0.0, "p < 1e-16"), (1e-300, "p < 1e-16"),
                                         (9.9e-17, "p < 1e-16"), (1e-16, "p = 1e-16"),
                                         (3.14e-5, "p = 3.1e-05"), (0.5, "p = 0.5"),
                                         (float("nan"), "p not computed")])
def test_p_values_below_the_floor_are_bounded_never_zero(p, text):
    assert p_text(p) == text


@pytest.mark.parametrize(("v", "fmt", "text"), [(-0.0, ".1f", "0.0"), (0.0, ".1f", "0.0"),
                                                (-0.0, ".3g", "0"), (-0.004, ".2f", "0.00"),
                                                (-0.0, "+.2f", "0.00"), (1e-9, "+.1f", "0.0"),
                                                (-1.25, ".2f", "-1.25"), (2.5, "+.1f", "+2.5"),
                                                (-12.73, ".3g", "-12.7"),
                                                (float("nan"), ".2f", "nan")])
def test_a_signed_zero_prints_without_its_sign(v, fmt, text):
    assert number(v, fmt) == text


def test_the_checks_of_the_words_catch_what_they_are_for():
    assert ZERO_P.search("(p = 0)") and ZERO_P.search("p = 0.00,")
    assert not ZERO_P.search("p = 0.49") and not ZERO_P.search("p = 0.0012")
    assert SIGNED_ZERO.search("x -0.0 µm") and SIGNED_ZERO.search("(x +0.00, y")
    assert not SIGNED_ZERO.search("-0.62 ± 0.09") and not SIGNED_ZERO.search("1e-05")


def test_value_with_u_and_a_u_not_determinable():
    assert value_u(12.73, 2.83, "urad") == "12.7 ± 2.8 µrad"
    assert value_u(-0.0, 0.12, "um") == "0 ± 0.12 µm"
    assert value_u(-1.5, 0.25, "") == "-1.5 ± 0.25"
    for u in (float("nan"), float("inf"), 0.0):
        t = value_u(1.2, u, "um", "aliased with drift")
        assert t == "1.2 µm (u not determinable: aliased with drift)" and "nan" not in t
    assert value_u(1.2, float("nan"), "um") == (
        "1.2 µm (u not determinable: the data do not determine it)")

"""Hidden-effect suite: each catalogue effect hidden from the baseline is named first and
adding it brings χ²/dof into [0.75, 1.3]; with nothing hidden the verdict is null."""

import numpy as np
import pytest
import scenarios as sc
from scipy import stats

from cmm_core.diagnosis import diagnose
from cmm_core.machine import ERROR_NAMES
from cmm_core.model import catalogue_entry, fit, parse_spec, simulate

# Realistic magnitudes: a few µm, a few arcseconds (1" = 4.85 µrad), 1-2 K.
HIDDEN = {
    "plate_sag": ({"effects": {"plate_sag": {"uu": -2.0, "uv": 0.5, "vv": -1.5}}},
                  "kinematic21"),
    "plate_thermal": ({"effects": {"plate_thermal": {"cte_per_K": 11.5e-6}}}, "kinematic21"),
    "probe_offset": ({"effects": {"probe_offset": {"sd_um": 2.0}}}, "kinematic21"),
    "drift": ({"effects": {"drift": {"sd_um_per_h": 3.0}}, "order": "serpentine"},
              "kinematic21"),
    "sxy": ({"kinematic": {"coefficients": {"sxy": 20.0}}}, "kinematic21,-sxy"),
    "syz": ({"kinematic": {"coefficients": {"syz": 10.0}}}, "kinematic21,-syz"),
    "rxy": ({"kinematic": {"coefficients": {"rxy[1]": 5.0, "rxy[2]": 2.0}}},
            "kinematic21,-rxy"),
    "dyz:3": ({"kinematic": {"spec": "kinematic21,dyz:3", "coefficients": {"dyz[3]": 2.0}}},
              "kinematic21"),
    # reversal span of 1.5 µm in X and Y, balls visited in serpentine order
    "backlash": ({"effects": {"backlash": {"x_um": 1.5, "y_um": 1.5, "z_um": 0.0}},
                  "order": "serpentine"}, "kinematic21"),
    # two orders above the model: offered as a candidate of its own (effects.candidates)
    "dyz:4": ({"kinematic": {"spec": "kinematic21,dyz:4", "coefficients": {"dyz[4]": 3.0}}},
              "kinematic21"),
}


@pytest.mark.parametrize("effect", list(HIDDEN))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hidden_effect_is_named_first(effect, seed):
    cfg, baseline = HIDDEN[effect]
    sim = simulate({**cfg, "seed": seed})
    d = diagnose(sim.dataset, baseline)
    assert d.verdict == effect, [(c.effect, round(c.delta_bic, 1)) for c in d.candidates[:4]]
    top = d.candidates[0]
    assert top.significant and top.confirmed and top.delta_bic < 0 and top.p_value < 1e-3
    refit = fit(sim.dataset, parse_spec(baseline).with_token(effect))
    assert 0.75 <= refit.chi2_dof <= 1.3
    assert refit.rms_um < d.baseline.rms_um
    # The signature is the part of the residual the effect removes: a least-squares
    # projection of the residual, so s·r = |s|² (one Gauss-Newton step, nearly linear).
    s, r = top.signature_um.ravel(), d.baseline.residuals_um.ravel()
    assert s @ r == pytest.approx(s @ s, rel=0.05)


def test_null_verdict_when_nothing_is_hidden():
    """No false alarms: at least 95 % of 20 clean seeds give a null verdict."""
    verdicts = [diagnose(simulate({"seed": 200 + s}).dataset, "kinematic21").verdict
                for s in range(20)]
    assert sum(v is None for v in verdicts) >= 19, verdicts


def test_drift_and_probe_step_are_aliases_when_probes_are_measured_in_blocks():
    """Probe blocks measured one after the other: a probe offset error looks like drift.
    The aliases are reported with the measurement that separates them."""
    sim = simulate({"seed": 3, "effects": {"probe_offset": {"sd_um": 2.0}}})
    d = diagnose(sim.dataset, "kinematic21")
    top = d.candidates[0]
    assert top.effect == "probe_offset" and "drift" in top.aliases
    assert "interleave" in top.separate_by
    assert "cannot be told apart" in d.message


def test_missing_data_skips_candidates_with_reason(thesis):
    d = diagnose(thesis, "kinematic21", positions=["BP211", "BP212", "BP311", "BP312"],
                 candidates=["plate_sag", "dxx:3"])
    assert "plate_sag" in d.skipped and "horizontal" in d.skipped["plate_sag"]


def test_thesis_diagnosis_runs_end_to_end(thesis):
    from cmm_core.diagnosis import detect_outliers

    d = diagnose(thesis, "kinematic21", exclude=detect_outliers(thesis).exclusions)
    assert d.baseline.chi2_dof > 10  # the thesis data are far from explained by 21 errors
    assert d.verdict == "plate_sag"
    out = d.to_dict()
    assert set(out) >= {"baseline", "candidates", "verdict"}
    assert out["candidates"][0]["delta_bic"] <= out["candidates"][1]["delta_bic"]


def test_every_candidate_has_a_catalogue_entry():
    for tok in parse_spec("rigid").candidates() + parse_spec("kinematic21").candidates():
        e = catalogue_entry(tok)
        assert e.explanation and e.needs and e.confused_with and e.separate_by


@pytest.mark.parametrize("seed", [5, 8])
def test_gp_discrepancy_shrinks_when_the_missing_effect_is_added(seed):
    """Issue 4 item 6: the GP over the residuals, with the model's own design matrix as its
    basis, sees the hidden sag as smooth structure in z; adding plate_sag leaves noise, so
    the structure the GP finds in z falls to a fraction (seeds 5-8 give ratios 0-0.22)
    and the one-number history value falls with it."""
    from cmm_core.diagnosis import discrepancy_gp

    sim = simulate({"seed": seed,
                    "effects": {"plate_sag": {"uu": -2.0, "uv": 0.5, "vv": -1.5}}})
    before = discrepancy_gp(fit(sim.dataset, "kinematic21"), restarts=1)
    after = discrepancy_gp(fit(sim.dataset, "kinematic21,plate_sag"), restarts=1)
    # z carries the sag: more structure there than in x and y before the effect is added
    assert before.structure_um["z"] > 2 * max(before.structure_um["x"],
                                              before.structure_um["y"])
    assert after.structure_um["z"] < 0.3 * before.structure_um["z"]
    assert after.rms_amplitude_um < 0.5 * before.rms_amplitude_um


def test_progress_callback_reports_monotone_fractions_up_to_one():
    calls = []
    sim = simulate({"seed": 9})
    diagnose(sim.dataset, "kinematic21", progress=lambda f, t: calls.append((f, t)))
    fracs = [f for f, _ in calls]
    assert len(calls) > 10 and fracs == sorted(fracs) and fracs[-1] == 1.0
    assert any("confirming" in t for _, t in calls)


@pytest.fixture(scope="module")
def clean_design():
    """A clean simulation of the thesis-like design: the detection limits depend on the
    design (placements, probes, noise), not on the values measured."""
    return simulate({"seed": 0}).dataset


def _limits(dataset, name):
    return diagnose(dataset, f"kinematic21,-{name}", candidates=[name]).candidates[0].detectable


@pytest.mark.parametrize("name", ERROR_NAMES)
def test_every_kinematic_error_at_twice_its_detection_limit_is_named_first(name, clean_design):
    """Each of the 21 errors hidden from kinematic21 at twice the size the tool says this
    design can see (from 0.2 µm for z straightness up to 9 µrad, about 2", for ryz: a ram
    rotation is only seen through the ±50 mm stylus arms) is named first, and the refit
    with it explains the data to noise."""
    base = f"kinematic21,-{name}"
    coefs = {lab: 2 * size * (-1) ** i
             for i, (lab, (_unit, size)) in enumerate(_limits(clean_design, name).items())}
    for seed in (1, 2):
        sim = simulate({"seed": seed, "kinematic": {"coefficients": coefs}})
        d = diagnose(sim.dataset, base)
        assert d.verdict == name, [(c.effect, round(c.delta_bic, 1)) for c in d.candidates[:3]]
        assert 0.75 <= fit(sim.dataset, parse_spec(base).with_token(name)).chi2_dof <= 1.3


@pytest.mark.slow
def test_detection_limit_is_calibrated(clean_design):
    """At exactly the reported detection limit an effect is found with 80 % probability
    (its definition). 60 simulations (sxy, syz; 30 seeds each): expect 48 detections,
    binomial sd 3.1; accept ±3 sd."""
    hits = 0
    for name in ("sxy", "syz"):
        coefs = {lab: size for lab, (_u, size) in _limits(clean_design, name).items()}
        for seed in range(100, 130):
            sim = simulate({"seed": seed, "kinematic": {"coefficients": coefs}})
            hits += diagnose(sim.dataset, f"kinematic21,-{name}",
                             candidates=[name]).verdict == name
    assert 39 <= hits <= 57, hits


def _periodic_sim(seed, axis, period, amp_um=1.0, pitch_mm=50.0, balls=9):
    """A periodic scale error on a plate fine enough to resolve it (9 x 9 balls at 50 mm:
    periods from 2.5 pitches = 125 mm are scanned)."""
    fn = {"x": "dxx", "y": "dyy", "z": "dzz"}[axis]
    return simulate({"seed": seed, "plate": {"rows": balls, "cols": balls, "pitch_mm": pitch_mm},
                     "kinematic": {
        "spec": f"kinematic21,periodic_{axis}:{period}",
        "coefficients": {f"{fn}[sin{period}]": amp_um, f"{fn}[cos{period}]": -amp_um / 2}}})


@pytest.mark.parametrize("axis,period", [("x", 180), ("y", 150), ("x", 250)])
@pytest.mark.parametrize("seed", [0, 1])
def test_hidden_periodic_scale_error_is_named_with_its_period(axis, period, seed):
    """A periodic scale error of 1.1 µm amplitude (not in the simulated baseline) is named
    first with its period found by the scan to 5 % (the scan's grid is 5 % apart and the
    best period is refined), and the refit explains the data to noise."""
    sim = _periodic_sim(seed, axis, period)
    d = diagnose(sim.dataset, "kinematic21")
    name, _, found = (d.verdict or "").partition(":")
    assert name == f"periodic_{axis}", [c.effect for c in d.candidates[:3]]
    assert float(found) == pytest.approx(period, rel=0.05)
    assert 0.75 <= fit(sim.dataset, f"kinematic21,{d.verdict}").chi2_dof <= 1.3


def test_a_long_period_and_a_higher_order_are_shown_as_an_undecided_pair():
    """300 mm is about one period over the 400 mm plate: an order-4 positioning error
    follows it as well (signatures 90 % alike). The physical polynomial is named, with the
    periodic error as its alias and the measurement that separates them."""
    d = diagnose(_periodic_sim(0, "x", 300).dataset, "kinematic21")
    assert d.verdict == "dxx:4"
    assert any(a.startswith("periodic_x:") for a in d.candidates[0].aliases)
    assert "cannot be told apart from periodic_x" in d.message


def test_a_period_the_ball_spacing_cannot_resolve_is_not_scanned():
    """60 mm along x is under half the 133 mm ball pitch: the plate samples it as another
    period, and anything that differs from ball to ball or placement to placement fits
    such periods as well. No period below 2.5 pitches (333 mm) is scanned."""
    from cmm_core.model import shortest_resolvable_period

    sim = _periodic_sim(0, "x", 60, pitch_mm=133.0, balls=5)
    d = diagnose(sim.dataset, "kinematic21")
    base = d.baseline
    shortest, spacing = shortest_resolvable_period(base.problem.obs, 0)
    assert spacing == pytest.approx(133.0, abs=1.0) and shortest == pytest.approx(332.5, abs=3)
    periods = [float(c.effect.partition(":")[2]) for c in d.candidates
               if c.effect.startswith("periodic_x:")]
    periods += [float(a.partition(":")[2]) for c in d.candidates for a in c.aliases
                if a.startswith("periodic_x:")]
    assert periods and min(periods) >= 330, periods


@pytest.mark.parametrize("order", [1, 3])
def test_candidates_are_scored_against_the_baseline_at_its_own_order(order):
    """Regression: at order 3 the candidates were once scored against an order-2 copy of
    the baseline, so adding a parameter "raised" χ² by hundreds. Adding parameters can only
    lower χ² (Δχ² >= 0 up to round-off), and a hidden sag is still named first."""
    sim = simulate({"seed": 4, "kinematic": {"order": order},
                    "effects": {"plate_sag": {"uu": -2.0, "uv": 0.5, "vv": -1.5}}})
    d = diagnose(sim.dataset, "kinematic21", order=order)
    assert d.baseline.spec == f"kinematic21:{order}"
    assert min(c.delta_chi2 for c in d.candidates) > -1e-6 * d.baseline.chi2
    assert d.verdict == "plate_sag"


def test_drift_of_every_position_is_not_credited_to_an_aliased_period():
    """Seed 54 (found by a stress run): hidden drift of every position. A periodic Y error
    at 45 mm, a period the 133 mm ball spacing aliases into a different slope at each
    position, once took a third of drift's χ² reduction with 2 parameters and was ranked
    first by ΔBIC. Such periods are no longer scanned: drift is named, and adding it
    explains the data to noise."""
    sim = simulate({"seed": 54, "order": "serpentine", "probes_interleaved": True,
                    "effects": {"drift": {"sd_um_per_h": 3.0},
                                "plate_thermal": {"cte_per_K": 11.5e-6}}})
    d = diagnose(sim.dataset, "kinematic21,plate_thermal")
    assert d.verdict == "drift", [(c.effect, round(c.delta_bic, 1)) for c in d.candidates[:3]]
    assert 0.75 <= fit(sim.dataset, "kinematic21,plate_thermal,drift").chi2_dof <= 1.3


def test_candidates_on_an_undetermined_baseline_count_only_their_own_parameters(thesis):
    """A single placement leaves combinations of kinematic21 undetermined. A candidate
    scored from it keeps them held: adding one Chebyshev term adds one parameter, not
    the baseline's undetermined directions as well (found by the browser review:
    rxy:3 was credited with 5)."""
    d = diagnose(thesis, "kinematic21", positions=["BP111"],
                 candidates=["rxy:3", "dzx:3", "dxx:3"])
    assert d.baseline.null_combinations and "undetermined" in d.message
    # one Chebyshev term each: at most one parameter (0 when the design cannot see it)
    n = {c.effect: c.n_params for c in d.candidates}
    assert max(n.values()) == 1 and n["rxy:3"] == 1, n


def test_a_higher_order_must_beat_the_next_one_by_a_nested_test():
    """Seed 1002 (stress run): hidden dzz[3] only. dzz:4 wins ΔBIC by 0.9 (a near tie:
    the extra coefficient takes 7.7 of χ² by chance); the nested F-test of order 4 against
    order 3 is not significant, so order 3 is named."""
    sim = simulate({"seed": 1002, "kinematic": {"spec": "kinematic21,dzz:3",
                                                "coefficients": {"dzz[3]": 1.5}}})
    d = diagnose(sim.dataset, "kinematic21")
    assert d.verdict == "dzz:3", [(c.effect, round(c.delta_bic, 1)) for c in d.candidates[:3]]
    assert "Order 4 adds nothing significant to order 3" in d.message


def test_two_hidden_effects_are_found_one_at_a_time():
    """Plate sag and backlash hidden together: the first diagnosis names one and says that
    more is missing; with it added the second names the other, and with both the data are
    explained to noise (the add-and-watch loop of the diagnosis page)."""
    sim = simulate({"seed": 21, "order": "serpentine",
                    "effects": {"plate_sag": {"uu": -4.0, "uv": 0.5, "vv": -3.0},
                                "backlash": {"x_um": 2.0, "y_um": 2.0}}})
    hidden = {"plate_sag", "backlash"}
    first = diagnose(sim.dataset, "kinematic21")
    assert first.verdict in hidden and "more is missing" in first.message
    second = diagnose(sim.dataset, f"kinematic21,{first.verdict}")
    assert second.verdict == (hidden - {first.verdict}).pop()
    both = fit(sim.dataset, "kinematic21,plate_sag,backlash")
    assert 0.75 <= both.chi2_dof <= 1.3 < first.candidates[0].chi2_dof
    assert diagnose(sim.dataset, "kinematic21,plate_sag,backlash").verdict is None


def test_a_slow_baseline_is_refitted_to_convergence_before_scoring(thesis):
    """BP111 alone at order 4 needs about 220 iterations (review finding): scored against
    the stopped fit, rxz:5 was credited with Δχ² ≈ 110 of the baseline's own unfinished
    improvement; against the converged one it adds nothing (Δχ² ≈ 0.1)."""
    d = diagnose(thesis, "kinematic21", order=4, positions=["BP111"],
                 candidates=["plate_thermal", "rxz:5"])
    assert d.baseline.status == "converged"
    # credited nothing: ranked with Δχ² < 1, or adding no determinable parameter at all
    # and so listed as unseen rather than ranked (issue 26, point 4)
    c = next((c for c in d.candidates if c.effect == "rxz:5"), None)
    assert ("rxz:5" in d.unseen) if c is None else c.delta_chi2 < 1.0


def test_an_unconverged_baseline_names_no_effect(monkeypatch):
    """Plate sag hidden, but every fit stopped after one iteration: no verdict, and the
    message says why instead of crediting the baseline's unfinished descent to an effect."""
    import cmm_core.diagnosis.search as dg

    real = dg.fit
    monkeypatch.setattr(dg, "fit", lambda *a, **k: real(*a, **{**k, "max_iter": 1}))
    sim = simulate({**HIDDEN["plate_sag"][0], "seed": 0})
    d = dg.diagnose(sim.dataset, "kinematic21")
    assert d.baseline.status != "converged"
    assert d.verdict is None and "did not converge" in d.message


def test_two_orders_of_one_function_are_not_reported_as_aliases():
    """Review finding: with_token replaces an order, so base+dyx:4+dyx:3 is base+dyx:3 and
    the nested tests made the two orders 'aliases'. Orders are compared by the Occam rule
    only; the message must not say they cannot be told apart."""
    sim = simulate({"seed": 1, "kinematic": {"spec": "kinematic21", "order": 4,
                                             "random_um": 0.3, "random_urad": 0.3,
                                             "coefficients": {"dyx[3]": 3.0, "dyx[4]": 4.0}}})
    d = diagnose(sim.dataset, "kinematic21")
    assert d.verdict == "dyx:4" and "dyx:3" not in d.candidates[0].aliases


def _candidate(effect, p, level, dbic):
    from cmm_core.diagnosis import Candidate

    return Candidate(effect=effect, title=effect, explanation="", needs="", separate_by="",
                     rms_um=0.5, chi2_dof=1.0, delta_chi2=30.0, n_params=1, delta_bic=dbic,
                     p_value=p, significant=True, confirmed=True,
                     signature_um=np.zeros((1, 3)), level=level)


@pytest.mark.parametrize("rival, named", [
    # an order-3 term ahead on ΔBIC, plate sag better supported at its level: plate sag
    (("rxx:3", 7e-5, 1.0e-4, -10.2), "plate_sag"),
    # a periodic error even better supported: the physical effect keeps the name
    (("periodic_x:180", 1e-12, 1.0e-4, -30.0), "plate_sag"),
])
def test_mutual_aliases_are_named_in_weighted_holm_order(monkeypatch, rival, named):
    """Two candidates neither of which adds anything once the other is in (nested F-tests
    mocked at p = 0.5): the one with the smaller p relative to its level is named, never
    a periodic error over a physical one, and the other is its alias (pitch-80 layout,
    plate sag hidden at its detection limit, was named rxx:3 by ΔBIC)."""
    from types import SimpleNamespace

    from cmm_core.diagnosis import verdict as V

    monkeypatch.setattr(V, "_refit", lambda base, spec, max_iter, cache=None: spec)
    monkeypatch.setattr(V, "_nested_p", lambda small, big: 0.5)
    spec = SimpleNamespace(with_token=lambda t: SimpleNamespace(with_token=lambda u: u))
    base = SimpleNamespace(problem=SimpleNamespace(spec=spec))
    top = _candidate(*rival)
    sag = _candidate("plate_sag", 4.1e-5, 1.0e-3, -4.8)
    out, note = V._encompassing(base, [top, sag], top.level, {}, 0.008)
    out = V._physical_before_periodic(out)
    assert out[0].effect == named and top.effect in out[0].aliases
    assert f"{named} is named ahead of {top.effect}" in note
    assert ("physical story" in note) == top.effect.startswith("periodic")


def test_two_aliases_far_beyond_their_levels_are_ordered_by_their_tails_not_rounding():
    """Issue 26: ``sxy`` hidden at twice its detection limit (11.4 µrad on this layout,
    ``bench/honesty.py``'s clean diagnosis, seed 999) on the 80 mm layout (seed 10), with
    ``rxz:4`` its alias. The alias rule names the one with the smaller p against its level;
    rxz:4's p (two parameters with a fixed certificate: Imhof's integral, accurate to
    ~1e-15) came out as 0 and won against sxy's 2.7e-21 by rounding. Compared on the
    F-tests' log-tails, sxy (Δχ² 106 for 1 parameter against rxz:4's 98 for 2) is named,
    with rxz:4 as its alias."""
    sim = sc.simulated("pitch80_3pos", 10, order="serpentine", kinematic={
        "spec": "kinematic21", "coefficients": {"sxy": 2 * 11.36}})
    d = diagnose(sim.dataset, "kinematic21,-sxy")
    by = {c.effect: c for c in d.candidates}
    assert by["rxz:4"].significant and by["rxz:4"].p_value < 1e-12  # both far beyond
    assert d.verdict == "sxy" and "rxz:4" in d.candidates[0].aliases, d.message


@pytest.mark.parametrize("k", [1, 2, 3, 9])
def test_the_detectable_size_is_the_80_percent_power_of_the_candidates_own_test(k):
    """``search._k_detect``: the shift (in standard uncertainties) at which a test of the
    candidate's k parameters at its level rejects with probability 0.8, checked by Monte
    Carlo of the test itself (the squared norm of k unit normals shifted along one
    direction against the central χ²_k quantile; the two-sided z-test for k = 1, whose
    far tail the normal approximation drops). 200 000 draws: binomial standard error
    0.0009, so ±0.005 is 5 of them."""
    from cmm_core.diagnosis.search import _k_detect

    level = 0.0008
    shift = _k_detect(level, k)
    z = np.random.default_rng(20261126).standard_normal((200_000, k))
    z[:, 0] += shift
    if k == 1:
        power = np.mean(np.abs(z[:, 0]) > stats.norm.isf(level / 2))
    else:
        power = np.mean((z ** 2).sum(axis=1) > stats.chi2.isf(level, k))
    assert power == pytest.approx(0.8, abs=0.005)

"""Blunders first (issue 26, point 1): a flagged gross error that holds most of the misfit
is the first verdict, with the observation, its share of χ² and the action; once it is
excluded the diagnosis names the real effect underneath. On three machine layouts and
three scenario layouts (not the sample data's)."""

import numpy as np
import pytest
import scenarios as sc

from cmm_core.diagnosis import BLUNDERS, DOMINANT_SHARE, diagnose
from cmm_core.model import simulate

SAG = {"plate_sag": {"uu": -1.0, "uv": 0.3, "vv": -0.8}}
"""A plate sag of about 1 µm at the plate's corners: small, yet found at σ = 0.5 µm
(p < 1e-6 on these layouts once the blunder is out)."""

CASES = [
    # (machine layout, scenario layout, hidden effect, the effect's token)
    ("moving_bridge_fxyz", "pitch100_4pos", SAG, "plate_sag"),
    ("gantry_fyxz", "pitch150_5pos", {"bridge_twist": {"lin_urad": 4.0, "quad_urad": 2.0}},
     "bridge_twist"),
    ("horizontal_arm_fxzy", "pitch80_3pos", SAG, "plate_sag"),
]

BLUNDER_UM = 40.0
"""The issue's case: one 40 µm blunder, 80 σ at σ = 0.5 µm."""


def _with_blunder(layout, name, effects, seed, row=17, axis=1, size_um=BLUNDER_UM):
    cfg = sc.layout_config(name, seed=seed, effects=effects)
    cfg["setup"]["machine"]["layout"] = layout
    ds = simulate(cfg).dataset
    delta = np.zeros((len(ds.meas), 3))
    delta[row, axis] = size_um * 1e-3
    return sc.perturb(ds, delta), ds.meas.iloc[row]


@pytest.mark.parametrize(("layout", "name", "effects", "token"), CASES)
def test_the_blunder_is_named_first_then_the_effect(layout, name, effects, token):
    data, bad = _with_blunder(layout, name, effects, seed=7)
    d = diagnose(data, "kinematic21")
    assert d.verdict == BLUNDERS, d.message
    b = d.blunders
    assert b.dominant and b.excess_share > DOMINANT_SHARE
    assert (bad["position"], bad["probe"], int(bad["ball"])) in b.exclusions
    # the message leads with it: which observation, its share, the action; no σ offered
    assert d.message.startswith("Flagged outlier(s) first")
    assert f"ball {int(bad['ball'])} y" in d.message and "--exclude-outliers" in d.message
    assert "Exclude the flagged outliers" in d.message
    assert d.sigma is None and d.holdout == []
    js = d.to_dict()
    assert js["verdict"] == BLUNDERS and js["blunders"]["exclusions"]
    # the action taken: the next verdict is the effect under the blunder
    d2 = diagnose(data, "kinematic21", exclude=b.exclusions)
    assert d2.verdict == token, d2.message
    assert d2.blunders is None


def test_a_blunder_under_a_large_effect_is_listed_not_the_verdict():
    """The rule is a share: a 12 µm blunder beside a 4 µm sag is not most of the misfit,
    so the sag is named and the outlier only mentioned."""
    effects = {"plate_sag": {"uu": -4.0, "uv": 1.0, "vv": -3.0}}
    data, bad = _with_blunder("moving_bridge_fxyz", "pitch100_4pos", effects, seed=8,
                              size_um=12.0)
    d = diagnose(data, "kinematic21")
    assert d.verdict == "plate_sag", d.message
    assert d.blunders is not None and not d.blunders.dominant
    assert "flagged outlier(s) are still in the fit" in d.message


def test_clean_data_have_no_blunder_verdict():
    data, _ = _with_blunder("moving_bridge_fxyz", "pitch100_4pos", SAG, seed=9, size_um=0.0)
    d = diagnose(data, "kinematic21")
    assert d.verdict == "plate_sag" and d.blunders is None

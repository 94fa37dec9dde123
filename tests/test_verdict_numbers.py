"""Verdicts that say the numbers (issue 26, point 5): a probe offset names the stylus and
its fitted offset vector with u, and the message says which χ²/dof the test decides on."""

import numpy as np
import pytest
import scenarios as sc

from cmm_core.diagnosis import diagnose
from cmm_core.model import simulate


@pytest.mark.parametrize(("layout", "name"), [("moving_bridge_fxyz", "pitch100_4pos"),
                                              ("gantry_fyxz", "pitch150_5pos"),
                                              ("horizontal_arm_fxzy", "pitch100_4pos")])
def test_a_probe_offset_verdict_names_the_stylus_and_its_vector(layout, name):
    """One stylus off by (0, 3, −2) µm (the others exact): named, with its vector within
    3 u of the truth relative to the mean of all styli (the fit's gauge: offsets sum to
    zero, so the truth seen is e − mean(e)). Not pitch80_3pos: there each placement
    measures its styli one after the other, so a probe offset is an alias of drift (the
    diagnosis says so and names drift; interleaving the styli separates them)."""
    probes = list(sc.LAYOUTS[name]["probes"])
    # a stylus used in more than one placement, so the fit can tell it from a placement
    uses = {q: sum(q in ps for _, ps in sc.LAYOUTS[name]["positions"].values())
            for q in probes}
    off_q = max(probes, key=lambda q: uses[q])
    e = np.array([0.0, 3.0, -2.0])
    effects = {"probe_offset": {q: (e if q == off_q else np.zeros(3)).tolist()
                                for q in probes}}
    cfg = sc.layout_config(name, seed=11, effects=effects)
    cfg["setup"]["machine"]["layout"] = layout
    d = diagnose(simulate(cfg).dataset, "kinematic21")
    assert d.verdict == "probe_offset", d.message
    assert f"Stylus {off_q} is the furthest off" in d.message
    best = d.candidates[0]
    fitted = d.to_dict()["candidates"][0]["fitted"]
    seen = e - e / len(probes)
    for i, a in enumerate("xyz"):
        f = fitted[f"probe{off_q}.{a}"]
        assert f["unit"] == "um"
        assert abs(f["value"] - seen[i]) < 3 * f["u"], (a, f, seen[i])
        assert f"{a} {f['value']:+.2f} ± {f['u']:.2f}" in d.message
    assert best.fitted == {k: (v["unit"], v["value"], v["u"]) for k, v in fitted.items()}


def test_the_tested_chi2_dof_is_named_as_the_one_that_decides():
    """With the certificate fixed the test counts its uncertainty: the message quotes
    that value first and explains the fit's own once."""
    d = diagnose(simulate(sc.layout_config("pitch100_4pos", seed=2)).dataset, "kinematic21")
    b = d.baseline
    assert b.test_counts_certificate
    assert f"χ²/dof {b.chi2_test_dof:.2f} at" in d.message
    assert "this is the value the test decides on" in d.message
    assert d.message.count(f"{b.chi2_dof:.2f}") == 1

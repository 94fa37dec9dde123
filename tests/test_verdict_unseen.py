"""Only what the design can see is ranked (issue 26, point 4): a candidate with no
determinable parameter on this design is listed under "cannot be seen with this design"
with the reason, never ranked and never given a detection limit of 0."""

import numpy as np
import pytest
import scenarios as sc

from cmm_core.diagnosis import diagnose
from cmm_core.model import simulate

SAG = {"plate_sag": {"uu": -2.0, "uv": 0.5, "vv": -1.5}}


@pytest.mark.parametrize(("layout", "name"), [("moving_bridge_fxyz", "pitch100_4pos"),
                                              ("gantry_fyxz", "pitch150_5pos"),
                                              ("fixed_bridge_xfyz", "pitch80_3pos")])
def test_a_hole_plate_cannot_see_its_sag(layout, name):
    """A hole plate measures only in its plane: its sag (normal to it) adds no
    determinable parameter, whatever the sag's size (here 2 µm, found at p < 1e-6 on a
    ball plate of the same layouts)."""
    cfg = sc.layout_config(name, seed=3, effects=SAG, artefact="hole_plate")
    cfg["setup"]["machine"]["layout"] = layout
    d = diagnose(simulate(cfg).dataset, "kinematic21")
    assert "plate_sag" not in [c.effect for c in d.candidates]
    assert "hole plate" in d.unseen["plate_sag"]
    assert "Cannot be seen with this design: plate_sag" in d.message
    assert d.to_dict()["cannot_see"] == d.unseen
    assert d.verdict != "plate_sag"
    for c in d.candidates:  # every ranked candidate adds something, with a real limit
        assert c.n_params > 0
        assert all(v > 0 for _, v in c.detectable.values()), (c.effect, c.detectable)


def test_the_same_sag_on_a_ball_plate_is_seen():
    """The control: the ball plate of the same layout and seed ranks and names it."""
    cfg = sc.layout_config("pitch100_4pos", seed=3, effects=SAG)
    d = diagnose(simulate(cfg).dataset, "kinematic21")
    assert d.verdict == "plate_sag" and not d.unseen
    lim = d.candidates[0].detectable
    assert all(np.isfinite(v) and v > 0 for _, v in lim.values())

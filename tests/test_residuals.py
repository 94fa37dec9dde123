"""'Where it fails' views: breakdowns and per-position trends."""

import numpy as np
import pytest

from cmm_core.analysis import against_coordinates, approach_split, breakdown, position_trends
from cmm_core.diagnosis import detect_outliers
from cmm_core.model import fit, simulate


def test_breakdown_shares_sum_to_one_and_find_the_bad_position():
    sim = simulate({"seed": 8})
    meas = sim.dataset.meas
    bad = (meas["position"] == "BP211").to_numpy()
    meas.loc[bad, "mx_mm"] += np.random.default_rng(0).normal(0, 3e-3, bad.sum())
    r = fit(sim.dataset)
    b = breakdown(r, "position")
    assert b["chi2_share"].sum() == pytest.approx(1.0)
    assert b.iloc[0]["position"] == "BP211"
    assert b["n"].sum() == r.n_obs
    long = against_coordinates(r)
    assert len(long) == 3 * r.n_obs and set(long["component"]) == {"x", "y", "z"}


def test_position_trends_recover_a_simulated_sag_bowl():
    """Sag acts only on horizontal placements: their bowl_uu matches the simulated
    coefficient (µm over the normalised plate), vertical ones show none."""
    sim = simulate({"seed": 1, "kinematic": {"random_um": 0, "random_urad": 0},
                    "plate": {"form_um": 0, "certificate_u_um": 0},
                    "effects": {"plate_sag": {"uu": -4.0, "vv": -2.0}}})
    t = position_trends(sim.dataset)
    h, v = t[t.horizontal], t[~t.horizontal]
    # 25 balls with 0.5 µm noise: u(bowl) ≈ 0.3 µm; allow 4u.
    assert np.all(np.abs(h["bowl_uu_um"] + 4.0) < 4 * h["u_bowl_uu_um"] + 0.05)
    assert np.all(np.abs(h["bowl_vv_um"] + 2.0) < 4 * h["u_bowl_vv_um"] + 0.05)
    assert np.all(np.abs(v["bowl_uu_um"]) < 4 * v["u_bowl_uu_um"] + 0.05)


def test_thesis_trends_show_bp111_y_scale_and_horizontal_bowl(thesis):
    t = position_trends(thesis, detect_outliers(thesis).exclusions).set_index("position")
    vertical = t[~t.horizontal]
    # BP111's plate-y scale stands apart from the vertical placements (docs/thesis-data.md).
    assert t.loc["BP111", "scale_v_ppm"] - vertical["scale_v_ppm"].mean() > 2 * t.loc[
        "BP111", "u_scale_v_ppm"]
    assert t.loc["BP111", "bowl_uu_um"] < vertical["bowl_uu_um"].min() - 5


def test_approach_split_points_at_a_hidden_reversal_and_clears_once_it_is_fitted():
    """Spans +3 µm in x, -2 µm in y, none in z, random order: without the backlash block
    the x and y residuals differ between the two approach directions by more than 4 u
    with the sign of the span; with it every difference is within 4 u of zero."""
    sim = simulate({"seed": 2, "order": "random",
                    "effects": {"backlash": {"x_um": 3.0, "y_um": -2.0, "z_um": 0.0}}})
    t = approach_split(fit(sim.dataset, "kinematic21")).set_index("axis")
    assert t.loc["x", "reversal_um"] > 4 * t.loc["x", "u_reversal_um"]
    assert t.loc["y", "reversal_um"] < -4 * t.loc["y", "u_reversal_um"]
    assert abs(t.loc["z", "reversal_um"]) < 4 * t.loc["z", "u_reversal_um"]
    assert (t["n_plus"] + t["n_minus"] <= len(sim.dataset.meas)).all()
    t2 = approach_split(fit(sim.dataset, "kinematic21,backlash"))
    assert (t2["reversal_um"].abs() < 4 * t2["u_reversal_um"]).all()

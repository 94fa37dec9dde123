"""Compensation through the blocks' hooks (issue 12): model files written before the
hooks give the same corrections bit for bit, and a machine_thermal model corrects new
points at other scale temperatures with calibrated uncertainties."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cmm_core.compensate import compensate, load_model, read_points

LEGACY = Path(__file__).resolve().parent / "corpus" / "legacy_models"
NUMERIC = ["xc_mm", "yc_mm", "zc_mm", "ex_um", "ey_um", "ez_um", "u_x_um", "u_y_um",
           "u_z_um"]


@pytest.mark.parametrize("tag", ["kinematic", "backlash"])
def test_model_files_written_before_the_hooks_give_the_same_corrections(tag):
    """``make_legacy_models.py`` wrote these files and their corrections with the release
    before compensation looped over the blocks (backlash then a special case of
    compensate): loaded now, they correct the same points to the same doubles."""
    model = load_model(LEGACY / f"model_{tag}.json")
    out = compensate(model, read_points(LEGACY / "points.csv"))
    want = pd.read_csv(LEGACY / f"corrected_{tag}.csv", keep_default_na=False)
    np.testing.assert_array_equal(out[NUMERIC].to_numpy(float), want[NUMERIC].to_numpy(float))
    assert list(out["extrapolated"]) == list(want["extrapolated"])
    approach = [f"approach_{a}" for a in "xyz"]
    assert (tag == "backlash") == (set(approach) <= set(out.columns))
    if tag == "backlash":
        np.testing.assert_array_equal(out[approach].to_numpy(), want[approach].to_numpy())

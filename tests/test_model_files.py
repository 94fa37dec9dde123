"""Model files: magnitudes a CMM can have, a covariance that is a covariance, and no NaN
or inf in any correction or grid (issue 25).

Reference values: the bound on a coefficient is checked against the kinematic model's own
error (``kinematics.error``) at the far corner of the strokes, an evaluation independent
of the Jacobian the check uses; the model is ``tests/corpus/good_model.json`` (a
``kinematic21`` fit of the simulated sample data, 1200 × 1000 × 700 mm).
"""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cmm_core.export import compensate, compensation_grid, model_from_dict
from cmm_core.io import DataError
from cmm_core.machine import kinematics as kin

GOOD = Path(__file__).resolve().parent / "corpus" / "good_model.json"
BOUND_MM = 10.0  # the documented bound (docs/compensation.md, model_file._MAX_ERROR_UM)


def _dict():
    return json.loads(GOOD.read_text())


def _far_corner_error_mm(d, label, value):
    """|error| (mm) at the far corner of the strokes of a model whose only coefficient
    is ``label`` = ``value`` (kinematics.error: the model itself, not the check)."""
    m = model_from_dict(_dict(), name="good_model.json")
    coef = np.zeros(m.terms.n)
    coef[m.terms.labels.index(label)] = value
    x = np.array([m.terms.range_mm], float)
    return float(np.abs(kin.error(m.terms, coef, x, np.zeros((1, 3)))).max()) * 1e-3


def test_the_sample_model_is_accepted():
    m = model_from_dict(_dict(), name="good_model.json")
    assert np.abs(m.coef).max() < 10  # micrometres: far below the bound


@pytest.mark.parametrize("value", [1e308, -1e308, 1e30])
def test_a_huge_finite_coefficient_is_refused_naming_it(value):
    """A coefficient of 1e308 is finite, yet gave ±inf and NaN in every grid (issue 25)."""
    d = _dict()
    d["coef"][3] = value
    with pytest.raises(DataError) as exc:
        model_from_dict(d, name="m.json")
    msg = str(exc.value)
    assert "m.json" in msg and d["labels"][3] in msg and "10 mm" in msg
    assert "\n" not in msg


def test_the_bound_is_the_error_the_coefficient_makes_in_the_machine():
    """dxx[1] scaled so that the model's own error at the far corner is 0.95 and 1.05
    times the 10 mm bound: the first is accepted, the second refused (the bound is a
    statement about the error, not about the coefficient's number)."""
    per_unit_mm = _far_corner_error_mm(_dict(), "dxx[1]", 1.0)
    assert per_unit_mm > 0
    k = _dict()["labels"].index("dxx[1]")
    for share, refused in ((0.95, False), (1.05, True)):
        d = _dict()
        d["coef"] = [0.0] * len(d["coef"])
        d["coef"][k] = share * BOUND_MM / per_unit_mm
        if refused:
            with pytest.raises(DataError, match="dxx"):
                model_from_dict(d, name="m.json")
        else:
            model_from_dict(d, name="m.json")


def test_a_huge_variance_is_refused():
    """A variance of 1e300 (u = 1e150 µm) is a finite positive-definite matrix's entry,
    and would make every uncertainty inf."""
    d = _dict()
    d["cov"][2][2] = 1e300
    with pytest.raises(DataError, match="standard uncertainty"):
        model_from_dict(d, name="m.json")


def test_a_singular_covariance_is_refused_unless_the_model_says_undetermined():
    """The smallest eigen-direction removed: still symmetric and positive semi-definite,
    but a determined model's covariance is positive definite."""
    d = _dict()
    V = np.array(d["cov"])
    w, Q = np.linalg.eigh(V)
    d["cov"] = (V - w[0] * np.outer(Q[:, 0], Q[:, 0])).tolist()
    with pytest.raises(DataError, match="not positive definite"):
        model_from_dict(d, name="m.json")
    d["undetermined"] = True
    assert model_from_dict(d, name="m.json").undetermined


def _points(m, n=50, seed=0):
    rng = np.random.default_rng(seed)
    pts = pd.DataFrame(rng.uniform(0.2, 0.8, (n, 3)) * np.asarray(m.terms.range_mm),
                       columns=["x_mm", "y_mm", "z_mm"])
    pts["probe"] = next(iter(m.probes_mm))
    return pts


def test_no_nan_or_inf_leaves_compensate_or_a_grid():
    """A model made in code (no file check) with absurd coefficients: compensate and the
    grid refuse it in one line rather than write inf or NaN; a sound model's outputs are
    all finite."""
    m = model_from_dict(_dict(), name="good_model.json")
    good = compensate(m, _points(m))
    cols = ["xc_mm", "yc_mm", "zc_mm", "ex_um", "ey_um", "ez_um", "u_x_um", "u_y_um",
            "u_z_um"]
    assert np.isfinite(good[cols].to_numpy(float)).all()
    grid = compensation_grid(m, 200.0)
    assert np.isfinite(grid.drop(columns="extrapolated").to_numpy(float)).all()
    bad = replace(m, coef=m.coef * 1e306)
    with pytest.raises(DataError, match="expected finite numbers") as exc:
        compensate(bad, _points(m))
    assert "\n" not in str(exc.value)
    with pytest.raises(DataError, match="expected finite numbers"):
        compensation_grid(bad, 200.0)


def _number_leaves(obj, path=()):
    """Index paths of every JSON number in ``obj`` (bools are not numbers)."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _number_leaves(v, (*path, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _number_leaves(v, (*path, i))
    elif isinstance(obj, int | float) and not isinstance(obj, bool):
        yield path


_NUMBER_PATHS = [p for p in _number_leaves(_dict()) if p[0] != "provenance"]


@pytest.mark.parametrize("value", [True, False, "2"])
def test_no_number_of_a_model_file_is_read_from_a_boolean_or_a_string(value):
    """Generated over every number of the sample model (orders, strokes, coefficients,
    covariance, offsets, summary): ``true`` (read as 1.0 by ``float``), ``false`` and
    ``"2"`` are each refused in one line naming the file; none is taken as a number
    (issue 38: "true read as 1.0")."""
    assert len(_NUMBER_PATHS) > 100  # 21 coefficients and their covariance at least
    accepted = []
    for path in _NUMBER_PATHS:
        d = _dict()
        t = d
        for k in path[:-1]:
            t = t[k]
        t[path[-1]] = value
        try:
            model_from_dict(d, name="m.json")
        except DataError as exc:
            assert "m.json" in str(exc) and "\n" not in str(exc), path
        else:
            accepted.append(path)
    assert not accepted, accepted[:5]

"""Compensation through the blocks' hooks (issue 12): model files written before the
hooks give the same corrections bit for bit (their uncertainties to round-off), and a machine_thermal model corrects new
points at other scale temperatures with calibrated uncertainties."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cmm_core.export import compensate, load_model, model_from_dict, model_to_dict, read_points
from cmm_core.io import SCALE_TEMP_COLUMNS, DataError
from cmm_core.machine import kinematics as kin
from cmm_core.model import fit, simulate

LEGACY = Path(__file__).resolve().parent / "corpus" / "legacy_models"
NUMERIC = ["xc_mm", "yc_mm", "zc_mm", "ex_um", "ey_um", "ez_um"]
U = ["u_x_um", "u_y_um", "u_z_um"]


@pytest.mark.parametrize("tag", ["kinematic", "backlash", "machine_thermal"])
def test_model_files_written_before_the_hooks_give_the_same_corrections(tag):
    """``make_legacy_models.py`` wrote these files and their corrections with the release
    before compensation looped over the blocks (backlash then a special case of
    compensate; a machine_thermal model kept only its kinematic coefficients): loaded
    now, they correct the same points to the same doubles (the machine_thermal one
    without scale temperatures, as then). The uncertainties agree to 1e-9 relative: they
    are now the norms of ``J L`` (``V = L Lᵀ``, issue 25) where they were
    ``diag(J V Jᵀ)`` summed term by term, the same number rounded differently (the
    covariance's condition number, about 3e3, times the double precision, 1e-16, is far
    below it)."""
    model = load_model(LEGACY / f"model_{tag}.json")
    out = compensate(model, read_points(LEGACY / "points.csv"))
    want = pd.read_csv(LEGACY / f"corrected_{tag}.csv", keep_default_na=False)
    np.testing.assert_array_equal(out[NUMERIC].to_numpy(float), want[NUMERIC].to_numpy(float))
    np.testing.assert_allclose(out[U].to_numpy(float), want[U].to_numpy(float), rtol=1e-9,
                               atol=0)
    assert list(out["extrapolated"]) == list(want["extrapolated"])
    approach = [f"approach_{a}" for a in "xyz"]
    assert (tag == "backlash") == (set(approach) <= set(out.columns))
    if tag == "backlash":
        np.testing.assert_array_equal(out[approach].to_numpy(), want[approach].to_numpy())


THERMAL = {"x_cte_per_K": 4e-6, "y_cte_per_K": -3e-6, "z_cte_per_K": 2e-6}
"""Scale expansion errors of a few ppm/K (as in test_blocks); the simulator's default
scale temperatures run from 20.5 to 23.7 °C over the six thesis positions."""
EXACT_PLATE = {"form_um": 2.0, "certificate_u_um": 0.0}


def _thermal_fit(seed, spec="kinematic21,machine_thermal", **extra):
    sim = simulate({"seed": seed, "plate": EXACT_PLATE,
                    "effects": {"machine_thermal": THERMAL, **extra.pop("effects", {})},
                    **extra})
    r = fit(sim.dataset, spec)
    assert not r.unidentifiable
    return sim, model_from_dict(model_to_dict(r), name="m.json")  # the saved form


def _new_points(model, rng, m):
    """m points inside the fitted region, random probes, scale temperatures 17-25 °C
    (outside the fitted 20.5-23.7 °C: the expansion is linear in them)."""
    lo, hi = (np.asarray(v) for v in model.summary["region_mm"])
    x = rng.uniform(lo, hi, (m, 3))
    probes = rng.choice(sorted(model.probes_mm), m)
    p = np.array([model.probes_mm[q] for q in probes])
    temps = rng.uniform(17.0, 25.0, (m, 3))
    pts = pd.DataFrame({"probe": probes, **dict(zip(("x_mm", "y_mm", "z_mm"), (x + p).T,
                                                    strict=True)),
                        **dict(zip(SCALE_TEMP_COLUMNS, temps.T, strict=True))})
    return pts, x, p, temps


def test_machine_thermal_correction_agrees_with_the_truth_within_its_uncertainty():
    """Simulate with the scales' expansion and varying scale temperatures, fit with
    machine_thermal, correct new noiseless points at other scale temperatures: the
    corrected points against the simulator's truth (its kinematic model and the scale
    term α_a (T_a − 20 °C) u_a, ``Problem.targets``) give z-scores whose RMS over 12
    seeds × 40 points × 3 components is 1. The z of one fit are correlated through its
    coefficients: the mean z² of one fit scatters with sd 0.6 (40 seeds: mean 0.94 ±
    0.10), so the RMS over 12 fits has a standard error of about 0.09; asserted in
    [0.75, 1.3], about 3 of them. Without the thermal part the same points miss the truth
    by several u."""
    zs, z_plain = [], []
    for seed in range(12):
        sim, model = _thermal_fit(40 + seed)
        pts, x, p, temps = _new_points(model, np.random.default_rng(seed), 40)
        coef = np.array([sim.truth[lab] for lab in model.terms.labels])
        cte = np.array([sim.truth[f"machine_thermal.cte_{a}"] for a in "xyz"])
        true_mm = kin.model_point(model.terms, coef, x, p) + cte * 1e-6 * (temps - 20) * x
        out = compensate(model, pts)
        cor = out[["xc_mm", "yc_mm", "zc_mm"]].to_numpy()
        u = out[["u_x_um", "u_y_um", "u_z_um"]].to_numpy()
        zs.append(((cor - true_mm) * 1e3 / u).ravel())
        plain = replace(model, parts={})  # the same model without its scale term
        cor0 = compensate(plain, pts)[["xc_mm", "yc_mm", "zc_mm"]].to_numpy()
        z_plain.append(((cor0 - true_mm) * 1e3 / u).ravel())
    z = np.concatenate(zs)
    assert 0.75 <= np.sqrt(np.mean(z**2)) <= 1.3 and np.abs(z).max() < 5, (
        np.sqrt(np.mean(z**2)), np.abs(z).max())
    assert np.sqrt(np.mean(np.concatenate(z_plain) ** 2)) > 3


def _perturbed(model, theta):
    """The model with its kinematic coefficients and parts' values replaced by the joint
    vector ``theta`` (kinematic first, then the parts in the file's order)."""
    n = model.terms.n
    parts, k = {}, n
    for tok, part in model.parts.items():
        parts[tok] = replace(part, values=theta[k:k + len(part.values)])
        k += len(part.values)
    return replace(model, coef=theta[:n], parts=parts)


def test_uncertainty_propagation_matches_a_finite_difference_jacobian():
    """Backlash and machine_thermal together (the joint covariance nests: kinematic,
    backlash spans, scale coefficients): the propagated u equals sqrt(diag(J V Jᵀ)) with
    J the central-difference derivative of the corrected points with respect to every
    coefficient, span and expansion coefficient (steps of 1e-3 of each parameter's
    unit; the correction is linear in the spans and coefficients and nearly so in the
    kinematic ones, so 1e-6 relative), and the corrections of points whose direction is
    unknown carry the span's extra variance on top."""
    sim, model = _thermal_fit(7, "kinematic21,backlash,machine_thermal", order="random",
                              effects={"backlash": {"x_um": 2.0, "y_um": -1.0}})
    assert list(model.parts) == ["backlash", "machine_thermal"]
    V = model.joint_cov
    theta = np.r_[model.coef, *(p.values for p in model.parts.values())]
    assert V.shape == (len(theta),) * 2
    pts, *_ = _new_points(model, np.random.default_rng(3), 25)
    out = compensate(model, pts)
    h = 1e-3
    J = np.empty((len(pts) * 3, len(theta)))
    for i in range(len(theta)):
        step = np.eye(len(theta))[i] * h
        hi = compensate(_perturbed(model, theta + step), pts)
        lo = compensate(_perturbed(model, theta - step), pts)
        J[:, i] = ((hi[["ex_um", "ey_um", "ez_um"]].to_numpy()
                    - lo[["ex_um", "ey_um", "ez_um"]].to_numpy()) / (2 * h)).ravel()
    u_fd2 = np.einsum("ik,kl,il->i", J, V, J).reshape(-1, 3)
    d = out[["approach_x", "approach_y", "approach_z"]].to_numpy()
    u_fd2 += (d == 0) * (model.parts["backlash"].values / 2) ** 2
    u = out[["u_x_um", "u_y_um", "u_z_um"]].to_numpy()
    np.testing.assert_allclose(u, np.sqrt(u_fd2), rtol=1e-6)
    assert (d[0] == 0).all() and (d[1:] != 0).any()


def test_machine_thermal_points_without_scale_temperatures_are_refused(tmp_path):
    """The model corrects each fitted axis at the point's scale temperature: points
    without the columns (or with a temperature in kelvin) are refused naming the file
    and the columns, never corrected as if at 20 °C."""
    _, model = _thermal_fit(5)
    pts, *_ = _new_points(model, np.random.default_rng(1), 3)
    path = tmp_path / "pts.csv"
    pts.drop(columns=["temp_y_C", "temp_z_C"]).to_csv(path, index=False)
    with pytest.raises(DataError, match=r"pts.csv.*temp_y_C, temp_z_C.*temp_x_C, temp_y_C, "
                                        r"temp_z_C") as exc:
        compensate(model, read_points(path))
    assert exc.value.column == "temp_y_C"
    pts.assign(temp_z_C=[20.0, 293.15, 20.0]).to_csv(path, index=False)
    with pytest.raises(DataError, match="kelvin") as exc:
        compensate(model, read_points(path))
    assert exc.value.row == 3 and exc.value.column == "temp_z_C"


def test_the_model_file_section_is_checked():
    """The machine_thermal section round-trips; a section without the spec, unknown keys
    or axes, a missing coefficient and a covariance of the wrong size are refused naming
    the key."""
    _, model = _thermal_fit(5)
    d = model_to_dict(model)
    assert set(d["machine_thermal"]) == {"axes", "cte_ppm_per_K", "cov_joint"}
    assert d["machine_thermal"]["axes"] == ["x", "y", "z"]
    back = model_from_dict(json.loads(json.dumps(d)))
    np.testing.assert_array_equal(back.joint_cov, model.joint_cov)
    # without the section: a file of the release before it, corrected as then
    old = model_from_dict({k: v for k, v in d.items() if k != "machine_thermal"})
    assert old.parts == {} and old.spec == model.spec
    with pytest.raises(DataError, match="spec has no machine_thermal"):
        model_from_dict({**d, "spec": "kinematic21"})
    sec = d["machine_thermal"]
    for bad, column in (({**sec, "extra": 1}, "machine_thermal"),
                        ({**sec, "axes": ["x", "w", "z"]}, "machine_thermal.axes"),
                        ({**sec, "cte_ppm_per_K": [1.0, None, 2.0]},
                         "machine_thermal.cte_ppm_per_K"),
                        ({**sec, "cov_joint": sec["cov_joint"][1:]},
                         "machine_thermal.cov_joint")):
        with pytest.raises(DataError) as exc:
            model_from_dict({**d, "machine_thermal": bad}, name="m.json")
        assert exc.value.column == column and "m.json" in str(exc.value)

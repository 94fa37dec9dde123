"""Effect blocks: the protocol every effect implements, and a new effect added as one
block (machine scale thermal expansion) working in simulation, fit and diagnosis."""

import numpy as np
import pytest
import scenarios as sc

from cmm_core.diagnosis import diagnose
from cmm_core.io import DataError
from cmm_core.model import (
    PHYSICAL,
    blocks,
    catalogue_entry,
    fit,
    parse_spec,
    simulate,
    weighted_residual,
)

MACHINE = {"x_cte_per_K": 5e-6, "y_cte_per_K": -4e-6, "z_cte_per_K": 3e-6}
"""Expansion coefficients (errors) of a few ppm/K: steel scales (11.5 ppm/K) compensated
with a nominal coefficient off by a third, within 1-2 K of 20 °C."""


@pytest.mark.parametrize("cls", [b for b in blocks.REGISTRY if b.token])
def test_every_physical_block_is_in_the_catalogue_with_its_text(cls):
    """A block's token is a catalogue effect, parsed in specs, with what it is, what it
    needs and what separates it (the block's own entry)."""
    assert cls.token in PHYSICAL
    assert cls.token in parse_spec(f"kinematic21,{cls.token}").effects
    e = catalogue_entry(cls.token)
    assert e is cls.entry and e.needs and e.separate_by and e.confused_with


@pytest.mark.parametrize("layout", list(sc.LAYOUTS))
def test_machine_thermal_is_recovered_within_3u(layout):
    """Scale expansion of each axis with its scale's temperature (recorded in temp_x_C
    ... columns): simulate then fit recovers every coefficient within 3 u, χ²/dof is
    consistent with noise, and the diagnosis of a kinematic21 baseline names it."""
    sim = sc.simulated(layout, 11, effects={"machine_thermal": MACHINE})
    assert {"temp_x_C", "temp_y_C", "temp_z_C"} <= set(sim.dataset.meas.columns)
    r = fit(sim.dataset, "kinematic21,machine_thermal")
    lab, v, u = r.block("machine_thermal")
    truth = np.array([sim.truth[k] for k in lab])
    assert len(lab) == 3 and np.all(np.abs(v - truth) < 3 * u), (v, truth, u)
    assert not r.fails_chi2_test
    d = diagnose(sim.dataset, "kinematic21")
    assert d.verdict == "machine_thermal", [(c.effect, c.p_value) for c in d.candidates[:3]]


def test_machine_thermal_needs_varying_scale_temperatures():
    """Without the columns, or with constant scale temperatures (then the expansion is the
    linear positioning error), the diagnosis skips it and says why."""
    plain = sc.simulated("pitch80_3pos", 3)
    d = diagnose(plain.dataset, "kinematic21")
    assert "temp_x_C" in d.skipped["machine_thermal"]
    const = sc.simulated("pitch80_3pos", 3, effects={"machine_thermal": {
        "x_cte_per_K": 1e-6, "temp_C": {p: [21.0, 21.0] for p in sc.LAYOUTS["pitch80_3pos"][
            "positions"]}}})
    d = diagnose(const.dataset, "kinematic21")
    assert "never change" in d.skipped["machine_thermal"]


def test_simulator_refuses_an_unknown_machine_thermal_key():
    with pytest.raises(DataError, match="machine_thermal"):
        simulate({"effects": {"machine_thermal": {"x_cte": 1e-6}}})


@pytest.mark.parametrize("plate,rows", [("prior", 7), ("free", 13), ("fixed", 5000)])
def test_blocked_normal_equations_equal_the_sparse_jacobians(plate, rows):
    """JᵀJ and Jᵀr accumulated over blocks of observations (never forming J) equal those
    of the full sparse Jacobian of ``Problem.residual`` plus the plate prior's rows, with
    every block in the model and block boundaries inside placements; 1e-10 of the size of
    the summed terms (summation order only)."""
    sim = simulate({"seed": 5, "order": "serpentine",
                    "effects": {"plate_sag": {"uu": -2}, "drift": {"sd_um_per_h": 2},
                                "plate_thermal": {}, "probe_offset": {"sd_um": 1},
                                "backlash": {"x_um": 1.0},
                                "machine_thermal": {"x_cte_per_K": 2e-6}}})
    spec = ("kinematic21,plate_thermal,plate_sag,probe_offset,drift,backlash,"
            "machine_thermal")
    r = fit(sim.dataset, spec, plate=plate, max_iter=3)
    prob, st = r.problem, r.state
    ne = prob.normal_equations(st, 0.5, rows=rows)
    _, rvec, J = weighted_residual(prob, st, 0.5, True)
    J = J.toarray()
    scale = np.abs(J.T @ J).max()
    np.testing.assert_allclose(ne.N, J.T @ J, rtol=0, atol=1e-10 * scale)
    # near the solution g is a sum of cancelling terms: compare against their size
    np.testing.assert_allclose(ne.g, J.T @ rvec, rtol=0,
                               atol=1e-10 * (np.abs(J).T @ np.abs(rvec)).max())
    assert ne.rows == rvec.size and ne.cost == pytest.approx(rvec @ rvec, rel=1e-12)


def test_scores_with_and_without_the_shared_cache_agree():
    """The diagnosis scores every candidate from one evaluation of the model with all of
    them added (``ScoreCache``); each candidate scored on its own gives the same Δχ²,
    added rank and uncertainties (1e-8 relative: rounding of two summation orders)."""
    from cmm_core.diagnosis import ScoreCache, score

    sim = sc.simulated("pitch100_4pos", 21, order="serpentine",
                       effects={"plate_sag": {"uu": -1.5}})
    base = fit(sim.dataset, "kinematic21")
    tokens = ["plate_sag", "probe_offset", "drift", "backlash", "dyz:3", "rxx:3"]
    cache = ScoreCache(base, tokens)
    for tok in tokens:
        a, b = score(base, tok, cache), score(base, tok)
        assert a[0] == pytest.approx(b[0], rel=1e-8, abs=1e-6), tok
        assert a[1] == b[1], tok
        for lab, (unit, u) in a[4].items():
            assert b[4][lab][0] == unit and u == pytest.approx(b[4][lab][1], rel=1e-8), lab

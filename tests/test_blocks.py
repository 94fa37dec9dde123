"""Effect blocks: the protocol every effect implements, and a new effect added as one
block (machine scale thermal expansion) working in simulation, fit and diagnosis."""

import numpy as np
import pytest
import scenarios as sc

from cmm_core import blocks
from cmm_core.diagnose import diagnose
from cmm_core.effects import PHYSICAL, catalogue_entry, parse_spec
from cmm_core.fit import fit
from cmm_core.io import DataError
from cmm_core.simulate import simulate

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

"""The simulator configuration's per-effect checks, each made by its block
(``Block.check_sim``): positions and probes the setup lacks, malformed vectors and
temperatures are refused naming the key, with the messages of before the move."""

import re

import pytest

from cmm_core.io import DataError
from cmm_core.model import simulate


@pytest.mark.parametrize("effects, column, message", [
    ({"probe_offset": {"9": [1, 0, 0]}}, "effects.probe_offset.9",
     "probe '9' is not in the setup (known: '1, 2, 3, 4, 5, 6')."),
    ({"probe_offset": {"1": [1, 0]}}, "effects.probe_offset.1",
     "expected 3 finite numbers (µm or µm/h), found [1, 0]."),
    ({"drift": {"BP11": [0, 0, 1]}}, "effects.drift.BP11",
     "position 'BP11' is not in the setup (known: 'BP111, BP112, BP211, BP212, BP311, "
     "BP312'); did you mean 'BP311'?"),
    ({"drift": {"BP111": [0, 0, "x"]}}, "effects.drift.BP111",
     "expected 3 finite numbers (µm or µm/h), found [0, 0, 'x']."),
    ({"plate_thermal": {"temp_C": [20, 21]}}, "effects.plate_thermal.temp_C",
     "expected an object position: [start, finish] in °C, found [20, 21]."),
    ({"plate_thermal": {"temp_C": {"BP999": [20, 21]}}}, "effects.plate_thermal.temp_C.BP999",
     "position 'BP999' is not in the setup"),
    ({"plate_thermal": {"temp_C": {"BP111": [20]}}}, "effects.plate_thermal.temp_C.BP111",
     "expected [start, finish] in °C, found [20]."),
    ({"plate_thermal": {"temp_C": {"BP111": [293.15, 293.4]}}},
     "effects.plate_thermal.temp_C.BP111", "temperature 293.15 is in kelvin"),
])
def test_messages_of_the_effects_are_unchanged(effects, column, message):
    """Each message as the simulator config wrote it before the blocks made the checks."""
    with pytest.raises(DataError) as exc:
        simulate({"effects": effects}, name="c.json")
    assert exc.value.column == column and message in str(exc.value)
    assert "c.json" in str(exc.value)


@pytest.mark.parametrize("temps, column, needle", [
    ([21, 22], "effects.machine_thermal.temp_C", "expected an object position"),
    ({"BP999": [21, 22]}, "effects.machine_thermal.temp_C.BP999", "not in the setup"),
    ({"BP111": "warm"}, "effects.machine_thermal.temp_C.BP111", "[start, finish] in °C"),
    ({"BP111": [294.0, 295.0]}, "effects.machine_thermal.temp_C.BP111", "kelvin"),
])
def test_machine_thermal_scale_temperatures_are_checked_like_the_plates(temps, column,
                                                                       needle):
    """The scale temperatures were not checked at all (a list or an unknown position was
    silently replaced by the defaults, a string ended in a ValueError, kelvin simulated a
    274 K expansion); the block checks them as plate_thermal checks its own."""
    with pytest.raises(DataError, match=re.escape(needle)) as exc:
        simulate({"effects": {"machine_thermal": {"x_cte_per_K": 1e-6, "temp_C": temps}}},
                  name="c.json")
    assert exc.value.column == column

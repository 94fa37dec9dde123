"""One effect = one module (issue 23): the planner, the simulator panel, the compensation
tables and the columns new points need all read the block registry."""

import numpy as np
import pytest

from cmm_core.export import comp_tables
from cmm_core.model import (
    BY_TOKEN,
    REGISTRY,
    Block,
    SimulatorEffect,
    correction_columns,
    parse_spec,
    simulate,
    simulator_effects,
)
from cmm_core.plan import PHYSICAL_CHECKS, detect

PHYSICAL_BLOCKS = [b for b in REGISTRY if b.token]

HOOKS = ("wanted", "needs", "columns", "probe_stage", "plate_stage", "reading_stage",
         "jacobian", "constraints", "update", "report", "draw", "check_sim",
         "detection_shapes", "injection", "compensation", "part_to_file", "part_from_file",
         "correct", "correction_columns")


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_is_declared_with_a_docstring_on_the_base_class(hook):
    """Callers never need ``hasattr``: each hook has a documented default."""
    assert callable(getattr(Block, hook)) and getattr(Block, hook).__doc__, hook


def test_default_update_and_report_change_nothing():
    b = Block(None)
    state = object()
    assert b.update(state) is state
    v = np.arange(3.0)
    assert b.report(state, v) is None and (v == np.arange(3.0)).all()


@pytest.mark.parametrize("cls", PHYSICAL_BLOCKS, ids=lambda c: c.token)
def test_every_physical_block_injects_what_its_simulator_draws(cls):
    """The planner's injection (``detect.injection``) hides the effect through the block's
    own simulator keys: drawing them back gives the values injected."""
    sim = simulate({"seed": 1, "effects": {cls.token: next(
        e for e in simulator_effects() if e.token == cls.token).config()}})
    truth = {k: v for k, v in sim.truth.items() if k.startswith(cls.token) or (
        cls.token in ("drift", "probe_offset") and ("drift" in k or k.startswith("probe")))}
    if cls.token == "drift":
        truth = {k: v for k, v in truth.items() if ".drift_" in k}
    if cls.token == "probe_offset":
        truth = {k: v for k, v in truth.items() if k.startswith("probe")}
    body = cls.injection(truth)
    assert isinstance(body, dict), cls.token
    again = simulate({"seed": 1, "effects": {cls.token: body}})
    for k, v in truth.items():
        assert again.truth[k] == pytest.approx(v, rel=1e-9, abs=1e-12), k


def test_simulator_effects_are_the_blocks_with_a_panel_entry():
    effs = simulator_effects()
    assert all(isinstance(e, SimulatorEffect) for e in effs)
    assert [e.token for e in effs] == [t for t, b in BY_TOKEN.items() if b.sim_label]
    for e in effs:
        lo_hi = BY_TOKEN[e.token].sim_ranges
        for p in e.params:
            assert p.low <= p.default <= p.high and p.unit and p.label
            if p.key in lo_hi:  # the inputs stay inside what the simulator accepts
                lo, hi = lo_hi[p.key]
                assert lo <= p.low * p.scale and p.high * p.scale <= hi, (e.token, p.key)
        simulate({"seed": 0, "effects": {e.token: e.config()}})  # accepted as drawn


@pytest.mark.parametrize("cls", REGISTRY, ids=lambda c: c.__name__)
def test_a_blocks_class_constants_are_read_only(cls):
    """A class constant is one object for the class and every subclass that does not set
    its own (RUF012): the simulator's ranges and fixed keys cannot be changed through one
    block."""
    for name in ("sim_ranges", "sim_fixed"):
        with pytest.raises(TypeError):
            getattr(cls, name)["new key"] = 0.0


def test_correction_columns_come_from_the_blocks():
    assert correction_columns("kinematic21") == ()
    assert correction_columns("kinematic21,backlash") == ("time_min",)
    assert correction_columns(parse_spec("kinematic21,machine_thermal,backlash")) == (
        "time_min", "temp_x_C", "temp_y_C", "temp_z_C")
    assert correction_columns(["plate", "rotation", "machine_thermal"]) == (
        "temp_x_C", "temp_y_C", "temp_z_C")
    assert correction_columns([BY_TOKEN["backlash"]]) == ("time_min",)
    assert correction_columns("kinematic21,bridge_twist,drift") == ()


def test_a_fit_and_a_saved_model_need_the_fitted_axes_columns_only():
    from cmm_core.export import model_from_dict, model_to_dict
    from cmm_core.model import fit

    sim = simulate({"seed": 2, "effects": {"machine_thermal": {"x_cte_per_K": 2e-6}}})
    r = fit(sim.dataset, "kinematic21,machine_thermal")
    assert correction_columns(r.problem.blocks) == ("temp_x_C", "temp_y_C", "temp_z_C")
    m = model_from_dict(model_to_dict(r))
    assert correction_columns(m.parts) == ("temp_x_C",)


def test_planner_and_tables_read_the_registry():
    assert set(PHYSICAL_CHECKS) == {b.token for b in PHYSICAL_BLOCKS if b.physical_check}
    assert {"plate_sag", "plate_thermal", "probe_offset", "drift", "backlash",
            "bridge_twist"} <= set(PHYSICAL_CHECKS)
    assert comp_tables._EXTRA_UNITS == {"backlash": "um", "machine_thermal": "1e-6/K",
                                        "bridge_twist": "urad", "column_bend": "um"}
    spec = parse_spec("kinematic21")
    for b in PHYSICAL_BLOCKS:
        labels = [f"{b.token}.a", f"{b.token}.b"]
        assert detect._shapes(b.token, labels, spec, ["P1", "P2"], ["A", "B"]) == \
            b.detection_shapes(labels, ["P1", "P2"], ["A", "B"])

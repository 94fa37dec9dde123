"""The Data page's simulator panel: a virtual CMM with known errors measuring the thesis
placements (any machine layout, hidden effects from the effect registry), loaded as the
dataset with its truth kept for comparison (``model.simulate``, ``analysis.simulated_sources``)."""

from __future__ import annotations

import io

import numpy as np
import streamlit as st

from cmm_core import analysis as A
from cmm_core.machine import DEFAULT_LAYOUT, LAYOUTS
from cmm_core.model import (
    simulate,
    simulate_laser,
    simulate_step_gauge,
    simulator_effects,
    thesis_machine_setup,
    write_laser,
    write_step_gauge,
)
from pages.ui import calls, state

LAYOUT_NAMES = {  # docs/layouts.md, in words
    "moving_bridge_fxyz": "Moving bridge, bridge along x (thesis machine)",
    "moving_bridge_fyxz": "Moving bridge, bridge along y",
    "fixed_bridge_xfyz": "Fixed bridge, table moving in x",
    "fixed_bridge_yfxz": "Fixed bridge, table moving in y",
    "gantry_fxyz": "Gantry, beam along x",
    "gantry_fyxz": "Gantry, beam along y",
    "horizontal_arm_fxzy": "Horizontal arm, column along x, arm in y",
    "horizontal_arm_fyzx": "Horizontal arm, column along y, arm in x",
}

SIMULATED_ORIGIN = {"kind": "simulated",
                    "setup_source": "the simulation's setup (thesis placements)",
                    "certificate_source": "the simulation's certificate"}
"""How the sidebar states where a simulation's setup and certificate come from."""


def _simulated_instruments(sim, seed: int) -> list:
    """A laser positioning run along x and a step gauge along a diagonal of the volume,
    measured on the simulation's true machine, as (kind, file name, text) triples."""

    rng = np.asarray(sim.dataset.setup.range_mm, float)
    laser = simulate_laser(sim, "x", [0.0, 0.1 * rng[1], 0.1 * rng[2]],
                               np.linspace(0.0, rng[0], 25), u_um=0.2, seed=seed + 1,
                               run="x_positioning", source="simulated_laser_x.csv")
    start, end = 0.1 * rng, np.array([0.9, 0.85, 0.6]) * rng
    n = int(np.linalg.norm(end - start) // 100)
    sg = simulate_step_gauge(sim, start, end, np.arange(1, n + 1) * 100.0, u_um=0.3,
                                 seed=seed + 2, source="simulated_step_gauge.csv")
    out = []
    for kind, item, write in (("laser", laser, write_laser),
                              ("step_gauge", sg, write_step_gauge)):
        text = io.StringIO()
        write(item, text)
        out.append((kind, item.source, text.getvalue()))
    return out


def simulate_section() -> None:
    """The simulator's form and its Simulate button."""
    st.write("A virtual CMM with known errors measuring the thesis placements: choose the "
             "noise, the plate form, hidden effects and the measurement order; the truth is "
             "kept for comparison.")
    c1, c2, c3, c4 = st.columns(4)
    seed = c1.number_input("Seed", 0, 10_000, 0, key="sim_seed")
    noise = c2.number_input("Noise σ (µm)", 0.0, 10.0, 0.5, 0.1, key="sim_noise")
    rnd_um = c3.number_input("Translational errors (µm, 1σ)", 0.0, 50.0, 1.0, key="sim_rum")
    rnd_urad = c4.number_input("Rotational errors (µrad, 1σ)", 0.0, 50.0, 1.0, key="sim_rurad")
    c1, c2, c3, c4 = st.columns(4)
    form = c1.number_input("Plate form (µm, 1σ)", 0.0, 20.0, 2.0, key="sim_form")
    order = c2.selectbox("Measurement order", ["row", "serpentine", "random"], key="sim_order")
    korder = c3.selectbox("Polynomial order of the true errors", [1, 2, 3, 4, 5], index=1,
                          key="sim_korder")
    interleave = c4.checkbox("Probes interleaved", key="sim_interleave")
    c1, c2 = st.columns([2, 2])
    layout = c1.selectbox("Machine layout", list(LAYOUTS), key="sim_layout",
                          format_func=lambda k: f"{LAYOUT_NAMES.get(k, k)} ({k})",
                          help="How the carriages are stacked and which one moves the table "
                               "(docs/layouts.md). The thesis placements are measured on it.")
    sim_inst = c2.checkbox("Also simulate a laser run along x and a step gauge",
                           key="sim_instruments",
                           help="Measured on the same true machine (laser u 0.2 µm, step "
                                "gauge u 0.3 µm) and fitted jointly with the plate: the "
                                "Kinematic model page then shows how much they lower each "
                                "coefficient's uncertainty.")
    st.markdown("**Hidden effects**")
    # one checkbox per effect block of the registry (cmm_core.model.simulator_effects):
    # a new effect appears here with its block, nothing to add to the page
    eff = {}
    cols = st.columns(4)
    for k, e in enumerate(simulator_effects()):
        col = cols[k % 4]
        if col.checkbox(e.label, key=f"sim_{e.token}", help=e.help or None):
            eff[e.token] = e.config({p.key: col.number_input(
                p.label, p.low, p.high, p.default, p.step, key=f"sim_{e.token}_{p.key}")
                for p in e.params})
    kin_cfg = {"order": int(korder), "random_um": float(rnd_um),
               "random_urad": float(rnd_urad)}
    p1, p2, p3, _p4 = st.columns(4)
    if p1.checkbox("Periodic X scale error", key="sim_periodic",
                   help="A sine wave along X (lead screw, rack): not in the default model, "
                        "so the diagnosis has to find it and its period. The 133 mm ball "
                        "pitch resolves no period under about 330 mm (2.5 pitches)."):
        per = int(p2.number_input("period (mm)", 20, 1200, 400, key="sim_per_mm"))
        amp = float(p3.number_input("amplitude (µm)", 0.0, 20.0, 1.0, key="sim_per_um"))
        kin_cfg.update(spec=f"kinematic21,periodic_x:{per}",
                       coefficients={f"dxx[sin{per}]": amp, f"dxx[cos{per}]": 0.0})
    if st.button("Simulate", key="simulate", type="primary"):
        cfg = {"seed": int(seed), "noise_um": float(noise), "order": order,
               "probes_interleaved": bool(interleave),
               "plate": {"form_um": float(form)},
               "kinematic": kin_cfg,
               "effects": eff}
        if layout != DEFAULT_LAYOUT:
            setup = thesis_machine_setup()
            setup["machine"]["layout"] = layout
            cfg["setup"] = setup
        sim = calls.safe(simulate, cfg, what="Simulation")
        inst = [] if sim is None or not sim_inst else calls.safe(
            _simulated_instruments, sim, int(seed), what="Simulating the instruments")
        if sim is not None:
            sources = A.simulated_sources(sim.dataset, f"simulated (seed {int(seed)})" + (
                "" if layout == DEFAULT_LAYOUT else f", {layout}"))
            ok = None if inst is None else calls.safe(
                state.set_dataset, sources, SIMULATED_ORIGIN, what="Loading the simulation")
            if ok is not None:
                state.set_instruments(inst)
                if inst:  # the simulation brings its own: "instrument files removed" misleads
                    st.session_state["reset_note"] = [
                        n for n in st.session_state.get("reset_note", [])
                        if "instrument file" not in n]
                st.session_state["sim_truth"] = {"key": A.sources_key(sources),
                                                 "truth": sim.truth, "config": cfg}
                state.loaded("Simulated dataset loaded" + (
                    " with a laser run and a step gauge fitted jointly" if inst else "")
                    + ". The true parameters are on the Kinematic model page.")

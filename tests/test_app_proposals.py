"""AppTest interaction tests of "measure next" (issue 29) in the app: the Diagnose page's
proposals beside the rivals of its verdict, their one-click simulation, and the hand-over
of a proposal to the Plan page as a plan file (no browser).

The case: the 80 mm layout of ``tests/scenarios.py`` with a high-order rotation of the X
carriage about Z (``rxz:4``, 3 µrad) hidden from a baseline without squareness
(``kinematic21,-sxy``), seed 7: the diagnosis names one of squareness ``sxy`` and
``rxz:4`` with the other as its alias (docs/proposals.md; the pair
``tests/test_proposals.py`` checks in the core). Which of the two it names depends on the
last digits of the files (ΔBIC -114 against -112), so either is accepted.
"""

import json
import sys
from pathlib import Path

import pytest

pytest.importorskip("streamlit")
from streamlit.testing.v1 import AppTest  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from scenarios import simulated  # noqa: E402

from cmm_core import analysis as A  # noqa: E402
from cmm_core.diagnosis import diagnose  # noqa: E402
from cmm_core.plan import read_plan  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
APP = str(ROOT / "app.py")
TIMEOUT = 120
BASE = "kinematic21,-sxy"
RIVALS = ("sxy", "rxz:4")


def _ok(at):
    assert not at.exception, [e.message for e in at.exception]
    assert not at.error, [e.value for e in at.error]


@pytest.fixture(scope="module")
def alias_files() -> A.DataSources:
    """The alias case as the Data page's simulator loads a simulation (its three files)."""
    sim = simulated("pitch80_3pos", 7, noise_um=0.5,
                    kinematic={"spec": "kinematic21,rxz:4", "coefficients": {"rxz[4]": 3.0}})
    return A.simulated_sources(sim.dataset, "simulated alias case (rxz:4 hidden, 80 mm plate)")


def _diagnosis_run(files: A.DataSources, spec: str | None = None) -> AppTest:
    """The app on ``files`` (with the baseline ``spec``, default the app's), the Diagnose
    page's diagnosis run."""
    at = AppTest.from_file(APP, default_timeout=TIMEOUT)
    at.session_state["sources"] = files
    at.session_state["ds_key"] = A.sources_key(files)
    if spec is not None:
        at.session_state["spec"] = spec
    at.run()
    at.switch_page("pages/diagnose.py")
    at.run()
    _ok(at)
    at.button(key="run_diagnosis").click()
    at.run()
    _ok(at)
    return at


def _next_shown(at: AppTest) -> AppTest:
    """``at`` with "Measure next" open."""
    at.session_state["w_diag_next"] = True
    at.run()
    _ok(at)
    return at


def _diagnosed(files: A.DataSources) -> AppTest:
    """The app on the alias case, the Diagnose page's diagnosis run, "Measure next" open."""
    at = _diagnosis_run(files, BASE)
    # one headline: the pair named as a set (issue 41), as the core words it
    named = [m.value for m in at.success if m.value.startswith("**Most likely missing")]
    assert len(named) == 1 and ("(sxy)" in named[0] or "(rxz:4)" in named[0]), named
    assert "squareness XY or X carriage yaw" in named[0] or (
        "X carriage yaw (about Z), order 4 or squareness XY" in named[0]), named
    # the section computes only while it is open (as the page's tabs)
    assert not any(b.key and b.key.startswith("next_sim_") for b in at.button)
    return _next_shown(at)


def test_the_page_shows_the_cores_headline(alias_files):
    """The Diagnose page draws the core's headline (``Diagnosis.headline``) as it is: one
    success message, title, text and action equal to the core's diagnosis of the same
    choices (the pair named as a set, no ``nan``)."""
    at = _diagnosed(alias_files)
    d = diagnose(A.load_sources(alias_files), BASE)
    h = d.headline()
    assert h.verdict == "named" and set(h.alias_of) & set(RIVALS) and "nan" not in h.text
    shown = [m.value for m in at.success]
    assert shown == [f"**{h.title}**\n\n{h.text}\n\nNext: {h.action}"]
    assert h.text in shown[0]


def _top_name(at) -> str:
    return next(b.key for b in at.button if b.key and b.key.startswith("next_sim_"))[
        len("next_sim_"):]


def test_diagnose_page_shows_proposals_beside_the_rivals_and_simulates_one(alias_files):
    at = _diagnosed(alias_files)
    pair = at.selectbox(key="w_next_pair")
    a, b = pair.value
    assert {a, b} == set(RIVALS)  # the verdict and its alias, the verdict first
    texts = [m.value for m in at.markdown]
    # the current data leave the pair open; the top proposals say what they would decide
    now = next(t for t in texts if t.startswith(f"The current data decide **{a}**"))
    assert "% power" in now
    outcomes = [t for t in texts if t.startswith("**1.** With ")]
    assert len(outcomes) == 1
    assert f"{a} and {b} differ by Δχ² ≈" in outcomes[0]
    assert "decided with" in outcomes[0] and "% power in" in outcomes[0]
    sims = [b for b in at.button if b.key and b.key.startswith("next_sim_")]
    assert len(sims) == 3  # NEXT_TOP proposals, each with its own buttons
    assert len([b for b in at.button if b.key and b.key.startswith("next_plan_")]) == 3
    name = _top_name(at)
    # one click: the proposal simulated with each rival as the truth, appended, diagnosed
    at.button(key=f"next_sim_{name}").click()
    at.run()
    _ok(at)
    said = next(m.value for m in at.markdown if m.value.startswith("Simulated (seed 0):"))
    assert "with **sxy** as the truth" in said and "with **rxz:4** as the truth" in said
    # the top proposal decides the pair with power near 1 on this case (docs/proposals.md:
    # 98 % of 50 seeds name the truth with it appended): both rivals separate here
    assert said.count("**separated**") == 2, said
    assert any("The rivals separate" in s.value for s in at.success)


def test_a_proposal_handed_to_the_plan_page_is_the_plan(alias_files):
    at = _diagnosed(alias_files)
    name = _top_name(at)
    at.button(key=f"next_plan_{name}").click()
    at.run()
    _ok(at)
    # the Plan page opens on the proposal as its plan
    assert at.session_state["w_plan_sample"].startswith(f"measure next: {name}")
    assert any(i.value.startswith("The plan is the measurement proposed on the Diagnose page")
               for i in at.info)
    text = at.session_state["w_plan_text"]
    doc = json.loads(text)
    assert doc["name"] == f"measure next: {name}"
    assert doc["model"]["spec"] == BASE
    # a plan file the command line's `plan` reads: the current placements, and with it
    plan = read_plan(doc, name="proposal")
    assert [p.name for p in plan.strategies][0] == "current data"
    assert plan.strategies[1].time_min > plan.strategies[0].time_min
    # both strategies evaluated on the page, side by side
    table = next(d.value for d in at.dataframe if "strategy" in d.value.columns)
    assert list(table["strategy"]) == [p.name for p in plan.strategies]
    # downloadable as the plan file shown
    dl = [d for d in at.get("download_button") if d.proto.label.startswith("Download the plan")]
    assert len(dl) == 1
    # another sample is still one choice away, and the proposal stays among the choices
    opts = at.selectbox(key="w_plan_sample").options
    assert opts[0].startswith("measure next:") and len(opts) == 3
    # (AppTest reruns the page it was last switched to: the script's switch is the app's)
    at.switch_page("pages/plan.py")
    at.selectbox(key="w_plan_sample").set_value(opts[1])
    at.run()
    _ok(at)
    assert json.loads(at.session_state["w_plan_text"])["name"] != doc["name"]


def test_instrument_runs_are_proposed_and_simulated_on_request(alias_files):
    """With "Also instrument runs" the instrument candidates are scored beside the plate's:
    on this case a step gauge or laser run along X (offset in Y: its Abbe arm sees rxz)
    decides the pair in less machine time than a new placement, so it is among the top
    proposals; its "Simulate it" runs the instrument on each rival's machine and it
    separates them, its "Use as the plan" is off (a plan file holds no instrument)."""
    at = _diagnosed(alias_files)
    before = {b.key for b in at.button if b.key and b.key.startswith("next_sim_")}
    assert not any(k.startswith(("next_sim_laser", "next_sim_step_gauge")) for k in before)
    at.checkbox(key="w_next_instruments").check()
    at.run()
    _ok(at)
    tools = [b.key[len("next_sim_"):] for b in at.button
             if b.key and b.key.startswith(("next_sim_laser_x", "next_sim_step_gauge_x"))]
    assert tools, [b.key for b in at.button if b.key]
    name = tools[0]
    assert at.button(key=f"next_plan_{name}").disabled
    assert not at.button(key=f"next_sim_{name}").disabled
    at.button(key=f"next_sim_{name}").click()
    at.run()
    _ok(at)
    said = next(m.value for m in at.markdown if m.value.startswith("Simulated (seed 0):"))
    assert said.count("**separated**") == 2, said


def test_a_repeat_proposal_handed_to_the_plan_page_is_a_plan_with_the_repeat():
    """Drift hidden with styli in blocks (seed 1000 of the bench's drift case: the
    diagnosis names drift with the probe offset as its alias): the pair's top proposal is
    a stylus repeated at the end of its placement; "Use as the plan" opens the Plan page on a plan whose second strategy holds
    the repeat (``repeat_at_end``) and is evaluated beside the current data, with more
    probings and minutes."""
    sim = simulated("pitch80_3pos", 1000, noise_um=0.5,
                    effects={"drift": {"sd_um_per_h": 1.0}})
    files = A.simulated_sources(sim.dataset, "simulated drift case")
    at = _next_shown(_diagnosis_run(files))
    assert tuple(at.selectbox(key="w_next_pair").value) == ("drift", "probe_offset")
    name = _top_name(at)
    assert name.startswith("repeat_"), name
    at.button(key=f"next_plan_{name}").click()
    at.run()
    _ok(at)
    doc = json.loads(at.session_state["w_plan_text"])
    now, more = read_plan(doc, name="proposal").strategies
    assert now.repeat_at_end == {} and more.repeat_at_end
    assert now.probes_of == more.probes_of
    table = next(d.value for d in at.dataframe if "strategy" in d.value.columns)
    assert list(table["strategy"]) == [now.name, more.name]
    assert table["probings"].iloc[1] > table["probings"].iloc[0]
    assert table["time (min)"].iloc[1] > table["time (min)"].iloc[0]


def _next_open(files: A.DataSources) -> AppTest:
    """The app on ``files`` with the baseline without squareness, the Diagnose page's
    diagnosis run and "Measure next" open (whatever the verdict)."""
    return _next_shown(_diagnosis_run(files, BASE))


def _next_texts(at) -> list:
    """The texts of "Measure next" in page order (markdown and alerts, no captions):
    ``(kind, text)``, from the element tree of its expander."""
    box = next(e for e in at.expander if e.label.startswith("Measure next"))
    out = []

    def walk(node):
        for child in getattr(node, "children", {}).values():
            kind = getattr(child, "type", "")
            if kind in ("markdown", "warning", "success", "info", "error"):
                out.append((kind, child.value))
            walk(child)

    walk(box)
    return out


def _weak(seed: int, size_urad: float) -> A.DataSources:
    """The 80 mm layout with ``rxz:4`` of ``size_urad`` hidden, as the Data page's
    simulator loads it."""
    sim = simulated("pitch80_3pos", seed, noise_um=0.5,
                    kinematic={"spec": "kinematic21,rxz:4",
                               "coefficients": {"rxz[4]": size_urad}})
    return A.simulated_sources(sim.dataset, f"rxz:4 = {size_urad:g} µrad hidden, seed {seed}")


def test_when_nothing_decides_the_page_says_so_before_the_proposals():
    """A weak yaw (1 µrad, seed 4): the diagnosis names nothing but leaves sxy and rxz:4
    open; no default candidate reaches 80 % power (the best about 70 %). The section's
    first text is the core's conclusion, "No candidate decides between ...", with the
    instrument runs named as not searched; no outcome reads "decided with"."""
    at = _next_open(_weak(4, 1.0))
    assert set(at.selectbox(key="w_next_pair").value) == set(RIVALS)
    texts = _next_texts(at)
    kind, first = texts[0]
    assert kind == "warning" and first.startswith("No candidate decides between "), texts
    assert "Best next measurement" not in first
    assert "Not searched, and might decide: instrument runs" in first
    outcomes = [t for k, t in texts if t.startswith("**1.** ")]
    assert len(outcomes) == 1 and "too little to decide" in outcomes[0], outcomes
    assert not any("decided with" in t for _, t in texts)
    # the proposals are still listed beneath it, each with its buttons
    assert len([b for b in at.button if b.key and b.key.startswith("next_sim_")]) == 3


def test_an_instrument_run_decides_when_instruments_are_included():
    """A yaw of 1.5 µrad (seed 7): the diagnosis names sxy with rxz:4 as its alias. With
    "Also instrument runs" a step gauge along X (its offset in Y an Abbe arm for rxz)
    comes first and decides the pair by itself, in less machine time than the plate
    moved; no "nothing decides" warning; it cannot be a plan file, and simulated on each
    rival's machine it separates them."""
    at = _next_open(_weak(7, 1.5))
    assert set(at.selectbox(key="w_next_pair").value) == set(RIVALS)
    assert not any(b.key.startswith("next_sim_step_gauge") for b in at.button if b.key)
    at.checkbox(key="w_next_instruments").check()
    at.run()
    _ok(at)
    texts = _next_texts(at)
    assert not any(t.startswith("No candidate decides") for _, t in texts), texts
    name = _top_name(at)
    assert name == "step_gauge_x", [b.key for b in at.button if b.key]
    first = next(t for _, t in texts if t.startswith("**1.** "))
    assert "step gauge" in first and "decided with" in first, first
    assert at.button(key=f"next_plan_{name}").disabled
    at.button(key=f"next_sim_{name}").click()
    at.run()
    _ok(at)
    said = next(m.value for m in at.markdown if m.value.startswith("Simulated (seed 0):"))
    assert said.count("**separated**") == 2, said

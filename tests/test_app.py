"""AppTest smoke and interaction tests of the Streamlit app (no browser)."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("streamlit")
import scenarios as sc  # noqa: E402
from conftest import svg_figures  # noqa: E402
from conftest import uploader as _uploader  # noqa: E402
from streamlit.testing.v1 import AppTest  # noqa: E402

from cmm_core import analysis as A  # noqa: E402
from cmm_core.diagnosis import diagnose  # noqa: E402
from cmm_core.export import downloads as export
from cmm_core.model import simulate  # noqa: E402
from pages.ui.session import session_record

ROOT = Path(__file__).resolve().parents[1]
APP = str(ROOT / "app.py")
THESIS = ROOT / "sample_data" / "thesis"
PAGES = {
    "pages/data.py": "Data",
    "pages/kinematic.py": "Kinematic model",
    "pages/gaussian_process.py": "Gaussian process",
    "pages/diagnose.py": "Compare and diagnose",
    "pages/uncertainty.py": "Uncertainty",
    "pages/export.py": "Compensate and export",
    "pages/plan.py": "Plan",
    "pages/check.py": "Interim check",
}
TIMEOUT = 60


def _new():
    at = AppTest.from_file(APP, default_timeout=TIMEOUT)
    at.run()
    return at


def _figures(at) -> list:
    """The keys of the figures on the page: Plotly charts and the static SVG figures
    (``widgets.svg_figure``: the ``data-figure`` of the SVG's div), in page order within each
    kind."""
    return [c.key for c in at.get("plotly_chart")] + list(svg_figures(at))


def _sim_tab(at):
    """Open the Data page's simulator tab: its widgets are drawn only while it is open
    (lazy tabs, issue 27)."""
    at.session_state["data_tab"] = "Simulate a virtual CMM"
    at.run()
    return at


def _parameters(at):
    """The Kinematic page's parameter table, its tab opened (drawn only while open)."""
    at.session_state["w_kin_tab"] = "Parameters"
    at.run()
    return _frame(at, "parameter")


def _ok(at):
    assert not at.exception, [e.message for e in at.exception]
    assert not at.error, [e.value for e in at.error]


def _frame(at, column):
    """The first dataframe on the page having ``column`` (dataframe keys are not exposed)."""
    for d in at.dataframe:
        if column in d.value.columns:
            return d.value
    raise KeyError(column)


def _restore(at, content) -> None:
    """Upload ``content`` (text or bytes) as a project file on the Data page and press
    Restore project."""
    data = content.encode() if isinstance(content, str) else content
    _uploader(at, "Project file").set_value(("p.json", data, "application/json"))
    at.run()
    at.button(key="restore_project").click()
    at.run()


def _sidebar_text(at) -> str:
    return " ".join([m.value for m in at.sidebar.markdown] + [c.value for c in at.sidebar.caption])


def _sidebar_rms(at) -> float:
    m = {x.label: x.value for x in at.sidebar.metric}
    return float(m["RMS (µm)"])


def _sidebar_birge(at) -> float:
    """The Birge ratio the sidebar's χ² warning states ("too small by ×B")."""
    w = next(w.value for w in at.sidebar.warning if "χ² test" in w.value)
    return float(re.search(r"×([0-9.]+)", w).group(1).rstrip("."))


@pytest.fixture(scope="module")
def app():
    return _new()


def test_first_run_shows_the_thesis_data_and_a_fitted_model(app):
    _ok(app)
    assert any("thesis tables" in m.value for m in app.sidebar.markdown)
    assert any("kinematic21" in m.value for m in app.sidebar.markdown)
    assert 4.0 < _sidebar_rms(app) < 6.0  # outliers included until the user excludes them
    labels = [c.label for c in app.checkbox]
    assert any("BP312 probe 6 ball 16" in lab for lab in labels)
    assert any("BP112 probe 2 ball 7" in lab for lab in labels)


def test_data_page_first_screen_has_no_data_grid_and_a_static_validation_table(app):
    """Issue 27: a table on the Data page's first screen made the browser load the data
    grid's and Arrow's scripts (some 1.3 MB) before the page was drawn; the validation table
    is markdown now, one row per position and probe of the thesis data (6 positions, one
    stylus each, 25 balls: thesis chapter 6), and no st.dataframe is on the first screen."""
    _ok(app)
    assert len(app.dataframe) == 0
    table = next(m.value for m in app.markdown if m.value.startswith("| position"))
    rows = table.splitlines()[2:]
    assert len(rows) == 6
    assert all(r.split("|")[3].strip() == "25" for r in rows)  # balls per position
    assert {r.split("|")[1].strip() for r in rows} == {
        "BP111", "BP112", "BP211", "BP212", "BP311", "BP312"}


def test_static_table_escapes_markdown_and_marks_missing_values():
    """A position or file name is shown as written (markdown's special characters escaped),
    a missing value as "—", floats to one decimal, numbers right-aligned."""
    import pandas as pd

    from pages.ui.widgets import static_table_markdown

    df = pd.DataFrame({"position": ["A*|b$", None], "balls": [25, 24],
                       "span_x_mm": [1023.456, float("nan")]})
    assert static_table_markdown(df).splitlines() == [
        "| position | balls | span\\_x\\_mm |",
        "|:---|---:|---:|",
        "| A\\*\\|b\\$ | 25 | 1023.5 |",
        "| — | 24 | — |"]


@pytest.mark.parametrize(("text", "markdown"), [
    ("- dxx", "\\- dxx"), ("+sxy, dxx", "\\+sxy, dxx"), ("1. x", "1\\. x"), ("12) y", "12\\) y"),
    ("A&B", "A\\&B"), ("3.5", "3.5"), ("BP111.csv", "BP111.csv"), ("x-1", "x-1")])
def test_markdown_escape_starts_no_list_and_keeps_entities_as_text(text, markdown):
    """A spec drawn at a line's start ("- dxx" removes dxx) or a name like "1. x" starts no
    list, "&copy;" stays that text; what needs no escape is left as written."""
    from pages.ui.widgets import md_escape

    assert md_escape(text) == markdown


@pytest.mark.parametrize("page", list(PAGES))
def test_every_page_renders_without_error(app, page):
    app.switch_page(page)
    app.run()
    _ok(app)
    assert any(PAGES[page] in t.value for t in app.title)
    assert [x.label for x in app.sidebar.metric] == ["RMS (µm)", "χ²/dof"]


def test_kinematic_page_elements_and_order_change():
    at = _new()
    at.switch_page("pages/kinematic.py")
    at.run()
    _ok(at)
    # lazy tabs (issue 27): only the open tab's figure is built and sent; the 2-D figures
    # as static SVG (no Plotly in the browser) unless "Interactive plots" is on
    assert _figures(at) == ["fig_errfun"] and not at.get("plotly_chart")
    for tab, key in (("Deviation plots", "fig_deviation"), ("Residuals", "fig_resid"),
                     ("Error functions", "fig_errfun")):
        at.session_state["w_kin_tab"] = tab
        at.run()
        assert _figures(at) == [key], tab
    at.sidebar.toggle(key="interactive_plots").set_value(True).run()
    assert [c.key for c in at.get("plotly_chart")] == ["fig_errfun"]
    at.sidebar.toggle(key="interactive_plots").set_value(False).run()
    pf = _parameters(at)
    # thesis data scatter ~10 σ (outliers included here): Birge-scaled u shown beside u,
    # scaled by the Birge ratio the χ² test reports (sidebar)
    birge = _sidebar_birge(at)
    assert birge > 5
    # ... its noise part: the certificate's propagated part is not scaled, so a u grows by
    # the full ratio where the certificate hardly matters and by less elsewhere
    ratio = (pf["u, Birge-scaled"] / pf["u"]).dropna().to_numpy()
    assert (ratio > 1).all() and (ratio <= birge * 1.01).all()
    assert ratio.max() == pytest.approx(birge, rel=0.01)
    assert at.slider(key="w_magnification").value == 2000.0
    rms2 = _sidebar_rms(at)
    at.selectbox(key="w_order").set_value(3)
    at.run()
    _ok(at)
    assert any("order 3" in m.value for m in at.sidebar.markdown)
    assert _sidebar_rms(at) < rms2  # more freedom, smaller residuals
    at.slider(key="w_magnification").set_value(5000.0)
    at.run()
    _ok(at)
    # the order survives a page switch
    at.switch_page("pages/diagnose.py")
    at.run()
    at.switch_page("pages/kinematic.py")
    at.run()
    assert at.selectbox(key="w_order").value == 3


def test_adopting_the_observed_scatter_scales_every_uncertainty():
    """The Birge button sets σ to σ × the Birge ratio of the χ² test: the fit is the same
    (uniform weights), so χ²/dof falls by its square and the probing-noise part of every u
    grows by the ratio (with the certificate fixed the test counts the certificate's
    uncertainty, so the fit's own χ²/dof need not become exactly 1; and the certificate's
    part of u, which the new σ does not touch, makes a u grow by less: by the full ratio
    where the certificate hardly matters, never by more)."""
    at = _new()
    at.switch_page("pages/kinematic.py")
    at.run()
    before = _parameters(at).set_index("parameter")
    chi2_before = float({m.label: m.value for m in at.metric}["χ²/dof"])
    birge = _sidebar_birge(at)
    at.button(key="adopt_scatter").click()
    at.run()
    _ok(at)
    after = _parameters(at).set_index("parameter")
    assert float({m.label: m.value for m in at.metric}["χ²/dof"]) == pytest.approx(
        chi2_before / birge**2, rel=0.01, abs=0.01)
    ratio = (after["u"] / before["u"]).dropna().to_numpy()
    assert (ratio > 1).all() and (ratio <= birge * 1.01).all()
    assert ratio.max() == pytest.approx(birge, rel=0.01)


def test_bad_model_spec_is_a_message_not_a_traceback():
    at = _new()
    at.switch_page("pages/kinematic.py")
    at.run()
    at.text_input(key="w_spec").set_value("kinematic21,warp_drive")
    at.run()
    assert not at.exception
    assert any("unknown model token" in e.value for e in at.error)


def test_excluding_outliers_lowers_the_rms():
    at = _new()
    before = _sidebar_rms(at)
    at.button(key="exclude_all").click()
    at.run()
    _ok(at)
    after = _sidebar_rms(at)
    assert after < before - 1.0
    assert all(c.value for c in at.checkbox if c.label.startswith("Exclude "))
    # one checkbox back: that observation returns to the fit
    box = next(c for c in at.checkbox if "ball 16" in c.label)
    box.uncheck()
    at.run()
    assert after < _sidebar_rms(at)


def test_diagnosis_add_an_effect_rms_falls_and_history_records_it():
    at = _new()
    at.switch_page("pages/diagnose.py")
    at.run()
    # the thesis outliers are flagged but still in: the page says so and offers to exclude
    assert any("still in the fit" in w.value for w in at.warning)
    at.button(key="diag_exclude_outliers").click()
    at.run()
    _ok(at)
    assert len(at.session_state["exclusions"]) == 3
    assert not any(b.key == "diag_exclude_outliers" for b in at.button)
    before = _sidebar_rms(at)
    at.button(key="run_diagnosis").click()
    at.run()
    _ok(at)
    table = _frame(at, "delta_bic")
    assert len(table) > 5
    best = str(table.iloc[0]["effect"])
    assert best == "plate_sag"  # docs/thesis-data.md: the bowl of the horizontal plates
    # the signature plot is open for the named effect only (issue 27)
    sig = {t.key: t.value for t in at.toggle if t.key.startswith("w_sig_")}
    assert [v for k, v in sig.items() if k.endswith("_plate_sag")] == [True]
    assert not any(v for k, v in sig.items() if not k.endswith("_plate_sag"))
    at.button(key=f"add_{best}").click()
    at.run()
    _ok(at)
    assert best in at.session_state["spec"]
    assert _sidebar_rms(at) < before
    # the exclusion is a step of the history (issue 41), each step fitted with the
    # exclusions it was made with: the blunders' step lowers the RMS by itself
    hist = _frame(at, "change")
    assert list(hist["change"]) == ["baseline", "exclude 3 flagged outliers", best]
    assert hist.iloc[1]["rms_um"] < hist.iloc[0]["rms_um"]
    assert hist.iloc[2]["rms_um"] < hist.iloc[1]["rms_um"]
    assert hist.iloc[2]["rms_um"] == pytest.approx(_sidebar_rms(at), abs=1e-3)
    # undone step by step: the effect, then the exclusion
    at.button(key="undo_step").click().run()
    assert at.session_state["spec"] == "kinematic21"
    assert len(at.session_state["exclusions"]) == 3
    at.button(key="undo_step").click().run()
    assert not at.exception  # the diagnosis now says "flagged outliers first" again
    assert at.session_state["exclusions"] == [] and len(_frame(at, "change")) == 1
    assert any("Flagged outlier(s) first" in e.value for e in at.error)


def test_a_blunder_verdict_is_one_headline_with_one_exclude_button():
    """Issue 41: a 40 µm blunder that holds the misfit (100 mm plate, four placements):
    the page draws the core's headline (outliers first) and one "Exclude the flagged
    outliers" button for that condition, not the pending-outlier warning beside it too;
    the button excludes them and the next diagnosis names no blunder."""
    ds = simulate(sc.layout_config("pitch100_4pos", seed=12)).dataset
    delta = np.zeros((len(ds.meas), 3))
    delta[17, 1] = 40e-3
    files = A.simulated_sources(sc.perturb(ds, delta), "simulated blunder")
    h = diagnose(A.load_sources(files), "kinematic21").headline()
    assert h.verdict == "flagged_outliers"
    at = AppTest.from_file(APP, default_timeout=TIMEOUT)
    at.session_state["sources"] = files
    at.session_state["ds_key"] = A.sources_key(files)
    at.run()
    at.switch_page("pages/diagnose.py")
    at.run()
    # before the diagnosis: the pending outliers' warning and its button
    assert [b.key for b in at.button if b.label == "Exclude the flagged outliers"] == [
        "diag_exclude_outliers"]
    at.button(key="run_diagnosis").click()
    at.run()
    assert not at.exception, [e.message for e in at.exception]
    assert [e.value for e in at.error] == [f"**{h.title}**\n\n{h.text}\n\nNext: {h.action}"]
    # (the sidebar's status line still counts them: no message with a button)
    assert not any("still in the fit" in w.value for w in at.main.warning)
    assert [b.key for b in at.button if b.label == "Exclude the flagged outliers"] == [
        "diag_exclude_blunders"]
    at.button(key="diag_exclude_blunders").click()
    at.run()
    _ok(at)
    assert at.session_state["exclusions"]
    assert not any(b.label == "Exclude the flagged outliers" for b in at.button)


def test_remove_an_error_function():
    at = _new()
    at.switch_page("pages/diagnose.py")
    at.run()
    # the spec token with its meaning in words (a newcomer read '-dxx' as jargon)
    assert "-sxy (drop squareness XY)" in at.selectbox(key="w_remove").options
    at.selectbox(key="w_remove").set_value("-sxy")
    at.button(key="remove_effect").click()
    at.run()
    _ok(at)
    assert at.session_state["spec"] == parse("kinematic21,-sxy")


def parse(spec):
    from cmm_core.model import parse_spec

    return parse_spec(spec).to_string()


def test_upload_long_form_csv_and_a_malformed_one():
    at = _new()
    # long form built from the thesis tables (probe column named explicitly)
    rows = ["position,probe,ball,x_mm,y_mm,z_mm"]
    probes = {"BP111": "1", "BP112": "2", "BP211": "3", "BP212": "4", "BP311": "5",
              "BP312": "6"}
    for pos, q in probes.items():
        for line in (THESIS / f"{pos}.csv").read_text().splitlines()[1:]:
            rows.append(f"{pos},{q},{line}")
    _uploader(at, "Measurement CSV").set_value(
        [("long.csv", "\n".join(rows).encode(), "text/csv")])
    at.button(key="load_upload").click()
    at.run()
    _ok(at)
    assert any("long.csv" in m.value for m in at.sidebar.markdown)
    # malformed: a unit in a number cell -> a validation row naming file, row and column
    bad = "ball,x_mm,y_mm,z_mm\n1,0,0,0\n2,133.0 mm,0,0\n3,266,0,0\n4,399,0,0\n"
    _uploader(at, "Measurement CSV").set_value([("BP111.csv", bad.encode(), "text/csv")])
    at.button(key="load_upload").click()
    at.run()
    assert not at.exception
    assert any("problem" in e.value for e in at.error)
    probs = _frame(at, "hint")
    assert probs.iloc[0]["file"] == "BP111.csv"
    assert probs.iloc[0]["row"] == 3 and probs.iloc[0]["column"] == "x_mm"
    assert any("long.csv" in m.value for m in at.sidebar.markdown)  # unchanged
    # issue 41: the fields keep the files (a refusal that emptied them lost the good
    # files with the bad), the message names the file to replace, and every problem is
    # shown in full, open, hint included
    assert any("keep your files: replace BP111.csv" in e.value for e in at.error)
    assert [f.name for f in _uploader(at, "Measurement CSV").value] == ["BP111.csv"]
    full = " ".join(m.value for m in at.markdown if m.value.startswith("- "))
    assert "**BP111.csv**, row 3, column x_mm:" in full and probs.iloc[0]["hint"] in full
    good = "ball,x_mm,y_mm,z_mm\n" + "".join(f"{b},{133 * (b - 1)},0,0\n" for b in range(1, 5))
    _uploader(at, "Measurement CSV").set_value([("BP111.csv", good.encode(), "text/csv")])
    at.button(key="load_upload").click()
    at.run()
    _ok(at)


def test_upload_with_its_own_setup_never_borrows_the_thesis_certificate(tmp_path):
    """Acceptance finding: measurements and setup of another plate, no certificate: the
    thesis certificate stood in silently and the fit was 20 times the noise. Now the plate
    is self-calibrated and the load message says so."""
    simulate({"seed": 5}).write(tmp_path)
    at = _new()
    _uploader(at, "Measurement CSV").set_value(
        [("measurements.csv", (tmp_path / "measurements.csv").read_bytes(), "text/csv")])
    _uploader(at, "Setup").set_value(
        [("setup.json", (tmp_path / "setup.json").read_bytes(), "application/json")])
    at.button(key="load_upload").click()
    at.run()
    _ok(at)
    assert any("No certificate" in m.value for m in at.success)
    assert {m.label: m.value for m in at.metric}["Certificate"] == "no"
    assert _sidebar_rms(at) < 1.0  # the simulated 0.5 µm noise, not a wrong plate


def test_the_same_file_uploaded_twice_is_one_problem():
    at = _new()
    data = (THESIS / "BP111.csv").read_bytes()
    _uploader(at, "Measurement CSV").set_value([("BP111.csv", data, "text/csv"),
                                               ("BP111 (1).csv", data, "text/csv")])
    at.button(key="load_upload").click()
    at.run()
    assert not at.exception
    probs = _frame(at, "hint")
    assert len(probs) == 1 and "uploaded twice" in probs.iloc[0]["problem"]


def test_simulate_a_virtual_cmm():
    at = _new()
    _sim_tab(at)
    at.checkbox(key="sim_plate_sag").check()
    at.run()
    at.button(key="simulate").click()
    at.run()
    _ok(at)
    assert any("simulated" in m.value for m in at.sidebar.markdown)
    at.switch_page("pages/kinematic.py")
    at.run()
    _ok(at)
    assert "true (simulation)" in _parameters(at).columns


def test_the_plan_page_keeps_its_plan_after_a_new_dataset():
    """Newcomer walk: loading a dataset resets every widget, the plan's text box too, and
    the Plan page then stopped at "The plan is not valid JSON"; it refills the sample."""
    at = _new()
    at.switch_page("pages/plan.py")
    at.run()
    _ok(at)
    at.switch_page("pages/data.py")
    at.run()
    _sim_tab(at)
    at.button(key="simulate").click()
    at.run()
    at.switch_page("pages/plan.py")
    at.run()
    _ok(at)
    assert at.session_state["w_plan_text"].strip().startswith("{")


def test_without_a_hidden_effect_the_fit_matches_the_truth_within_its_uncertainty():
    """The (value − true)/u column: nothing hidden, so every kinematic parameter's z-score
    is within 4 (about 60 of them: the chance of one beyond 4 is 0.4 %). With a hidden
    effect this column is where the bias shows first."""
    at = _new()
    _sim_tab(at)
    at.button(key="simulate").click()
    at.run()
    at.switch_page("pages/kinematic.py")
    at.run()
    _ok(at)
    table = _parameters(at)
    z = table.loc[table["block"] == "kinematic", "(value − true)/u"].dropna()
    assert len(z) > 20 and (z.abs() < 4).all(), z.abs().max()
    assert 0.7 < float(np.sqrt(np.mean(z**2))) < 1.3  # χ²₆₀/60 in [0.5, 1.7]: > 4 sd wide


def test_simulator_settings_survive_a_visit_to_another_page():
    """Acceptance finding: the hidden-effect boxes reset when the user left the Data page,
    so a second simulation silently carried (or lost) effects."""
    at = _new()
    _sim_tab(at)
    at.selectbox(key="sim_order").set_value("serpentine")
    at.checkbox(key="sim_backlash").check()
    at.run()
    at.number_input(key="sim_backlash_y_um").set_value(2.5)
    at.run()
    at.switch_page("pages/kinematic.py")
    at.run()
    at.switch_page("pages/data.py")
    at.run()
    _ok(at)
    _sim_tab(at)
    assert at.checkbox(key="sim_backlash").value
    assert at.number_input(key="sim_backlash_y_um").value == 2.5
    assert at.selectbox(key="sim_order").value == "serpentine"


def test_hidden_periodic_error_found_added_and_error_falls():
    """The heart of the product on an effect the default model lacks: simulate a 2 µm
    periodic X scale error of 400 mm (the 133 mm pitch resolves nothing under 333 mm),
    diagnose, add the named effect, watch RMS fall. Over the 700 mm the balls span, an
    order-3 X positioning error follows it as well: the two are shown as an undecided pair
    and the polynomial, with its physical story, is named."""
    at = _new()
    _sim_tab(at)
    at.checkbox(key="sim_periodic").check()
    at.run()
    at.number_input(key="sim_per_um").set_value(2.0)
    at.button(key="simulate").click()
    at.run()
    _ok(at)
    at.switch_page("pages/diagnose.py")
    at.run()
    before = _sidebar_rms(at)
    at.button(key="run_diagnosis").click()
    at.run()
    _ok(at)
    top = _frame(at, "delta_bic").iloc[0]
    best = str(top["effect"])
    assert best.startswith("periodic_x:") or "periodic_x:" in str(top["aliases"])
    at.button(key=f"add_{best}").click()
    at.run()
    _ok(at)
    assert _sidebar_rms(at) < 0.6 * before


def test_hidden_backlash_seen_by_direction_named_added_and_error_falls():
    """Backlash of 2 µm, serpentine order: the 'by approach direction' table shows the
    reversal, the diagnosis names backlash, adding it brings the RMS to the noise."""
    at = _new()
    _sim_tab(at)
    at.selectbox(key="sim_order").set_value("serpentine")
    at.checkbox(key="sim_backlash").check()
    at.run()
    for a in "xyz":
        at.number_input(key=f"sim_backlash_{a}_um").set_value(2.0)
    at.button(key="simulate").click()
    at.run()
    at.switch_page("pages/diagnose.py")
    at.run()
    _ok(at)
    split = _frame(at, "reversal_um").set_index("axis")
    assert split.loc["x", "reversal_um"] > 4 * split.loc["x", "u_reversal_um"]
    before = _sidebar_rms(at)
    at.button(key="run_diagnosis").click()
    at.run()
    _ok(at)
    assert str(_frame(at, "delta_bic").iloc[0]["effect"]) == "backlash"
    at.button(key="add_backlash").click()
    at.run()
    _ok(at)
    assert _sidebar_rms(at) < 0.55 < before  # down to the 0.5 µm noise


def test_downloads_present_and_project_roundtrip():
    at = _new()
    at.switch_page("pages/export.py")
    at.run()
    _ok(at)
    keys = {b.key for b in at.get("download_button")}
    assert {"dl_parameters", "dl_residuals", "dl_grid", "dl_report", "dl_project",
            "dl_corrected"} <= keys
    # a project file with a changed model and exclusions restores the session
    text = export.project_to_json(
        dataset_name="restored thesis",
        measurements=[(f"{p}.csv", (THESIS / f"{p}.csv").read_text())
                      for p in ("BP111", "BP112", "BP211", "BP212", "BP311", "BP312")],
        setup=(THESIS / "setup.json").read_text(),
        certificate=("certificate.csv", (THESIS / "certificate.csv").read_text()),
        model={"spec": "kinematic21,plate_sag", "order": 2, "plate": "fixed",
               "sigma_um": 0.5, "positions": None, "probes": None},
        exclusions=[("BP112", "2", 7), ("BP312", "6", 16)],
        history=[{"spec": "kinematic21", "change": "baseline"},
                 {"spec": "kinematic21,plate_sag", "change": "plate_sag"}])
    at.switch_page("pages/data.py")
    at.run()
    _restore(at, text)
    _ok(at)
    assert at.session_state["spec"] == "kinematic21,plate_sag"
    assert len(at.session_state["exclusions"]) == 2
    assert any("restored thesis" in m.value for m in at.sidebar.markdown)
    at.switch_page("pages/diagnose.py")
    at.run()
    _ok(at)
    assert len(_frame(at, "change")) == 2


def _thesis_project_text(exclusions):
    return export.project_to_json(
        dataset_name="restored thesis",
        measurements=[(f"{p}.csv", (THESIS / f"{p}.csv").read_text())
                      for p in ("BP111", "BP112", "BP211", "BP212", "BP311", "BP312")],
        setup=(THESIS / "setup.json").read_text(),
        certificate=("certificate.csv", (THESIS / "certificate.csv").read_text()),
        model={"spec": "kinematic21", "order": 2, "plate": "fixed", "sigma_um": 0.5,
               "positions": None, "probes": None},
        exclusions=exclusions, history=[])


def test_a_project_with_sigma_auto_restores_with_the_estimate():
    """σ "auto" (a record from the command line): the app estimates it from the data with
    the core's estimator, says so, and fits with it."""
    from cmm_core.diagnosis import estimate_sigma
    from cmm_core.io import thesis_dataset

    doc = json.loads(_thesis_project_text([]))
    doc["model"]["sigma_um"] = "auto"
    at = _new()
    _restore(at, json.dumps(doc))
    _ok(at)
    want = estimate_sigma(thesis_dataset(), "kinematic21", plate="fixed").value_um
    assert at.session_state["sigma_um"] == pytest.approx(want, abs=1e-4)
    assert any("σ is 'auto'" in s.value for s in at.success)


def test_project_exclusions_are_checked_and_unflagged_ones_shown():
    """Acceptance finding: an exclusion of a ball the data do not have restored silently,
    and one the detector does not flag could be neither seen nor undone."""
    at = _new()
    _restore(at, _thesis_project_text([("BP999", "1", 3)]))
    assert not at.exception
    assert any("BP999 probe 1 ball 3" in e.value for e in at.error)
    assert any("thesis tables" in m.value for m in at.sidebar.markdown)  # nothing lost
    _restore(at, _thesis_project_text([("BP111", "1", 17)]))
    _ok(at)
    assert any("BP111 probe 1 ball 17" in i.value for i in at.info)
    at.button(key="include_unflagged").click()
    at.run()
    assert at.session_state["exclusions"] == []


def test_bad_project_file_is_a_message():
    at = _new()
    _restore(at, b"{not json")
    assert not at.exception
    assert any("not valid JSON" in e.value for e in at.error)


def test_gaussian_process_fit_and_chapter7_comparison():
    at = _new()
    at.switch_page("pages/gaussian_process.py")
    at.run()
    _ok(at)
    cols = _frame(at, "kin_minus_meas_um").columns
    assert {"kin_z", "thesis_pct_kin"} <= set(cols)
    at.number_input(key="w_gp_restarts").set_value(0)  # fastest: one optimisation each
    at.run()
    at.button(key="fit_gp").click()
    at.run(timeout=300)
    _ok(at)
    hyp = _frame(at, "LOO RMS (µm)")
    assert list(hyp["component"]) == ["x", "y", "z"]
    assert {"gp_minus_meas_um", "gp_loo_z", "thesis_pct_gp", "gp_loo_minus_meas_um"} <= set(
        _frame(at, "gp_loo_z").columns)
    assert "gp_z" not in _frame(at, "gp_loo_z").columns  # no in-sample z
    # the page's leave-one-out RMS of component x is the core's closed-form LOO RMS
    metric = {m.label: m.value for m in at.metric}
    loo_page = float(metric["GP LOO RMS Δ (µm)"])
    assert loo_page == pytest.approx(float(hyp.iloc[0]["LOO RMS (µm)"]), abs=1.5e-3)
    # predicting a ball from the others is harder than refitting it
    assert loo_page > float(metric["GP RMS Δ (µm)"])


def test_gp_probe_input_coverage_and_degenerate_fit_offered():
    """Issue 16: with several styli the GP takes the probe offset as input and shows its
    leave-one-out 95 % coverage per component (thesis data, blunders excluded: within
    95 ± 2 %). Issue 11: over tip coordinates alone the e_y GP collapses (length scale
    0.6 mm against a 133 mm pitch); the page says so and offers the next-best optimum."""
    at = _new()
    at.button(key="exclude_all").click()
    at.run()
    at.switch_page("pages/gaussian_process.py")
    at.run()
    assert at.checkbox(key="w_gp_probe").value is True
    at.button(key="fit_gp").click()
    at.run(timeout=300)
    _ok(at)
    hyp = _frame(at, "LOO 95 % coverage (%)")
    assert all(93.0 <= v <= 97.0 for v in hyp["LOO 95 % coverage (%)"]), hyp
    assert "converged" in set(hyp["status"]) and "degenerate" not in set(hyp["status"])
    assert hyp["noise sd per stylus (µm)"].str.contains("2:").all()
    metric = {m.label: m.value for m in at.metric}
    for c in "xyz":
        assert 93.0 <= float(metric[f"e{c}: LOO 95 % coverage"].rstrip(" %")) <= 97.0
    assert not any("Degenerate" in w.value for w in at.warning)
    at.checkbox(key="w_gp_probe").uncheck()
    at.run(timeout=300)
    _ok(at)
    warn = [w.value for w in at.warning if "Degenerate GP fit" in w.value]
    assert warn and "ey" in warn[0] and "lower bound" in warn[0]
    hyp = _frame(at, "LOO 95 % coverage (%)")
    assert hyp.set_index("component").loc["y", "status"] == "degenerate"
    at.checkbox(key="w_gp_use_alt").check()
    at.run(timeout=300)
    _ok(at)
    hyp = _frame(at, "LOO 95 % coverage (%)").set_index("component")
    assert hyp.loc["y", "status"] == "next-best optimum"
    assert float(hyp.loc["y", "length scale (mm)"]) > 8.0


def test_gp_with_the_kinematic_mean_is_a_different_gp():
    """Found by the browser review: the GP over the kinematic residuals shared the cache
    entry of the zero-mean GP over the measured errors (the values were not part of the
    key), so both showed the same hyperparameters."""
    at = _new()
    at.switch_page("pages/gaussian_process.py")
    at.run()
    at.number_input(key="w_gp_restarts").set_value(0)
    at.run()
    at.button(key="fit_gp").click()
    at.run(timeout=300)
    zero = _frame(at, "LOO RMS (µm)")
    at.radio(key="w_gp_mean").set_value("kinematic")
    at.run(timeout=300)
    _ok(at)
    kin = _frame(at, "LOO RMS (µm)")
    assert not np.allclose(zero["log marginal likelihood"], kin["log marginal likelihood"])


def test_location_0_alone_is_reported_rank_deficient_on_every_page():
    """Issue 2: location 0 alone is reported as rank-deficient, not returned as numbers.
    The fit converges, U1-U3 are a warning rather than a table of "None", the Monte Carlo
    check is not run, and the export page warns that corrections are arbitrary."""
    at = _new()
    at.switch_page("pages/kinematic.py")
    at.run()
    at.multiselect(key="w_positions").set_value(["BP111", "BP112"])
    at.run()
    _ok(at)
    assert any("undetermined combination" in c.value for c in at.sidebar.caption)
    # each combination in plain words (issue 41), the weights for experts apart
    words = " ".join(m.value for m in at.markdown if m.value.startswith("- "))
    assert "cannot be told apart" in words and "·" not in words
    assert "z positions of placements BP111 and BP112" in words, words
    at.switch_page("pages/uncertainty.py")
    at.run()
    _ok(at)
    assert any("U1-U3 are not evaluated" in w.value for w in at.warning)
    assert not any(d.key == "u_table" for d in at.dataframe)
    at.switch_page("pages/export.py")
    at.run()
    _ok(at)
    assert any("not determined" in w.value for w in at.warning)


def test_uncertainty_monte_carlo_budget_and_mpe():
    at = _new()
    at.switch_page("pages/uncertainty.py")
    at.run()
    _ok(at)
    u = _frame(at, "u_x (µm, k = 1)")
    u = u.set_index("quantity")["u_x (µm, k = 1)"]
    # certificate fixed: U1 is not evaluated (left out, the caption says why); U2 < U3
    assert not any(q.startswith("U1") for q in u.index)
    assert 0 < u["U2: CMM error in the evaluated region"] < u[
        "U3: CMM error in the whole working volume"]
    at.button(key="run_mc").click()
    at.run()
    _ok(at)
    ratio = next(m for m in at.metric if m.label.startswith("Monte Carlo u"))
    assert 0.8 < float(ratio.value) < 1.2
    if not any(b.key == "run_budget_mc" for b in at.button):
        pytest.skip("cmm_core.budget not available")
    assert any(m.label == "k" for m in at.metric)
    at.number_input(key="w_b_trials").set_value(50_000)
    at.button(key="run_budget_mc").click()
    at.run()
    _ok(at)
    assert any("Monte Carlo (50000 trials" in x.value for x in at.success)
    table = _frame(at, "decision")
    assert "decision" in table.columns
    # U of the decision is the test's by default (plate certificate + σ), named in the
    # caption; the CMM specification is the alternative (acceptance finding)
    from cmm_core.gum import conformity_uncertainty_um, uncertainty_um

    np.testing.assert_allclose(table["U_um"], conformity_uncertainty_um(table["length_mm"], 0.5))
    assert any("plate certificate" in c.value for c in at.caption)
    assert "fig_mpe" in _figures(at)
    at.radio(key="w_mpe_u").set_value("cmm_spec")
    at.run()
    table = _frame(at, "decision")
    np.testing.assert_allclose(table["U_um"], uncertainty_um(table["length_mm"]))


# ----------------------------------------------------------------- issue 16: a new user's afternoon

def _sim_upload(at, tmp_path, seed, label=""):
    """Upload a simulated dataset's measurements.csv and setup.json, optionally named."""
    from cmm_core.model import simulate

    d = tmp_path / f"case{seed}"
    simulate({"seed": seed}).write(d)
    _uploader(at, "Measurement CSV").set_value(
        [("measurements.csv", (d / "measurements.csv").read_bytes(), "text/csv")])
    _uploader(at, "Setup").set_value(
        [("setup.json", (d / "setup.json").read_bytes(), "application/json")])
    if label:
        next(t for t in at.text_input if t.label.startswith("Dataset name")).input(label)
    at.button(key="load_upload").click()
    at.run()
    _ok(at)


def test_a_new_dataset_starts_from_its_defaults_and_the_sidebar_says_what_was_reset():
    at = _new()
    at.switch_page("pages/kinematic.py")
    at.run()
    at.selectbox(key="w_order").set_value(3)
    at.run()
    at.selectbox(key="w_plate").set_value("free")
    at.run()
    assert any("order 3, plate free" in m.value for m in at.sidebar.markdown)
    at.switch_page("pages/data.py")
    at.run()
    at.button(key="load_thesis").click()
    at.run()
    _ok(at)
    assert at.session_state["order"] == 2 and at.session_state["plate"] == "auto"
    assert any("order 2, plate auto" in m.value for m in at.sidebar.markdown)
    text = _sidebar_text(at)
    assert "settings reset to its defaults" in text
    assert "order 3 → 2" in text and "plate geometry free → auto" in text


def test_uploads_replace_are_named_and_say_which_setup_and_certificate(tmp_path):
    """Two cases both named measurements.csv are told apart; after a load the uploaders
    are empty so the next upload replaces the files; the sidebar says which setup and
    certificate are in use."""
    at = _new()
    assert "thesis setup (sample_data/thesis/setup.json)" in _sidebar_text(at)
    _sim_upload(at, tmp_path, 1)
    name1 = next(m.value for m in at.sidebar.markdown if "Dataset:" in m.value)
    assert "measurements.csv (upload 1)" in name1
    assert "setup.json (uploaded)" in _sidebar_text(at)
    assert "none (plate geometry self-calibrated)" in _sidebar_text(at)
    # the uploaders were replaced by empty ones
    assert not _uploader(at, "Measurement CSV").value
    assert _uploader(at, "Setup").value is None
    _sim_upload(at, tmp_path, 2)
    name2 = next(m.value for m in at.sidebar.markdown if "Dataset:" in m.value)
    assert "measurements.csv (upload 2)" in name2 and name1 != name2
    _sim_upload(at, tmp_path, 3, label="bridge CMM, March")
    assert any("Dataset:** bridge CMM, March" in m.value for m in at.sidebar.markdown)


def test_without_a_setup_the_stand_in_is_named_and_unknown_positions_ask_for_one(tmp_path):
    at = _new()
    _uploader(at, "Measurement CSV").set_value(
        [(f"{p}.csv", (THESIS / f"{p}.csv").read_bytes(), "text/csv") for p in ("BP211",
                                                                               "BP212")])
    at.button(key="load_upload").click()
    at.run()
    _ok(at)
    text = _sidebar_text(at)
    assert "thesis setup (stand-in: no setup uploaded)" in text
    assert "thesis certificate (stand-in: none uploaded)" in text
    # positions the thesis setup does not know: the problem says so and asks for a setup
    from cmm_core.model import simulate

    simulate({"seed": 4}).write(tmp_path)
    long = (tmp_path / "measurements.csv").read_text().replace("BP111,", "H1,")
    _uploader(at, "Measurement CSV").set_value([("m.csv", long.encode(), "text/csv")])
    at.button(key="load_upload").click()
    at.run()
    assert not at.exception
    probs = _frame(at, "hint")
    row = probs[probs["problem"].str.contains("does not know position")].iloc[0]
    assert "H1" in row["problem"] and "upload the setup JSON" in row["hint"]
    assert "docs/formats.md" in row["hint"]


def test_points_and_observations_agree_after_exclusions():
    at = _new()
    at.button(key="exclude_all").click()
    at.run()
    md = next(m.value for m in at.sidebar.markdown if "Dataset:" in m.value)
    assert "150 probed ball centres (3 excluded)" in md
    assert any("147 observations in the fit" in c.value for c in at.sidebar.caption)


def test_sag_is_explained_as_bowl_heights_and_drift_over_row_order():
    at = _new()
    at.switch_page("pages/kinematic.py")
    at.run()
    at.text_input(key="w_spec").input("kinematic21,plate_sag,drift")
    at.run()
    _ok(at)
    pf = _parameters(at)
    assert {"plate_sag.uu", "plate_sag.vv"} <= set(pf["parameter"])
    cap = " ".join(c.value for c in at.caption)
    assert "bowl heights at the plate edge" in cap
    assert "no time_min column" in cap and "row order" in cap


def test_model_spec_is_shown_as_written_and_wraps_at_commas():
    """Issue 16: shorthand was expanded into long lists and long names were cut. The
    user's spec stays as written through an edit on the Diagnose page; the sidebar shows
    it breakable only after commas with the full text (and its expansion) on hover; the
    history table shows each step's model as written."""
    at = _new()
    at.switch_page("pages/kinematic.py")
    at.run()
    at.text_input(key="w_spec").input("translational,squareness")
    at.run()
    _ok(at)
    at.switch_page("pages/diagnose.py")
    at.run()
    at.selectbox(key="w_remove").set_value("-sxy")
    at.button(key="remove_effect").click()
    at.run()
    _ok(at)
    assert at.session_state["spec"] == "translational,squareness,-sxy"
    # the spec as written, wrapping at its commas; its expansion in the help (hover)
    side = next(m for m in at.sidebar.markdown if "Model:" in m.value)
    assert "**Model:** translational, squareness, -sxy  \n" in side.value
    assert "dxx" not in side.value  # not expanded where it is displayed
    from cmm_core.model import parse_spec

    full = parse_spec("translational,squareness,-sxy", default_order=2).to_string()
    assert side.proto.help == f"translational,squareness,-sxy  \n= {full}"
    assert "<" not in side.value and not side.proto.allow_html  # plain markdown (issue 41)
    head = next(m for m in at.markdown if m.value.startswith("Model"))
    assert "translational, squareness, -sxy" in head.value
    assert head.proto.help == side.proto.help
    hist = _frame(at, "change")
    assert list(hist["spec"]) == ["translational, squareness",
                                  "translational, squareness, -sxy"]
    # undoing a step through its opposite token removes it rather than growing the text
    from pages.ui.state import compose_spec

    assert compose_spec("translational,squareness,-sxy", "sxy", 2) == \
        "translational,squareness"
    assert compose_spec("kinematic21", "plate_sag", 2) == "kinematic21,plate_sag"


def test_kinematic_z_on_clean_simulated_data_has_rms_one():
    """Issue 16: the chapter-7 kinematic z divided a residual by √(u² + σ²) (model and
    measurement as if independent), which makes z too small. Divided by the residual's
    own sd σ√(1 − h_ii), the RMS z over the n balls of a component of clean simulated data
    (the simulator's noise is the σ the fit uses) is 1 within the χ² tolerance: n z² is
    about χ²_n-distributed, so mean z² is 1 ± 4√(2/n) at more than 4 sd."""
    at = _new()
    _sim_tab(at)
    at.button(key="simulate").click()
    at.run()
    _ok(at)
    at.switch_page("pages/gaussian_process.py")
    at.run()
    _ok(at)
    assert float(at.session_state["sigma_um"]) == 0.5  # the simulator's noise_um
    for comp in "xyz":
        at.radio(key="w_gp_comp").set_value(comp)
        at.checkbox(key="w_gp_only_pos").uncheck()
        at.run()
        _ok(at)
        table = _frame(at, "kin_z")
        n = len(table)
        assert n > 50
        mean_z2 = float(np.mean(table["kin_z"] ** 2))
        assert abs(mean_z2 - 1) < 4 * np.sqrt(2 / n), (comp, mean_z2, n)
        rms = float({m.label: m.value for m in at.metric}["kin. RMS z"])
        assert rms == pytest.approx(np.sqrt(mean_z2), abs=2e-3)


def test_gp_coverage_outside_the_band_is_explained_on_the_page():
    """Issue 16: when a component's leave-one-out coverage is outside 93-97 %, the page
    says why in a caption driven by the numbers. The six thesis placements are within
    the band (test above); the two vertical placements BP211 and BP212 alone (50 points,
    styli 3 and 4) with a GP over tip coordinates only cover 90 % in e_x. Components
    outside the band carry the caption, those inside do not."""
    at = _new()
    at.switch_page("pages/kinematic.py")
    at.run()
    at.multiselect(key="w_positions").set_value(["BP211", "BP212"])
    at.run()
    _ok(at)
    at.switch_page("pages/gaussian_process.py")
    at.run()
    at.number_input(key="w_gp_restarts").set_value(0)
    at.checkbox(key="w_gp_probe").uncheck()
    at.run()
    at.button(key="fit_gp").click()
    at.run(timeout=300)
    _ok(at)
    hyp = _frame(at, "LOO 95 % coverage (%)").set_index("component")
    captions = [c.value for c in at.caption if c.value.startswith("**Why e")]
    outside = [c for c in "xyz" if not 93.0 <= hyp.loc[c, "LOO 95 % coverage (%)"] <= 97.0]
    assert "x" in outside, hyp  # the case this test is about
    for c in "xyz":
        has = any(cap.startswith(f"**Why e{c} covers") for cap in captions)
        assert has == (c in outside), (c, captions)
    why_x = next(cap for cap in captions if cap.startswith("**Why ex"))
    assert "One noise level is shared by several styli" in why_x
    assert any("outside 95 ± 2 %" in w.value for w in at.warning)


@pytest.mark.parametrize("page", ["pages/kinematic.py", "pages/gaussian_process.py",
                                  "pages/diagnose.py", "pages/uncertainty.py"])
def test_every_page_with_an_uncertainty_says_the_fit_fails_its_chi2_test(page):
    """Issue 16: on the thesis data the fit fails its χ² test; every page that shows an
    uncertainty (bands, u, z-scores, U1-U3) shows the banner with the Birge ratio the
    sidebar states, so no σ-based number is read as trustworthy."""
    at = _new()
    at.switch_page(page)
    at.run()
    _ok(at)
    birge = _sidebar_birge(at)
    banner = [w.value for w in at.main.warning if w.value.startswith(
        "The model fails its χ² test")]
    assert len(banner) == 1, [w.value for w in at.main.warning]
    assert f"×{birge:.2f}" in banner[0]


# --- instruments: laser runs and step gauges fitted with the plate ------------------------

LASER = ROOT / "sample_data" / "instruments" / "laser_x.csv"


@pytest.fixture(scope="module")
def inst_app():
    """One session for the instrument tests (AppTest runs are slow): the thesis data."""
    return _new()


def test_a_bad_instrument_file_is_one_line_and_keeps_the_dataset(inst_app):
    at = inst_app
    lines = LASER.read_text().splitlines()
    lines[2] = lines[2].rsplit(",", 1)[0] + ",0.2 um"  # a unit in a number cell, file row 3
    _uploader(at, "Laser interferometer").set_value(
        [("laser_bad.csv", "\n".join(lines).encode(), "text/csv")])
    at.button(key="add_instruments").click()
    at.run()
    assert not at.exception
    (err,) = [e.value for e in at.error]
    assert "\n" not in err and "laser_bad.csv" in err
    assert "row 3" in err and "column 'u_um'" in err
    assert any("thesis tables" in m.value for m in at.sidebar.markdown)  # nothing lost
    assert not at.session_state["instruments"]


def test_a_laser_upload_shows_its_residuals_and_the_uncertainty_gain(inst_app):
    at = inst_app
    _uploader(at, "Laser interferometer").set_value(
        [("laser_x.csv", LASER.read_bytes(), "text/csv")])
    at.button(key="add_instruments").click()
    at.run()
    _ok(at)
    assert [i[1] for i in at.session_state["instruments"]] == ["laser_x.csv"]
    assert any("laser_x.csv" in c.value for c in at.sidebar.caption)
    at.switch_page("pages/kinematic.py")
    at.run()
    _ok(at)
    summary = _frame(at, "RMS residual/u")
    assert list(summary["file"]) == ["laser_x.csv"] and summary["readings"].iloc[0] == 50
    assert len(_frame(at, "residual (µm)")) == 50
    gain = _frame(at, "gain")
    assert gain["gain"].is_monotonic_decreasing and gain["gain"].iloc[0] > 3
    assert gain["parameter"].iloc[0].startswith("dxx")  # a run along x sees dxx first
    # every fit of the app has it: the diagnosis's baseline is this fit
    at.switch_page("pages/diagnose.py")
    at.run()
    _ok(at)
    # the project file carries the instrument file; restoring it brings it back
    from cmm_core import analysis as A

    state = {k: at.session_state[k] for k in ("sources", "spec", "order", "plate",
                                               "sigma_um", "instruments")}
    text = A.record_to_project_json(session_record(state))
    at.switch_page("pages/data.py")
    at.run()
    # back on the Data page the expander is closed, a line under it names the file
    assert any(c.value == "1 instrument file(s) in every fit: laser_x.csv."
               for c in at.caption)
    at.session_state["w_instruments_open"] = True
    at.run()
    at.button(key="rm_instrument_0").click()
    at.run()
    assert not at.session_state["instruments"]
    _restore(at, text)
    _ok(at)
    assert [i[1] for i in at.session_state["instruments"]] == ["laser_x.csv"]


def test_the_same_instrument_file_twice_is_refused_and_nothing_changes(inst_app):
    """A copy of a file already fitted (other name, same readings) would count its readings
    double: refused in one line naming both, the session's instruments unchanged."""
    at = inst_app
    before = list(at.session_state["instruments"])
    assert [i[1] for i in before] == ["laser_x.csv"]
    _uploader(at, "Laser interferometer").set_value(
        [("laser_copy.csv", LASER.read_bytes(), "text/csv")])
    at.button(key="add_instruments").click()
    at.run()
    assert not at.exception
    (err,) = [e.value for e in at.error]
    assert "\n" not in err and "laser_copy.csv" in err and "laser_x.csv" in err
    assert list(at.session_state["instruments"]) == before


def test_simulated_moving_table_with_instruments_fits_within_its_noise():
    at = _new()
    _sim_tab(at)
    at.selectbox(key="sim_layout").set_value("fixed_bridge_xfyz")
    at.checkbox(key="sim_instruments").check()
    at.run()
    at.button(key="simulate").click()
    at.run()
    _ok(at)
    assert [i[0] for i in at.session_state["instruments"]] == ["laser", "step_gauge"]
    at.switch_page("pages/kinematic.py")
    at.run()
    _ok(at)
    chi2 = float({m.label: m.value for m in at.metric}["χ²/dof"])
    assert 0.75 <= chi2 <= 1.3
    assert set(_frame(at, "RMS residual/u")["kind"]) == {"laser", "step_gauge"}
    assert (_frame(at, "gain")["gain"] > 0.99).all()


def test_placements_drawn_as_three_views_and_in_3d_on_request():
    """Issue 27: the Data page, the app's first screen, draws the placements as three
    orthographic views in plain SVG (no Plotly script on a first load) and the WebGL 3-D
    scene only when asked."""
    at = _new()
    at.switch_page("pages/data.py")
    at.run()
    _ok(at)
    assert not at.get("plotly_chart")
    assert not [m for m in at.markdown if "<svg" in m.value]  # framed, not in markdown
    (svg,) = svg_figures(at).values()
    assert svg.count("<title>BP111, probe") == 3 * 25  # every ball of a placement, 3 views
    at.toggle(key="w_place_3d").set_value(True)
    at.run()
    _ok(at)
    assert [c.key for c in at.get("plotly_chart")] == ["fig_placements"]


def test_placement_views_put_every_ball_where_it_is(rng):
    """The SVG's markers sit at the ball's coordinates: in each view, the marker centres
    are an affine image of the two coordinates with one scale on both axes (px per mm),
    and the y axis points up. Checked on a simulated dataset with random placements."""

    from cmm_core.analysis import placement_views_svg
    from cmm_core.model import simulate

    ds = simulate({"seed": int(rng.integers(1000)), "noise_um": 0.0}).dataset
    svg = placement_views_svg(ds)
    xyz = ds.meas[["mx_mm", "my_mm", "mz_mm"]].to_numpy()
    # open circles (first placement) are centred at cx, cy; open squares (second) are the
    # path M(x - r, y - r) h(2r): centred half a side in
    marks = [(t[6], float(t[7]), t[8], float(t[9]),
              float(t[0] or t[2]) + (float(t[4]) / 2 if t[2] else 0),
              float(t[1] or t[3]) + (float(t[4]) / 2 if t[3] else 0))
             for t in re.findall(r'(?:<circle cx="(-?[\d.]+)" cy="(-?[\d.]+)"|'
                                 r'<path d="M(-?[\d.]+) (-?[\d.]+)h([\d.]+)v[^"]*Z")[^>]*>'
                                 r'<title>([^<]*): ([XYZ]) (-?[\d.]+), ([XYZ]) (-?[\d.]+) mm'
                                 r'</title>', svg)]
    for a, b in (("X", "Y"), ("X", "Z"), ("Y", "Z")):
        pts = np.array([m[1:2] + m[3:] for m in marks if (m[0], m[2]) == (a, b)])
        assert len(pts) == 100  # two placements of 25 balls, two styli each
        fx, fy = np.polyfit(pts[:, 0], pts[:, 2], 1), np.polyfit(pts[:, 1], pts[:, 3], 1)
        assert fx[0] > 0 and fy[0] == pytest.approx(-fx[0], rel=1e-2)  # one scale, y up
        for f, u, v in ((fx, 0, 2), (fy, 1, 3)):  # 0.1 px rounding of the coordinates
            assert np.abs(np.polyval(f, pts[:, u]) - pts[:, v]).max() < 0.2
    assert svg.count("<title>") == 3 * len(xyz) + 3  # every ball in 3 views, 3 volumes


def test_diagnose_page_draws_only_the_open_tabs_figure():
    """Issue 27: the 3-D residual map (WebGL) was drawn in its hidden tab on every visit
    and every rerun (Add, Undo); the tabs are lazy, as on the Kinematic page."""
    at = _new()
    at.switch_page("pages/diagnose.py")
    at.run()
    _ok(at)
    keys = _figures(at)
    assert "diag_resid" in keys and "diag_map" not in keys
    at.session_state["w_diag_tab"] = "Residual map (3D)"
    at.run()
    _ok(at)
    keys = _figures(at)
    assert "diag_map" in keys and "diag_resid" not in keys


def test_a_restored_record_is_fitted_as_the_report_fits_it():
    """Issue 23: a record with σ 'auto', a selection of positions and the outlier rule on,
    restored in the app, gives the fit analysis.run gives it (the CLI's and the report's):
    the same σ, the same exclusions, the same numbers on the Kinematic page."""
    import dataclasses

    from cmm_core import analysis as A

    rec = dataclasses.replace(
        A.read_record(ROOT / "sample_data" / "thesis" / "analysis.json"), sigma_um="auto",
        exclude_outliers=True, exclusions=(), positions=("BP111", "BP112", "BP211", "BP212"),
        spec="kinematic21", history=(("kinematic21", "baseline"),), diagnose=False)
    res = A.run(rec)
    assert res.sigma["auto"] and len(res.exclusions) > len(rec.exclusions)
    at = _new()
    at.switch_page("pages/data.py")
    at.run()
    _restore(at, A.record_to_project_json(rec))
    _ok(at)
    assert at.session_state["sigma_um"] == res.sigma["value_um"]
    assert {tuple(e) for e in at.session_state["exclusions"]} == set(res.exclusions)
    at.switch_page("pages/kinematic.py")
    at.run()
    _ok(at)
    shown = {m.label: m.value for m in at.metric}
    assert shown["RMS residual"] == f"{res.fit.rms_um:.3f} µm"
    assert shown["χ²/dof"] == f"{res.fit.chi2_dof:.2f}"
    assert int(shown["Parameters (rank)"]) == res.fit.rank


def test_an_exclusion_after_a_restored_history_keeps_its_steps_fits():
    """Review of issue 41's history steps: a restored record's steps (written before
    steps had exclusions of their own) keep the fits they had when the outliers are then
    excluded, and ticking one box and unticking it again leaves no step."""
    at = _new()
    at.session_state["history"] = [{"spec": "kinematic21", "change": "baseline"},
                                   {"spec": "kinematic21,plate_sag", "change": "plate_sag"}]
    at.session_state["spec"] = "kinematic21,plate_sag"
    at.switch_page("pages/diagnose.py").run()
    before = list(_frame(at, "change")["rms_um"])
    at.button(key="diag_exclude_outliers").click().run()
    assert not at.exception
    hist = _frame(at, "change")
    assert list(hist["change"]) == ["baseline", "plate_sag", "exclude 3 flagged outliers"]
    assert list(hist["rms_um"])[:2] == before  # fitted as before, with no exclusions
    assert hist.iloc[2]["rms_um"] < before[1]
    # a box ticked and unticked on the Data page: no step
    at.switch_page("pages/data.py").run()
    box = next(c for c in at.checkbox if c.key.startswith("w_ex_"))
    box.set_value(not box.value).run()
    assert at.session_state["history"][-1]["change"] == "exclusions edited by hand"
    box = next(c for c in at.checkbox if c.key == box.key)
    box.set_value(not box.value).run()
    assert not at.exception
    assert [h["change"] for h in at.session_state["history"]] == [
        "baseline", "plate_sag", "exclude 3 flagged outliers"]

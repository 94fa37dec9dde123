"""The Interim check page (issue 28) in AppTest: the sample history's checks and history
render without an error, and the crash is reported."""

import json
import re
from pathlib import Path

import pytest

pytest.importorskip("streamlit")
from conftest import svg_figures  # noqa: E402
from streamlit.testing.v1 import AppTest  # noqa: E402

from cmm_core import analysis as A  # noqa: E402
from cmm_core.export import load_model  # noqa: E402

APP = str(Path(__file__).resolve().parents[1] / "app.py")
SAMPLES = Path(__file__).resolve().parents[1] / "sample_data"
FILES = ("measurements.csv", "setup.json", "certificate.csv")


def _page():
    at = AppTest.from_file(APP, default_timeout=120)
    at.run()
    at.switch_page("pages/check.py")
    at.run()
    return at


def _ok(at):
    assert not at.exception, [e.message for e in at.exception]
    assert not at.error, [e.value for e in at.error]


def test_crash_sample_fails_names_sxy_and_history_shows_it():
    at = _page()
    assert any("Interim check" in t.value for t in at.title)
    _ok(at)  # the default sample: the check after the crash
    assert any("Verdict: changed" in w.value for w in at.warning)
    # the fewest changes first: the squareness alone, with its size (issue 39)
    verdict = next(w.value for w in at.warning if "Verdict: changed" in w.value)
    assert "The fewest changes that explain the new data" in verdict
    assert "the xy squareness (sxy): +" in verdict.split("Parameter by parameter")[0]
    assert any("no longer behaves" in c.value for c in at.caption)
    assert any("sxy" in m.value for m in at.markdown)
    # the diagnosis against the stored model names the crash's squareness
    assert any("names squareness XY (sxy" in m.value for m in at.markdown)
    # the E_n map: every place of the check in one of the three |E_n| classes, the
    # crash's beyond 1.5; 200 observations (4 placements × 25 balls × 2 styli) at 104
    # places of the machine's x, y (both styli on each ball, and balls of different
    # placements over each other): the sample's geometry, whole millimetres apart
    svg = svg_figures(at)["chk_map"]
    counts = [int(n) for n in re.findall(r"\|E_n\|[^<]*?: (\d+)<", svg)]
    assert len(counts) == 3 and counts[2] > 0 and sum(counts) == 104
    # the history tab, drawn only while open: the squareness's change between the last two
    # calibrations, its trend and the error map's change
    at.session_state["chk_tab"] = "History"
    at.run()
    _ok(at)
    assert any("sxy" in m.value and "significant" in m.value for m in at.markdown)
    assert any("The fewest changes that explain each difference" in m.value
               and "2024-03-04 → 2025-03-03: the xy squareness (sxy)" in m.value
               for m in at.markdown)
    assert {c.key for c in at.get("plotly_chart")} >= {"hist_trend", "hist_map"}


def test_quiet_sample_passes_and_bad_mpe_is_one_message():
    at = _page()
    at.selectbox(key="chk_sample").set_value("quiet (2024-06-17, one placement)").run()
    _ok(at)
    # one placement passes but cannot see every combination: partial, never "unchanged"
    assert any("behaves as the stored model predicts" in c.value for c in at.caption)
    assert any("partial" in i.value and "cannot see" in i.value for i in at.info)
    assert not at.success
    at.text_input(key="chk_mpe").set_value("six").run()
    assert not at.exception
    assert [e.value for e in at.error] and "MPE" in at.error[0].value


def test_check_offers_its_results_document(downloads):
    # review 2 #14: the document downloaded is the check shown
    files = downloads
    at = _page()
    _ok(at)
    buttons = at.get("download_button")
    assert [b for b in buttons if "results (JSON)" in b.proto.label]
    # the downloads' one rule: <stored calibration>_<date>_interim_check_results.json
    name = next(n for n in files if n and n.endswith("_interim_check_results.json"))
    assert name.startswith("calibration_2024-03-04_")
    doc = json.loads(files[name])
    ic = doc["interim_check"]
    test = ic["test"]
    shown = next(m.value for m in at.metric if m.label == "χ² / dof")
    assert shown == f"{test['chi2']:.1f} / {test['dof']}"
    assert ic["verdict"] == "changed" and ic["model"] == "calibration_2024-03-04.json"
    assert ic["new_effects"]["named"][0]["effect"] == "sxy"
    # each change with its posterior sd as the standard uncertainty and u_null (its sd
    # if nothing changed) beside it: cov(δ | d) = V − cov(s), so u² + u_null² is the
    # stored model's variance of sxy (to rounding)
    sxy = next(p for p in ic["changes"]["parameters"] if p["name"] == "sxy")
    model = load_model(SAMPLES / "history" / "calibration_2024-03-04.json")
    j = model.terms.labels.index("sxy")
    assert sxy["standard_uncertainty"] ** 2 + sxy["u_null"] ** 2 == pytest.approx(
        model.cov[j, j], rel=1e-9)


def test_mpe_field_refuses_infinity_as_the_cli_does():
    # review 2 #12: the page parsed 'A,D' itself and took inf,600; both now call
    # monitor.parse_mpe
    at = _page()
    at.text_input(key="chk_mpe").set_value("inf,600").run()
    assert not at.exception
    assert [e.value for e in at.error] and "MPE" in at.error[0].value
    assert "finite" in at.error[0].value


def test_an_uploaded_bad_model_is_one_message_naming_the_file():
    # review 2 #12: the page read the model with json.loads ("Expecting value: line 1
    # ..." without the file's name); now as analysis.load_stored_model reads one
    at = _page()
    at.radio(key="chk_src").set_value("Upload files").run()
    at.radio(key="chk_stored").set_value("A model file").run()
    at.file_uploader(key="chk_model").set_value(("stored.json", b"not a model", "application/json"))
    at.selectbox(key="chk_kind").set_value("ball_bar")
    bar = (SAMPLES / "instruments" / "ball_bar.csv").read_bytes()
    at.file_uploader(key="chk_inst").set_value([("ball_bar.csv", bar, "text/csv")])
    at.run()
    assert not at.exception
    errors = [e.value for e in at.error]
    assert len(errors) == 1 and "stored.json" in errors[0], errors
    assert "\n" not in errors[0].strip()


def test_the_check_tab_keeps_its_choices_while_the_history_is_open():
    """Both tabs are drawn only while open or while they hold the user's choices: the
    check's "Upload files" source and a stored model chosen survive a look at the
    History tab."""
    at = _page()
    at.radio(key="chk_src").set_value("Upload files").run()
    at.radio(key="chk_stored").set_value("A model file").run()
    stored = (SAMPLES / "history" / "calibration_2024-03-04.json").read_bytes()
    at.file_uploader(key="chk_model").set_value(("stored.json", stored, "application/json"))
    at.run()
    at.session_state["chk_tab"] = "History"
    at.run()
    _ok(at)
    at.session_state["chk_tab"] = "Interim check"
    at.run()
    _ok(at)
    assert at.radio(key="chk_src").value == "Upload files"
    assert at.radio(key="chk_stored").value == "A model file"
    assert at.file_uploader(key="chk_model").value.name == "stored.json"


def test_the_map_states_En_at_k_2_and_its_legend_counts_the_markers_drawn():
    # E_n as laboratories read it, with its coverage factor beside it everywhere the page
    # shows one; the map's legend: each class's count is the number of its markers drawn
    at = _page()
    _ok(at)
    assert any("Largest |E_n| (k = 2)" in c.value for c in at.caption)
    assert any(m.label == "Largest |E_n (k = 2)|" for m in at.metric)
    svg = svg_figures(at)["chk_map"]
    assert "Normalised errors of the new observations: E_n (k = 2)" in svg
    # legend entries: a marker without a hover title, then "label: count"
    legend = re.findall(r'<circle [^>]*fill="(#[0-9a-f]{6})"[^>]*/>\s*<text[^>]*>([^<]*): '
                        r"(\d+)</text>", svg)
    assert [lab for _, lab, _ in legend] == ["|E_n| ≤ 1 (k = 2)", "1 &lt; |E_n| ≤ 1.5 (k = 2)",
                                             "|E_n| &gt; 1.5 (k = 2)"]
    # the markers drawn: one per place (issue 41: 200 observations had been drawn on 111
    # places, up to five on one spot), each with its hover title listing every
    # observation there
    drawn = re.findall(r'<circle [^>]*fill="(#[0-9a-f]{6})"[^>]*><title>([^<]*)</title>', svg)
    places = {re.match(r"x (-?\d+), y (-?\d+) mm", t).groups() for _, t in drawn}
    assert len(drawn) == len(places) < 200
    assert sum(t.count(" stylus ") for _, t in drawn) == 200 and "nan" not in svg.lower()
    colours = [c for c, _ in drawn]
    assert {c: int(n) for c, _, n in legend} == {c: colours.count(c) for c, _, _ in legend}
    assert any("200 observations" in c.value for c in at.caption)
    # each marker's colour is the class of the largest |E_n| listed in its hover title
    order = [c for c, _, _ in legend]
    for colour, title in drawn:
        worst = max(abs(float(v)) for v in re.findall(r"[xyz] ([+-]\d+\.\d+)", title))
        if min(abs(worst - 1.0), abs(worst - 1.5)) > 0.005:  # not at a class edge: the
            # hover's two decimals cannot tell 1.004 from 1.0
            assert colour == order[0 if worst <= 1 else 1 if worst <= 1.5 else 2], title
    # the tables' E_n columns are headed with their k
    tables = [t.value for t in at.dataframe if "E_n (k = 2)" in t.value.columns]
    assert tables, "a table of the changes with its E_n headed with k"
    # what the check cannot see, in words (the quiet one-placement check)
    at.selectbox(key="chk_sample").set_value("quiet (2024-06-17, one placement)").run()
    _ok(at)
    words = next(m.value for m in at.markdown if m.value.startswith("- "))
    assert "the z scale" in words and "[1]" not in words and " - 0." not in words


def test_the_stored_calibration_can_be_this_analysis_with_its_date(downloads):
    """Issue 41: the stored calibration taken from the current analysis (here a
    four-placement check's own files), its calibration date asked for, shown and recorded
    in the check's results; a date not in ISO form is one message and no check."""
    files = downloads
    at = _page()
    # the analysis: a four-placement check's own files, as the Data page's upload loads them
    check = SAMPLES / "history" / "check_2025-02-10_after_crash"
    up = {n: (n, (check / n).read_bytes()) for n in FILES}
    asm = A.assemble_upload([up["measurements.csv"]], up["setup.json"], up["certificate.csv"],
                            name="after crash")
    assert asm.sources is not None, asm.problems
    at.session_state["sources"] = asm.sources
    at.session_state["ds_key"] = A.sources_key(asm.sources)
    at.radio(key="chk_src").set_value("Upload files").run()
    assert at.radio(key="chk_stored").value == "This analysis's fit"
    for key, name, mime in (("chk_meas", "measurements.csv", "text/csv"),
                            ("chk_setup", "setup.json", "application/json"),
                            ("chk_cert", "certificate.csv", "text/csv")):
        at.file_uploader(key=key).set_value((name, (check / name).read_bytes(), mime))
    at.text_input(key="chk_cal_date").set_value("15.01.2026").run()
    assert not at.exception
    assert [e.value for e in at.error] == [
        "Calibration date: expected YYYY-MM-DD, got '15.01.2026'."]
    at.text_input(key="chk_cal_date").set_value("2026-01-15").run()
    _ok(at)
    said = [c.value for c in at.caption if c.value.startswith("Stored calibration: ")]
    assert said and "(this analysis), calibrated 2026-01-15." in said[0], said
    # the same data as the calibration: nothing changed
    assert any(m.value.startswith("**Verdict: no change seen.**") for m in at.success)
    name = next(n for n in files if n and n.endswith("_interim_check_results.json")
                and "this_analysis" in n)
    doc = json.loads(files[name])
    assert doc["interim_check"]["model"].endswith("(this analysis)")
    assert "2026-01-15" in json.dumps(doc), "the calibration date is not in the record"

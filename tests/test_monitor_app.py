"""The Interim check page (issue 28) in AppTest: the sample history's checks and history
render without an error, and the crash is reported."""

from pathlib import Path

import pytest

pytest.importorskip("streamlit")
from streamlit.testing.v1 import AppTest  # noqa: E402

APP = str(Path(__file__).resolve().parents[1] / "app.py")


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
    assert any("no longer behaves" in c.value for c in at.caption)
    assert any("sxy" in m.value for m in at.markdown)
    # the diagnosis against the stored model names the crash's squareness
    assert any("names squareness XY (sxy" in m.value for m in at.markdown)
    # the history tab: the squareness's change between the last two calibrations
    assert any("sxy" in m.value and "significant" in m.value for m in at.markdown)


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


def test_check_offers_its_results_document():
    at = _page()
    _ok(at)
    buttons = at.get("download_button")
    assert [b for b in buttons if "results (JSON)" in b.proto.label]

"""The Interim check page in a real browser (issue 28): streamlit run of the app and
headless Debian chromium through Playwright, as tests/test_browser.py drives it.

Opens the page from the app's navigation, checks the sample history's check after a
crash against the stored calibration (the sample is the page's default data): the
verdict, the E_n map, the new effect the diagnosis names; then the quiet one-placement
check: partial, with what it cannot see; then the History tab's trend.
"""

from pathlib import Path

import pytest
from test_browser import (
    _browser_context,
    _choose,
    _goto,
    _idle,
    _start_server,
    _stop_server,
    svg_figure,
)

pytestmark = pytest.mark.slow  # a real browser: seconds a test (`make test-fast` skips)

ROOT = Path(__file__).resolve().parents[1]
ART = ROOT / "tests" / "artifacts"

# importing test_browser (above) skips this module where chromium or playwright is missing
from playwright.sync_api import expect, sync_playwright  # noqa: E402

expect.set_options(timeout=60_000)  # a wait for the page, not a speed requirement


@pytest.fixture(scope="module")
def server():
    proc, url = _start_server()  # the app itself (app.py)
    yield url
    _stop_server(proc)


@pytest.fixture()
def page(server):
    ART.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as pw:
        browser, ctx = _browser_context(pw)
        pg = ctx.new_page()
        pg.set_default_timeout(90_000)
        pg.goto(server)
        _idle(pg)
        _goto(pg, "Interim check")
        yield pg
        ctx.close()
        browser.close()


def _no_exception(pg):
    assert pg.locator('[data-testid="stException"]').count() == 0
    assert pg.locator('[data-testid="stAlertContentError"]').count() == 0



def _markers(chart) -> tuple[int, int, int]:
    """The E_n map's markers (those whose hover title gives the three E_n), the distinct
    places their titles name, and the observations they list (one line each)."""
    titles = [t for t in chart.locator("title").all_text_contents() if "E_n x" in t]
    places = {t.split(" mm,")[0] for t in titles}
    return len(titles), len(places), sum(t.count(" stylus ") for t in titles)


def test_sample_check_after_a_crash_shows_verdict_map_and_effect(page):
    # the sample history is the page's default data: the check after the crash runs
    expect(page.get_by_text("Stored calibration: calibration_2024-03-04.json")).to_be_visible()
    expect(page.get_by_text("Verdict: changed").first).to_be_visible()
    # the E_n map: a picture drawn on the server with its title, one marker per ball
    # centre, each with its hover title
    chart = svg_figure(page, "chk_map")
    expect(chart.get_by_text("Normalised errors of the new observations")).to_be_visible()
    # one marker per place, every observation (4 placements × 25 balls × 2 styli) listed
    markers, places, observations = _markers(chart)
    assert markers == places < observations == 200
    # what changed: the fewest changes first (the squareness alone), then as the
    # diagnosis names effects
    expect(page.get_by_text("The fewest changes that explain the new data").first
           ).to_be_visible()
    expect(page.get_by_text("names squareness XY (sxy").first).to_be_visible()
    expect(page.get_by_role("heading", name="Conformity")).to_be_visible()
    _no_exception(page)
    page.screenshot(path=str(ART / "check_01_after_crash.png"), full_page=True)


def test_quiet_one_placement_check_is_partial(page):
    _choose(page, "Sample check", "quiet (2024-06-17, one placement)")
    expect(page.get_by_text("Verdict: partial").first).to_be_visible()
    expect(page.get_by_text("cannot see 19 combination(s)").first).to_be_visible()
    chart = svg_figure(page, "chk_map")
    markers, places, observations = _markers(chart)
    assert markers == places == observations == 50  # one placement, its two styli apart
    _no_exception(page)
    page.screenshot(path=str(ART / "check_02_quiet.png"), full_page=True)


def test_history_tab_shows_the_squareness_trend(page):
    page.get_by_role("tab", name="History").click()
    _idle(page)
    expect(page.locator(".st-key-hist_trend [data-testid='stPlotlyChart']")).to_be_visible()
    expect(page.get_by_text("sxy over the calibrations").first).to_be_visible()
    _no_exception(page)

"""The foreign-file panel in a real browser: streamlit run of tests/apps/mapping_app.py
(a page that only draws ``pages.ui.panels.mapping.mapping_panel``) and headless Debian
chromium through Playwright, as tests/test_browser.py drives the app.

Uploads a vendor CSV with decimal commas in µm, picks the columns, sees the preview of the
parsed rows, loads and sees the loaded row count; then a .dmo file and a bad pattern.
"""

from pathlib import Path

import pytest
from test_browser import (
    _browser_context,
    _choose,
    _idle,
    _no_exception,
    _start_server,
    _stop_server,
)

pytestmark = pytest.mark.slow  # a real browser: seconds a test (`make test-fast` skips)

ROOT = Path(__file__).resolve().parents[1]
APP = ROOT / "tests" / "apps" / "mapping_app.py"
ART = ROOT / "tests" / "artifacts"

# importing test_browser (above) skips this module where chromium or playwright is missing
from playwright.sync_api import expect, sync_playwright  # noqa: E402

expect.set_options(timeout=30_000)  # a wait for the page, not a speed requirement

# balls 1..4 of position BP111 in µm with decimal commas; a plane the pattern leaves out
VENDOR = ("Name;X-Wert;Y-Wert;Z-Wert;Durchmesser\n"
          "BP111_1;333999,306;233998,938;-1,962;25,4\n"
          "BP111_2;467000,128;234001,007;0,512;25,4\n"
          "EBENE_1;0;0;0;0\n"
          "BP111_3;600000,455;233999,760;1,004;25,4\n"
          "BP111_4;733001,022;234000,331;-0,250;25,4\n")
DMO = ("FILNAM/'plate',05.3\nUNITS/INCH,ANGDEC\nDATE=2026/11/24\nTIME=14:05:33\n"
       "FA(BP111_1)=FEAT/SPHERE,CART,13.149606,9.212598,$\n  0.000000,1.000000\n"
       "TIME=14:06:03\nFA(BP111_2)=FEAT/SPHERE,CART,18.385827,9.212598,0.000000,1.0\n")


@pytest.fixture(scope="module")
def server():
    proc, url = _start_server(APP)  # the one server start of the browser tests
    yield url
    _stop_server(proc)


@pytest.fixture()
def page(server):
    ART.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as pw:
        browser, ctx = _browser_context(pw)
        pg = ctx.new_page()
        pg.set_default_timeout(60_000)
        pg.goto(server)
        expect(pg.locator("h1", has_text="Mapping panel")).to_be_visible()
        yield pg
        ctx.close()
        browser.close()


def _upload(pg, name: str, text: str):
    uploader = pg.locator('[data-testid="stFileUploader"]')
    uploader.locator('input[type="file"]').set_input_files(
        {"name": name, "mimeType": "text/plain", "buffer": text.encode()})
    expect(pg.get_by_text(name).first).to_be_visible()
    _idle(pg)




def test_vendor_table_mapped_previewed_and_loaded(page):
    _upload(page, "messung.csv", VENDOR)
    # the German column names are suggested; the label column is picked by hand here
    _choose(page, "Label column", "Name")
    page.locator('[data-testid="stRadio"]').filter(has_text="Length unit").get_by_text(
        "µm", exact=True).click()
    _idle(page)
    pattern = page.get_by_role("textbox", name="Label pattern", exact=True)
    pattern.fill(r"(?P<position>BP\d+)_(?P<ball>\d+)")
    pattern.press("Enter")
    _idle(page)
    # the preview: parsed rows in the long form, in mm, before anything is loaded
    grid = page.locator('[data-testid="stDataFrame"]').first
    expect(grid).to_be_visible()
    expect(page.get_by_text("Preview: 4 row(s) parsed")).to_be_visible()
    expect(page.get_by_text("1 label(s) do not match the pattern")).to_be_visible()
    expect(page.get_by_text("converted from um to mm")).to_be_visible()
    assert page.locator('[data-testid="stAlertContentError"]').count() == 0
    _no_exception(page)
    page.screenshot(path=str(ART / "mapping_01_preview.png"), full_page=True)
    page.get_by_role("button", name="Load mapped table").click()
    _idle(page)
    expect(page.get_by_text("Loaded 4 rows from messung.csv.")).to_be_visible()
    _no_exception(page)


def test_dmis_file_and_a_bad_pattern_is_one_error_line(page):
    _upload(page, "plate.dmo", DMO)
    expect(page.get_by_text("2 sphere(s) read")).to_be_visible()
    expect(page.get_by_text("INCH converted to mm")).to_be_visible()
    pattern = page.get_by_role("textbox", name="DMIS label pattern")
    pattern.fill(r"(?P<position>BP\d+_(?P<ball>\d+)")
    pattern.press("Enter")
    _idle(page)
    errors = page.locator('[data-testid="stAlertContentError"]')
    expect(errors.first).to_contain_text("not a valid regular expression")
    assert errors.count() == 1 and "\n" not in errors.first.inner_text().strip()
    expect(page.get_by_role("button", name="Load mapped table")).to_be_disabled()
    _no_exception(page)
    pattern.fill(r"(?P<position>BP\d+)_(?P<ball>\d+)")
    pattern.press("Enter")
    _idle(page)
    page.get_by_role("button", name="Load mapped table").click()
    _idle(page)
    expect(page.get_by_text("Loaded 2 rows from plate.dmo.")).to_be_visible()
    page.screenshot(path=str(ART / "mapping_02_dmis.png"), full_page=True)

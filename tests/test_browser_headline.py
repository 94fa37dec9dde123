"""The diagnosis's headline in a real browser (issue 41): streamlit run of the app and
headless Debian chromium through Playwright, as tests/test_browser.py drives it.

Three simulated cases, each uploaded as a user would (measurements.csv, setup.json,
certificate.csv on the Data page), fitted and diagnosed on the Compare and diagnose page:
a probe offset that cannot be told apart from drift (styli measured one after another),
a blunder of 0.3 mm in one reading (outliers first, one "Exclude" button, then the
headline after excluding it), and a clean fit with a squareness of 12 µrad in the model
(explained to noise, squareness first among the significant terms). What a person reads
is checked against the core's ``Diagnosis.headline()`` of the same files: the page must
draw the core's words, and never "nan" or "p = 0" anywhere in its text.
"""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import scenarios as sc
from test_browser import _browser_context, _goto, _idle, _start_server, _stop_server
from test_headline import ZERO_P

from cmm_core import analysis as A

pytestmark = pytest.mark.slow  # a real browser: seconds a test (`make test-fast` skips)

ROOT = Path(__file__).resolve().parents[1]
ART = ROOT / "tests" / "artifacts"
FILES = ("measurements.csv", "setup.json", "certificate.csv")

# importing test_browser (above) skips this module where chromium or playwright is missing
from playwright.sync_api import expect, sync_playwright  # noqa: E402

expect.set_options(timeout=60_000)  # a wait for the page, not a speed requirement

NAN = re.compile(r"\bnan\b", re.IGNORECASE)
"""A "nan" word: not the "nan" inside "resonance"."""
LEVELS = {"success": "Success", "info": "Info", "warning": "Warning", "error": "Error"}
"""A headline's level and the suffix of Streamlit's alert test id (stAlertContentInfo)."""


@pytest.fixture(scope="module")
def server():
    proc, url = _start_server()  # the app itself (app.py, as `make run`)
    yield url
    _stop_server(proc)


@pytest.fixture(scope="module")
def browser():
    ART.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as pw:
        br, ctx = _browser_context(pw)
        ctx.close()  # each case opens a context of its own: a fresh session, no leftovers
        yield br
        br.close()


@pytest.fixture()
def page(browser, server):
    ctx = browser.new_context(viewport={"width": 1500, "height": 1800})
    pg = ctx.new_page()
    pg.set_default_timeout(90_000)
    pg.goto(server)
    expect(pg.get_by_text("Current analysis")).to_be_visible(timeout=90_000)
    _idle(pg)
    yield pg
    ctx.close()


# --- the cases and what the core says of them ---------------------------------------------

def _alias_case():
    # each placement measures its styli one after the other: a stylus's offset and drift
    # draw the same pattern (tests/test_headline.py's ALIASES)
    return sc.simulated("pitch80_3pos", 4, effects={"probe_offset": {"sd_um": 2.0}})


def _blunder_case():
    """A clean simulation with one reading off by 0.3 mm in y (row 18 of the file)."""
    sim = sc.simulated("pitch100_4pos", 12)
    delta = np.zeros((len(sim.dataset.meas), 3))
    delta[17, 1] = 0.3
    return dataclasses.replace(sim, dataset=sc.perturb(sim.dataset, delta))


def _clean_case():
    # a squareness the baseline kinematic21 fits: nothing is missing
    return sc.simulated("pitch100_4pos", 5, kinematic={"coefficients": {"sxy": 12.0}})


def _record(folder: Path, exclusions=()) -> A.AnalysisRecord:
    """The files as the app holds them after the upload, at its default settings (the
    record's defaults are the app's: kinematic21, order 2, σ 0.5 µm, plate auto)."""
    meas, setup, cert = (str(folder / f) for f in FILES)
    return A.AnalysisRecord(data=A.DataSources(
        "simulated", (A.DataFile(FILES[0], meas),), A.DataFile(FILES[1], setup),
        A.DataFile(FILES[2], cert)), exclusions=tuple(exclusions))


def _core(folder: Path, exclusions=()):
    """The core's diagnosis of the files, fitted and diagnosed as the page does
    (``analysis.fit_record``, then ``diagnose_record`` on that fit)."""
    rec = _record(folder, exclusions)
    ds = A.load_data(rec)
    return A.diagnose_record(rec, ds, baseline_fit=A.fit_record(rec, ds))


# --- driving the page ---------------------------------------------------------------------

def _upload(pg, folder: Path):
    """Upload the three files on the Data page's "Upload CSVs" tab and load them."""
    pg.get_by_role("tab", name="Upload CSVs").click()
    fields = pg.locator('[data-testid="stFileUploader"]')
    for label, name in (("Measurement CSV", FILES[0]), ("Setup (JSON)", FILES[1]),
                        ("Certificate (CSV", FILES[2])):
        field = fields.filter(has_text=label).first
        field.locator('input[type="file"]').set_input_files(str(folder / name))
        expect(field.get_by_text(name).first).to_be_visible()
        # the name shows while the file is still being sent; an upload reruns the page:
        # a click on "Load" before both are done may load without the file (seen once)
        expect(field.get_by_role("progressbar")).to_have_count(0)
        _idle(pg)
    pg.get_by_role("button", name="Load uploaded files").click()
    _idle(pg)
    expect(pg.get_by_text("Loaded 1 uploaded file(s)").first).to_be_visible()
    _no_exception(pg)


def _diagnose(pg):
    """Open the Compare and diagnose page (its fit) and run the diagnosis."""
    _goto(pg, "Compare and diagnose")
    expect(pg.get_by_text("RMS residual").first).to_be_visible()
    pg.get_by_role("button", name="Run the diagnosis").click()
    _idle(pg)
    expect(pg.get_by_text("Running the diagnosis")).to_have_count(0, timeout=120_000)
    _idle(pg)


def _no_exception(pg):
    assert pg.locator('[data-testid="stException"]').count() == 0


def _words(text: str) -> str:
    """Text with every run of white space one blank (the page wraps and splits lines)."""
    return " ".join(text.split())


def _shown_headline(pg, h) -> str:
    """The headline's message on the page, checked to be the core's ``h`` word for word,
    drawn at its level, and scrolled into view (for the screenshot: a certificate warning
    above it can push it below the window); its text (white space made single)."""
    box = pg.locator('[data-testid="stAlert"]').filter(has_text=h.title)
    expect(box).to_have_count(1)
    shown = _words(box.inner_text())
    for part in (h.title, h.text, f"Next: {h.action}"):
        assert _words(part) in shown, (part, shown)
    assert box.locator(f'[data-testid="stAlertContent{LEVELS[h.level]}"]').count() == 1
    box.scroll_into_view_if_needed()
    return shown


def _clean_words(pg):
    """No "nan" and no "p = 0" anywhere in the page's text (sidebar included)."""
    body = pg.inner_text("body")
    assert not NAN.search(body), NAN.search(body)
    assert not ZERO_P.search(body), body[max(0, ZERO_P.search(body).start() - 200):][:400]
    _no_exception(pg)


# --- the three cases ----------------------------------------------------------------------

def test_an_alias_is_named_as_a_pair_with_its_size(page, tmp_path):
    _alias_case().write(tmp_path)
    d = _core(tmp_path)
    h = d.headline()
    assert h.verdict == "named" and set(h.alias_of) == {"drift"}, h
    _upload(page, tmp_path)
    _diagnose(page)
    shown = _shown_headline(page, h)
    # what a person reads: the effect, that it cannot be told apart from drift, its size
    assert "probe_offset" in shown and "drift" in shown
    assert "cannot be told apart" in shown and "this data cannot decide" in shown
    size = re.search(r"[-+]?\d+(\.\d+)? ± \d+(\.\d+)?", shown)
    assert size and " µm" in shown[size.start():], shown
    assert "Measure next" in shown
    _clean_words(page)
    page.screenshot(path=str(ART / "headline_01_alias.png"), full_page=True)


def test_a_blunder_comes_first_with_one_exclude_button(page, tmp_path):
    _blunder_case().write(tmp_path)
    d = _core(tmp_path)
    h = d.headline()
    assert h.verdict == "flagged_outliers", h
    flagged = [tuple(e) for e in d.blunders.exclusions]
    assert len(flagged) == 1, flagged
    _upload(page, tmp_path)
    _diagnose(page)
    shown = _shown_headline(page, h)
    assert shown.startswith("Flagged outlier(s) first")
    assert "1 observation(s) flagged as gross errors" in shown and "µm" in shown
    # one condition, one button: the headline's, not the outlier warning's beside it
    exclude = page.get_by_role("button", name=re.compile("Exclude"))
    expect(exclude).to_have_count(1)
    expect(exclude).to_be_enabled()
    _clean_words(page)
    page.screenshot(path=str(ART / "headline_02_blunder.png"), full_page=True)

    exclude.click()
    _idle(page)
    expect(page.get_by_text("Running the diagnosis")).to_have_count(0, timeout=120_000)
    _idle(page)
    after = _core(tmp_path, flagged).headline()
    assert after.verdict != "flagged_outliers", after
    _shown_headline(page, after)
    expect(page.get_by_role("button", name=re.compile("Exclude"))).to_have_count(0)
    expect(page.locator('[data-testid="stSidebar"]').get_by_text(
        "1 observation(s) excluded")).to_be_visible()
    _clean_words(page)
    page.screenshot(path=str(ART / "headline_03_blunder_excluded.png"), full_page=True)


def test_a_clean_fit_is_explained_to_noise_squareness_first(page, tmp_path):
    _clean_case().write(tmp_path)
    h = _core(tmp_path).headline()
    assert h.verdict == "explained_to_noise", h
    _upload(page, tmp_path)
    _diagnose(page)
    shown = _shown_headline(page, h)
    assert shown.startswith("Explained to noise")
    assert "the data are explained to noise by this model" in shown
    # the significant terms, the simulated squareness first with its u and unit
    terms = shown.split("Significant in the model: ", 1)[1]
    assert re.match(r"squareness XY \d+(\.\d+)? ± \d+(\.\d+)? µrad, ", terms), terms
    assert "Nothing to add" in shown
    _clean_words(page)
    page.screenshot(path=str(ART / "headline_04_clean.png"), full_page=True)

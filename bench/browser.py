"""Benchmark: what a person waits for in the browser (issue 27), beside the server's share.

``streamlit run app.py`` and Debian's chromium driven by Playwright (headless). Each action
is timed from the click (or the navigation) until the app is idle and every plot on the
page is drawn: no "running" status widget, no skeleton, every Plotly chart with its SVG,
every static figure's frame with its picture and as tall as it.
Beside it, in the same run, the server's time for the same action: the wall time of every
script run that ended inside the action's window, summed (``app.py`` appends each run to the
file named by ``CMM_LAB_RUN_LOG``). The difference is the browser's share (transfer,
layout, Plotly drawing) plus Streamlit's own round trips.

Actions (medians of ``--runs`` repetitions, each in a new browser context, i.e. a new
session; the first load cold starts a new server each time):

- first load: a cold server, and a new session on a warm server (``/data``, thesis data),
  each in a browser context with an empty cache (a first visit ever: Streamlit's frontend
  fetches the scripts of each element kind on first use, plotly's 3.5 MB and the data
  grid's among them), and a new session of a browser that opened the app before;
- the first visit of every page in a session;
- Run the diagnosis (first in a session: the server's cache may hold it from an earlier
  session, as it would for a second user), Add this effect, Undo last step;
- Exclude all flagged outliers on the Data page, and Include all again;
- Load uploaded files (the six thesis tables as CSVs).

The peer of the first loads, in the same run: an empty Streamlit app (a title and one
metric) opened the same way, the part of a first load that is Streamlit's own frontend
(its script bundle in a browser context with an empty cache) rather than this app.

Goals: every action and page visit under 1 s, the first load under 2 s.

An app is started as ``make run`` starts it (``serve.py``, the app's imports done before
the server answers) where the checkout has ``serve.py``; the server's start, from the
command to its first answer, is printed beside.

``--against DIR`` (another checkout, e.g. ``git worktree add /tmp/old <commit>``) runs its
app on a second server in the same run, the sessions of the two apps interleaved (first
loads and whole sessions alternate, the order swapped each repetition), so that a busy
machine slows both alike: the table then has the other checkout's browser time beside.

    .venv/bin/python bench/browser.py [--runs 3] [--quick] [--against DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
THESIS = ROOT / "sample_data" / "thesis"
NAV = ".st-key-app_nav a"
PAGES = ["Kinematic model", "Gaussian process", "Compare and diagnose", "Uncertainty",
         "Compensate and export", "Plan", "Interim check", "Data"]
GOAL_S, FIRST_LOAD_GOAL_S = 1.0, 2.0

# idle and drawn: no status widget, no skeleton, every plotly chart has its svg, every
# static figure's frame (widgets.svg_figure) its picture and the picture's height
IDLE_JS = """() => !document.querySelector('[data-testid="stStatusWidget"]')
  && !document.querySelector('[data-testid="stSkeleton"]')
  && Array.from(document.querySelectorAll('[data-testid="stPlotlyChart"]'))
       .every(c => c.querySelector('.main-svg'))
  && Array.from(document.querySelectorAll('iframe[data-testid="stIFrame"]')).every(f => {
       const s = f.contentDocument && f.contentDocument.querySelector('svg');
       return s && Math.abs(f.getBoundingClientRect().height
                            - s.getBoundingClientRect().height) < 2; })"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


EMPTY_APP = 'import streamlit as st\n\nst.title("Empty")\nst.sidebar.metric("RMS (µm)", "0")\n'
"""The peer of a first load: a Streamlit app with a title and one metric, what Streamlit's
own frontend costs before this app draws anything."""


class Server:
    """``streamlit run app.py`` (or ``script``) on a free port with a run log and a sessions
    folder of its own."""

    def __init__(self, tmp: Path, script: Path = ROOT / "app.py"):
        self.log = tmp / f"runs-{time.time_ns()}.jsonl"
        port = _free_port()
        env = {**os.environ, "STREAMLIT_BROWSER_GATHER_USAGE_STATS": "false",
               "CMM_LAB_RUN_LOG": str(self.log), "CMM_LAB_SESSIONS": str(tmp / "sessions")}
        # an app is started as ``make run`` starts it (serve.py: its imports done before
        # the server starts), where the checkout has it; anything else by streamlit run
        serve = script.parent / "serve.py"
        start = ([str(serve)] if script.name == "app.py" and serve.exists()
                 else ["-m", "streamlit", "run", str(script)])
        t0 = time.time()
        self.proc = subprocess.Popen(
            [sys.executable, *start,
             "--server.headless", "true", "--server.port", str(port), "--server.address",
             "127.0.0.1", "--server.fileWatcherType", "none"],
            cwd=script.parent, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.url = f"http://127.0.0.1:{port}"
        deadline = time.time() + 60
        while time.time() < deadline:
            try:
                with urllib.request.urlopen(self.url + "/_stcore/health", timeout=2):
                    self.start_s = time.time() - t0
                    return
            except OSError:
                time.sleep(0.2)
        self.stop()
        raise RuntimeError("streamlit did not start within 60 s")

    def runs(self) -> list:
        """The script runs logged so far."""
        if not self.log.exists():
            return []
        return [json.loads(line) for line in self.log.read_text().splitlines() if line]

    def server_s(self, t0: float, t1: float) -> float:
        """Wall time of the script runs that ended between ``t0`` and ``t1`` (epoch s)."""
        return sum(r["s"] for r in self.runs() if t0 <= r["t_end"] <= t1 + 0.05)

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def _idle(pg, timeout_ms=120_000):
    """Wait until the app is idle and drawn (twice, 150 ms apart: a rerun can start just
    after the first idle moment)."""
    for _ in range(2):
        pg.wait_for_timeout(150)
        pg.wait_for_function(IDLE_JS, timeout=timeout_ms)


def timed(server: Server, pg, act) -> tuple[float, float]:
    """(browser s, server s) of ``act()`` followed by idle-and-drawn. Streamlit shows its
    status widget only some time after a run starts, so "idle" right after a click can be
    the moment before the run: the wait first needs a new script run in the server's log.
    The two 150 ms settling waits of :func:`_idle` are subtracted: they are the
    benchmark's, not the app's."""
    n0 = len(server.runs())
    t0 = time.time()
    act()
    deadline = time.time() + 120
    while len(server.runs()) == n0 and time.time() < deadline:
        pg.wait_for_timeout(20)
    _idle(pg)
    t1 = time.time()
    return t1 - t0 - 0.3, server.server_s(t0, t1)


def _new_page(browser):
    ctx = browser.new_context(viewport={"width": 1500, "height": 1800})
    pg = ctx.new_page()
    pg.set_default_timeout(120_000)
    return ctx, pg


def _shown(pg, selector: str, text: str, timeout_ms=120_000):
    """Wait until an element matching ``selector`` whose text contains ``text`` is in the
    page, checked on every animation frame. Not ``locator.wait_for``: Playwright retries a
    selector after 0, 20, 50, 100, 100 ms and then every 500 ms, so an element that
    appears 0.8 s after the wait began is seen up to half a second late, and every first
    load and page visit was timed in steps of about 0.5 s."""
    pg.wait_for_function(
        "([sel, text]) => Array.from(document.querySelectorAll(sel))"
        ".some(e => e.textContent.includes(text))", arg=[selector, text],
        polling="raf", timeout=timeout_ms)


def _goto(pg, title):
    def act():
        pg.locator(NAV, has_text=title).first.click()
        _shown(pg, "h1", title)
    return act


def _open(server, pg):
    def act():
        pg.goto(server.url + "/data")
        _shown(pg, '[data-testid="stMetricLabel"]', "RMS (µm)")
    return act


def _upload(pg):
    pg.get_by_role("tab", name="Upload CSVs").click()
    up = pg.locator('[data-testid="stFileUploader"]').filter(has_text="Measurement CSV")
    up.locator('input[type="file"]').set_input_files(
        [str(THESIS / f"{p}.csv") for p in ("BP111", "BP112", "BP211", "BP212", "BP311",
                                             "BP312")])
    up.get_by_text("BP312.csv").first.wait_for()  # the validation table names it too


def one_session(server, browser, results):
    ctx, pg = _new_page(browser)
    try:
        results.setdefault("first load, new session on a warm server", []).append(
            timed(server, pg, _open(server, pg)))
        for title in PAGES:
            results.setdefault(f"first visit: {title}", []).append(
                timed(server, pg, _goto(pg, title)))
        _upload(pg)
        results.setdefault("Load uploaded files", []).append(timed(
            server, pg, lambda: pg.get_by_role("button", name="Load uploaded files").click()))
        results.setdefault("Exclude all flagged", []).append(timed(
            server, pg, lambda: pg.get_by_role("button", name="Exclude all flagged").click()))
        results.setdefault("Include all", []).append(timed(
            server, pg, lambda: pg.get_by_role("button", name="Include all").click()))
        timed(server, pg, _goto(pg, "Compare and diagnose"))
        results.setdefault("Run the diagnosis", []).append(timed(
            server, pg, lambda: pg.get_by_role("button", name="Run the diagnosis").click()))
        results.setdefault("Add this effect", []).append(timed(
            server, pg, lambda: pg.get_by_role("button", name="Add this effect").first.click()))
        results.setdefault("Undo last step", []).append(timed(
            server, pg, lambda: pg.get_by_role("button", name="Undo last step").click()))
    finally:
        ctx.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="repetitions per action (default 3)")
    ap.add_argument("--quick", action="store_true",
                    help="one cold server start instead of --runs of them")
    ap.add_argument("--against", type=Path, default=None,
                    help="another checkout whose app runs interleaved with this one")
    args = ap.parse_args(argv)
    if not Path(CHROMIUM).exists():
        print(f"{CHROMIUM} is not installed: nothing to measure.")
        return 0
    from playwright.sync_api import sync_playwright  # lazy: only this bench needs it

    apps = {"this": ROOT / "app.py"}
    if args.against is not None:
        apps["other"] = args.against.resolve() / "app.py"
    results: dict[str, dict[str, list]] = {k: {} for k in apps}
    loads = [os.getloadavg()[0]]
    starts: dict[str, list] = {}  # server start to healthy, s
    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True,
                                     args=["--no-sandbox", "--disable-gpu"])

        def order(rep):
            return list(apps.items()) if rep % 2 == 0 else list(reversed(apps.items()))

        for rep in range(1 if args.quick else args.runs):
            for k, app in order(rep):
                server = Server(Path(tmp), app)
                try:
                    ctx, pg = _new_page(browser)
                    results[k].setdefault("first load, cold server", []).append(
                        timed(server, pg, _open(server, pg)))
                    starts.setdefault(k, []).append(server.start_s)
                    ctx.close()
                finally:
                    server.stop()
        empty = Path(tmp) / "empty_app.py"
        empty.write_text(EMPTY_APP)
        for _ in range(args.runs):
            server = Server(Path(tmp), empty)
            try:
                for label in ("peer: an empty Streamlit app, cold server",
                              "peer: an empty Streamlit app, warm server"):
                    ctx, pg = _new_page(browser)
                    t0 = time.time()
                    pg.goto(server.url)
                    _shown(pg, "h1", "Empty")
                    _idle(pg)
                    for k in apps:
                        results[k].setdefault(label, []).append((time.time() - t0 - 0.3, 0.0))
                    ctx.close()
            finally:
                server.stop()
        servers = {k: Server(Path(tmp), app) for k, app in apps.items()}
        try:
            for server in servers.values():
                one_session(server, browser, {})  # warm-up: the server's caches, imports
            for rep in range(args.runs):
                for k, _app in order(rep):
                    one_session(servers[k], browser, results[k])
                    loads.append(os.getloadavg()[0])
            # a returning user: the browser has Streamlit's and plotly's scripts in its
            # cache (a new page of a context that opened the app before is a new session)
            for k, server in servers.items():
                ctx, pg = _new_page(browser)
                _open(server, pg)()
                _idle(pg)
                for _ in range(args.runs):
                    pg.close()
                    pg = ctx.new_page()
                    results[k].setdefault("first load, new session, browser cache warm",
                                          []).append(timed(server, pg, _open(server, pg)))
                ctx.close()
        finally:
            for server in servers.values():
                server.stop()
        browser.close()
    other = results.get("other", {})
    print(f"{'action':46s} {'browser s':>10s} {'server s':>9s} {'browser-only s':>14s}  goal"
          + ("        other checkout browser s" if other else ""))
    for name, v in results["this"].items():
        b = statistics.median(x[0] for x in v)
        srv = statistics.median(x[1] for x in v)
        goal = FIRST_LOAD_GOAL_S if name.startswith("first load") else GOAL_S
        line = (f"{name:46s} {b:10.2f} {srv:9.2f} {b - srv:14.2f}  "
                f"{'ok' if b < goal else 'MISSES'} (< {goal:g} s)")
        if other and not name.startswith("peer"):
            line += f"  {statistics.median(x[0] for x in other[name]):10.2f}"
        print(line)
    print("server start, from the command to its first answer: "
          + ", ".join(f"{k} {statistics.median(v):.2f} s" for k, v in starts.items())
          + " (serve.py imports the app's modules before it answers)")
    print(f"medians of {args.runs} runs; server s: the script runs inside the action's window; "
          f"load average {min(loads):.1f}-{max(loads):.1f} (1 min, {os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: every page's response time to a widget change on the thesis data, once warm.

Uses Streamlit's AppTest (the full script run, no browser). For each page a widget is
toggled between two values; after a warm-up pass (caches filled) the median of several
timed runs is printed, with the peer in the same run: the same page run cold (every
st.cache_data / st.cache_resource cleared, so the fit, uncertainty and figures are
recomputed) and the warm/cold ratio. Target: < 0.5 s per change.

``--diagnosis`` times the "Run the diagnosis" button instead (issue 18, target < 1 s): on
the thesis data and on the simulated sample (``sample_data/simulated``), the page's run
after the click with the fit cached and the diagnosis's own cache cleared before every
click, beside the peer in the same run: ``cmm_core.diagnosis.diagnose`` called directly
with the page's arguments (the app's overhead is the ratio). Then the core diagnosis alone
on simulated cases of the honesty bench's kind (``tests/scenarios.py``).

``--add-effect`` times "Add this effect" (the refit and the new diagnosis) beside the core
calls, and a new session's first render with cold and warm caches.

    .venv/bin/python bench/app.py [--runs N] [--diagnosis | --add-effect]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import streamlit as st
from streamlit.testing.v1 import AppTest

from cmm_core import analysis as A

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
TARGET_S = 0.5

# page, widget kind, key, two values to alternate, session state to set first
CASES = [
    ("pages/data.py", "checkbox", "w_ex_BP112_2_7", (True, False), {}),
    ("pages/kinematic.py", "selectbox", "w_order", (3, 2), {}),
    ("pages/kinematic.py", "slider", "w_magnification", (5000.0, 2000.0), {}),
    ("pages/gaussian_process.py", "radio", "w_gp_comp", ("y", "x"), {"gp_on": True}),
    ("pages/diagnose.py", "radio", "w_map_comp", ("x", "norm"), {"diag_on": True}),
    ("pages/uncertainty.py", "slider", "w_u_z", (300.0, 400.0), {}),
    ("pages/export.py", "number_input", "w_grid_step", (200.0, 100.0), {}),
]


def _set(at, kind, key, value):
    w = getattr(at, kind)(key=key)
    if kind == "checkbox":
        w.check() if value else w.uncheck()
    else:
        w.set_value(value)


def bench(runs: int = 5) -> list:
    rows = []
    for page, kind, key, values, state in CASES:
        at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=300)
        at.run()
        for k, v in state.items():
            at.session_state[k] = v
        at.switch_page(page)
        at.run()
        st.cache_data.clear()
        st.cache_resource.clear()
        t0 = time.perf_counter()
        at.run()
        cold = time.perf_counter() - t0
        for v in values * 2:  # warm: every value cached
            _set(at, kind, key, v)
            at.run()
        if at.exception:
            raise RuntimeError(f"{page}: {at.exception[0].message}")
        times = []
        for i in range(runs):
            _set(at, kind, key, values[i % 2])
            t0 = time.perf_counter()
            at.run()
            times.append(time.perf_counter() - t0)
        rows.append((page, key, statistics.median(times), max(times), cold))
    return rows


def _simulated_files() -> A.DataSources:
    d = ROOT / "sample_data" / "simulated"
    return A.DataSources(
        "simulated sample",
        (A.DataFile("measurements.csv", content=(d / "measurements.csv").read_text()),),
        A.DataFile("setup.json", content=(d / "setup.json").read_text()),
        A.DataFile("certificate.csv", content=(d / "certificate.csv").read_text()))


def _diagnose_page(case: str):
    """An app session on the Diagnose page with the thesis data or the simulated sample:
    ``(AppTest, the pages.state and pages.cached modules it runs)``."""
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=300)
    at.run()
    common = sys.modules["pages.ui.state"]
    cached = sys.modules["pages.ui.cached"]
    if case != "thesis":
        files = _simulated_files()
        at.session_state["sources"] = files
        at.session_state["ds_key"] = A.sources_key(files)
    at.switch_page("pages/diagnose.py")
    at.run()
    return at, common, cached


def bench_diagnosis(runs: int = 5) -> list:
    """``(case, first click s, median s of the later clicks, median s of the core
    diagnosis, verdict)``."""
    from cmm_core.diagnosis import diagnose

    rows = []
    for case in ("thesis", "simulated sample"):
        at, common, cached = _diagnose_page(case)
        times = []
        for _ in range(runs + 1):  # the first click warms imports
            cached.cached_diagnosis.clear()
            at.button(key="run_diagnosis").click()
            t0 = time.perf_counter()
            at.run()
            times.append(time.perf_counter() - t0)
            if at.exception:
                raise RuntimeError(f"{case}: {at.exception[0].message}")
            at.button(key="hide_diagnosis").click()
            at.run()
        ds = common.load_sources(at.session_state["ds_key"], at.session_state["sources"])
        key, spec, order, plate, sigma, pos, prb, excl = _fit_args(at)
        core = []
        for _ in range(runs):
            t0 = time.perf_counter()
            d = diagnose(ds, baseline=spec, order=order,
                         plate=None if plate == "auto" else plate, sigma_um=sigma,
                         exclude=excl)
            core.append(time.perf_counter() - t0)
        rows.append((case, times[0], statistics.median(times[1:]), statistics.median(core),
                     d.verdict))
    return rows


def bench_add_effect(runs: int = 3) -> list:
    """"Add this effect" on the Diagnose page: the click's rerun (refit with the effect and
    a new diagnosis, fits cached as the app caches them) timed on the thesis data and on
    the simulated sample, undone between clicks; peer: the core refit and diagnosis called
    directly. ``(case, effect, median s app, median s core)``."""
    from cmm_core.diagnosis import diagnose
    from cmm_core.model import fit

    rows = []
    for case in ("thesis", "simulated sample"):
        at, common, cached = _diagnose_page(case)
        at.button(key="run_diagnosis").click()
        at.run()
        adds = [b for b in at.button if str(b.key).startswith("add_")]
        if not adds:
            continue
        key = adds[0].key
        times = []
        for _ in range(runs + 1):  # the first click warms the refit's imports
            cached.cached_diagnosis.clear()
            at.button(key=key).click()
            t0 = time.perf_counter()
            at.run()
            times.append(time.perf_counter() - t0)
            if at.exception:
                raise RuntimeError(f"{case}: {at.exception[0].message}")
            at.button(key="undo_step").click()
            at.run()
        ds = common.load_sources(at.session_state["ds_key"], at.session_state["sources"])
        _, spec, order, plate, sigma, _, _, excl = _fit_args(at)
        new = f"{spec},{key[4:]}"
        core = []
        for _ in range(runs):
            t0 = time.perf_counter()
            fit(ds, new, order=order, plate=None if plate == "auto" else plate,
                sigma_um=sigma, exclude=excl)
            diagnose(ds, baseline=new, order=order, plate=None if plate == "auto" else plate,
                     sigma_um=sigma, exclude=excl)
            core.append(time.perf_counter() - t0)
        rows.append((case, key[4:], statistics.median(times[1:]), statistics.median(core)))
    return rows


def bench_first_render(runs: int = 3) -> tuple:
    """A new session's first render (app.py with the Data page and the automatic fit):
    cold (every cache cleared, as after starting the server) and warm (another session of
    a running server). ``(median s cold, median s warm)``."""
    cold, warm = [], []
    for _ in range(runs):
        st.cache_data.clear()
        st.cache_resource.clear()
        for out in (cold, warm):
            at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=300)
            t0 = time.perf_counter()
            at.run()
            out.append(time.perf_counter() - t0)
            if at.exception:
                raise RuntimeError(at.exception[0].message)
    return statistics.median(cold), statistics.median(warm)


def _fit_args(at):
    s = at.session_state
    return (s["ds_key"], s["spec"], s["order"], s["plate"], s["sigma_um"], None, None,
            tuple(tuple(e) for e in s["exclusions"]))


def bench_core_cases(runs: int = 3) -> list:
    """The core diagnosis on simulated layouts of ``tests/scenarios.py``, each with a
    catalogue effect hidden in it: ``(case, median s, verdict)``."""
    sys.path.insert(0, str(ROOT / "tests"))
    from scenarios import simulated  # noqa: PLC0415

    from cmm_core.diagnosis import diagnose

    cases = [("pitch100_4pos", {"plate_sag": {"uu": -2.0, "uv": 0.5, "vv": -1.5}}),
             ("pitch80_3pos", {"probe_offset": {"sd_um": 2.0}}),
             ("pitch150_5pos", {"drift": {"sd_um_per_h": 3.0}})]
    rows = []
    for layout, effects in cases:
        data = simulated(layout, 7, effects=effects).dataset
        times = []
        for _ in range(runs):
            t0 = time.perf_counter()
            d = diagnose(data)
            times.append(time.perf_counter() - t0)
        rows.append((f"{layout} {next(iter(effects))}", statistics.median(times), d.verdict))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--diagnosis", action="store_true",
                    help='time the "Run the diagnosis" button instead')
    ap.add_argument("--add-effect", action="store_true",
                    help='time "Add this effect" and a new session\'s first render instead')
    args = ap.parse_args(argv)
    if args.add_effect:
        print(f"{'Add this effect':34s} {'app s':>7s} {'core s':>7s} {'app/core':>8s}")
        for case, effect, app_s, core_s in bench_add_effect(args.runs):
            print(f"{case + ': ' + effect:34s} {app_s:7.3f} {core_s:7.3f} "
                  f"{app_s / core_s:8.2f}")
        cold, warm = bench_first_render(args.runs)
        print(f"{'first render, cold caches':34s} {cold:7.3f}")
        print(f"{'first render, warm (new session)':34s} {warm:7.3f} {'':7s} "
              f"{warm / cold:8.2f}")
        return 0
    if args.diagnosis:
        head = f"{'Run the diagnosis':34s} {'first s':>7s} {'app s':>7s} {'core s':>7s}"
        print(f"{head} {'app/core':>8s}  verdict")
        for case, first, app_s, core_s, verdict in bench_diagnosis(args.runs):
            print(f"{case:34s} {first:7.3f} {app_s:7.3f} {core_s:7.3f} {app_s / core_s:8.2f}"
                  f"  {verdict}")
        for case, core_s, verdict in bench_core_cases():
            print(f"{'core: ' + case:34s} {'':7s} {'':7s} {core_s:7.3f} {'':8s}  {verdict}")
        return 0
    rows = bench(args.runs)
    print(f"{'page':30s} {'widget':18s} {'median s':>9s} {'max s':>7s} {'cold s':>7s} "
          f"{'ratio':>6s}")
    worst = 0.0
    for page, key, med, mx, cold in rows:
        flag = "" if med < TARGET_S else "  <-- over target"
        print(f"{page:30s} {key:18s} {med:9.3f} {mx:7.3f} {cold:7.3f} {med / cold:6.2f}{flag}")
        worst = max(worst, med)
    print(f"worst median {worst:.3f} s (target < {TARGET_S} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: every page's response time to a widget change on the thesis data, once warm.

Uses Streamlit's AppTest (the full script run, no browser). For each page a widget is
toggled between two values; after a warm-up pass (caches filled) the median of several
timed runs is printed, with the peer in the same run: the same page run cold (every
st.cache_data / st.cache_resource cleared, so the fit, uncertainty and figures are
recomputed) and the warm/cold ratio. Target: < 0.5 s per change.

    .venv/bin/python bench/app.py [--runs N]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import streamlit as st
from streamlit.testing.v1 import AppTest

ROOT = Path(__file__).resolve().parents[1]
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args(argv)
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

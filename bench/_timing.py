"""Shared timing helper of the benchmark scripts (run as ``python bench/NAME.py``)."""

import time

import numpy as np


def median_time(f, repeats):
    """Median wall time of ``repeats`` calls of ``f()`` (s), and the last call's result."""
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out

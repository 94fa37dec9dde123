"""Benchmark: GUM Supplement 1 Monte Carlo, 10^6 trials of a simple additive budget.

Prints the median wall time of ``cmm_core.gum.monte_carlo`` (chunked, with progress
callback) and of a naive non-chunked numpy run of the same computation (all 10^6 x N
draws at once, sort, symmetric and shortest intervals) in the same process, and their ratio.
Run: ``.venv/bin/python bench/gum_mc.py``.
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import median_time  # noqa: E402

from cmm_core.gum import Contribution, coverage_intervals, monte_carlo

M = 1_000_000
REPEATS = 7
BUDGET = [
    Contribution("a", 1.0, "normal", c=1.0),
    Contribution.from_half_width("b", 1.0, "rectangular", c=2.0),
    Contribution.from_half_width("c", 0.5, "triangular", c=1.0),
    Contribution.from_half_width("d", 0.3, "u_shaped", c=1.0),
]




def ours(seed=1):
    return monte_carlo(BUDGET, trials=M, seed=seed, progress=lambda f: None)


def naive(seed=1):
    """Same model, every input drawn for all trials at once, no chunks, no callbacks."""
    rng = np.random.default_rng(seed)
    y = (rng.normal(0.0, 1.0, M) + 2.0 * rng.uniform(-1.0, 1.0, M)
         + rng.triangular(-0.5, 0.0, 0.5, M) + 0.3 * np.cos(np.pi * rng.uniform(0, 1, M)))
    ys = np.sort(y)
    return ys.mean(), ys.std(ddof=1), coverage_intervals(ys, 0.95)


def main():
    ours()
    naive()
    t_ours, _ = median_time(ours, REPEATS)
    t_naive, _ = median_time(naive, REPEATS)
    r = ours()
    print(f"monte_carlo, {M:.0e} trials, {len(BUDGET)} inputs: median {t_ours:.3f} s "
          f"over {REPEATS} runs (u = {r.u:.4f}, shortest 95 % interval "
          f"[{r.interval_shortest[0]:.3f}, {r.interval_shortest[1]:.3f}])")
    print(f"naive non-chunked numpy: median {t_naive:.3f} s; ratio ours/naive = "
          f"{t_ours / t_naive:.2f}")


if __name__ == "__main__":
    main()

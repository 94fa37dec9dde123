"""Benchmark: cmm_core.gp.fit_gp against scikit-learn's GaussianProcessRegressor.

Same data (a smooth error surface of a few µm over a 500 mm plate plus 0.3 µm noise), same
model (SE isotropic × signal variance + white noise, zero mean), same number of restarts,
in the same run. Prints the median fit time of each, their ratio, the peak traced memory
(tracemalloc, which sees numpy's allocations) and both log marginal likelihoods.

BLAS is limited to one thread for both (``--threads``) so that the timings do not depend
on how busy a shared machine is; fewer repeats (and restarts) at large n keep the whole
run under about two minutes. Run: ``.venv/bin/python bench/gp.py``.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cmm_core.gp import fit_gp  # noqa: E402

# n: (repeats, restarts); restarts are the same for both implementations at each n
PLAN = {25: (7, 3), 200: (3, 3), 1000: (1, 3), 2000: (1, 0)}


def data(n, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 500, (n, 2))
    y = 3 * np.sin(X[:, 0] / 120) + 2 * np.cos(X[:, 1] / 90) + 0.3 * rng.standard_normal(n)
    return X, y


def run_ours(X, y, restarts):
    r = fit_gp(X, y, mean="zero", kernel="se_iso", restarts=restarts, seed=0)
    return r.log_marginal_likelihood


def run_sklearn(X, y, restarts):
    # imported in main() before any measurement, so import memory is not counted here
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    k = ConstantKernel(1.0) * RBF(100.0) + WhiteKernel(0.1)
    g = GaussianProcessRegressor(k, n_restarts_optimizer=restarts, random_state=0).fit(X, y)
    return g.log_marginal_likelihood_value_


def measure(fn, X, y, restarts, repeats):
    times, peak, lml = [], 0, None
    for _ in range(repeats):
        tracemalloc.start()
        t0 = time.perf_counter()
        lml = fn(X, y, restarts)
        times.append(time.perf_counter() - t0)
        peak = max(peak, tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    return statistics.median(times), peak / 2**20, lml


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="25,200,1000,2000")
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads for both (default 1)")
    args = ap.parse_args(argv)
    try:
        import sklearn.gaussian_process  # noqa: F401
    except ImportError:
        print("scikit-learn is not installed (pip install -r requirements-test.txt)")
        return 1
    try:
        from threadpoolctl import threadpool_limits

        limit = threadpool_limits(args.threads)
    except ImportError:
        limit = contextlib.nullcontext()
    warnings.filterwarnings("ignore")  # sklearn's bound ConvergenceWarnings
    sizes = [int(s) for s in args.sizes.split(",")]
    print(f"GP fit: cmm_core.gp.fit_gp vs scikit-learn GaussianProcessRegressor "
          f"(SE iso + noise, zero mean, BLAS threads {args.threads})")
    head = (f"{'n':>5} {'restarts':>8} {'repeats':>7} {'ours_s':>9} {'sklearn_s':>9} "
            f"{'sk/ours':>7} {'ours_MiB':>8} {'sk_MiB':>8} {'lml_ours':>11} {'lml_sk':>11}")
    print(head)
    t_all = time.perf_counter()
    verdict = None
    with limit:
        run_ours(*data(25), 0)  # warm-up: first-call costs are not the fit's
        run_sklearn(*data(25), 0)
        for n in sizes:
            repeats, restarts = PLAN.get(n, (1, 3))
            X, y = data(n)
            to, mo, lo = measure(run_ours, X, y, restarts, repeats)
            ts, ms, ls = measure(run_sklearn, X, y, restarts, repeats)
            print(f"{n:>5} {restarts:>8} {repeats:>7} {to:>9.3f} {ts:>9.3f} {ts / to:>7.2f} "
                  f"{mo:>8.1f} {ms:>8.1f} {lo:>11.4f} {ls:>11.4f}", flush=True)
            if n == 1000:
                verdict = to <= ts
    print(f"total {time.perf_counter() - t_all:.1f} s")
    if verdict is not None:
        print(f"target (no slower than scikit-learn at n = 1000): "
              f"{'met' if verdict else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

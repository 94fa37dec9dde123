"""Benchmark: kinematic fit on the six thesis tables and on a dense simulated dataset.

Prints median wall times, the ratio against scipy.optimize.least_squares solving the same
problem (same residuals, same analytic sparse Jacobian, no constraints needed for the
fixed-plate model) in the same run, and the peak traced memory.
Run: ``.venv/bin/python bench/fit.py``.
"""

import sys
import tracemalloc
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import median_time  # noqa: E402

from cmm_core.dataset import thesis_dataset  # noqa: E402
from cmm_core.effects import parse_spec  # noqa: E402
from cmm_core.fit import Problem, fit, select  # noqa: E402
from cmm_core.outliers import detect_outliers  # noqa: E402
from cmm_core.simulate import simulate  # noqa: E402


def peer(data, exclude=()):
    """scipy least_squares (trust-region reflective) on the same fixed-plate problem."""
    prob = Problem(select(data, exclude=exclude), parse_spec("kinematic21"), "fixed")
    st0 = prob.initial_state()

    def state(x):
        return prob.update(st0, x)

    def res(x):
        return prob.residual(state(x))[0].ravel() / 0.5

    dense = prob.n_obs <= 5000

    def jac(x):
        J = prob.residual(state(x), True)[1] / 0.5
        return J.toarray() if dense else J

    return least_squares(res, np.zeros(prob.layout.n), jac=jac, method="trf",
                         x_scale="jac", tr_solver="exact" if dense else "lsmr")


def report(name, data, repeats, exclude=()):
    ours, _ = median_time(lambda: fit(data, "kinematic21", exclude=exclude), repeats)
    theirs, _ = median_time(lambda: peer(data, exclude), max(1, repeats // 3))
    tracemalloc.start()
    fit(data, "kinematic21", exclude=exclude)
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    r = fit(data, "kinematic21", exclude=exclude)
    p = peer(data, exclude)
    chi2_peer = float(p.fun @ p.fun)
    print(f"{name}: n_obs={r.n_obs}  median fit {ours * 1e3:.1f} ms  "
          f"least_squares {theirs * 1e3:.1f} ms  ratio {ours / theirs:.2f}  "
          f"peak memory {peak:.0f} MB  chi2 ours {r.chi2:.1f} vs peer {chi2_peer:.1f}")


if __name__ == "__main__":
    th = thesis_dataset()
    report("thesis six tables", th, 21, detect_outliers(th).exclusions)
    dense = simulate({"seed": 1, "repeats": 334}).dataset
    report("simulated dense", dense, 3)

"""Benchmark: kinematic fit on the six thesis tables, and on 10^5 and 10^6 simulated
observations.

For each dataset: the median wall time of ``cmm_core.model.fit`` and, in the same run, of
scipy.optimize.least_squares solving the same problem (same residuals, same analytic sparse
Jacobian, no constraints needed for the fixed-plate model), their ratio, the peak traced
memory of one fit (tracemalloc, which sees numpy's allocations) and both χ².

On 10^6 observations (issue 25: under 5 s and 400 MB) the least_squares peer would take
many minutes; the peer there is the floor of any Gauss-Newton fit of this model: one
pass of the forward model's Jacobian (``kinematics.jacobian``) over the same points, in
blocks of ``normal.ROWS``, times the number of Jacobian passes the fit made (one per
accumulation of the normal equations, ``normal.accumulate``, counted in the run; the
certificate's terms take theirs from the last one). Wall and CPU time are both printed,
with the load average: on a shared machine the wall time measures the neighbours too.

Then the forward model alone on the 10^5 points: ``kinematics.jacobian`` and
``kinematics.model_point`` against the previous implementation (batched (n, 3, 3) matrix
products, ``kinematics.py`` at commit ``PREVIOUS``, read with git: a self-contained module
of numpy only; skipped with a note where git or that commit is missing).

The large datasets are the default simulation with 100 repeats (30,000 rows, the
simulator's limit) tiled to 100,200 and 1,000,000 rows: the same problem structure (25
balls, 6 positions, 2 probes each) at that size.
Run: ``.venv/bin/python bench/fit.py`` (``--quick``: no least_squares peer on the 10^5
set, whose lsmr solve takes about a minute, and one repeat of the 10^6 fit).
"""

import argparse
import dataclasses
import importlib.util
import os
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _timing import median_time  # noqa: E402

from cmm_core.diagnosis import detect_outliers  # noqa: E402
from cmm_core.io import thesis_dataset  # noqa: E402
from cmm_core.machine import KinematicTerms  # noqa: E402
from cmm_core.machine import kinematics as kin  # noqa: E402
from cmm_core.model import ROWS, Problem, fit, parse_spec, select, simulate  # noqa: E402
from cmm_core.model import normal as normal_module  # noqa: E402

PREVIOUS = "08e52a4"  # last commit with the batched-matmul forward model
N_LARGE = 100_200
N_HUGE = 1_000_000


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


def peak_mb(f):
    tracemalloc.start()
    try:
        f()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def report(name, data, repeats, exclude=(), with_peer=True):
    fit(data, "kinematic21", exclude=exclude)  # warm-up: first-call page faults, imports
    ours, r = median_time(lambda: fit(data, "kinematic21", exclude=exclude), repeats)
    peak = peak_mb(lambda: fit(data, "kinematic21", exclude=exclude))
    line = f"{name}: n_obs={r.n_obs}  median fit {ours * 1e3:.1f} ms ({repeats} repeats)"
    if with_peer:
        theirs, p = median_time(lambda: peer(data, exclude), max(1, repeats // 3))
        line += (f"  least_squares {theirs * 1e3:.1f} ms  ratio ours/peer {ours / theirs:.2f}"
                 f"  chi2 ours {r.chi2:.1f} vs peer {float(p.fun @ p.fun):.1f}")
    print(line + f"  peak memory {peak:.0f} MB", flush=True)


def jacobian_pass(data):
    """Seconds of one pass of ``kinematics.jacobian`` over the observations of ``data``,
    in blocks of ``ROWS`` (what one accumulation of the normal equations must evaluate)."""
    obs = select(data)
    m = parse_spec("kinematic21")
    terms = KinematicTerms(m.active, tuple(obs.range_mm), m.periods)
    coef = np.random.default_rng(0).normal(0, 5, terms.n)
    x, p = obs.r_mm - obs.p_mm, obs.p_mm
    t = time.perf_counter()
    for lo in range(0, len(x), ROWS):
        kin.jacobian(terms, coef, x[lo:lo + ROWS], p[lo:lo + ROWS])
    return time.perf_counter() - t


def report_huge(data, repeats):
    """The 10^6-observation fit: time (wall and this process's CPU), peak memory, and the
    Jacobian-pass floor."""
    calls = []
    accumulate = normal_module.accumulate

    def counted(*a, **k):
        calls.append(1)
        return accumulate(*a, **k)

    cpu = []

    def timed():
        t = time.process_time()
        out = fit(data, "kinematic21")
        cpu.append(time.process_time() - t)
        return out

    ours, r = median_time(timed, repeats)
    normal_module.accumulate = counted  # the Problem looks it up in the module
    try:
        fit(data, "kinematic21")
    finally:
        normal_module.accumulate = accumulate
    t = time.process_time()
    floor = jacobian_pass(data) * len(calls)
    floor_cpu = (time.process_time() - t) * len(calls)
    peak = peak_mb(lambda: fit(data, "kinematic21"))
    print(f"simulated 10^6: n_obs={r.n_obs}  median fit {ours:.1f} s wall, "
          f"{np.median(cpu):.1f} s CPU ({repeats} repeats; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)  peak memory {peak:.0f} MB "
          f"(traced)  peer: {len(calls)} Jacobian passes of the forward model alone "
          f"{floor:.1f} s wall, {floor_cpu:.1f} s CPU  ratio ours/peer {ours / floor:.2f} "
          f"(CPU {np.median(cpu) / floor_cpu:.2f})", flush=True)


def large_dataset(n=N_LARGE):
    ds = simulate({"seed": 1, "repeats": 100}).dataset
    reps = -(-n // len(ds.meas))
    meas = pd.concat([ds.meas] * reps, ignore_index=True).iloc[:n]
    return dataclasses.replace(ds, meas=meas)


def previous_kinematics():
    """``kinematics.py`` at ``PREVIOUS`` as a module, or None without git."""
    try:
        src = subprocess.run(["git", "show", f"{PREVIOUS}:cmm_core/kinematics.py"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):  # no git, or a shallow clone
        return None
    spec = importlib.util.spec_from_loader("kinematics_previous", loader=None)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    exec(compile(src, "kinematics_previous.py", "exec"), mod.__dict__)
    return mod


def forward_model(data, repeats=5):
    old = previous_kinematics()
    if old is None:
        print(f"  git or commit {PREVIOUS} unavailable: previous implementation not "
              "compared")
        return
    obs = select(data)
    m = parse_spec("kinematic21")
    terms = KinematicTerms(m.active, tuple(obs.range_mm), m.periods)
    coef = np.random.default_rng(0).normal(0, 5, terms.n)
    x, p = obs.r_mm - obs.p_mm, obs.p_mm
    for label, fn in (("jacobian", "jacobian"), ("model_point", "model_point")):
        getattr(kin, fn)(terms, coef, x, p)
        getattr(old, fn)(terms, coef, x, p)
        t_new, a = median_time(lambda f=fn: getattr(kin, f)(terms, coef, x, p), repeats)
        t_old, b = median_time(lambda f=fn: getattr(old, f)(terms, coef, x, p), repeats)
        if fn == "jacobian":
            diff = (f"max |Δx*| {np.abs(a[0] - b[0]).max():.1e} mm, "
                    f"max |ΔJ| {np.abs(a[1] - b[1]).max():.1e}")
        else:
            diff = f"max |Δx*| {np.abs(a - b).max():.1e} mm"
        print(f"  {label:<12} n={len(x)}  ours {t_new * 1e3:.1f} ms  previous "
              f"{t_old * 1e3:.1f} ms  speed-up {t_old / t_new:.2f}×  {diff}", flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="no least_squares peer on the 10^5-observation set, one repeat of "
                         "the 10^6 fit")
    args = ap.parse_args()
    th = thesis_dataset()
    report("thesis six tables", th, 21, detect_outliers(th).exclusions)
    big = large_dataset()
    report("simulated 10^5", big, 3, with_peer=not args.quick)
    print("forward model on the 10^5 points, kinematic21 order 2:")
    forward_model(big)
    del big
    report_huge(large_dataset(N_HUGE), 1 if args.quick else 3)

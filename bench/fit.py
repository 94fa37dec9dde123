"""Benchmark: kinematic fit on the six thesis tables and on 10^5 simulated observations.

For each dataset: the median wall time of ``cmm_core.fit.fit`` and, in the same run, of
scipy.optimize.least_squares solving the same problem (same residuals, same analytic sparse
Jacobian, no constraints needed for the fixed-plate model), their ratio, the peak traced
memory of one fit (tracemalloc, which sees numpy's allocations) and both χ².

Beside it, the same fit by the previous ``fit.py`` (commit ``PREVIOUS_FIT``, read with git
and loaded as a module of the package: it built the sparse J and multiplied it out, where
the fit now accumulates the normal equations block by block of observations), with its
time, peak memory and the largest parameter difference (relative to the parameter and to
its uncertainty).

Then the forward model alone on the 10^5 points: ``kinematics.jacobian`` and
``kinematics.model_point`` against the previous implementation (batched (n, 3, 3) matrix
products, ``kinematics.py`` at commit ``PREVIOUS``, read with git), with the largest
difference of their results.

The 10^5-observation dataset is the default simulation with 100 repeats (30,000 rows, the
simulator's limit) tiled to 100,200 rows, the size of the issue-18 figure (334 repeats):
the same problem structure (25 balls, 6 positions, 2 probes each) at that size.
Run: ``.venv/bin/python bench/fit.py`` (``--quick`` skips the least_squares peer on the
large set, whose lsmr solve takes about a minute).
"""

import argparse
import dataclasses
import importlib.util
import subprocess
import sys
import tracemalloc
import types
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _timing import median_time  # noqa: E402

from cmm_core.diagnosis import detect_outliers  # noqa: E402
from cmm_core.io import thesis_dataset  # noqa: E402
from cmm_core.machine import kinematics as kin  # noqa: E402
from cmm_core.model import Problem, fit, parse_spec, select, simulate  # noqa: E402

PREVIOUS = "08e52a4"  # last commit with the batched-matmul forward model
PREVIOUS_FIT = "718abca"  # last commit whose fit formed the sparse Jacobian
N_LARGE = 100_200


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


def with_previous_kinematics(old, f):
    """``f()`` with every cmm_core module's ``kin`` swapped for the previous kinematics
    (which knows only the moving bridge FXYZ: the layout argument is dropped)."""
    mods = [m for k, m in list(sys.modules.items())
            if k.startswith("cmm_core") and getattr(m, "kin", None) is kin]
    shim = types.ModuleType("kinematics_previous_shim")
    shim.__dict__.update(old.__dict__)

    def terms(orders, range_mm, periods=(), layout=kin.DEFAULT_LAYOUT):
        if layout != kin.DEFAULT_LAYOUT:
            raise ValueError(f"the previous kinematics has no layout {layout!r}")
        return old.KinematicTerms(orders, range_mm, periods)

    shim.KinematicTerms = terms
    for m in mods:
        m.kin = shim
    try:
        return f()
    finally:
        for m in mods:
            m.kin = kin


def previous_fit():
    """``fit.py`` at ``PREVIOUS_FIT`` as a module of the package, or None without git."""
    try:
        src = subprocess.run(["git", "show", f"{PREVIOUS_FIT}:cmm_core/fit.py"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    spec = importlib.util.spec_from_loader("cmm_core._fit_previous", loader=None)
    mod = importlib.util.module_from_spec(spec)
    mod.__package__ = "cmm_core"
    sys.modules[spec.name] = mod
    exec(compile(src, "fit_previous.py", "exec"), mod.__dict__)
    return mod


def peak_mb(f):
    tracemalloc.start()
    try:
        f()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def compare_previous(data, repeats, exclude, ours, r, peak):
    prev = previous_fit()
    if prev is None:
        print("  previous fit.py: git unavailable, not compared")
        return
    t_prev, p = median_time(lambda: prev.fit(data, "kinematic21", exclude=exclude), repeats)
    peak_prev = peak_mb(lambda: prev.fit(data, "kinematic21", exclude=exclude))
    dv = np.abs(r.values - p.values)
    rel = float(np.max(dv / np.maximum(np.abs(p.values), 1e-300)))
    rel_u = float(np.nanmax(dv / p.u))
    print(f"  same fit by the previous fit.py ({PREVIOUS_FIT}): {t_prev * 1e3:.1f} ms, ratio "
          f"ours/previous {ours / t_prev:.2f}, peak memory {peak_prev:.0f} MB (ours {peak:.0f}),"
          f" largest parameter difference {rel:.1e} relative, {rel_u:.1e} of its u; chi2 "
          f"{p.chi2:.1f} vs ours {r.chi2:.1f}; iterations {p.iterations} vs {r.iterations}",
          flush=True)


def report(name, data, repeats, exclude=(), with_peer=True, old=None):
    fit(data, "kinematic21", exclude=exclude)  # warm-up: first-call page faults, imports
    ours, r = median_time(lambda: fit(data, "kinematic21", exclude=exclude), repeats)
    peak = peak_mb(lambda: fit(data, "kinematic21", exclude=exclude))
    line = f"{name}: n_obs={r.n_obs}  median fit {ours * 1e3:.1f} ms ({repeats} repeats)"
    if with_peer:
        theirs, p = median_time(lambda: peer(data, exclude), max(1, repeats // 3))
        line += (f"  least_squares {theirs * 1e3:.1f} ms  ratio ours/peer {ours / theirs:.2f}"
                 f"  chi2 ours {r.chi2:.1f} vs peer {float(p.fun @ p.fun):.1f}")
    print(line + f"  peak memory {peak:.0f} MB", flush=True)
    compare_previous(data, repeats, exclude, ours, r, peak)
    if old is not None:
        t_old, r_old = with_previous_kinematics(old, lambda: median_time(
            lambda: fit(data, "kinematic21", exclude=exclude), repeats))
        print(f"  same fit with the previous kinematics ({PREVIOUS}): {t_old * 1e3:.1f} ms, "
              f"ratio ours/previous {ours / t_old:.2f}, chi2 {r_old.chi2:.1f}", flush=True)


def large_dataset():
    ds = simulate({"seed": 1, "repeats": 100}).dataset
    reps = -(-N_LARGE // len(ds.meas))
    meas = pd.concat([ds.meas] * reps, ignore_index=True).iloc[:N_LARGE]
    return dataclasses.replace(ds, meas=meas)


def previous_kinematics():
    """``kinematics.py`` at ``PREVIOUS`` as a module, or None without git."""
    try:
        src = subprocess.run(["git", "show", f"{PREVIOUS}:cmm_core/kinematics.py"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    spec = importlib.util.spec_from_loader("kinematics_previous", loader=None)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    exec(compile(src, "kinematics_previous.py", "exec"), mod.__dict__)
    return mod


def forward_model(data, repeats=5):
    old = previous_kinematics()
    if old is None:
        print("forward model: git unavailable, previous implementation not compared")
        return
    obs = select(data)
    m = parse_spec("kinematic21")
    terms = kin.KinematicTerms(m.active, tuple(obs.range_mm), m.periods)
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
                    help="no least_squares peer on the 10^5-observation set")
    args = ap.parse_args()
    prev = previous_kinematics()
    th = thesis_dataset()
    report("thesis six tables", th, 21, detect_outliers(th).exclusions, old=prev)
    big = large_dataset()
    report("simulated 10^5", big, 3, with_peer=not args.quick, old=prev)
    print("forward model on the 10^5 points, kinematic21 order 2:")
    forward_model(big)

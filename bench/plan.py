"""Benchmark and Monte Carlo check of measurement planning (issue 14).

Prints, in one run:

1. the median wall time of ``plan.evaluate`` for the thesis layout (six placements,
   detection limits of every catalogue effect included) and, as its peer, of one fit of
   simulated data of the same plan (``model.fit``), with their ratio;
2. the throughput (simulated data sets fitted per second) of a planning study run on a
   ``dask.distributed`` LocalCluster (2 worker processes) against the same tasks in a
   serial loop, with their ratio;
3. the Monte Carlo check of the detection limits: for each effect, the predicted size,
   the observed detection rate over N data sets with the effect at that size (expected
   0.8), its binomial standard error, and whether it lies in 0.8 ± 0.04; plus the
   observed mean χ² reduction against its prediction c1·k + λ (c1: a fixed certificate's
   inflation, ``plan.detect.cert_scales``); and the observed U2/U3
   against the predicted ones.

Run: ``.venv/bin/python bench/plan.py [--trials N] [--study-tasks M]`` (defaults 300 and
40; the check then takes several minutes on two cores); ``--detection-only`` runs item 3
alone (``--serial``: in one process, on one core).
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from _timing import median_time  # noqa: E402

from cmm_core.plan import (  # noqa: E402
    dask_client,
    evaluate,
    fit_plan_data,
    read_plan,
    run_serial,
    run_tasks,
    simulate_plan,
    summarise,
    tasks_for,
)

EFFECTS = ("plate_sag", "dzz:3", "rxy:3", "plate_thermal", "backlash", "dyy:3")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=300,
                    help="data sets per effect in the detection check (default 300)")
    ap.add_argument("--study-tasks", type=int, default=40,
                    help="tasks of the throughput comparison (default 40)")
    ap.add_argument("--repeats", type=int, default=7, help="timing repeats (default 7)")
    ap.add_argument("--detection-only", action="store_true",
                    help="only the Monte Carlo check of the detection limits (item 3)")
    ap.add_argument("--serial", action="store_true",
                    help="with --detection-only: one process instead of a Dask cluster")
    args = ap.parse_args(argv)
    plans = {p.name: p for p in read_plan(ROOT / "sample_data/plans/thesis_plan.json")
             .strategies}
    six = plans["thesis (all six)"]
    if args.detection_only:
        ev = evaluate(six)
        tasks = [t for t in tasks_for([ev], args.trials, list(EFFECTS)) if t.limit is not None]
        t0 = time.perf_counter()
        if args.serial:
            recs = run_serial(tasks, progress=_every(0.1))
        else:
            with dask_client(workers=2) as client:
                recs = run_tasks(tasks, client=client, progress=_every(0.1))
        print(f"3. Monte Carlo check: {len(tasks)} data sets in "
              f"{time.perf_counter() - t0:.0f} s")
        _detection_table(summarise([ev], tasks, recs).to_dict()["plans"][0])
        return

    t_eval, ev = median_time(lambda: evaluate(six), args.repeats)
    t_loc0, _ = median_time(lambda: evaluate(plans["location 0"]), args.repeats)
    data = simulate_plan(six, seed=1, noise_um=six.noise_um, prior=True)
    t_fit, _ = median_time(lambda: fit_plan_data(six, data), args.repeats)
    print("1. Plan evaluation (thesis layout, 150 probings, detection limits of "
          f"{len(ev.detection_limits)} effects)")
    print(f"   evaluate(all six):        median {t_eval * 1e3:7.1f} ms  (issue: < 500 ms)")
    print(f"   evaluate(location 0):     median {t_loc0 * 1e3:7.1f} ms")
    print(f"   peer, fit of its data:    median {t_fit * 1e3:7.1f} ms  "
          f"ratio evaluate/fit {t_eval / t_fit:.2f}")

    tasks = tasks_for([ev], args.study_tasks // 2, ["plate_sag"])
    with dask_client(workers=2) as client:
        run_tasks(tasks[:4], client=client)  # warm the workers (imports)
        t0 = time.perf_counter()
        run_tasks(tasks, client=client)
        t_dask = time.perf_counter() - t0
        t0 = time.perf_counter()
        run_serial(tasks)
        t_ser = time.perf_counter() - t0
        print(f"\n2. Study throughput ({len(tasks)} simulated data sets fitted)")
        print(f"   Dask LocalCluster, 2 processes: {len(tasks) / t_dask:6.2f} per s")
        print(f"   serial loop:                    {len(tasks) / t_ser:6.2f} per s  "
              f"ratio Dask/serial {t_ser / t_dask:.2f}")

        tasks = tasks_for([ev], args.trials, list(EFFECTS))
        t0 = time.perf_counter()
        recs = run_tasks(tasks, client=client, progress=_every(0.1))
        print(f"\n3. Monte Carlo check: {len(tasks)} data sets in "
              f"{time.perf_counter() - t0:.0f} s")
    s = summarise([ev], tasks, recs).to_dict()["plans"][0]
    print(f"   U2/U3 over {s['trials']} data sets: largest relative difference from the "
          f"prediction {s['max_relative_difference']:.1e}; RMS of normalised coefficient "
          f"errors {s['z_rms']:.3f}")
    _detection_table(s)


def _detection_table(s):
    """Item 3's table: per effect the limit, the observed rate with its standard error,
    whether it is in 0.8 ± 0.04, and the mean Δχ² against c1·k + λ."""
    print(f"   {'effect':15s} {'limit':>9s} {'unit':8s} {'rate':>6s} {'±SE':>6s}  in 0.8±0.04"
          f"  {'mean Δχ²':>9s} {'c1·k+λ':>7s}")
    for eff, d in s["detection"].items():
        ok = abs(d["rate"] - 0.8) <= 0.04  # issue 26: 80 ± 4 % at the stated limit
        print(f"   {eff:15s} {d['size']:9.3g} {d['unit']:8s} {d['rate']:6.3f} "
              f"{np.sqrt(d['rate'] * (1 - d['rate']) / d['trials']):6.3f}  "
              f"{'yes' if ok else 'NO':>11s}  {d['mean_delta_chi2']:9.2f} "
              f"{d['expected_delta_chi2']:7.2f}")


def _every(step):
    state = {"next": step}

    def cb(frac, text):
        if frac >= state["next"] or frac == 1.0:
            print(f"   [{100 * frac:3.0f} %] {text}", file=sys.stderr, flush=True)
            state["next"] = frac + step

    return cb


if __name__ == "__main__":
    main()

"""Interim checks on simulated machines whose truth is known (issue 28).

For each layout of ``tests/scenarios.py`` and each seed: a calibration is simulated and
fitted (kinematic21, plate fixed to its certificate), saved as a model, and the same
machine is measured again (new noise, new certificate draw) and checked against it:

- no change, the full plate: the χ² test's false-alarm rate (stated level ``--alpha``)
  and the coverage of the residuals' 95 % intervals;
- a squareness step of ``--step`` u (u of ``sxy`` in the stored model) after a crash,
  with the full plate and with one placement (the layout's first): the power.

With ``--oracle`` each unchanged check is also made against the machine's *true*
coefficients (the stored model replaced by the truth, its covariance by ~0): the same new
data, so the two rates differ only by what the stored model's uncertainty adds; an excess
the oracle shares lies in the new data, not in the model's covariance. ``--first-seed``
runs another block of seeds (disjoint seed sets pool into larger counts).

Rates are printed with their binomial standard errors. With ``--timing``: the median
time of the check's GLS step (``gls_fit``: Cholesky of the dense covariance) with one BLAS
thread, beside the same function with the default threads in the same run. Usage:
``python bench/monitor.py [--seeds N] [--first-seed S] [--layouts a,b] [--step 3]
[--plate fixed|free] [--oracle] [--timing]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import scenarios as sc  # noqa: E402

from cmm_core.export import model_from_result  # noqa: E402
from cmm_core.model import fit  # noqa: E402
from cmm_core.monitor import check_system, gls_fit, interim_check, remeasured  # noqa: E402


def one_seed(layout: str, seed: int, step_u: float, alpha: float, label: str = "sxy",
             plate: str = "fixed", oracle: bool = False):
    """(rejects when unchanged, coverage, rejects after the step with the full plate, with
    one placement[, the oracle's rejects when unchanged]) for one seed; the calibration
    fitted with ``plate`` (fixed to its certificate, or free: self-calibrated)."""
    cal = sc.simulated(layout, seed)
    model = model_from_result(fit(cal.dataset, "kinematic21", plate=plate))
    j = model.terms.labels.index(label)
    step = {label: step_u * float(np.sqrt(model.cov[j, j]))}
    ppp = cal.config["probes_per_position"]
    first = str(cal.dataset.positions[0])
    new = remeasured(cal, 10_000 + seed).dataset
    same = interim_check(model, new, alpha=alpha)
    full = interim_check(model, remeasured(cal, 20_000 + seed, changes=step).dataset,
                         alpha=alpha)
    single = interim_check(model, remeasured(cal, 30_000 + seed, changes=step,
                                             probes_per_position={first: ppp[first]}).dataset,
                           alpha=alpha)
    out = (not same.passes, same.coverage_95, not full.passes, not single.passes)
    if oracle:
        truth = np.array([cal.truth[lab] for lab in model.terms.labels])
        exact = dataclasses.replace(model, coef=truth, cov=model.cov * 1e-8)
        out += (not interim_check(exact, new, alpha=alpha).passes,)
    return out


def timing(layout: str, repeats: int = 21) -> None:
    """Median wall and CPU time of ``gls_fit`` with one BLAS thread and with the default
    threads (its undecorated function), on one check of ``layout``."""
    cal = sc.simulated(layout, 0)
    model = model_from_result(fit(cal.dataset, "kinematic21", plate="fixed"))
    system = check_system(model, remeasured(cal, 1).dataset)
    for name, fn in (("one BLAS thread", gls_fit), ("default threads", inspect.unwrap(gls_fit))):
        wall, cpu = [], []
        for _ in range(repeats):
            t, c = time.perf_counter(), time.process_time()
            fn(system)
            wall.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
        print(f"{layout} gls_fit ({3 * len(system.obs.r_mm)} rows), {name}: median "
              f"{1e3 * statistics.median(wall):.1f} ms wall, "
              f"{1e3 * statistics.median(cpu):.1f} ms CPU")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=400, help="seeds per layout")
    ap.add_argument("--first-seed", type=int, default=0, help="first seed (default 0)")
    ap.add_argument("--oracle", action="store_true",
                    help="also check the same new data against the true coefficients")
    ap.add_argument("--layouts", default="pitch100_4pos,pitch80_3pos",
                    help="comma-separated layouts of tests/scenarios.py")
    ap.add_argument("--step", type=float, default=3.0, help="squareness step in u of sxy")
    ap.add_argument("--alpha", type=float, default=0.05, help="the χ² test's level")
    ap.add_argument("--plate", choices=("fixed", "free"), default="fixed",
                    help="plate mode of the calibrations' fits")
    ap.add_argument("--timing", action="store_true",
                    help="time the GLS step only (one BLAS thread beside the default)")
    args = ap.parse_args()
    if args.timing:
        for layout in args.layouts.split(","):
            timing(layout)
        return
    for layout in args.layouts.split(","):
        t0 = time.perf_counter()
        seeds = range(args.first_seed, args.first_seed + args.seeds)
        rows = np.array([one_seed(layout, s, args.step, args.alpha, plate=args.plate,
                                  oracle=args.oracle) for s in seeds], float)
        n = len(rows)
        fa, cov, pf, p1 = rows.mean(axis=0)[:4]

        se = np.sqrt(rows.mean(axis=0) * (1 - rows.mean(axis=0)) / n)
        print(f"{layout} (calibration plate {args.plate}): {n} seeds "
              f"({seeds.start}-{seeds.stop - 1}), "
              f"{time.perf_counter() - t0:.0f} s")
        print(f"  false alarms (no change)      {100 * fa:5.1f} % ± {100 * se[0]:.1f} "
              f"(stated {100 * args.alpha:g} %)")
        print(f"  coverage of 95 % intervals    {100 * cov:5.2f} % (mean over seeds, "
              f"sd of the mean {100 * rows[:, 1].std(ddof=1) / np.sqrt(n):.2f})")
        print(f"  power, sxy + {args.step:g} u, full plate  {100 * pf:5.1f} % ± {100 * se[2]:.1f}")
        print(f"  power, sxy + {args.step:g} u, one placement {100 * p1:5.1f} % ± "
              f"{100 * se[3]:.1f}")
        if args.oracle:
            print(f"  false alarms, true coefficients {100 * rows[:, 4].mean():5.1f} % ± "
                  f"{100 * se[4]:.1f} (the same new data)")


if __name__ == "__main__":
    main()

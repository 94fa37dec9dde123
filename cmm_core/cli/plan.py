"""Command-line front ends of ``plan`` and ``task`` (registered in ``cli``).

Each ``add_*_arguments`` adds the options of one sub-command; each ``run_*`` returns the
JSON-ready result (``cli.main`` prints it and turns errors into one line on stderr).
"""

from __future__ import annotations

import argparse
import sys

from ..export import load_model
from ..io import DataError
from ..plan import check_plans, design_from_file, evaluate, read_plan, read_task, task_uncertainty
from .inputs import number_arg


def _progress(frac: float, text: str) -> None:
    """Progress on stderr (one line per step, stdout stays JSON)."""
    print(f"[{100 * frac:5.1f} %] {text}", file=sys.stderr, flush=True)


MAX_TRIALS = 10**7
"""Most Monte Carlo trials of ``task --trials`` (the task file's ``trials`` has the same
range, from :data:`MIN_TRIALS`)."""
MIN_TRIALS = 100
MAX_CHECK_TRIALS = 10**5
"""Most simulated data sets per strategy of ``plan --check-trials``."""
MAX_WORKERS = 1024
"""Most local Dask workers of ``plan --workers``."""


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``plan``."""
    p.add_argument("plan", metavar="PLAN.json",
                   help="measurement plan: setup (machine, placements, styli offsets in mm), "
                        "plate (rows, cols, pitch_mm, certificate_u_um in µm), model, "
                        "noise_um (µm), measurement order and timing (minutes), strategies "
                        "to compare and an optional design section (docs/planning.md; "
                        "example: sample_data/plans/thesis_plan.json); required")
    p.add_argument("--no-detection", action="store_true",
                   help="skip the detection limits of the catalogue effects (default: "
                        "computed for every effect the diagnosis would try)")
    p.add_argument("--check-trials", type=number_arg(int, 0, MAX_CHECK_TRIALS), default=0,
                   metavar="N",
                   help="Monte Carlo check of each strategy (and of the designed plan): "
                        "simulate N data sets with noise and the prior errors, run the real "
                        "fit and the diagnosis's tests, and compare the observed U2/U3 and "
                        "detection rates with the predictions; runs on Dask; 0 to "
                        f"{MAX_CHECK_TRIALS} (default: %(default)s, no check)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="Dask scheduler address for the Monte Carlo check, e.g. "
                        "tcp://10.0.0.5:8786 (default: a local cluster of --workers "
                        "processes on this machine)")
    p.add_argument("--workers", type=number_arg(int, 1, MAX_WORKERS), default=2, metavar="N",
                   help="workers of the local Dask cluster when no --scheduler is given, "
                        f"1 to {MAX_WORKERS} (default: %(default)s)")


def run_plan(args: argparse.Namespace) -> dict:
    """``plan``: evaluate every strategy; design and check when asked."""

    pf = read_plan(args.plan)
    evals = [evaluate(p, detection=not args.no_detection) for p in pf.strategies]
    out: dict = {"strategies": [e.to_dict() for e in evals]}
    if pf.design is not None:

        try:
            d = design_from_file(pf)
        except DataError:
            raise
        except ValueError as exc:  # the target or pool the design cannot work with
            raise DataError(str(exc), file=pf.name, column="design") from None
        out["design"] = d.to_dict()
        evals.append(d.evaluation)
    if args.check_trials:

        out["check"] = check_plans(evals, trials=args.check_trials, scheduler=args.scheduler,
                                   workers=args.workers, progress=_progress).to_dict()
    return out


def add_task_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``task``."""
    p.add_argument("model", metavar="MODEL.json",
                   help="fitted model written by 'fit --save' (kinematic coefficients and "
                        "their covariance, styli offsets in mm); required")
    p.add_argument("task", metavar="TASK.json",
                   help="measurement task: 'distance', 'circle' or 'plane', its points "
                        "(reported tip centres x_mm, y_mm, z_mm in mm, machine frame, with "
                        "the stylus) and the influences (probing noise in µm, workpiece "
                        "temperature in °C, optional discrepancy); docs/planning.md, "
                        "example: sample_data/plans/task_distance.json; required")
    p.add_argument("--trials", type=number_arg(int, MIN_TRIALS, MAX_TRIALS), default=None,
                   metavar="N",
                   help=f"Monte Carlo trials (JCGM 101), {MIN_TRIALS} to {MAX_TRIALS}, "
                        "overriding the task file's 'trials' (default: the task file's "
                        "value, else 20000)")


def run_task(args: argparse.Namespace) -> dict:
    """``task``: task-specific uncertainty of a measurement with the fitted machine."""

    model = load_model(args.model)
    task = read_task(args.task)
    trials = args.trials
    if trials is not None and not MIN_TRIALS <= trials <= MAX_TRIALS:  # called without argparse
        raise DataError(f"--trials: expected {MIN_TRIALS} to {MAX_TRIALS}, found {trials}.",
                        file="command line")
    return task_uncertainty(model, task, trials=trials).to_dict()

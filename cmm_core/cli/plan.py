"""Command-line front ends of ``plan`` and ``task`` (registered, with their options, in
:mod:`.parser`).

Each ``run_*`` returns the JSON-ready result (``cli.main`` prints it and turns errors into
one line on stderr).
"""

from __future__ import annotations

import argparse
import sys

from ..export import load_model
from ..io import DataError
from ..plan import check_plans, design_from_file, evaluate, read_plan, read_task, task_uncertainty
from .parser import MAX_TRIALS, MIN_TRIALS


def _progress(frac: float, text: str) -> None:
    """Progress on stderr (one line per step, stdout stays JSON)."""
    print(f"[{100 * frac:5.1f} %] {text}", file=sys.stderr, flush=True)


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


def run_task(args: argparse.Namespace) -> dict:
    """``task``: task-specific uncertainty of a measurement with the fitted machine."""

    model = load_model(args.model)
    task = read_task(args.task)
    trials = args.trials
    if trials is not None and not MIN_TRIALS <= trials <= MAX_TRIALS:  # called without argparse
        raise DataError(f"--trials: expected {MIN_TRIALS} to {MAX_TRIALS}, found {trials}.",
                        file="command line")
    return task_uncertainty(model, task, trials=trials).to_dict()


def cmd_plan(args: argparse.Namespace) -> dict:
    return run_plan(args)


def cmd_task(args: argparse.Namespace) -> dict:
    return run_task(args)

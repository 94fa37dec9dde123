"""Planning studies on Dask: Monte Carlo checks of plan predictions over many plans.

A study checks what ``plan.evaluate`` predicts from the design alone against what the
real fit and the diagnosis's tests deliver on simulated data (JCGM 101 §7: propagation
of distributions by simulation; ISO/TS 15530-4: simulation-based evaluation). Each task
simulates one data set of one plan on the virtual CMM (noise σ, kinematic errors drawn
from the plan's prior sizes) and fits the plan's model:

- a *clean* task returns the fit's U2/U3 (``uncertainty.evaluate``) and the normalised
  errors ``z = (estimate − truth) / u`` of the kinematic coefficients;
- an *effect* task hides one catalogue effect at its predicted detection limit and runs
  the diagnosis's test of it (``detect.detection_trial``).

Tasks are independent, so they are mapped over a ``dask.distributed`` cluster: a
``LocalCluster`` by default, or any scheduler address. Summaries: observed against
predicted U2/U3, the RMS of z (1 when the predicted uncertainties hold), and each
effect's detection rate with its binomial standard error (80 % expected).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .._blas import single_blas_thread
from ..model import BY_TOKEN
from ..model import evaluate as evaluate_u
from .detect import DetectionLimit, detection_trial
from .plans import Plan, fit_plan_data, simulate_plan

if TYPE_CHECKING:
    from .evaluation import PlanEvaluation

_Progress = Callable[[float, str], object] | None
"""``progress(fraction, text)``, called as tasks complete (None: silent)."""

PHYSICAL_CHECKS = tuple(t for t, b in BY_TOKEN.items() if b.physical_check)
"""Effects checked by default (those whose limit is finite for the plan): the blocks with
``physical_check`` (``blocks.REGISTRY`` order)."""


@dataclass(frozen=True)
class StudyTask:
    """One simulated data set of one plan.

    Attributes
    ----------
    plan : Plan
    seed : int
        Seed of the simulation (noise, prior errors).
    limit : detect.DetectionLimit or None
        The effect hidden at its detection limit; None for a clean task.
    plan_index : int
        Index of the plan in the study (for the summaries).
    """

    plan: Plan
    seed: int
    limit: DetectionLimit | None = None
    plan_index: int = 0


@single_blas_thread
def run_task(task: StudyTask) -> dict:
    """Run one study task (module docstring); returns a small picklable record."""
    plan = task.plan
    if task.limit is not None:
        detected, p, dchi2 = detection_trial(plan, task.limit, task.limit.size, task.seed)
        return {"plan": task.plan_index, "effect": task.limit.effect, "detected": detected,
                "p_value": p, "delta_chi2": dchi2}
    sim_data, truth = simulate_plan(plan, seed=task.seed, noise_um=plan.noise_um,
                                    prior=True, with_truth=True)
    r = fit_plan_data(plan, sim_data)
    u = evaluate_u(r, seed=plan.seed)
    kin = r.terms.labels
    est = dict(zip(r.labels, r.values, strict=True))
    unc = dict(zip(r.labels, r.u, strict=True))
    z = [(est[lab] - truth[lab]) / unc[lab] for lab in kin
         if np.isfinite(unc[lab]) and unc[lab] > 0]
    return {"plan": task.plan_index, "effect": None, "U2_um": u.U2_um, "U3_um": u.U3_um,
            "z": z, "chi2_p": r.chi2_p_value}


def tasks_for(evals: Sequence[PlanEvaluation], trials: int,
              effects: Sequence[str] | None = None, seed0: int = 1000) -> list[StudyTask]:
    """The tasks of a study: ``trials`` clean data sets per plan and ``trials`` per effect
    checked (``effects``: tokens or families; default the physical effects whose limit
    is finite for the plan)."""
    out = []
    for i, ev in enumerate(evals):
        plan = ev.plan
        if plan is None:
            raise ValueError(f"the evaluation {ev.name!r} keeps no plan to simulate; "
                             "evaluate the plan again (plan.evaluate).")
        out += [StudyTask(plan, seed0 + s, None, i) for s in range(trials)]
        for lim in ev.detection_limits.values():
            wanted = (lim.family in PHYSICAL_CHECKS if effects is None
                      else lim.effect in effects or lim.family in effects)
            if wanted and np.isfinite(lim.size):
                out += [StudyTask(plan, seed0 + 10**6 + s, lim, i) for s in range(trials)]
    return out


@contextmanager
def dask_client(scheduler: str | None = None, workers: int = 2, processes: bool = True
                ) -> Iterator[Any]:
    """A ``dask.distributed`` client: on the scheduler at ``scheduler`` (an address such
    as ``tcp://host:8786``), or on a new ``LocalCluster`` of ``workers`` single-threaded
    workers (processes by default; threads with ``processes=False``)."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        client = Client(scheduler)
        try:
            yield client
        finally:
            client.close()
        return
    with LocalCluster(n_workers=max(workers, 1), threads_per_worker=1, processes=processes,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        yield client


def run_tasks(tasks: Sequence[StudyTask], *, client: Any = None, scheduler: str | None = None,
              workers: int = 2, progress: _Progress = None, processes: bool = True) -> list:
    """Run tasks on Dask (``client``, else a scheduler address or a local cluster), in
    completion order with ``progress(fraction, text)`` after each; returns the records in
    task order. An exception raised by ``progress`` (a changed input in the app) cancels
    the remaining tasks."""
    from dask.distributed import as_completed

    def go(c):
        futures = c.map(run_task, tasks, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        out = [None] * len(tasks)
        try:
            for done, fut in enumerate(as_completed(futures), 1):
                out[index[fut.key]] = fut.result()
                if progress is not None:
                    progress(done / len(tasks), f"Monte Carlo: {done}/{len(tasks)} "
                             "simulated data sets fitted")
        except BaseException:
            c.cancel(futures)
            raise
        return out

    if client is not None:
        return go(client)
    with dask_client(scheduler, workers, processes) as c:
        return go(c)


def run_serial(tasks: Sequence[StudyTask], progress: _Progress = None) -> list:
    """The same tasks in a plain loop (the benchmark's peer)."""
    out = []
    for i, t in enumerate(tasks, 1):
        out.append(run_task(t))
        if progress is not None:
            progress(i / len(tasks), f"{i}/{len(tasks)}")
    return out


@dataclass(frozen=True)
class StudyResult:
    """Monte Carlo check of plan predictions.

    Attributes
    ----------
    plans : list of dict
        Per plan: ``name``, ``trials``, predicted and observed (mean) U2/U3 per axis (µm)
        with the largest relative difference, ``z_rms`` (RMS of the normalised
        coefficient errors; 1 when the predicted uncertainties hold) with its standard
        error, and ``detection``: per effect, the predicted size and unit, the observed
        rate, its binomial standard error and the expected 0.8.
    n_tasks : int
        Simulated data sets fitted.
    """

    plans: list
    n_tasks: int

    def to_dict(self) -> dict:
        """JSON-ready record."""
        return {"plans": self.plans, "n_tasks": self.n_tasks}


def summarise(evals: Sequence[PlanEvaluation], tasks: Sequence[StudyTask],
              records: Sequence[dict]) -> StudyResult:
    """Observed against predicted, per plan (see :class:`StudyResult`)."""
    out = []
    for i, ev in enumerate(evals):
        clean = [r for r in records if r["plan"] == i and r["effect"] is None]
        rec = {"name": ev.name, "trials": len(clean)}
        if clean and ev.U2_um is not None and ev.U3_um is not None \
                and clean[0]["U2_um"] is not None:
            obs2 = {a: float(np.mean([r["U2_um"][a] for r in clean])) for a in "xyz"}
            obs3 = {a: float(np.mean([r["U3_um"][a] for r in clean])) for a in "xyz"}
            rel = max(abs(obs2[a] / ev.U2_um[a] - 1) for a in "xyz")
            rel = max(rel, max(abs(obs3[a] / ev.U3_um[a] - 1) for a in "xyz"))
            z = np.concatenate([r["z"] for r in clean])
            rec.update({"U2_um": {"predicted": ev.U2_um, "observed": obs2},
                        "U3_um": {"predicted": ev.U3_um, "observed": obs3},
                        "max_relative_difference": float(rel),
                        "z_rms": float(np.sqrt(np.mean(z ** 2))),
                        # sd of RMS(z) over n normal values ~ 1/sqrt(2n) (correlated z's:
                        # an underestimate; a guide only)
                        "z_rms_se": float(1 / np.sqrt(2 * len(z)))})
        det = {}
        for lim in ev.detection_limits.values():
            rs = [r for r in records if r["plan"] == i and r["effect"] == lim.effect]
            if rs:
                rate = float(np.mean([r["detected"] for r in rs]))
                det[lim.effect] = {"size": lim.size, "unit": lim.unit, "trials": len(rs),
                                   "rate": rate, "se": float(np.sqrt(0.8 * 0.2 / len(rs))),
                                   "expected": 0.8,
                                   "mean_delta_chi2": float(np.mean([r["delta_chi2"]
                                                                     for r in rs])),
                                   "expected_delta_chi2": float(
                                       lim.numerator_scale * lim.n_params + lim.size ** 2
                                       * lim.noncentrality_per_unit2)}
        rec["detection"] = det
        out.append(rec)
    return StudyResult(out, len(records))


def check_plans(evals: Sequence[PlanEvaluation], *, trials: int,
                effects: Sequence[str] | None = None, scheduler: str | None = None,
                workers: int = 2, progress: _Progress = None, client: Any = None,
                processes: bool = True) -> StudyResult:
    """Monte Carlo check of the plans' predictions on Dask (module docstring)."""
    tasks = tasks_for(evals, trials, effects)
    records = run_tasks(tasks, client=client, scheduler=scheduler, workers=workers,
                        progress=progress, processes=processes)
    return summarise(evals, tasks, records)

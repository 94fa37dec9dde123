"""Plan before you measure: evaluate, design and check measurement plans from their design
alone, and the task-specific uncertainty of a measurement (``docs/planning.md``).

Owns: :mod:`.plans` (:class:`Plan`, its simulated data and fit), :mod:`.evaluation`
(:func:`evaluate`), :mod:`.detect` (detection limits), :mod:`.designer` (cheapest plan),
:mod:`.study` (Monte Carlo checks, Dask), :mod:`.files` (plan JSON), :mod:`.task`,
``proposals/`` (measure next: candidates, appending, rivals, separation, ranking, outcomes).
May import: ``machine``, ``io``, ``model``, ``diagnosis``, ``gum``, ``export``.
"""

from __future__ import annotations

from .designer import (
    WEAK_PRIOR,
    DesignResult,
    PoolModel,
    design,
    failing,
    figures,
    meets,
    random_plans,
)
from .detect import (
    POWER,
    DetectionLimit,
    baseline_basis,
    candidate_tokens,
    cert_columns,
    cert_scales,
    default_period,
    detection_limits,
    detection_trial,
    diagnosis_detects,
    injection,
    noncentrality_for_power,
)
from .evaluation import PlanEvaluation, evaluate, function_uncertainty
from .files import (
    MEASUREMENT_DEFAULTS,
    MODEL_DEFAULTS,
    PLATE_DEFAULTS,
    STRATEGY_KEYS,
    TOP_KEYS,
    PlanFile,
    design_from_file,
    evaluate_file,
    read_design,
    read_plan,
    units_of,
)
from .plans import STROKE_POINTS, Plan, design_fit, fit_plan_data, simulate_plan, simulation_config
from .proposals import (
    BASELINE,
    CHUNK,
    NO_POWER,
    PLACEMENT_SCALE,
    PSEUDO,
    REPEAT_BALLS,
    SCALE_RTOL,
    SHIFT_FRACTION,
    STYLUS_OFFSET_MM,
    TARGET_POWER,
    NextMeasurement,
    Outcome,
    PlateGrid,
    Proposal,
    Proposals,
    RivalFits,
    ScaleFit,
    append_measurement,
    blocked_styli,
    fit_rivals,
    instrument_candidates,
    instrument_of,
    measurement_candidates,
    measurement_observations,
    open_pairs,
    plan_file,
    plate_grid,
    propose,
    propose_many,
    repeat_candidates,
    repeat_from_fit,
    restrict,
    rival_pairs,
    rivals_of,
    scale_columns,
    simulate_outcomes,
    truth_config,
    wide_candidates,
)
from .study import (
    PHYSICAL_CHECKS,
    StudyResult,
    StudyTask,
    check_plans,
    dask_client,
    run_serial,
    run_task,
    run_tasks,
    summarise,
    tasks_for,
)
from .task import (
    MIN_LENGTH_MM,
    TASK_KEYS,
    TASKS,
    Task,
    TaskResult,
    feature,
    read_task,
    task_uncertainty,
)

__all__ = [
    "baseline_basis", "candidate_tokens", "cert_columns", "cert_scales", "check_plans", "dask_client", "default_period",
    "design", "design_fit", "design_from_file", "DesignResult", "detection_limits",
    "detection_trial", "DetectionLimit", "diagnosis_detects", "evaluate", "evaluate_file",
    "failing", "feature", "figures", "fit_plan_data", "function_uncertainty", "injection",
    "MEASUREMENT_DEFAULTS", "meets", "MIN_LENGTH_MM", "MODEL_DEFAULTS",
    "noncentrality_for_power", "PHYSICAL_CHECKS", "Plan", "PlanEvaluation", "PlanFile",
    "PLATE_DEFAULTS", "PoolModel", "POWER", "random_plans", "read_design", "read_plan",
    "read_task", "run_serial", "run_task", "run_tasks", "simulate_plan", "simulation_config",
    "STRATEGY_KEYS", "STROKE_POINTS", "StudyResult", "StudyTask", "summarise", "Task",
    "TASK_KEYS", "task_uncertainty", "TaskResult", "TASKS", "tasks_for", "TOP_KEYS", "units_of",
    "WEAK_PRIOR",
    # measure next (proposals/)
    "TARGET_POWER", "SHIFT_FRACTION", "STYLUS_OFFSET_MM", "NextMeasurement", "Outcome",
    "PlateGrid", "Proposal", "Proposals", "RivalFits", "append_measurement", "fit_rivals",
    "measurement_candidates", "measurement_observations", "plan_file", "plate_grid",
    "propose", "rivals_of", "simulate_outcomes", "truth_config", "CHUNK", "propose_many",
    "wide_candidates", "instrument_candidates", "instrument_of", "rival_pairs", "restrict",
    "PLACEMENT_SCALE", "ScaleFit", "scale_columns", "SCALE_RTOL", "BASELINE",
    "PSEUDO", "open_pairs", "blocked_styli", "repeat_candidates", "repeat_from_fit",
    "REPEAT_BALLS", "NO_POWER",
]

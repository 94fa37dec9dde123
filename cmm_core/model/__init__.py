"""The model and its fit: observations, effect blocks, the least-squares fit with its state
and result, the certificate prior, hole plates, instruments (laser, step gauge, ball bar
and their files), the virtual CMM and the uncertainty of fitted errors (thesis ch. 4-6).

Owns: :mod:`.observations`, :mod:`.effects` (model specs and the catalogue), ``blocks/``
(one module per physical effect and :data:`blocks.REGISTRY`), :mod:`.problem` (parameter
layout, residuals, Jacobian), :mod:`.fitting` (:func:`fit`), :mod:`.result`
(:class:`FitResult`), :mod:`.solver`, :mod:`.normal`, :mod:`.certificate_prior`,
:mod:`.hole_plate`, :mod:`.instruments`, :mod:`.ballbar`, :mod:`.instrument_files`,
:mod:`.virtual_cmm` (:func:`simulate`), :mod:`.simulation_config`, :mod:`.uncertainty`
(U1-U3, propagation to points), :mod:`.words` (the parameters in words). May import: ``machine``, ``io``.
"""

from __future__ import annotations

from . import blocks
from .ballbar import BallBar, simulate_ball_bar
from .blocks import BY_TOKEN, REGISTRY, Block, Eval, needs
from .blocks.compensation import MAX_MODEL_U, checked_cov
from .blocks.periodic import PERIOD_SCAN, PERIODIC, shortest_resolvable_period
from .blocks.plate import Plate
from .blocks.simulation import SimParam, SimulatorEffect
from .certificate_prior import certificate_terms, held_prior_rows, residual_u_um
from .effects import (
    GROUPS,
    MAX_ORDER,
    PHYSICAL,
    ModelSpec,
    catalogue_entry,
    correction_columns,
    parse_spec,
    rotation_kind,
)
from .fitting import PLATE_MODES, fit
from .hole_plate import (
    ROUNDING,
    TILT_NOTE_RAD,
    TILT_USE_RAD,
    in_plane,
    initial_state,
    is_hole_plate,
    measured_normal,
    tilt_note,
)
from .instrument_files import (
    BALL_BAR_COLUMNS,
    BALL_BAR_OPTIONAL,
    INSTRUMENT_KINDS,
    LASER_COLUMNS,
    LASER_OPTIONAL,
    LINE_TOLERANCE_MM,
    MAX_ERROR_UM,
    MAX_LENGTH_DIFF_MM,
    MAX_STYLUS_MM,
    MIN_BAR_MM,
    OFFSET_COLUMNS,
    STEP_GAUGE_COLUMNS,
    STEP_GAUGE_OPTIONAL,
    read_ball_bar,
    read_instrument,
    read_laser,
    read_step_gauge,
    write_ball_bar,
    write_instrument,
    write_laser,
    write_step_gauge,
)
from .instruments import (
    MAX_INSTRUMENT_READINGS,
    RANGE_MARGIN,
    Instruments,
    LaserRun,
    StepGauge,
    content_key,
    length_change,
    refuse_repeated,
    residuals_frame,
    simulate_laser,
    simulate_step_gauge,
    summary,
    truth_of,
)
from .normal import ROWS, NormalEquations, accumulate, cost_of, rows_of
from .observations import (
    Observations,
    approach_directions,
    check_selection,
    has_plate,
    instrument_observations,
    select,
    selected_rows,
    setup_layout,
)
from .problem import Problem, augmented_state, held_constraints, weighted_residual
from .result import CHI2_ALPHA, IMPLAUSIBLE, FitResult
from .simulation_config import DEFAULT_CONFIG, check_repeat_at_end, simulator_effects
from .solver import Normal, describe_null, normal_equations, signed_sum, solve, surely_determined
from .state import State
from .uncertainty import (
    UncertaintySummary,
    aligned_error_u,
    covariance_factor,
    error_at,
    error_covariance,
    evaluate,
    monte_carlo_error,
    propagate_error,
    residual_u,
    rigid_body_projector,
    rigid_removed_error_u,
)
from .virtual_cmm import Simulation, simulate, thesis_machine_setup
from .words import (
    CARRIER_WEIGHT,
    MAX_CARRIERS,
    direction_phrase,
    distinct_words,
    null_carriers,
    null_words,
    parameter_name,
)

__all__ = [
    "accumulate", "aligned_error_u", "approach_directions", "augmented_state",
    "BALL_BAR_COLUMNS", "BALL_BAR_OPTIONAL", "BallBar", "Block", "BY_TOKEN", "catalogue_entry",
    "CARRIER_WEIGHT", "direction_phrase", "distinct_words", "MAX_CARRIERS", "null_carriers", "null_words", "parameter_name",
    "certificate_terms", "check_selection", "checked_cov", "CHI2_ALPHA", "correction_columns",
    "check_repeat_at_end", "cost_of", "DEFAULT_CONFIG", "describe_null", "error_at", "error_covariance",
    "Eval", "evaluate", "fit", "FitResult", "GROUPS", "has_plate", "held_constraints", "held_prior_rows",
    "IMPLAUSIBLE", "in_plane", "initial_state", "instrument_observations", "INSTRUMENT_KINDS", "Instruments",
    "is_hole_plate", "LASER_COLUMNS", "LASER_OPTIONAL", "LaserRun", "length_change",
    "LINE_TOLERANCE_MM", "MAX_ERROR_UM", "MAX_MODEL_U", "MAX_LENGTH_DIFF_MM", "MAX_ORDER", "MAX_STYLUS_MM",
    "measured_normal", "MIN_BAR_MM", "ModelSpec", "monte_carlo_error", "needs", "Normal",
    "normal_equations", "NormalEquations", "Observations", "OFFSET_COLUMNS", "parse_spec", "rotation_kind",
    "PERIOD_SCAN", "PERIODIC", "PHYSICAL", "Plate", "PLATE_MODES", "Problem", "propagate_error",
    "covariance_factor",
    "RANGE_MARGIN", "read_ball_bar", "read_instrument", "read_laser", "read_step_gauge",
    "REGISTRY", "residual_u", "residual_u_um", "residuals_frame", "rigid_body_projector",
    "rigid_removed_error_u", "ROUNDING", "ROWS", "rows_of", "select", "selected_rows", "setup_layout",
    "shortest_resolvable_period", "signed_sum", "SimParam", "simulate", "simulate_ball_bar",
    "simulate_laser", "simulate_step_gauge", "Simulation", "simulator_effects",
    "SimulatorEffect", "solve", "State", "STEP_GAUGE_COLUMNS", "STEP_GAUGE_OPTIONAL",
    "StepGauge", "summary", "MAX_INSTRUMENT_READINGS", "content_key", "refuse_repeated", "surely_determined", "thesis_machine_setup", "tilt_note",
    "TILT_NOTE_RAD", "TILT_USE_RAD", "truth_of", "UncertaintySummary", "weighted_residual",
    "write_ball_bar", "write_instrument", "write_laser", "write_step_gauge", "blocks"
]

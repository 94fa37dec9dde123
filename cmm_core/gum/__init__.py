"""Measurement uncertainty: the GUM framework (JCGM 100), Monte Carlo propagation
(JCGM 101), the thesis ball-plate calibration budget (tables 6.1-6.6), the Edlén air
refractive index and MPE conformity (ISO 10360-2, ISO 14253-1).

Owns: :mod:`.inputs` (:class:`Contribution`), :mod:`.framework` (:func:`gum_combine`),
:mod:`.mc` (:func:`monte_carlo`), :mod:`.evaluate` (budgets from a dict), :mod:`.ballplate`
(the thesis budget), :mod:`.air`, :mod:`.mpe`. May import: ``io``.
"""

from __future__ import annotations

from .air import (
    CO2_REFERENCE_PPM,
    air_from_args,
    refractive_index_edlen,
    refractive_index_sensitivities,
    refractive_index_thesis_eq319,
    saturation_vapour_pressure_Pa,
)
from .ballplate import (
    PLATE_BALLS_PER_SIDE,
    PLATE_PITCH_MM,
    THESIS_ENVIRONMENT,
    BallPlateBudget,
    BallPlateBudgetInputs,
    EnvironmentRecord,
    LengthDependence,
    average_environment,
    ballplate_budget,
    budget_spec_dict,
    budget_vs_length,
    cmm_uncertainty_um,
    default_inputs,
    inputs_from_record,
    plate_lengths_mm,
    plate_uncertainty_um,
    read_budget,
    thesis_budgets,
)
from .evaluate import budget_from_dict, contribution_from_dict, correlations_from_list
from .framework import (
    GumResult,
    coverage_factor,
    gum_combine,
    sensitivity_coefficients,
    welch_satterthwaite,
)
from .inputs import DISTRIBUTIONS, Contribution, correlation_matrix, half_width_divisor
from .mc import MonteCarloResult, coverage_intervals, monte_carlo
from .mpe import (
    DECISIONS,
    DIRECTIONS,
    U_SOURCES,
    MpeResult,
    check_dataset,
    conformity_uncertainty_um,
    decide,
    line_pairs,
    mpe_check,
    mpe_um,
    plate_side,
    uncertainty_um,
)

__all__ = [
    "air_from_args", "average_environment", "ballplate_budget", "BallPlateBudget",
    "BallPlateBudgetInputs", "budget_from_dict", "budget_spec_dict", "budget_vs_length",
    "check_dataset", "plate_side", "cmm_uncertainty_um", "CO2_REFERENCE_PPM", "conformity_uncertainty_um",
    "Contribution", "contribution_from_dict", "correlation_matrix", "correlations_from_list",
    "coverage_factor", "coverage_intervals", "decide",
    "DECISIONS", "default_inputs", "DIRECTIONS", "DISTRIBUTIONS", "EnvironmentRecord",
    "gum_combine", "GumResult", "half_width_divisor", "inputs_from_record", "LengthDependence",
    "line_pairs", "monte_carlo", "MonteCarloResult", "mpe_check", "mpe_um", "MpeResult",
    "PLATE_BALLS_PER_SIDE", "plate_lengths_mm", "PLATE_PITCH_MM", "plate_uncertainty_um",
    "read_budget", "refractive_index_edlen", "refractive_index_sensitivities",
    "refractive_index_thesis_eq319", "saturation_vapour_pressure_Pa",
    "sensitivity_coefficients", "thesis_budgets", "THESIS_ENVIRONMENT", "U_SOURCES",
    "uncertainty_um", "welch_satterthwaite"
]

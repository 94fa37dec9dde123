"""The diagnosis: which physical effect is missing from the model, how sure we are, and
what the data cannot tell apart (docs/validation.md; thesis ch. 7 for the GP residual).

Owns: :mod:`.search` (:func:`diagnose`, :class:`Diagnosis`, :class:`Candidate`, σ
estimate), :mod:`.scoring` (the significance rule: Δχ², family-wise levels, BIC),
:mod:`.verdict` (conclusion, aliases, encompassing), :mod:`.crossval` (leave-one-placement-
out check), :mod:`.certificate_check`, :mod:`.discrepancy` (GP on the residuals),
:mod:`.replicates` (σ from repeats and residuals), :mod:`.outliers`, :mod:`.blunders`
(flagged outliers that dominate the misfit are the verdict before any effect),
:mod:`.certnoise` (a fixed certificate's own errors in the candidates' F-tests),
:mod:`.headline` (:class:`Headline`: the verdict in one message, shared by the app, the
report and the CLI).
May import: ``machine``, ``io``, ``model``, ``gp``.
"""

from __future__ import annotations

from .blunders import ACTION, BLUNDERS, DOMINANT_SHARE, BlunderCheck, blunder_check
from .certificate_check import ALPHA, CertificateCheck, check_certificate, released
from .certnoise import (
    MIN_FORM_DOF,
    CertNoise,
    cert_columns,
    cert_noise,
    cert_scales,
    critical_ratio,
    null_p_value,
    quadratic_form_sf,
    rejection_probability,
    size_for_power,
)
from .crossval import (
    MATERIAL,
    MIN_PLACEMENTS,
    SCALE_ALONE_ALPHA,
    SCALE_ALPHA,
    HoldoutCheck,
    check,
    placement_scale_columns,
    placement_scale_test,
    plate_columns,
    scale_columns,
    scales_alone_p,
)
from .discrepancy import Discrepancy, discrepancy_gp, kinematic_basis
from .headline import (
    HEADLINE_LEVELS,
    HEADLINE_VERDICTS,
    MAX_TERMS,
    SETUP_GROUPS,
    SIGNIFICANT_Z,
    Headline,
    headline_of,
    significant_terms,
)
from .outliers import OutlierReport, detect_outliers
from .replicates import (
    UNIFORM_ALPHA,
    SigmaEstimate,
    Uniformity,
    axis_weights,
    estimate,
    flexible_spec,
    from_repeats,
    from_residuals,
    uniformity,
)
from .scoring import (
    FAMILY_ALPHA,
    PHYSICAL_SHARE,
    ScoreCache,
    baseline_basis,
    candidate_noise,
    candidate_stats,
    certificate_noise,
    family_levels,
    needs_met,
    scan_period,
    score,
)
from .search import (
    BASE_MAX_ITER,
    MAX_READINGS,
    Candidate,
    Diagnosis,
    diagnose,
    estimate_sigma,
)
from .verdict import (
    OUTSIDE,
    evidence,
    fitted_parameters,
    fitted_text,
    misfit_location,
    stylus_offsets,
    stylus_text,
)

__all__ = [
    "ACTION", "ALPHA", "axis_weights", "BASE_MAX_ITER", "blunder_check", "BlunderCheck", "BLUNDERS",
    "DOMINANT_SHARE", "baseline_basis", "Candidate", "candidate_stats",
    "CertificateCheck", "check", "check_certificate", "detect_outliers", "diagnose",
    "Diagnosis", "Discrepancy", "discrepancy_gp", "estimate", "estimate_sigma", "evidence", "fitted_text", "FAMILY_ALPHA",
    "family_levels", "flexible_spec", "from_repeats", "from_residuals", "HoldoutCheck",
    "kinematic_basis", "MATERIAL", "MAX_READINGS", "MIN_PLACEMENTS", "misfit_location", "needs_met",
    "OutlierReport", "OUTSIDE", "PHYSICAL_SHARE", "placement_scale_columns", "scale_columns", "placement_scale_test", "plate_columns", "SCALE_ALONE_ALPHA", "SCALE_ALPHA", "scales_alone_p", "released", "scan_period", "score",
    "ScoreCache", "SigmaEstimate", "stylus_offsets", "UNIFORM_ALPHA", "Uniformity", "uniformity",
    "candidate_noise", "certificate_noise", "CertNoise", "cert_columns", "cert_noise",
    "cert_scales", "critical_ratio", "MIN_FORM_DOF", "null_p_value", "quadratic_form_sf",
    "rejection_probability", "size_for_power",
    "Headline", "headline_of", "HEADLINE_LEVELS", "HEADLINE_VERDICTS", "MAX_TERMS",
    "SETUP_GROUPS", "SIGNIFICANT_Z", "significant_terms", "fitted_parameters", "stylus_text",
]

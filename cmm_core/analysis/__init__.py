"""One analysis, one record: what the user chose (data, model, σ, exclusions, GP, MPE), run
the same way by the app, the CLI and the report, and the report with its figures.

Owns: :mod:`.record` (:class:`AnalysisRecord`), :mod:`.record_io` (JSON and project
files), :mod:`.runner` (:func:`run`, :class:`AnalysisResult`), :mod:`.residuals`,
:mod:`.comparison` (thesis chapter 7: kinematic vs GP vs measurement), :mod:`.figures`
(plotly figures), :mod:`.report` (HTML report), :mod:`.first_look` (the first screen's
summary and next step), :mod:`.sessions` (analyses kept on disk between browser
sessions). May import every wing below it except ``cli``.
"""

from __future__ import annotations

from .comparison import (
    ComparisonFigure,
    ModelComparison,
    PlaneGrid,
    compare_models,
    coverage_reasons,
    placement_plane_grid,
    plate_coordinates_mm,
)
from .figures import (
    AXIS_COLOURS,
    COLORWAY,
    EN_CLASSES,
    EN_PLACE_MM,
    FUNCTION_UNITS,
    PLACEMENT_SYMBOLS,
    deviations_plate_frame,
    en_classes,
    error_function_curves,
    fig_budget_vs_length,
    fig_detection_limits,
    fig_deviation,
    fig_en_map,
    fig_error_functions,
    fig_error_map_change,
    fig_history,
    fig_mpe,
    fig_parameter_trend,
    fig_pattern,
    fig_placement_views,
    fig_placements,
    fig_residual_map,
    fig_residuals_time,
    fig_signature_scatter,
    fig_surface_grid,
    true_function_curve,
)
from .first_look import FIRST_STEPS, FirstLook, first_look
from .record import (
    DEFAULT_EXCLUDE_OUTLIERS,
    ERROR_CONVENTION,
    FORMAT,
    GP_KERNELS,
    GP_MEANS,
    MPE_U_SOURCES,
    PLATE_CHOICES,
    VERSION,
    AnalysisRecord,
    CheckChoices,
    DataFile,
    DataSources,
    HistoryChoices,
    InstrumentFile,
    instrument_kinds,
    measured_error_from_residuals_um,
    measured_error_um,
)
from .record_io import (
    KEYS,
    instruments_from_list,
    read_record,
    record_files,
    record_from_dict,
    record_from_inline,
    record_from_project,
    record_to_dict,
    record_to_json,
    record_to_project_json,
)
from .report import (
    TIMESTAMP,
    analysis_report,
    build_report,
    chi2_html,
    chi2_test_numbers,
    diagnosis_conclusion,
    diagnosis_rows,
    figure_html,
    headline_html,
    monitor_sections,
    plotly_loader,
    render,
    write_report,
)
from .residuals import (
    against_coordinates,
    approach_split,
    breakdown,
    instrument_tables,
    position_trends,
    residual_summary,
    uncertainty_gain,
)
from .runner import (
    AnalysisResult,
    FitChoices,
    diagnose_record,
    fit_kwargs,
    fit_record,
    history_exclusions,
    load_data,
    load_instruments,
    load_stored_model,
    record_exclusions,
    resolve_sigma,
    results_document,
    run,
    with_instruments,
)
from .sessions import (
    KEEP_DAYS,
    LOCK_WAIT_S,
    MAX_SESSION_BYTES,
    PRIVATE_FILE,
    PRIVATE_FOLDER,
    STALE_LOCK_S,
    SavedSession,
    SessionConflict,
    SessionStore,
    default_session_folder,
    new_session_id,
    text_digest,
    valid_session_id,
)
from .sources import (
    FOREIGN_HINT,
    THESIS_ORIGIN,
    Assembly,
    SourceProblem,
    assemble_upload,
    inline_sources,
    load_sources,
    problems_of,
    record_from_sources,
    refuse_paths,
    simulated_sources,
    sources_key,
    thesis_sources,
)
from .svg import figure_svg, nice_ticks, placement_views_svg, svg_supported, tick_label

__all__ = [
    "FIRST_STEPS", "FirstLook", "first_look",
    "THESIS_ORIGIN", "FOREIGN_HINT", "Assembly", "SourceProblem", "assemble_upload", "inline_sources", "refuse_paths",
    "load_sources", "problems_of", "record_from_sources", "simulated_sources", "sources_key",
    "thesis_sources",
    "placement_views_svg", "figure_svg", "nice_ticks", "svg_supported", "tick_label", "COLORWAY", "PLACEMENT_SYMBOLS", "fig_placement_views", "record_exclusions", "resolve_sigma", "diagnose_record", "FitChoices", "fit_kwargs", "fit_record", "history_exclusions",
    "against_coordinates", "analysis_report", "AnalysisRecord", "AnalysisResult",
    "approach_split", "AXIS_COLOURS", "breakdown", "build_report", "chi2_html",
    "chi2_test_numbers", "CheckChoices", "compare_models", "ComparisonFigure", "coverage_reasons", "DataFile", "DataSources", "default_session_folder", "DEFAULT_EXCLUDE_OUTLIERS", "MAX_SESSION_BYTES", "PRIVATE_FILE", "PRIVATE_FOLDER", "LOCK_WAIT_S", "STALE_LOCK_S", "SessionConflict", "text_digest",
    "deviations_plate_frame", "diagnosis_conclusion", "diagnosis_rows", "headline_html", "ERROR_CONVENTION",
    "EN_CLASSES", "EN_PLACE_MM", "en_classes", "error_function_curves", "fig_deviation", "fig_en_map", "fig_detection_limits", "fig_error_functions", "fig_history", "fig_budget_vs_length", "fig_mpe", "fig_residuals_time", "fig_parameter_trend", "fig_error_map_change",
    "fig_pattern", "fig_placements", "fig_residual_map", "fig_signature_scatter",
    "fig_surface_grid", "figure_html", "FORMAT", "FUNCTION_UNITS", "GP_KERNELS", "GP_MEANS",
    "HistoryChoices", "load_stored_model", "results_document",
    "instrument_kinds", "instrument_tables", "InstrumentFile", "instruments_from_list", "KEEP_DAYS",
    "KEYS", "new_session_id", "SavedSession", "SessionStore", "valid_session_id",
    "load_data", "load_instruments", "measured_error_from_residuals_um", "measured_error_um",
    "ModelComparison", "monitor_sections", "MPE_U_SOURCES", "placement_plane_grid", "PlaneGrid", "PLATE_CHOICES",
    "plate_coordinates_mm", "plotly_loader", "position_trends", "read_record",
    "record_from_dict", "record_from_inline", "record_from_project", "record_to_dict",
    "record_files", "record_to_json", "record_to_project_json", "render", "residual_summary", "run",
    "TIMESTAMP", "true_function_curve", "uncertainty_gain", "VERSION", "with_instruments",
    "write_report"
]

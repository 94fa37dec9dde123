"""What leaves the program for a machine or a spreadsheet: the model file, corrected
points, compensation tables and grids, results and project files (``docs/compensation.md``).

Owns: :mod:`.safe` (spreadsheet-safe CSV, grid limits), :mod:`.model_file` (the model
file: :class:`Model`, written and read back checked), :mod:`.correction`
(:func:`compensate`: corrected points with their uncertainty), :mod:`.comp_tables` (controller tables and grids),
:mod:`.results` (results bundle), :mod:`.qif` (QIF 3.0 document), :mod:`.downloads` (parameter, residual and grid CSV,
project files). May import: ``machine``, ``io``, ``model``.
"""

from __future__ import annotations

from .comp_tables import (
    AXIS_FORMAT,
    GRID_FORMAT,
    MAX_AXIS_NODES,
    SIGN_GRID,
    as_model,
    axis_functions,
    axis_nodes,
    axis_roles,
    axis_table,
    axis_tables,
    axis_tables_csv,
    axis_tables_zip,
    chi2_status,
    compensation_grid,
    function_values,
    grid_csv,
    model_extras,
    model_lines,
    probe_offset,
    squareness_table,
)
from .correction import (
    OFF_MACHINE,
    compensate,
    extrapolation_note,
    read_points,
    refuse_off_machine,
)
from .downloads import (
    PROJECT_FORMAT,
    PROJECT_VERSION,
    compensate_points,
    corrected_csv,
    download_name,
    error_map_csv,
    error_map_grid,
    parameters_csv,
    project_from_json,
    project_to_json,
    residuals_csv,
)
from .model_file import (
    COMPENSATING,
    MODEL_FORMAT,
    Model,
    certificate_digest,
    load_model,
    model_from_dict,
    model_from_result,
    model_to_dict,
    save_model,
)
from .qif import (
    EXTENSION_NS,
    QIF_GEOMETRY,
    QIF_VERSION,
    TEMPERATURE_COMPENSATION,
    qif_document,
)
from .results import (
    DEFAULT_COVERAGE_FACTOR,
    RESULTS_FORMAT,
    RESULTS_VERSION,
    Characteristic,
    characteristics,
    held_labels,
    results_dict,
    results_json,
    results_xml,
)
from .safe import MAX_GRID_NODES, neutralise, safe_csv, safe_frame

__all__ = [
    "as_model", "AXIS_FORMAT", "axis_functions", "axis_nodes", "axis_roles", "axis_table",
    "axis_tables", "axis_tables_csv", "axis_tables_zip", "Characteristic", "characteristics",
    "chi2_status", "compensate", "compensate_points", "corrected_csv", "COMPENSATING", "compensation_grid",
    "DEFAULT_COVERAGE_FACTOR", "download_name", "error_map_csv", "error_map_grid", "extrapolation_note",
    "function_values", "grid_csv", "GRID_FORMAT", "held_labels", "load_model", "MAX_AXIS_NODES",
    "MAX_GRID_NODES", "Model", "model_extras", "MODEL_FORMAT", "model_from_dict",
    "model_from_result", "certificate_digest", "model_lines", "model_to_dict", "neutralise", "OFF_MACHINE",
    "parameters_csv", "probe_offset", "PROJECT_FORMAT", "project_from_json", "project_to_json",
    "PROJECT_VERSION", "read_points", "refuse_off_machine", "residuals_csv", "results_dict",
    "RESULTS_FORMAT", "results_json", "RESULTS_VERSION", "results_xml", "safe_csv",
    "safe_frame", "save_model", "SIGN_GRID", "squareness_table", "EXTENSION_NS",
    "QIF_GEOMETRY", "QIF_VERSION", "TEMPERATURE_COMPENSATION", "qif_document",
]

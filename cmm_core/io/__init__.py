"""Reading and validating measurements, setups and certificates (``docs/formats.md``).

Every problem is reported as a :class:`DataError` naming the file, row and column and what
was expected, with a hint at the fix. Row numbers are the rows a spreadsheet shows (the
header is row 1, so the first data row is row 2; blank lines count as rows). Measurement
and certificate files are checked completely before anything is raised: the error carries
every cell-level problem in ``DataError.problems`` while ``str(exc)`` stays one line.

Owns: :mod:`.errors` (DataError, problem collector, name checks), :mod:`.delimited` (bytes,
CSV cells, numbers, JSON), :mod:`.setup`, :mod:`.measurements`, :mod:`.certificate`,
:mod:`.matching` (measurements against setup and certificate), :mod:`.qif` (QIF 3.0 results), :mod:`.dataset` (one call
from files to a :class:`Dataset`), :mod:`.provenance` (what every record says of its
software, inputs and machine). May import: ``machine`` (layout names).
"""

from __future__ import annotations

from .certificate import MIN_CERTIFICATE_BALLS, Certificate, read_certificate, write_certificate
from .dataset import (
    SAMPLE_DIR,
    THESIS_DIR,
    THESIS_POSITIONS,
    Dataset,
    load_dataset,
    read_machine,
    stated_certificate,
    thesis_dataset,
)
from .delimited import (
    MAX_BYTES,
    MAX_MEASUREMENT_ROWS,
    FileSource,
    blank_leading_comments,
    file_rows,
    numeric_column,
    read_bytes,
    read_csv_text,
    read_json,
    require_columns,
    require_rows,
)
from .dmis import DMIS_SUFFIXES, DMIS_UNITS_MM, read_dmis, read_foreign
from .errors import (
    COLUMN_ALIASES,
    MAX_PROBLEMS,
    DataError,
    Problems,
    cut_repr,
    describe_error,
    likely_typo,
    not_a_json_number,
    refuse_unknown_keys,
)
from .matching import missing_balls, resolve
from .measurements import (
    LONG_COLUMNS,
    OPTIONAL_COLUMNS,
    SCALE_TEMP_COLUMNS,
    THESIS_COLUMNS,
    read_measurement_files,
    read_measurements,
    write_long_csv,
)
from .msl import (
    MSL_API_NAMES,
    MSL_HEADER_KEYS,
    MSL_KINDS,
    MSL_LAYOUTS,
    MSL_MAX_DEVIATION_MM,
    MSL_PARAMETERS,
    MSL_ROUNDING_U_UM,
    MSL_SQUARENESS_CARRIERS,
    ForeignDataset,
    ForeignStepGauge,
    MslFiles,
    MslNames,
    combine_plates,
    msl_coefficients,
    msl_degree,
    msl_header,
    msl_layout,
    msl_metadata_text,
    msl_parameters,
    msl_rotation,
    read_msl_bar,
    read_msl_files,
    read_msl_metadata,
    read_msl_plate,
    rounding_u_um,
    sniff,
)
from .output import (
    atomic_write_all,
    atomic_write_bytes,
    atomic_write_text,
    atomic_writer,
    check_outputs,
    forget_outputs,
)
from .provenance import (
    COMMIT_FILE,
    SOFTWARE,
    InputFile,
    Provenance,
    file_input,
    input_file,
    provenance,
    provenance_from_dict,
    software_identity,
)
from .qif import QIF_LABEL_PATTERN, QIF_NS, QIF_SUFFIXES, QIF_UNITS_MM, is_qif, read_qif
from .setup import (
    ARTEFACTS,
    AXIS_TOLERANCE_DEG,
    COMBINE,
    CTE_RANGE_PER_K,
    LAYOUTS,
    MAX_MACHINE_ID,
    MAX_PROBE_MM,
    MAX_STROKE_MM,
    MIN_STROKE_MM,
    SETUP_KEYS,
    TEMP_RANGE_C,
    CertificateUncertainty,
    Placement,
    Setup,
    check_celsius,
    range_tolerance,
    reach_tolerance,
    read_setup,
)
from .table_mapping import (
    DECIMALS,
    DELIMITERS,
    LABEL_GROUPS,
    LENGTH_UNITS_MM,
    TIME_UNITS_MIN,
    ForeignTable,
    Preview,
    TableInfo,
    TableMapping,
    apply_mapping,
    inspect_table,
    preview,
    read_mapping,
    suggest_mapping,
)

__all__ = [
    "apply_mapping", "ARTEFACTS", "atomic_write_all", "atomic_write_bytes", "atomic_write_text", "atomic_writer",
    "AXIS_TOLERANCE_DEG", "Certificate", "CertificateUncertainty", "check_celsius",
    "check_outputs", "forget_outputs", "COLUMN_ALIASES", "COMBINE", "combine_plates", "CTE_RANGE_PER_K",
    "cut_repr", "not_a_json_number", "describe_error", "DataError", "Dataset", "DECIMALS", "DELIMITERS", "DMIS_SUFFIXES",
    "DMIS_UNITS_MM", "file_rows", "FileSource", "ForeignDataset", "ForeignStepGauge",
    "ForeignTable", "inspect_table", "LABEL_GROUPS", "LAYOUTS", "LENGTH_UNITS_MM",
    "likely_typo", "load_dataset", "read_machine", "LONG_COLUMNS", "MAX_BYTES", "MAX_MEASUREMENT_ROWS", "MAX_PROBE_MM", "MAX_PROBLEMS",
    "MAX_STROKE_MM", "MIN_CERTIFICATE_BALLS", "MIN_STROKE_MM", "missing_balls",
    "msl_coefficients", "MSL_HEADER_KEYS", "MSL_KINDS", "msl_layout", "MSL_LAYOUTS",
    "MSL_MAX_DEVIATION_MM", "MSL_PARAMETERS", "msl_rotation", "MSL_ROUNDING_U_UM",
    "MSL_API_NAMES", "MSL_SQUARENESS_CARRIERS", "MslFiles", "MslNames", "read_msl_files", "msl_degree", "msl_header",
    "msl_metadata_text", "msl_parameters", "read_msl_metadata", "rounding_u_um",
    "numeric_column", "OPTIONAL_COLUMNS", "Placement", "Preview", "preview", "Problems",
    "range_tolerance", "reach_tolerance", "read_certificate", "read_csv_text", "blank_leading_comments", "read_dmis",
    "read_foreign", "read_json", "read_mapping", "read_measurement_files", "read_measurements",
    "read_msl_bar", "read_msl_plate", "read_setup", "refuse_unknown_keys", "require_columns",
    "require_rows", "resolve", "SAMPLE_DIR", "SCALE_TEMP_COLUMNS", "Setup", "SETUP_KEYS",
    "sniff", "stated_certificate", "suggest_mapping", "TableInfo", "TableMapping",
    "TEMP_RANGE_C", "THESIS_COLUMNS", "thesis_dataset", "THESIS_DIR", "THESIS_POSITIONS",
    "TIME_UNITS_MIN", "write_certificate", "write_long_csv", "InputFile", "Provenance",
    "file_input", "input_file", "provenance", "provenance_from_dict", "software_identity", "read_bytes", "COMMIT_FILE", "SOFTWARE", "MAX_MACHINE_ID",
    "QIF_LABEL_PATTERN", "QIF_NS", "QIF_SUFFIXES", "QIF_UNITS_MM", "is_qif", "read_qif",
]

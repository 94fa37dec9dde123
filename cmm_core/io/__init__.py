"""Reading and validating measurements, setups and certificates (``docs/formats.md``).

Every problem is reported as a :class:`DataError` naming the file, row and column and what
was expected, with a hint at the fix. Row numbers are the rows a spreadsheet shows (the
header is row 1, so the first data row is row 2; blank lines count as rows). Measurement
and certificate files are checked completely before anything is raised: the error carries
every cell-level problem in ``DataError.problems`` while ``str(exc)`` stays one line.

Owns: :mod:`.errors` (DataError, problem collector, name checks), :mod:`.delimited` (bytes,
CSV cells, numbers, JSON), :mod:`.setup`, :mod:`.measurements`, :mod:`.certificate`,
:mod:`.matching` (measurements against setup and certificate), :mod:`.dataset` (one call
from files to a :class:`Dataset`). May import: ``machine`` (layout names).
"""

from __future__ import annotations

from .certificate import MIN_CERTIFICATE_BALLS, Certificate, read_certificate, write_certificate
from .dataset import SAMPLE_DIR, THESIS_DIR, THESIS_POSITIONS, Dataset, load_dataset, thesis_dataset
from .delimited import (
    MAX_BYTES,
    file_rows,
    numeric_column,
    read_csv_text,
    read_json,
    require_columns,
    require_rows,
)
from .errors import (
    COLUMN_ALIASES,
    MAX_PROBLEMS,
    DataError,
    Problems,
    cut_repr,
    likely_typo,
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
from .setup import (
    ARTEFACTS,
    AXIS_TOLERANCE_DEG,
    CTE_RANGE_PER_K,
    LAYOUTS,
    MAX_PROBE_MM,
    MAX_STROKE_MM,
    MIN_STROKE_MM,
    SETUP_KEYS,
    TEMP_RANGE_C,
    Placement,
    Setup,
    check_celsius,
    read_setup,
)

__all__ = [
    "ARTEFACTS", "AXIS_TOLERANCE_DEG", "Certificate", "check_celsius", "COLUMN_ALIASES",
    "CTE_RANGE_PER_K", "cut_repr", "DataError", "Dataset", "file_rows", "LAYOUTS",
    "likely_typo", "load_dataset", "LONG_COLUMNS", "MAX_BYTES", "MAX_PROBE_MM", "MAX_PROBLEMS",
    "MAX_STROKE_MM", "MIN_CERTIFICATE_BALLS", "MIN_STROKE_MM", "missing_balls",
    "numeric_column", "OPTIONAL_COLUMNS", "Placement", "Problems", "read_certificate",
    "read_csv_text", "read_json", "read_measurement_files", "read_measurements", "read_setup",
    "refuse_unknown_keys", "require_columns", "require_rows", "resolve", "SAMPLE_DIR",
    "SCALE_TEMP_COLUMNS", "Setup", "SETUP_KEYS", "TEMP_RANGE_C", "THESIS_COLUMNS",
    "thesis_dataset", "THESIS_DIR", "THESIS_POSITIONS", "write_certificate", "write_long_csv"
]

"""Reading and validating measurements, setups and certificates (SPEC "Data formats").

Every problem is reported as a :class:`DataError` naming the file, row and column and what
was expected, with a hint at the fix. Row numbers are the rows a spreadsheet shows (the
header is row 1, so the first data row is row 2; blank lines count as rows).

Measurement and certificate files are checked completely before anything is raised: the
error carries every cell-level problem of the file in ``DataError.problems`` (at most
:data:`MAX_PROBLEMS`, with the full count in ``DataError.n_problems``), while ``str(exc)``
stays one line, the first problem plus "(and N more problems)".

This module is the entry point; the code lives in one module per concept, each importing
only those before it:

- :mod:`cmm_core.io_errors`: :class:`DataError`, the problem collector, name checks;
- :mod:`cmm_core.io_csv`: raw bytes, CSV cells and numbers, :func:`read_json`;
- :mod:`cmm_core.io_setup`: :class:`Setup`, :class:`Placement`, :func:`read_setup`;
- :mod:`cmm_core.io_measurements`: :func:`read_measurements`, :func:`write_long_csv`;
- :mod:`cmm_core.io_certificate`: :class:`Certificate`, :func:`read_certificate`;
- :mod:`cmm_core.io_resolve`: :func:`resolve`, :func:`missing_balls`.
"""

from __future__ import annotations

from .io_certificate import (
    MIN_CERTIFICATE_BALLS,
    Certificate,
    _check_isolated_balls,
    _check_plate_frame,
    _uncertainties,
    read_certificate,
    write_certificate,
)
from .io_csv import (
    _COLUMNS_HINT,
    _DECIMAL_COMMA,
    _DELIM_NAMES,
    _NAN_WORDS,
    MAX_BYTES,
    _delimiter,
    _file_rows,
    _names,
    _numeric,
    _read_bytes,
    _read_csv,
    _require,
    _require_rows,
    _too_many_fields,
    read_json,
)
from .io_errors import (
    COLUMN_ALIASES,
    MAX_PROBLEMS,
    DataError,
    _check_keys,
    _cut,
    _fold,
    _Problems,
    _typo,
    refuse_unknown_keys,
)
from .io_measurements import (
    LONG_COLUMNS,
    OPTIONAL_COLUMNS,
    SCALE_TEMP_COLUMNS,
    THESIS_COLUMNS,
    _ball_numbers,
    _check_duplicates,
    _check_units,
    _named,
    read_measurement_files,
    read_measurements,
    write_long_csv,
)
from .io_resolve import (
    _UNIT_RATIOS,
    _check_certificate_in_machine,
    _check_geometry,
    _first_per,
    _first_rows,
    missing_balls,
    resolve,
)
from .io_setup import (
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
    _check_celsius,
    _json_object,
    _range_tolerance,
    _record,
    _vector,
    read_setup,
)

__all__ = [
    # readers, writers and their types
    "DataError", "Setup", "Placement", "Certificate",
    "read_measurements", "read_measurement_files", "read_setup", "read_certificate",
    "read_json", "resolve", "missing_balls", "write_long_csv", "write_certificate",
    # limits and column sets
    "LONG_COLUMNS", "SCALE_TEMP_COLUMNS", "OPTIONAL_COLUMNS", "THESIS_COLUMNS",
    "MAX_BYTES", "MAX_PROBLEMS", "MIN_CERTIFICATE_BALLS", "LAYOUTS", "AXIS_TOLERANCE_DEG",
    "MIN_STROKE_MM", "MAX_STROKE_MM", "MAX_PROBE_MM", "CTE_RANGE_PER_K", "TEMP_RANGE_C",
    "SETUP_KEYS", "COLUMN_ALIASES",
    # Private helpers, re-exported because this module held them all before the split and
    # other modules use them through it (compensate, export, task, analysis, plan_file and
    # simulate_config read their own files with _read_csv, _numeric, _cut, _typo,
    # _check_celsius, ...): every `from cmm_core.io import _x` keeps working.
    "_Problems", "_cut", "_fold", "_typo", "_check_keys", "refuse_unknown_keys",
    "_NAN_WORDS", "_DELIM_NAMES", "_DECIMAL_COMMA", "_COLUMNS_HINT", "_read_bytes",
    "_delimiter", "_too_many_fields", "_read_csv", "_file_rows", "_numeric", "_names",
    "_require", "_require_rows",
    "_range_tolerance", "_record", "_check_celsius", "_json_object", "_vector",
    "_ball_numbers", "_check_duplicates", "_check_units", "_named",
    "_check_isolated_balls", "_uncertainties", "_check_plate_frame",
    "_check_certificate_in_machine", "_UNIT_RATIOS", "_check_geometry", "_first_rows",
    "_first_per",
]

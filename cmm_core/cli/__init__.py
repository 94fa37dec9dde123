"""The command line (``cmm-error-lab``, or ``python -m cmm_core``): one subcommand per task, JSON on stdout with
``--json``, one-line errors on stderr and a non-zero exit (``docs/formats.md``).

Owns: :mod:`.commands` (the parser and :func:`main`), :mod:`.inputs` (shared arguments),
:mod:`.plan` (plan and task), :mod:`.export` (comp-table, results). May import every wing.
"""

from __future__ import annotations

from .commands import (
    MAX_MESSAGE,
    build_parser,
    cmd_air,
    cmd_budget,
    cmd_compensate,
    cmd_diagnose,
    cmd_fit,
    cmd_gp,
    cmd_plan,
    cmd_report,
    cmd_simulate,
    cmd_task,
    main,
    program_name,
)
from .export import AXIS_TABLE_FILES, add_arguments, add_parser, command, output_files, run
from .inputs import (
    CERT_HELP,
    MEAS_HELP,
    ORDER_HELP,
    PLATE_HELP,
    SETUP_HELP,
    CommandChoices,
    add_data_args,
    add_fit_args,
    add_foreign_args,
    add_instrument_args,
    add_outlier_args,
    data_of,
    dataset_of,
    exclusions_of,
    fit_args_of,
    instruments_of,
    number_arg,
    sigma_of,
)
from .plan import (
    MAX_CHECK_TRIALS,
    MAX_TRIALS,
    MAX_WORKERS,
    MIN_TRIALS,
    add_plan_arguments,
    add_task_arguments,
    run_plan,
    run_task,
)

__all__ = [
    "add_arguments", "add_data_args", "add_fit_args", "add_foreign_args", "add_instrument_args",
    "add_outlier_args", "add_parser", "add_plan_arguments", "add_task_arguments",
    "AXIS_TABLE_FILES", "build_parser", "CERT_HELP", "cmd_air", "cmd_budget", "cmd_compensate",
    "cmd_diagnose", "cmd_fit", "CommandChoices", "fit_args_of", "cmd_gp", "cmd_plan", "cmd_report", "cmd_simulate", "cmd_task",
    "command", "data_of", "dataset_of", "exclusions_of", "instruments_of", "main", "MAX_CHECK_TRIALS",
    "MAX_MESSAGE", "MAX_TRIALS", "MAX_WORKERS", "MEAS_HELP", "MIN_TRIALS", "number_arg",
    "ORDER_HELP",
    "output_files", "PLATE_HELP", "program_name", "run", "run_plan", "run_task", "SETUP_HELP", "sigma_of"
]

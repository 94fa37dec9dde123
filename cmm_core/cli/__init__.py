"""The command line (``cmm-error-lab``, or ``python -m cmm_core``): one subcommand per task, JSON on stdout with
``--json``, one-line errors on stderr and a non-zero exit (``docs/formats.md``).

Owns: :mod:`.commands` (:func:`main`), :mod:`.parser` (the parser: every sub-command, its
options and the function it runs), :mod:`.options` (the options several share), and one
module per command or pair of commands that use the same wings: :mod:`.fitting` (fit,
diagnose, gp, reading their data through :mod:`.inputs`), :mod:`.simulate`,
:mod:`.compensate`, :mod:`.budget` (budget, air), :mod:`.report`, :mod:`.plan` (plan,
task), :mod:`.export`, :mod:`.check` (check, compare), :mod:`.proposals` (next),
:mod:`.app` (app: the app's server, standard library only). May import every wing.

A lazy face (PEP 562): :func:`main`, the parser and the options are imported here, and
need the standard library only, so that ``--help`` starts without numpy, scipy, pandas or
plotly (``tests/test_cli_start.py``); a command's functions are imported from their
module on first use of their name here (:data:`_LAZY`), as ``main`` imports a command's
module only when the command runs.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .app import (
    APP_PACKAGE,
    DEFAULT_HOST,
    DEFAULT_PORT,
    add_app_arguments,
    app_folder,
    serve_app,
    server_command,
)
from .commands import main
from .options import (
    CERT_HELP,
    DEFAULT_ORDER,
    DEFAULT_SIGMA_UM,
    MEAS_HELP,
    ORDER_HELP,
    PLATE_HELP,
    SETUP_HELP,
    add_data_args,
    add_fit_args,
    add_foreign_args,
    add_instrument_args,
    add_outlier_args,
    msl_metadata_beside,
    number_arg,
)
from .parser import (
    COMMANDS,
    MAX_CHECK_TRIALS,
    MAX_MESSAGE,
    MAX_TRIALS,
    MAX_WORKERS,
    MIN_TRIALS,
    Subcommand,
    add_command,
    add_export_arguments,
    add_plan_arguments,
    add_task_arguments,
    build_parser,
    program_name,
)

add_arguments = add_export_arguments
"""The options of ``export`` (the name they had when ``export.py`` defined them)."""

if TYPE_CHECKING:
    from .budget import cmd_air, cmd_budget
    from .compensate import cmd_compensate
    from .export import (
        AXIS_TABLE_FILES,
        add_parser,
        command,
        msl_parameters_text,
        output_files,
        run,
    )
    from .fitting import cmd_diagnose, cmd_fit, cmd_gp
    from .inputs import (
        MSL_CLI_NAMES,
        CommandChoices,
        MslInputs,
        data_of,
        dataset_of,
        exclusions_of,
        fit_args_of,
        instruments_of,
        msl_inputs,
        notes_of,
        settle_defaults,
        sigma_of,
    )
    from .plan import cmd_plan, cmd_task, run_plan, run_task
    from .records import command_inputs, provenance_of
    from .report import cmd_report
    from .simulate import cmd_simulate

_LAZY = {
    "cmd_air": "budget", "cmd_budget": "budget", "cmd_compensate": "compensate",
    "AXIS_TABLE_FILES": "export", "add_parser": "export", "command": "export",
    "output_files": "export", "run": "export", "msl_parameters_text": "export",
    "cmd_diagnose": "fitting", "cmd_fit": "fitting", "cmd_gp": "fitting",
    "CommandChoices": "inputs", "command_inputs": "records", "provenance_of": "records",
    "data_of": "inputs", "dataset_of": "inputs",
    "exclusions_of": "inputs", "fit_args_of": "inputs", "instruments_of": "inputs",
    "sigma_of": "inputs", "MSL_CLI_NAMES": "inputs", "MslInputs": "inputs",
    "msl_inputs": "inputs", "notes_of": "inputs", "settle_defaults": "inputs",
    "cmd_plan": "plan", "cmd_task": "plan", "run_plan": "plan", "run_task": "plan",
    "cmd_report": "report", "cmd_simulate": "simulate",
}
"""Name -> the module of this wing that defines it, for the names this face imports on
first use (their modules load the core's wings)."""


def __getattr__(name: str):
    """A name of :data:`_LAZY`, imported from its module on first use (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    # lazy: a command's module loads numpy, scipy, pandas (the face's light names do not)
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


__all__ = [
    "add_app_arguments", "APP_PACKAGE", "app_folder", "DEFAULT_HOST", "DEFAULT_PORT",
    "serve_app", "server_command", "command_inputs", "provenance_of", "add_arguments", "add_command", "add_data_args", "add_export_arguments", "add_fit_args",
    "add_foreign_args", "add_instrument_args", "add_outlier_args", "add_parser",
    "add_plan_arguments", "add_task_arguments", "AXIS_TABLE_FILES", "build_parser",
    "CERT_HELP", "cmd_air", "cmd_budget", "cmd_compensate", "cmd_diagnose", "cmd_fit",
    "cmd_gp", "cmd_plan", "cmd_report", "cmd_simulate", "cmd_task", "command",
    "CommandChoices", "COMMANDS", "data_of", "dataset_of", "exclusions_of", "fit_args_of",
    "instruments_of", "main", "MAX_CHECK_TRIALS", "MAX_MESSAGE", "MAX_TRIALS", "MAX_WORKERS",
    "MEAS_HELP", "MIN_TRIALS", "number_arg", "ORDER_HELP", "output_files", "PLATE_HELP",
    "program_name", "run", "run_plan", "run_task", "SETUP_HELP", "sigma_of", "Subcommand",
    "DEFAULT_ORDER", "DEFAULT_SIGMA_UM", "msl_metadata_beside", "MSL_CLI_NAMES", "MslInputs",
    "msl_inputs", "notes_of", "settle_defaults", "msl_parameters_text",
]

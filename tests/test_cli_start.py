"""``cmm-error-lab --help`` and ``COMMAND --help`` start at once: building the parser needs
the standard library only, and a command imports its module (and the core's wings it
uses) only when it runs (``cmm_core/cli/parser.py``). Checked by what a child process has
imported, never by a clock (``bench/cli_start.py`` measures the time)."""

from __future__ import annotations

import argparse
import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from cmm_core import cli
from cmm_core.cli import build_parser, options, parser

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "scipy", "pandas", "plotly", "streamlit")

# in a child process: run main(argv), then print what it imported of HEAVY as the last line
CHILD = """
import json, sys
from cmm_core.cli import main
try:
    code = main(json.loads(sys.argv[1]))
except SystemExit as exc:
    code = exc.code
print(json.dumps({"exit": code, "heavy": sorted(m for m in sys.argv[2:] if m in sys.modules)}))
"""


def _subcommands() -> list[str]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return list(sub.choices)


def _child(argv: list[str]) -> dict:
    done = subprocess.run([sys.executable, "-c", CHILD, json.dumps(argv), *HEAVY], cwd=ROOT,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_parser_lists_every_command_of_the_table():
    assert _subcommands() == list(parser.COMMANDS)
    assert len(_subcommands()) >= 14


@pytest.mark.parametrize("argv", [["--help"]] + [[c, "--help"] for c in _subcommands()],
                         ids=lambda argv: " ".join(argv))
def test_help_imports_no_heavy_module(argv):
    out = _child(argv)
    assert out == {"exit": 0, "heavy": []}


def test_a_usage_error_imports_no_heavy_module():
    assert _child(["fit", "--bogus"]) == {"exit": 2, "heavy": []}
    assert _child(["no-such-command"]) == {"exit": 2, "heavy": []}


def test_python_m_cmm_core_help_imports_no_heavy_module():
    code = ("import runpy, sys\nsys.argv = ['cmm_core', 'fit', '--help']\n"
            "try:\n    runpy.run_module('cmm_core', run_name='__main__')\n"
            "except SystemExit as exc:\n    assert exc.code == 0, exc.code\n"
            f"print([m for m in {HEAVY!r} if m in sys.modules])")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, check=True)
    assert "--sigma-um UM" in done.stdout
    assert done.stdout.strip().splitlines()[-1] == "[]"


def test_the_package_and_the_cli_face_import_light():
    code = ("import sys, cmm_core, cmm_core.cli\n"
            f"print([m for m in {HEAVY!r} if m in sys.modules])")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, check=True)
    assert done.stdout.strip() == "[]"


@pytest.mark.parametrize("name", list(parser.COMMANDS))
def test_every_command_names_a_function_of_a_cli_module(name):
    """The table's ``"module:function"`` names import (the parser never does) and name a
    function of the command line's own wing, so the wing rules of its imports hold."""
    module, function = parser.COMMANDS[name].run.split(":")
    assert (ROOT / "cmm_core" / "cli" / f"{module}.py").is_file(), module
    assert callable(getattr(importlib.import_module(f"cmm_core.cli.{module}"), function))


def test_the_limits_in_the_help_texts_are_the_cores():
    """``cli.options`` copies the limits its help texts state (a wing's face loads the
    whole wing, numpy with it): each copy is the value of the wing that owns it."""
    from cmm_core.model import MAX_ORDER
    from cmm_core.monitor import MAX_MAP_NODES_PER_AXIS
    from cmm_core.plan import TARGET_POWER

    assert options._MAX_ORDER == MAX_ORDER
    assert options._TARGET_POWER == TARGET_POWER
    assert options._MAX_MAP_NODES_PER_AXIS == MAX_MAP_NODES_PER_AXIS


def test_the_lazy_face_names_are_their_modules_objects():
    for name, module in cli._LAZY.items():
        assert name in cli.__all__, name
        assert getattr(cli, name) is getattr(importlib.import_module(f"cmm_core.cli.{module}"),
                                             name)
    with pytest.raises(AttributeError):
        cli.no_such_name  # noqa: B018

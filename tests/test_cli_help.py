"""`python -m cmm_core COMMAND --help` is documentation a metrologist reads (issue 16):
every option of every sub-command has help text saying its unit (where it has one) and
its default (or that it is required)."""

import argparse
import re
import subprocess
import sys
from pathlib import Path

import pytest

from cmm_core.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


def _subparsers():
    ap = build_parser()
    sub = next(a for a in ap._actions if isinstance(a, argparse._SubParsersAction))
    return [("(top level)", ap)] + list(sub.choices.items())


def _options(parser):
    return [a for a in parser._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]


@pytest.mark.parametrize("name,parser", _subparsers(), ids=lambda v: v if isinstance(v, str)
                         else "")
def test_every_option_has_help_with_its_default(name, parser):
    for a in _options(parser):
        text = (a.help or "") % {"default": a.default} if a.help else ""
        assert len(text) > 15, f"{name} {a.option_strings or a.dest}: no help text"
        if a.option_strings and not isinstance(a, argparse._StoreTrueAction):
            assert a.required or "default" in text.lower(), \
                f"{name} {a.option_strings}: help says neither the default nor 'required'"
            if a.required:
                assert "required" in text.lower(), f"{name} {a.option_strings}"


def test_units_named_where_options_carry_them():
    """Options whose name carries a unit say it in words too; lengths say mm."""
    units = {"_um": "µm", "_C": "°C", "_Pa": "Pa", "_percent": "%", "_nm": "nm"}
    for name, parser in _subparsers():
        for a in _options(parser):
            for suffix, unit in units.items():
                if a.dest.endswith(suffix):
                    assert unit in (a.help % {"default": a.default}), (name, a.dest)
    helps = {n: " ".join(a.help for a in _options(p)) for n, p in _subparsers()}
    for cmd in ("fit", "diagnose", "gp"):
        assert "mm" in helps[cmd] and "docs/formats.md" in helps[cmd]


def test_help_runs_and_never_points_outside_the_repository():
    out = subprocess.run([sys.executable, "-m", "cmm_core", "diagnose", "--help"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    assert "--sigma-um UM" in out and "default: 0.5 µm" in out
    for name, parser in _subparsers():
        text = parser.format_help()
        assert not re.search(r"SPEC\.md|\.\./shared", text), name


@pytest.mark.parametrize("argv0, prog", [
    ("/home/u/lab/.venv/bin/cmm-error-lab", "cmm-error-lab"),
    ("/home/u/lab/cmm_core/__main__.py", "python -m cmm_core"),
    ("", "python -m cmm_core")])
def test_usage_names_the_command_as_it_was_called(monkeypatch, argv0, prog):
    """The installed console script is named in usage lines and error hints as the user
    typed it; ``python -m cmm_core`` otherwise."""
    monkeypatch.setattr(sys, "argv", [argv0])
    ap = build_parser()
    assert ap.prog == prog
    with pytest.raises(SystemExit):
        ap.parse_args(["fit", "--bogus"])

"""Every command line of the README's "Command line" section runs as written (issue 27).

The block is read from README.md itself, so an example that drifts from the product fails
here. Each line (continuations joined, comments dropped) runs in bash from a folder that
holds ``sample_data`` (a link to the checkout's) and the ``out/`` the examples write into,
with the venv's ``cmm-error-lab`` first on PATH, as after ``make run``/``make test``. Each
must exit 0 and print no traceback; a command that prints JSON must print valid JSON.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    """The shell lines of the first fenced block after ``## Command line``."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Command line"):]
    block = re.search(r"```\n(.*?)```", section, re.S)
    assert block, "README: no fenced block in the Command line section"
    joined = block.group(1).replace("\\\n", " ")
    lines = []
    for line in joined.splitlines():
        line = re.sub(r"\s+#.*$", "", line).strip()  # a comment after the command
        if line and not line.startswith("#"):
            lines.append(line)
    return lines


COMMANDS = readme_commands()


def test_the_block_covers_every_command_of_the_cli():
    """Each subcommand of the parser has at least one example that runs."""
    from cmm_core.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    shown = {c.split()[1] for c in COMMANDS if c.startswith("cmm-error-lab ")}
    assert set(sub.choices) - shown == set()


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("readme")
    (d / "sample_data").symlink_to(ROOT / "sample_data")
    return d


@pytest.mark.slow
def test_every_readme_command_runs_as_written(workdir):
    # in order: later lines read what earlier ones wrote (out/thesis_model.json, out/sim)
    exe = Path(sys.executable).parent
    if shutil.which("cmm-error-lab", path=str(exe)) is None:
        pytest.skip("cmm-error-lab is not installed in this venv (make run/test installs it)")
    env = {**os.environ, "PATH": f"{exe}{os.pathsep}{os.environ.get('PATH', '')}"}
    before = {p: p.stat().st_mtime_ns for p in (ROOT / "sample_data").rglob("*") if p.is_file()}
    for cmd in COMMANDS:
        r = subprocess.run(["bash", "-c", cmd], cwd=workdir, env=env, capture_output=True,
                           text=True, timeout=600)
        assert r.returncode == 0, f"{cmd}\n{r.stderr[-2000:]}"
        assert "Traceback" not in r.stderr, cmd
        if r.stdout.lstrip().startswith("{"):
            json.loads(r.stdout)
    # the examples only read the samples
    after = {p: p.stat().st_mtime_ns for p in (ROOT / "sample_data").rglob("*") if p.is_file()}
    assert after == before
    assert (workdir / "out" / "corrected.csv").stat().st_size > 0
    assert (workdir / "out" / "report.html").read_text(encoding="utf-8").startswith("<!")

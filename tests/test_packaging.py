"""What a lab installs: the lock files, and the wheel with the app inside it.

The wheel test builds the wheel from a copy of the checkout, installs it with the locked
versions in a fresh virtual environment, starts ``cmm-error-lab app`` from a folder
outside the checkout and loads the first page in a real browser.
"""

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
from conftest import free_port, wait_until_served
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
PIN = re.compile(r"^([A-Za-z0-9_.\-]+)==([^\s;]+)")


def _pins(name: str) -> dict[str, str]:
    pins = {}
    for line in (ROOT / name).read_text(encoding="utf-8").splitlines():
        m = PIN.match(line)
        if m:
            pins[m[1].lower().replace("_", "-")] = m[2]
    return pins


def _requirements(name: str) -> list[Requirement]:
    out = []
    for line in (ROOT / name).read_text(encoding="utf-8").splitlines():
        line = line.split("#", 1)[0].strip()
        if line and not line.startswith("-"):
            out.append(Requirement(line))
    return out


@pytest.mark.parametrize(("requirements", "lock"), [
    ("requirements.txt", "requirements-lock.txt"),
    ("requirements-test.txt", "requirements-test-lock.txt"),
])
def test_the_lock_pins_every_requirement_within_its_bounds(requirements, lock):
    pins = _pins(lock)
    reqs = _requirements(requirements)
    if requirements == "requirements-test.txt":
        reqs += _requirements("requirements.txt")
    for req in reqs:
        name = req.name.lower().replace("_", "-")
        assert name in pins, f"{lock} does not pin {req.name}: run `make lock`"
        assert req.specifier.contains(pins[name], prereleases=True), (
            f"{lock} pins {name}=={pins[name]} outside {req.specifier}: run `make lock`")


def test_the_app_and_the_tests_run_on_the_same_versions():
    """The runtime lock is the tested one: every package both files pin has one version."""
    runtime, test = _pins("requirements-lock.txt"), _pins("requirements-test-lock.txt")
    assert runtime, "requirements-lock.txt pins nothing"
    differ = {k: (v, test[k]) for k, v in runtime.items() if k in test and test[k] != v}
    missing = sorted(set(runtime) - set(test))
    assert not differ and not missing, (differ, missing)


# --- the wheel, installed in a fresh virtual environment -------------------------------

COPY_IGNORE = shutil.ignore_patterns(".venv", "build", "dist", "*.egg-info", "__pycache__",
                                     ".pytest_cache", ".ruff_cache", ".mypy_cache",
                                     ".hypothesis", "artifacts")


def _bin(venv: Path, name: str) -> Path:
    return venv / ("Scripts" if os.name == "nt" else "bin") / name


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """A wheel built from a copy of this checkout (its git history with it, so the wheel
    records the commit), installed with the locked versions in a new environment."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=COPY_IGNORE)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                    "--no-build-isolation", "-w", str(tmp / "dist"), str(src)],
                   check=True, capture_output=True, timeout=600)
    (wheel,) = (tmp / "dist").glob("cmm_error_lab-*.whl")
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    out = subprocess.run([str(_bin(venv, "python")), "-m", "pip", "install", "-q", str(wheel),
                          "-r", str(ROOT / "requirements-lock.txt")],
                         capture_output=True, text=True, timeout=1200)
    assert out.returncode == 0, out.stderr[-3000:]
    away = tmp / "elsewhere"  # not the checkout: nothing found by relative paths
    away.mkdir()
    return wheel, venv, away


@pytest.mark.slow
def test_the_wheel_holds_the_app_and_the_sample_data_and_nothing_of_the_checkout(installed):
    wheel, _, _ = installed
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in ("cmm_error_lab_app/app.py", "cmm_error_lab_app/serve.py",
                 "cmm_error_lab_app/.streamlit/config.toml",
                 "cmm_error_lab_app/pages/data.py", "cmm_error_lab_app/pages/ui/__init__.py",
                 "cmm_error_lab_app/pages/ui/panels/upload.py",
                 "cmm_core/sample_data/thesis/BP111.csv", "cmm_core/cli/__init__.py",
                 "cmm_core/_commit.json"):
        assert name in names, name
    pages = {p.relative_to(ROOT).as_posix() for p in (ROOT / "pages").rglob("*.py")}
    assert {f"cmm_error_lab_app/{p}" for p in pages} <= names
    assert not [n for n in names if n.startswith(("tests/", "cmm_error_lab_app/tests"))
                or n.endswith("/setup.py") and not n.startswith("cmm_core/io/")]


@pytest.mark.slow
def test_the_installed_package_names_its_commit_and_finds_its_sample_data(installed):
    _, venv, away = installed
    code = ("import json; from cmm_core.io import SAMPLE_DIR, software_identity; "
            "print(json.dumps([str(SAMPLE_DIR), software_identity()]))")
    out = subprocess.run([str(_bin(venv, "python")), "-c", code], cwd=away,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    sample, ident = json.loads(out.stdout)
    assert Path(sample).is_relative_to(venv) and (Path(sample) / "thesis" / "BP111.csv").is_file()
    if (ROOT / ".git").exists():
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
        assert ident["commit"] == head


@pytest.mark.slow
def test_cmm_error_lab_app_serves_the_first_page_from_the_installed_wheel(installed):
    """Started outside the checkout: the server answers on 127.0.0.1 (not on the
    computer's other addresses), and a browser gets the Data page with its sidebar."""
    _, venv, away = installed
    port = free_port()
    proc = subprocess.Popen([str(_bin(venv, "cmm-error-lab")), "app", "--port", str(port)],
                            cwd=away, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        wait_until_served(proc, url)
        listening = [c for c in _listening() if c[1] == port]
        assert listening and all(addr == "127.0.0.1" for addr, _ in listening), listening
        if not Path(CHROMIUM).exists():
            pytest.skip(f"{CHROMIUM} is not installed: the server answered, no page loaded")
        sync_playwright = pytest.importorskip("playwright.sync_api").sync_playwright
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True,
                                         args=["--no-sandbox", "--disable-gpu"])
            page = browser.new_page()
            page.goto(url, timeout=90_000)
            page.get_by_role("heading", name="Data").first.wait_for(timeout=90_000)
            assert page.locator('[data-testid="stSidebar"]').get_by_text(
                "CMM error lab").count() >= 1
            assert page.locator('[data-testid="stException"]').count() == 0
            browser.close()
    finally:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
    # the server runs in a child of the command: stopped with it (SIGTERM passed on),
    # nothing listens on the port any more (servers of earlier runs outlived it)
    deadline = time.monotonic() + 20
    while any(c[1] == port for c in _listening()) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(c[1] == port for c in _listening())


def _listening() -> list[tuple[str, int]]:
    """(address, port) of every listening TCP socket of this computer, from /proc
    (Linux; empty elsewhere). IPv6 addresses are given as ``ipv6:`` and their hex digits:
    the app must have none."""
    out = []
    for table in ("tcp", "tcp6"):
        path = Path("/proc/net") / table
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A":  # LISTEN
                hex_addr, hex_port = fields[1].split(":")
                addr = (socket.inet_ntoa(bytes.fromhex(hex_addr)[::-1]) if table == "tcp"
                        else "ipv6:" + hex_addr)
                out.append((addr, int(hex_port, 16)))
    return out

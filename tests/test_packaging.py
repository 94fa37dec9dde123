"""What a lab installs: the lock files, and the wheel with the app inside it.

The wheel test builds the wheel from a copy of the checkout, installs it with the locked
versions in a fresh virtual environment, starts ``cmm-error-lab app`` from a folder
outside the checkout and loads the first page in a real browser.
"""

import re
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
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

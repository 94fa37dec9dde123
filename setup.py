"""Where the wheel's files come from (the rest of the packaging is in ``pyproject.toml``).

Two packages: ``cmm_core`` (the analysis, with the checkout's ``sample_data/`` folder as its
``cmm_core/sample_data`` data) and ``cmm_error_lab_app`` (the checkout's ``app.py``,
``serve.py``, ``pages/`` and ``.streamlit/``), which ``cmm-error-lab app`` starts from
wherever it is installed. The checkout keeps the layout its users know (``app.py`` and
``pages/`` at the top); only the wheel names them as a package. A ``setup.py`` because
``pyproject.toml`` cannot both find the core's subpackages and map the app's folders.
"""

import json
import subprocess
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

APP = "cmm_error_lab_app"
APP_PACKAGES = {APP: ".", f"{APP}.pages": "pages", f"{APP}.pages.ui": "pages/ui",
                f"{APP}.pages.ui.panels": "pages/ui/panels"}



HERE = Path(__file__).resolve().parent


def _git(*args):
    try:
        out = subprocess.run(["git", "-C", str(HERE), *args], capture_output=True,
                             text=True, timeout=30, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


class BuildPy(build_py):
    """``build_py`` that leaves this file out of the app package mapped onto the checkout's
    top folder (setuptools skips its own script only when run as ``python setup.py``),
    and records the commit it was built from in ``cmm_core/_commit.json`` (an installed
    package has no git checkout to ask: cmm_core.io.provenance reads it)."""

    def find_package_modules(self, package, package_dir):
        return [m for m in super().find_package_modules(package, package_dir)
                if not (package == APP and m[1] == "setup")]

    def run(self):
        super().run()
        commit = _git("rev-parse", "HEAD") if (HERE / ".git").exists() else None
        if commit:
            status = _git("status", "--porcelain", "--untracked-files=no")
            target = Path(self.build_lib) / "cmm_core" / "_commit.json"
            target.write_text(json.dumps({"commit": commit, "dirty": bool(status)}),
                              encoding="utf-8")


setup(
    cmdclass={"build_py": BuildPy},
    packages=[*find_packages(include=["cmm_core", "cmm_core.*"]), "cmm_core.sample_data",
              *APP_PACKAGES],
    package_dir={"cmm_core.sample_data": "sample_data", **APP_PACKAGES},
    package_data={"cmm_core.sample_data": ["**/*"], APP: [".streamlit/config.toml"]},
    include_package_data=False,
)

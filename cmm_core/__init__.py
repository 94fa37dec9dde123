"""CMM error lab core: data, kinematic error model, fitting, uncertainty, GP, diagnosis.

Lengths are mm in files and in the geometry; errors and residuals are µm; rotations µrad.
The wings and what each may import: docs/architecture.md, "The core, in wings".
"""

from importlib import metadata as _metadata
from pathlib import Path as _Path


def _version() -> str:
    """The one version number, ``pyproject.toml``'s: from the installed package's metadata,
    else (a checkout run in place, as ``make run`` does) read from the file itself."""
    try:
        return _metadata.version("cmm-error-lab")
    except _metadata.PackageNotFoundError:
        import tomllib  # lazy: only a checkout that is not installed needs it

        with open(_Path(__file__).resolve().parents[1] / "pyproject.toml", "rb") as f:
            return tomllib.load(f)["project"]["version"]


__version__ = _version()

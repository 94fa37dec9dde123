"""Where a record came from: the software, its inputs, the machine and the day.

ISO/IEC 17025 (7.5, 7.11) asks a laboratory to identify the software that made a result and
to keep records from which the result can be traced to its inputs. Every file this project
writes (model, results JSON and XML, HTML report, project file, analysis record,
compensation tables) carries a :class:`Provenance`: the software's name and version, the
git commit it ran from (with a flag when the checkout had uncommitted changes), the time
the record was made, the SHA-256 of each input file, the machine's identity and the
calibration's date (the setup's ``machine.id`` and ``calibration_date``, docs/formats.md),
and the Python and operating system it ran on.

The commit comes from ``git`` when the package runs from a checkout, else from the
``_commit.json`` a wheel build writes beside this package; neither present (a source copy
without git) gives None, said as "commit unknown".
"""

from __future__ import annotations

import datetime as _dt
import functools
import hashlib
import json
import platform
import re
import subprocess
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from .. import __version__
from .errors import DataError, cut_repr

__all__ = ["COMMIT_FILE", "InputFile", "Provenance", "SOFTWARE", "file_input", "input_file",
           "provenance", "provenance_from_dict", "software_identity"]

SOFTWARE = "cmm-error-lab"
"""The software's name in every record."""
COMMIT_FILE = "_commit.json"
"""Written into the package by a wheel build: ``{"commit": ..., "dirty": ...}``."""
_PACKAGE = Path(__file__).resolve().parents[1]
_SHA256 = re.compile(r"[0-9a-f]{64}")


@dataclass(frozen=True)
class InputFile:
    """One input of a record, identified by its content."""

    name: str
    """The file's name as the record names it."""
    sha256: str
    """SHA-256 of the file's bytes, 64 hex digits: the same file gives the same digest on
    any computer; one changed byte gives another."""
    n_bytes: int
    """The file's size in bytes."""

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {"name": self.name, "sha256": self.sha256, "bytes": self.n_bytes}


def input_file(name: str, data: bytes | str) -> InputFile:
    """The :class:`InputFile` of ``data`` (text is hashed as its UTF-8 bytes)."""
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    return InputFile(str(name), hashlib.sha256(raw).hexdigest(), len(raw))


def file_input(path: str | Path, name: str | None = None) -> InputFile:
    """The :class:`InputFile` of the file at ``path`` (named ``name``, default its file
    name), its digest computed in blocks: a file streamed by its reader (the points of
    ``compensate``) is hashed without being held in memory."""
    p = Path(path)
    with p.open("rb") as fh:
        digest = hashlib.file_digest(fh, "sha256")
        n = fh.tell()
    return InputFile(str(name or p.name), digest.hexdigest(), n)


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(_PACKAGE.parent), *args], capture_output=True,
                             text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):  # no git on this computer
        return None
    return out.stdout if out.returncode == 0 else None


@functools.cache
def software_identity() -> dict:
    """``{"software", "version", "commit", "dirty", "python", "system"}`` of this process
    (computed once: a checkout's commit does not change under a running program that
    could tell)."""
    commit, dirty = None, None
    if (_PACKAGE.parent / ".git").exists():
        head = _git("rev-parse", "HEAD")
        if head:
            commit = head.strip()
            status = _git("status", "--porcelain", "--untracked-files=no")
            dirty = None if status is None else bool(status.strip())
    else:
        try:
            built = json.loads((_PACKAGE / COMMIT_FILE).read_text(encoding="utf-8"))
            commit, dirty = built.get("commit"), built.get("dirty")
        except (OSError, ValueError, AttributeError):
            pass
    return {"software": SOFTWARE, "version": __version__, "commit": commit, "dirty": dirty,
            "python": platform.python_version(), "system": platform.platform(terse=True)}


@dataclass(frozen=True)
class Provenance:
    """Where a record came from (the module docstring); written as the record's
    ``provenance`` object and read back by :func:`provenance_from_dict`."""

    version: str
    """The software's version (``cmm-error-lab`` MAJOR.MINOR.PATCH, CHANGELOG.md)."""
    commit: str | None
    """The git commit it ran from; None: not known (see the module docstring)."""
    dirty: bool | None
    """The checkout had uncommitted changes: the commit alone does not identify the code."""
    created: str
    """When the record was made: ISO 8601 in UTC, to the second."""
    inputs: tuple[InputFile, ...] = ()
    """Each input file with its SHA-256."""
    machine: str | None = None
    """The machine's identity (name and serial) from the setup; None: the setup names none."""
    calibration_date: str | None = None
    """The calibration's date (ISO 8601) from the setup; None: not stated."""
    python: str = ""
    """The Python version it ran on."""
    system: str = ""
    """The operating system it ran on."""
    software: str = SOFTWARE
    """The software's name."""
    extra: Mapping[str, Any] = field(default_factory=dict)
    """Record-specific facts (the stored model a check used, for instance)."""

    def to_dict(self) -> dict:
        """JSON-ready form (the ``provenance`` object of every record)."""
        out = {"software": self.software, "version": self.version, "commit": self.commit,
               "dirty": self.dirty, "created": self.created,
               "inputs": [f.to_dict() for f in self.inputs], "machine": self.machine,
               "calibration_date": self.calibration_date, "python": self.python,
               "system": self.system}
        return {**out, **dict(self.extra)}

    @property
    def code(self) -> str:
        """``cmm-error-lab 0.8.0 (commit 1a2b3c4d5e6f, with uncommitted changes)``."""
        commit = ("commit unknown" if self.commit is None else f"commit {self.commit[:12]}"
                  + (", with uncommitted changes" if self.dirty else ""))
        return f"{self.software} {self.version} ({commit})"

    @property
    def machine_text(self) -> str:
        """The machine and calibration date in words, "not named" when unknown."""
        name = self.machine or "machine not named (setup key machine.id)"
        return name + (f", calibrated {self.calibration_date}" if self.calibration_date
                       else ", calibration date not stated")

    def lines(self) -> list[str]:
        """The provenance as text lines (headers of text tables, the report)."""
        return [f"software: {self.code}; Python {self.python} on {self.system}",
                f"made: {self.created}", f"machine: {self.machine_text}",
                *(f"input: {f.name} sha256:{f.sha256} ({f.n_bytes} bytes)"
                  for f in self.inputs)]

    def with_inputs(self, inputs: Iterable[InputFile]) -> Provenance:
        """The same provenance with ``inputs`` added after its own (none twice)."""
        seen = {(f.name, f.sha256) for f in self.inputs}
        more = tuple(f for f in inputs if (f.name, f.sha256) not in seen)
        return replace(self, inputs=self.inputs + more)


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()


def provenance(inputs: Iterable[InputFile] = (), *, machine: str | None = None,
               calibration_date: str | None = None, now: str | None = None,
               extra: Mapping[str, Any] | None = None) -> Provenance:
    """The provenance of a record made now by this process from ``inputs``.

    Parameters
    ----------
    inputs : iterable of InputFile
        The record's input files (:func:`input_file`).
    machine, calibration_date : str, optional
        The setup's ``machine.id`` and ``calibration_date``.
    now : str, optional
        The record's time (ISO 8601); default the current time in UTC.
    extra : mapping, optional
        Record-specific facts, written beside the standard keys.
    """
    ident = software_identity()
    return Provenance(ident["version"], ident["commit"], ident["dirty"], now or _now(),
                      tuple(inputs), machine, calibration_date, ident["python"],
                      ident["system"], ident["software"], dict(extra or {}))


_KEYS = ("software", "version", "commit", "dirty", "created", "inputs", "machine",
         "calibration_date", "python", "system")


def _expect(ok: bool, name: str, key: str, expected: str, found: Any) -> None:
    if not ok:
        raise DataError(f"provenance.{key}: expected {expected}, found {cut_repr(found)}.",
                        file=name, column=f"provenance.{key}",
                        hint="the provenance is written by the software; do not edit it.")


def provenance_from_dict(d: Any, name: str = "record") -> Provenance:
    """Read a record's ``provenance`` object back, checking each field (DataError naming
    the file and the key)."""
    _expect(isinstance(d, dict), name, "", "a JSON object", d)
    missing = [k for k in _KEYS if k not in d]
    _expect(not missing, name, missing[0] if missing else "", "the key", "none")
    for key in ("software", "version", "created", "python", "system"):
        _expect(isinstance(d[key], str), name, key, "a string", d[key])
    for key in ("commit", "machine", "calibration_date"):
        _expect(d[key] is None or isinstance(d[key], str), name, key, "a string or null",
                d[key])
    _expect(d["dirty"] is None or isinstance(d["dirty"], bool), name, "dirty",
            "true, false or null", d["dirty"])
    _expect(isinstance(d["inputs"], list), name, "inputs", "a list", d["inputs"])
    files = []
    for i, f in enumerate(d["inputs"]):
        ok = (isinstance(f, dict) and isinstance(f.get("name"), str)
              and isinstance(f.get("sha256"), str) and _SHA256.fullmatch(f["sha256"])
              is not None and isinstance(f.get("bytes"), int) and f["bytes"] >= 0)
        _expect(ok, name, f"inputs[{i}]",
                'an object {"name", "sha256": 64 hex digits, "bytes"}', f)
        files.append(InputFile(f["name"], f["sha256"], f["bytes"]))
    extra = {k: v for k, v in d.items() if k not in _KEYS}
    return Provenance(d["version"], d["commit"], d["dirty"], d["created"], tuple(files),
                      d["machine"], d["calibration_date"], d["python"], d["system"],
                      d["software"], extra)

"""Analyses kept on disk between browser sessions: a reload (F5), or the same URL opened in
a new tab, finds the analysis where it was left.

The app names each analysis by a random session id carried in the URL (``?session=...``)
and keeps its project file (:func:`cmm_core.analysis.record_to_project_json`, the format a
user downloads from *Compensate and export*) in a per-user folder, one file per id. Only
whoever has the URL reaches an analysis: the id is 128 random bits, and a browser that
opens the app without one starts a new analysis. The files are written atomically
(:func:`cmm_core.io.atomic_write_text`), so a reload during a save finds the previous
state, never half a file.

Folder (:func:`default_session_folder`): ``$CMM_LAB_SESSIONS`` when set, else the place
each operating system keeps a program's per-user state: ``cmm-error-lab/sessions`` in
``%LOCALAPPDATA%`` on Windows, ``~/Library/Application Support/cmm-error-lab/sessions`` on macOS,
``$XDG_STATE_HOME/cmm-error-lab/sessions`` (``~/.local/state/...``) elsewhere. On POSIX
systems the folder is readable by its owner only (0700) and so is each file (0600): on a
shared computer another account cannot list or read the analyses. Files not written for
:data:`KEEP_DAYS` days are removed when a new analysis starts.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import secrets
import stat
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from ..io import atomic_write_text

__all__ = ["KEEP_DAYS", "LOCK_WAIT_S", "MAX_SESSION_BYTES", "PRIVATE_FILE", "PRIVATE_FOLDER",
           "SessionConflict", "STALE_LOCK_S", "text_digest", "SavedSession", "SessionStore", "default_session_folder",
           "new_session_id", "valid_session_id"]

KEEP_DAYS = 30
"""Days an analysis nobody has opened is kept (a month of a calibration campaign)."""

_ID = re.compile(r"[0-9a-f]{32}")


def new_session_id() -> str:
    """A fresh id: 32 hex digits (128 random bits from :mod:`secrets`)."""
    return secrets.token_hex(16)


def valid_session_id(sid: object) -> bool:
    """Whether ``sid`` has the form :func:`new_session_id` gives; anything else (a path, a
    guess of another form) is never turned into a file name."""
    return isinstance(sid, str) and _ID.fullmatch(sid) is not None


MAX_SESSION_BYTES = 100_000_000
"""Largest saved analysis a reload reads (bytes): twice the largest upload, since a session
carries its files' text; a bigger file named like a session is not read."""
PRIVATE_FOLDER = 0o700
"""Mode of the sessions folder on POSIX systems: its owner only."""
PRIVATE_FILE = 0o600
"""Mode of each saved analysis on POSIX systems."""


def default_session_folder(platform: str | None = None,
                           environ: dict[str, str] | None = None,
                           home: Path | None = None) -> Path:
    """The per-user folder of saved analyses (see the module docstring).

    Parameters
    ----------
    platform, environ, home : optional
        ``sys.platform``, ``os.environ`` and the home folder, by default this computer's
        (given to show where another system keeps them).
    """
    platform = sys.platform if platform is None else platform
    env = os.environ if environ is None else environ
    home = Path.home() if home is None else home
    if env.get("CMM_LAB_SESSIONS"):
        return Path(env["CMM_LAB_SESSIONS"])
    if platform.startswith("win"):
        base = Path(env.get("LOCALAPPDATA") or home / "AppData" / "Local")
    elif platform == "darwin":
        base = home / "Library" / "Application Support"
    else:
        base = Path(env.get("XDG_STATE_HOME") or home / ".local" / "state")
    return base / "cmm-error-lab" / "sessions"


def text_digest(text: str) -> str:
    """SHA-256 of a saved analysis's text: what a tab last saw of its file."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class SessionConflict(Exception):
    """The analysis's file changed since this tab last read or wrote it: another tab or
    window of the same analysis saved in between. The later save is refused, never lost
    silently: the tab is asked to reload."""


LOCK_WAIT_S = 5.0
"""Seconds a save waits for another save of the same analysis to finish."""
STALE_LOCK_S = 60.0
"""A lock older than this (a server killed mid-save) is taken over."""


@dataclass(frozen=True)
class SavedSession:
    """An analysis found on disk."""

    session_id: str
    """Its id (the URL's ``session`` parameter)."""
    path: Path
    """The project file it is kept in."""
    text: str
    """The project file's content (JSON)."""
    saved: float
    """When it was last written (seconds since the epoch)."""

    @property
    def digest(self) -> str:
        """:func:`text_digest` of the file as read: the ``expected`` of the next save."""
        return text_digest(self.text)

    @property
    def saved_text(self) -> str:
        """The save time in local time, ``YYYY-MM-DD HH:MM``."""
        return time.strftime("%Y-%m-%d %H:%M", time.localtime(self.saved))


@dataclass(frozen=True)
class SessionStore:
    """The folder of saved analyses, one project file per session id."""

    folder: Path
    """Where the files are (created on the first save)."""

    def path(self, sid: str) -> Path:
        """The file of session ``sid``; a malformed id is refused (ValueError)."""
        if not valid_session_id(sid):
            raise ValueError(f"session id: expected 32 hex digits, found {sid!r}.")
        return self.folder / f"{sid}.json"

    def save(self, sid: str, text: str, expected: str | None | bool = True) -> Path:
        """Write the analysis of ``sid`` (atomically) and return its path.

        ``expected``: the :func:`text_digest` of the file as this writer last read or wrote
        it (None: it had no file yet); when the file on disk is another, another tab saved
        in between and :class:`SessionConflict` is raised with nothing written. ``True``
        (the default) writes whatever is there. One save of an analysis at a time: a lock
        file beside it (created exclusively, which every operating system provides) keeps
        two servers or threads from interleaving the check and the write."""
        p = self.path(sid)
        p.parent.mkdir(parents=True, exist_ok=True, mode=PRIVATE_FOLDER)
        if os.name == "posix":  # a folder made before this rule, or by a wider umask
            os.chmod(p.parent, PRIVATE_FOLDER)
        with self._locked(sid):
            if p.is_symlink():  # planted in the folder: a save would write where it points
                p.unlink()
            if expected is not True:
                now = self.load(sid)
                if (now.digest if now is not None else None) != expected:
                    raise SessionConflict(
                        "this analysis was changed in another tab or window since this "
                        "one last saved it; reload the page to see that version (the "
                        "change made here is not saved).")
            atomic_write_text(p, text)
            if os.name == "posix":
                os.chmod(p, PRIVATE_FILE)
        return p

    @contextlib.contextmanager
    def _locked(self, sid: str) -> Iterator[None]:
        lock = self.folder / f"{sid}.lock"
        deadline = time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, PRIVATE_FILE)
                break
            except FileExistsError:
                with contextlib.suppress(OSError):
                    if time.time() - lock.stat().st_mtime > STALE_LOCK_S:
                        lock.unlink()
                        continue
                if time.monotonic() > deadline:
                    raise SessionConflict("another save of this analysis did not finish; "
                                          "reload the page.") from None
                time.sleep(0.02)
        try:
            yield
        finally:
            os.close(fd)
            with contextlib.suppress(OSError):
                lock.unlink()

    def load(self, sid: str) -> SavedSession | None:
        """The analysis saved under ``sid``, or None when there is none (or the id is
        malformed: a URL edited by hand starts a new analysis, it never reads a file).

        Only a regular file of at most :data:`MAX_SESSION_BYTES` is read, never through a
        symbolic link: a link, a FIFO (which would block the reload) or a device named like
        a session is not an analysis."""
        if not valid_session_id(sid):
            return None
        p = self.path(sid)
        try:
            info = os.lstat(p)
            if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_SESSION_BYTES:
                return None
            fd = os.open(p, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0)
                         | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
            with open(fd, "rb") as f:
                raw = f.read(MAX_SESSION_BYTES + 1)
            if len(raw) > MAX_SESSION_BYTES:
                return None
            return SavedSession(sid, p, raw.decode("utf-8"), info.st_mtime)
        except (OSError, UnicodeDecodeError):
            return None

    def forget(self, sid: str) -> None:
        """Remove the file of ``sid`` (nothing happens when there is none)."""
        if valid_session_id(sid):
            self.path(sid).unlink(missing_ok=True)

    def prune(self, keep_days: float = KEEP_DAYS, now: float | None = None) -> int:
        """Remove analyses not written for ``keep_days`` days; returns how many."""
        if not self.folder.is_dir():
            return 0
        limit = (time.time() if now is None else now) - keep_days * 86400
        gone = 0
        for p in self.folder.glob("*.json"):
            try:
                if valid_session_id(p.stem) and p.stat().st_mtime < limit:
                    p.unlink()
                    gone += 1
            except OSError:  # another server pruned it first
                continue
        return gone

"""Writing output files without destroying anything (issue 25).

Every file the command line writes goes through :func:`atomic_write_bytes` (or
:func:`atomic_write_text`): the data go to a temporary file in the same folder, are
flushed to disk, and the temporary file is renamed over the target (``os.replace``, atomic
on one file system). A reader sees the old file or the new one, never half of one; a run
that fails mid-write leaves the old file as it was and no temporary file behind. Two runs
writing the same file: each version is whole, and a run whose output another run wrote
after this one's :func:`check_outputs` is refused at the rename, keeping its own result
beside the file (:func:`_Temp.check_unchanged`): the loser is told, nothing is lost.

:func:`check_outputs` refuses, before any work, an output that is one of the command's
inputs, an existing folder, or the same file as another output, in one line naming the
option and the file.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO

from .errors import DataError

_STARTED: dict[Path, tuple | None] = {}
"""Each output of the running command (its resolved target) -> the file's state when the
command started (:func:`_state`), recorded by :func:`check_outputs`."""


def forget_outputs() -> None:
    """End of a command: its outputs' starting states are forgotten, so that a later
    write in the same process (a test, the app) is not compared with them."""
    _STARTED.clear()


def _state(target: Path) -> tuple | None:
    """(device, inode, size, mtime in ns) of a file, or None when there is none."""
    try:
        s = target.stat()
    except OSError:
        return None
    return (s.st_dev, s.st_ino, s.st_size, s.st_mtime_ns)


def _target(path) -> Path:
    """The file a write to ``path`` replaces: a symbolic link is followed, so the link
    stays and the file it points to is replaced."""
    return Path(os.path.realpath(os.fspath(path)))


class _Temp:
    """The temporary file that will replace one output: staged beside its target, then
    committed (renamed into place) or discarded. Refuses, before anything is written, a
    target that is a folder or whose folder does not exist."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.shown = Path(path)
        self.target = _target(path)
        if self.target.is_dir():
            raise DataError("is a folder, not a file; name a file to write.",
                            file=str(self.shown))
        if not self.target.parent.is_dir():
            raise DataError(f"No such file or directory: the folder {self.shown.parent} "
                            "does not exist.", file=str(self.shown),
                            hint="create it or write elsewhere.")
        try:  # an existing file keeps its permissions
            self.keep: int | None = stat.S_IMODE(self.target.stat().st_mode)
        except OSError:
            self.keep = None
        self.tmp: Path | None = None

    def open(self, mode: str, encoding: str | None) -> IO:
        """Create the temporary file (0o666 less the umask, as a new file gets)."""
        for _ in range(100):
            tmp = self.target.parent / f".{self.target.name}.{secrets.token_hex(4)}.tmp"
            try:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL
                             | getattr(os, "O_BINARY", 0), 0o666)
            except FileExistsError:
                continue
            self.tmp = tmp
            if mode == "w":
                return open(fd, "w", encoding=encoding or "utf-8", newline="")
            return open(fd, "wb")
        raise FileExistsError(errno.EEXIST, "no free temporary name",  # pragma: no cover
                              str(self.target))

    @staticmethod
    def finish(f: IO) -> None:
        """Everything written reaches the disk before any rename."""
        f.flush()
        os.fsync(f.fileno())

    def check_unchanged(self) -> None:
        """Refuse to rename over an output that another run wrote after this command
        started (its state differs from the one :func:`check_outputs` recorded): the
        temporary file is kept as ``NAME.conflict-XXXX`` beside it and named in one
        line, so neither run's result is lost and the later one is told."""
        if self.target not in _STARTED or _state(self.target) == _STARTED[self.target]:
            return
        assert self.tmp is not None
        kept = self.target.parent / f"{self.target.name}.conflict-{secrets.token_hex(3)}"
        os.replace(self.tmp, kept)
        self.tmp = None
        raise DataError(f"was written by another run while this one ran; this run's result "
                        f"is kept as {kept.name} beside it.", file=str(self.shown),
                        hint="compare the two and keep one; run one command at a time "
                             "on one output.")

    def commit(self) -> None:
        """Rename the finished temporary file over the target (:meth:`check_unchanged`
        first), and record the new file as this run's own."""
        assert self.tmp is not None
        if self.keep is not None:
            os.chmod(self.tmp, self.keep)
        os.replace(self.tmp, self.target)
        self.tmp = None
        _sync_folder(self.target.parent)
        if self.target in _STARTED:
            _STARTED[self.target] = _state(self.target)

    def discard(self) -> None:
        """Remove the temporary file (nothing happens to the target)."""
        if self.tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.tmp)
            self.tmp = None

    def error(self, exc: OSError) -> OSError:
        """``exc`` naming the output, not the temporary file."""
        return OSError(exc.errno, exc.strerror or str(exc), str(self.shown))


@contextlib.contextmanager
def atomic_writer(path: str | os.PathLike, mode: str = "wb", encoding: str | None = None) -> Iterator[IO]:
    """A file to write whose content replaces ``path`` when the ``with`` block ends
    without an exception: a temporary file in the same folder, fsync, ``os.replace``, so
    an output too large to hold in memory is written a piece at a time under the same
    rule. On any failure the temporary file is removed and an existing ``path`` is left
    untouched. ``mode`` is ``"wb"`` or ``"w"`` (text, with ``encoding``, line ends as
    written).

    Raises
    ------
    DataError
        ``path`` is a folder, or its folder does not exist.
    OSError
        The write failed (disk full, no permission); ``filename`` is ``path``, not the
        temporary file.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"mode: expected 'wb' or 'w', found {mode!r}.")
    t = _Temp(path)
    try:
        with t.open(mode, encoding) as f:
            yield f
            t.finish(f)
        t.check_unchanged()
        t.commit()
    except OSError as exc:
        raise t.error(exc) from exc
    finally:
        t.discard()


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:func:`atomic_writer`): a temporary file in
    the same folder, fsync, ``os.replace``; on any failure an existing ``path`` is left
    untouched."""
    with atomic_writer(path, "wb") as f:
        f.write(data)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (:func:`atomic_write_bytes`), encoded as is:
    line ends are written as they are in ``text``."""
    atomic_write_bytes(path, text.encode(encoding))


def atomic_write_all(files: Mapping[Path, str | bytes], encoding: str = "utf-8") -> None:
    """Write several files all or none, in two phases: every one is written to its
    temporary file and flushed to disk first; only when all are on disk are they renamed
    into place, one after another. A failure in the first phase (a disk that fills up
    on the third file, a folder that has gone) removes every temporary file and leaves
    every existing output as it was, so a run does not leave a grid from this model
    beside axis tables from the last. A rename failing part-way through the second
    phase (rare: the temporary files sit beside their targets) can still leave a mix;
    the error then names the file."""
    temps = [_Temp(path) for path in files]  # every target checked before any write
    current = temps[0] if temps else None
    try:
        for t, content in zip(temps, files.values(), strict=True):
            current = t
            with t.open("wb", None) as f:
                f.write(content.encode(encoding) if isinstance(content, str) else content)
                t.finish(f)
        for t in temps:  # every target checked before the first rename: all or none
            current = t
            t.check_unchanged()
        for t in temps:
            current = t
            t.commit()
    except OSError as exc:
        raise (current.error(exc) if current is not None else exc) from exc
    finally:
        for t in temps:
            t.discard()


def _sync_folder(folder: Path) -> None:
    """Make the rename durable (POSIX); a no-op where folders cannot be opened."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        with contextlib.suppress(OSError):
            os.fsync(fd)
    finally:
        os.close(fd)


def _same(a: Path, b: Path) -> bool:
    """True when ``a`` and ``b`` are one file: ``os.path.samefile`` when both exist (hard
    links, case-insensitive file systems), else the resolved paths."""
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.normcase(os.path.realpath(a)) == os.path.normcase(os.path.realpath(b))


def check_outputs(outputs: dict, inputs: Iterable = (), *, folders: dict | None = None) -> None:
    """Refuse outputs that would destroy an input or each other, before any work.

    Parameters
    ----------
    outputs : dict
        Option (as the user typed it, e.g. ``"--json"``) -> file path, or a list of
        paths (the files an option writes into its folder); None entries are skipped.
    inputs : iterable of path
        Every file the command reads (None entries skipped).
    folders : dict, optional
        Option -> folder the command creates (with its parents) and writes into: it must
        not be an existing file, and the files in it are exempt from the check that an
        output's folder exists.

    Raises
    ------
    DataError
        One line naming the option and the file: an output is one of the inputs, an
        existing folder, in a folder that does not exist, or the same file as another
        output (a folder of ``folders`` an existing file).
    """
    ins = [Path(p) for p in inputs if p is not None and not isinstance(p, bool)]
    _STARTED.clear()  # one command at a time in a process: its outputs alone
    made = {opt: Path(d) for opt, d in (folders or {}).items() if d is not None}
    for opt, d in made.items():
        if d.exists() and not d.is_dir():
            raise DataError(f"{opt} names a file, not a folder; name a folder to write "
                            "into (created if missing).", file=str(d))
    seen: list[tuple[str, Path]] = []  # (option, path)
    for opt, value in outputs.items():
        if value is None:
            continue
        for p in ([value] if isinstance(value, str | os.PathLike) else value):
            p = Path(p)
            if p.is_dir():
                raise DataError(f"{opt} names a folder, not a file; name a file to "
                                "write.", file=str(p))
            if not any(_same(p.parent, d) for d in made.values()) and not p.parent.is_dir():
                raise DataError(f"No such file or directory: the folder {p.parent} does "
                                f"not exist ({opt}).", file=str(p),
                                hint="create it or write elsewhere.")
            for src in ins:
                if _same(p, src):
                    also = "" if str(src) == str(p) else f" ({src})"
                    raise DataError(f"{opt} names an input of this command{also}; writing "
                                    "it would destroy it. Name another file.", file=str(p))
            for other, q in seen:
                if _same(p, q):
                    what = (f"{opt} names the same file twice" if other == opt
                            else f"{other} and {opt} name the same file")
                    raise DataError(f"{what}. Name different files.", file=str(p))
            seen.append((opt, p))
            _STARTED[_target(p)] = _state(_target(p))

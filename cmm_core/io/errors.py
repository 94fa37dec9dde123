"""Errors of the data readers and the name checks they share.

Holds :class:`DataError` (the one exception every reader raises, naming file, row, column
and a fix), :class:`Problems` (the collector that lets a reader report every problem of
a file at once, capped at :data:`MAX_PROBLEMS`), :func:`cut_repr` (values shortened for
messages) and the misspelt-name checks (:data:`COLUMN_ALIASES`, :func:`likely_typo`,
:func:`_check_keys`) used by the CSV and JSON readers alike.

This is the bottom of the ``cmm_core.io`` modules: it imports none of them. Import from
:mod:`cmm_core.io`, which re-exports everything here.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Collection, Iterable, Sequence
from typing import Any

import numpy as np

MAX_PROBLEMS = 50


class DataError(ValueError):
    """Bad input: the message names file, row, column, what was expected and a fix.

    Attributes
    ----------
    detail, file, row, column, hint
        The parts of the (first) problem.
    problems : list of DataError
        Every problem found (``[self]`` for a single one), capped at :data:`MAX_PROBLEMS`.
    n_problems : int
        How many problems were found, including those beyond the cap.
    """

    def __init__(self, message: str, *, file: str | None = None, row: int | None = None,
                 column: str | None = None, hint: str | None = None) -> None:
        self.file, self.row, self.column, self.hint = file, row, column, hint
        self.detail = message
        self.problems = [self]
        self.n_problems = 1
        where = [str(file)] if file else []
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        text = (": ".join([", ".join(where), message]) if where else message)
        if hint:
            text += f" Hint: {hint}"
        super().__init__(text)

    @classmethod
    def collect(cls, problems: Sequence[DataError], total: int | None = None) -> DataError:
        """One error reporting several ``problems`` (DataErrors), the first in its message.

        ``total`` is the number found when ``problems`` holds only the first of them.
        """
        first = problems[0]
        err = cls(first.detail, file=first.file, row=first.row, column=first.column,
                  hint=first.hint)
        err.problems = list(problems[:MAX_PROBLEMS])
        err.n_problems = max(total or 0, len(problems))
        more = err.n_problems - 1
        if more:
            err.args = (f"{err.args[0]} (and {more} more problem{'s' * (more > 1)})",)
        return err


class Problems:
    """Problems found in one file (or, for :func:`resolve`, in rows of several files),
    collected so the user can fix them all in one go.

    Each check keeps its first :data:`MAX_PROBLEMS` cells and counts the rest: enough to
    list the first :data:`MAX_PROBLEMS` of the file by row, without building millions of
    errors for a file that is wrong throughout.

    Parameters
    ----------
    name : str or None
        File name for messages.
    rows : array of int
        File row of each data row.
    columns : sequence of str
        The file's columns, to list problems of one row in column order.
    files : array of str, optional
        File name of each row, when the rows come from several files.
    """

    def __init__(self, name: str | None, rows: Any, columns: Iterable[str] = (),
                 files: Any = None) -> None:
        self.name, self.rows, self.columns = name, np.asarray(rows), list(columns)
        self.files = files
        self.found: list[DataError] = []
        self.total = 0

    def file(self, i: int) -> str | None:
        """File name of data row ``i``."""
        return self.name if self.files is None else self.files[i]

    def where(self, j: int, i: int) -> str:
        """'row N' of data row ``j``, with its file when that differs from row ``i``'s."""
        row = f"row {self.rows[j]}"
        return row if self.file(j) == self.file(i) else f"{self.file(j)}, {row}"

    def add(self, mask: Any, column: str | None, message: Callable[..., str],
            hint: str | None = None) -> None:
        """Report every True entry of ``mask``; ``message(i)`` words the problem of row i."""
        idx = np.flatnonzero(np.asarray(mask))
        self.total += len(idx)
        for i in idx[:MAX_PROBLEMS]:
            self.found.append(DataError(message(i), file=self.file(i),
                                        row=int(self.rows[i]), column=column, hint=hint))

    def add_file(self, message: str, column: str | None = None,
                 hint: str | None = None) -> None:
        """Report a problem of the file as a whole (no row)."""
        self.total += 1
        self.found.append(DataError(message, file=self.name, column=column, hint=hint))

    def raise_if_any(self, sort: bool = True) -> None:
        """Raise one :class:`DataError` listing the problems (by row when ``sort``)."""
        if not self.found:
            return
        if sort:
            order: dict[str | None, int] = {c: k for k, c in enumerate(self.columns)}
            self.found.sort(key=lambda e: (e.row or 0, order.get(e.column, len(order))))
        raise DataError.collect(self.found, self.total)


def cut_repr(value: object, limit: int = 60) -> str:
    """``repr`` of a value for a message, cut to ``limit`` characters: a 1 MB cell or a
    binary blob must not become a 1 MB error line."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 1] + "…"


def not_a_json_number(value: object) -> str:
    """Where ``value`` (a JSON number or nested lists of them) holds something else: ``""``
    when it holds numbers only, else the first offender's index path and value, as
    ``"[3]: true"``.

    ``np.asarray(value, float)`` and ``float()`` read ``true`` as 1.0 and ``"2"`` as 2.0:
    a hand-edited file would pass with a number nobody wrote. Checked before any
    conversion."""
    if isinstance(value, bool) or not isinstance(value, int | float | list):
        return f": {cut_repr(value, 30)}"
    if isinstance(value, list):
        for i, v in enumerate(value):
            bad = not_a_json_number(v)
            if bad:
                return f"[{i}]{bad}"
    return ""


COLUMN_ALIASES = {"time": "time_min", "t_min": "time_min", "minutes": "time_min",
                  "time_s": "time_min", "time_h": "time_min", "temp": "temp_C",
                  "temperature": "temp_C", "t_c": "temp_C", "temp_k": "temp_C",
                  "x": "x_mm", "y": "y_mm", "z": "z_mm", "x_m": "x_mm", "y_m": "y_mm",
                  "z_m": "z_mm", "x_in": "x_mm", "y_in": "y_mm", "z_in": "z_mm",
                  "x_um": "x_mm", "y_um": "y_mm", "z_um": "z_mm", "pos": "position",
                  "placement": "position", "stylus": "probe", "ball_no": "ball",
                  "rep": "repeat", "u_axis": "u_axis", "uaxis": "u_axis", "vaxis": "v_axis"}
"""Names (lower case) that stand for a known column or key: refused with the name they
mean, since read as an extra column they would silently leave a record (time, a
temperature) out, and a unit in the name says the values are not in mm, minutes or °C."""


def _fold(key: str) -> str:
    """A key as compared for misspellings: case, hyphens and spaces do not count."""
    return str(key).lower().replace("-", "_").replace(" ", "_")


def likely_typo(key: str, known: Collection[Any], cutoff: float = 0.85) -> Any:
    """The known key ``key`` most likely misspells (case, a dropped letter), or None."""
    if key in known:
        return None
    low = {_fold(k): k for k in known}
    if _fold(key) in low:
        return low[_fold(key)]
    if key.lower() in COLUMN_ALIASES and COLUMN_ALIASES[key.lower()] in known:
        return COLUMN_ALIASES[key.lower()]
    close = difflib.get_close_matches(_fold(key), list(low), n=1, cutoff=cutoff)
    return low[close[0]] if close else None


def refuse_unknown_keys(obj: Iterable[Any], known: Collection[Any], name: str | None,
                        where: str = "", what: str = "key") -> None:
    """Refuse any key of ``obj`` not in ``known``: a DataError naming the file and the key
    (``where`` + key), the known key it most likely misspells, and the known keys. The one
    validator of JSON inputs (analysis record, plan, task, simulation config): an unknown
    key would silently leave its default."""
    for k in obj:
        if k not in known:
            guess = likely_typo(str(k), known, cutoff=0.6)
            hint = f"did you mean {guess!r}? " if guess else ""
            raise DataError(f"unknown {what} {cut_repr(k)}; {hint}expected one of "
                            f"{', '.join(map(str, known))}.", file=name, column=f"{where}{k}")


def _check_keys(obj: dict, known, name, where: str):
    for k in obj:
        guess = likely_typo(str(k), known)
        if guess is not None:
            raise DataError(f"unknown key {cut_repr(k)}; did you mean {guess!r}? (A misspelt key "
                            "would silently leave its default.)", file=name,
                            column=f"{where}.{k}" if where else str(k))


def describe_error(exc: Exception) -> str:
    """The one line a user reads for ``exc``: a :class:`DataError` as it is (file, row,
    column, what was expected), a ``ValueError``/``KeyError`` its message without the
    quotes ``KeyError`` adds, any other exception its type and message (never a
    traceback)."""
    if isinstance(exc, DataError):
        return str(exc)
    if isinstance(exc, (ValueError, KeyError)):
        return str(exc).strip("'\"")
    return f"{type(exc).__name__}: {exc}"

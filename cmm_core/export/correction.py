"""Compensation: correct measured points with a fitted model, with uncertainties.

The true tip centre of a reported point ``r`` measured with probe offset ``p`` is
``r + e(r - p, p)`` (docs/formats.md conventions), from the model a model file holds
(:mod:`.model_file`). The effect blocks that act on new points correct the points in turn
(``Block.correct``): ``backlash`` for the direction from which each axis last moved,
``machine_thermal`` for the scales' expansion at the points' scale temperatures. The
uncertainty propagates the kinematic coefficients and every part's parameters through
their joint covariance (JCGM 100 eq. 13): ``u² = diag(J V Jᵀ)`` with
``J = [∂e/∂coef, ∂δ_block/∂values ...]``. A file of points is streamed a chunk at a time.
"""

from __future__ import annotations

import codecs
import io
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import overload

import numpy as np
import pandas as pd

from ..io import (
    MAX_BYTES,
    DataError,
    Provenance,
    atomic_writer,
    file_input,
)
from ..io.delimited import (
    FileSource,
    blank_leading_comments,
    file_rows,
    numeric_column,
    read_csv_text,
    require_columns,
    require_rows,
)
from ..io.errors import cut_repr
from ..model import (
    FitResult,
    covariance_factor,
    propagate_error,
)
from ..units import UM
from .model_file import COMPENSATING, Model, model_from_result

OFF_MACHINE = "outside the machine's range"


def refuse_off_machine(corrected: pd.DataFrame, name: str = "points") -> None:
    """Raise a :class:`DataError` when :func:`compensate` flagged points outside the
    machine's range: their "correction" extrapolates a polynomial far beyond the data
    (a point 400 m away got a 352 m correction), so a batch run must not pass it on as a
    result. The CLI calls this unless ``--allow-extrapolation`` is given."""
    off = (corrected["extrapolated"] == OFF_MACHINE).to_numpy()
    if off.any():
        i = int(np.flatnonzero(off)[0])
        raise _off_machine_error(int(off.sum()), int(file_rows(corrected)[i]),
                                 corrected[["x_mm", "y_mm", "z_mm"]].to_numpy(float)[i], name)


def _off_machine_error(n: int, row: int, r_mm: np.ndarray, name: str) -> DataError:
    """The refusal of ``n`` points off the machine, the first at file ``row``."""
    return DataError(f"{n} point{'s' * (n > 1)} lie outside the machine's range, where "
                     "the model is not defined (this one at "
                     f"{np.round(r_mm, 1).tolist()} mm); expected points in mm, machine "
                     "frame.", file=name, row=row, column="x_mm",
                     hint="check units and frame; to keep such points anyway, use "
                          "--allow-extrapolation (they are flagged in the 'extrapolated' "
                          "column).")


def extrapolation_note(m: Model, x_mm: np.ndarray) -> np.ndarray:
    """Per point: "" inside the region the fit measured (box of its scale readings),
    else why the correction is an extrapolation. A polynomial fitted over part of a
    stroke is not evidence about the rest, and outside the machine's range it is not even
    defined; the uncertainty, propagated from the coefficients, does not show that."""
    rng = np.asarray(m.terms.range_mm, float)
    note = np.full(len(x_mm), "", dtype=object)
    region = m.summary.get("region_mm") if isinstance(m.summary, dict) else None
    if region is not None:
        lo, hi = np.asarray(region[0], float), np.asarray(region[1], float)
        outside = ((x_mm < lo - 1.0) | (x_mm > hi + 1.0)).any(axis=1)
        note[outside] = "outside the measured region"
    # styli put scale readings a little beyond the strokes (the thesis layout: z = -50 mm),
    # so only an excursion of more than a stylus length (100 mm, or 5 % of a longer stroke)
    # says the point is off the machine, or units or frame are wrong
    tol = np.maximum(0.05 * rng, 100.0)
    beyond = ((x_mm < -tol) | (x_mm > rng + tol)).any(axis=1)
    note[beyond] = OFF_MACHINE
    return note


def read_points(source: FileSource, *, name: str | None = None) -> pd.DataFrame:
    """Read points to correct: ``x_mm,y_mm,z_mm`` and ``probe`` (plus any other columns),
    the whole file at once (at most :data:`cmm_core.io.MAX_BYTES`); :func:`compensate` with
    ``out`` streams a file of any size instead."""
    df, name = read_csv_text(source, name)
    return _points_table(df, name)


def _points_table(df: pd.DataFrame, name: str) -> pd.DataFrame:
    """The points of a table of strings (:func:`read_csv_text`): coordinates as numbers,
    every unreadable cell refused with its row."""
    require_columns(df, ("x_mm", "y_mm", "z_mm"), name, "points")
    require_rows(df, name, "point to correct")
    out = df.copy()
    for c in ("x_mm", "y_mm", "z_mm"):
        out[c] = numeric_column(df, c, name)
    out.attrs["source"] = name
    return out


_CHUNK_POINTS = 10_000
"""Points corrected at a time. A chunk's Jacobian holds points × 3 × parameters numbers
(8 MB for the 33 coefficients of ``kinematic21`` at order 2, with a few working copies),
so the memory a correction takes does not grow with the number of points. 10^6 points
from the command line: 251 MB peak and 14.1 s at 10 000 a chunk, 307 MB and 12.3 s at
20 000 (session 12, load 1.4): the smaller chunk keeps the 300 MB goal."""

_NOT_UTF8 = "is not UTF-8 text (a binary file, or another encoding)."


@overload
def compensate(model: Model | FitResult, points: pd.DataFrame, *, out: None = None,
               allow_extrapolation: bool = True,
               chunk_points: int = _CHUNK_POINTS) -> pd.DataFrame: ...


@overload
def compensate(model: Model | FitResult, points: str | os.PathLike, *, out: str | os.PathLike,
               allow_extrapolation: bool = True, chunk_points: int = _CHUNK_POINTS,
               provenance: Provenance | None = None) -> dict: ...


def compensate(model: Model | FitResult, points: pd.DataFrame | str | os.PathLike, *,
               out: str | os.PathLike | None = None, allow_extrapolation: bool = True,
               chunk_points: int = _CHUNK_POINTS,
               provenance: Provenance | None = None) -> pd.DataFrame | dict:
    """Corrected points ``xc_mm, yc_mm, zc_mm`` with standard uncertainties in µm.

    ``points`` needs ``x_mm, y_mm, z_mm`` (reported tip centres, machine frame) and a
    ``probe`` column unless the model has a single probe. With a backlash model the
    points' order (``time_min``, else the rows) is their measurement order, and the
    output gets the approach direction of each axis (``approach_x`` ...: +1, -1, 0 unknown).
    With a machine_thermal model the points need the scale temperature of every fitted
    axis (``temp_x_C``, ``temp_y_C``, ``temp_z_C``, °C).

    The correction is ``e + Σ δ_block`` (kinematic error, thesis eq. 4.13, plus each
    part's :meth:`blocks.base.Block.correct`), its uncertainty the propagation of the
    joint covariance (module docstring) plus any variance a part adds. Both are
    evaluated ``chunk_points`` points at a time, so memory stays bounded.

    Parameters
    ----------
    model : Model or FitResult
    points : DataFrame, or path of a points CSV file when ``out`` is given
    out : path, optional
        Stream ``points`` (a file) to this CSV file, a chunk at a time: the memory taken
        does not depend on the file's size. Written as the CLI's ``--out``: through a
        temporary file in the same folder renamed into place at the end, so a failed run
        leaves no half file and an existing file as it was. Models with ``backlash`` read
        the file whole (the approach directions follow the points' order over the whole
        file), within the size limit of every reader.
    allow_extrapolation : bool
        With ``out``: when False, points outside the machine's range are refused
        (:func:`refuse_off_machine`) after the flagged output is written.
    chunk_points : int
        Points evaluated (and, with ``out``, read) at a time.
    provenance : Provenance, optional
        With ``out``: what made the output, written as ``#`` comment lines before the
        header row (:meth:`Provenance.lines`), the points file's SHA-256 added to its
        inputs; default the model's (:meth:`Model.derived_provenance`).

    Returns
    -------
    DataFrame
        The input columns plus ``xc_mm, yc_mm, zc_mm``, ``ex_um, ey_um, ez_um``,
        ``u_x_um, u_y_um, u_z_um`` and ``extrapolated`` (and each part's columns).
    dict
        With ``out``: ``out``, ``n_points`` and ``max_correction_um``.

    Raises
    ------
    DataError
        A point the model cannot correct (unknown probe, non-finite or metre coordinates,
        a missing column a part needs), or a correction that is not a finite number.
    """
    m = model_from_result(model) if isinstance(model, FitResult) else model
    if out is not None:
        # a path that is no regular file is refused by the reader below, in its words
        digest = [file_input(Path(points))] if Path(points).is_file() else []
        prov = (provenance or m.derived_provenance()).with_inputs(digest)
        return _compensate_file(m, Path(points), out, allow_extrapolation, chunk_points,
                                prov.lines())
    if not isinstance(points, pd.DataFrame):
        raise ValueError("points: expected a DataFrame (or a file path together with out=), "
                         f"found {type(points).__name__}.")
    name = points.attrs.get("source", "points")
    r = _coordinates(points, name)
    _refuse_metres(m, float(np.abs(r).max()) if len(r) else 0.0, name)
    return _corrected(m, covariance_factor(m.joint_cov), points, r, name, chunk_points)


def _propagated(m: Model, L: np.ndarray, x: np.ndarray, p: np.ndarray,
                extra_jac: list | None = None, chunk_points: int = _CHUNK_POINTS
                ) -> tuple[np.ndarray, np.ndarray]:
    """Kinematic error ``e(x, p)`` (µm) at scale readings ``x`` with offsets ``p`` (mm)
    and its standard uncertainty with the linear terms whose Jacobians (µm per unit,
    (m, 3, k) each) ``extra_jac`` holds (:func:`cmm_core.model.propagate_error` with the
    covariance's factor ``L``, :func:`cmm_core.model.covariance_factor` of
    ``m.joint_cov``, computed once per model), ``chunk_points`` points at a time (the
    memory of one chunk's Jacobian)."""
    e_um = np.empty_like(x)
    u = np.empty_like(x)
    step = max(int(chunk_points), 1)
    for a in range(0, len(x), step):
        s = slice(a, a + step)
        with np.errstate(over="ignore", invalid="ignore"):  # refused after, one line
            e_um[s], u[s] = propagate_error(
                m.terms, m.coef, None, x[s], p[s],
                np.concatenate([j[s] for j in extra_jac], axis=2) if extra_jac else None,
                factor=L)
    return e_um, u


def _coordinates(points: pd.DataFrame, name: str) -> np.ndarray:
    """The reported tip centres (mm), finite, as an (m, 3) array."""
    r = points[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    bad = ~np.isfinite(r).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise DataError("expected finite coordinates (mm), found "
                        f"{r[i].tolist()}.", file=name, row=int(file_rows(points)[i]),
                        column="x_mm")
    return r


def _refuse_metres(m: Model, max_abs_mm: float, name: str) -> None:
    """Refuse points that all lie within 2 mm of the origin of a machine of 100 mm or
    more: they are metres (``max_abs_mm``: the largest |coordinate| of all the points)."""
    rng = np.asarray(m.terms.range_mm, float)
    if rng.max() >= 100 and max_abs_mm <= 2.0:
        raise DataError(f"every coordinate is within 2 mm of the origin of a "
                        f"{rng.max():.0f} mm machine: the points look like metres.",
                        file=name, column="x_mm", hint="write the points in mm.")


def _probe_offsets(m: Model, points: pd.DataFrame, name: str) -> np.ndarray:
    """Each point's probe offset (mm), (m, 3); an unknown probe refused with its row."""
    if "probe" not in points:
        if len(m.probes_mm) == 1:
            return np.broadcast_to(next(iter(m.probes_mm.values())), (len(points), 3))
        raise DataError(f"missing column 'probe'; the model has probes "
                        f"{', '.join(m.probes_mm)}.", file=name, column="probe")
    names, inverse = np.unique(points["probe"].astype(str).str.strip().to_numpy(),
                               return_inverse=True)
    for k, q in enumerate(names):
        if q not in m.probes_mm:
            i = int(np.flatnonzero(inverse == k)[0])
            raise DataError(f"probe {cut_repr(q)} is not in the model {m.name} (known: "
                            f"{', '.join(m.probes_mm)}).", file=name,
                            row=int(file_rows(points)[i]), column="probe")
    table = np.array([m.probes_mm[q] for q in names], float).reshape(-1, 3)
    return table[inverse.ravel()]


def _corrected(m: Model, factor: np.ndarray, points: pd.DataFrame, r: np.ndarray, name: str,
               chunk_points: int) -> pd.DataFrame:
    """:func:`compensate` of a table whose coordinates ``r`` are checked."""
    p = _probe_offsets(m, points, name)
    x = r - p
    fixes = [b.correct(part, points, x, name) for b in COMPENSATING
             if (part := m.parts.get(b.token)) is not None]
    e_um, u = _propagated(m, factor, x, p, [f.jac for f in fixes], chunk_points)
    for f in fixes:
        e_um += f.delta_um
    extra = [f.var_um2 for f in fixes if f.var_um2 is not None]
    if extra:
        u = np.sqrt(u**2 + sum(extra))
    _refuse_non_finite(m, points, e_um, u, name)
    if m.undetermined:
        u[:] = np.nan
    out = points.copy()
    out["xc_mm"], out["yc_mm"], out["zc_mm"] = (r + e_um * UM).T
    out["ex_um"], out["ey_um"], out["ez_um"] = e_um.T
    out["u_x_um"], out["u_y_um"], out["u_z_um"] = u.T
    out["extrapolated"] = extrapolation_note(m, x)
    for f in fixes:
        for col, v in f.columns.items():
            out[col] = v
    return out


def _refuse_non_finite(m: Model, points: pd.DataFrame | None, e_um: np.ndarray,
                       u: np.ndarray, name: str) -> None:
    """No NaN or inf leaves :func:`compensate` or a grid: a correction or uncertainty that
    is not finite (a model built in code with absurd numbers, or a part's input such as
    a temperature far out of range) is refused at its point (its file row when
    ``points`` is a table, else its index), naming the model."""
    bad = ~(np.isfinite(e_um) & np.isfinite(u)).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        where = "" if points is not None else f" at node {i} ({m.terms.range_mm} mm box)"
        raise DataError(f"the model {m.name} gives a correction of {e_um[i].tolist()} µm "
                        f"± {u[i].tolist()} µm{where}; expected finite numbers.",
                        file=name, row=None if points is None else int(file_rows(points)[i]),
                        column="x_mm" if points is not None else None,
                        hint="check the point's columns and the model (refit and save it "
                             "again, fit --save).")


def _compensate_file(m: Model, path: Path, out, allow_extrapolation: bool,
                     chunk_points: int, head: list[str]) -> dict:
    """:func:`compensate` of the points file ``path`` streamed to ``out``, the comment
    lines ``head`` first."""
    name = path.name
    factor = covariance_factor(m.joint_cov)
    whole = "backlash" in m.parts  # directions follow the order over the whole file
    tables = iter([read_points(path)]) if whole else _point_chunks(path, name, chunk_points)
    n, n_off, first_off, max_abs, max_corr = 0, 0, None, 0.0, 0.0
    with atomic_writer(out, "w") as fh:
        fh.write("".join(f"# {line}\n" for line in head))
        for table in tables:
            r = _coordinates(table, name)
            res = _corrected(m, factor, table, r, name, chunk_points)
            fh.write(_csv_text(res, header=n == 0))
            off = (res["extrapolated"] == OFF_MACHINE).to_numpy()
            if off.any() and first_off is None:
                i = int(np.flatnonzero(off)[0])
                first_off = (int(file_rows(table)[i]), r[i])
            n, n_off = n + len(res), n_off + int(off.sum())
            max_abs = max(max_abs, float(np.abs(r).max()))
            max_corr = max(max_corr, float(np.abs(res[["ex_um", "ey_um", "ez_um"]]
                                                  .to_numpy()).max()))
        # a check of all the points: raised before the output is renamed into place
        _refuse_metres(m, max_abs, name)
    if first_off is not None and not allow_extrapolation:
        raise _off_machine_error(n_off, *first_off, name)
    return {"out": str(out), "n_points": n, "max_correction_um": max_corr}


def _point_chunks(path: Path, name: str, chunk_points: int) -> Iterator[pd.DataFrame]:
    """The points of a CSV file, about ``chunk_points`` rows at a time, read as
    :func:`read_points` reads a whole file (the same separators, decimal commas, blank
    lines, quotes, refusals, and the file's row numbers in ``attrs``). A chunk ends at a
    line end outside quotes; the header line is given to every chunk."""
    if not path.exists():
        raise DataError("file not found.", file=name, hint="check the path.")
    if path.is_dir():
        raise DataError("is a folder; expected a file.", file=name,
                        hint="name the file inside the folder.")
    block = int(min(1 << 20, max(256, 32 * chunk_points)))
    decoder = codecs.getincrementaldecoder("utf-8-sig")()
    pending, header, first_row, columns = "", None, 1, None
    try:
        fh = path.open("rb")
    except OSError as exc:
        raise DataError(f"cannot read ({exc.strerror}).", file=name,
                        hint="check the path and that it is a file.") from None
    with fh:
        while True:
            raw = fh.read(block)
            try:
                pending += decoder.decode(raw, final=not raw)
            except UnicodeDecodeError:
                raise DataError(_NOT_UTF8, file=name,
                                hint="export the table as CSV (UTF-8).") from None
            if "\x00" in pending:
                raise DataError("contains NUL bytes; it is not a text table.", file=name,
                                hint="export the table as CSV (UTF-8).")
            # one line end everywhere, as read_csv_text; a CR ending the block may be
            # the first half of a CRLF
            keep_cr = bool(raw) and pending.endswith("\r")
            text = (pending[:-1] if keep_cr else pending).replace("\r\n", "\n") \
                .replace("\r", "\n")
            # at the end of the file the rest is the last chunk, whatever it holds
            cut = len(text) if not raw else _chunk_end(text, chunk_points,
                                                      blank=header is None)
            if raw and cut == 0:
                if len(text) > MAX_BYTES:
                    raise DataError(f"has a line or quoted cell longer than "
                                    f"{MAX_BYTES / 1e6:.0f} MB; it is not a points table.",
                                    file=name, row=first_row)
                pending = text + ("\r" if keep_cr else "")
                continue
            chunk, pending = text[:cut], text[cut:] + ("\r" if keep_cr else "")
            if header is not None and not chunk.strip(" \t\n,;"):
                if not raw:  # blank lines after the last chunk
                    return
                first_row += chunk.count("\n")
                continue
            if header is None:
                df, _ = read_csv_text(chunk.encode(), name)
                header = _header_line(chunk)
                columns = list(df.columns) if df.attrs.get("delimiter") == "," else None
            else:
                df = _chunk_table(header, chunk, first_row, columns, name)
            first_row += chunk.count("\n")
            if len(df) or not raw:
                yield _points_table(df, name)
            if not raw:
                return


def _chunk_end(text: str, chunk_points: int, *, blank: bool) -> int:
    """Where a chunk of ``text`` (lines of a CSV file) may end: after its last line end
    outside quotes once it holds ``chunk_points`` lines; 0 to read on. The first chunk
    (``blank``) also waits for a line that is not blank (the header)."""
    if text.count("\n") < chunk_points or (blank and not blank_leading_comments(text).strip()):
        return 0
    cut = text.rfind("\n") + 1
    while cut > 0 and text.count('"', 0, cut) % 2:
        cut = text.rfind("\n", 0, cut - 1) + 1
    return cut


def _header_line(chunk: str) -> str:
    """The header line of a file's first chunk: its first line with a cell after any
    comment lines."""
    return next(line for line in blank_leading_comments(chunk).split("\n")
                if line.strip(" \t,;"))


_BLANK_LINE = re.compile(r"^(?:[^\S\n]|,)*$", re.MULTILINE)
"""A line without a cell (blank, or separators only): read_csv_text skips it."""


def _chunk_table(header: str, chunk: str, first_row: int, columns: list | None,
                 name: str) -> pd.DataFrame:
    """A later chunk as :func:`read_csv_text` reads it with the header line before it, its
    rows numbered in the file (``first_row``: the file row of its first line). A chunk of
    plain comma-separated cells (no quotes, no blank line, the header's number of cells
    on every line) goes through pandas' C reader, which gives the same strings faster."""
    n_lines = chunk.count("\n") + (not chunk.endswith("\n"))
    body = chunk[:-1] if chunk.endswith("\n") else chunk
    if columns is not None and '"' not in chunk and not _BLANK_LINE.search(body):
        try:
            df = pd.read_csv(io.StringIO(chunk), header=None, names=columns, dtype=str,
                             na_filter=False, skipinitialspace=True, engine="c")
        except (ValueError, pd.errors.ParserError):
            df = None
        if df is not None and len(df) == n_lines and \
                chunk.count(",") == n_lines * (len(columns) - 1):
            df.attrs.update(delimiter=",", decimal_comma=False,
                            rows=np.arange(first_row, first_row + n_lines))
            return df
    df, _ = read_csv_text((header + "\n" + chunk).encode(), name)
    df.attrs["rows"] = np.asarray(df.attrs["rows"]) + first_row - 2
    return df


def _csv_text(df: pd.DataFrame, *, header: bool) -> str:
    """``df.to_csv(index=False, float_format="%.6f")`` (without or with the header line),
    written a row at a time through one format string: the same text several times
    faster. NaN cells are empty; text cells are quoted when they hold a comma, a quote or
    a line end."""
    cells, fmt = [], []
    for c in df.columns:
        v = df[c].to_numpy()
        if v.dtype.kind == "f" and np.isfinite(v).all():
            cells.append(v.tolist())
            fmt.append("%.6f")
        elif v.dtype.kind in "iub":
            cells.append(v.astype(np.int64).tolist())
            fmt.append("%d")
        else:
            if v.dtype.kind == "f":
                text = pd.Series(["" if x != x else f"{x:.6f}" for x in v.tolist()])
            else:
                text = pd.Series(v, dtype=object).where(pd.notna(v), "").astype(str)
                odd = text.str.contains(r'[,"\n\r]', regex=True).to_numpy()
                if odd.any():
                    text[odd] = text[odd].map(_quoted)
            cells.append(text.tolist())
            fmt.append("%s")
    line = ",".join(fmt) + "\n"
    head = ",".join(_quoted(str(c)) for c in df.columns) + "\n" if header else ""
    return head + "".join(line % row for row in zip(*cells, strict=True))


def _quoted(cell: str) -> str:
    """A CSV cell as pandas writes it (minimal quoting)."""
    if any(ch in cell for ch in ',"\n\r'):
        return '"' + cell.replace('"', '""') + '"'
    return cell

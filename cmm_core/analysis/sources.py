"""The data of an analysis as :class:`~cmm_core.analysis.DataSources`: assembled from
uploaded files (every problem of every file, the notes of how they were read), from the
thesis sample, or from a simulation, and loaded into a :class:`~cmm_core.io.Dataset`.

The app's session holds its data as these sources (issue 36: one dataset), and the record,
the project file and the report are made from them; the command line's readers use the
same assembly, so an upload is judged the same way everywhere.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..io import (
    MAX_PROBLEMS,
    THESIS_DIR,
    THESIS_POSITIONS,
    DataError,
    Dataset,
    describe_error,
    is_qif,
    load_dataset,
    read_certificate,
    read_measurements,
    read_setup,
    sniff,
    write_certificate,
    write_long_csv,
)
from .record import AnalysisRecord, DataFile, DataSources
from .record_io import record_from_inline

__all__ = ["SourceProblem", "Assembly", "problems_of", "thesis_sources", "assemble_upload",
           "simulated_sources", "inline_sources", "refuse_paths", "load_sources", "sources_key", "record_from_sources",
           "THESIS_ORIGIN", "FOREIGN_HINT"]

@dataclass(frozen=True)
class SourceProblem:
    """One problem of an upload, as a row of its problem table."""

    file: str
    """The file it is in ("" for the upload as a whole)."""
    problem: str
    """What is wrong, in one sentence."""
    hint: str = ""
    """How to fix it."""
    row: int | None = None
    """The file's row (1 = the header line), where one is to blame."""
    column: str = ""
    """The column (or JSON key) to blame, where one is."""
    more: int = 0
    """For a note row: how many problems it stands for that are not listed."""

    def to_dict(self) -> dict:
        """The row as a plain dict (the app's table)."""
        return {"file": self.file, "row": self.row, "column": self.column,
                "problem": self.problem, "hint": self.hint}


@dataclass(frozen=True)
class Assembly:
    """What an upload assembles to: the sources when everything loads, else the problems."""

    sources: DataSources | None
    """The data, ready to load (None when any file was refused)."""
    problems: tuple[SourceProblem, ...] = ()
    """Every problem of every file (at most ``MAX_PROBLEMS`` rows, then a note row)."""
    notes: tuple[str, ...] = ()
    """How the files were read where that is not the default (another delimiter, a
    stand-in setup or certificate, a column mapping): nothing happens unseen."""
    setup_source: str = ""
    """Where the setup came from, in words ("setup.json (uploaded)")."""
    certificate_source: str = ""
    """Where the certificate came from, in words (or that there is none)."""
    origin: dict = field(default_factory=dict)
    """``{"kind", "setup_source", "certificate_source"}`` as the app shows them."""

    @property
    def ok(self) -> bool:
        """Whether the upload assembled to sources."""
        return self.sources is not None

    @property
    def n_problems(self) -> int:
        """Problems listed plus those the note rows say are not listed."""
        return sum(p.more or 1 for p in self.problems)


def problems_of(exc: Exception, file: str = "") -> list[SourceProblem]:
    """Every problem an exception carries, as problem rows: a
    :class:`~cmm_core.io.DataError` lists all problems of its file (capped by the core),
    and a last row says how many it found but does not list."""
    if not isinstance(exc, DataError):
        return [SourceProblem(file, describe_error(exc))]
    rows = [SourceProblem(p.file or "", p.detail, p.hint or "", p.row, p.column or "")
            for p in exc.problems]
    hidden = exc.n_problems - len(exc.problems)
    if hidden > 0:
        rows.append(SourceProblem(exc.file or "", f"... and {hidden} more problem(s) not "
                                  "listed.", "fix these and load again to see the rest.",
                                  more=hidden))
    return rows


def _capped(problems: list[SourceProblem]) -> tuple[SourceProblem, ...]:
    """At most ``MAX_PROBLEMS`` rows (several bad files could list that many each), plus
    a note row for the rest."""
    if len(problems) <= MAX_PROBLEMS:
        return tuple(problems)
    rest = sum(p.more or 1 for p in problems[MAX_PROBLEMS:])
    return (*problems[:MAX_PROBLEMS], SourceProblem(
        "", f"... and {rest} more problem(s) not listed.",
        "fix the problems listed and load again.", more=rest))


def _read_note(name: str, attrs: dict) -> str | None:
    """How a file not separated by commas was read."""
    delim = attrs.get("delimiter", ",")
    if delim == ",":
        return None
    kind = {";": "semicolon", "\t": "tab"}.get(delim, repr(delim))
    comma = " with decimal commas" if attrs.get("decimal_comma") else ""
    return f"{name} was read as {kind}-separated{comma}."


def _text(name: str, data: bytes, reader, problems: list) -> str | None:
    """The file's text if ``reader`` accepts it, else None with its problems noted."""
    try:
        text = data.decode("utf-8-sig")
        reader(io.StringIO(text), name=name)
        return text
    except UnicodeDecodeError:
        problems.append(SourceProblem(name, "is not UTF-8 text.",
                                      "save it as UTF-8 CSV/JSON."))
    except Exception as exc:  # noqa: BLE001 - every problem becomes a row
        problems.extend(problems_of(exc, name))
    return None


def _measurements(files: Sequence[tuple[str, bytes]], problems: list, notes: list,
                  foreign_hint: str) -> tuple[list[tuple[str, str]], set[str]]:
    """(name, text) of every measurement file that reads, and the positions they name;
    the problems of the others noted (a file of another tool's format named as such)."""
    meas: list[tuple[str, str]] = []
    seen: dict[bytes, str] = {}
    positions: set[str] = set()
    for name, data in files:
        if data in seen:
            # one line, not one "appears twice" per ball of the combined table
            problems.append(SourceProblem(name, f"has the same content as {seen[data]}: "
                                          "the file was uploaded twice.",
                                          "remove one of them."))
            continue
        seen[data] = name
        try:
            df = read_measurements(io.BytesIO(data), name=name)
        except Exception as exc:  # noqa: BLE001 - every problem becomes a row
            foreign = sniff(data) or (_QIF_SENTENCE if is_qif(data, name) else None)
            problems.extend([SourceProblem(name, foreign, foreign_hint)]
                            if foreign else problems_of(exc, name))
            continue
        meas.append((name, data.decode("utf-8-sig")))
        positions |= set(df["position"].astype(str))
        note = _read_note(name, df.attrs)
        if note:
            notes.append(note)
    return meas, positions


def _with_statement(setup_text: str, statement: dict, problems: list) -> str | None:
    """The setup text with ``statement`` as its ``certificate`` section, checked by the
    setup reader (None with the problem noted when refused)."""
    raw = json.loads(setup_text)
    raw["certificate"] = statement
    text = json.dumps(raw, indent=1)
    try:
        read_setup(io.StringIO(text), name="setup.json")
    except Exception as exc:  # noqa: BLE001 - every problem becomes a row
        problems.extend(problems_of(exc, "certificate uncertainty (entered)"))
        return None
    return text


def _statement_words(statement: dict) -> str:
    if statement.get("exact"):
        return "exact"
    return "U(k={k:g}) = {a:g} ⊕ {b:g}·L µm ({c})".format(
        k=statement["k"], a=statement["U_um"][0], b=statement["U_um"][1],
        c=statement["combine"])


FOREIGN_HINT = "read it with that tool's reader (docs/foreign-formats.md)."
_QIF_SENTENCE = ("this is a QIF 3.0 document, not a measurement CSV: its measured spheres are "
                "read through a label pattern (cmm_core.io.read_qif; in the app, the "
                "mapped import).")
"""What the plain reader says of a QIF document (the foreign hint follows)."""
"""The default hint beside a measurement file in another tool's format."""


def thesis_sources() -> DataSources:
    """The six ball-plate tables of thesis chapter 6 with their setup and certificate
    (appendix 5), carried inline."""
    return DataSources(
        name="thesis tables 6.1-6.6",
        measurements=tuple(DataFile(f"{p}.csv", content=(THESIS_DIR / f"{p}.csv").read_text())
                           for p in THESIS_POSITIONS),
        setup=DataFile("setup.json", content=(THESIS_DIR / "setup.json").read_text()),
        certificate=DataFile("certificate.csv",
                             content=(THESIS_DIR / "certificate.csv").read_text()))


THESIS_ORIGIN = {"kind": "thesis", "setup_source": "thesis setup (sample_data/thesis/setup.json)",
                 "certificate_source": "thesis certificate (appendix 5)"}
"""How the app states where the thesis sample's setup and certificate come from."""


def _setup_of(setup: tuple[str, bytes] | None, use_thesis: bool, positions: set[str],
              problems: list, notes: list) -> tuple[str | None, str]:
    """The setup's text and where it came from: the uploaded one, or the thesis setup
    standing in when asked (refused when it cannot place the positions measured)."""
    if setup is not None:
        return _text(setup[0], setup[1], read_setup, problems), f"{setup[0]} (uploaded)"
    if not use_thesis:
        problems.append(SourceProblem("setup.json", "no setup given.",
                                      "upload a setup JSON (docs/formats.md#setup) or use "
                                      "the thesis setup."))
        return None, ""
    missing = sorted(positions - set(THESIS_POSITIONS))
    if missing:
        # the thesis placements cannot place these positions: ask for their setup
        problems.append(SourceProblem(
            "setup.json", "no setup uploaded, and the thesis setup that would stand in "
            f"does not know position(s) {', '.join(missing[:8])}"
            + (" ..." if len(missing) > 8 else "") + ", so their placement in the "
            "machine is unknown.", "upload the setup JSON of these measurements "
            "(positions, placements and probe offsets: docs/formats.md#setup)."))
    notes.append("The thesis setup (the placements of chapter 6) stands in for the setup "
                 "not uploaded.")
    return (THESIS_DIR / "setup.json").read_text(), "thesis setup (stand-in: no setup uploaded)"


def _certificate_of(certificate: tuple[str, bytes] | None, stand_in: bool, problems: list,
                    notes: list) -> tuple[tuple[str, str] | None, str]:
    """The certificate (name, text) and where it came from."""
    if certificate is not None:
        text = _text(certificate[0], certificate[1], read_certificate, problems)
        return (None if text is None else (certificate[0], text),
                f"{certificate[0]} (uploaded)")
    if stand_in:
        notes.append("The thesis certificate (appendix 5) stands in for the certificate "
                     "not uploaded.")
        return (("certificate.csv", (THESIS_DIR / "certificate.csv").read_text()),
                "thesis certificate (stand-in: none uploaded)")
    notes.append("No certificate: the plate geometry is fitted from the positions "
                 "(self-calibration, plate free).")
    return None, "none (plate geometry self-calibrated)"


def assemble_upload(measurements: Sequence[tuple[str, bytes]],
                    setup: tuple[str, bytes] | None = None,
                    certificate: tuple[str, bytes] | None = None, *,
                    use_thesis: bool = False, name: str = "",
                    mapped: tuple | None = None,
                    certificate_statement: dict | None = None,
                    foreign_hint: str = FOREIGN_HINT,
                    load: Callable[[DataSources], Dataset] | None = None) -> Assembly:
    """Check every uploaded file on its own, then together, and assemble the sources.

    Parameters
    ----------
    measurements : sequence of (file name, bytes)
        One long-form CSV, or one thesis-form CSV per position (docs/formats.md).
    setup, certificate : (file name, bytes) or None
        The setup JSON and the plate certificate CSV.
    use_thesis : bool
        Without a setup: the thesis setup stands in (and, with no certificate either, the
        thesis certificate), said in the notes; refused when the thesis placements do not
        know a position measured.
    name : str
        The dataset's label (default: the measurement files' names).
    mapped : tuple, optional
        A table from another tool already converted to the long form: (file name, long-form
        text[, source name, source text, mapping]); with the last three the source table and
        its column mapping travel into the record and project file.
    certificate_statement : dict, optional
        The setup's ``certificate`` section as the user states it (``{"exact": true}`` or
        ``{"U_um": [a, b], "k", "combine"}``): it replaces the setup's own statement.
    foreign_hint : str
        The hint beside a measurement file another tool wrote (what takes it instead).
    load : callable, optional
        How the assembled sources are loaded to check them together (default
        :func:`load_sources`): a caller that keeps loaded datasets (the app's cache) passes
        its own, so the upload is read once.

    Returns
    -------
    Assembly
        The sources when everything loads, else every problem (never raises for a bad
        file).
    """
    problems: list[SourceProblem] = []
    notes: list[str] = []
    meas, positions = _measurements(measurements, problems, notes, foreign_hint)
    files: list[tuple] = list(meas)
    if mapped is not None:
        files.append(tuple(mapped[2:]) if len(mapped) == 5 and None not in mapped[3:]
                     else tuple(mapped[:2]))
        notes.append(f"{mapped[0]}: read through the column mapping.")
    if not measurements and mapped is None:
        problems.append(SourceProblem("", "no measurement file given.", "upload one "
                                      "long-form CSV or one thesis-form CSV per position."))
    setup_text, setup_source = _setup_of(setup, use_thesis, positions, problems, notes)
    if certificate_statement is not None and setup_text is not None:
        setup_text = _with_statement(setup_text, certificate_statement, problems)
        notes.append(f"Certificate uncertainty: {_statement_words(certificate_statement)}, "
                     "as entered; a certificate's own u columns take precedence.")
    cert, cert_source = _certificate_of(certificate, use_thesis and setup is None,
                                        problems, notes)
    origin = {"kind": "upload", "setup_source": setup_source,
              "certificate_source": cert_source}
    if problems or setup_text is None:
        return Assembly(None, _capped(problems), tuple(notes), setup_source, cert_source,
                        origin)
    label = name.strip()[:80] if name and name.strip() else \
        ", ".join(f[0] for f in files)[:60]
    sources = DataSources(
        name=label,
        measurements=tuple(DataFile(f[0], content=f[1], mapping=f[2] if len(f) > 2 else None)
                           for f in files),
        setup=DataFile("setup.json", content=setup_text),
        certificate=None if cert is None else DataFile(cert[0], content=cert[1]))
    try:
        (load or load_sources)(sources)
    except Exception as exc:  # noqa: BLE001 - every problem becomes a row
        return Assembly(None, _capped(problems_of(exc)), tuple(notes), setup_source,
                        cert_source, origin)
    return Assembly(sources, (), tuple(notes), setup_source, cert_source, origin)


def simulated_sources(dataset: Dataset, name: str) -> DataSources:
    """A simulated dataset (``model.simulate(...).dataset``) as sources: its measurements
    in long form, its setup and certificate, written to text in memory."""
    if dataset.certificate is None:
        raise ValueError("a simulation's dataset has a certificate; this one has none.")
    meas, cert = io.StringIO(), io.StringIO()
    write_long_csv(dataset.meas, meas)
    write_certificate(dataset.certificate, cert)
    return DataSources(name=name,
                       measurements=(DataFile("measurements.csv", content=meas.getvalue()),),
                       setup=DataFile("setup.json",
                                      content=json.dumps(dataset.setup.raw, indent=1)),
                       certificate=DataFile("certificate.csv", content=cert.getvalue()))


def inline_sources(sources: DataSources) -> DataSources:
    """``sources`` with every file's text read and carried inline (a file named by path is
    read once, here) and without instruments: the data as the app's session holds them."""

    def inline(f: DataFile) -> DataFile:
        return DataFile(f.name, content=f.source_text(), mapping=f.mapping)

    return DataSources(name=sources.name,
                       measurements=tuple(inline(f) for f in sources.measurements),
                       setup=inline(sources.setup),
                       certificate=None if sources.certificate is None
                       else inline(sources.certificate))


def _data_files(value: Any, where: str):
    """Every :class:`DataFile` inside ``value`` (dataclasses, tuples and lists walked),
    with the field path it sits at ("data.measurements[0]")."""
    if isinstance(value, DataFile):
        yield where, value
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            yield from _data_files(getattr(value, f.name), f"{where}.{f.name}" if where
                                   else f.name)
    elif isinstance(value, (tuple, list)):
        for k, v in enumerate(value):
            yield from _data_files(v, f"{where}[{k}]")


def refuse_paths(record: AnalysisRecord, source: str) -> None:
    """Raise :class:`~cmm_core.io.DataError` when any file of ``record`` (its data,
    instruments, an interim check's stored model, a history's models) is named by a path
    rather than carried inline: a file uploaded to a server must never make the server
    read a path of its own (issue 38). The message names the first such field."""
    for where, f in _data_files(record, ""):
        if f.path is not None:
            raise DataError(f"names the file {f.name!r} by a path ({where}); a file uploaded "
                            "to the app must carry its files' content.", file=source,
                            hint="save the project from the app's Compensate and export "
                                 "page (it carries every file), or load the files "
                                 "themselves on the Data page.")


def load_sources(sources: DataSources) -> Dataset:
    """The :class:`~cmm_core.io.Dataset` of ``sources`` (``DataError`` naming the file,
    row and column when a file does not read)."""

    def src(f: DataFile) -> tuple[io.BytesIO, str]:
        return io.BytesIO(f.text().encode()), f.name

    return load_dataset([src(f) for f in sources.measurements], src(sources.setup)[0],
                        None if sources.certificate is None else src(sources.certificate),
                        name=sources.name)


def sources_key(sources: DataSources) -> str:
    """A short digest of the sources' name and every file's text (a cache key)."""
    h = hashlib.sha1()
    h.update(sources.name.encode())
    for f in sources.measurements:
        h.update(f.name.encode() + b"\0" + f.source_text().encode() + b"\0")
        if f.mapping is not None:
            h.update(json.dumps(f.mapping, sort_keys=True).encode())
    h.update(sources.setup.text().encode())
    if sources.certificate is not None:
        h.update(b"cert" + sources.certificate.text().encode())
    return h.hexdigest()[:16]


def record_from_sources(sources: DataSources, instruments: Sequence = (),
                        **choices: Any) -> AnalysisRecord:
    """An analysis record of ``sources`` (their files' text travels inline),
    ``instruments`` as ``(kind, file name, text)`` triples and the record's ``choices``
    (:func:`~cmm_core.analysis.record_from_inline`)."""
    files = {"name": sources.name,
             "measurements": [(f.name, f.source_text(), f.mapping) if f.mapping is not None
                              else (f.name, f.text()) for f in sources.measurements],
             "setup": sources.setup.text(),
             "certificate": None if sources.certificate is None else (
                 sources.certificate.name, sources.certificate.text())}
    return record_from_inline(files, instruments, **choices)

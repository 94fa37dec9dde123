"""Reading and writing analysis records (``ANALYSIS.json``, docs/report.md), building one
from the app session, and carrying one in a project file. Every refusal names the file,
the key and what was expected."""

from __future__ import annotations

import datetime as dt
import json
import os
from collections.abc import Iterable, Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

from ..export import PROJECT_FORMAT, project_from_json, project_to_json
from ..io import DataError, TableMapping, provenance_from_dict, read_json, refuse_unknown_keys
from ..io.delimited import FileSource
from ..io.errors import cut_repr
from ..model import MAX_ORDER, parse_spec
from .record import (
    FORMAT,
    GP_KERNELS,
    GP_MEANS,
    MPE_U_SOURCES,
    PLATE_CHOICES,
    VERSION,
    AnalysisRecord,
    CheckChoices,
    DataFile,
    DataSources,
    HistoryChoices,
    InstrumentFile,
    instrument_kinds,
)

__all__ = ["KEYS", "instruments_from_list", "record_from_dict", "record_to_dict",
           "record_to_json", "read_record", "record_files", "record_from_inline",
           "record_to_project_json", "record_from_project"]

KEYS = [f.name for f in fields(AnalysisRecord)]
_DATA_KEYS = ("name", "measurements", "setup", "certificate", "instruments")
_FILE_KEYS = ("name", "path", "content")
_MEASUREMENT_KEYS = (*_FILE_KEYS, "mapping")


def instruments_from_list(items: Iterable[dict], name: str | None, where: str = "data.instruments",
                      base: Path | None = None) -> tuple:
    """:class:`InstrumentFile` per entry of a JSON list (``{"kind", "path"}`` or ``{"kind",
    "name", "content"}``); DataError naming ``name`` and the entry otherwise."""
    _check(isinstance(items, list), name, where, "a list of instrument files", items)
    return tuple(_instrument(x, name, f"{where}[{i}]", base) for i, x in enumerate(items))


def _instrument(obj, name, where, base) -> InstrumentFile:
    _check(isinstance(obj, dict) and "kind" in obj, name, where,
           "an object {\"kind\": ..., \"path\": ...} or {\"kind\": ..., \"name\": ..., "
           "\"content\": ...}", obj)
    kind = obj["kind"]
    try:
        refuse_unknown_keys({str(kind): None}, instrument_kinds(), name,
                            what="instrument kind")
    except DataError as exc:
        raise DataError(exc.detail, file=name, column=where + ".kind") from None
    rest = {k: v for k, v in obj.items() if k != "kind"}
    return InstrumentFile(str(kind), _file(rest, name, where, base))


def _file(obj, name, where, base, keys=_FILE_KEYS) -> DataFile:
    if isinstance(obj, str):
        obj = {"path": obj}
    if not isinstance(obj, dict):
        raise DataError(f"expected {{\"path\": ...}} or {{\"name\": ..., \"content\": ...}}, "
                        f"found {cut_repr(obj)}.", file=name, column=where)
    refuse_unknown_keys(obj, keys, name, where + ".")
    path, content = obj.get("path"), obj.get("content")
    if (path is None) == (content is None) or not isinstance(path or content, str):
        raise DataError("expected exactly one of path (text) and content (text).", file=name,
                        column=where)
    if path is not None and base is not None and not Path(path).is_absolute():
        path = str(Path(base) / path)
    label = obj.get("name") or (Path(path).name if path else None)
    if not isinstance(label, str) or not label:
        raise DataError("expected a file name (name) with the content.", file=name,
                        column=where)
    return DataFile(label, path, content, _mapping(obj.get("mapping"), name, where))


def _mapping(obj, name, where) -> dict | None:
    """A measurement file's column mapping, checked (``TableMapping.from_dict``) with the
    key named under ``where``; None when absent."""
    if obj is None:
        return None
    try:
        return TableMapping.from_dict(obj, name=name).to_dict()
    except DataError as exc:
        col = f"{where}.mapping" + (f".{exc.column}" if exc.column else "")
        raise DataError(exc.detail, file=name, column=col, hint=exc.hint) from None


def _check(cond, name, key, expected, found):
    if not cond:
        t = json.dumps(found, ensure_ascii=False, default=str)  # as written in the file
        raise DataError(f"{key} must be {expected}, found {t[:60]}.", file=name, column=key)


def _triple(e) -> bool:
    """An exclusion ``[position, probe, ball]``: two names (text or whole numbers) and a
    whole ball number; anything else would be taken as a name (``{}`` as a probe)."""
    def name(v):
        return isinstance(v, str) or _num(-1e9, 1e9)(v)
    return (isinstance(e, list | tuple) and len(e) == 3 and name(e[0]) and name(e[1])
            and _num(1, 1e6)(e[2]))


def _num(lo, hi, whole=True):
    return lambda v: (isinstance(v, int | float) and not isinstance(v, bool) and lo <= v <= hi
                      and (not whole or float(v).is_integer()))


def _one_of(choices, none=False):
    return (lambda v: v in choices or (none and v is None),
            ("null or " if none else "") + "one of " + ", ".join(choices), lambda v: v)


_NAMES = (lambda v: v is None or (isinstance(v, list) and len(v) > 0
                                  and all(isinstance(x, str | int) for x in v)),
          "null (all) or a non-empty list of names",
          lambda v: None if v is None else tuple(str(x) for x in v))
_BOOL = (lambda v: isinstance(v, bool), "true or false", bool)
_RULES = {  # key: (test, what is expected, conversion)
    "spec": (lambda v: isinstance(v, str), "a model spec such as \"kinematic21,plate_sag\"",
             str),
    "order": (_num(1, MAX_ORDER), f"a whole number 1-{MAX_ORDER}", int),
    "plate": _one_of(PLATE_CHOICES),
    "sigma_um": (lambda v: v == "auto" or (_num(0, 1e3, False)(v) and v > 0),
                 "a repeatability in µm between 0 and 1000, or \"auto\"",
                 lambda v: v if v == "auto" else float(v)),
    "positions": _NAMES, "probes": _NAMES, "exclude_outliers": _BOOL, "diagnose": _BOOL,
    "uncertainty_points": (_num(20, 100_000), "a whole number 20-100000", int),
    "uncertainty_seed": (_num(0, 2**31), "a whole number 0-2147483648", int),
    "gp_mean": _one_of(GP_MEANS, none=True), "gp_kernel": _one_of(GP_KERNELS),
    "mpe_u_source": _one_of(MPE_U_SOURCES),
    "magnification": (_num(1, 1e6, False), "a number 1-1000000", float),
}


def record_from_dict(doc: Any, name: str = "ANALYSIS.json", base: Path | None = None
                 ) -> AnalysisRecord:
    """Check an analysis document (parsed JSON, docs/report.md) and build the record.

    ``name`` is the file named in messages, ``base`` the folder relative data paths are
    resolved against. Raises :class:`DataError` naming the key, what was expected and what
    was found; an unknown key is refused with the known key it most likely misspells.
    """
    _check(isinstance(doc, dict), name, "(document)", "a JSON object", type(doc).__name__)
    refuse_unknown_keys(doc, ["format", "version", "provenance", *KEYS], name)
    if "provenance" in doc:  # what made the record: checked, not used to rerun it
        provenance_from_dict(doc["provenance"], name)
    if doc.get("format") != FORMAT:
        raise DataError(f"is not an analysis record (expected \"format\": \"{FORMAT}\", "
                        f"found {cut_repr(doc.get('format'))!r}).", file=name, column="format")
    _check(_num(1, VERSION)(doc.get("version", VERSION)), name, "version",
           f"a whole number 1-{VERSION} (a newer file needs a newer cmm_core)",
           doc.get("version"))
    d = doc.get("data")
    _check(isinstance(d, dict) and "setup" in d, name, "data",
           "an object with measurements and setup", d)
    refuse_unknown_keys(d, _DATA_KEYS, name, "data.")
    meas = d.get("measurements")
    _check(isinstance(meas, list) and len(meas) > 0, name, "data.measurements",
           "a non-empty list of files", meas)
    files = tuple(_file(m, name, f"data.measurements[{i}]", base, _MEASUREMENT_KEYS)
                  for i, m in enumerate(meas))
    cert = d.get("certificate")
    out: dict[str, Any] = {"data": DataSources(
        str(d.get("name") or ", ".join(f.name for f in files)), files,
        _file(d["setup"], name, "data.setup", base),
        None if cert is None else _file(cert, name, "data.certificate", base),
        instruments_from_list(d.get("instruments") or [], name, base=base))}
    for key, (ok, expected, convert) in _RULES.items():
        if key in doc:
            _check(ok(doc[key]), name, key, expected, doc[key])
            out[key] = convert(doc[key])
    if "spec" in out:
        try:
            parse_spec(out["spec"], default_order=out.get("order", 2))
        except ValueError as exc:
            raise DataError(str(exc), file=name, column="spec") from None
    excl = doc.get("exclusions") or []
    _check(isinstance(excl, list) and all(_triple(e) for e in excl), name, "exclusions",
           "a list of [position, probe, ball] triples (names, and a whole ball number)",
           excl)
    out["exclusions"] = tuple(sorted((str(p), str(q), int(b)) for p, q, b in excl))
    hist = doc.get("history") or []
    _check(isinstance(hist, list) and all(isinstance(h, dict) and isinstance(
        h.get("spec"), str) and (h.get("exclusions") is None or isinstance(
            h["exclusions"], list) and all(_triple(e) for e in h["exclusions"]))
        for h in hist), name, "history",
        "a list of {\"spec\": ..., \"change\": ...} steps, each optionally with its "
        "\"exclusions\" ([position, probe, ball] triples)", hist)
    out["history"] = tuple(
        (h["spec"], str(h.get("change") or ""))
        + (() if h.get("exclusions") is None else
           (tuple(sorted((str(p), str(q), int(b)) for p, q, b in h["exclusions"])),))
        for h in hist)
    if doc.get("interim_check") is not None:
        out["interim_check"] = _check_choices(doc["interim_check"], name, base)
    if doc.get("calibration_history") is not None:
        out["calibration_history"] = _history_choices(doc["calibration_history"], name, base)
    return AnalysisRecord(**out)


_LEVEL = (_num(0.001, 0.2, False), "a level from 0.001 to 0.2")


def _check_choices(obj: Any, name: str, base: Path | None) -> CheckChoices:
    """The ``interim_check`` block: ``{"model": file, "alpha", "family_alpha", "sigma_um",
    "mpe": [A, D]}``."""
    key = "interim_check"
    _check(isinstance(obj, dict) and "model" in obj, name, key,
           "an object {\"model\": {\"path\": ...}, \"alpha\": ..., \"mpe\": [A, D]}", obj)
    refuse_unknown_keys(obj, ("model", "alpha", "family_alpha", "sigma_um", "mpe"), name,
                        key + ".")
    out: dict[str, Any] = {"model": _file(obj["model"], name, key + ".model", base)}
    for k in ("alpha", "family_alpha"):
        if k in obj:
            _check(_LEVEL[0](obj[k]), name, f"{key}.{k}", _LEVEL[1], obj[k])
            out[k] = float(obj[k])
    if obj.get("sigma_um") is not None:
        _check(_num(1e-3, 1e3, False)(obj["sigma_um"]), name, key + ".sigma_um",
               "a repeatability in µm from 0.001 to 1000, or null (the model's)",
               obj["sigma_um"])
        out["sigma_um"] = float(obj["sigma_um"])
    if obj.get("mpe") is not None:
        m = obj["mpe"]
        _check(isinstance(m, list) and len(m) == 2 and _num(0, 1e4, False)(m[0])
               and _num(1e-6, 1e9, False)(m[1]) and m[1] > 0, name, key + ".mpe",
               "[A, D]: MPE = A µm + L/D with A >= 0 and D > 0, e.g. [0.6, 600]", m)
        out["mpe"] = (float(m[0]), float(m[1]))
    return CheckChoices(**out)


def _history_choices(obj: Any, name: str, base: Path | None) -> HistoryChoices:
    """The ``calibration_history`` block: ``{"models": [{"path", "date"}, ...],
    "family_alpha", "nodes", "date"}``."""
    key = "calibration_history"
    _check(isinstance(obj, dict) and isinstance(obj.get("models"), list), name, key,
           "an object {\"models\": [{\"path\": ..., \"date\": \"YYYY-MM-DD\"}, ...]}", obj)
    refuse_unknown_keys(obj, ("models", "family_alpha", "nodes", "date"), name, key + ".")
    models = []
    for i, m in enumerate(obj["models"]):
        where = f"{key}.models[{i}]"
        _check(isinstance(m, dict) and _date(m.get("date")), name, where + ".date",
               "a calibration date YYYY-MM-DD", m.get("date") if isinstance(m, dict) else m)
        models.append((_file({k: v for k, v in m.items() if k != "date"}, name, where, base),
                       str(m["date"])))
    out: dict[str, Any] = {"models": tuple(models)}
    if "family_alpha" in obj:
        _check(_LEVEL[0](obj["family_alpha"]), name, key + ".family_alpha", _LEVEL[1],
               obj["family_alpha"])
        out["family_alpha"] = float(obj["family_alpha"])
    if "nodes" in obj:
        _check(_num(2, 21)(obj["nodes"]), name, key + ".nodes", "a whole number 2-21",
               obj["nodes"])
        out["nodes"] = int(obj["nodes"])
    if obj.get("date") is not None:
        _check(_date(obj["date"]), name, key + ".date",
               "this analysis's calibration date YYYY-MM-DD, or null", obj["date"])
        out["date"] = str(obj["date"])
    _check(len(models) + (out.get("date") is not None) >= 2, name, key + ".models",
           "at least two calibrations (the model files, and this analysis when date is "
           "given)", obj["models"])
    return HistoryChoices(**out)


def _date(v: Any) -> bool:
    """An ISO 8601 calendar date ``YYYY-MM-DD``."""
    if not isinstance(v, str):
        return False
    try:
        dt.date.fromisoformat(v)
    except ValueError:
        return False
    return len(v) == 10


def record_to_dict(record: AnalysisRecord, relative_to: str | Path | None = None) -> dict:
    """The record as a JSON-ready dict (inverse of :func:`record_from_dict`); paths are
    written relative to ``relative_to`` when given."""
    def file(f: DataFile) -> dict:
        mapping = {} if f.mapping is None else {"mapping": f.mapping}
        if f.content is not None:
            return {"name": f.name, "content": f.content, **mapping}
        if f.path is None:
            raise ValueError(f"data file {f.name!r} has neither a path nor its content")
        p = f.path if relative_to is None else Path(os.path.relpath(
            Path(f.path).resolve(), Path(relative_to).resolve())).as_posix()
        return ({"path": p} if Path(p).name == f.name else {"name": f.name, "path": p}) \
            | mapping

    d = record.data
    out: dict[str, Any] = {"format": FORMAT, "version": VERSION,
           "provenance": record.data.provenance().to_dict(),
           "data": {"name": d.name, "measurements": [file(f) for f in d.measurements],
                    "setup": file(d.setup),
                    "certificate": None if d.certificate is None else file(d.certificate)}}
    if d.instruments:  # written only when there are some: older records stay as they were
        out["data"]["instruments"] = [{"kind": i.kind, **file(i.file)} for i in d.instruments]
    for k in KEYS[1:]:
        v = getattr(record, k)
        if k in ("interim_check", "calibration_history"):
            if v is not None:  # written only when there is one: older records stay
                out[k] = _monitor_block(v, file)
            continue
        out[k] = ([{"spec": s, "change": c, **({"exclusions": [list(e) for e in own[0]]}
                                                if own else {})}
                   for s, c, *own in v] if k == "history" else
                  [list(e) for e in v] if k == "exclusions" else
                  list(v) if isinstance(v, tuple) else v)
    return out


def _monitor_block(v: CheckChoices | HistoryChoices, file: Any) -> dict:
    """The ``interim_check`` or ``calibration_history`` block of a record (``file``
    writes one DataFile)."""
    if isinstance(v, CheckChoices):
        return {"model": file(v.model), "alpha": v.alpha, "family_alpha": v.family_alpha,
                "sigma_um": v.sigma_um, "mpe": None if v.mpe is None else list(v.mpe)}
    return {"models": [{**file(f), "date": d} for f, d in v.models],
            "family_alpha": v.family_alpha, "nodes": v.nodes, "date": v.date}


def record_to_json(record: AnalysisRecord, relative_to: str | Path | None = None) -> str:
    """JSON text of the record (``ANALYSIS.json``)."""
    return json.dumps(record_to_dict(record, relative_to), indent=1, ensure_ascii=False)


def record_files(record: AnalysisRecord) -> list[tuple[str, DataFile]]:
    """Every file the record reads, with the key that names it: the data, the
    instruments, the interim check's stored model and the history's models."""
    data = record.data
    out = [(f"data.measurements[{i}]", f) for i, f in enumerate(data.measurements)]
    out += [("data.setup", data.setup)]
    out += [("data.certificate", data.certificate)] if data.certificate else []
    out += [(f"data.instruments[{i}]", x.file) for i, x in enumerate(data.instruments)]
    if record.interim_check is not None:
        out.append(("interim_check.model", record.interim_check.model))
    if record.calibration_history is not None:
        out += [(f"calibration_history.models[{i}]", f)
                for i, (f, _) in enumerate(record.calibration_history.models)]
    return out


def read_record(source: FileSource, name: str | None = None, *,
                confine: bool = False) -> AnalysisRecord:
    """Read ``ANALYSIS.json`` (path, bytes or text); relative data paths are resolved
    against the file's folder.

    With ``confine`` (the command line's default), every file the record names by path
    must lie in the record's folder or below it, links resolved: a record handed on by
    someone else cannot make the program read, or count as its input, a file elsewhere
    on the computer (``/etc/...``, ``../../other_lab/...``). Refused in one line naming
    the key."""
    doc, name = read_json(source, name)
    base = Path(source).parent if isinstance(source, str | Path) and not str(
        source).lstrip().startswith("{") else None
    record = record_from_dict(doc, name or "ANALYSIS.json", base)
    if confine and base is not None:
        root = base.resolve()
        for where, f in record_files(record):
            if f.path is not None and not Path(f.path).resolve().is_relative_to(root):
                shown = os.path.relpath(f.path, base)  # as the record names it
                raise DataError(f"{cut_repr(shown, 80)} lies outside the record's folder; "
                                "expected a file in it or below it.", file=name,
                                column=where, hint="copy the file beside the record, or "
                                "pass --any-path to read files elsewhere.")
    return record


def _inline(name, measurements, setup, certificate, instruments=()) -> dict:
    """The ``data`` block of a record that carries its files' text (``measurements``:
    ``(file name, text)`` pairs, or ``(file name, source table, column mapping)``;
    ``instruments``: ``(kind, file name, text)`` triples)."""
    return {"name": name, "measurements": [{"name": m[0], "content": m[1]}
                                           | ({"mapping": m[2]} if len(m) > 2 else {})
                                           for m in measurements],
            "setup": {"name": "setup.json", "content": setup},
            "certificate": certificate and {"name": certificate[0], "content": certificate[1]},
            "instruments": [{"kind": k, "name": n, "content": c} for k, n, c in instruments]}


def record_from_inline(files: Mapping[str, Any], instruments: Iterable = (),
                       **choices: Any) -> AnalysisRecord:
    """A record whose data travel as text (the app's session, a saved session).

    ``files``: ``name``, ``measurements`` as (file name, text) pairs, ``setup`` text,
    ``certificate`` as a (file name, text) pair or None, and optionally ``mapped``: file
    name -> (source name, source table text, column mapping) for the measurement files
    converted from another tool's table, kept so that the record reloads them through
    their mapping. ``instruments``: ``(kind, file name, text)`` triples. ``choices``: the
    record's own fields by name (:class:`AnalysisRecord`: ``spec``, ``order``, ``plate``,
    ``sigma_um``, ``positions``, ``probes``, ``exclusions``, ``history`` as
    ``{"spec", "change"}`` dicts (optionally with the step's own ``"exclusions"``), ``diagnose`` ...); None or missing takes the record's
    default, an empty history the baseline step of ``spec``.
    """
    mapped = {k: tuple(v) for k, v in (files.get("mapped") or {}).items()}
    doc = {k: list(v) if isinstance(v, tuple) else v for k, v in choices.items()
           if v is not None or k in ("positions", "probes")}
    hist = doc.get("history") or [{"spec": doc.get("spec", "kinematic21"),
                                   "change": "baseline"}]
    doc.update(format=FORMAT, exclusions=[list(e) for e in doc.get("exclusions") or []],
               history=[dict(h) for h in hist],
               data=_inline(files["name"], [mapped.get(m[0], m) for m in files["measurements"]],
                            files["setup"], files.get("certificate"), instruments))
    return record_from_dict(doc, "session")


def record_to_project_json(record: AnalysisRecord) -> str:
    """A project file (``cmm_core.export``) carrying the record: the model block, the
    exclusions and history as ever, the other choices and the instrument files (their
    text) under ``extra.analysis``."""

    d, full = record.data, record_to_dict(record)
    model = {k: full.pop(k) for k in ("spec", "order", "plate", "sigma_um", "positions",
                                      "probes")}
    rest = {k: v for k, v in full.items() if k not in ("data", "format", "version",
                                                       "exclusions", "history", "provenance")}
    for k in ("interim_check", "calibration_history"):  # the project carries the files
        if getattr(record, k) is not None:
            rest[k] = _monitor_block(getattr(record, k), lambda f: {
                "name": f.name, "content": f.source_text()})
    if d.instruments:
        rest["instruments"] = [{"kind": i.kind, "name": i.file.name, "content": i.file.text()}
                               for i in d.instruments]
    mapped = [{"index": k, "name": f.name, "content": f.source_text(), "mapping": f.mapping}
              for k, f in enumerate(d.measurements) if f.mapping is not None]
    if mapped:  # the measurements hold the long form; the source table and its mapping too
        rest["mappings"] = mapped
    return project_to_json(dataset_name=d.name, measurements=[(f.name, f.text()) for f in
                                                              d.measurements],
                           setup=d.setup.text(), certificate=None if d.certificate is None else (
                               d.certificate.name, d.certificate.text()),
                           model=model, exclusions=record.exclusions,
                           history=full["history"], extra={"analysis": rest},
                           provenance=d.provenance())


def record_from_project(text: str | bytes, name: str = "project.json") -> AnalysisRecord:
    """The record a project file carries (its ``extra.analysis`` choices when present)."""

    _check_project_shape(text, name)
    p = project_from_json(text, name)
    extra = p["extra"].get("analysis") or {}
    _check(isinstance(extra, dict), name, "extra.analysis", "an object", extra)
    extra = dict(extra)
    data = _inline(p["dataset_name"], p["measurements"], p["setup"], p["certificate"])
    data["instruments"] = extra.pop("instruments", None) or []
    mapped = extra.pop("mappings", None) or []
    _check(isinstance(mapped, list), name, "extra.analysis.mappings",
           "a list of {\"index\", \"name\", \"content\", \"mapping\"} objects", mapped)
    for k, m in enumerate(mapped):
        where = f"extra.analysis.mappings[{k}]"
        _check(isinstance(m, dict) and _num(0, len(data["measurements"]) - 1)(m.get("index")),
               name, where, "an object whose index names one of the project's "
               f"{len(data['measurements'])} measurement file(s)", m)
        data["measurements"][int(m["index"])] = {x: v for x, v in m.items() if x != "index"}
    doc = {**extra, **p["model"], "format": FORMAT, "exclusions": p["exclusions"],
           "history": p["history"], "data": data}
    return record_from_dict(doc, name)


_SHAPES = (  # (path, test, what is expected): the shape of a project file's parts
    (("dataset",), lambda v: isinstance(v, dict), "an object with measurements and setup"),
    (("dataset", "measurements"), lambda v: isinstance(v, list) and len(v) > 0,
     "a non-empty list of {\"name\": ..., \"content\": ...} files"),
    (("dataset", "setup"), lambda v: isinstance(v, dict | str), "the setup (an object)"),
    (("model",), lambda v: v is None or isinstance(v, dict), "an object"),
    (("exclusions",), lambda v: v is None or isinstance(v, list),
     "a list of [position, probe, ball] triples"),
    (("history",), lambda v: v is None or isinstance(v, list) and all(
        isinstance(h, dict) and isinstance(h.get("spec"), str) for h in v),
     "a list of {\"spec\": ..., \"change\": ...} steps"),
    (("extra",), lambda v: v is None or isinstance(v, dict), "an object"),
    (("extra", "analysis"), lambda v: v is None or isinstance(v, dict), "an object"),
)


def _check_project_shape(text: str | bytes, name: str) -> None:
    """Refuse a project file whose parts have the wrong type, one line naming the key
    (the project reader would stumble on them with a Python error); what it checks
    itself (format, version, entries) is left to it."""
    doc, _ = read_json(text.encode() if isinstance(text, str) else text, name)
    if not isinstance(doc, dict) or doc.get("format") != PROJECT_FORMAT:
        return  # not a project: its reader says so
    for path, ok, expected in _SHAPES:
        parent: Any = doc
        for key in path[:-1]:
            parent = parent.get(key)
            if not isinstance(parent, dict):
                break
        else:
            if path[-1] in parent or len(path) == 1 and path[0] == "dataset":
                _check(ok(parent.get(path[-1])), name, ".".join(path), expected,
                       parent.get(path[-1]))

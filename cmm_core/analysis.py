"""One analysis record: what was analysed and how, shared by the app, the CLI and the report.

An :class:`AnalysisRecord` names the data, selection, exclusions, model (spec, order, plate
mode, σ) and the diagnosis, GP, MPE and report choices. It is read and written as JSON
(``ANALYSIS.json``, docs/report.md), built from the app session by the Export page and
carried by the project file; :func:`run` turns it into numbers, so the same record gives
the same numbers (and the same report) everywhere. Laser interferometer runs and step
gauges (docs/instruments.md) ride along as :class:`InstrumentFile` and are fitted jointly
with the plate in every fit of :func:`run`. Also defined once here: the sign of the
measured error (:data:`ERROR_CONVENTION`) and the outlier default
(:data:`DEFAULT_EXCLUDE_OUTLIERS`).
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from .effects import MAX_ORDER, parse_spec
from .io import DataError, _cut, read_json, refuse_unknown_keys
from .io_instruments import INSTRUMENT_KINDS, read_instrument
from .observations import check_selection

FORMAT = "cmm-error-lab-analysis"
"""Value of the ``format`` key of an analysis record file."""
VERSION = 1
"""Version of the record format written by this code."""
DEFAULT_EXCLUDE_OUTLIERS = False
"""Flagged outliers stay in the fit unless excluded by name or by ``exclude_outliers``:
excluding silently what a robust check flags hides a real effect as easily as a gross
error, so the app and the CLI both show the flags and exclude only what the record says."""
ERROR_CONVENTION = ("measured error = true − reported (µm): the true point is the reported "
                    "point plus the error, which is what compensation adds")
"""The sign of every error shown by the app, the CLI and the report."""
PLATE_CHOICES = ("auto", "fixed", "prior", "free")
GP_MEANS = ("zero", "quadratic", "thesis_quadratic", "kinematic")
GP_KERNELS, MPE_U_SOURCES = ("se_iso", "se_ard"), ("test", "cmm_spec")


def measured_error_um(reported_mm, true_mm) -> np.ndarray:
    """Measured error (µm, :data:`ERROR_CONVENTION`) of points as the CMM reports them
    (``reported_mm``, (n, 3)) given their true or corrected positions (``true_mm``)."""
    return (np.asarray(true_mm, float) - np.asarray(reported_mm, float)) * 1e3


def measured_error_from_residuals_um(residuals_um) -> np.ndarray:
    """Measured error (µm) from the residuals of a fit with no error model (``rigid``):
    the residual is reported minus placed ball, so the error is its negative."""
    return -np.asarray(residuals_um, float)


@dataclass(frozen=True)
class DataFile:
    """One input file, by path or by content (exactly one of the two)."""

    name: str
    """File name used in messages; thesis-form measurement files name their position."""
    path: str | None = None
    """Path of the file (relative paths are resolved against the record's folder)."""
    content: str | None = None
    """The file's text, when the record carries it (the app's downloads do)."""

    def text(self) -> str:
        """The file's text (read from ``path`` when the record does not carry it)."""
        if self.content is not None:
            return self.content
        try:
            return Path(self.path).read_bytes().decode("utf-8-sig")
        except (OSError, UnicodeDecodeError) as exc:
            why = getattr(exc, "strerror", None) or "not UTF-8 text"
            raise DataError(f"cannot be read ({why}).", file=Path(self.path).name) from None


def instrument_kinds() -> tuple:
    """The instrument kinds a record may name (``io_instruments.INSTRUMENT_KINDS``)."""
    return tuple(INSTRUMENT_KINDS)


@dataclass(frozen=True)
class InstrumentFile:
    """One instrument file of an analysis (docs/instruments.md)."""

    kind: str
    """Instrument kind, one of :func:`instrument_kinds` (``laser``, ``step_gauge``)."""
    file: DataFile
    """The file, by path or by content."""

    def read(self):
        """The instrument's readings (``io_instruments``); DataError when bad."""
        return read_instrument(io.StringIO(self.file.text()), self.kind, name=self.file.name)


@dataclass(frozen=True)
class DataSources:
    """The data of an analysis: measurements, setup, an optional certificate and
    instrument files."""

    name: str
    """Dataset label shown in the app and the report."""
    measurements: tuple
    """:class:`DataFile` per measurement file (one long-form or one per position)."""
    setup: DataFile
    """The setup JSON."""
    certificate: DataFile | None = None
    """The plate certificate CSV; None: the plate is self-calibrated."""
    instruments: tuple = ()
    """:class:`InstrumentFile` per laser run or step-gauge file, fitted with the plate."""


@dataclass(frozen=True)
class AnalysisRecord:
    """Everything that decides the numbers of an analysis (docs/report.md)."""

    data: DataSources
    """Input files."""
    spec: str = "kinematic21"
    """Model spec (docs/formats.md#model-specs)."""
    order: int = 2
    """Default polynomial order of the error functions, 1-5."""
    plate: str = "auto"
    """Plate geometry: auto (fixed with a certificate, else free), fixed, prior, free."""
    sigma_um: float | str = 0.5
    """Repeatability of one probed coordinate, µm, or "auto" (estimated from the data)."""
    positions: tuple | None = None
    """Positions fitted (None: all)."""
    probes: tuple | None = None
    """Probes fitted (None: all)."""
    exclusions: tuple = ()
    """``(position, probe, ball)`` observations the user excluded."""
    exclude_outliers: bool = DEFAULT_EXCLUDE_OUTLIERS
    """Also exclude every observation the robust outlier check flags."""
    history: tuple = ()
    """``(spec, change)`` steps of the diagnosis history, first the baseline."""
    diagnose: bool = False
    """Run the diagnosis (ranked missing effects) and report it."""
    uncertainty_points: int = 200
    """Random points of U2/U3 (thesis §4.5.3)."""
    uncertainty_seed: int = 0
    """Seed of those points."""
    gp_mean: str | None = None
    """GP of the measured errors with this mean (:data:`GP_MEANS`); None: no GP."""
    gp_kernel: str = "se_iso"
    """GP covariance: se_iso or se_ard."""
    mpe_u_source: str = "test"
    """U of the MPE decision: "test" (certificate and σ) or "cmm_spec"."""
    magnification: float = 2000.0
    """Magnification of the deviation plots."""


KEYS = [f.name for f in fields(AnalysisRecord)]
_DATA_KEYS = ("name", "measurements", "setup", "certificate", "instruments")
_FILE_KEYS = ("name", "path", "content")


def instruments_from_list(items, name, where="data.instruments", base=None) -> tuple:
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


def _file(obj, name, where, base) -> DataFile:
    if isinstance(obj, str):
        obj = {"path": obj}
    if not isinstance(obj, dict):
        raise DataError(f"expected {{\"path\": ...}} or {{\"name\": ..., \"content\": ...}}, "
                        f"found {_cut(obj)}.", file=name, column=where)
    refuse_unknown_keys(obj, _FILE_KEYS, name, where + ".")
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
    return DataFile(label, path, content)


def _check(cond, name, key, expected, found):
    if not cond:
        t = json.dumps(found, ensure_ascii=False, default=str)  # as written in the file
        raise DataError(f"{key} must be {expected}, found {t[:60]}.", file=name, column=key)


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


def record_from_dict(doc, name="ANALYSIS.json", base=None) -> AnalysisRecord:
    """Check an analysis document (parsed JSON, docs/report.md) and build the record.

    ``name`` is the file named in messages, ``base`` the folder relative data paths are
    resolved against. Raises :class:`DataError` naming the key, what was expected and what
    was found; an unknown key is refused with the known key it most likely misspells.
    """
    _check(isinstance(doc, dict), name, "(document)", "a JSON object", type(doc).__name__)
    refuse_unknown_keys(doc, ["format", "version", *KEYS], name)
    if doc.get("format") != FORMAT:
        raise DataError(f"is not an analysis record (expected \"format\": \"{FORMAT}\", "
                        f"found {_cut(doc.get('format'))!r}).", file=name, column="format")
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
    files = tuple(_file(m, name, f"data.measurements[{i}]", base) for i, m in enumerate(meas))
    cert = d.get("certificate")
    out = {"data": DataSources(
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
    try:
        out["exclusions"] = tuple(sorted((str(p), str(q), int(b))
                                         for p, q, b in doc.get("exclusions") or []))
    except (TypeError, ValueError):
        raise DataError("exclusions must be [position, probe, ball] triples, found "
                        f"{_cut(doc.get('exclusions'))}.", file=name,
                        column="exclusions") from None
    hist = doc.get("history") or []
    _check(isinstance(hist, list) and all(isinstance(h, dict) and isinstance(
        h.get("spec"), str) for h in hist), name, "history",
        "a list of {\"spec\": ..., \"change\": ...} steps", hist)
    out["history"] = tuple((h["spec"], str(h.get("change") or "")) for h in hist)
    return AnalysisRecord(**out)


def record_to_dict(record: AnalysisRecord, relative_to=None) -> dict:
    """The record as a JSON-ready dict (inverse of :func:`record_from_dict`); paths are
    written relative to ``relative_to`` when given."""
    def file(f: DataFile):
        if f.content is not None:
            return {"name": f.name, "content": f.content}
        p = f.path if relative_to is None else Path(os.path.relpath(
            Path(f.path).resolve(), Path(relative_to).resolve())).as_posix()
        return {"path": p} if Path(p).name == f.name else {"name": f.name, "path": p}

    d = record.data
    out = {"format": FORMAT, "version": VERSION,
           "data": {"name": d.name, "measurements": [file(f) for f in d.measurements],
                    "setup": file(d.setup),
                    "certificate": None if d.certificate is None else file(d.certificate)}}
    if d.instruments:  # written only when there are some: older records stay as they were
        out["data"]["instruments"] = [{"kind": i.kind, **file(i.file)} for i in d.instruments]
    for k in KEYS[1:]:
        v = getattr(record, k)
        out[k] = ([{"spec": s, "change": c} for s, c in v] if k == "history" else
                  [list(e) for e in v] if k == "exclusions" else
                  list(v) if isinstance(v, tuple) else v)
    return out


def record_to_json(record: AnalysisRecord, relative_to=None) -> str:
    """JSON text of the record (``ANALYSIS.json``)."""
    return json.dumps(record_to_dict(record, relative_to), indent=1, ensure_ascii=False)


def read_record(source, name=None) -> AnalysisRecord:
    """Read ``ANALYSIS.json`` (path, bytes or text); relative data paths are resolved
    against the file's folder."""
    doc, name = read_json(source, name)
    base = Path(source).parent if isinstance(source, str | Path) and not str(
        source).lstrip().startswith("{") else None
    return record_from_dict(doc, name or "ANALYSIS.json", base)


def _inline(name, measurements, setup, certificate, instruments=()) -> dict:
    """The ``data`` block of a record that carries its files' text (``instruments``:
    ``(kind, file name, text)`` triples)."""
    return {"name": name, "measurements": [{"name": n, "content": c} for n, c in measurements],
            "setup": {"name": "setup.json", "content": setup},
            "certificate": certificate and {"name": certificate[0], "content": certificate[1]},
            "instruments": [{"kind": k, "name": n, "content": c} for k, n, c in instruments]}


def record_from_session(state) -> AnalysisRecord:
    """The record of an app session (the Export page passes ``st.session_state``).

    ``state`` is a mapping with the app's canonical keys: ``ds_files`` (name, measurements
    as (file name, text) pairs, setup text, certificate pair or None), ``instruments``
    (``(kind, file name, text)`` triples, optional), ``spec, order,
    plate, sigma_um, positions, probes, exclusions, history, diag_on, magnification`` and,
    when set, ``w_mpe_u, w_u_npts, w_u_seed`` and, with ``w_report_gp`` true, ``w_gp_mean,
    w_gp_kernel``. Missing keys take the record's defaults.
    """
    f, g = state["ds_files"], state.get
    keys = {"spec": "spec", "order": "order", "plate": "plate", "sigma_um": "sigma_um",
            "positions": "positions", "probes": "probes", "diagnose": "diag_on",
            "exclude_outliers": "exclude_outliers", "uncertainty_points": "w_u_npts",
            "uncertainty_seed": "w_u_seed", "gp_kernel": "w_gp_kernel",
            "mpe_u_source": "w_mpe_u", "magnification": "magnification"}
    doc = {k: list(g(s)) if isinstance(g(s), tuple) else g(s) for k, s in keys.items()
           if g(s) is not None or k in ("positions", "probes")}
    hist = g("history") or [{"spec": doc.get("spec", "kinematic21"), "change": "baseline"}]
    doc.update(format=FORMAT, exclusions=[list(e) for e in g("exclusions") or []],
               history=[dict(h) for h in hist], gp_mean=g("w_gp_mean") if g("w_report_gp")
               else None, data=_inline(f["name"], f["measurements"], f["setup"],
                                       f.get("certificate"), g("instruments") or ()))
    return record_from_dict(doc, "session")


def record_to_project_json(record: AnalysisRecord) -> str:
    """A project file (``cmm_core.export``) carrying the record: the model block, the
    exclusions and history as ever, the other choices and the instrument files (their
    text) under ``extra.analysis``."""
    from .export import project_to_json

    d, full = record.data, record_to_dict(record)
    model = {k: full.pop(k) for k in ("spec", "order", "plate", "sigma_um", "positions",
                                      "probes")}
    rest = {k: v for k, v in full.items() if k not in ("data", "format", "version",
                                                       "exclusions", "history")}
    if d.instruments:
        rest["instruments"] = [{"kind": i.kind, "name": i.file.name, "content": i.file.text()}
                               for i in d.instruments]
    return project_to_json(dataset_name=d.name, measurements=[(f.name, f.text()) for f in
                                                              d.measurements],
                           setup=d.setup.text(), certificate=d.certificate and (
                               d.certificate.name, d.certificate.text()),
                           model=model, exclusions=record.exclusions,
                           history=full["history"], extra={"analysis": rest})


def record_from_project(text, name="project.json") -> AnalysisRecord:
    """The record a project file carries (its ``extra.analysis`` choices when present)."""
    from .export import project_from_json

    p = project_from_json(text, name)
    extra = p["extra"].get("analysis") or {}
    _check(isinstance(extra, dict), name, "extra.analysis", "an object", extra)
    extra = dict(extra)
    data = _inline(p["dataset_name"], p["measurements"], p["setup"], p["certificate"])
    data["instruments"] = extra.pop("instruments", None) or []
    doc = {**extra, **p["model"], "format": FORMAT, "exclusions": p["exclusions"],
           "history": p["history"], "data": data}
    return record_from_dict(doc, name)


def load_data(record: AnalysisRecord):
    """The :class:`~cmm_core.dataset.Dataset` the record names."""
    from .dataset import load_dataset

    def src(f):
        return io.BytesIO(f.text().encode()), f.name

    d = record.data
    return load_dataset([src(f) for f in d.measurements], src(d.setup)[0],
                        d.certificate and src(d.certificate), name=d.name)


def load_instruments(record: AnalysisRecord) -> tuple:
    """The instrument readings the record names (``LaserRun``, ``StepGauge`` ...)."""
    return tuple(i.read() for i in record.data.instruments)


def with_instruments(ds, instruments, *, positions=None, probes=None, exclude=()):
    """What the fits of an analysis take as data: ``ds`` itself without instruments, else
    its selected observations carrying them, so every model built from them (the
    diagnosis's scores and refits, the σ estimate) includes their rows
    (docs/instruments.md#python)."""
    if not instruments:
        return ds
    from .observations import select

    obs = select(ds, positions=positions and list(positions),
                 probes=probes and list(probes), exclude=list(exclude))
    return replace(obs, instruments=tuple(instruments))


@dataclass(frozen=True)
class AnalysisResult:
    """The numbers of one record (:func:`run`)."""

    record: AnalysisRecord
    """The record these numbers come from."""
    dataset: object
    """The loaded :class:`~cmm_core.dataset.Dataset`."""
    fit: object
    """The :class:`~cmm_core.fit.FitResult` of the record's model."""
    exclusions: tuple
    """Observations left out: the record's and, with ``exclude_outliers``, the flagged."""
    flagged: tuple
    """``(position, probe, ball)`` the robust outlier check flags (excluded or not)."""
    sigma: dict
    """σ used: ``{"value_um", "auto"}`` plus the estimate's fields when auto."""
    uncertainty: object
    """:class:`~cmm_core.uncertainty.UncertaintySummary`, or None when it failed."""
    history: tuple
    """History rows: spec, change, rms_um, chi2_dof, bic, n_params."""
    measured_error_um: np.ndarray
    """(n, 3) measured error at the fitted observations (µm, :data:`ERROR_CONVENTION`)."""
    diagnosis: object = None
    """:class:`~cmm_core.diagnose.Diagnosis` when the record asks for it."""
    mpe: object = None
    """:class:`~cmm_core.mpe.MpeResult`, None without a 25-ball certificate."""
    gp: object = None
    """:class:`~cmm_core.gp_cmm.GPComponents` when the record names a GP mean."""
    instruments: tuple = ()
    """Per instrument file, its record of ``instruments.summary`` (kind, file, readings,
    rows, χ², rms_um, max_abs_z ...); empty without instruments."""
    instrument_residuals: object = None
    """``instruments.residuals_frame`` of the fit (one row per reading), None without."""


def _fit_kwargs(r: AnalysisRecord, exclude, **more) -> dict:
    return {"order": r.order, "plate": None if r.plate == "auto" else r.plate,
            "positions": r.positions and list(r.positions), "exclude": list(exclude),
            "probes": r.probes and list(r.probes), **more}


def run(record: AnalysisRecord) -> AnalysisResult:
    """Dataset, fit, history, measured errors, uncertainty, and the optional diagnosis,
    MPE check and GP of a record, every fit with the record's instruments. The app and
    the CLI both call this."""
    from .diagnose import diagnose, estimate_sigma
    from .fit import fit
    from .instruments import residuals_frame, summary
    from .mpe import check_dataset
    from .outliers import detect_outliers
    from .uncertainty import evaluate

    ds = load_data(record)
    check_selection(ds, record.positions, record.probes, record.exclusions,
                    "analysis record")
    try:
        flagged = tuple(tuple(e) for e in detect_outliers(ds).exclusions)
    except ValueError:  # too few positions to compare: nothing flagged unless asked to
        if record.exclude_outliers:
            raise
        flagged = ()
    excl = tuple(sorted(set(record.exclusions) | (set(flagged) if record.exclude_outliers
                                                 else set())))
    inst = load_instruments(record)
    data = with_instruments(ds, inst, positions=record.positions, probes=record.probes,
                            exclude=excl)
    if record.sigma_um == "auto":
        est = estimate_sigma(data, record.spec, **_fit_kwargs(record, excl))
        sigma = {**est.to_dict(), "value_um": float(est.value_um), "auto": True}
    else:
        sigma = {"value_um": float(record.sigma_um), "auto": False}
    kw = _fit_kwargs(record, excl, sigma_um=sigma["value_um"])
    r = fit(data, record.spec, **kw)
    history = [{"spec": spec, "change": change, "rms_um": round(h.rms_um, 4),
                "chi2_dof": round(h.chi2_dof, 3), "bic": round(h.bic, 1), "n_params": h.rank}
               for spec, change in record.history
               for h in [r if spec == record.spec else fit(data, spec, **kw)]]
    rigid = fit(data, "rigid", **kw)
    err = measured_error_from_residuals_um(rigid.residuals_um)
    try:
        unc = evaluate(r, n_random=record.uncertainty_points, seed=record.uncertainty_seed)
    except (ValueError, np.linalg.LinAlgError):
        unc = None
    diag = diagnose(data, record.spec, **kw) if record.diagnose else None
    mpe, _ = check_dataset(ds, u_source=record.mpe_u_source, sigma_um=r.sigma_um)
    gp = None
    if record.gp_mean is not None:
        from .gp_cmm import gp_components

        obs = rigid.problem.obs
        kin = record.gp_mean == "kinematic"
        vals = measured_error_from_residuals_um(r.residuals_um) if kin else err
        gp = gp_components(obs.r_mm, vals, mean="zero" if kin else record.gp_mean,
                           kernel=record.gp_kernel, restarts=1, probe_mm=obs.p_mm)
    return AnalysisResult(record, ds, r, excl, flagged, sigma, unc, tuple(history), err,
                          diag, mpe, gp, tuple(summary(r)) if inst else (),
                          residuals_frame(r) if inst else None)

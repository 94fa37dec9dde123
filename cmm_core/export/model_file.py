"""The model file: a fitted model detached from its data, written and read back checked.

A saved model (``fit --save``, the app's download) holds what a correction needs: the
kinematic terms and coefficients with their covariance, the probe offsets (nominal plus
any fitted offset error), each compensating block's part (``Block.part_to_file``), a
summary of the fit and its provenance (docs/formats.md "Provenance of every record").
:func:`model_from_dict` refuses, naming the key, anything a program could not have
written: another format, labels that do not follow from the orders, a covariance that is
not positive semi-definite, magnitudes that are not µm and mm. The correction itself is
:mod:`.correction`.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..io import (
    MAX_PROBE_MM,
    MAX_STROKE_MM,
    MIN_STROKE_MM,
    DataError,
    atomic_write_text,
    read_json,
)
from ..io.delimited import (
    FileSource,
    read_bytes,
)
from ..io.errors import cut_repr, not_a_json_number
from ..io.provenance import InputFile, Provenance, input_file, provenance_from_dict
from ..io.provenance import provenance as make_provenance
from ..machine import DEFAULT_LAYOUT, LAYOUTS, KinematicTerms
from ..machine import kinematics as kin
from ..model import (
    MAX_ORDER,
    REGISTRY,
    FitResult,
    checked_cov,
    parse_spec,
)
from ..units import UM

COMPENSATING = tuple(b for b in REGISTRY if b.model_keys)
"""Blocks that act on new points, in the order of their parameters in the joint
covariance (after the kinematic coefficients)."""


@dataclass(frozen=True)
class Model:
    """A fitted kinematic model detached from its data (what ``fit --save`` writes).

    Attributes
    ----------
    spec : str
    terms : KinematicTerms
    coef : ndarray
        Kinematic coefficients (µm, µrad).
    cov : ndarray
        Their covariance.
    probes_mm : dict
        Probe name -> effective offset (nominal plus fitted error) in mm.
    undetermined : bool
        True when some kinematic combination was not determined by the data; corrected
        points then carry NaN uncertainties.
    summary : dict
        RMS, χ²/dof and provenance for the record.
    parts : dict
        Block token -> :class:`blocks.compensation.ModelPart` of each block that acts on new
        points (backlash spans, scale expansion coefficients), in :data:`COMPENSATING`
        order; each holds the joint covariance up to its own parameters.
    name : str
        File the model was read from (for messages).
    provenance : Provenance or None
        What made it (software, inputs with their SHA-256, machine, calibration date), as
        its file records it; None for a model not yet written or a file written before
        files carried it (0.7 and earlier).
    source : InputFile or None
        The model file itself with its SHA-256, when read from one: the input of every
        record made from this model.
    certificate : dict or None
        With the plate fixed to its certificate: ``digest`` (SHA-256 of the certificate's
        ball numbers, coordinates and uncertainties as the fit used them), ``balls`` and
        ``sensitivity`` (``S``, kinematic coefficients × 3 per ball: their change per
        standard uncertainty of each certificate coordinate; the certificate's part of
        ``cov`` is ``S Sᵀ``): what lets two calibrations made with one certificate be
        compared with their shared errors counted (``monitor.compare_calibrations``).
    """

    spec: str
    terms: KinematicTerms
    coef: np.ndarray
    cov: np.ndarray
    probes_mm: dict
    undetermined: bool
    summary: dict
    parts: dict = field(default_factory=dict)
    name: str = "model"
    provenance: Provenance | None = None
    source: InputFile | None = None
    certificate: dict | None = None

    def derived_provenance(self, inputs: Iterable[InputFile] = (),
                           **extra: Any) -> Provenance:
        """The provenance of a record made now from this model (results, a check, a
        compensation table): its inputs are the model file and ``inputs``; the machine
        and calibration date are those the model's file names, and ``model_made_by`` /
        ``model_made`` say which software made the model and when."""
        p = self.provenance
        files = [*([self.source] if self.source is not None else []), *inputs]
        if p is None:
            return make_provenance(files, extra=extra)
        return make_provenance(files, machine=p.machine, calibration_date=p.calibration_date,
                               extra={"model_made_by": p.code, "model_made": p.created,
                                      **extra})

    @property
    def joint_cov(self) -> np.ndarray:
        """Covariance of the kinematic coefficients followed by every part's parameters
        (the last part's: each part holds the covariance up to its own)."""
        return next(reversed(self.parts.values())).cov if self.parts else self.cov


def model_from_result(result: FitResult) -> Model:
    """Detach the model from a fit result."""
    obs = result.problem.obs
    probes = {}
    lab, val, _ = result.block("probe_offset")
    for i, q in enumerate(obs.probes):
        p = obs.p_mm[obs.probe == i][0].copy()
        if len(lab):
            p = p + val.reshape(-1, 3)[i] * 1e-3
        probes[q] = p
    blk = result.problem.layout.blocks
    before = np.arange(blk["kinematic"].start, blk["kinematic"].stop)
    parts = {}
    for b in COMPENSATING:
        part = b.compensation(result, before)
        if part is not None and b.token is not None:  # a part has a token (Block.compensation)
            parts[b.token] = part
            before = np.r_[before, np.arange(blk[b.token].start, blk[b.token].stop)]
    # an undetermined span or coefficient would be applied as if known: it makes the
    # model undetermined
    used = set(result.terms.labels).union(*(p.labels for p in parts.values()))
    return Model(result.spec, result.terms, result.kinematic_coef.copy(),
                 result.kinematic_cov.copy(), probes,
                 any(lab in used for lab in result.unidentifiable),
                 {"rms_um": result.rms_um, "chi2_dof": result.chi2_dof, "n_obs": result.n_obs,
                  "fails_chi2_test": bool(result.fails_chi2_test),
                  "birge_ratio": float(result.birge_ratio),
                  # the χ² test's statistic, so that results exported from the model file
                  # state the test as those of the fit (export.results); absent in files
                  # written before them, which then report these as unknown
                  "chi2_test_dof": float(result.chi2_test_dof),
                  "dof_test": int(result.test_statistic[1]),
                  "chi2_p_value": float(result.chi2_p_value),
                  "artefact": getattr(obs, "artefact", "ball_plate"),
                  "placements": [str(p) for p in obs.positions],
                  "plate": result.plate, "sigma_um": result.sigma_um,
                  "certificate_u_source": result.certificate_u_source,
                  "region_mm": _region_mm(obs)},
                 parts, certificate=_certificate_share(result))


def _certificate_share(result: FitResult) -> dict | None:
    """The model's ``certificate`` (:class:`Model`) from a fit with the certificate fixed."""
    S = result.certificate_sensitivity
    obs = result.problem.obs
    if S is None or obs.cert_u_um is None:
        return None
    s = result.problem.layout.blocks["kinematic"]
    return {"digest": certificate_digest(obs.balls, obs.plate0_mm, obs.cert_u_um),
            "balls": [int(b) for b in obs.balls], "sensitivity": np.asarray(S[s], float)}


def certificate_digest(balls, xyz_mm, u_um) -> str:
    """SHA-256 of a certificate as a fit uses it: the ball numbers, the coordinates to
    1 nm and the uncertainties to 1 pm, so that a certificate re-read from its file (or
    written with other line ends) has the same digest, and any other certificate not."""
    rows = [f"{int(b)}:{x:.6f},{y:.6f},{z:.6f}:{ux:.6f},{uy:.6f},{uz:.6f}"
            for b, (x, y, z), (ux, uy, uz) in zip(balls, np.asarray(xyz_mm, float),
                                                  np.asarray(u_um, float), strict=True)]
    return hashlib.sha256("\n".join(rows).encode()).hexdigest()


def _region_mm(obs) -> list:
    """``[min, max]`` of the scale readings the fit saw (mm): the plate's, and the
    instruments' points (an instrument-only fit has no plate readings)."""
    pts = [obs.r_mm - obs.p_mm] + [x for i in obs.instruments for x, _ in i.points()]
    xyz = np.vstack([p for p in pts if len(p)])
    return [np.min(xyz, axis=0).tolist(), np.max(xyz, axis=0).tolist()]


def model_to_dict(model: Model | FitResult, provenance: Provenance | None = None) -> dict:
    """JSON-ready dict of a model (or of a fit result's model).

    ``provenance`` (:meth:`cmm_core.io.Dataset.provenance` of the fitted data) is written
    as the file's ``provenance``; without it, a model read from a file keeps the one it
    has, and any other gets this software's identity and the time alone.
    """
    m = model_from_result(model) if isinstance(model, FitResult) else model
    prov = provenance or m.provenance or make_provenance()
    return {"format": "cmm-error-lab model 1", "spec": m.spec,
            "orders": [list(o) for o in m.terms.orders], "range_mm": list(m.terms.range_mm),
            "periods": [list(o) for o in m.terms.periods],
            # the default layout is left out: model files of the moving bridge stay
            # readable by releases before layouts existed
            **({} if m.terms.layout == DEFAULT_LAYOUT else {"layout": m.terms.layout}),
            "labels": m.terms.labels, "coef": m.coef.tolist(), "cov": m.cov.tolist(),
            "probes_mm": {k: list(map(float, v)) for k, v in m.probes_mm.items()},
            "undetermined": m.undetermined, "summary": m.summary,
            # each block's own keys; none for a model without such blocks (the format of
            # releases before them)
            **{k: v for b in COMPENSATING if b.token in m.parts
               for k, v in b.part_to_file(m.parts[b.token]).items()},
            **({} if m.certificate is None else {"certificate": {
                "digest": m.certificate["digest"], "balls": list(m.certificate["balls"]),
                "sensitivity": np.asarray(m.certificate["sensitivity"]).tolist()}}),
            "provenance": prov.to_dict()}


MODEL_FORMAT = "cmm-error-lab model 1"
_MODEL_REQUIRED = ("format", "spec", "orders", "range_mm", "periods", "labels", "coef",
                   "cov", "probes_mm", "undetermined", "summary")
_MODEL_OPTIONAL = ("layout", "provenance", "certificate",
                   *(k for b in COMPENSATING for k in b.model_keys))


_checked_cov = checked_cov  # the name this module used before the blocks shared it


def model_from_dict(d: dict, *, name: str = "model") -> Model:
    """Rebuild a model from :func:`model_to_dict` output, checking every field.

    Refused with a :class:`DataError` naming the field: another format, labels that do not
    follow from the orders (reordered or edited), non-finite coefficients, a covariance
    that is not a finite positive semi-definite matrix, strokes that are not mm, probe
    offsets that are not 3-vectors in mm.
    """
    layout = _checked_model_header(d, name)
    terms, coef, cov, probes = _parsed_model(d, name, layout)
    spec = _checked_model_terms(d, terms, name)
    _checked_model_values(d, terms, coef, cov, probes, name)
    parts = _model_parts(d, spec, terms.n, name)
    summary = d.get("summary", {})
    if not isinstance(summary, dict):
        raise DataError("summary must be an object.", file=name, column="summary")
    region = summary.get("region_mm")
    if region is not None:
        reg = np.asarray(region, float) if isinstance(region, list) else None
        if reg is None or reg.shape != (2, 3) or not np.isfinite(reg).all():
            raise DataError(f"summary.region_mm must be [[3 numbers], [3 numbers]] (mm), "
                            f"found {cut_repr(region)}.", file=name, column="summary.region_mm")
    if not isinstance(d.get("undetermined", False), bool):
        raise DataError("undetermined must be true or false.", file=name,
                        column="undetermined")
    prov = provenance_from_dict(d["provenance"], name) if "provenance" in d else None
    cert = _checked_certificate(d.get("certificate"), terms.n, name)
    return Model(spec, terms, coef, cov, probes, bool(d.get("undetermined")), summary,
                 parts, name, prov, certificate=cert)


def _checked_certificate(c, n: int, name: str) -> dict | None:
    """The file's ``certificate`` block, checked, or None when absent."""
    if c is None:
        return None
    where = "certificate"
    if not isinstance(c, dict) or set(c) != {"digest", "balls", "sensitivity"}:
        raise DataError("expected an object with digest, balls and sensitivity.", file=name,
                        column=where, hint="refit and save the model again (fit --save); "
                                           "do not edit it.")
    digest, balls, S = c["digest"], c["balls"], c["sensitivity"]
    if not (isinstance(digest, str) and len(digest) == 64
            and all(ch in "0123456789abcdef" for ch in digest)):
        raise DataError(f"expected a SHA-256 in hex, found {cut_repr(digest)}.", file=name,
                        column=where + ".digest")
    if not (isinstance(balls, list) and balls and all(
            isinstance(b, int) and not isinstance(b, bool) and b >= 1 for b in balls)
            and len(set(balls)) == len(balls)):
        raise DataError(f"expected distinct ball numbers, found {cut_repr(balls)}.",
                        file=name, column=where + ".balls")
    bad = not_a_json_number(S)
    if bad:
        raise DataError(f"expected JSON numbers, found sensitivity{bad}.", file=name,
                        column=where + ".sensitivity")
    arr = np.asarray(S, float)
    if arr.shape != (n, 3 * len(balls)) or not np.isfinite(arr).all():
        raise DataError(f"expected {n} rows of {3 * len(balls)} finite numbers (the "
                        f"coefficients by the balls' coordinates), found shape "
                        f"{arr.shape}.", file=name, column=where + ".sensitivity")
    return {"digest": digest, "balls": list(balls), "sensitivity": arr}


def _model_parts(d, spec, n_kin, name):
    """The parts of the compensating blocks the file holds, each read and checked by its
    block; a spec naming such a block without its part (or the reverse) is refused."""
    effects = parse_spec(spec).effects
    parts, n_before = {}, n_kin
    for b in COMPENSATING:
        part = b.part_from_file(d, n_before, name)
        if part is None and b.token in effects and not b.model_keys_optional:
            raise DataError(f"the model's spec has {b.token} but the file holds no "
                            f"{b.model_what} (written by an older version).", file=name,
                            hint="refit and save the model again.")
        if part is not None and b.token not in effects:
            raise DataError(f"the file holds {b.model_what} but the model's spec has no "
                            f"{b.token}.", file=name, column=b.model_keys[0],
                            hint="refit and save the model again (fit --save); do not "
                                 "edit it.")
        if part is not None:
            parts[b.token] = part
            n_before += len(part.values)
    return parts


def _checked_model_header(d, name):
    """A dict of this program's model format, with its machine layout."""
    if not isinstance(d, dict):
        raise DataError(f"is not a model file written by 'fit --save' (expected a JSON object, "
                        f"found {type(d).__name__}).", file=name)
    missing = [k for k in _MODEL_REQUIRED if k not in d]
    extra = sorted(set(map(str, d)) - set(_MODEL_REQUIRED) - set(_MODEL_OPTIONAL))
    if d.get("format") == MODEL_FORMAT and (missing or extra):
        # written by the program: a missing or renamed key ("undeterminedx") would
        # silently take a default (an undetermined model passing as determined)
        raise DataError(f"{'missing key ' + repr(missing[0]) if missing else ''}"
                        f"{'; ' if missing and extra else ''}"
                        f"{'unknown key ' + cut_repr(extra[0]) if extra else ''}; expected the "
                        f"keys {', '.join(_MODEL_REQUIRED)}.", file=name,
                        column=missing[0] if missing else extra[0],
                        hint="refit and save the model again (fit --save); do not edit it.")
    if d.get("format") != MODEL_FORMAT:
        raise DataError(f"is not a model file written by 'fit --save' (expected \"format\": "
                        f"\"{MODEL_FORMAT}\", found {cut_repr(d.get('format'))}).", file=name)
    layout = d.get("layout", DEFAULT_LAYOUT)  # files written before layouts existed
    if not isinstance(layout, str) or layout not in LAYOUTS:
        raise DataError(f"layout {cut_repr(layout)} is not a known machine layout; expected one "
                        f"of: {', '.join(LAYOUTS)}.", file=name, column="layout",
                        hint="refit and save the model again (fit --save); do not edit it.")
    return layout


_SUMMARY_NUMBERS = ("rms_um", "chi2_dof", "birge_ratio", "chi2_p_value", "chi2_test_dof",
                    "dof_test", "n_obs", "sigma_um")
"""Summary keys that hold one number (or null): what the check and report print."""


def _refuse_non_numbers(d, name):
    """Every number of the file a JSON number: ``true`` or ``"2"`` where a coefficient,
    a variance, an order or a stroke belongs would be read as 1.0 or 2.0."""
    fields = [(k, d.get(k)) for k in ("coef", "cov", "range_mm") if k in d]
    if isinstance(d.get("probes_mm"), dict):
        fields += [(f"probes_mm.{q}", v) for q, v in d["probes_mm"].items()]
    for key in ("orders", "periods"):
        if isinstance(d.get(key), list):
            fields += [(f"{key}[{i}]", pair[1]) for i, pair in enumerate(d[key])
                       if isinstance(pair, list) and len(pair) == 2]
    summary = d.get("summary")
    if isinstance(summary, dict):
        fields += [(f"summary.{k}", summary[k]) for k in _SUMMARY_NUMBERS
                   if summary.get(k) is not None]
        if summary.get("region_mm") is not None:
            fields.append(("summary.region_mm", summary["region_mm"]))
    for column, value in fields:
        bad = not_a_json_number(value)
        if bad:
            raise DataError(f"expected JSON numbers, found {column}{bad}.", file=name,
                            column=column, hint="refit and save the model again (fit "
                                                "--save); do not edit it.")
    orders = d.get("orders") if isinstance(d.get("orders"), list) else []
    for i, pair in enumerate(orders):
        order = pair[1] if isinstance(pair, list) and len(pair) == 2 else None
        if isinstance(order, float) and not order.is_integer():
            raise DataError(f"expected a whole polynomial order, found {order!r}.", file=name,
                            column=f"orders[{i}]")


def _parsed_model(d, name, layout):
    """The model's terms and arrays, or a DataError when the file's structure is wrong."""
    _refuse_non_numbers(d, name)
    try:
        terms = KinematicTerms(tuple((str(n), int(o)) for n, o in d["orders"]),
                                   tuple(float(x) for x in d["range_mm"]),
                                   tuple((str(n), float(p)) for n, p in d.get("periods", [])),
                                   layout)
        coef = np.asarray(d["coef"], float)
        cov = np.asarray(d["cov"], float)
        probes = {str(k): np.asarray(v, float) for k, v in d["probes_mm"].items()}
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise DataError(f"is not a model file written by 'fit --save' ({cut_repr(str(exc), 80)}).",
                        file=name) from None
    return terms, coef, cov, probes


def _checked_model_terms(d, terms, name):
    """Spec, strokes, orders, periods and labels consistent with each other; the spec."""
    if not isinstance(d["periods"], list) or not isinstance(d["orders"], list):
        raise DataError("orders and periods must be lists of [function, value] pairs.",
                        file=name, column="orders" if not isinstance(d["orders"], list)
                        else "periods")
    spec = d["spec"]
    try:
        if not isinstance(spec, str):
            raise ValueError(f"expected a model spec string, found {cut_repr(spec)}")
        parse_spec(spec)
    except ValueError as exc:
        raise DataError(f"spec: {cut_repr(str(exc), 120)}.", file=name, column="spec",
                        hint="refit and save the model again (fit --save).") from None
    rng = np.asarray(terms.range_mm, float)
    if rng.shape != (3,) or not np.isfinite(rng).all() or rng.min() < MIN_STROKE_MM \
            or rng.max() > MAX_STROKE_MM:
        raise DataError(f"range_mm {cut_repr(d['range_mm'])} is not three strokes in mm "
                        f"({MIN_STROKE_MM:g} to {MAX_STROKE_MM:g}).", file=name,
                        column="range_mm")
    if any(o < 1 or o > MAX_ORDER for _, o in terms.orders):
        raise DataError(f"orders must be 1 to {MAX_ORDER}, found {cut_repr(d['orders'])}.",
                        file=name, column="orders")
    if any(not (np.isfinite(p) and p > 0) for _, p in terms.periods):
        raise DataError(f"periods must be positive lengths (mm), found "
                        f"{cut_repr(d.get('periods'))}.", file=name, column="periods")
    if d.get("labels") != terms.labels:
        raise DataError(f"labels {cut_repr(d.get('labels'), 80)} do not match the orders (expected "
                        f"{cut_repr(terms.labels, 80)}); the coefficients cannot be assigned.",
                        file=name, column="labels",
                        hint="refit and save the model again (fit --save); do not edit it.")
    return spec


def _checked_model_values(d, terms, coef, cov, probes, name):
    """Finite coefficients, a positive semi-definite covariance and probe offsets in mm."""
    if coef.shape != (terms.n,) or cov.shape != (terms.n, terms.n):
        raise DataError(f"expected {terms.n} coefficients and a {terms.n}x{terms.n} "
                        f"covariance, found {coef.shape} and {cov.shape}.", file=name)
    if not np.isfinite(coef).all():
        k = int(np.flatnonzero(~np.isfinite(coef))[0])
        raise DataError(f"coefficient {terms.labels[k]} is {coef[k]}; expected a finite "
                        "number.", file=name, column="coef",
                        hint="refit and save the model again (fit --save).")
    _checked_cov(cov, terms.n, name, "cov")
    if d.get("undetermined") is False:
        _checked_definite(cov, name, "cov")
    if not probes:
        raise DataError("the model has no probes; expected probes_mm with one offset per "
                        "stylus.", file=name, column="probes_mm")
    for q, p in probes.items():
        if p.shape != (3,) or not np.isfinite(p).all() or np.linalg.norm(p) > MAX_PROBE_MM:
            raise DataError(f"expected 3 finite numbers (mm), found {cut_repr(d['probes_mm'][q])}.",
                            file=name, column=f"probes_mm.{q}")
    _checked_magnitudes(terms, coef, cov, probes, name)


_MAX_ERROR_UM = 10_000.0
"""Largest error (µm) a model term may contribute anywhere in the machine's range, and
largest standard uncertainty of that contribution: 10 mm.

A CMM's geometric errors are micrometres to a few tens of micrometres per metre (ISO
10360-2 MPEs of a few µm + L/300 µm); a controller's uncompensated errors rarely exceed a
fraction of a millimetre. The kinematic model itself is a small-angle linearisation
(thesis eq. 4.1-4.3: rotations enter as first-order terms), which no longer holds at
10 mm over a metre (10 mrad). A term beyond this bound is a file in the wrong units, or
corrupt: finite but huge coefficients (1e308) would turn every correction and grid node
into ±inf or NaN."""


def _sample_points(terms, probes):
    """Scale readings on a 5 × 5 × 5 grid over the strokes (corners included), with each
    probe's offset: where the model's terms are evaluated to bound their size. The
    polynomial bases reach their extremes at the stroke ends; a periodic term may peak
    between nodes, by less than the bound's margin."""
    g = [np.linspace(0.0, r, 5) for r in terms.range_mm]
    x = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)
    offsets = np.array(list(probes.values()), float).reshape(-1, 3)
    return np.tile(x, (len(offsets), 1)), np.repeat(offsets, len(x), axis=0)


def _checked_magnitudes(terms, coef, cov, probes, name):
    """Refuse a coefficient whose contribution to the error anywhere in the machine's
    range (its value times the largest sensitivity of a tip-centre coordinate to it,
    thesis eq. 4.13 linearised at zero) exceeds :data:`_MAX_ERROR_UM`, and the same for
    its standard uncertainty (``sqrt(cov_kk)`` times that sensitivity)."""
    if not terms.n:
        return
    x, p = _sample_points(terms, probes)
    _, J = kin.jacobian(terms, np.zeros(terms.n), x, p)
    sens = np.abs(J).max(axis=(0, 1)) / UM  # µm of error per unit coefficient
    for what, size, col in (("coefficient", np.abs(coef), "coef"),
                            ("standard uncertainty of coefficient",
                             np.sqrt(np.clip(np.diag(cov), 0, None)), "cov")):
        with np.errstate(over="ignore"):  # 1e308 × a sensitivity: inf, refused
            error_um = size * sens
        big = error_um > _MAX_ERROR_UM
        if big.any():
            k = int(np.flatnonzero(big)[0])
            raise DataError(f"{what} {terms.labels[k]} ({size[k]:.3g}) makes an error of "
                            f"{error_um[k] / 1e3:.3g} mm within the machine's range; "
                            f"expected at most {_MAX_ERROR_UM / 1e3:g} mm (a CMM's errors are "
                            "micrometres).", file=name, column=col,
                            hint="check the units; refit and save the model again "
                                 "(fit --save).")


def _checked_definite(cov, name, column):
    """Refuse a covariance that is not positive definite (a determined model's: every
    coefficient combination has a finite, non-zero variance). Tested on the correlation
    matrix, so that the variances' units and scales do not matter: its Cholesky factor
    exists."""
    d = np.diag(cov)
    try:
        if (d <= 0).any():
            raise np.linalg.LinAlgError
        s = 1 / np.sqrt(d)
        np.linalg.cholesky(cov * s[:, None] * s[None, :])
    except np.linalg.LinAlgError:
        raise DataError("the covariance is not positive definite, yet the model says every "
                        "coefficient is determined (\"undetermined\": false).", file=name,
                        column=column, hint="refit and save the model again "
                                            "(fit --save); do not edit it.") from None


def save_model(model: Model | FitResult, path: str | os.PathLike,
               provenance: Provenance | None = None) -> None:
    """Write a model JSON file (atomically: a reader never sees half of it, a failed
    write leaves an existing file as it was), with ``provenance`` (:func:`model_to_dict`)."""
    atomic_write_text(path, json.dumps(model_to_dict(model, provenance), indent=1))


def load_model(path: FileSource, name: str | None = None) -> Model:
    """Read a model JSON file (a path, or bytes / file-like as uploaded), every field
    checked (:func:`model_from_dict`); the model keeps the file's SHA-256
    (:attr:`Model.source`)."""
    raw, name = read_bytes(Path(path) if isinstance(path, str) else path, name)
    d, name = read_json(raw, name)
    return replace(model_from_dict(d, name=name), source=input_file(name, raw))


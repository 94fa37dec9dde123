"""Compensation: correct measured points with a fitted model, with uncertainties.

The true tip centre of a reported point ``r`` measured with probe offset ``p`` is
``r + e(r - p, p)`` (docs/formats.md conventions). A saved model holds what that needs: the
kinematic terms and coefficients with their covariance, and the probe offsets (nominal plus
any fitted offset error). The effect blocks that act on new points add their parts
(``Block.compensation``; the model file's keys are each block's, ``Block.part_to_file``)
and correct the points in turn (``Block.correct``): ``backlash`` for the direction from
which each axis last moved, ``machine_thermal`` for the scales' expansion at the points'
scale temperatures. The uncertainty propagates the kinematic coefficients and every
part's parameters through their joint covariance (JCGM 100 eq. 13):
``u² = diag(J V Jᵀ)`` with ``J = [∂e/∂coef, ∂δ_block/∂values ...]``.
"""

from __future__ import annotations

import codecs
import io
import json
import os
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, overload

import numpy as np
import pandas as pd

from ..io import (
    MAX_BYTES,
    MAX_PROBE_MM,
    MAX_STROKE_MM,
    MIN_STROKE_MM,
    DataError,
    atomic_write_text,
    atomic_writer,
    read_json,
)
from ..io.delimited import (
    FileSource,
    file_rows,
    numeric_column,
    read_bytes,
    read_csv_text,
    require_columns,
    require_rows,
)
from ..io.errors import cut_repr
from ..io.provenance import InputFile, Provenance, input_file, provenance_from_dict
from ..io.provenance import provenance as make_provenance
from ..machine import DEFAULT_LAYOUT, LAYOUTS, KinematicTerms
from ..machine import kinematics as kin
from ..model import (
    MAX_ORDER,
    REGISTRY,
    FitResult,
    checked_cov,
    covariance_factor,
    parse_spec,
    propagate_error,
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
                 parts)


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
            "provenance": prov.to_dict()}


MODEL_FORMAT = "cmm-error-lab model 1"
_MODEL_REQUIRED = ("format", "spec", "orders", "range_mm", "periods", "labels", "coef",
                   "cov", "probes_mm", "undetermined", "summary")
_MODEL_OPTIONAL = ("layout", "provenance", *(k for b in COMPENSATING for k in b.model_keys))


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
    return Model(spec, terms, coef, cov, probes, bool(d.get("undetermined")), summary,
                 parts, name, prov)


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


def _parsed_model(d, name, layout):
    """The model's terms and arrays, or a DataError when the file's structure is wrong."""
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
               allow_extrapolation: bool = True, chunk_points: int = _CHUNK_POINTS) -> dict: ...


def compensate(model: Model | FitResult, points: pd.DataFrame | str | os.PathLike, *,
               out: str | os.PathLike | None = None, allow_extrapolation: bool = True,
               chunk_points: int = _CHUNK_POINTS) -> pd.DataFrame | dict:
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
        return _compensate_file(m, Path(points), out, allow_extrapolation, chunk_points)
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
                     chunk_points: int) -> dict:
    """:func:`compensate` of the points file ``path`` streamed to ``out``."""
    name = path.name
    factor = covariance_factor(m.joint_cov)
    whole = "backlash" in m.parts  # directions follow the order over the whole file
    tables = iter([read_points(path)]) if whole else _point_chunks(path, name, chunk_points)
    n, n_off, first_off, max_abs, max_corr = 0, 0, None, 0.0, 0.0
    with atomic_writer(out, "w") as fh:
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
    if text.count("\n") < chunk_points or (blank and not text.strip()):
        return 0
    cut = text.rfind("\n") + 1
    while cut > 0 and text.count('"', 0, cut) % 2:
        cut = text.rfind("\n", 0, cut - 1) + 1
    return cut


def _header_line(chunk: str) -> str:
    """The header line of a file's first chunk: its first line with a cell."""
    return next(line for line in chunk.split("\n") if line.strip(" \t,;"))


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

"""A calibration as an ANSI/DMSC QIF 3.0 document (``QIFDocument``, schema-valid).

What is written where (``docs/formats.md``, "QIF 3.0"):

- ``Header`` (QIF 3.0 Part 2, QIFDocument.xsd ``QIFDocumentHeaderType``): the software,
  its version and commit as the ``Application``, and the whole provenance (input files
  with their SHA-256, machine, calibration date) as the ``Description``; the same facts,
  one per item, in the document's ``Attributes`` (``AttributeStr``, Part 2 Primitives.xsd)
  so that a program need not parse the text. ``Version/TimeCreated`` is the record's time.
- ``FileUnits``: lengths in mm, temperatures in °C (each with its conversion to SI).
- ``MeasurementResources`` (Part 5, QIFMeasurementResources.xsd): the CMM as a
  ``CartesianCMM``: its name (the setup's ``machine.id``) and serial number (read from
  the name's ``S/N ...``), ``Calibrations`` (the setup's ``calibration_date``, the plate
  temperatures recorded at each placement), ``WorkingVolume`` (the setup's strokes, when
  it states them), ``TemperatureCompensation`` and ``CMMGeometry`` (from the layout),
  ``Accuracies`` (an ISO 10360-2 ``CartesianCMMISO10360Test`` from an MPE ``A + L·B``).
- ``Features`` (Part 3, Features.xsd): with a ball diameter, one sphere definition, each
  certificate ball as a ``SphereFeatureNominal`` (plate frame), each probed ball of each
  placement as a ``SphereFeatureItem`` referring to its nominal. QIF's sphere definition
  requires a diameter, which a ball-plate setup does not state: without one, no features
  are written and the certificate is in the extension only.
- ``Results`` (Part 6, QIFResults.xsd): one ``MeasurementResults`` per placement, each
  probed centre a ``SphereFeatureMeasurement`` whose ``FeatureName`` is
  ``position/probe/ball`` (:data:`cmm_core.io.QIF_LABEL_PATTERN` reads it back) and whose ``Location``
  is the centre as measured (mm, in the setup's frame) with the fit's repeatability as
  its combined standard uncertainty per coordinate.
- ``UserDataXML`` (the QIF document's extension point, Part 2): what QIF has no element
  for, in the namespace :data:`EXTENSION_NS` (structure in ``docs/formats.md``): the
  fitted error model (every parameter with its value, u, expanded U and the Birge-inflated
  u; the χ² test), the certificate with its uncertainties and the setup's frame.

Numbers are written as the shortest positional decimal that reads back as the same double
(xs:decimal has no exponent), so the centres read back are the centres written.
"""

from __future__ import annotations

import calendar
import re
import uuid
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from dataclasses import replace
from datetime import date

import numpy as np

from ..io import LAYOUTS, QIF_NS, Dataset, Provenance
from ..model import FitResult
from .comp_tables import as_model
from .model_file import Model
from .results import DEFAULT_COVERAGE_FACTOR, results_dict

QIF_VERSION = "3.0.0"
"""``QIFDocument/@versionQIF``."""
EXTENSION_NS = "urn:cmm-error-lab:qif:1"
"""Namespace of the elements this program writes in QIF's ``UserDataXML``."""
TEMPERATURE_COMPENSATION = ("NONE", "DEVICE_ONLY", "DEVICE_AND_PART_SAME",
                            "DEVICE_AND_PART_SEPARATE")
"""QIF's ``TemperatureCompensationEnum`` values (Part 5)."""
QIF_GEOMETRY = {"moving_bridge": "MOVING_BRIDGE", "fixed_bridge": "FIXED_BRIDGE",
            "gantry": "GANTRY", "horizontal_arm": "FIXED_TABLE_HORIZONTAL_ARM"}
"""Layout family (``machine.layout`` up to its chain) -> ``CartesianCMMGeometryEnum``; a
horizontal arm of this model stands on a fixed table (its chain starts at F)."""

_SERIAL = re.compile(r"\b(?:S/?N|serial(?:\s+no\.?)?)\s*[:#]?\s*(\S+)", re.I)


def _q(tag: str) -> str:
    return f"{{{QIF_NS}}}{tag}"


def _x(tag: str) -> str:
    return f"{{{EXTENSION_NS}}}{tag}"


def _decimal(v: float) -> str:
    """``v`` as an xs:decimal: shortest positional digits that read back as the same
    double (``repr`` would write ``1e-05``, which xs:decimal refuses)."""
    v = float(v)
    if not np.isfinite(v):
        raise ValueError(f"not a finite number: {v!r}")
    return np.format_float_positional(v, trim="-")


def _el(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    el = ET.SubElement(parent, _q(tag), attrib)
    if text is not None:
        el.text = text
    return el


class _Ids:
    """QIF ids: positive integers unique in the document (``QIFIdUnique``); the largest
    is the document's ``idMax``."""

    def __init__(self) -> None:
        self.last = 0

    def next(self) -> str:
        self.last += 1
        return str(self.last)


def _unit(parent: ET.Element, tag: str, name: str, si: str, factor: str,
          offset: str | None = None) -> None:
    u = _el(parent, tag)
    _el(u, "SIUnitName", si)
    _el(u, "UnitName", name)
    conv = _el(u, "UnitConversion")
    _el(conv, "Factor", factor)
    if offset is not None:
        _el(conv, "Offset", offset)


def _header(root: ET.Element, prov: Provenance) -> None:
    """Attributes, Version, Header and FileUnits (QIFDocumentType's order)."""
    facts = [("software", prov.software), ("version", prov.version),
             ("commit", prov.commit or "unknown"),
             ("uncommitted changes", {True: "yes", False: "no", None: "unknown"}[prov.dirty]),
             ("created", prov.created), ("python", prov.python), ("system", prov.system)]
    if prov.machine:
        facts.append(("machine", prov.machine))
    if prov.calibration_date:
        facts.append(("calibration date", prov.calibration_date))
    facts += [(f"input {f.name}", f"sha256:{f.sha256} ({f.n_bytes} bytes)")
              for f in prov.inputs]
    attrs = _el(root, "Attributes", n=str(len(facts)))
    for k, v in facts:
        _el(attrs, "AttributeStr", name=k, value=v)
    _el(_el(root, "Version"), "TimeCreated", prov.created)
    head = _el(root, "Header")
    app = _el(head, "Application")
    _el(app, "Name", prov.software)
    _el(app, "AddonName", prov.code)
    _el(head, "Description", "\n".join(prov.lines()))
    _el(head, "Scope", "calibration of a CMM's 21 kinematic errors from ball-plate "
        "measurements")
    prim = _el(_el(root, "FileUnits"), "PrimaryUnits")
    _unit(prim, "LinearUnit", "mm", "meter", "0.001")
    _unit(prim, "TemperatureUnit", "C", "kelvin", "1", "273.15")


def _expiry(day: str, months: int) -> str:
    d = date.fromisoformat(day)
    m = d.month - 1 + months
    y, m = d.year + m // 12, m % 12 + 1
    return date(y, m, min(d.day, calendar.monthrange(y, m)[1])).isoformat()


def _calibrations(cmm: ET.Element, ds: Dataset, interval_months: int) -> None:
    day = ds.setup.calibration_date
    if day is None:
        return  # QIF's Calibration needs its dates; the setup states none
    cal = _el(_el(cmm, "Calibrations", n="1"), "Calibration")
    temps = [t for p in ds.setup.positions.values() for t in p.temp_C]
    if temps:
        ts = _el(cal, "Temperatures", n=str(len(temps)))
        for t in temps:
            _el(_el(ts, "Temperature"), "Temperature", _decimal(t))
    _el(cal, "CalibrationDate", f"{day}T00:00:00")
    _el(cal, "ExpirationDate", f"{_expiry(day, interval_months)}T00:00:00")


def _accuracy(cmm: ET.Element, mpe: tuple[float, float]) -> None:
    """ISO 10360-2 ``E = A + L·B`` (A µm, B µm per mm) as QIF's LinearError (Part 5:
    BaseError in the file's length unit, ErrorRate per unit of length measured)."""
    a_um, b_um_per_mm = (float(v) for v in mpe)
    acc = _el(_el(cmm, "Accuracies", n="1"), "CartesianCMMAccuracy")
    _el(acc, "EnvironmentalRange")
    lin = _el(_el(acc, "CartesianCMMISO10360Test"), "LinearError")
    _el(lin, "BaseError", _decimal(a_um / 1000))
    _el(lin, "ErrorRate", _decimal(b_um_per_mm / 1000))
    _el(_el(acc, "AccuracySource"), "AccuracySourceEnum", "MANUFACTURER_SPECIFICATION")


def _cmm(root: ET.Element, ds: Dataset, ids: _Ids, layout: str, *, mpe, compensation,
         interval_months) -> str:
    """``MeasurementResources`` with the CMM; its id."""
    devs = _el(_el(root, "MeasurementResources"), "MeasurementDevices", n="1")
    cmm_id = ids.next()
    cmm = _el(devs, "CartesianCMM", id=cmm_id)
    ident = ds.setup.machine_id
    _el(cmm, "Name", " ".join((ident or "CMM").split()))
    _el(cmm, "Description", f"layout {layout}")
    serial = _SERIAL.search(ident or "")
    if serial:
        _el(cmm, "SerialNumber", serial[1].rstrip(",;"))
    _calibrations(cmm, ds, interval_months)
    machine = ds.setup.raw.get("machine")
    if isinstance(machine, dict) and "range_mm" in machine:
        vol = _el(cmm, "CartesianWorkingVolume")
        for axis, v in zip("XYZ", ds.setup.range_mm, strict=True):
            _el(vol, f"{axis}AxisLength", _decimal(v))
    if compensation is not None:
        _el(_el(cmm, "TemperatureCompensation"), "TemperatureCompensationEnum", compensation)
    family = layout.rsplit("_", 1)[0]
    _el(_el(cmm, "CMMGeometry"), "CartesianCMMGeometryEnum", QIF_GEOMETRY[family])
    if mpe is not None:
        _accuracy(cmm, mpe)
    return cmm_id


def _label(position, probe, ball) -> str:
    return f"{position}/{probe}/{int(ball)}"


def _features(root: ET.Element, ds: Dataset, ids: _Ids, diameter_mm: float) -> dict:
    """Definition, nominals (certificate) and items (probed balls); ``{label: item id}``."""
    cert = ds.certificate
    assert cert is not None
    feats = _el(root, "Features")
    defs = _el(feats, "FeatureDefinitions", n="1")
    def_id = ids.next()
    d = _el(defs, "SphereFeatureDefinition", id=def_id)
    _el(d, "InternalExternal", "EXTERNAL")
    _el(d, "Diameter", _decimal(diameter_mm))
    noms = _el(feats, "FeatureNominals", n=str(len(cert.balls)))
    nominal = {}
    for b, xyz in zip(cert.balls, cert.xyz_mm, strict=True):
        nominal[int(b)] = ids.next()
        n = _el(noms, "SphereFeatureNominal", id=nominal[int(b)])
        _el(n, "Name", f"ball {int(b)}")
        _el(n, "FeatureDefinitionId", def_id)
        _el(n, "Location", " ".join(_decimal(v) for v in xyz))
    keys = list(dict.fromkeys(_label(p, q, b) for p, q, b in
                              ds.meas[["position", "probe", "ball"]].itertuples(index=False)
                              if int(b) in nominal))
    items = _el(feats, "FeatureItems", n=str(len(keys)))
    out = {}
    for key in keys:
        out[key] = ids.next()
        it = _el(items, "SphereFeatureItem", id=out[key])
        _el(it, "FeatureNominalId", nominal[int(key.rsplit("/", 1)[1])])
        _el(it, "FeatureName", key)
        _el(_el(it, "DeterminationMode"), "Checked")
    return out


def _results(root: ET.Element, ds: Dataset, ids: _Ids, cmm_id: str,
             sigma_mm: float | None, items: dict) -> None:
    """One MeasurementResults per placement, one SphereFeatureMeasurement per centre
    (without its uncertainty when the model states no σ: a model file of an old release)."""
    positions = ds.positions
    rs = _el(_el(root, "Results"), "MeasurementResultsSet", n=str(len(positions)))
    u = {} if sigma_mm is None else dict.fromkeys(
        ("xCombinedUncertainty", "yCombinedUncertainty", "zCombinedUncertainty"),
        _decimal(sigma_mm))
    for pos in positions:
        g = ds.meas[ds.meas["position"] == pos]
        res = _el(rs, "MeasurementResults", id=ids.next())
        attrs = _el(res, "Attributes", n="2")
        _el(attrs, "AttributeStr", name="position", value=str(pos))
        _el(attrs, "AttributeStr", name="frame", value=ds.setup.frame)
        mf = _el(res, "MeasuredFeatures", n=str(len(g)))
        for p, q, b, x, y, z in g[["position", "probe", "ball", "x_mm", "y_mm",
                                   "z_mm"]].itertuples(index=False):
            key = _label(p, q, b)
            m = _el(mf, "SphereFeatureMeasurement", id=ids.next())
            if key in items:
                _el(m, "FeatureItemId", items[key])
            _el(m, "FeatureName", key)
            _el(_el(m, "MeasurementDeviceIds", n="1"), "Id", cmm_id)
            _el(m, "Location", " ".join(_decimal(v) for v in (x, y, z)), **u)
        _el(_el(res, "InspectionStatus"), "InspectionStatusEnum", "NOT_CALCULATED")


def _ext_text(parent: ET.Element, tag: str, value, **attrib: str) -> None:
    el = ET.SubElement(parent, _x(tag), attrib)
    if value is not None:
        el.text = _decimal(value) if isinstance(value, float) else str(value)


def _extension(root: ET.Element, ds: Dataset, doc: dict) -> None:
    """``UserDataXML/ErrorModel``: the fitted model and the certificate (docs/formats.md)."""
    em = ET.SubElement(_el(root, "UserDataXML"), _x("ErrorModel"),
                       {"spec": doc["model"]["spec"], "layout": doc["machine"]["layout"],
                        "chain": doc["machine"]["chain"], "frame": ds.setup.frame})
    fit = ET.SubElement(em, _x("Fit"))
    _ext_text(fit, "Repeatability", doc["model"]["sigma_um"], unit="um")
    _ext_text(fit, "RMS", doc["model"]["rms_um"], unit="um")
    t = doc["chi2_test"]
    chi = ET.SubElement(fit, _x("Chi2Test"), {"alpha": _decimal(t["alpha"])})
    for tag, key in (("Chi2PerDof", "chi2_dof"), ("TestedChi2PerDof", "chi2_test_dof"),
                     ("DegreesOfFreedom", "dof"), ("PValue", "p_value"),
                     ("BirgeRatio", "birge_ratio")):
        if t[key] is not None:
            _ext_text(chi, tag, t[key])
    _ext_text(chi, "Outcome", {True: "fails", False: "passes", None: "unknown"}[t["fails"]])
    params = ET.SubElement(em, _x("Parameters"), {"n": str(len(doc["characteristics"]))})
    for c in doc["characteristics"]:
        p = ET.SubElement(params, _x("Parameter"),
                          {"name": c["name"], "block": c["block"], "unit": c["unit"],
                           "determined": "true" if c["determined"] else "false"})
        for tag, key in (("Value", "value"), ("StandardUncertainty", "standard_uncertainty"),
                         ("CoverageFactor", "coverage_factor"),
                         ("ExpandedUncertainty", "expanded_uncertainty"),
                         ("StandardUncertaintyInflated", "standard_uncertainty_inflated")):
            if c[key] is not None:
                _ext_text(p, tag, float(c[key]))
    cert = ds.certificate
    if cert is not None:
        ce = ET.SubElement(em, _x("Certificate"), {"unit": "mm", "uncertaintyUnit": "um",
                                                    "source": cert.u_source})
        u = cert.u_um if cert.u_um is not None else np.full_like(cert.xyz_mm, np.nan)
        for b, xyz, ub in zip(cert.balls, cert.xyz_mm, u, strict=True):
            a = {"number": str(int(b))}
            a.update({f"{k}": _decimal(v) for k, v in zip("xyz", xyz, strict=True)})
            a.update({f"u{k}": _decimal(v) for k, v in zip("xyz", ub, strict=True)
                      if np.isfinite(v)})
            ET.SubElement(ce, _x("Ball"), a)


def _fitted(ds: Dataset, placements) -> Dataset:
    """``ds`` cut to the fit's placements (a fit of some of the dataset's placements): the
    document's measured centres are those its parameters were fitted to."""
    if not isinstance(placements, list) or set(ds.positions) <= set(placements):
        return ds
    return replace(ds, meas=ds.meas[ds.meas["position"].isin(placements)]
                   .reset_index(drop=True))


def _qpid(prov: Provenance) -> str:
    """The document's QPId: a UUID from its provenance, so the same record of the same
    inputs has the same id (QIF 3.0 Part 2: a QPId identifies one document)."""
    key = "|".join([prov.code, prov.created, *(f.sha256 for f in prov.inputs)])
    return str(uuid.uuid5(uuid.NAMESPACE_URL, f"{EXTENSION_NS}:{key}"))


def _check(fitted: list | None, ds: Dataset, mpe, compensation, ball_diameter_mm,
           interval_months) -> None:
    if ds.certificate is None:
        raise ValueError("a QIF calibration document needs the certificate (nominal "
                         "centres): load the dataset with its certificate.")
    missing = [p for p in fitted or () if p not in set(ds.positions)]
    if missing:
        raise ValueError(f"the dataset lacks placement(s) {', '.join(map(str, missing))} of "
                         "the fit: give the data the model was fitted to.")
    layout = ds.setup.raw.get("machine", {}).get("layout", LAYOUTS[0])
    if layout.rsplit("_", 1)[0] not in QIF_GEOMETRY:
        raise ValueError(f"layout {layout!r} has no QIF CMM geometry.")
    if compensation is not None and compensation not in TEMPERATURE_COMPENSATION:
        raise ValueError(f"temperature_compensation must be one of "
                         f"{', '.join(TEMPERATURE_COMPENSATION)}, found {compensation!r}.")
    if mpe is not None and (len(mpe) != 2 or not all(np.isfinite(float(v)) and float(v) >= 0
                                                     for v in mpe)):
        raise ValueError(f"mpe must be (A in µm, B in µm per mm), two numbers >= 0; found "
                         f"{mpe!r}.")
    if ball_diameter_mm is not None and not (0 < float(ball_diameter_mm) < 1000):
        raise ValueError(f"ball_diameter_mm must be a diameter in mm, found "
                         f"{ball_diameter_mm!r}.")
    if not 1 <= int(interval_months) <= 120:
        raise ValueError(f"calibration_interval_months must be 1 to 120, found "
                         f"{interval_months!r}.")


def qif_document(result: FitResult | Model, dataset: Dataset, *, provenance: Provenance | None = None,
                 mpe: Sequence[float] | None = None,
                 temperature_compensation: str | None = None,
                 ball_diameter_mm: float | None = None,
                 calibration_interval_months: int = 12,
                 coverage_factor: float = DEFAULT_COVERAGE_FACTOR,
                 created: str | None = None, inputs: Iterable = ()) -> bytes:
    """A calibration as a QIF 3.0 document (ANSI/DMSC QIF 3.0, Parts 2, 3, 5 and 6).

    Parameters
    ----------
    result : FitResult or Model
        The fit of ``dataset`` (its parameters and χ² test go into the extension), or the
        model file of that fit (``export --qif``: the caller makes sure the model was
        fitted to ``dataset``); the repeatability σ is its summary's.
    dataset : Dataset
        The measurements (ball centres), the setup (machine, strokes, calibration date) and
        the certificate (nominal centres with their uncertainties); required. Only the
        placements the fit used are written (a fit of some of them writes those).
    provenance : Provenance, optional
        What made the document; default ``dataset.provenance(inputs)``.
    mpe : (float, float), optional
        The CMM's ISO 10360-2 maximum permissible error ``E = A + L·B``: A in µm and B in
        µm per mm of length (0.6 µm + L/600: ``(0.6, 1/600)``), written as the CMM's
        ``Accuracies``.
    temperature_compensation : str, optional
        The CMM's temperature compensation, one of :data:`TEMPERATURE_COMPENSATION`;
        written when given (a setup does not record it).
    ball_diameter_mm : float, optional
        The plate's ball diameter: with it, the certificate balls are written as QIF
        sphere nominals and each measurement refers to its feature item (QIF's sphere
        definition requires a diameter).
    calibration_interval_months : int
        QIF's ``Calibration`` requires an ``ExpirationDate``: the calibration date plus
        this interval (the laboratory's recalibration interval; default 12 months).
    coverage_factor : float
        k of the expanded uncertainties in the extension.
    created : str, optional
        The record's time (ISO 8601), default now.
    inputs : iterable of InputFile
        More inputs for the default provenance.

    Returns
    -------
    bytes
        The UTF-8 XML document, root ``QIFDocument`` in :data:`QIF_NS`.

    Raises
    ------
    ValueError
        Without a certificate, without a placement the fit used, for a layout QIF cannot
        name, or a bad keyword value.
    """
    # the placements of the fit (a model file of a release before the key: None)
    fitted = as_model(result).summary.get("placements")
    _check(fitted, dataset, mpe, temperature_compensation, ball_diameter_mm,
           calibration_interval_months)
    prov = provenance or dataset.provenance(tuple(inputs))
    dataset = _fitted(dataset, fitted)
    if created is not None:
        prov = replace(prov, created=created)
    doc = results_dict(result, coverage_factor=coverage_factor, provenance=prov)
    ET.register_namespace("", QIF_NS)
    ET.register_namespace("cel", EXTENSION_NS)
    ids = _Ids()
    root = ET.Element(_q("QIFDocument"), {"versionQIF": QIF_VERSION})
    _el(root, "QPId", _qpid(prov))
    _header(root, prov)
    layout = doc["machine"]["layout"]
    cmm_id = _cmm(root, dataset, ids, layout, mpe=None if mpe is None else tuple(mpe),
                  compensation=temperature_compensation,
                  interval_months=int(calibration_interval_months))
    items = {} if ball_diameter_mm is None else _features(root, dataset, ids,
                                                          float(ball_diameter_mm))
    sigma_um = doc["model"]["sigma_um"]  # a fit's, or the one its model file records
    _results(root, dataset, ids, cmm_id, None if sigma_um is None else sigma_um / 1000, items)
    _extension(root, dataset, doc)
    root.set("idMax", str(ids.last))
    ET.indent(root, space=" ")
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"

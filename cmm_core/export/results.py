"""Fitted parameters with uncertainties for a quality system: JSON and QIF-like XML.

Schema in ``docs/compensation.md`` ("Results for a quality system"). Each parameter is a
*characteristic* with its value, unit, standard uncertainty (law of propagation of
uncertainty, GUM 5.1.2; the fit's covariance), the coverage factor k and the expanded
uncertainty ``U = k·u`` (GUM 6.2.1), and the Birge-inflated standard uncertainty (the
honest figure when the fit fails its χ² test, ``FitResult.u_inflated``). The χ² test of the
fit and whether the model fails it are part of the document. Element names of the XML
follow the spirit of QIF MeasurementResults (machine, artefact, characteristics); it is not
a QIF-schema-valid document.

Numbers are written with Python's shortest round-trip representation, so a value read
back with ``float`` is the same double; a value the data do not determine is ``null`` in
JSON and an absent element (with ``determined="false"``) in XML. So is a parameter held by
a gauge constraint rather than determined by the data (a hole plate's hole coordinates
along the normal, its placements' tilts and normal translations: ``hole_plate``): its
value is the one it was held at, with no uncertainty.

A saved model's results equal those of the model of the fit it came from
(:func:`model_file.model_from_result`): the summary keeps the artefact, the placements
and the χ² test's statistic. A model file written before those were kept reports a ball
plate, no placements and the statistic as unknown.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..io import Provenance
from ..model import FitResult
from .comp_tables import as_model, chi2_status, model_extras
from .model_file import Model

RESULTS_FORMAT = "cmm-error-lab results"
RESULTS_VERSION = 1
DEFAULT_COVERAGE_FACTOR = 2.0
"""k = 2: about 95 % coverage for a normal distribution (GUM 6.2.2, 6.3.3)."""


@dataclass(frozen=True)
class Characteristic:
    """One fitted parameter as a quality system records it."""

    name: str
    """Parameter label, e.g. ``dxx[1]`` (Chebyshev degree in brackets) or ``sxy``."""
    block: str
    """Parameter block: ``kinematic``, ``backlash``, a plate or placement block..."""
    unit: str
    """Unit code: ``um``, ``urad``, ``um/h``, ``1e-6/K``, ``mm``."""
    value: float
    """Estimate."""
    u: float
    """Standard uncertainty (k = 1) from the fit's covariance; NaN when undetermined."""
    u_inflated: float
    """``u`` times the Birge ratio when that exceeds 1 (else ``u``)."""
    determined: bool
    """False when the data do not determine the parameter."""


def held_labels(result: FitResult) -> set:
    """Labels of the parameters a gauge constraint holds by itself (a unit vector of the
    parameter lies in the span of the constraint rows): the data say nothing about them,
    so they are not determined. Combinations held across several parameters (a plate's
    translation) leave each parameter its uncertainty and are not named."""
    C = result.problem.constraints()
    if C is None or not len(C):
        return set()
    # orthonormal basis of the row space: a parameter is held when its unit vector is in it
    _, sv, Vt = np.linalg.svd(np.asarray(C, float), full_matrices=False)
    rows = Vt[sv > 1e-12 * sv.max(initial=0.0)]
    inside = np.sum(rows ** 2, axis=0)  # squared norm of each e_j projected on the span
    return {lab for lab, q in zip(result.labels, inside, strict=True) if q > 1 - 1e-9}


def characteristics(obj: Model | FitResult) -> list[Characteristic]:
    """Every parameter of a fit result; of a saved model, its kinematic coefficients and
    backlash spans (what a model file holds)."""
    t = chi2_status(obj)
    inflate = max(1.0, t["birge_ratio"] or 1.0)
    if isinstance(obj, FitResult):
        bad = set(obj.unidentifiable) | held_labels(obj)
        return [Characteristic(lab, grp, un, float(v), math.nan if lab in bad else float(u),
                               math.nan if lab in bad else float(ui), lab not in bad)
                for lab, grp, un, v, u, ui in zip(obj.labels, obj.groups, obj.units,
                                                  obj.values, obj.u, obj.u_inflated,
                                                  strict=True)]
    m = obj
    ok = not m.undetermined
    u = np.sqrt(np.clip(np.diag(m.cov), 0, None)) if ok else np.full(len(m.coef), np.nan)
    out = [Characteristic(lab, "kinematic", m.terms.unit(lab), float(v), float(s),
                          float(s) * inflate, ok)
           for lab, v, s in zip(m.terms.labels, m.coef, u, strict=True)]
    out += [Characteristic(lab, lab.split(".")[0], unit, v, s if ok else math.nan,
                           s * inflate if ok else math.nan, ok)
            for lab, unit, v, s in model_extras(m)]
    return out


def _num(v):
    """A JSON number, or None for NaN / infinity / missing."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def results_dict(obj: Model | FitResult, *, coverage_factor: float = DEFAULT_COVERAGE_FACTOR,
                 source: str | None = None, created: str | None = None,
                 interim_check: dict | None = None, history: dict | None = None,
                 provenance: Provenance | None = None) -> dict:
    """The results document (JSON-ready; schema in docs/compensation.md).

    ``provenance``: what made it (a fit result's :meth:`cmm_core.io.Dataset.provenance`);
    default, for a model, :meth:`Model.derived_provenance` (the model file and the machine
    it names). Its ``created`` is the document's.

    ``interim_check`` and ``history``: the sections of an interim check against a stored
    calibration and of the machine's calibration history (``monitor``'s
    ``CheckOutcome.results_section`` and ``History.results_section``, docs/monitoring.md),
    written under those keys when given."""
    if not (math.isfinite(coverage_factor) and 1.0 <= coverage_factor <= 10.0):
        raise ValueError(f"the coverage factor must be from 1 to 10, found {coverage_factor!r}.")
    m = as_model(obj)
    prov = provenance or m.derived_provenance()
    if created is not None:
        prov = replace(prov, created=created)
    s = m.summary if isinstance(m.summary, dict) else {}
    t = chi2_status(obj)
    region = s.get("region_mm")
    kind = s["artefact"] if s.get("artefact") in ("ball_plate", "hole_plate") \
        else "ball_plate"  # model files written before the key: ball plates
    artefact = {"type": kind.replace("_", " "), "plate_geometry": s.get("plate"),
                "n_observations": s.get("n_obs"),
                "certificate_uncertainty_source": s.get("certificate_u_source"),
                "measured_region_mm": region}
    if isinstance(s.get("placements"), list):
        artefact["placements"] = [str(p) for p in s["placements"]]
    chars = [{"name": c.name, "block": c.block, "unit": c.unit, "value": _num(c.value),
              "standard_uncertainty": _num(c.u), "coverage_factor": coverage_factor,
              "expanded_uncertainty": _num(c.u * coverage_factor),
              "standard_uncertainty_inflated": _num(c.u_inflated),
              "determined": c.determined}
             for c in characteristics(obj)]
    return {"format": RESULTS_FORMAT, "version": RESULTS_VERSION,
            "created": prov.created,
            "software": {"name": prov.software, "version": prov.version},
            "provenance": prov.to_dict(),
            "machine": {"layout": m.terms.layout, "chain": m.terms.chain,
                        "range_mm": [float(v) for v in m.terms.range_mm],
                        "probes_mm": {k: [float(x) for x in v] for k, v in m.probes_mm.items()}},
            "artefact": artefact,
            "model": {"name": source or m.name, "spec": m.spec,
                      "sigma_um": _num(s.get("sigma_um")), "rms_um": _num(s.get("rms_um")),
                      "undetermined": bool(m.undetermined)},
            "chi2_test": {"chi2_dof": _num(t["chi2_dof"]),
                          "chi2_test_dof": _num(t["chi2_test_dof"]), "dof": t["dof"],
                          "p_value": _num(t["p_value"]), "alpha": t["alpha"],
                          "fails": t["fails"], "birge_ratio": _num(t["birge_ratio"])},
            "characteristics": chars,
            **({} if interim_check is None else {"interim_check": interim_check}),
            **({} if history is None else {"history": history})}


def results_json(obj: Model | FitResult, **kw: Any) -> str:
    """:func:`results_dict` as JSON text (no NaN: undetermined numbers are ``null``)."""
    return json.dumps(results_dict(obj, **kw), indent=1, allow_nan=False, ensure_ascii=False)


def _text(parent, tag, value, **attrib):
    """Append ``<tag attrib>value</tag>``; numbers as their shortest round-trip repr."""
    el = ET.SubElement(parent, tag, {k: str(v) for k, v in attrib.items()})
    if isinstance(value, bool):
        el.text = "true" if value else "false"
    elif isinstance(value, int | np.integer):
        el.text = str(int(value))
    elif isinstance(value, float | np.floating):
        el.text = repr(float(value))
    elif value is not None:
        el.text = str(value)
    return el


def _provenance_xml(parent, p: dict) -> None:
    """``<Provenance>``: the software with its commit, the machine, and each input file
    with its SHA-256."""
    el = ET.SubElement(parent, "Provenance")
    _text(el, "Software", p["software"], version=p["version"], python=p["python"],
          system=p["system"])
    if p["commit"] is not None:
        _text(el, "Commit", p["commit"], dirty="true" if p["dirty"] else "false")
    _text(el, "Created", p["created"])
    if p["machine"] is not None:
        _text(el, "Machine", p["machine"])
    if p["calibration_date"] is not None:
        _text(el, "CalibrationDate", p["calibration_date"])
    for f in p["inputs"]:
        _text(el, "Input", f["name"], sha256=f["sha256"], bytes=f["bytes"])


def results_xml(obj: Model | FitResult, **kw: Any) -> str:
    """The results document as QIF-like XML (UTF-8, ``MeasurementResults`` root).

    Structure (docs/compensation.md): ``Header``, ``MeasurementDevice`` (machine layout,
    strokes, probes), ``Artefact``, ``Model``, ``Chi2Test`` and ``Characteristics`` with one
    ``Characteristic`` per parameter holding ``Value``, ``StandardUncertainty``,
    ``CoverageFactor``, ``ExpandedUncertainty`` and ``StandardUncertaintyInflated``.
    """
    d = results_dict(obj, **kw)
    root = ET.Element("MeasurementResults", {"format": d["format"],
                                             "version": str(d["version"])})
    head = ET.SubElement(root, "Header")
    _text(head, "Created", d["created"])
    _text(head, "Software", d["software"]["name"], version=d["software"]["version"])
    _provenance_xml(head, d["provenance"])
    mac = ET.SubElement(root, "MeasurementDevice", {"type": "CMM"})
    _text(mac, "Layout", d["machine"]["layout"], chain=d["machine"]["chain"])
    rng = ET.SubElement(mac, "Range", {"unit": "mm"})
    for a, v in zip("XYZ", d["machine"]["range_mm"], strict=True):
        _text(rng, a, v)
    for name, p in d["machine"]["probes_mm"].items():
        pr = ET.SubElement(mac, "Probe", {"name": name, "unit": "mm"})
        for a, v in zip("XYZ", p, strict=True):
            _text(pr, a, v)
    art = ET.SubElement(root, "Artefact", {"type": d["artefact"]["type"]})
    _text(art, "PlateGeometry", d["artefact"]["plate_geometry"])
    _text(art, "NumberOfObservations", d["artefact"]["n_observations"])
    for p in d["artefact"].get("placements", []):
        _text(art, "Placement", p)
    mod = ET.SubElement(root, "Model", {"spec": d["model"]["spec"]})
    _text(mod, "Name", d["model"]["name"])
    _text(mod, "Repeatability", d["model"]["sigma_um"], unit="um")
    _text(mod, "RMS", d["model"]["rms_um"], unit="um")
    _text(mod, "Undetermined", d["model"]["undetermined"])
    t = d["chi2_test"]
    chi = ET.SubElement(root, "Chi2Test", {"alpha": repr(t["alpha"])})
    for tag, key in (("Chi2PerDof", "chi2_dof"), ("TestedChi2PerDof", "chi2_test_dof"),
                     ("DegreesOfFreedom", "dof"), ("PValue", "p_value"),
                     ("BirgeRatio", "birge_ratio")):
        if t[key] is not None:
            _text(chi, tag, t[key])
    _text(chi, "Outcome", {True: "fails", False: "passes", None: "unknown"}[t["fails"]])
    _text(chi, "ModelFailsTest", t["fails"] if t["fails"] is not None else "unknown")
    chars = ET.SubElement(root, "Characteristics", {"count": str(len(d["characteristics"]))})
    for i, c in enumerate(d["characteristics"], 1):
        el = ET.SubElement(chars, "Characteristic",
                           {"id": str(i), "name": c["name"], "block": c["block"],
                            "determined": "true" if c["determined"] else "false"})
        _text(el, "Value", c["value"], unit=c["unit"])
        for tag, key in (("StandardUncertainty", "standard_uncertainty"),
                         ("CoverageFactor", "coverage_factor"),
                         ("ExpandedUncertainty", "expanded_uncertainty"),
                         ("StandardUncertaintyInflated", "standard_uncertainty_inflated")):
            if c[key] is not None:
                _text(el, tag, c[key], **({} if key == "coverage_factor" else
                                          {"unit": c["unit"]}))
    ET.indent(root, space=" ")
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"

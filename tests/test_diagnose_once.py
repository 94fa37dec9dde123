"""One judgement (issue 36, item 2): ``diagnose`` takes the baseline fit its caller holds
and fits the baseline only when given none; given or fitted, the verdict and every number
are the same, and a fit of other data or settings is refused."""

import json

import numpy as np
import pytest
from scenarios import layout_data, simulated

from cmm_core import analysis as A
from cmm_core.diagnosis import certificate_check, diagnose, replicates, search, verdict
from cmm_core.model import fit, parse_spec, simulate

SAG = {"plate_sag": {"uu": -2.0, "uv": 0.5, "vv": -1.5}}
"""A 2 µm plate sag: the diagnosis names it (tests/test_diagnose.py's hidden effect)."""


def _case(name):
    """``(data, baseline spec, fit kwargs)`` of a simulated case (seeded)."""
    if name == "sag":
        return simulate({"seed": 3, "effects": SAG}).dataset, "kinematic21", {}
    if name == "clean":  # nothing hidden: no effect named
        return simulate({"seed": 201}).dataset, "kinematic21", {}
    if name == "pitch100_sag":  # another plate, pitch, placements and styli
        return simulated("pitch100_4pos", 11, effects=SAG).dataset, "kinematic21", {}
    if name == "gantry_drift":  # another machine layout, a drift hidden
        return (layout_data("pitch150_5pos", "gantry_fxyz", 12,
                            effects={"drift": {"sd_um_per_h": 1.0}}).dataset,
                "kinematic21", {})
    # σ stated too small (0.3 µm for 0.5 µm noise): the σ check and uniformity run
    return simulate({"seed": 5}).dataset, "kinematic21", {"sigma_um": 0.3}


def _doc(d) -> str:
    """The diagnosis's JSON (every verdict, number and message), NaN as text so that two
    equal documents compare equal."""
    return json.dumps(d.to_dict(), sort_keys=True, default=float)


@pytest.mark.parametrize("name", ["sag", "clean", "sigma", "pitch100_sag", "gantry_drift"])
def test_given_fit_gives_the_same_diagnosis(name):
    data, spec, kw = _case(name)
    alone = diagnose(data, spec, **kw)
    given = diagnose(data, spec, baseline_fit=fit(data, spec, **kw), **kw)
    assert given.verdict == alone.verdict
    # exact: the same deterministic computation from the same baseline (a converged fit
    # stops at the same step whatever its iteration budget)
    assert _doc(given) == _doc(alone)
    assert given.message == alone.message
    for a, b in zip(alone.candidates, given.candidates, strict=True):
        np.testing.assert_array_equal(a.signature_um, b.signature_um)


def test_the_certificate_case_is_the_same_given_its_fit(thesis_clean):
    """The thesis data with the certificate fixed: the baseline's fixed-plate fit is also
    the certificate check's (``fitted=``), given or not."""
    ds, excl = thesis_clean
    alone = diagnose(ds, "kinematic21", exclude=excl)
    given = diagnose(ds, "kinematic21", exclude=excl,
                     baseline_fit=fit(ds, "kinematic21", exclude=excl))
    assert _doc(given) == _doc(alone)


def _counting(monkeypatch) -> list:
    """Every ``model.fit`` the diagnosis makes, as ``(spec spelt out, plate mode,
    observations)``: the name is wrapped in each diagnosis module that calls it (each
    imported it by name)."""
    calls: list = []

    def counted(data, spec="kinematic21", **kw):
        model = parse_spec(spec, default_order=kw.get("order", 2)) if isinstance(
            spec, str) else spec
        calls.append((model.to_string(explicit=True), kw.get("plate"), data))
        return fit(data, spec, **kw)

    for mod in (search, verdict, certificate_check, replicates):
        monkeypatch.setattr(mod, "fit", counted)
    return calls


def _baseline_fits(calls, base) -> int:
    """How many of ``calls`` fit the baseline's model with its plate mode to all its
    observations. The certificate check's fits of the baseline's model with the plate
    free or as a prior are other fits; a holdout check's fits the baseline to fewer
    observations (the other placements)."""
    n = len(base.problem.obs.table)
    return sum(spec == base.spec and plate in (None, base.plate)
               and len(data.meas if hasattr(data, "meas") else data.table) >= n
               for spec, plate, data in calls)


@pytest.mark.parametrize("name", ["sag", "sigma"])
def test_a_diagnosis_given_its_fit_fits_the_baseline_never(monkeypatch, name):
    data, spec, kw = _case(name)
    base = fit(data, spec, **kw)
    calls = _counting(monkeypatch)
    diagnose(data, spec, baseline_fit=base, **kw)
    assert calls, "the wrapper saw no fit: it wraps the wrong name"
    assert _baseline_fits(calls, base) == 0, [c[:2] for c in calls]
    # and without one it fits the baseline exactly once
    calls.clear()
    diagnose(data, spec, **kw)
    assert _baseline_fits(calls, base) == 1, [c[:2] for c in calls]


def test_a_fit_of_other_choices_is_refused():
    data, spec, _ = _case("sag")
    base = fit(data, spec)
    with pytest.raises(ValueError, match="expects 0.7, the fit has 0.5"):
        diagnose(data, spec, baseline_fit=base, sigma_um=0.7)
    with pytest.raises(ValueError, match="another model"):
        diagnose(data, "kinematic21,plate_sag", baseline_fit=base)
    with pytest.raises(ValueError, match="plate mode: the diagnosis expects 'fixed'"):
        diagnose(data, spec, baseline_fit=fit(data, spec, plate="free"))
    one = (data.positions[0], data.probes[0], 1)
    with pytest.raises(ValueError, match="other observations"):
        diagnose(data, spec, baseline_fit=base, exclude=[one])


def test_the_record_runner_fits_the_baseline_once(monkeypatch):
    """``analysis.diagnose_record`` given the record's fit (as ``analysis.run`` and the
    app pass it) makes no baseline fit of its own, and agrees with the one that does."""
    data, spec, _ = _case("sag")

    class Choices:  # the fit fields of an analysis record (analysis.FitChoices)
        order, plate, sigma_um, positions, probes, exclusions = 2, "auto", 0.5, None, None, ()

    Choices.spec = spec
    base = A.fit_record(Choices, data)
    alone = A.diagnose_record(Choices, data)
    calls = _counting(monkeypatch)
    given = A.diagnose_record(Choices, data, baseline_fit=base)
    assert _baseline_fits(calls, base) == 0
    assert _doc(given) == _doc(alone)

"""The model-spec grammar of SPEC "the effect catalogue" and the catalogue entries."""

import pytest

from cmm_core.machine import ROTATIONAL, SQUARENESS
from cmm_core.model import catalogue_entry, parse_spec


@pytest.mark.parametrize("spec,expected", [
    ("kinematic21", "kinematic21"),
    ("kinematic21,-sxy", "kinematic21,-sxy"),
    ("translational,squareness", "kinematic21,-rotational"),
    ("translational", "dxx,dxy,dxz,dyx,dyy,dyz,dzx,dzy,dzz"),
    ("kinematic21,plate_sag", "kinematic21,plate_sag"),
    ("kinematic21,dyz:3", "kinematic21,dyz:3"),
    ("dyz:3,-dyz,dyz", "dyz"),  # tokens apply left to right
    ("kinematic21,-rotational,rxx", "kinematic21," + ",".join(
        f"-{n}" for n in ROTATIONAL if n != "rxx")),
    ("kinematic21,periodic_x:180,-periodic_x,periodic_y:95", "kinematic21,periodic_y:95"),
    ("rigid", "rigid"),
    ("", "rigid"),
    (" Kinematic21, DYZ:3 ,Backlash", "kinematic21,dyz:3,backlash"),  # case and spaces
])
def test_spec_grammar_and_round_trip(spec, expected):
    m = parse_spec(spec)
    assert m.to_string() == expected
    assert parse_spec(m.to_string()) == m


def _orders(m):
    """Orders that change the model (squareness is one constant at any order)."""
    return {n: (1 if n in SQUARENESS else o) for n, o in m.active}


@pytest.mark.parametrize("order", [1, 2, 3, 5])
@pytest.mark.parametrize("spec", ["kinematic21", "kinematic21,dyz:2,-sxy,plate_sag",
                                  "translational,squareness", "dxx,rzz:4", "rigid"])
def test_explicit_string_reads_back_at_the_spec_default_order(spec, order):
    """Reports and the CLI write orders relative to the SPEC's default 2, so that
    "kinematic21" fitted at order 3 is never read back as order 2; the plain string
    keeps the model's own default so that the app's order selector re-orders it."""
    m = parse_spec(spec, default_order=order)
    text = m.to_string(explicit=True)
    back = parse_spec(text)
    assert _orders(back) == _orders(m) and back.effects == m.effects, text
    assert _orders(parse_spec(m.to_string(), default_order=order)) == _orders(m)
    if order != 2 and m.active:
        assert f":{order}" in text


@pytest.mark.parametrize("spec,needle", [
    ("kinematic21,foo", "unknown model token 'foo'"),
    ("dxx:9", "order must be 1-5"),
    ("dxx:two", "whole number"),
    ("periodic_x", "give the period in mm"),
    ("periodic_z:0.1", "give the period in mm"),
])
def test_bad_tokens_say_what_was_expected(spec, needle):
    with pytest.raises(ValueError, match=needle):
        parse_spec(spec)


def test_candidates_are_every_missing_token_and_each_has_a_catalogue_entry():
    m = parse_spec("kinematic21,-sxy,plate_sag")
    cands = m.candidates()
    assert "sxy" in cands and "plate_sag" not in cands and {"dxx:3", "dxx:4"} <= set(cands)
    assert "dxx:5" in parse_spec("kinematic21", default_order=4).candidates()
    assert not any(c.startswith("dxx:6") for c in
                   parse_spec("kinematic21", default_order=4).candidates())
    assert {"plate_thermal", "probe_offset", "drift"} <= set(cands)
    assert {"periodic_x", "periodic_y", "periodic_z"} <= set(cands)
    for tok in cands + ["periodic_x:180"]:
        e = catalogue_entry(tok)
        assert e.explanation and e.needs and e.confused_with and e.separate_by

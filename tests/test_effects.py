"""The model-spec grammar of SPEC "the effect catalogue" and the catalogue entries."""

import pytest

from cmm_core.effects import catalogue_entry, parse_spec
from cmm_core.kinematics import ERROR_NAMES, ROTATIONAL


@pytest.mark.parametrize("spec,expected", [
    ("kinematic21", "kinematic21"),
    ("kinematic21,-sxy", ",".join(n for n in ERROR_NAMES if n != "sxy")),
    ("translational,squareness", "dxx,dxy,dxz,dyx,dyy,dyz,dzx,dzy,dzz,sxy,sxz,syz"),
    ("kinematic21,plate_sag", "kinematic21,plate_sag"),
    ("kinematic21,dyz:3", "kinematic21,dyz:3"),
    ("dyz:3,-dyz,dyz", "dyz"),  # tokens apply left to right
    ("kinematic21,-rotational,rxx", ",".join(
        n for n in ERROR_NAMES if n not in ROTATIONAL or n == "rxx")),
    ("kinematic21,periodic_x:180,-periodic_x,periodic_y:95", "kinematic21,periodic_y:95"),
    ("rigid", "rigid"),
    ("", "rigid"),
])
def test_spec_grammar_and_round_trip(spec, expected):
    m = parse_spec(spec)
    assert m.to_string() == expected
    assert parse_spec(m.to_string()) == m


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
    assert "sxy" in cands and "plate_sag" not in cands and "dxx:3" in cands
    assert {"plate_thermal", "probe_offset", "drift"} <= set(cands)
    assert {"periodic_x", "periodic_y", "periodic_z"} <= set(cands)
    for tok in cands + ["periodic_x:180"]:
        e = catalogue_entry(tok)
        assert e.explanation and e.needs and e.confused_with and e.separate_by

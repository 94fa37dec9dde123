"""Foreign files into the long form: DMIS output (.dmo) and mapped vendor tables.

DMIS files and vendor tables are written here from the project's own simulator and read
back to the same long form; unit conversions are checked against hand-computed values;
every bad input is one DataError naming the file, the row and (for tables) the column.
"""

from __future__ import annotations

import datetime as dt
import io
import json

import numpy as np
import pytest
from conftest import ROOT

from cmm_core.cli import main
from cmm_core.io import DataError, load_dataset, write_certificate
from cmm_core.io.dmis import read_dmis, read_foreign
from cmm_core.io.table_mapping import (
    ForeignTable,
    TableMapping,
    apply_mapping,
    inspect_table,
    preview,
    read_mapping,
    suggest_mapping,
)
from cmm_core.model import simulate

PATTERN = r"(?P<position>BP\d+)_P(?P<probe>\w+)_B(?P<ball>\d+)"
XYZ = ["x_mm", "y_mm", "z_mm"]
T0 = dt.datetime(2026, 11, 24, 14, 5, 33)


@pytest.fixture(scope="module")
def sim():
    return simulate({"seed": 11, "minutes_per_ball": 1.0})


@pytest.fixture(scope="module")
def meas(sim):
    return sim.dataset.meas[["position", "probe", "ball", "time_min", "temp_C", *XYZ]]


def _dmo(meas, *, unit="MM", factor=1.0, decimals=6, continued=True, header=True):
    """A DMIS output file of the measurements: one TIME line and one FA sphere each."""
    lines = ["$$ written by tests/test_foreign_tables.py", "FILNAM/'ball plate',05.3"]
    if header:
        lines += [f"UNITS/{unit},ANGDEC", f"DATE={T0:%Y/%m/%d}"]
    for k, r in enumerate(meas.itertuples()):
        t = T0 + dt.timedelta(minutes=float(r.time_min))
        lines.append(f"TIME={t:%H:%M:%S}")
        x, y, z = (v / factor for v in (r.x_mm, r.y_mm, r.z_mm))
        label = f"{r.position}_P{r.probe}_B{r.ball}"
        if continued and k % 3 == 0:  # continuation lines: $ at the end
            lines += [f"FA({label})=FEAT/SPHERE,CART,{x:.{decimals}f},$",
                      f"   {y:.{decimals}f}, {z:.{decimals}f},$", "   25.4000"]
        else:
            lines.append(f"FA({label})=FEAT/SPHERE,CART, {x:.{decimals}f}, {y:.{decimals}f},"
                         f" {z:.{decimals}f}, 25.4000")
    return ("\n".join(lines) + "\n").encode()


def _same_long_form(table: ForeignTable, meas, tol_mm=1.5e-6, time=True):
    got = table.meas.reset_index(drop=True)
    want = meas.reset_index(drop=True)
    assert got["position"].tolist() == want["position"].tolist()
    assert got["probe"].tolist() == [str(p) for p in want["probe"]]
    assert got["ball"].tolist() == want["ball"].tolist()
    np.testing.assert_allclose(got[XYZ].to_numpy(), want[XYZ].to_numpy(), atol=tol_mm, rtol=0)
    if time:
        np.testing.assert_allclose(got["time_min"], want["time_min"], atol=1e-6)


def _one_line(exc):
    assert "\n" not in str(exc.value)
    return exc.value


# ---------------------------------------------------------------------------------------
# DMIS
# ---------------------------------------------------------------------------------------

def test_dmis_from_the_simulator_reads_back_and_loads(sim, meas, tmp_path):
    table = read_dmis(_dmo(meas), name="run.dmo", pattern=PATTERN)
    _same_long_form(table, meas)
    assert table.unmatched == () and table.csv_name == "run.dmo (mapped)"
    # each row stands on the line of its statement: row in messages = line of the .dmo
    text = _dmo(meas).decode().split("\n")
    for row, label in zip(table.meas["row"][:6], ("BP111_P1_B1", "BP111_P1_B2"), strict=False):
        assert label in text[row - 1]
    # the CSV text loads as a dataset with the simulation's setup and certificate
    (tmp_path / "setup.json").write_text(json.dumps(sim.dataset.setup.raw))
    write_certificate(sim.dataset.certificate, tmp_path / "cert.csv")
    ds = load_dataset([table.as_source()], tmp_path / "setup.json", tmp_path / "cert.csv")
    assert len(ds.meas) == len(meas)
    np.testing.assert_allclose(ds.meas[XYZ].to_numpy(), meas[XYZ].to_numpy(), atol=1.5e-6)


def test_dmis_in_inch_is_converted_to_mm(meas):
    table = read_dmis(_dmo(meas, unit="INCH", factor=25.4, decimals=9), name="inch.dmo",
                      pattern=PATTERN)
    _same_long_form(table, meas, tol_mm=2e-6)
    assert any("INCH converted to mm (× 25.4)" in n for n in table.notes)


def test_dmis_hand_computed_units_and_times():
    text = (b"UNITS/INCH,ANGDEC\nDATE=2026/11/24\nTIME=23:59:30\n"
            b"FA(H_1)=FEAT/SPHERE,CART,10,0.5,-2,1\n"
            b"DATE=2026/11/25\nTIME=00:01:00\n"
            b"UNITS/MM,ANGDEC\n"
            b"FA(H_2)=FEAT/SPHERE,OUTER,CART,100.0,-50.25,3E+01,25.4\n")
    t = read_dmis(text, name="h.dmo", pattern=r"(?P<position>H)_(?P<ball>\d+)").meas
    np.testing.assert_allclose(t[XYZ].to_numpy(), [[254.0, 12.7, -50.8], [100.0, -50.25, 30.0]])
    np.testing.assert_allclose(t["time_min"], [0.0, 1.5])  # across midnight by DATE
    assert t["probe"].tolist() == ["1", "1"]


@pytest.mark.parametrize("date_line, time_line, minutes", [
    ("DATE=2026-11-24", "TIME=14:06:03", 0.5),
    ("DATE='24.11.2026'", "TIME='14:06:03.000'", 0.5),
    ("DATE=11/24/2026", "TIME=14:06", 0.45),
    ("DATE = 24-NOV-2026", "TIME = 14:06", 0.45),
])
def test_dmis_common_date_and_time_forms(date_line, time_line, minutes):
    text = (f"DATE=2026/11/24\nTIME=14:05:33\nFA(P_1)=FEAT/SPHERE,CART,0,0,0,25\n"
            f"{date_line}\n{time_line}\nFA(P_2)=FEAT/SPHERE,CART,500,0,0,25\n").encode()
    t = read_dmis(text, name="d.dmo", pattern=r"(?P<position>P)_(?P<ball>\d+)").meas
    np.testing.assert_allclose(t["time_min"], [0.0, minutes])


def test_dmis_without_units_or_time_is_mm_with_notes():
    text = b"F(B1)=FEAT/SPHERE,CART,1,2,3,25\nF(B2)=FEAT/SPHERE,CART,500,2,3,25\n"
    t = read_dmis(text, name="plain.dmo", pattern=r"B(?P<ball>\d+)", default_position="BP111",
                  default_probe="7")
    assert "time_min" not in t.meas
    np.testing.assert_allclose(t.meas["x_mm"], [1.0, 500.0])
    assert t.meas["position"].tolist() == ["BP111"] * 2 and t.meas["probe"].tolist() == ["7"] * 2
    assert any("no UNITS line" in n and "mm" in n for n in t.notes)
    # the nominal line of a sphere F(...) is not read when measured FA(...) are present
    both = text + b"FA(B1)=FEAT/SPHERE,CART,1.001,2,3,25\nFA(B2)=FEAT/SPHERE,CART,500.002,2,3,25\n"
    t = read_dmis(both, name="both.dmo", pattern=r"B(?P<ball>\d+)", default_position="P")
    np.testing.assert_allclose(t.meas["x_mm"], [1.001, 500.002])
    assert any("2 nominal sphere(s)" in n for n in t.notes)


def test_dmis_continuation_lines_and_comments():
    text = (b"$$ header comment\nUNITS/MM\nFA(BP1_1)=FEAT/SPHERE,$\n  CART,$\n"
            b"  10.5,$   $$ x\n  20.5,$\n  -30.5,25\nFA(BP1_2)=FEAT/SPHERE,CART,400,20,-30,25\n")
    t = read_dmis(text, name="c.dmo", pattern=r"(?P<position>BP\d+)_(?P<ball>\d+)")
    np.testing.assert_allclose(t.meas[XYZ].to_numpy()[0], [10.5, 20.5, -30.5])
    assert t.meas["row"].tolist() == [3, 8]  # the statement's first line
    bad = text.replace(b"  20.5,$", b"  2O.5,$")
    exc = _one_line(pytest.raises(DataError, read_dmis, bad, name="c.dmo",
                                  pattern=r"(?P<position>BP\d+)_(?P<ball>\d+)"))
    assert (exc.file, exc.row) == ("c.dmo", 3)
    assert "FA(BP1_1)" in exc.detail and "'2O.5'" in exc.detail and "y value" in exc.detail


def test_dmis_labels_not_matching_are_listed_in_one_line(meas):
    extra = (b"FA(PLANE_1)=FEAT/PLANE,CART,0,0,0,0,0,1\n"  # not a sphere: not a label here
             b"FA(REF_A)=FEAT/SPHERE,CART,0,0,0,25\nFA(REF_B)=FEAT/SPHERE,CART,1,0,0,25\n"
             b"FA(CHECK)=FEAT/SPHERE,CART,2,0,0,25\n")
    table = read_dmis(_dmo(meas.head(5), continued=False) + extra, name="m.dmo",
                      pattern=PATTERN)
    assert len(table.meas) == 5
    assert table.unmatched == ("REF_A", "REF_B", "CHECK")
    note = [n for n in table.notes if "do not match" in n]
    assert len(note) == 1 and note[0].startswith("3 label(s)") and "'REF_A'" in note[0]
    # the plane is not a ball, and is said to be left out with its row (not dropped)
    other = [n for n in table.notes if "other than spheres" in n]
    assert len(other) == 1 and "PLANE FA(PLANE_1) (row " in other[0]
    exc = _one_line(pytest.raises(DataError, read_dmis, extra, name="m.dmo", pattern=PATTERN))
    assert exc.file == "m.dmo" and "none of the 3 sphere label(s)" in exc.detail


def test_dmis_label_measured_twice_is_a_repeat():
    text = (b"FA(BP1_1)=FEAT/SPHERE,CART,0,0,0,25\nFA(BP1_2)=FEAT/SPHERE,CART,500,0,0,25\n"
            b"FA(BP1_1)=FEAT/SPHERE,CART,0.001,0,0,25\n")
    t = read_dmis(text, name="r.dmo", pattern=r"(?P<position>BP\d+)_(?P<ball>\d+)")
    assert t.meas["repeat"].tolist() == [0, 0, 1]
    # two labels for the same ball: a pattern that loses a part of the label
    two = text.replace(b"FA(BP1_1)=FEAT/SPHERE,CART,0.001", b"FA(BP1_01)=FEAT/SPHERE,CART,0.001")
    exc = _one_line(pytest.raises(DataError, read_dmis, two, name="r.dmo",
                                  pattern=r"(?P<position>BP\d+)_(?P<ball>\d+)"))
    assert (exc.file, exc.row) == ("r.dmo", 3) and "FA(BP1_01)" in exc.detail
    assert "appears twice (also in row 1)" in exc.detail


@pytest.mark.parametrize("text, row, words", [
    (b"UNITS/FURLONG\nFA(B_1)=FEAT/SPHERE,CART,0,0,0,25\n", 1, "UNITS/FURLONG"),
    (b"DATE=2026/13/24\nFA(B_1)=FEAT/SPHERE,CART,0,0,0,25\n", 1, "expected a date"),
    (b"TIME=25:61\nFA(B_1)=FEAT/SPHERE,CART,0,0,0,25\n", 1, "expected a time of day"),
    (b"TIME=10:00\nFA(B_1)=FEAT/SPHERE,CART,0,0,0,25\nTIME=09:00\n"
     b"FA(B_2)=FEAT/SPHERE,CART,500,0,0,25\n", 4, "timed 09:00:00, before the sphere above it (10:00:00, row 2)"),
    (b"\nFA(B_1)=FEAT/SPHERE,POL,10,20,0,25\n", 2, "expected CART"),
    (b"FA(B_1)=FEAT/SPHERE,CART,0,0,25\n", 1, "expected 4 values"),
    (b"FA(B_1)=FEAT/SPHERE,CART,0,nan,0,25\n", 1, "y value"),
    (b"FA(B_x)=FEAT/SPHERE,CART,0,0,0,25\n", 1, "expected a whole ball number"),
])
def test_dmis_bad_input_names_file_line_and_label(text, row, words):
    exc = _one_line(pytest.raises(DataError, read_dmis, text, name="bad.dmo",
                                  pattern=r"(?P<position>B)_(?P<ball>\w+)"))
    assert exc.file == "bad.dmo" and exc.row == row and words in exc.detail
    if b"FA(B_" in text.split(b"\n")[row - 1]:
        assert "B_" in exc.detail  # the label


@pytest.mark.parametrize("pattern, words", [
    (r"(?P<position>BP\d+_(?P<ball>\d+)", "not a valid regular expression"),
    (r"(?P<position>BP\d+)_\d+", "has no group 'ball'"),
    (r"(?P<postion>BP\d+)_(?P<ball>\d+)", "did you mean 'position'"),
    (r"BP\d+_(?P<ball>\d+)", "has no group 'position'"),
])
def test_dmis_bad_pattern_is_one_line(meas, pattern, words):
    exc = _one_line(pytest.raises(DataError, read_dmis, _dmo(meas.head(2)), name="p.dmo",
                                  pattern=pattern))
    assert exc.column == "pattern" and words in exc.detail


def test_dmis_file_level_problems():
    exc = _one_line(pytest.raises(DataError, read_dmis, b"FILNAM/'x'\nUNITS/MM\n",
                                  name="e.dmo", pattern=PATTERN))
    assert exc.file == "e.dmo" and "no sphere" in exc.detail
    exc = _one_line(pytest.raises(DataError, read_dmis, b"\x00\x01", name="b.dmo",
                                  pattern=PATTERN))
    assert "NUL" in exc.detail
    exc = _one_line(pytest.raises(DataError, read_dmis, "/no/such/file.dmo", pattern=PATTERN))
    assert exc.file == "file.dmo" and "not found" in exc.detail
    # not UTF-8 (a degree sign in a comment from an old controller): read, with a note
    t = read_dmis("$$ 20\xb0C\nFA(BP1_1)=FEAT/SPHERE,CART,0,0,0,25\n".encode("latin-1"),
                  name="l.dmo", pattern=r"(?P<position>BP\d+)_(?P<ball>\d+)")
    assert any("Latin-1" in n for n in t.notes)


def test_dmis_units_that_look_wrong_keep_the_file_and_line():
    text = b"".join(b"FA(BP1_%d)=FEAT/SPHERE,CART,%f,0.1,0,25\n" % (k, 0.1 * k)
                    for k in range(1, 6))
    exc = _one_line(pytest.raises(DataError, read_dmis, text, name="m.dmo",
                                  pattern=r"(?P<position>BP\d+)_(?P<ball>\d+)"))
    assert "look like metres" in exc.detail and "unit" in exc.hint


# ---------------------------------------------------------------------------------------
# Mapped tables
# ---------------------------------------------------------------------------------------

def _vendor_feature_csv(meas):
    """Feature,X,Y,Z,Diameter in mm, decimal point, comma-separated."""
    lines = ["Feature,X,Y,Z,Diameter"]
    for r in meas.itertuples():
        lines.append(f"{r.position}_P{r.probe}_B{r.ball},{r.x_mm:.6f},{r.y_mm:.6f},"
                     f"{r.z_mm:.6f},25.4002")
    return ("\n".join(lines) + "\n").encode()


def _german_csv(meas, factor=1e-3, decimals=3):
    """Name;X-Wert;Y-Wert;Z-Wert in µm (factor mm per unit) with decimal commas."""
    lines = ["Name;X-Wert;Y-Wert;Z-Wert;Zeit [s];Temperatur"]
    for r in meas.itertuples():
        vals = [f"{v / factor:.{decimals}f}".replace(".", ",") for v in (r.x_mm, r.y_mm, r.z_mm)]
        t = f"{r.time_min * 60:.1f}".replace(".", ",")
        temp = f"{r.temp_C:.4f}".replace(".", ",")
        lines.append(";".join([f"{r.position}_P{r.probe}_B{r.ball}", *vals, t, temp]))
    return ("\n".join(lines) + "\n").encode()


def test_vendor_feature_table_reads_back(meas):
    data = _vendor_feature_csv(meas)
    info = inspect_table(data, name="vendor.csv")
    assert info.suggestion == {"x": "X", "y": "Y", "z": "Z", "label": "Feature"}
    m = TableMapping(x="X", y="Y", z="Z", label="Feature", pattern=PATTERN)
    table = apply_mapping(data, m, name="vendor.csv")
    _same_long_form(table, meas, time=False)
    assert table.meas["row"].tolist()[:3] == [2, 3, 4]


@pytest.mark.parametrize("unit, factor, decimals", [("um", 1e-3, 3), ("inch", 25.4, 9)])
def test_german_table_with_decimal_commas_and_units_reads_back(meas, unit, factor, decimals):
    data = _german_csv(meas, factor, decimals)
    m = TableMapping(x="X-Wert", y="Y-Wert", z="Z-Wert", label="Name", pattern=PATTERN,
                     time="Zeit [s]", time_unit="s", temperature="Temperatur", unit=unit,
                     decimal=",", delimiter=";")
    table = apply_mapping(data, m, name="export.csv")
    _same_long_form(table, meas, tol_mm=2e-6)
    np.testing.assert_allclose(table.meas["temp_C"], meas["temp_C"], atol=1e-4)
    assert any("semicolon-separated with decimal commas" in n for n in table.notes)
    assert any(f"from {unit} to mm" in n for n in table.notes)


def test_mapped_columns_and_constants_hand_computed():
    data = (b"Pos\tKugel\tX\tY\tZ\n"
            b"A\t1\t1000\t2000,5\t-3000\n"
            b"A\t2\t500000\t2000\t-3000\n")
    m = TableMapping(x="X", y="Y", z="Z", position="Pos", ball="Kugel", unit="um",
                     decimal=",", constant_probe="S2")
    t = apply_mapping(data, m, name="tab.txt")
    np.testing.assert_allclose(t.meas[XYZ].to_numpy(), [[1.0, 2.0005, -3.0], [500.0, 2.0, -3.0]])
    assert t.meas["probe"].tolist() == ["S2", "S2"] and t.meas["ball"].tolist() == [1, 2]
    assert any("probe 'S2' for every row" in n for n in t.notes)
    # a quoted decimal comma in a comma-separated file, inch, constant position
    data = b'Ball,X,Y,Z\n1,"10,5",0,0\n2,20,"0,25",0\n'
    m = TableMapping(x="X", y="Y", z="Z", ball="Ball", constant_position="H1", unit="inch",
                     decimal=",")
    t = apply_mapping(data, m, name="q.csv")
    np.testing.assert_allclose(t.meas[XYZ].to_numpy(), [[266.7, 0, 0], [508.0, 6.35, 0]])


def test_mapping_json_round_trip_and_file(tmp_path):
    m = TableMapping(x="X-Wert", y="Y-Wert", z="Z-Wert", label="Name", pattern=PATTERN,
                     unit="um", decimal=",", delimiter="\t")
    assert TableMapping.from_dict(m.to_dict()) == m
    path = tmp_path / "mapping.json"
    path.write_text(json.dumps(m.to_dict()))
    assert read_mapping(path) == m
    assert TableMapping.from_dict({"x": "X", "y": "Y", "z": "Z", "ball": "B",
                                   "constant_position": "P"}).unit == "mm"


@pytest.mark.parametrize("obj, column, words", [
    ({"x": "X", "y": "Y", "z": "Z", "ball": "B", "postion": "P"}, "postion",
     "did you mean 'position'"),
    ({"x": "X", "y": "Y", "ball": "B", "constant_position": "P"}, "z", "missing key 'z'"),
    ({"x": "X", "y": "Y", "z": "Z", "ball": 3, "constant_position": "P"}, "ball",
     "expected a column name (text) or null, found 3"),
    ({"x": "X", "y": "Y", "z": "Z", "ball": "B", "constant_position": "P", "unit": "µm"},
     "unit", "found 'µm'; did you mean 'um'?"),
    ({"x": "X", "y": "Y", "z": "Z", "ball": "B", "constant_position": "P", "decimal": ";"},
     "decimal", "expected one of '.', ','"),
    ({"x": "X", "y": "Y", "z": "Z", "ball": "B", "constant_position": "P",
      "delimiter": "|"}, "delimiter", "found '|'"),
    ({"x": "X", "y": "Y", "z": "Z", "constant_position": "P"}, "ball", "no ball number"),
    ({"x": "X", "y": "Y", "z": "Z", "ball": "B"}, "position", "no position"),
    ({"x": "X", "y": "Y", "z": "Z", "ball": "B", "constant_position": "P",
      "constant_probe": None}, "probe", "no probe"),
    ({"x": "X", "y": "Y", "z": "Z", "label": "F", "constant_position": "P"}, "pattern",
     "label given without pattern"),
    ({"x": "X", "y": "X", "z": "Z", "ball": "B", "constant_position": "P"}, "y",
     "x and y both name column 'X'"),
    ({"x": "X", "y": "Y", "z": "Z", "label": "F", "pattern": "(?P<bal>\\d+)",
      "constant_position": "P"}, "pattern", "did you mean 'ball'"),
])
def test_mapping_validation_is_one_line_with_did_you_mean(obj, column, words):
    exc = _one_line(pytest.raises(DataError, TableMapping.from_dict, obj, name="map.json"))
    assert exc.file == "map.json" and exc.column == column and words in exc.detail


def test_mapping_json_file_problems(tmp_path):
    path = tmp_path / "m.json"
    path.write_text("[1, 2]")
    exc = _one_line(pytest.raises(DataError, read_mapping, path))
    assert exc.file == "m.json" and "expected a JSON object" in exc.detail
    path.write_text("{\"x\": ")
    assert "not valid JSON" in _one_line(pytest.raises(DataError, read_mapping, path)).detail


GERMAN = TableMapping(x="X-Wert", y="Y-Wert", z="Z-Wert", label="Name", pattern=PATTERN,
                      unit="um", decimal=",")


@pytest.mark.parametrize("mapping, data, row, column, words", [
    (TableMapping(x="X-Wrt", y="Y-Wert", z="Z-Wert", label="Name", pattern=PATTERN,
                  decimal=","), None, 1, "X-Wrt", "did you mean 'X-Wert'"),
    (GERMAN, b"Name;X-Wert;Y-Wert;Z-Wert\nBP1_P1_B1;1;2;x3\n", 2, "Z-Wert",
     "expected a number, found 'x3'"),
    (GERMAN, b"Name;X-Wert;Y-Wert;Z-Wert\n\nBP1_P1_B1;1;2;3\nBP1_P1_B01;500000;2;3\n", 4,
     "Name", "appears twice (also in row 3)"),
    (TableMapping(x="X-Wert", y="Y-Wert", z="Z-Wert", label="Name", pattern=PATTERN),
     None, None, None, "decimal commas"),
    (TableMapping(x="X-Wert", y="Y-Wert", z="Z-Wert", label="Name", pattern=PATTERN,
                  decimal=",", delimiter=","), None, 1, None, "mapping says comma"),
    (TableMapping(x="X", y="Y", z="Z", ball="B", constant_position="P", temperature="T"),
     b"B,X,Y,Z,T\n1,0,0,0,293.15\n2,500,0,0,20\n", 2, "T", "looks like kelvin"),
    (TableMapping(x="X", y="Y", z="Z", ball="B", constant_position="P"),
     b"B,X,Y,Z\n1,0,0,0\n2.5,500,0,0\n", 3, "B", "whole ball number"),
    (TableMapping(x="X", y="Y", z="Z", ball="B", constant_position="P"),
     b"B,X,Y,Z\n1,0,0,0\n2,500000,0,0\n", 3, "X", "looks like µm"),
    (TableMapping(x="X", y="Y", z="Z", label="F", pattern=r"(?P<position>P)(?P<ball>\w)"),
     b"F,X,Y,Z\nP1,0,0,0\nPa,500,0,0\n", 3, "F", "'Pa': the ball group matched 'a'"),
])
def test_bad_tables_are_one_error_naming_file_row_and_column(meas, mapping, data, row,
                                                              column, words):
    data = data or _german_csv(meas.head(3))
    exc = _one_line(pytest.raises(DataError, apply_mapping, data, mapping, name="t.csv"))
    assert exc.file == "t.csv"
    assert exc.row == row and exc.column == column and words in exc.detail
    if "looks like µm" in words:
        assert "unit" in exc.hint


def test_every_problem_of_a_table_is_reported(meas):
    data = b"Name;X-Wert;Y-Wert;Z-Wert\nBP1_P1_B1;a;2;3\nBP1_P1_B2;1;b;3\nNOISE;1;1;1\n"
    exc = pytest.raises(DataError, apply_mapping, data, GERMAN, name="t.csv").value
    assert [(p.row, p.column) for p in exc.problems] == [(2, "X-Wert"), (3, "Y-Wert")]
    assert "(and 1 more problem)" in str(exc)


def test_no_label_matching_is_one_line():
    data = b"F,X,Y,Z\nPLANE,0,0,0\nCIRCLE,1,1,1\n"
    m = TableMapping(x="X", y="Y", z="Z", label="F", pattern=r"(?P<position>BP\d)_(?P<ball>\d+)")
    exc = _one_line(pytest.raises(DataError, apply_mapping, data, m, name="t.csv"))
    assert exc.column == "F" and "'PLANE', 'CIRCLE'" in exc.detail


def test_preview_shows_first_rows_and_problems_without_raising(meas):
    data = _german_csv(meas)
    pv = preview(data, GERMAN, name="export.csv", n=4)
    assert pv.ok and pv.n_rows == len(meas) and len(pv.rows) == 4
    assert pv.rows.columns.tolist()[:7] == ["row", "position", "probe", "ball", *XYZ]
    np.testing.assert_allclose(pv.rows[XYZ].to_numpy(), meas[XYZ].to_numpy()[:4], atol=1e-6)
    bad = data.replace(b";BP111_P1_B2;", b";BP111_P1_B2;").split(b"\n")
    bad[2] = bad[2].replace(b";", b";x", 1)  # row 3: x cell unreadable
    pv = preview(b"\n".join(bad), GERMAN, name="export.csv", n=4)
    assert not pv.ok and len(pv.rows) == 4 and np.isnan(pv.rows["x_mm"][1])
    assert pv.problems[0].startswith("export.csv, row 3, column 'X-Wert'")
    pv = preview(data, {"x": "X-Wert", "y": "Y-Wert", "z": "nope", "label": "Name",
                        "pattern": PATTERN, "decimal": ","}, name="export.csv")
    assert not pv.ok and pv.n_rows == 0 and "'nope' is not in the file" in pv.problems[0]


def test_suggestions_for_vendor_column_names():
    assert suggest_mapping(["Name", "X-Wert", "Y-Wert", "Z-Wert"]) == {
        "x": "X-Wert", "y": "Y-Wert", "z": "Z-Wert", "label": "Name"}
    assert suggest_mapping(["position", "probe", "ball", "x_mm", "y_mm", "z_mm",
                            "time_min", "temp_C"]) == {
        "x": "x_mm", "y": "y_mm", "z": "z_mm", "ball": "ball", "position": "position",
        "probe": "probe", "time": "time_min", "temperature": "temp_C"}
    assert suggest_mapping(["X [mm]", "Y [mm]", "Z [mm]"])["x"] == "X [mm]"


def test_read_foreign_dispatches_by_name(meas, tmp_path):
    path = tmp_path / "run.dmo"
    path.write_bytes(_dmo(meas.head(4)))
    assert len(read_foreign(path, pattern=PATTERN).meas) == 4
    exc = _one_line(pytest.raises(DataError, read_foreign, path))
    assert exc.file == "run.dmo" and "label pattern" in exc.detail
    csv = tmp_path / "v.csv"
    csv.write_bytes(_vendor_feature_csv(meas.head(4)))
    m = {"x": "X", "y": "Y", "z": "Z", "label": "Feature", "pattern": PATTERN}
    assert len(read_foreign(csv, mapping=m).meas) == 4
    assert len(read_foreign(io.BytesIO(csv.read_bytes()), name="v.csv", mapping=m).meas) == 4


def test_the_command_line_says_what_a_mapped_tables_reader_did(tmp_path, capsys):
    """Every note of the reader (separator, decimal comma, unit conversion) reaches the
    user: one stderr line each, and the result's ``notes`` (issue: no silent drops)."""
    f, sim = ROOT / "sample_data" / "foreign", ROOT / "sample_data" / "simulated"
    rc = main(["--json", str(tmp_path / "fit.json"), "fit", str(f / "vendor_export.csv"),
               "--mapping", str(f / "mapping.json"), "--setup", str(sim / "setup.json"),
               "--certificate", str(sim / "certificate.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    notes = json.loads((tmp_path / "fit.json").read_text())["notes"]
    assert rc == 0 and notes and err == [f"note: {n}" for n in notes]
    assert any("converted from um to mm" in n for n in notes)

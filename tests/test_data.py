"""Data I/O, validation messages, thesis table 6.8 and outlier flags."""

import io
import json

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT, THESIS

from cmm_core.dataset import THESIS_POSITIONS, load_dataset
from cmm_core.io import DataError, read_certificate, read_measurements, read_setup
from cmm_core.outliers import detect_outliers


def test_table_6_8_reproduced_to_printed_digits(thesis):
    """Table 6.8 = |mean of tables 6.1-6.6 - certificate| (SPEC 'Known defects'), printed
    to 0.00001 mm = 0.01 µm: agreement within half a printed unit (0.005 µm)."""
    printed = pd.read_csv(ROOT / "tests" / "data_table_6_8.csv")
    tables = np.array([thesis.plate_frame_table(p) for p in THESIS_POSITIONS])
    diff_um = np.abs(tables.mean(0) - thesis.certificate.xyz_mm) * 1e3
    ref_um = printed[["dx_mm", "dy_mm", "dz_mm"]].to_numpy() * 1e3
    assert np.abs(diff_um - ref_um).max() <= 0.005 + 1e-9


def test_table_6_7_is_a_copy_of_6_6_not_the_mean(thesis):
    """The thesis's 'average' table equals table 6.6: the mean differs from it by far more."""
    t66 = thesis.plate_frame_table("BP312")
    mean = np.mean([thesis.plate_frame_table(p) for p in THESIS_POSITIONS], 0)
    assert np.abs(mean - t66).max() * 1e3 > 20


def test_gross_outliers_flagged(thesis):
    rep = detect_outliers(thesis)
    flagged = {(o["position"], o["ball"], o["axis"]) for o in rep.outliers}
    assert ("BP112", 7, "x") in flagged
    assert ("BP312", 16, "x") in flagged
    big = {o["ball"]: o for o in rep.outliers if abs(o["deviation_um"]) > 40}
    assert abs(big[7]["deviation_um"] + 50) < 5  # printed value is 50 µm low
    assert abs(big[16]["deviation_um"] - 100) < 5  # sign slip of -0.05 mm
    assert big[16]["source"] == "BP312.csv" and big[16]["row"] == 17
    # Nothing is dropped: the dataset still holds every row.
    assert len(thesis.meas) == 150


def test_no_false_outliers_on_clean_simulation():
    from cmm_core.simulate import simulate

    sim = simulate({"seed": 4})
    assert detect_outliers(sim.dataset).outliers == []


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, needle", [
    ("ball,x_mm,y_mm\n1,0,0\n", "missing column(s) z_mm"),
    ("ball,x_mm,y_mm,z_mm\n1,0,0,0\n2,abc,0,0\n", "row 3, column 'x_mm': expected a number"),
    ("ball,x_mm,y_mm,z_mm\n1.5,0,0,0\n", "expected a whole ball number"),
    ("ball,x_mm,y_mm,z_mm\n1,0,0,0\n2,0.133,0,0\n3,0.266,0,0\n4,0,0.133,0\n", "look like metres"),
    ("", "file is empty"),
])
def test_measurement_errors_name_file_row_column(tmp_path, text, needle):
    p = _write(tmp_path, "BP9.csv", text)
    with pytest.raises(DataError) as exc:
        read_measurements(p)
    assert "BP9.csv" in str(exc.value) and needle in str(exc.value)


def test_unknown_position_and_duplicate_ball(tmp_path):
    setup = THESIS / "setup.json"
    p = _write(tmp_path, "X1.csv", (THESIS / "BP111.csv").read_text())
    with pytest.raises(DataError, match=r"X1.csv, row 2, column 'position'.*not in the setup"):
        load_dataset([p], setup)
    rows = (THESIS / "BP111.csv").read_text().splitlines()
    p = _write(tmp_path, "BP111.csv", "\n".join(rows + [rows[3]]) + "\n")
    with pytest.raises(DataError, match=r"row 27, column 'ball'.*appears twice"):
        load_dataset([p], setup)


def test_unknown_probe_in_long_form(tmp_path):
    p = _write(tmp_path, "m.csv", "position,probe,ball,x_mm,y_mm,z_mm\n"
               "BP111,9,1,0,0,0\nBP111,9,2,133,0,0\nBP111,9,3,266,0,0\nBP111,9,6,0,133,0\n")
    with pytest.raises(DataError, match=r"m.csv, row 2, column 'probe'.*'9'"):
        load_dataset([p], THESIS / "setup.json")


def test_setup_and_certificate_validation(tmp_path):
    with pytest.raises(DataError, match="origin_mm"):
        read_setup({"positions": {"A": {"u_axis": [1, 0, 0]}}})
    with pytest.raises(DataError, match="parallel"):
        read_setup({"positions": {"A": {"origin_mm": [0, 0, 0], "u_axis": [1, 0, 0],
                                         "v_axis": [2, 0, 0]}}})
    p = _write(tmp_path, "cert.csv", "ball,x_mm,y_mm,z_mm\n1,0,0,0\n1,1,1,1\n")
    with pytest.raises(DataError, match=r"cert.csv, row 3, column 'ball'.*twice"):
        read_certificate(p)


def test_thesis_setup_places_plates_inside_the_machine(thesis):
    for pos in THESIS_POSITIONS:
        m = thesis.meas[thesis.meas.position == pos][["mx_mm", "my_mm", "mz_mm"]].to_numpy()
        assert (m >= -1).all() and (m <= thesis.setup.range_mm + 1).all()
    assert thesis.setup.positions["BP111"].horizontal
    assert not thesis.setup.positions["BP211"].horizontal


def test_certificate_ball_16_x_contradicted_by_all_positions(thesis):
    """Appendix 5 gives ball 16 X = -0.03190 mm; the five consistent tables give about
    -0.052 mm: the certificate value is suspect by about 20 µm."""
    rep = detect_outliers(thesis)
    sus = {(s["ball"], s["axis"]): s["deviation_um"] for s in rep.certificate_suspects}
    assert set(sus) == {(16, "x")}
    assert -25 < sus[(16, "x")] < -15


_GOOD_POS = {"origin_mm": [0, 0, 0], "u_axis": [1, 0, 0], "v_axis": [0, 1, 0]}


@pytest.mark.parametrize("raw, column, needle", [
    ({"positions": 1}, "positions", "expected a JSON object"),
    ({"positions": {"H": [1, 2, 3]}}, "positions.H", "expected an object"),
    ({"positions": {"H": {**_GOOD_POS, "origin_mm": ["a", 0, 0]}}}, "positions.H.origin_mm",
     "3 numbers"),
    ({"positions": {"H": {**_GOOD_POS, "u_axis": [0, 0, 0]}}}, "positions.H.u_axis", "zero"),
    ({"positions": {"H": {**_GOOD_POS, "temp_C": "warm"}}}, "positions.H.temp_C", "numbers"),
    ({"positions": {"H": _GOOD_POS}, "probes": {"1": "long"}}, "probes.1", "3 numbers"),
    ({"positions": {"H": _GOOD_POS}, "probes": [0, 0, -150]}, "probes", "JSON object"),
    ({"positions": {"H": _GOOD_POS}, "machine": {"range_mm": [1200, 1000]}},
     "machine.range_mm", "three positive"),
    ({"positions": {"H": _GOOD_POS}, "plate": {"cte_per_K": "steel"}}, "plate.cte_per_K",
     "must be a number"),
])
def test_malformed_setup_names_the_field_and_what_was_expected(raw, column, needle):
    """Every structural mistake in a setup JSON is a DataError naming the field (found by
    the browser review: a non-object `positions` used to raise AttributeError)."""
    with pytest.raises(DataError, match=needle) as exc:
        read_setup(io.BytesIO(json.dumps(raw).encode()), name="setup.json")
    assert exc.value.column == column and exc.value.file == "setup.json"

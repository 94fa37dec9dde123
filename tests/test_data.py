"""Data I/O, validation messages, thesis table 6.8 and outlier flags."""

import io
import json

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT, THESIS
from conftest import uploader as _uploader

from cmm_core.diagnosis import detect_outliers
from cmm_core.io import (
    THESIS_POSITIONS,
    DataError,
    load_dataset,
    read_certificate,
    read_measurements,
    read_setup,
)


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
    from cmm_core.model import simulate

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


# ---------------------------------------------------------------------------------------
# Browser review of uploads: defects 1-5
# ---------------------------------------------------------------------------------------

_HEADER = "ball,x_mm,y_mm,z_mm\n"
_PLATE = "1,0,0,0\n2,133,0,0\n3,266,0,0\n4,0,133,0\n"


def _err(reader, text, name="BP9.csv"):
    with pytest.raises(DataError) as exc:
        reader(io.BytesIO(text.encode()), name=name)
    return exc.value


def test_header_only_files_and_short_certificates_are_rejected():
    """Defect 1: a header-only measurement CSV loaded as a 0-point dataset that the Data
    page called valid; a header-only certificate, or one with fewer than 3 balls (or all on
    one line), cannot define a plate frame."""
    for head in (_HEADER, "position,probe,ball,x_mm,y_mm,z_mm\n", _HEADER + "\n,,,\n"):
        err = _err(read_measurements, head)
        assert "BP9.csv" in str(err) and "has no data rows" in str(err)
    assert "has no data rows" in str(_err(read_certificate, _HEADER, "cert.csv"))
    err = _err(read_certificate, _HEADER + "1,0,0,0\n2,133,0,0\n", "cert.csv")
    assert "has 2 balls; expected at least 3" in str(err) and "non-collinear" in str(err)
    err = _err(read_certificate, _HEADER + "1,0,0,0\n2,133,0,0\n3,266,0,0\n", "cert.csv")
    assert "on one line" in str(err)
    assert len(read_certificate(io.BytesIO((_HEADER + _PLATE).encode())).balls) == 4


def test_every_cell_problem_of_a_file_is_reported_with_row_and_column():
    """Defect 2: only the first problem per file was reported. All cell-level problems
    (non-numbers, blanks, non-finite values, duplicate balls, µm/metres) are listed with row
    and column, and str(exc) stays one line: the first problem plus '(and N more ...)'."""
    text = _HEADER + "1,0,0,0\n2,abc,0,\n2,133,inf,0\n4,0,133,2e6\n"
    err = _err(read_measurements, text)
    got = [(p.row, p.column) for p in err.problems]
    assert got == [(3, "x_mm"), (3, "z_mm"), (4, "ball"), (4, "y_mm"), (5, "z_mm")]
    assert all(p.file == "BP9.csv" for p in err.problems) and err.n_problems == 5
    assert "\n" not in str(err) and str(err).endswith("(and 4 more problems)")
    assert str(err).startswith("BP9.csv, row 3, column 'x_mm': expected a number")
    metres = _err(read_measurements, _HEADER + "1,0,0,0\n2,0.133,0,0\n3,0.266,0,x\n"
                  "4,0,0.133,0\n5,0,0.266,0\n")
    assert [p.column for p in metres.problems] == ["x_mm", "z_mm"]
    assert "look like metres" in metres.problems[0].detail
    # A file wrong throughout: the list is capped, the count is not.
    many = _err(read_measurements, _HEADER + "".join(f"{i},x,0,0\n" for i in range(1, 81)))
    assert many.n_problems == 80 and len(many.problems) == 50
    assert [p.row for p in many.problems] == list(range(2, 52))
    assert "(and 79 more problems)" in str(many)
    cert = _err(read_certificate, _HEADER + _PLATE + "2,1,1,1\n3,,0,0\n", "cert.csv")
    assert [(p.row, p.column) for p in cert.problems] == [(6, "ball"), (7, "ball"),
                                                          (7, "x_mm")]
    assert "also in row 3" in cert.problems[0].detail


def test_setup_problems_of_all_files_are_reported_together(tmp_path):
    """Defect 2 (across files): an unknown position is one problem per file, not one per
    row, and the other files' problems are listed as well."""
    rows = (THESIS / "BP111.csv").read_text()
    files = [_write(tmp_path, "X1.csv", rows), _write(tmp_path, "X2.csv", rows)]
    with pytest.raises(DataError) as exc:
        load_dataset(files, THESIS / "setup.json")
    assert [(p.file, p.row, p.column) for p in exc.value.problems] == [
        ("X1.csv", 2, "position"), ("X2.csv", 2, "position")]
    assert "(and 1 more problem)" in str(exc.value)


@pytest.mark.parametrize("text, row, column, needle, forbidden", [
    (_HEADER + "1,0,0,0\n2,,0,0\n", 3, "x_mm", "found an empty cell", "nan"),
    (_HEADER + "1,0,0,0\n2,inf,0,0\n", 3, "x_mm", "'inf', which is not a finite number",
     "µm"),
    (_HEADER + "1,0,0,0\n2,0,-inf,0\n", 3, "y_mm", "not a finite number", "µm"),
    (_HEADER + "1,0,0,0\n2,0,0,nan\n", 3, "z_mm", "'nan', which is not a finite number",
     "µm"),
    (_HEADER + "1,0,0,0\n2,133,5,0,0\n", 3, None, "expected 4 fields", "Error tokenizing"),
    ("ball x_mm y_mm z_mm\n1 0 0 0\n", 1, None, "found a single column", "missing column"),
])
def test_messages_say_what_is_wrong(text, row, column, needle, forbidden):
    """Defect 3: a blank cell read 'found nan'; inf/nan were 'looks like µm'; a decimal
    comma gave the raw pandas tokenizer error without a row; a file with another separator
    reported missing columns."""
    err = _err(read_measurements, text)
    assert (err.row, err.column) == (row, column)
    assert needle in str(err) and forbidden not in str(err)


def test_decimal_comma_rows_and_semicolon_files():
    """Defect 3: every row split by a decimal comma is named, with a hint; files separated
    by semicolons (decimal commas) or tabs are read, and say which separator was used."""
    err = _err(read_measurements, _HEADER + "1,0,0,0\n2,133,5,0,0\n3,266,0,0\n4,0,1,5,0\n")
    assert [p.row for p in err.problems] == [3, 5] and "decimal comma" in err.hint
    semi = "ball;x_mm;y_mm;z_mm\n1;0;0;0\n2;133,25;0;0\n3;266;0;-1,5e-3\n4;0;133;0\n"
    df = read_measurements(io.BytesIO(semi.encode()), name="BP9.csv")
    assert df.attrs == {"delimiter": ";", "decimal_comma": True}
    assert df["x_mm"].tolist() == [0, 133.25, 266, 0] and df["z_mm"][2] == -1.5e-3
    tab = read_measurements(io.BytesIO(_PLATE.join([_HEADER, ""]).replace(",", "\t")
                                       .encode()), name="BP9.csv")
    assert tab.attrs["delimiter"] == "\t" and len(tab) == 4
    # Blank lines keep their place in the row numbering (a spreadsheet shows them).
    err = _err(read_measurements, "\n" + _HEADER + "1,0,0,0\n\n2,x,0,0\n")
    assert err.row == 5


def _upload_app():
    """The app on the Data page, with a 'Load uploaded files' helper."""
    from streamlit.testing.v1 import AppTest

    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.run()
    return at


def _sfx(at) -> str:
    """The key suffix of the current upload fields: each load, accepted or refused, gives
    the next upload empty fields under new keys."""
    gen = at.session_state["upload_gen"] if "upload_gen" in at.session_state else 0
    return "" if gen == 0 else f"_{gen}"


def _upload(at, files):
    _uploader(at, "Measurement CSV").set_value(
        [(n, t.encode(), "text/csv") for n, t in files])
    at.button(key="load_upload").click()
    at.run()
    assert not at.exception


def _problem_table(at):
    tables = [d.value for d in at.dataframe if "hint" in d.value.columns]
    return tables[0] if tables else None


def test_upload_report_lists_every_problem_and_stays_until_the_next_load():
    """Defects 2 and 4: the Data page's problem table lists every problem of every file
    (with row and column), and it no longer disappears at the next interaction: it stays
    until the next load attempt, and a successful load removes it."""
    pytest.importorskip("streamlit")
    at = _upload_app()
    bad = _HEADER + "1,0,0,0\n2,abc,0,\n3,266,inf,0\n4,0,133,0\n"
    _upload(at, [("BP111.csv", bad), ("BP112.csv", _HEADER)])
    table = _problem_table(at)
    assert table is not None
    assert list(zip(table["file"], table["column"], strict=True)) == [
        ("BP111.csv", "x_mm"), ("BP111.csv", "z_mm"), ("BP111.csv", "y_mm"), ("BP112.csv", "")]
    assert table["row"].iloc[:3].tolist() == [3, 3, 4] and pd.isna(table["row"].iloc[3])
    assert table["problem"].iloc[-1].startswith("has no data rows")
    assert any("4 problem(s)" in e.value for e in at.error)
    at.checkbox(key="use_thesis_setup").uncheck().run()  # any other interaction
    assert _problem_table(at) is not None and len(_problem_table(at)) == 4
    good = (THESIS / "BP111.csv").read_text()
    _upload(at, [("BP111.csv", good)])
    assert _problem_table(at) is not None  # no setup now: a new report replaces the old
    assert list(_problem_table(at)["problem"]) == ["no setup given."]
    at.checkbox(key="use_thesis_setup").check().run()
    _upload(at, [("BP111.csv", good)])
    assert _problem_table(at) is None and not at.error


def test_outlier_labels_say_robust_score_not_z():
    """Defect 5: outlier labels read 'x +98.8 µm (z +126.1)', where z (a robust z-score)
    is easily taken for the z axis."""
    pytest.importorskip("streamlit")
    at = _upload_app()
    labels = [c.label for c in at.checkbox if c.label.startswith("Exclude ")]
    assert labels and all("robust score" in lab and "(z " not in lab for lab in labels)


@pytest.mark.parametrize("path, typo, meant", [
    ((), "frme", "frame"),
    (("plate",), "cte_per_k", "cte_per_K"),
    (("positions", "BP211"), "v_axs", "v_axis"),
    (("machine",), "range_MM", "range_mm"),
])
def test_a_misspelt_setup_key_is_refused_with_the_key_it_resembles(path, typo, meant):
    """Acceptance finding: 'v_axs' and 'cte_per_k' loaded silently with the defaults."""
    raw = json.loads((THESIS / "setup.json").read_text())
    obj = raw
    for k in path:
        obj = obj[k]
    obj[typo] = obj.pop(meant, 1)
    with pytest.raises(DataError) as exc:
        read_setup(raw)
    assert f"did you mean {meant!r}" in str(exc.value) and exc.value.column.endswith(typo)


def test_free_notes_in_a_setup_are_kept_and_a_misspelt_column_is_refused():
    raw = json.loads((THESIS / "setup.json").read_text())
    raw["operator"] = "J. Smith"
    raw["plate"]["serial"] = "BP-123"
    assert read_setup(raw).positions  # descriptive keys are free
    text = "position,probe,ball,x_mm,y_mm,z_mm,tempC\nBP111,1,1,0,0,0,20.1\n"
    with pytest.raises(DataError) as exc:
        read_measurements(io.BytesIO(text.encode()), name="m.csv")
    assert "did you mean 'temp_C'" in str(exc.value) and exc.value.column == "tempC"


def test_the_data_page_takes_a_certificate_statement_for_a_certificate_without_u():
    """Issue 24: a certificate without u columns and a setup that states nothing are
    refused; the statement entered on the Data page (U(k) = a ⊕ b·L, or exact) goes into
    the setup's certificate section and is what the dataset uses, source named. Reference:
    thesis appendix 1, U(k=2) = sqrt(0.26² + (1.9e-3 L)²) µm, L from ball 1."""
    raw = json.loads((THESIS / "setup.json").read_text())
    del raw["certificate"]
    setup = ("setup.json", json.dumps(raw).encode(), "application/json")
    cert = ("certificate.csv", (THESIS / "certificate.csv").read_bytes(), "text/csv")
    meas = [(p + ".csv", (THESIS / f"{p}.csv").read_bytes(), "text/csv")
            for p in THESIS_POSITIONS]
    at = _upload_app()
    at.switch_page("pages/data.py")
    at.run()

    def load(choice, a=0.0, b=0.0):
        """Upload the three kinds of file (widget keys of the current upload generation)."""
        sfx = _sfx(at)
        _uploader(at, "Measurement CSV").set_value(meas)
        _uploader(at, "Setup").set_value(setup)
        _uploader(at, "Certificate").set_value(cert)
        radio = at.radio(key=f"up_cert_u{sfx}")
        radio.set_value(radio.options[choice]).run()
        if choice == 1:
            at.number_input(key=f"up_cert_a{sfx}").set_value(a)
            at.number_input(key=f"up_cert_b{sfx}").set_value(b).run()
        at.button(key="load_upload").click()
        at.run()
        assert not at.exception

    load(0)  # as the file or setup states it: neither does
    assert "gives no uncertainty" in " ".join(_problem_table(at)["problem"])
    load(2)  # exact (the refusal above emptied the fields: new keys)
    assert _problem_table(at) is None and not at.error
    assert json.loads(at.session_state["sources"].setup.text())["certificate"]["exact"] is True
    load(1, 0.26, 0.0019)  # the fields of the next upload generation
    assert _problem_table(at) is None and not at.error
    from cmm_core import analysis as A

    ds = A.load_sources(at.session_state["sources"])
    c = ds.certificate
    L = np.linalg.norm(c.xyz_mm - c.xyz_mm[0], axis=1)
    np.testing.assert_allclose(c.u_um[:, 0], np.hypot(0.26, 1.9e-3 * L) / 2, rtol=1e-12)
    assert "entered on the Data page" in c.u_source


@pytest.mark.parametrize("part, value", [("measurements", 5), ("history", 5),
                                         ("extra", [1])])
def test_a_project_file_of_the_wrong_shape_restores_nothing_and_says_why(part, value):
    """Issue 25: the Data page restores a project through the core's reader: a wrong type
    in dataset.measurements, history or extra is the core's one line naming the key (no
    Python error text), and the session keeps its data."""
    from cmm_core import analysis as A
    from cmm_core.io import thesis_dataset

    rec = A.read_record(ROOT / "sample_data" / "thesis" / "analysis.json")
    doc = json.loads(A.record_to_project_json(rec))
    (doc["dataset"] if part == "measurements" else doc)[part] = value
    at = _upload_app()
    at.switch_page("pages/data.py")
    at.run()
    _uploader(at, "Project file").set_value(
        ("p.json", json.dumps(doc).encode(), "application/json"))
    at.run()
    at.button(key="restore_project").click()
    at.run()
    assert not at.exception
    (err,) = [e.value for e in at.error]
    where = "dataset.measurements" if part == "measurements" else part
    assert f"p.json, column '{where}'" in err or f"p.json, column {where}" in err, err
    assert not any(e in err for e in ("TypeError", "AttributeError", "KeyError"))
    assert "\n" not in err
    assert len(at.session_state["sources"].measurements) == len(
        thesis_dataset().positions)  # the thesis data still loaded


def test_the_upload_tab_keeps_what_the_user_chose_while_another_tab_is_open():
    """The upload tab is drawn only while open or while its fields hold the user's choices
    (issue 27): a certificate statement entered and the thesis setup switched off, then
    the Thesis sample tab looked at, are still there on return, where Streamlit would
    have forgotten the widgets of a tab not drawn. A session that chose nothing does not
    draw the tab."""
    from conftest import open_data_tab

    at = _upload_app()
    assert not [r for r in at.radio if r.key == "up_cert_u"]  # not drawn on the first screen
    open_data_tab(at, "Upload CSVs")
    at.radio(key="up_cert_u").set_value("U(k) = a ⊕ b·L, entered here").run()
    at.number_input(key="up_cert_a").set_value(0.3).run()
    at.checkbox(key="use_thesis_setup").uncheck().run()
    open_data_tab(at, "Thesis sample")
    open_data_tab(at, "Upload CSVs")
    assert not at.exception
    assert at.radio(key="up_cert_u").value == "U(k) = a ⊕ b·L, entered here"
    assert at.number_input(key="up_cert_a").value == pytest.approx(0.3)
    assert at.checkbox(key="use_thesis_setup").value is False

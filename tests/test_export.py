"""Exports: spreadsheet safety, the error-map grid, compensation, project files, report."""

import io
import json

import numpy as np
import pandas as pd
import pytest

from cmm_core import analysis as report
from cmm_core import export
from cmm_core.io import THESIS_DIR, THESIS_POSITIONS, DataError, thesis_dataset
from cmm_core.model import fit


@pytest.fixture(scope="module")
def result():
    return fit(thesis_dataset())


@pytest.mark.parametrize("cell", ["=1+2", "+cmd", "-x", "@SUM(A1)", "\tfoo", "\rbar",
                                  "=HYPERLINK(\"http://x\")", "-", "+"])
def test_dangerous_text_cells_get_an_apostrophe(cell):
    text = export.safe_csv(pd.DataFrame({"name": [cell], "v": [1.5]}))
    got = pd.read_csv(io.StringIO(text), keep_default_na=False)["name"][0]
    assert got.startswith("'")
    assert got[1:].strip("\r\t") == cell.strip("\r\t")


@pytest.mark.parametrize("cell", ["-1.5", "+2", "-3e-4", "BP111", "ball 7", "1"])
def test_plain_numbers_and_text_are_untouched(cell):
    assert export.neutralise(cell) == cell


def test_numeric_columns_stay_numbers():
    text = export.safe_csv(pd.DataFrame({"x_mm": [-1.25, 2.0], "probe": ["=1", "2"]}))
    df = pd.read_csv(io.StringIO(text))
    assert df["x_mm"].tolist() == [-1.25, 2.0]
    assert df["probe"].tolist() == ["'=1", "2"]


def test_column_names_are_neutralised_too():
    text = export.safe_csv(pd.DataFrame({"=evil": [1]}))
    assert text.splitlines()[0] == "'=evil"


def test_parameters_and_residuals_csv(result):
    p = pd.read_csv(io.StringIO(export.parameters_csv(result)), comment="#")
    assert {"parameter", "block", "unit", "value", "u_standard", "identifiable"} <= set(p)
    assert len(p) == len(result.labels)
    r = pd.read_csv(io.StringIO(export.residuals_csv(result)), comment="#")
    assert len(r) == result.n_obs
    assert np.allclose(r[["rx_um", "ry_um", "rz_um"]].to_numpy(), result.residuals_um,
                       atol=1e-4)


def test_error_map_grid_matches_the_model(result):
    from cmm_core.model import error_at

    g = export.error_map_grid(result, step_mm=(300, 250, 350))
    assert list(g.columns) == ["x_mm", "y_mm", "z_mm", "ex_um", "ey_um", "ez_um",
                               "u_ex_um", "u_ey_um", "u_ez_um", "extrapolated"]
    assert len(g) == 5 * 5 * 3  # 0..1200/300, 0..1000/250, 0..700/350
    assert g["x_mm"].iloc[1] == 300.0 and g["y_mm"].iloc[0] == 0.0  # x fastest
    e, u = error_at(result, g[["x_mm", "y_mm", "z_mm"]].to_numpy())
    assert np.allclose(g[["ex_um", "ey_um", "ez_um"]].to_numpy(), e)
    assert np.allclose(g[["u_ex_um", "u_ey_um", "u_ez_um"]].to_numpy(), u)
    text = export.error_map_csv(result, g)
    assert text.startswith("# CMM error map")
    back = pd.read_csv(io.StringIO(text), comment="#")
    assert np.allclose(back["ez_um"], g["ez_um"], atol=1e-5)
    with pytest.raises(ValueError):
        export.error_map_grid(result, step_mm=0.1)
    assert "backlash" not in text


def test_error_map_header_says_a_fitted_backlash_is_not_in_the_table():
    from cmm_core.model import simulate

    sim = simulate({"seed": 4, "order": "serpentine",
                    "effects": {"backlash": {"x_um": 2.0, "y_um": 1.0}}})
    r = fit(sim.dataset, "kinematic21,backlash")
    text = export.error_map_csv(r, export.error_map_grid(r, step_mm=400))
    line = next(x for x in text.splitlines() if x.startswith("# NOT in this table: backlash"))
    x_span, u_span = (float(v) for v in line.split("x ")[1].split(";")[0].split(" +- "))
    assert abs(x_span - 2.0) < 3 * u_span  # the fitted span, with its uncertainty


def test_error_map_header_says_a_fitted_scale_expansion_is_not_in_the_table():
    """The grid is for the scales at 20 °C: a fitted machine_thermal expansion is named
    in the header with its value and uncertainty (simulated 1 ppm/K on x)."""
    from cmm_core.model import simulate

    sim = simulate({"seed": 3, "effects": {"machine_thermal": {
        "x_cte_per_K": 1e-6, "temp_C": {"BP111": [20, 23], "BP211": [21, 24],
                                         "BP311": [19, 22]}}}})
    r = fit(sim.dataset, "kinematic21,machine_thermal")
    text = export.error_map_csv(r, export.error_map_grid(r, step_mm=400))
    line = next(x for x in text.splitlines()
                if x.startswith("# NOT in this table: machine_thermal"))
    cte, u = (float(v) for v in line.split("cte_x ")[1].split(" ppm/K")[0].split(" +- "))
    assert abs(cte - 1.0) < 3 * u


def test_compensation_adds_the_error(result):
    from cmm_core.model import error_at

    obs = result.problem.obs
    pts = pd.DataFrame({"probe": ["1", "3"], "x_mm": [500.0, 700.0], "y_mm": [400.0, 300.0],
                        "z_mm": [100.0, 200.0], "label": ["=a", "b"]})
    out = export.compensate_points(result, pts)
    assert {"xc_mm", "yc_mm", "zc_mm", "u_x_um", "u_y_um", "u_z_um"} <= set(out.columns)
    p1 = obs.p_mm[obs.probe == obs.probes.index("1")][0]
    e, _ = error_at(result, np.array([[500.0, 400.0, 100.0]]) - p1, "1")
    assert np.allclose(out.loc[0, ["xc_mm", "yc_mm", "zc_mm"]].to_numpy(float),
                       np.array([500.0, 400.0, 100.0]) + e[0] * 1e-3, atol=1e-9)


def test_read_points_reports_row_and_column():
    with pytest.raises(DataError) as exc:
        export.read_points(b"probe,x_mm,y_mm,z_mm\n1,1,2,3\n1,abc,2,3\n", name="pts.csv")
    assert exc.value.row == 3 and exc.value.column == "x_mm"
    with pytest.raises(DataError):
        export.read_points(b"a,b\n1,2\n", name="pts.csv")


def test_unknown_probe_is_reported_at_its_file_row_past_blank_lines(result):
    """Header row 1, a point on row 2, two blank lines, the bad probe on row 5."""
    pts = export.read_points(b"probe,x_mm,y_mm,z_mm\n1,400,300,100\n\n\n9,400,300,100\n",
                             name="pts.csv")
    with pytest.raises(DataError) as exc:
        export.compensate_points(result, pts)
    assert exc.value.row == 5 and exc.value.column == "probe" and "'9'" in str(exc.value)


def _thesis_project(**kw):
    args = dict(dataset_name="thesis",
                measurements=[(f"{p}.csv", (THESIS_DIR / f"{p}.csv").read_text())
                              for p in THESIS_POSITIONS],
                setup=(THESIS_DIR / "setup.json").read_text(),
                certificate=("certificate.csv", (THESIS_DIR / "certificate.csv").read_text()),
                model={"spec": "kinematic21,plate_sag", "order": 3, "plate": "prior",
                       "sigma_um": 0.7, "positions": None, "probes": ["1", "2"]},
                exclusions=[("BP112", "2", 7)],
                history=[{"spec": "kinematic21", "change": "baseline", "rms_um": float("nan")}])
    args.update(kw)
    return export.project_to_json(**args)


def test_project_roundtrip_restores_everything():
    doc = export.project_from_json(_thesis_project())
    assert doc["dataset_name"] == "thesis"
    assert [n for n, _ in doc["measurements"]] == [f"{p}.csv" for p in THESIS_POSITIONS]
    assert doc["measurements"][0][1] == (THESIS_DIR / "BP111.csv").read_text()
    assert doc["certificate"][0] == "certificate.csv"
    assert doc["model"]["spec"] == "kinematic21,plate_sag" and doc["model"]["order"] == 3
    assert doc["exclusions"] == [("BP112", "2", 7)]
    assert doc["history"][0]["rms_um"] is None  # NaN is not JSON
    # the restored files load into the same dataset
    from cmm_core.io import load_dataset

    ds = load_dataset([(io.StringIO(c), n) for n, c in doc["measurements"]],
                      io.StringIO(doc["setup"]), (io.StringIO(doc["certificate"][1]),
                                                  doc["certificate"][0]))
    assert len(ds.meas) == len(thesis_dataset().meas)


@pytest.mark.parametrize("text, needle", [
    (b"{nope", "not valid JSON"),
    (b"[1, 2]", "not a CMM error lab project"),
    (b'{"format": "cmm-error-lab-project", "version": 99}', "newer version"),
    (b'{"format": "cmm-error-lab-project", "version": 1}', "no dataset"),
    (b"\xff\xfe", "UTF-8"),
])
def test_bad_project_files_are_data_errors(text, needle):
    with pytest.raises(DataError, match=needle):
        export.project_from_json(text)


def test_report_is_self_contained(result):
    ds = thesis_dataset()
    html = report.build_report(ds, result, exclusions=[("BP112", "2", 7)],
                               history=[{"spec": "kinematic21", "change": "baseline",
                                         "rms_um": 5.2, "chi2_dof": 127.0, "bic": 1.0,
                                         "gp_amplitude_um": None}])
    assert html.startswith("<!DOCTYPE html>")
    assert "<script src=" not in html.replace(" ", "")  # every script is inline
    assert html.count("plotly.js v") >= 1  # the library itself is inline
    assert html.count("Plotly.newPlot") >= 5
    for text in ("Fitted error functions", "Deviations, BP111", "Residuals",
                 "Fitted parameters", "BP112/2 ball 7", "kinematic21", "µm"):
        assert text in html
    assert "<td>None</td>" not in html  # a value never computed is a dash
    assert "<td>um</td>" not in html and "µm" in html  # units as on screen


def test_report_carries_the_mpe_check_and_the_diagnosis_verdict(result):
    """Acceptance finding: a report to file needs the conformity result and the verdict
    in words, not only a table of 43 candidates."""
    from cmm_core.gum import check_dataset

    ds = thesis_dataset()
    check, skipped = check_dataset(ds, sigma_um=0.5)
    assert check is not None and not skipped
    diag = pd.DataFrame([{"effect": f"e{i}", "title": "t", "explanation": "long text",
                          "delta_bic": float(i)} for i in range(43)])
    html = report.build_report(ds, result, diagnosis=diag, mpe=check,
                               diagnosis_conclusion="Most likely missing: plate sag.")
    assert "MPE check" in html and "Most likely missing: plate sag." in html
    assert "The 10 best of 43 candidates" in html and "long text" not in html
    assert "Certificate" in html


@pytest.mark.parametrize("field, value, needle", [
    ("order", "two", "whole number 1-5"),
    ("order", 99, "whole number 1-5"),
    ("spec", "kinematic21,wobble", "unknown model token"),
    ("plate", "wobbly", "one of auto, fixed"),
    ("sigma_um", "x", "positive repeatability"),
    ("sigma_um", -1, "positive repeatability"),
    ("positions", "BP111", "list of names"),
])
def test_bad_model_fields_in_a_project_are_named(field, value, needle):
    """Found by the browser review: a project with "order": "two" broke every page of the
    restored session. Each model field is checked where the file is read."""
    model = {"spec": "kinematic21", "order": 2, "plate": "auto", "sigma_um": 0.5,
             "positions": None, "probes": None, field: value}
    with pytest.raises(DataError, match=needle) as exc:
        export.project_from_json(_thesis_project(model=model))
    assert exc.value.column == f"model.{field}"


def test_project_version_must_be_a_number():
    doc = json.loads(_thesis_project())
    doc["version"] = "2"
    with pytest.raises(DataError, match="version must be a number"):
        export.project_from_json(json.dumps(doc))


def test_error_map_grid_refuses_a_grid_too_fine_to_compute_quickly(result):
    """Found by the browser review: a 10 mm step (867 691 nodes) blocked the page for
    28 s. The limit names the node count and a step that fits."""
    with pytest.raises(ValueError, match=r"867,691 nodes.*step of about \d+ mm"):
        export.error_map_grid(result, step_mm=10.0)
    assert len(export.error_map_grid(result, step_mm=50.0)) <= export.MAX_GRID_NODES


@pytest.mark.parametrize("spec", ["kinematic21", "kinematic21,dyz:3,periodic_x:180"])
def test_true_function_curve_reads_the_coefficient_labels(spec):
    """Fed the fit's own coefficients as 'truth', the dashed true curves coincide with the
    fitted ones (same basis reached from the labels), including straightness (no linear
    term), squareness (a constant angle) and a periodic term."""
    from cmm_core.model import simulate

    sim = simulate({"seed": 5, "kinematic": {"spec": spec}})
    r = fit(sim.dataset, spec)
    truth = dict(zip(r.terms.labels, r.kinematic_coef, strict=True))
    for name in ("dxx", "dyz", "sxy", "rzz"):
        u, val, _ = report.error_function_curves(r, name)
        np.testing.assert_allclose(report.true_function_curve(truth, name, u,
                                                              r.terms.range_mm), val,
                                   atol=1e-12)
    assert report.true_function_curve(truth, "nonexistent", u, r.terms.range_mm) is None
    fig = report.fig_error_functions(r, truth=sim.truth)
    assert any(t.name == "true (simulation)" for t in fig.data)


def test_error_functions_shade_the_measured_span_and_history_survives_empty_columns(result):
    """Review findings: the shading was added before the traces, which plotly skips; an
    all-empty first history column made an invalid axis reference."""
    fig = report.fig_error_functions(result)
    assert len(fig.layout.shapes) == len(result.terms.functions)
    x0 = min(s.x0 for s in fig.layout.shapes if s.xref == "x")
    assert x0 > 0  # dxx: the balls start well inside the X stroke
    hist = [{"change": "baseline", "rms_um": None, "chi2_dof": None, "bic": None,
             "gp_amplitude_um": None}]
    assert "not computed" in [a.text for a in report.fig_history(hist).layout.annotations]


def test_a_project_naming_a_position_its_data_lack_is_refused():
    """Issue 13: such a project restored to "No fit for these settings" with no reason."""
    model = {"spec": "kinematic21", "order": 2, "plate": "auto", "sigma_um": 0.5,
             "positions": ["BP111", "BP999"], "probes": None}
    with pytest.raises(DataError, match="'BP999', which the project's data do not have") \
            as exc:
        export.project_from_json(_thesis_project(model=model))
    assert exc.value.column == "model.positions" and exc.value.file == "project.json"
    # a byte-order mark is read as in CSV files
    doc = export.project_from_json(b"\xef\xbb\xbf" + _thesis_project().encode())
    assert doc["dataset_name"] == "thesis"


def test_error_map_is_the_compensation_grid(result):
    """One grid: the error map is comp_tables.compensation_grid for the fit's first probe
    (same nodes, each axis ending at its stroke even when the step does not divide it;
    same numbers; the region test of compensate), under its own column names. Before,
    its x axis stopped at 1050 of 1200 mm for a 350 mm step and it had no
    extrapolation flag."""
    from cmm_core.export import comp_tables as ct
    from cmm_core.export import model_from_result
    from cmm_core.export.correction import extrapolation_note

    g = export.error_map_grid(result, step_mm=350.0)
    c = ct.compensation_grid(result, 350.0, probe=result.problem.obs.probes[0],
                             allow_undetermined=True)
    assert sorted(set(g["x_mm"])) == [0.0, 350.0, 700.0, 1050.0, 1200.0]
    for a in "xyz":
        assert g[f"{a}_mm"].equals(c[f"{a}_mm"])
        assert g[f"e{a}_um"].equals(c[f"c{a}_um"]) and g[f"u_e{a}_um"].equals(c[f"u_c{a}_um"])
    x = g[["x_mm", "y_mm", "z_mm"]].to_numpy()
    flag = (extrapolation_note(model_from_result(result), x) != "").astype(int)
    assert (g["extrapolated"].to_numpy() == flag).all() and 0 < flag.sum() < len(g)
    text = export.error_map_csv(result, g)
    assert "# extrapolated: 1 where the node lies outside" in text
    box = export.error_map_grid(result, step_mm=100.0, lower_mm=(200, 200, 100),
                                upper_mm=(450, 400, 100))
    assert sorted(set(box["x_mm"])) == [200.0, 300.0, 400.0, 450.0]
    assert set(box["z_mm"]) == {100.0}

"""Compensation tables (3-D grid, per-axis), results JSON / QIF-like XML and the export CLI.

The per-axis tables are checked against the grid through an implementation of eq.
(L1)-(L2) of docs/layouts.md written here with scipy's rotations (no code shared with
``cmm_core.machine.kinematics``), on every distinct kinematic chain.
"""

import argparse
import hashlib
import io
import json
import math
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from cmm_core.cli import export as export_cli
from cmm_core.export import Model, compensate, load_model, model_from_result, save_model
from cmm_core.export import comp_tables as ct
from cmm_core.export import results as rx
from cmm_core.io import DataError
from cmm_core.machine import ERROR_NAMES, KinematicTerms

ROOT = Path(__file__).resolve().parents[1]
CHAINS = {"moving_bridge_fxyz": "Fxyz", "moving_bridge_fyxz": "Fyxz",
          "fixed_bridge_xfyz": "xFyz", "fixed_bridge_yfxz": "yFxz",
          "horizontal_arm_fxzy": "Fxzy", "horizontal_arm_fyzx": "Fyzx"}
# Round-off of the CSV files: 6 decimals, so each value is within 5e-7 µm or µrad; a
# correction sums at most 9 translations and 9 rotations on levers below 2 m
# (5e-7 µrad × 2000 mm = 1e-6 µm): 2e-5 µm bounds the composed round-off.
CSV_TOL_UM = 2e-5
# In memory both sides are float64 sums of the same ~30 terms of up to ~1e3 µm in mm
# (1e-16 relative): 1e-9 µm is round-off with a wide margin, far below any error term.
FLOAT_TOL_UM = 1e-9


@pytest.fixture(scope="module")
def thesis_fit(request):
    from cmm_core.io import thesis_dataset
    from cmm_core.model import fit

    return fit(thesis_dataset())


def _random_model(layout, seed=20261124):
    """A model with every function at order 3 and a periodic x scale error, coefficients
    of a few µm / µrad (a poor machine: corrections of tens of µm), a random covariance."""
    rng = np.random.default_rng(seed)
    terms = KinematicTerms(tuple((n, 3) for n in ERROR_NAMES), (1000.0, 800.0, 600.0),
                               (("dxx", 180.0),), layout)
    coef = rng.normal(0.0, 4.0, terms.n)
    a = rng.normal(0.0, 0.1, (terms.n, terms.n))
    return Model("kinematic21", terms, coef, a @ a.T, {"1": np.array([20.0, -10.0, -150.0])},
                 False, {"sigma_um": 0.5, "rms_um": 0.51, "chi2_dof": 1.04, "n_obs": 300,
                         "fails_chi2_test": False, "birge_ratio": 1.02, "plate": "fixed",
                         "region_mm": [[100.0, 100.0, 50.0], [900.0, 700.0, 500.0]]},
                 name="random.json")


def _read(text):
    return pd.read_csv(io.StringIO(text), comment="#")


def _compose(tables, chain, x_mm, table_sign=-1.0):
    """Correction (µm) at scale readings ``x_mm`` with the probe at the origin from the
    per-axis tables, by (L1)-(L2) of docs/layouts.md: tool carriages
    ``P = a e_a + d_a + s_a + R_a P`` from the probe outwards, then the table carriages
    ``X = R_b^T (X + b e_b + s_b - d_b)``; ``R = Rz Ry Rx``. ``table_sign`` is the sign of
    a table's translations there (-1; +1 only to show the test tells them apart)."""
    f = chain.index("F")
    table, tool = chain[:f][::-1], chain[f + 1:]
    sq = tables["squareness"].set_index("name")["value_urad"]
    out = np.empty((len(x_mm), 3))
    for i, x in enumerate(x_mm):
        d, R, s = {}, {}, {}
        for k, a in enumerate("xyz"):
            t = tables[a]
            row = t.iloc[int(np.argmin(np.abs(t[f"{a}_mm"].to_numpy() - x[k])))]
            assert abs(row[f"{a}_mm"] - x[k]) < 1e-6  # the tables hold the grid's nodes
            d[a] = np.array([row[f"d{a}{c}_um"] for c in "xyz"]) * 1e-3
            ang = [row[f"r{a}{c}_urad"] * 1e-6 for c in "xyz"]
            R[a] = Rotation.from_euler("ZYX", ang[::-1]).as_matrix()
        s = {"x": np.zeros(3), "y": np.array([sq["sxy"] * x[1], 0, 0]) * 1e-6,
             "z": np.array([sq["sxz"] * x[2], sq["syz"] * x[2], 0]) * 1e-6}
        P = np.zeros(3)
        for a in reversed(tool):
            P = np.eye(3)["xyz".index(a)] * x["xyz".index(a)] + d[a] + s[a] + R[a] @ P
        X = P
        for b in table:
            X = R[b].T @ (X + np.eye(3)["xyz".index(b)] * x["xyz".index(b)] + s[b]
                          + table_sign * d[b])
        out[i] = (X - x) * 1e3
    return out


@pytest.mark.parametrize("layout", list(CHAINS))
def test_axis_tables_reproduce_the_grid_through_the_kinematic_model(layout):
    m = _random_model(layout)
    grid = ct.compensation_grid(m, (250.0, 200.0, 150.0))
    assert len(grid) == 5 * 5 * 5
    x = grid[["x_mm", "y_mm", "z_mm"]].to_numpy()
    c = grid[["cx_um", "cy_um", "cz_um"]].to_numpy()
    assert np.abs(c).max() > 20.0  # tens of µm: a sign or lever error would show
    mem = ct.axis_tables(m, 50.0)  # a finer step holds the grid's nodes too
    np.testing.assert_allclose(_compose(mem, CHAINS[layout], x), c, rtol=0, atol=FLOAT_TOL_UM)
    files = {k.removeprefix("axis_").removesuffix(".csv"): _read(v)
             for k, v in ct.axis_tables_csv(m, 50.0).items()}
    np.testing.assert_allclose(_compose(files, CHAINS[layout], x), c, rtol=0, atol=CSV_TOL_UM)
    if "F" != CHAINS[layout][0]:  # a moving table: its translations enter with minus
        wrong = _compose(mem, CHAINS[layout], x, table_sign=+1.0)
        assert np.abs(wrong - c).max() > 1.0


def test_grid_equals_compensate_at_every_node(thesis_fit):
    """At each node the grid's correction of the tip reading (node + probe offset) is
    what ``compensate`` adds to that reading, uncertainty and extrapolation flag too."""
    grid = ct.compensation_grid(thesis_fit, (300.0, 250.0, 350.0), probe="3")
    assert len(grid) == 5 * 5 * 3
    pts = pd.DataFrame({"probe": "3", "x_mm": grid["tip_x_mm"], "y_mm": grid["tip_y_mm"],
                        "z_mm": grid["tip_z_mm"]})
    out = compensate(thesis_fit, pts)
    for g, o in (("cx_um", "ex_um"), ("cy_um", "ey_um"), ("cz_um", "ez_um"),
                 ("u_cx_um", "u_x_um"), ("u_cy_um", "u_y_um"), ("u_cz_um", "u_z_um")):
        np.testing.assert_allclose(grid[g], out[o], rtol=0, atol=FLOAT_TOL_UM)
    assert (grid["extrapolated"] == 1).tolist() == (out["extrapolated"] != "").tolist()
    assert 0 < grid["extrapolated"].sum() < len(grid)  # the plate covers part of the volume
    p3 = model_from_result(thesis_fit).probes_mm["3"]
    np.testing.assert_allclose(grid[["tip_x_mm", "tip_y_mm", "tip_z_mm"]].to_numpy()
                               - grid[["x_mm", "y_mm", "z_mm"]].to_numpy(),
                               np.broadcast_to(p3, (len(grid), 3)), atol=1e-12)
    back = _read(ct.grid_csv(thesis_fit, grid, "3"))
    assert list(back.columns) == list(grid.columns)
    np.testing.assert_allclose(back["cz_um"], grid["cz_um"], rtol=0, atol=5e-7)


def test_on_an_axis_the_corrections_are_that_axis_functions(thesis_fit):
    """With the probe at the origin and y = z = 0 nothing carries a lever: the grid's
    correction along x is (dxx, dxy, dxz) of the x table, with the same uncertainty."""
    grid = ct.compensation_grid(thesis_fit, 100.0)
    on_x = grid[(grid["y_mm"] == 0) & (grid["z_mm"] == 0)]
    t = ct.axis_table(thesis_fit, "x", 100.0)
    for c, f in zip("xyz", ("dxx", "dxy", "dxz"), strict=True):
        np.testing.assert_allclose(on_x[f"c{c}_um"], t[f"{f}_um"], rtol=0, atol=FLOAT_TOL_UM)
        np.testing.assert_allclose(on_x[f"u_c{c}_um"], t[f"u_{f}_um"], rtol=1e-9, atol=1e-12)
    sq = ct.squareness_table(thesis_fit).set_index("name")
    lab = list(thesis_fit.labels)
    for n in ("sxy", "sxz", "syz"):
        assert sq.loc[n, "value_urad"] == thesis_fit.values[lab.index(n)]
        assert math.isclose(sq.loc[n, "u_urad"], thesis_fit.u[lab.index(n)], rel_tol=1e-9)


def test_headers_state_units_sign_layout_probe_and_the_chi2_test(thesis_fit):
    grid = ct.compensation_grid(thesis_fit, 400.0)
    head = [x for x in ct.grid_csv(thesis_fit, grid, source="thesis fit").splitlines()
            if x.startswith("#")]
    text = "\n".join(head)
    for needle in ("format: cmm-error-lab compensation grid 1", "true - indicated, added to "
                   "the reading", "layout: moving_bridge_fxyz", "probe: none, the ram "
                   "reference point", "x 0 to 1200 mm, 4 nodes, step 400",
                   "z 0 to 700 mm, 3 nodes", "chi2 test at 0.01: FAILS", "Birge ratio 10.6",
                   "thesis fit", "sigma 0.5 um"):
        assert needle in text, needle
    axes = ct.axis_tables_csv(_random_model("fixed_bridge_xfyz"), 100.0)
    assert set(axes) == {"axis_x.csv", "axis_y.csv", "axis_z.csv", "squareness.csv"}
    assert "moves the table" in axes["axis_x.csv"] and "enter the correction with -" in \
        axes["axis_x.csv"]
    assert "carries the probe" in axes["axis_y.csv"]
    assert "chi2 test at 0.01: passes" in axes["axis_y.csv"]
    z = ct.axis_table(_random_model("moving_bridge_fxyz"), "z", 250.0)
    assert z["z_mm"].tolist() == [0.0, 250.0, 500.0, 600.0]  # ends at the stroke
    with zipfile.ZipFile(io.BytesIO(ct.axis_tables_zip(thesis_fit, 100.0))) as zf:
        assert sorted(zf.namelist()) == sorted(axes)


def test_refusals(thesis_fit):
    from cmm_core.io import thesis_dataset
    from cmm_core.model import fit

    under = fit(thesis_dataset(), positions=["BP111", "BP112"])
    with pytest.raises(DataError, match="do not determine") as exc:
        ct.compensation_grid(under, 200.0)
    assert exc.value.column == "undetermined"
    with pytest.raises(DataError, match="do not determine"):
        ct.axis_tables(under, 200.0)
    g = ct.compensation_grid(under, 400.0, allow_undetermined=True)
    assert g["u_cx_um"].isna().all()
    with pytest.raises(DataError, match="probe '9' is not in the model") as exc:
        ct.compensation_grid(thesis_fit, 200.0, probe="9")
    assert exc.value.column == "probes_mm"
    with pytest.raises(ValueError, match="stroke of x"):
        ct.compensation_grid(thesis_fit, 1.0)
    with pytest.raises(ValueError, match="positive length"):
        ct.axis_table(thesis_fit, "x", 0.0)
    with pytest.raises(ValueError, match="coverage factor"):
        rx.results_dict(thesis_fit, coverage_factor=0.5)


def _chars(d):
    return {c["name"]: c for c in d["characteristics"]}


def test_results_json_round_trips_every_number(thesis_fit):
    d = json.loads(rx.results_json(thesis_fit, coverage_factor=2.0))
    assert d["format"] == "cmm-error-lab results" and d["version"] == 1
    assert d["chi2_test"]["fails"] is True and d["chi2_test"]["alpha"] == 0.01
    assert d["chi2_test"]["p_value"] == thesis_fit.chi2_p_value
    c = _chars(d)
    assert list(c) == list(thesis_fit.labels)
    for lab, v, u, ui in zip(thesis_fit.labels, thesis_fit.values, thesis_fit.u,
                             thesis_fit.u_inflated, strict=True):
        assert c[lab]["value"] == v and c[lab]["standard_uncertainty"] == u
        assert c[lab]["expanded_uncertainty"] == 2.0 * u
        assert c[lab]["standard_uncertainty_inflated"] == ui
    assert d["artefact"]["placements"] == ["BP111", "BP112", "BP211", "BP212", "BP311",
                                           "BP312"]


def test_results_xml_parses_and_round_trips(thesis_fit):
    from cmm_core.io import thesis_dataset
    from cmm_core.model import fit

    root = ET.fromstring(rx.results_xml(thesis_fit, source='fit <of> "thesis" & more'))
    assert root.tag == "MeasurementResults" and root.get("version") == "1"
    assert root.find("Model/Name").text == 'fit <of> "thesis" & more'
    assert root.find("Chi2Test/ModelFailsTest").text == "true"
    assert float(root.find("Chi2Test/PValue").text) == thesis_fit.chi2_p_value
    assert int(root.find("Chi2Test/DegreesOfFreedom").text) == thesis_fit.dof_test
    chars = root.findall("Characteristics/Characteristic")
    assert len(chars) == len(thesis_fit.labels)
    for el, lab, v, u in zip(chars, thesis_fit.labels, thesis_fit.values, thesis_fit.u,
                             strict=True):
        assert el.get("name") == lab
        assert float(el.find("Value").text) == v
        assert float(el.find("StandardUncertainty").text) == u
        assert float(el.find("CoverageFactor").text) == 2.0
        assert float(el.find("ExpandedUncertainty").text) == 2.0 * u
    # an undetermined parameter has no uncertainty elements and says so
    under = fit(thesis_dataset(), positions=["BP111", "BP112"])
    root = ET.fromstring(rx.results_xml(under))
    bad = [el for el in root.iter("Characteristic") if el.get("determined") == "false"]
    assert {el.get("name") for el in bad} == set(under.unidentifiable)
    assert all(el.find("StandardUncertainty") is None for el in bad)
    assert json.loads(rx.results_json(under))["characteristics"][0]["determined"] in (True,
                                                                                      False)


def _parser():
    ap = argparse.ArgumentParser(prog="python -m cmm_core")
    export_cli.add_parser(ap.add_subparsers(dest="command", required=True))
    return ap


def test_cli_writes_every_file_from_a_saved_model(thesis_fit, tmp_path, capsys):
    model = tmp_path / "model.json"
    save_model(thesis_fit, model)
    argv = ["export", str(model), "--grid-step-mm", "200", "--grid", str(tmp_path / "g.csv"),
            "--axis-tables", str(tmp_path / "axes"), "--results-json",
            str(tmp_path / "r.json"), "--results-xml", str(tmp_path / "r.xml"),
            "--probe", "2"]
    assert export_cli.run(_parser().parse_args(argv)) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["grid"]["nodes"] == 7 * 6 * 5
    m = load_model(model)
    grid = pd.read_csv(tmp_path / "g.csv", comment="#")
    np.testing.assert_allclose(grid["cy_um"], ct.compensation_grid(m, 200.0, probe="2")
                               ["cy_um"], rtol=0, atol=5e-7)
    assert sorted(p.name for p in (tmp_path / "axes").iterdir()) == [
        "axis_x.csv", "axis_y.csv", "axis_z.csv", "squareness.csv"]
    d = json.loads((tmp_path / "r.json").read_text())
    assert [c["value"] for c in d["characteristics"]] == m.coef.tolist()
    assert d["model"]["name"] == "model.json" and d["chi2_test"]["fails"] is True
    root = ET.parse(tmp_path / "r.xml").getroot()
    assert [float(e.text) for e in root.iter("Value")] == m.coef.tolist()


@pytest.mark.parametrize("extra, needle", [
    ([], "nothing to write"),
    (["--grid", "{tmp}/g.csv", "--probe", "9"], "column 'probes_mm': probe '9'"),
    (["--grid", "{tmp}/g.csv", "--grid-step-mm", "1"], "stroke of x"),
    (["--grid", "{tmp}/missing/g.csv"], "g.csv: No such file"),
])
def test_cli_refusals_are_one_line_naming_the_file(thesis_fit, tmp_path, capsys, extra,
                                                   needle):
    model = tmp_path / "model.json"
    save_model(thesis_fit, model)
    argv = ["export", str(model), *(a.replace("{tmp}", str(tmp_path)) for a in extra)]
    assert export_cli.run(_parser().parse_args(argv)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and needle in err
    assert not (tmp_path / "g.csv").exists()


def test_cli_bad_model_file_names_its_column(tmp_path, capsys):
    d = json.loads(json.dumps({"format": "cmm-error-lab model 1"}))
    (tmp_path / "bad.json").write_text(json.dumps(d))
    assert export_cli.run(_parser().parse_args(
        ["export", str(tmp_path / "bad.json"), "--results-json", str(tmp_path / "r.json")])) == 2
    err = capsys.readouterr().err
    assert "bad.json" in err and "missing key" in err and err.count("\n") == 1
    with pytest.raises(SystemExit) as exc:  # argparse refuses a bad step before running
        _parser().parse_args(["export", "m.json", "--grid-step-mm", "-5"])
    assert exc.value.code == 2
    assert "0.1 to 10000 mm" in capsys.readouterr().err


def test_export_page_offers_the_new_downloads():
    pytest.importorskip("streamlit")
    from streamlit.testing.v1 import AppTest

    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.run()
    at.switch_page("pages/export.py")
    at.run()
    assert not at.exception, [e.message for e in at.exception]
    keys = {b.key for b in at.get("download_button")}
    assert {"dl_comp_grid", "dl_axis_tables", "dl_results_json", "dl_results_xml"} <= keys

    def grid_help():
        return next(b for b in at.get("download_button") if b.key == "dl_comp_grid").proto.help

    assert grid_help().startswith("1144 nodes")  # 13 × 11 × 8 at 100 mm
    at.number_input(key="w_comp_step").set_value(200.0)
    at.run()
    assert not at.exception and not at.error
    assert grid_help().startswith("210 nodes")  # 7 × 6 × 5: 0..1200, 0..1000, 0..700 (end)


def test_backlash_is_a_characteristic_and_named_as_not_in_the_tables():
    """A model fitted with backlash: the saved model's results carry the spans with the
    fit's uncertainties; the tables (position only) say they do not hold them."""
    from cmm_core.model import fit, simulate

    sim = simulate({"seed": 4, "order": "serpentine",
                    "effects": {"backlash": {"x_um": 2.0, "y_um": 1.0}}})
    r = fit(sim.dataset, "kinematic21,backlash")
    lab, val, u = r.block("backlash")
    c = _chars(rx.results_dict(model_from_result(r)))
    for name, v, s in zip(lab, val, u, strict=True):
        assert c[name]["value"] == v and math.isclose(c[name]["standard_uncertainty"], s,
                                                      rel_tol=1e-9)
        assert c[name]["unit"] == "um"
    assert abs(c["backlash.x"]["value"] - 2.0) < 4 * c["backlash.x"]["standard_uncertainty"]
    text = ct.grid_csv(r, ct.compensation_grid(r, 400.0))
    line = next(x for x in text.splitlines() if x.startswith("# NOT in this table"))
    assert "backlash.x" in line and f"{val[0]:.4g}" in line


def test_cli_refuses_an_undetermined_model_and_writes_nothing(tmp_path, capsys):
    from cmm_core.io import thesis_dataset
    from cmm_core.model import fit

    model = tmp_path / "under.json"
    save_model(fit(thesis_dataset(), positions=["BP111", "BP112"]), model)
    argv = ["export", str(model), "--grid", str(tmp_path / "g.csv"), "--results-json",
            str(tmp_path / "r.json"), "--axis-tables", str(tmp_path / "axes")]
    assert export_cli.run(_parser().parse_args(argv)) == 2
    err = capsys.readouterr().err
    assert "under.json" in err and "column 'undetermined'" in err and err.count("\n") == 1
    assert not any(tmp_path.glob("r.json")) and not (tmp_path / "axes").exists()
    assert export_cli.run(_parser().parse_args([*argv, "--allow-undetermined"])) == 0
    assert pd.read_csv(tmp_path / "g.csv", comment="#")["u_cx_um"].isna().all()
    assert json.loads((tmp_path / "r.json").read_text())["model"]["undetermined"] is True


def test_every_option_says_its_unit_and_default():
    """The rules of tests/test_cli_help.py for the sub-command, before it is wired in."""
    p = _parser()._subparsers._group_actions[0].choices["export"]
    for a in p._actions:
        if isinstance(a, argparse._HelpAction):
            continue
        text = a.help % {"default": a.default}
        assert len(text) > 40, a.dest
        if a.option_strings and not isinstance(a, argparse._StoreTrueAction):
            assert "default" in text.lower(), a.option_strings
        if a.dest.endswith("_mm"):
            assert "mm" in text, a.dest


def test_the_worked_example_of_the_docs_is_the_thesis_model(thesis_fit):
    """docs/compensation.md quotes one node of the thesis model to 3 decimals."""
    text = (ROOT / "docs" / "compensation.md").read_text()
    row = next(x for x in text.splitlines() if x.startswith("| correction (µm) |"))
    quoted = [float(v.replace("−", "-")) for v in row.split("|")[2:5]]
    g = ct.compensation_grid(thesis_fit, 100.0)
    node = g[(g["x_mm"] == 600) & (g["y_mm"] == 500) & (g["z_mm"] == 300)]
    np.testing.assert_allclose(node[["cx_um", "cy_um", "cz_um"]].to_numpy()[0], quoted,
                               rtol=0, atol=5e-4)
    assert "dxx 17.338" in text and "rxz 84.351" in text and "sxy 77.650" in text
    x = ct.axis_table(thesis_fit, "x", 100.0).set_index("x_mm").loc[600.0]
    assert f"{x['dxx_um']:.3f}" == "17.338" and f"{x['rxz_urad']:.3f}" == "84.351"


def test_hole_plate_results_say_hole_plate_and_leave_held_parameters_undetermined(tmp_path):
    """A hole plate fit: the artefact is a hole plate in the results of the fit and of its
    saved model, and what gauge constraints hold (each hole's normal coordinate, each
    placement's tilt and normal translation: here the horizontal placements' rx, ry and
    tz) is not determined, with no uncertainty (it was exported as 0 ± 0, determined)."""
    from cmm_core.model import fit, simulate

    sim = simulate({"seed": 5, "artefact": "hole_plate",
                    "plate": {"form_um": 2.0, "certificate_u_um": 0.1}})
    r = fit(sim.dataset, "kinematic21", plate="prior")
    d = rx.results_dict(r)
    assert d["artefact"]["type"] == "hole plate"
    c = _chars(d)
    held = {n for n, v in c.items() if not v["determined"]}
    B = len(r.problem.obs.balls)
    assert {f"BP111.{k}" for k in ("rx", "ry", "tz")} <= held
    assert sum(n.endswith(".z") for n in held) == B, sorted(held)
    assert all(c[n]["standard_uncertainty"] is None for n in held)
    assert all(v["determined"] for n, v in c.items() if n in r.terms.labels)
    save_model(r, tmp_path / "m.json")
    assert rx.results_dict(load_model(tmp_path / "m.json"))["artefact"]["type"] == "hole plate"


def test_results_of_the_app_equal_those_of_the_cli_from_the_saved_model(tmp_path):
    """A backlash fit: the Export page's results (of the fit's model, named as the model
    file it offers) and `python -m cmm_core export cmm_model.json` give the same document,
    χ² test included (a model file kept no statistic: dof and p were null)."""
    from cmm_core.model import fit, simulate

    sim = simulate({"seed": 4, "order": "serpentine",
                    "effects": {"backlash": {"x_um": 2.0, "y_um": 1.0}}})
    r = fit(sim.dataset, "kinematic21,backlash")
    kw = {"coverage_factor": 2.0, "source": "cmm_model.json", "created": "2026-11-24T00:00:00"}
    app = rx.results_dict(ct.as_model(r), **kw)
    save_model(r, tmp_path / "cmm_model.json", sim.dataset.provenance())
    cli = rx.results_dict(load_model(tmp_path / "cmm_model.json"), **kw)
    # the same results; what made each differs: the CLI's names the model file it read
    made = cli.pop("provenance")
    assert app.pop("provenance")["inputs"] == []
    assert app == cli
    raw = (tmp_path / "cmm_model.json").read_bytes()
    assert made["inputs"][0] == {"name": "cmm_model.json", "bytes": len(raw),
                                 "sha256": hashlib.sha256(raw).hexdigest()}
    assert made["created"] == kw["created"] and made["model_made_by"].startswith("cmm-error-lab")
    assert cli["chi2_test"]["dof"] == r.dof_test and cli["chi2_test"]["p_value"] == r.chi2_p_value
    assert cli["artefact"]["placements"] == list(r.problem.obs.positions)

    def without_provenance(xml):
        root = ET.fromstring(xml.encode())
        head = root.find("Header")
        head.remove(head.find("Provenance"))
        return ET.tostring(root)

    assert without_provenance(rx.results_xml(ct.as_model(r), **kw)) == without_provenance(
        rx.results_xml(load_model(tmp_path / "cmm_model.json"), **kw))


def test_a_legacy_model_file_still_exports_its_results():
    """Model files written before the summary kept the artefact and the χ² statistic: a
    ball plate, the statistic unknown (null), nothing refused."""
    for f in sorted((ROOT / "tests" / "corpus" / "legacy_models").glob("model_*.json")):
        d = rx.results_dict(load_model(f))
        assert d["artefact"]["type"] == "ball plate" and "placements" not in d["artefact"]
        assert d["chi2_test"]["dof"] is None and d["chi2_test"]["p_value"] is None

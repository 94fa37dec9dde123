"""The command line: simulate -> fit --save -> compensate; diagnose; one-line errors."""

import json
import subprocess
import sys

import pytest
from conftest import ROOT, THESIS

SIM = ROOT / "sample_data" / "simulated"


def run(*args, check=True):
    p = subprocess.run([sys.executable, "-m", "cmm_core", *map(str, args)], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    if check:
        assert p.returncode == 0, p.stderr
    return p


def test_fit_thesis_tables_reports_outliers_and_parameters():
    """Flagged observations are listed and fitted (the app's and the record's rule);
    --exclude-outliers leaves them out and says which."""
    files = sorted(THESIS.glob("BP*.csv"))
    args = ("fit", *files, "--setup", THESIS / "setup.json", "--certificate",
            THESIS / "certificate.csv")
    out = json.loads(run(*args).stdout)
    assert out["model"] == "kinematic21" and out["n_obs"] == 150 and out["excluded"] == []
    assert {"rms_um", "chi2_dof", "parameters", "unidentifiable", "outliers"} <= set(out)
    flagged = {(o["position"], o["ball"]) for o in out["outliers"]}
    assert flagged >= {("BP112", 7), ("BP312", 16)}
    assert set(out["parameters"]["dxx[1]"]) >= {"value", "u"}
    cut = json.loads(run(*args, "--exclude-outliers").stdout)
    assert cut["n_obs"] == 150 - len(cut["excluded"]) == 147
    assert {(p, b) for p, _, b in cut["excluded"]} == flagged
    assert cut["chi2_dof"] < out["chi2_dof"]


def test_simulate_fit_save_compensate_roundtrip(tmp_path):
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"seed": 9}))
    run("simulate", cfg, "--out", tmp_path / "sim")
    sim = tmp_path / "sim"
    res = json.loads(run("fit", sim / "measurements.csv", "--setup", sim / "setup.json",
                         "--certificate", sim / "certificate.csv", "--save",
                         tmp_path / "model.json").stdout)
    assert 0.75 < res["chi2_dof"] < 1.3 and res["unidentifiable"] == []
    pts = tmp_path / "pts.csv"
    pts.write_text("id,probe,x_mm,y_mm,z_mm\nA,1,500,400,100\nB,3,650,420,300\n")
    run("compensate", tmp_path / "model.json", pts, "--out", tmp_path / "corr.csv")
    lines = (tmp_path / "corr.csv").read_text().splitlines()
    text = [line for line in lines if not line.startswith("# ")]  # its provenance first
    assert lines[0].startswith("# software: cmm-error-lab")
    assert text[0].startswith("id,probe,x_mm,y_mm,z_mm,xc_mm") and len(text) == 3


def test_diagnose_names_the_hidden_sag_in_the_sample():
    out = json.loads(run("diagnose", SIM / "measurements.csv", "--setup", SIM / "setup.json",
                         "--certificate", SIM / "certificate.csv", "--baseline",
                         "kinematic21").stdout)
    assert out["verdict"] == "plate_sag"
    c0 = out["candidates"][0]
    assert {"effect", "rms_um", "chi2_dof", "delta_bic", "p_value"} <= set(c0)
    assert out["baseline"]["chi2_dof"] > c0["chi2_dof"]


@pytest.mark.parametrize("args, needle", [
    (["fit", "nope.csv", "--setup", THESIS / "setup.json"], "nope.csv: file not found"),
    (["fit", THESIS / "BP111.csv", "--setup", THESIS / "setup.json", "--model", "dxx,foo"],
     "unknown model token 'foo'"),
    (["compensate", THESIS / "setup.json", THESIS / "BP111.csv", "--out", "/tmp/x.csv"],
     "setup.json: is not a model file"),
])
def test_bad_input_exits_nonzero_with_one_line(args, needle):
    p = run(*args, check=False)
    assert p.returncode == 2
    assert len(p.stderr.strip().splitlines()) == 1 and needle in p.stderr


def test_simulate_rejects_unknown_keys(tmp_path):
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"effects": {"plate_sagg": {"uu": 1}}}))
    p = run("simulate", cfg, "--out", tmp_path / "o", check=False)
    assert p.returncode == 2 and "unknown effect 'plate_sagg'" in p.stderr

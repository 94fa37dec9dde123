"""Writes the committed corpus of nasty inputs (issue 13) and its manifest.

Run from the repository root: ``PYTHONPATH=. .venv/bin/python tests/corpus/make_corpus.py``.
Each file reproduces one defect of the issue (``issue`` in ``manifest.json``);
``tests/test_hardening.py`` feeds them to the command line.
"""
import copy
import json
import pathlib

from cmm_core.export import model_to_dict
from cmm_core.model import fit, simulate

C = pathlib.Path("tests/corpus")
SIM = pathlib.Path("sample_data/simulated")
TH = pathlib.Path("sample_data/thesis")
meas = (SIM / "measurements.csv").read_text()
setup = json.loads((SIM / "setup.json").read_text())
tsetup = json.loads((TH / "setup.json").read_text())
cert = (TH / "certificate.csv").read_text()
bp111 = (TH / "BP111.csv").read_text()
man = []

def put(fname, content, kind, needle, note):
    p = C / fname
    if isinstance(content, (dict, list)):
        content = json.dumps(content, indent=1)
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    man.append({"file": fname, "kind": kind, "needle": needle, "issue": note})

lines = meas.splitlines()
# --- measurement files (long form, with the simulated sample's setup and certificate)
put("meas_trailing_comma_with_data.csv", "\n".join([lines[0]] + [ln + ",7" for ln in lines[1:40]]) + "\n",
    "meas", "expected 8 fields", "a trailing field holding data on every row")
put("meas_bare_cr_extra_field.csv", lines[0] + "\n" + lines[1] + ",\rX\n" + "\n".join(lines[2:30]) + "\n",
    "meas", "row 3", "extra field after a bare carriage return (_csv.Error): a bare CR ends a line, as in universal newlines")
put("meas_missing_position.csv", "\n".join(",".join(ln.split(",")[1:]) for ln in lines[:60]) + "\n",
    "meas", "missing column(s) position", "missing position column read as thesis form")
put("meas_huge_cell.csv", lines[0] + "\n" + lines[1].replace("333.999306", "9" * 150_000, 1) + "\n",
    "meas", "", "a 1 MB cell echoed into one 1 MB stderr line")
put("meas_inches.csv", lines[0] + "\n" + "\n".join(
    ",".join(f[:3] + [f"{float(v) / 25.4:.6f}" for v in f[3:6]] + f[6:]) for f in (ln.split(",") for ln in lines[1:51])) + "\n",
    "meas", "look like inches", "coordinates in inches fitted at RMS 27.7 mm, exit 0")
put("meas_time_renamed.csv", meas.replace("time_min", "time", 1), "meas", "did you mean 'time_min'",
    "time_min renamed time ignored silently")
put("meas_kelvin.csv", lines[0] + "\n" + "\n".join(ln.rsplit(",", 1)[0] + ",293.150000" for ln in lines[1:26]) + "\n",
    "meas", "kelvin", "temperatures in kelvin")
put("meas_binary.csv", bytes(range(256)) * 4, "meas", "not UTF-8", "binary file")
put("meas_nul.csv", lines[0] + "\n" + lines[1] + "\x00\n", "meas", "NUL", "NUL bytes")
put("meas_duplicate_header.csv", lines[0].replace("z_mm", "x_mm") + "\n" + "\n".join(lines[1:10]) + "\n",
    "meas", "twice", "a column named twice")
put("meas_unclosed_quote.csv", lines[0] + "\n" + '"BP111,1,1,3,4,5,0,20\n', "meas", "", "unclosed quote")
# --- setups (machine frame, with the simulated sample)
def s_mod(f):
    d = copy.deepcopy(setup)
    f(d)
    return d
put("setup_layout_banana.json", s_mod(lambda d: d["machine"].update(layout="banana")), "setup",
    "moving_bridge_fxyz", "machine.layout banana accepted")
put("setup_u_axis_hyphen.json", s_mod(lambda d: d["positions"]["BP111"].update({"u-axis": d["positions"]["BP111"].pop("u_axis")})),
    "setup", "did you mean 'u_axis'", "misspelt u-axis ignored")
put("setup_axes_45deg.json", s_mod(lambda d: d["positions"]["BP111"].update(v_axis=[0.7071067811865476, 0.7071067811865476, 0])),
    "setup", "orthogonal", "non-orthogonal axes orthogonalised silently")
put("setup_origin_metres.json", s_mod(lambda d: d["positions"]["BP111"].update(origin_mm=[0.334, 0.234, 0.0])),
    "setup", "metres", "origin in metres")
put("setup_probe_metres.json", s_mod(lambda d: d["probes"].update({"1": [0, 0, -0.15]})),
    "setup", "metres", "probe offset in metres")
put("setup_range_metres.json", s_mod(lambda d: d["machine"].update(range_mm=[1.2, 1.0, 0.7])),
    "setup", "metres", "ranges in metres")
put("setup_cte_negative.json", s_mod(lambda d: d.setdefault("plate", {}).update(cte_per_K=-5)),
    "setup", "cte_per_K", "CTE of -5/K")
put("setup_cte_per_MK.json", s_mod(lambda d: d.setdefault("plate", {}).update(cte_per_K=11.5)),
    "setup", "cte_per_K", "CTE written per MK")
put("setup_bom.json", b"\xef\xbb\xbf" + json.dumps(s_mod(lambda d: d["machine"].update(layout="banana"))).encode(),
    "setup", "moving_bridge_fxyz", "JSON with a BOM refused where CSV with a BOM is accepted: now read, then checked")
put("setup_binary.json", bytes(range(255, -1, -1)) * 3, "setup", "not UTF-8", "UnicodeDecodeError without the file name")
put("setup_truncated.json", json.dumps(setup)[:200], "setup", "not valid JSON", "truncated JSON")
put("setup_temp_kelvin.json", s_mod(lambda d: d["positions"]["BP111"].update(temp_C=[293.1, 293.4])),
    "setup", "kelvin", "temperatures in kelvin")
put("setup_temp_string.json", s_mod(lambda d: d["positions"]["BP111"].update(temp_C="20")),
    "setup", "list of numbers", "a temperature string read digit by digit")
put("setup_origin_strings.json", s_mod(lambda d: d["positions"]["BP111"].update(origin_mm=["334", "234", "0"])),
    "setup", "3 numbers", "numbers as strings accepted")
# thesis data (plate frame) with the frame key missing: default machine
t = copy.deepcopy(tsetup)
t.pop("frame")
put("setup_thesis_no_frame.json", t, "setup_thesis", "frame", "missing frame: 30 unidentifiable parameters")
# --- certificates
cl = cert.splitlines()
put("cert_ball_5m.csv", "\n".join(cl[:8] + [cl[8].split(",")[0] + ",399.0,5000.0,0.0"] + cl[9:]) + "\n",
    "cert", "nearest neighbour", "a ball at y = 5000 mm loads without a word")
put("cert_metres.csv", cl[0] + "\n" + "\n".join(",".join([f[0]] + [f"{float(v) / 1000:.8f}" for v in f[1:]]) for f in (ln.split(",") for ln in cl[1:])) + "\n",
    "cert", "metres", "certificate in metres")
put("cert_collinear.csv", cl[0] + "\n" + "\n".join(cl[1:6]) + "\n", "cert", "one line", "collinear balls")
# --- simulation configs
for i, (cfg, needle, note) in enumerate([
        ({"seed": "abc"}, "seed", "traceback"), ({"repeats": 0}, "repeats", "traceback"),
        ({"plate": {"rows": 0}}, "plate.rows", "traceback"), ({"effects": ["plate_sag"]}, "effects", "traceback"),
        ({"plate": None}, "plate", "traceback"), ({"kinematic": {"coefficients": {"dxx[9]": 1.0}}}, "dxx[9]", "dropped silently"),
        ({"kinematic": {"coefficients": {"dxx1": 1.0}}}, "dxx1", "dropped silently"),
        ({"probes_per_position": {"BP999": ["1"]}}, "BP999", "unknown position dropped"),
        ({"plate": {"pitch_mm": 0}}, "pitch_mm", "pitch 0 accepted"), ({"plate": {"rows": 1}}, "one line", "collinear plate"),
        ({"minutes_per_ball": -0.5}, "minutes_per_ball", "negative time per ball"),
        ({"effects": {"plate_sag": "big"}}, "plate_sag", "traceback"), ({"noise_um": -1}, "noise_um", "negative noise"),
        ({"order": "spiral"}, "order", "unknown order")]):
    put(f"sim_{i:02d}.json", cfg, "sim", needle, note)
# --- model files
r = fit(simulate({"seed": 2}).dataset, "kinematic21")
good = model_to_dict(r)
(C / "good_model.json").write_text(json.dumps(good))
def m_mod(f):
    d = copy.deepcopy(good)
    f(d)
    return d
put("model_nan_coef.json", json.dumps(m_mod(lambda d: d["coef"].__setitem__(3, float("nan")))), "model", "finite", "NaN corrections, exit 0")
put("model_nan_cov.json", json.dumps(m_mod(lambda d: d["cov"][2].__setitem__(2, float("nan")))), "model", "NaN", "NaN covariance")
put("model_negative_variance.json", m_mod(lambda d: d["cov"][0].__setitem__(0, -1.0)), "model", "negative", "negative variance")
put("model_zero_range.json", m_mod(lambda d: d.update(range_mm=[0, 1000, 700])), "model", "range_mm", "zero range")
put("model_negative_range.json", m_mod(lambda d: d.update(range_mm=[-1200, 1000, 700])), "model", "range_mm", "negative range")
put("model_wrong_format.json", m_mod(lambda d: d.update(format="something else")), "model", "not a model file", "wrong format")
put("model_reordered_labels.json", m_mod(lambda d: d.update(labels=d["labels"][::-1])), "model", "labels", "reordered labels")
put("model_missing_cov.json", m_mod(lambda d: d.pop("cov")), "model", "missing key 'cov'", "missing field")
put("model_bom.json", b"\xef\xbb\xbf" + json.dumps(m_mod(lambda d: d.update(format="x"))).encode(), "model", "not a model file", "BOM read like CSV")
# --- points to correct (with good_model.json)
put("points_400m.csv", "probe,x_mm,y_mm,z_mm\n1,500,400,100\n1,400000,300,0\n", "points", "outside the machine's range", "352 m correction, exit 0")
put("points_nan.csv", "probe,x_mm,y_mm,z_mm\n1,500,400,nan\n", "points", "not a finite number", "NaN point")
put("points_header_only.csv", "probe,x_mm,y_mm,z_mm\n", "points", "no data rows", "nothing to correct")
# --- budgets
put("budget_bad_u.json", {"contributions": [{"name": "a", "u": -1}]}, "budget", "u", "errors never named the budget file")
put("budget_not_object.json", [1, 2], "budget", "budget", "errors never named the budget file")
put("budget_bad_distribution.json", {"contributions": [{"name": "a", "half_width": 1, "distribution": "gauss"}]}, "budget", "distribution", "errors never named the budget file")
(C / "manifest.json").write_text(json.dumps(man, indent=1, ensure_ascii=False) + "\n")
print(len(man), "files")

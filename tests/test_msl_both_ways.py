"""MSL cmm-error-map files both ways (issue 42, item 3): files in MSL's format written here
(plates and a bar, from this project's simulator with MSL-style parameters; none of MSL's
own files) fitted from the command line with nothing beyond the files and ``--msl-kind``,
every default the files set said in one ``note:`` line; every refusal in the flags'
words, naming the file; the fitted machine written back in MSL's metadata form and read
back to the same numbers; ``--help`` true; the commands of docs/msl-format.md run."""

from __future__ import annotations

import ast
import io
import json
import re
import shlex
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_msl import MSL_TRUTH, RANGE, msl_files_of, simulated_machine, write_msl

from cmm_core.cli import main, options
from cmm_core.io import DataError, msl
from cmm_core.machine import error
from cmm_core.model import truth_of

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "msl-format.md"
LAYOUT = "fixed_bridge_xfyz"  # MSL's "old PMM866": table in x, y across a fixed bridge
BAR_AT = np.array([100.0, 300.0, 300.0])  # ram position of the bar's ball id 0, mm
BAR_PITCH, BAR_BALLS = 20.0, 31


def write_bar(sim, folder: Path, kind: str = "simulated") -> Path:
    """A 31-ball bar along machine x in MSL's format on ``sim``'s true machine: MSL's
    simulation writes nominal + (true - indicated), a measurement the indications."""
    terms, coef = truth_of(sim)
    nominal = msl._grid(BAR_BALLS, 1, BAR_PITCH)
    e_mm = error(terms, coef, BAR_AT + nominal, np.zeros((BAR_BALLS, 3))) * 1e-3
    xyz = nominal + e_mm if kind == "simulated" else nominal - e_mm
    xyz -= xyz[0]  # MSL's frame starts at ball id 0 (a rigid shift: lengths unchanged)
    snap, _meta = write_msl(folder, "bar", np.round(xyz, 5), BAR_BALLS, 1, BAR_PITCH,
                            BAR_AT, (0.0, 0.0, 0.0), LAYOUT, (0.0, 0.0, 0.0), MSL_TRUTH)
    return snap


@pytest.fixture(scope="module")
def machine():
    return simulated_machine(LAYOUT)


@pytest.fixture
def files(tmp_path, machine):
    """``XY``, ``XZ``, ``YZ`` plates and a ``bar``, each snapshot.csv with its
    metadata.csv beside it, as MSL saves them; the paths as the docs name them."""
    sim, _truth = machine
    msl_files_of(sim, tmp_path, "simulated", LAYOUT)
    write_bar(sim, tmp_path / "bar")
    return tmp_path


def run(argv, capsys):
    """``main(argv)``: (status, JSON or None, note lines, error lines)."""
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    lines = cap.err.splitlines()
    out = json.loads(cap.out) if rc == 0 and cap.out.strip() else None
    return (rc, out, [ln[6:] for ln in lines if ln.startswith("note: ")],
            [ln for ln in lines if ln.startswith("error: ")])


def plates(folder: Path) -> list:
    return [a for p in ("XY", "XZ", "YZ") for a in ("--msl", folder / p / "snapshot.csv")]


# ------------------------------------------------------------------ defaults from the files


def test_plates_and_bar_fit_with_the_files_and_kind_alone(files, machine, capsys):
    """Three plates and a bar in one fit, no option but --msl-kind: order 1 (the metadata's
    linear parameters), σ the rounding of 5 decimals, the plate fixed, each metadata file
    from beside its snapshot, each said in one line; every determined parameter back."""
    _sim, truth = machine
    rc, out, notes, errors = run(["fit", *plates(files), "--msl-bar", files / "bar" /
                                  "snapshot.csv", "--msl-kind", "simulated"], capsys)
    assert rc == 0, errors
    assert out["sigma"] == {"value_um": pytest.approx(msl.MSL_ROUNDING_U_UM), "auto": False}
    assert all(re.fullmatch(r"(.*\.)?[a-z]+(\[1\])?", lab) for lab in out["parameters"])
    assert out["chi2_dof"] < 2.0  # σ = the rounding explains noise-free files
    assert [i["kind"] for i in out["instruments"]] == ["step_gauge"]
    said = {n.split(": ", 1)[0] for n in notes}
    assert {"order", "sigma", "plate"} <= said
    assert sum("metadata.csv saved beside" in n for n in notes) == 4  # three plates, a bar
    for key in ("kind", "origin", "angles", "balls", "layout", "u_um", "lengths"):
        assert any(f": {key}: " in n for n in notes), key  # the reader's conventions
    assert any(n.startswith("order: 1, the degree") for n in notes)
    assert any(n.startswith("sigma: 0.00289 µm, the rounding") for n in notes)
    # each convention once: the three plates' shared notes are not said three times
    assert len(notes) == len(set(notes))
    assert sum(": kind: " in n for n in notes) == 1
    got = out["parameters"]
    for lab, v in truth.items():
        if lab not in out["unidentifiable"]:
            assert abs(got[lab]["value"] - v) < max(5 * got[lab]["u"], 0.01), lab


def test_an_option_given_is_taken_and_not_said(files, capsys):
    rc, out, notes, _ = run(["fit", *plates(files), "--msl-kind", "simulated", "--order",
                             "2", "--sigma-um", "0.01", "--plate", "fixed"], capsys)
    assert rc == 0 and out["sigma"]["value_um"] == 0.01
    assert any(lab.endswith("[2]") for lab in out["parameters"])
    assert not [n for n in notes if n.split(": ", 1)[0] in ("order", "sigma", "plate")]


def test_a_measurement_states_no_repeatability_and_the_cli_says_it_assumed_one(tmp_path,
                                                                             machine,
                                                                             capsys):
    sim, _ = machine
    msl_files_of(sim, tmp_path, "measured", LAYOUT)
    rc, out, notes, _ = run(["fit", *plates(tmp_path), "--msl-kind", "measured",
                             "--msl-certificate-u", "0.01,0"], capsys)
    assert rc == 0 and out["sigma"]["value_um"] == options.DEFAULT_SIGMA_UM
    assert any(n.startswith("sigma: 0.5 µm, assumed") and "--sigma-um" in n for n in notes)
    assert any(n.startswith("plate: ") and "--msl-certificate-u" in n for n in notes)
    assert "--msl-certificate-u" in out["certificate_u_source"]


def test_a_bar_alone_takes_its_machine_and_order_from_its_metadata(files, capsys):
    rc, out, notes, errors = run(["fit", "--msl-bar", files / "bar" / "snapshot.csv",
                                  "--msl-kind", "simulated", "--model", "dxx"], capsys)
    assert rc == 0, errors
    assert list(out["parameters"]) == ["dxx[1]"]
    assert any(n.startswith("order: 1") for n in notes)
    # dxx alone takes the whole length error the bar sees (its scale and the Abbe terms
    # of the carriage rotations): the slope of measured - certified, µm/mm, times s/2
    bar = msl.read_msl_bar(files / "bar" / "snapshot.csv", files / "bar" / "metadata.csv",
                           kind="simulated")
    sg = pd.read_csv(io.StringIO(bar.step_gauge_csv))
    slope = np.polyfit(sg["certified_mm"], 1e3 * (sg["measured_mm"] - sg["certified_mm"]),
                       1)[0]
    assert out["parameters"]["dxx[1]"]["value"] == pytest.approx(slope * RANGE[0] / 2,
                                                                 abs=0.01)


# ------------------------------------------------------------------ refusals in the flags' words


def _refused(argv, capsys):
    rc, _out, _notes, errors = run(argv, capsys)
    assert rc == 2 and len(errors) == 1, errors
    return errors[0]


def test_every_refusal_names_the_flag_and_the_file(files, tmp_path, capsys):
    xz = files / "XZ" / "snapshot.csv"
    bar = files / "bar" / "snapshot.csv"
    cases = [  # argv, the flags the line must name
        (["--msl", xz], ["--msl-kind", str(xz)]),
        (["--msl", xz, "--msl-kind", "measured"], ["--msl-certificate-u", str(xz)]),
        (["--msl", xz, "--msl-kind", "simulated", "--msl-certificate-u", "0.2,0"],
         ["--msl-certificate-u", "--msl-kind measured", str(xz)]),
        (["--msl", bar, "--msl-kind", "simulated"], ["--msl-bar", "--msl", str(bar)]),
        (["--msl-bar", xz, "--msl-kind", "simulated"], ["--msl-bar", "--msl", str(xz)]),
        (["--msl", xz, "--msl-metadata", files / "XY" / "metadata.csv", "--msl-kind",
          "simulated"], ["--msl-metadata", str(files / "XY" / "metadata.csv")]),
        (["--msl", xz, "--msl-metadata", xz, "--msl-kind", "simulated"],
         ["--msl-metadata", str(xz)]),
        (["--msl", files / "XZ" / "metadata.csv", "--msl-kind", "simulated"],
         ["--msl", "metadata.csv"]),
        (["--msl", xz, "--msl", xz, "--msl-kind", "simulated"], ["--msl", str(xz)]),
        (["--msl-bar", bar, "--msl-bar", bar, "--msl-kind", "simulated"],
         ["--msl-bar", str(bar)]),
        # an MSL file given as this project's measurements: the flags that take it
        ([xz, "--setup", ROOT / "sample_data" / "simulated" / "setup.json"],
         ["--msl", "--msl-kind", "snapshot.csv"]),
        ([files / "XZ" / "metadata.csv", "--setup", ROOT / "sample_data" / "simulated" /
          "setup.json"], ["--msl", "--msl-metadata", "metadata.csv"]),
    ]
    for args, words in cases:
        line = _refused(["fit", *args], capsys)
        for w in words:
            assert w in line, (args, line)
        # no Python names: the command line's user typed flags
        for python in ("kind=", "certificate_u", "read_msl_", "setup.json"):
            assert python not in line, (args, line)
    lone = tmp_path / "lone"
    lone.mkdir()
    shutil.copy(xz, lone / "snapshot.csv")  # a snapshot without its metadata
    line = _refused(["fit", "--msl", lone / "snapshot.csv", "--msl-kind", "simulated"],
                    capsys)
    assert "--msl-metadata" in line and str(lone / "snapshot.csv") in line


@pytest.mark.parametrize("value,words", [
    ("0,0", "both 0"), ("1", "A_UM,B_UM_PER_MM"), ("200,0", "0 to 100 µm"),
    ("0,2", "0 to 1 µm/mm"), ("nan,0", "0 to 100 µm")])
def test_a_bad_certificate_u_is_refused_at_parsing_naming_the_flag(files, capsys, value,
                                                                   words):
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--msl", str(files / "XZ" / "snapshot.csv"), "--msl-kind", "measured",
              f"--msl-certificate-u={value}"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--msl-certificate-u" in err and words in err
    assert "setup.json" not in err


def test_the_certificate_ranges_of_the_flag_are_the_setups(files):
    """``--msl-certificate-u``'s parse-time ranges copy the setup's: the largest values
    load, a bit more is refused by the setup (``cli.options`` copies, pinned here)."""
    s, m = files / "XZ" / "snapshot.csv", files / "XZ" / "metadata.csv"
    hi = (options._MSL_CERTIFICATE_A_UM[1], options._MSL_CERTIFICATE_B_UM_PER_MM[1])
    cu = {"U_um": list(hi), "k": 2, "combine": "quadrature"}
    msl.read_msl_plate(s, m, kind="measured", certificate_u=cu).to_dataset()
    with pytest.raises(DataError, match="certificate"):
        msl.read_msl_plate(s, m, kind="measured", certificate_u=dict(
            cu, U_um=[hi[0] * 1.01, 0.0])).to_dataset()
    assert options._MSL_ROUNDING_UM == round(msl.MSL_ROUNDING_U_UM, 4)
    assert msl.rounding_u_um(5) == pytest.approx(msl.MSL_ROUNDING_U_UM)


def test_metadata_pair_by_header_in_any_order(files, capsys):
    metas = [a for p in ("YZ", "XY", "XZ") for a in ("--msl-metadata", files / p /
                                                    "metadata.csv")]
    rc, _out, notes, errors = run(["fit", *plates(files), *metas, "--msl-kind", "simulated",
                                   "--model", "dxx"], capsys)
    assert rc == 0, errors
    assert not any("saved beside" in n for n in notes)  # every one was given


def test_one_placement_twice_is_refused_by_the_library_too(files):
    s, m = files / "XZ" / "snapshot.csv", files / "XZ" / "metadata.csv"
    one = msl.read_msl_plate(s, m, kind="simulated")
    with pytest.raises(DataError, match="placement"):
        msl.combine_plates([one, one])


# ------------------------------------------------------------------ the writer


def test_the_fitted_machine_is_written_in_msl_form_and_read_back(files, tmp_path, capsys):
    """fit --save, export --msl-parameters: the file MSL's form (its header first, no
    comment line), read back by read_msl_metadata and turned into this project's
    coefficients by msl_coefficients, gives the model's to the 10 digits written; the
    determined parameters are MSL's own, in MSL's sign."""
    model = tmp_path / "model.json"
    rc, fitted, _, errors = run(["fit", *plates(files), "--msl-kind", "simulated",
                                 "--save", model], capsys)
    assert rc == 0, errors
    out = tmp_path / "machine.csv"
    line = _refused(["export", model, "--msl-parameters", out], capsys)
    assert "--allow-undetermined" in line and not out.exists()
    rc, summary, notes, errors = run(["export", model, "--msl-parameters", out,
                                      "--allow-undetermined"], capsys)
    assert rc == 0, errors
    assert summary["msl_parameters"] == str(out)
    assert any("minimum-norm" in n for n in notes)
    text = out.read_text()
    assert text.startswith("save time,") and "#" not in text
    back = msl.read_msl_metadata(out)
    assert back["layout"] == LAYOUT and back["range_mm"] == RANGE
    assert back["probe_mm"] == [0.0, 0.0, 0.0] and set(back["parameters"]) == set(
        msl.MSL_PARAMETERS)
    coef = msl.msl_coefficients(back["parameters"], LAYOUT, RANGE, order=1)
    kin = {lab: p["value"] for lab, p in fitted["parameters"].items() if "." not in lab}
    assert set(kin) <= set(coef)
    for lab, v in kin.items():
        assert coef[lab] == pytest.approx(v, rel=1e-9, abs=1e-12), lab
    # both ways: MSL's parameters in, MSL's parameters out, where the plates determine them
    det = {"Txx": "dxx[1]", "Tyy": "dyy[1]", "Rxx": "rxx[1]", "Ryy": "ryy[1]"}
    for name, lab in det.items():
        if lab not in fitted["unidentifiable"]:
            u = fitted["parameters"][lab]["u"]
            scale = (2e-3 if name[0] == "T" else 2e-6) / RANGE["xyz".index(name[1].lower())]
            assert back["parameters"][name][1] == pytest.approx(
                MSL_TRUTH[name], abs=max(5 * u, 0.01) * scale), name


def test_the_writers_lines_are_msls_and_read_back():
    """The writer's file line by line against MSL's conventions (docs/msl-format.md,
    "MSL's conventions the writer follows": MSL's data_cmpts.py and design_poly.py at
    c337a60): the eight header lines and the machine and probe lines in MSL's order and
    form, the artefact lines saying no artefact, the 21 parameters in MSL's order as
    Python lists, lowest power first, in mm/mm and rad/mm with MSL's sign; then read back
    by this project's reader (and named by ``sniff`` as the machine it is, not a bar)."""
    probe = (0.0, 130.0, -243.4852)
    for (fixed, bridge), layout in msl.MSL_LAYOUTS.items():
        params, left_out = msl.msl_parameters(msl.msl_coefficients(MSL_TRUTH, layout, RANGE),
                                              layout, RANGE)
        assert not left_out
        text = msl.msl_metadata_text(params, layout, RANGE, probe_name="p1", probe_mm=probe,
                                     title="cmm-error-lab fit, order 1", name="model",
                                     machine="PMM866")
        lines = text.splitlines()
        keys = [ln.split(",", 1)[0] for ln in lines]
        assert keys[:8] == list(msl.MSL_HEADER_KEYS)
        assert keys[8:16] == ["cmm_model.title", "cmm_model.size", "cmm_model.fixed_table",
                              "cmm_model.bridge_axis", "probe.title", "probe.name",
                              "probe.length", "model parameters"]
        assert keys[16:] == list(msl.MSL_PARAMETERS)  # all 21: MSL's model needs each
        assert re.fullmatch(r"save time,\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{6}", lines[0])
        assert lines[1:8] == ["title,cmm-error-lab fit order 1", "name,model",
                              "artefact.title,none (a fitted machine)", "artefact.nballs,1,1",
                              "artefact.ball_spacing,1.0", "location,0.0, 0.0, 0.0",
                              "rotation/deg,0.0, 0.0, 0.0"]
        assert lines[8:16] == ["cmm_model.title,PMM866", "cmm_model.size,800.0,600.0,600.0",
                               f"cmm_model.fixed_table,{fixed}",
                               f"cmm_model.bridge_axis,{bridge}", "probe.title,stylus",
                               "probe.name,p1", "probe.length,0.0,130.0,-243.4852",
                               "model parameters"]
        for line in lines[16:]:
            name, _, value = line.partition(",")
            # a Python list, as MSL writes its own, to the writer's 10 digits
            assert re.fullmatch(r"\[\S+(, \S+)+\]", value), line
            assert ast.literal_eval(value) == pytest.approx(params[name], rel=1e-9,
                                                            abs=1e-20), line
        # MSL's own linear parameters (mm/mm, rad/mm, true - indicated) come out as given
        for name, v in MSL_TRUTH.items():
            assert params[name] == pytest.approx([0.0, v], abs=1e-18), (layout, name)
        back = msl.read_msl_metadata(text.encode(), "machine.csv")
        assert back["layout"] == layout and back["range_mm"] == RANGE
        assert back["probe_name"] == "p1" and back["probe_mm"] == list(probe)
        assert back["title"] == "PMM866"
        for name, v in params.items():
            assert back["parameters"][name] == pytest.approx(v, rel=1e-9, abs=1e-20), name
        said = msl.sniff(text.encode())
        assert "read_msl_metadata" in said and "read_msl_bar" not in said


def test_the_writer_inverts_the_readers_conventions_at_any_order():
    rng = np.random.default_rng(3)
    for layout in msl.MSL_LAYOUTS.values():
        coef = msl.msl_coefficients(MSL_TRUTH, layout, RANGE, order=3)
        coef = {k: v + rng.normal() for k, v in coef.items()}
        params, left = msl.msl_parameters(coef, layout, RANGE)
        assert not left
        back = msl.msl_coefficients(params, layout, RANGE, order=3)
        for k, v in coef.items():
            assert back[k] == pytest.approx(v, abs=1e-9), (layout, k)
        at1 = msl.msl_parameters(msl.msl_coefficients(MSL_TRUTH, layout, RANGE), layout,
                                 RANGE)[0]
        for k, v in MSL_TRUTH.items():  # MSL's own linear parameters, exactly back
            assert at1[k] == pytest.approx([0.0, v], abs=1e-18), (layout, k)
    with pytest.raises(ValueError, match="layouts"):
        msl.msl_parameters({}, "gantry_fxyz", RANGE)  # MSL knows no gantry


def test_the_writer_refuses_to_overwrite_the_model(files, tmp_path, capsys):
    model = tmp_path / "model.json"
    assert run(["fit", *plates(files), "--msl-kind", "simulated", "--model", "dxx",
                "--save", model], capsys)[0] == 0
    before = model.read_bytes()
    _refused(["export", model, "--msl-parameters", model], capsys)
    assert model.read_bytes() == before


# ------------------------------------------------------------------ --help and the docs


def _help(argv, capsys):
    with pytest.raises(SystemExit):
        main([*argv, "--help"])
    return " ".join(capsys.readouterr().out.split())


def test_help_says_the_defaults_the_files_set(capsys):
    text = _help(["fit"], capsys)
    assert "the snapshot alone" not in text
    assert "metadata.csv saved beside each snapshot" in text
    assert "degree of the model parameters their metadata lists" in text
    assert "the rounding of their decimals, 0.0029 µm for 5" in text
    assert "with --msl-bar too" in text and "with the --msl plates, or alone" in text
    text = _help(["export"], capsys)
    assert "--msl-parameters OUT.csv" in text and "No provenance line" in text


def _doc_commands():
    """Every ``cmm-error-lab ...`` line of the doc's ``sh`` blocks."""
    blocks = re.findall(r"```sh\n(.*?)```", DOC.read_text(), flags=re.S)
    text = "\n".join(blocks).replace("\\\n", " ")
    return [shlex.split(ln)[1:] for ln in text.splitlines()
            if ln.strip().startswith("cmm-error-lab ")]


def test_every_command_of_the_docs_runs(files, monkeypatch, capsys):
    """docs/msl-format.md's commands, on files of the names it uses (XY, XZ, YZ, bar),
    in its order: each exits 0."""
    commands = _doc_commands()
    assert len(commands) >= 4
    monkeypatch.chdir(files)
    for argv in commands:
        rc, _out, _notes, errors = run(argv, capsys)
        assert rc == 0, (argv, errors)


def test_every_python_example_of_the_docs_runs(files, monkeypatch):
    """docs/msl-format.md's ``python`` blocks, executed in their order in a folder of the
    files they name (the XZ plate's files also as ``snapshot.csv``/``metadata.csv``,
    the first block's names): none raises, and what they build is what they say."""
    for name in ("snapshot.csv", "metadata.csv"):
        shutil.copy(files / "XZ" / name, files / name)
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.S)
    assert len(blocks) >= 3
    monkeypatch.chdir(files)
    scope: dict = {}
    for block in blocks:
        exec(compile(block, str(DOC), "exec"), scope)  # noqa: S102 - the docs' own examples
    assert len(scope["plate"].notes) > 0 and len(scope["ds"].meas) > 0
    assert len(scope["gauges"]) == 1 and scope["res"].status in ("converged", "ok")

"""The HTML report (issue 12): one core function from one analysis record, so the app's
Export page and ``python -m cmm_core report`` give the same bytes (the generation time
aside); the χ² test beside every uncertainty (issue 11); plotly.js once and < 2 MB
(issue 18)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from scenarios import simulated

from cmm_core import analysis as A
from cmm_core.analysis import report as rep
from cmm_core.cli import main
from cmm_core.units import p_text
from pages.ui.session import session_record

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "thesis" / "analysis.json"
FLAGGED = [("BP112", "2", 7), ("BP112", "2", 10), ("BP312", "6", 16)]


def _session(**state):
    """Session state as the app holds it (pages/state.py DEFAULTS, the thesis files)."""
    from pages.ui import state as C

    return {**{k: list(v) if isinstance(v, list) else v for k, v in C.DEFAULTS.items()},
            "sources": A.thesis_sources(), **state}


def _cli(record_path, out, capsys, *flags):
    code = main(["report", str(record_path), "--out", str(out), *flags])
    printed = capsys.readouterr()
    return code, printed


def _same(a: str, b: str) -> bool:
    strip = rep.TIMESTAMP.sub("Generated (time)", a), rep.TIMESTAMP.sub("Generated (time)", b)
    return strip[0] == strip[1]


def test_export_page_calls_the_cli_function_on_the_session_record():
    """No AppTest needed: the page builds the record with the core function and renders
    it with the function the CLI calls; it assembles no report arguments itself."""
    src = (ROOT / "pages" / "export.py").read_text()
    assert "session.session_record, s," in src and "A.analysis_report(_record)" in src
    assert "build_report" not in src
    cli = (ROOT / "cmm_core" / "analysis" / "report.py").read_text()
    assert "res = run(read_record(Path(analysis_path), confine=confine))" in cli and "text = render(res)" in cli
    assert "def analysis_report" in cli


@pytest.fixture(scope="module")
def thesis_app():
    record = session_record(_session(exclusions=list(FLAGGED)))
    return record, rep.analysis_report(record)


def test_thesis_report_app_and_cli_byte_identical(thesis_app, tmp_path, capsys):
    record, app_html = thesis_app
    path = tmp_path / "ANALYSIS.json"
    path.write_text(A.record_to_json(record))  # the page's ANALYSIS.json download
    code, printed = _cli(path, tmp_path / "r.html", capsys)
    assert code == 0, printed.err
    cli_html = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert _same(app_html, cli_html)
    assert rep.TIMESTAMP.search(cli_html)
    # the committed sample names the same files by path: the same report again
    code, printed = _cli(SAMPLE, tmp_path / "s.html", capsys)
    assert code == 0, printed.err
    assert _same(app_html, (tmp_path / "s.html").read_text(encoding="utf-8"))
    out = json.loads(printed.out)
    assert out["fails_chi2_test"] is True and out["chi2_dof"] == pytest.approx(44.7, abs=0.1)


def test_thesis_report_shows_the_failed_chi2_test_and_inflated_values(thesis_app):
    record, html = thesis_app
    res = A.run(record)
    val, dof, _ = rep.chi2_test_numbers(res.fit)
    assert res.fit.chi2_dof == pytest.approx(44.7, abs=0.05) and res.fit.fails_chi2_test
    # the statistic the core tests (certificate uncertainty counted), p, dof, and the
    # fit's own χ²/dof beside it
    assert "The model fails its χ² test" in html and f"χ²/dof {val:.2f} at {dof}" in html
    # p as the core writes every p-value: "p < 1e-16", never "p = 0"
    assert p_text(res.fit.chi2_p_value) in html and "p = 0 " not in html and "44.71" in html
    assert "FAILS at 1 %" in html and f"×{res.fit.birge_ratio:.2f}" in html
    assert html.count("class='chi2 fail'") >= 4  # summary, functions, U, MPE, parameters
    assert "x × Birge (µm)" in html and "u × Birge" in html
    assert "χ² test passed" not in html


def test_report_size_and_plotly_once(thesis_app):
    _, html = thesis_app
    assert len(html.encode()) < 2_000_000
    assert html.count("id='cmm-plotly'") == 1 and "<script src=" not in html
    assert html.count("Plotly.newPlot") >= 10  # one per figure, the data packed once
    assert "plotly.js v" in html and "id='fig1'" in html  # deterministic ids


def _sim_session(tmp_path, sim, **state):
    # The session holds the written files' text, as an upload of them would: the written
    # setup.json carries the simulation's provenance, which the report's input digests see.
    d = tmp_path / "data"
    sim.write(d)
    return d, _session(sources=A.inline_sources(_written(d)), **state)


def _written(d):
    return A.DataSources("simulated", (A.DataFile("measurements.csv", str(d / "measurements.csv")),),
                         A.DataFile("setup.json", str(d / "setup.json")),
                         A.DataFile("certificate.csv", str(d / "certificate.csv")))


def test_simulated_hidden_effect_app_and_cli_byte_identical(tmp_path, capsys):
    """A plate sag hidden in simulated data, with the diagnosis in the report: the
    session record and a record naming the written files by path give the same bytes."""
    sim = simulated("pitch100_4pos", 5, effects={"plate_sag": {"uu": -3.0, "uv": 0.5,
                                                               "vv": -2.0}})
    d, state = _sim_session(tmp_path, sim, diag_on=True)
    record = session_record(state)
    app_html = rep.analysis_report(record)
    by_path = dataclasses.replace(record, data=_written(d))
    path = tmp_path / "ANALYSIS.json"
    path.write_text(A.record_to_json(by_path, relative_to=path.parent))
    assert '"data/measurements.csv"' in path.read_text()
    code, printed = _cli(path, tmp_path / "r.html", capsys)
    assert code == 0, printed.err
    assert _same(app_html, (tmp_path / "r.html").read_text(encoding="utf-8"))
    # the same record one folder down names ../data: refused unless --any-path is given
    below = tmp_path / "rec" / "ANALYSIS.json"
    below.parent.mkdir()
    below.write_text(A.record_to_json(by_path, relative_to=below.parent))
    code, printed = _cli(below, tmp_path / "r2.html", capsys)
    assert code == 2 and not (tmp_path / "r2.html").exists()
    assert printed.err.count("\n") == 1 and "'data.measurements[0]': '../data/measurements" \
        ".csv' lies outside the record's folder" in printed.err and "--any-path" in printed.err
    assert main(["report", str(below), "--out", str(tmp_path / "r2.html"), "--any-path"]) == 0
    assert "Diagnosis: candidate effects" in app_html and "plate_sag" in app_html
    assert "The model fails its χ² test" in app_html and "x × Birge (µm)" in app_html


def test_clean_simulation_passes_without_an_inflation_row(tmp_path):
    _, state = _sim_session(tmp_path, simulated("pitch100_4pos", 1))
    res = A.run(session_record(state))
    assert not res.fit.fails_chi2_test
    html = rep.render(res)
    assert "χ² test passed" in html and "passes at 1 %" in html
    assert "Birge (µm)" not in html and "u × Birge" not in html
    assert "fails its χ² test" not in html


@pytest.mark.parametrize("doc, needle", [
    ({"sigma": 0.5}, "did you mean 'sigma_um'"),
    ({"exclude_outlier": True}, "did you mean 'exclude_outliers'"),
    ({"order": "two"}, "order must be a whole number 1-5, found \"two\""),
])
def test_cli_refuses_a_bad_record_in_one_line(doc, needle, tmp_path, capsys):
    base = json.loads(SAMPLE.read_text())
    base["data"]["measurements"] = [{"path": str(SAMPLE.parent / m["path"])}
                                    for m in base["data"]["measurements"]]
    base["data"]["setup"] = str(SAMPLE.parent / "../thesis/setup.json")
    base["data"]["certificate"] = None
    path = tmp_path / "ANALYSIS.json"
    path.write_text(json.dumps({**base, **doc}))
    code, printed = _cli(path, tmp_path / "r.html", capsys)
    assert code == 2 and not (tmp_path / "r.html").exists()
    err = printed.err.strip()
    assert "\n" not in err and "ANALYSIS.json" in err and needle in err
    assert "Traceback" not in err


def test_cli_report_exit_codes(tmp_path, capsys):
    code, printed = _cli(tmp_path / "missing.json", tmp_path / "r.html", capsys)
    assert code == 2 and "missing.json" in printed.err
    with pytest.raises(SystemExit) as exc:  # --out is required: argparse's usage error
        main(["report", str(SAMPLE)])
    assert exc.value.code == 2 and "--out" in capsys.readouterr().err
    code, printed = _cli(SAMPLE, tmp_path / "no_such_dir" / "r.html", capsys)
    assert code == 2 and printed.err.count("\n") == 1 and "no_such_dir" in printed.err


def test_report_with_an_instrument_app_and_cli_byte_identical(tmp_path, capsys):
    """A laser run fitted with the plate: the session record (file text) and a record
    naming the files by path give the same bytes, with the instruments section."""
    sim, ins = ROOT / "sample_data" / "simulated", ROOT / "sample_data" / "instruments"
    files = A.DataSources(
        "simulated sample",
        (A.DataFile("measurements.csv", content=(sim / "measurements.csv").read_text()),),
        A.DataFile("setup.json", content=(sim / "setup.json").read_text()),
        A.DataFile("certificate.csv", content=(sim / "certificate.csv").read_text()))
    record = session_record(_session(
        sources=files, instruments=[("laser", "laser_x.csv", (ins / "laser_x.csv").read_text())]))
    app_html = rep.analysis_report(record)
    by_path = dataclasses.replace(record, data=A.DataSources(
        "simulated sample", (A.DataFile("measurements.csv", str(sim / "measurements.csv")),),
        A.DataFile("setup.json", str(sim / "setup.json")),
        A.DataFile("certificate.csv", str(sim / "certificate.csv")),
        (A.InstrumentFile("laser", A.DataFile("laser_x.csv", str(ins / "laser_x.csv"))),)))
    path = tmp_path / "ANALYSIS.json"
    path.write_text(A.record_to_json(by_path, relative_to=tmp_path))
    assert '"kind": "laser"' in path.read_text()
    # the record names the sample data where they are: outside its folder
    code, printed = _cli(path, tmp_path / "r.html", capsys, "--any-path")
    assert code == 0, printed.err
    assert _same(app_html, (tmp_path / "r.html").read_text(encoding="utf-8"))
    assert "Instruments fitted with the plate" in app_html
    assert "x_straight_y_y100_z50" in app_html and "RMS residual/u" in app_html

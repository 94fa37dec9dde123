"""The data of an analysis as sources (issue 36, one dataset): the upload's assembly in the
core (every problem of every file, the notes), the thesis and simulated sources, and their
round trip through a record and a project file."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import THESIS

from cmm_core import analysis as A
from cmm_core.io import load_dataset, thesis_dataset
from cmm_core.model import simulate


def _thesis_upload():
    meas = [(f"{p}.csv", (THESIS / f"{p}.csv").read_bytes())
            for p in ("BP111", "BP112", "BP211", "BP212", "BP311", "BP312")]
    return (meas, ("setup.json", (THESIS / "setup.json").read_bytes()),
            ("certificate.csv", (THESIS / "certificate.csv").read_bytes()))


def test_the_thesis_sources_load_the_thesis_dataset():
    ds = A.load_sources(A.thesis_sources())
    ref = thesis_dataset()
    # the same files read by the same reader: the same numbers, bit for bit
    np.testing.assert_array_equal(ds.meas[["mx_mm", "my_mm", "mz_mm"]].to_numpy(),
                                  ref.meas[["mx_mm", "my_mm", "mz_mm"]].to_numpy())
    assert ds.positions == ref.positions and ds.name == "thesis tables 6.1-6.6"


def test_an_upload_of_the_thesis_files_assembles_to_the_thesis_data():
    meas, setup, cert = _thesis_upload()
    got = A.assemble_upload(meas, setup, cert, name="mine")
    assert got.ok and got.problems == () and got.sources.name == "mine"
    assert got.setup_source == "setup.json (uploaded)"
    assert A.sources_key(got.sources) != A.sources_key(A.thesis_sources())  # another name
    np.testing.assert_array_equal(A.load_sources(got.sources).meas["mz_mm"],
                                  thesis_dataset().meas["mz_mm"])


def test_every_problem_of_every_file_is_a_row_naming_file_row_and_column():
    meas, setup, cert = _thesis_upload()
    bad = meas[0][1].decode().splitlines()
    bad[3] = bad[3].replace(bad[3].split(",")[1], "abc", 1)  # a number that is no number
    got = A.assemble_upload([(meas[0][0], "\n".join(bad).encode()), meas[1], meas[1]],
                            ("setup.json", b"{not json"), cert)
    assert not got.ok and got.sources is None
    files = {p.file for p in got.problems}
    assert {"BP111.csv", "BP112.csv", "setup.json"} <= files
    (cell,) = [p for p in got.problems if p.file == "BP111.csv"]
    assert cell.row == 4 and cell.column == "x_mm"
    assert any("uploaded twice" in p.problem for p in got.problems)
    assert got.n_problems == len(got.problems)


def test_the_thesis_setup_stands_in_only_for_positions_it_knows():
    meas, _setup, _cert = _thesis_upload()
    ok = A.assemble_upload(meas[:2], use_thesis=True)
    assert ok.ok and any("stands in" in n for n in ok.notes)
    assert ok.certificate_source.startswith("thesis certificate (stand-in")
    renamed = [("Q1.csv", meas[0][1])]
    refused = A.assemble_upload(renamed, use_thesis=True)
    assert not refused.ok
    assert any("does not know position(s) Q1" in p.problem for p in refused.problems)
    none = A.assemble_upload(meas[:1])
    assert [p.problem for p in none.problems] == ["no setup given."]


def test_a_file_of_another_tool_is_named_with_the_hint_given(tmp_path):
    from test_msl import msl_files_of, simulated_machine

    sim, _coef = simulated_machine("fixed_bridge_xfyz")
    snapshot, _meta = msl_files_of(sim, tmp_path, "simulated", "fixed_bridge_xfyz")[0]
    name = Path(snapshot).name
    got = A.assemble_upload([(name, Path(snapshot).read_bytes())], use_thesis=True,
                            foreign_hint="use the other tab.")
    (p,) = [p for p in got.problems if p.file == name]
    assert "MSL cmm-error-map" in p.problem and p.hint == "use the other tab."


def test_a_certificate_statement_replaces_the_setups_and_is_said():
    meas, setup, cert = _thesis_upload()
    stmt = {"U_um": [0.26, 0.0019], "k": 2.0, "combine": "quadrature", "source": "here"}
    got = A.assemble_upload(meas, setup, cert, certificate_statement=stmt)
    assert got.ok
    assert json.loads(got.sources.setup.text())["certificate"] == stmt
    assert any("U(k=2) = 0.26 ⊕ 0.0019·L µm" in n for n in got.notes)


@pytest.mark.parametrize("seed", [1, 7])
def test_simulated_sources_hold_the_simulation_without_a_folder(seed):
    """The simulator's dataset written to text in memory and read back: the same
    coordinates to the files' 1 nm (six decimals of mm)."""
    sim = simulate({"seed": seed, "noise_um": 0.3})
    src = A.simulated_sources(sim.dataset, f"sim {seed}")
    back = A.load_sources(src)
    np.testing.assert_allclose(back.meas[["x_mm", "y_mm", "z_mm"]].to_numpy(),
                               sim.dataset.meas[["x_mm", "y_mm", "z_mm"]].to_numpy(),
                               atol=5e-7, rtol=0)
    np.testing.assert_allclose(back.certificate.xyz_mm, sim.dataset.certificate.xyz_mm,
                               atol=5e-7, rtol=0)


def test_a_record_of_sources_round_trips_through_a_project_file():
    src = A.thesis_sources()
    rec = A.record_from_sources(src, spec="kinematic21,plate_sag", order=2)
    back = A.record_from_project(A.record_to_project_json(rec), "p.json")
    assert A.sources_key(A.inline_sources(back.data)) == A.sources_key(src)
    assert back.spec == "kinematic21,plate_sag"


def test_inline_sources_read_a_file_named_by_path_once(tmp_path):
    path = tmp_path / "setup.json"
    path.write_text((THESIS / "setup.json").read_text())
    src = A.DataSources("p", A.thesis_sources().measurements, A.DataFile("setup.json", str(path)))
    inline = A.inline_sources(src)
    path.unlink()  # the session's copy no longer needs the file
    ds = A.load_sources(inline)
    ref = load_dataset([(io.StringIO((THESIS / f"{p}.csv").read_text()), f"{p}.csv")
                        for p in ds.positions], THESIS / "setup.json")
    np.testing.assert_array_equal(ds.meas["mx_mm"], ref.meas["mx_mm"])

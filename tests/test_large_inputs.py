"""Bounded memory for large inputs (issue 25): ``compensate`` streamed a chunk at a time
gives what the whole-file path gives, byte for byte, with the same refusals and rows;
laser runs' nuisances eliminated without an m × m matrix; instrument files beyond the
stated size refused in one line; the fit's blocks in placement order give the same
normal equations. Speed is measured in ``bench/`` (bench/compensate.py, bench/fit.py),
not here."""

import dataclasses
import io
import os
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cmm_core.export import compensate, load_model, read_points
from cmm_core.io import MAX_MEASUREMENT_ROWS, DataError, read_measurements
from cmm_core.model import LaserRun, Problem, parse_spec, select, simulate
from cmm_core.model import instruments as ins
from cmm_core.model import normal as normal_module

GOOD = Path(__file__).resolve().parent / "corpus" / "good_model.json"


@pytest.fixture(scope="module")
def model():
    return load_model(GOOD)


def _points(model, n, seed=0):
    rng = np.random.default_rng(seed)
    pts = pd.DataFrame(rng.uniform(0.1, 0.9, (n, 3)) * np.asarray(model.terms.range_mm),
                       columns=["x_mm", "y_mm", "z_mm"]).round(4)
    pts["probe"] = rng.choice(list(model.probes_mm), n)
    return pts


def _whole(model, path):
    """The previous path: the file read whole, corrected, written by pandas."""
    return compensate(model, read_points(path)).to_csv(index=False, float_format="%.6f")


def _streamed(model, path, tmp_path, chunk_points=7, **kw):
    out = tmp_path / "out.csv"
    summary = compensate(model, path, out=out, chunk_points=chunk_points, **kw)
    return _table(out.read_text(encoding="utf-8")), summary


def _table(text):
    """The output's table after its provenance lines (``# software: ...`` first)."""
    assert text.startswith("# software: cmm-error-lab")
    return "".join(line for line in text.splitlines(keepends=True) if not line.startswith("# "))


def test_streamed_equals_whole_file_through_every_reading_path(model, tmp_path):
    """Chunks of 7 rows over a file with blank lines, CRLF line ends, a quoted cell with a
    comma and a line end inside, and a note column: the streamed output is the whole-file
    output byte for byte (chunks cut outside quotes, rows numbered in the file)."""
    pts = _points(model, 60)
    pts["note"] = [f"n{i}" for i in range(60)]
    pts.loc[9, "note"] = 'a "quoted", note'
    pts.loc[23, "note"] = "two\nlines"
    text = pts.to_csv(index=False, lineterminator="\r\n")
    lines = text.split("\r\n")
    lines.insert(15, "")
    lines.insert(40, " , , , , ")
    path = tmp_path / "points.csv"
    path.write_bytes("\r\n".join(lines).encode())
    got, summary = _streamed(model, path, tmp_path)
    assert got == _whole(model, path)
    assert summary["n_points"] == 60


def test_streamed_equals_whole_file_with_semicolons_and_decimal_commas(model, tmp_path):
    pts = _points(model, 30)
    path = tmp_path / "points.csv"
    path.write_text(pts.to_csv(index=False, sep=";", decimal=","), encoding="utf-8")
    got, _ = _streamed(model, path, tmp_path, chunk_points=4)
    assert got == _whole(model, path)


def test_a_bad_cell_in_a_later_chunk_is_refused_at_its_file_row(model, tmp_path):
    """The same message (file, row, column) as the whole-file reader's, and no output:
    the temporary file is removed, an existing output kept."""
    pts = _points(model, 50).astype(object)
    pts.loc[37, "y_mm"] = "12,5mm"
    path = tmp_path / "points.csv"
    pts.to_csv(path, index=False)
    with pytest.raises(DataError) as whole:
        read_points(path)
    out = tmp_path / "out.csv"
    out.write_text("previous result\n")
    with pytest.raises(DataError) as streamed:
        compensate(model, path, out=out, chunk_points=5)
    assert str(streamed.value) == str(whole.value)
    assert "row 39" in str(streamed.value)  # header row 1, data from row 2
    assert out.read_text() == "previous result\n"
    assert sorted(os.listdir(tmp_path)) == ["out.csv", "points.csv"]


def test_an_unknown_probe_in_a_later_chunk_names_its_row(model, tmp_path):
    pts = _points(model, 40)
    pts.loc[33, "probe"] = "nope"
    path = tmp_path / "points.csv"
    pts.to_csv(path, index=False)
    with pytest.raises(DataError, match="row 35.*nope|nope.*row 35"):
        compensate(model, path, out=tmp_path / "out.csv", chunk_points=6)


def test_points_in_metres_are_refused_over_the_whole_file(model, tmp_path):
    """Every coordinate within 2 mm of the origin is the whole file's property: refused
    after the last chunk, before the output is renamed into place."""
    pts = _points(model, 30)
    pts[["x_mm", "y_mm", "z_mm"]] /= 1000.0
    path = tmp_path / "points.csv"
    pts.to_csv(path, index=False)
    with pytest.raises(DataError, match="metres"):
        compensate(model, path, out=tmp_path / "out.csv", chunk_points=4)
    assert sorted(os.listdir(tmp_path)) == ["points.csv"]


def test_points_off_the_machine_in_later_chunks_are_counted_and_flagged(model, tmp_path):
    pts = _points(model, 40)
    pts.loc[[12, 31], "x_mm"] = 1e5
    path = tmp_path / "points.csv"
    pts.to_csv(path, index=False)
    with pytest.raises(DataError, match="2 points lie outside") as exc:
        compensate(model, path, out=tmp_path / "out.csv", allow_extrapolation=False,
                   chunk_points=5)
    assert "row 14" in str(exc.value)
    flagged = pd.read_csv(io.StringIO(_table((tmp_path / "out.csv").read_text())),
                          keep_default_na=False)["extrapolated"]
    assert list(np.flatnonzero(flagged == "outside the machine's range")) == [12, 31]


def _peak_mb(f):
    tracemalloc.start()
    try:
        f()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_streamed_memory_does_not_grow_with_the_points(model, tmp_path):
    """Four times the points, chunks of 500: the traced peak (numpy's and pandas'
    allocations included; 1.3 MB for both sizes when written) grows by less than a
    third, and stays below half of what the whole-file path's Jacobian alone takes for
    20,000 points (3 × 33 doubles each: 16 MB)."""
    peaks = []
    for n in (5_000, 20_000):
        path = tmp_path / f"p{n}.csv"
        _points(model, n).to_csv(path, index=False)
        out = tmp_path / f"o{n}.csv"
        peaks.append(_peak_mb(lambda p=path, o=out: compensate(model, p, out=o,
                                                               chunk_points=500)))
    assert peaks[1] < 1.33 * peaks[0], peaks
    assert peaks[1] < 8, peaks


# --- laser runs ---------------------------------------------------------------------------

def _dense_rows(run, d):
    """The rows of eq. 1 as the release before issue 25 formed them: per run the complete
    Q of the weighted nuisance columns, its last m - k columns transposed."""
    out = []
    for k in range(len(run.runs)):
        sel = np.flatnonzero(run.run == k)
        a = run.axis[sel[0]]
        cols = [np.ones(sel.size)]
        if run.component[sel[0]] != a:
            u = run.r_mm[sel, a]
            cols.append((u - u.mean()) / max(np.ptp(u), 1e-9))
        V = np.column_stack(cols)
        w = 1.0 / run.u_um[sel]
        Q = np.linalg.qr(w[:, None] * V, mode="complete")[0]
        out.append(Q[:, V.shape[1]:].T @ (w * d[sel]))
    return np.concatenate(out)


def test_laser_rows_by_reflectors_equal_the_complete_q():
    """Two runs (positioning, straightness) in one file, interleaved: the reflectors give
    the χ² of the complete Q's rows to round-off (1e-12 relative), Q has orthonormal
    columns (T W⁻¹ Q = I), and T acts on a Jacobian's columns as on each column."""
    sim = simulate({"seed": 2})
    xs = np.linspace(0.0, 1200.0, 40)
    a = ins.simulate_laser(sim, "x", [0, 100, 50], xs, u_um=0.2, seed=1, run="pos")
    b = ins.simulate_laser(sim, "x", [0, 300, 50], xs, component="z", u_um=0.3, seed=2,
                           run="str")
    order = np.argsort(np.r_[np.arange(40), np.arange(40) + 0.5])  # interleaved readings

    def cat(f):
        return np.concatenate([getattr(a, f), getattr(b, f)])[order]

    run = LaserRun("laser.csv", cat("rows"), np.r_[np.zeros(40, int), np.ones(40, int)][order],
                   ("pos", "str"), cat("axis"), cat("component"), cat("r_mm"), cat("p_mm"),
                   cat("error_um"), cat("u_um"))
    d = np.random.default_rng(3).normal(0, 1, 80)
    T, Q = run.transform
    assert T.shape == (80 - 1 - 2, 80) and Q.shape == (80, 77)
    want = _dense_rows(run, d)
    # rows within a run are determined up to the order of the basis: compare the norms
    # per run, and the projection Q T d, which is basis-free
    assert np.isclose(np.sum((T @ d) ** 2), np.sum(want ** 2), rtol=1e-12)
    z = np.random.default_rng(4).normal(0, 1, 77)
    # T = Q2ᵀ W and Q = Q2 with orthonormal columns: T (W⁻¹ Q z) = z
    np.testing.assert_allclose(T @ ((Q @ z) * run.u_um), z, atol=1e-12)
    J = np.random.default_rng(5).normal(0, 1, (80, 6))
    np.testing.assert_allclose(T @ J, np.column_stack([T @ J[:, j] for j in range(6)]),
                               atol=1e-12)


def test_an_instrument_file_beyond_the_stated_size_is_refused_in_one_line():
    """One reading more than ``MAX_INSTRUMENT_READINGS`` (the readers' limit too), built
    in code: refused when the problem is built, naming the file and the limit, before
    any Jacobian is evaluated."""
    from cmm_core.model import MAX_INSTRUMENT_READINGS

    sim = simulate({"seed": 1})
    m = MAX_INSTRUMENT_READINGS + 1
    xs = np.linspace(0.0, 1200.0, m)
    big = ins.simulate_laser(sim, "x", [0, 100, 50], xs, u_um=0.2, seed=1,
                             source="huge_laser.csv")
    obs = dataclasses.replace(select(sim.dataset), instruments=(big,))
    with pytest.raises(DataError) as exc:
        Problem(obs, parse_spec("kinematic21"), "fixed")
    msg = str(exc.value)
    assert "huge_laser.csv" in msg and f"{m:,} readings" in msg
    assert f"{MAX_INSTRUMENT_READINGS:,}" in msg and "\n" not in msg


# --- the fit's blocks ---------------------------------------------------------------------

def test_normal_equations_of_observations_out_of_block_order():
    """A tiled table (placements interleaved, as concatenated files give): blocks of 500
    rows in placement order, reordered once and kept, give the normal equations of one
    block of all rows, on the first accumulation and on the next (the kept order)."""
    ds = simulate({"seed": 1, "repeats": 4}).dataset
    meas = pd.concat([ds.meas] * 3, ignore_index=True)
    data = dataclasses.replace(ds, meas=meas.sample(frac=1.0, random_state=1)
                               .reset_index(drop=True))
    prob = Problem(select(data), parse_spec("kinematic21"), "fixed")
    st = prob.initial_state()
    one = normal_module.accumulate(prob, st, 1.0, rows=10 ** 9)
    for _ in range(2):
        blocks = normal_module.accumulate(prob, st, 1.0, rows=500)
        np.testing.assert_allclose(blocks.N, one.N, rtol=1e-10, atol=1e-9 * np.abs(one.N).max())
        np.testing.assert_allclose(blocks.g, one.g, rtol=1e-10, atol=1e-9 * np.abs(one.g).max())
        np.testing.assert_array_equal(blocks.d, one.d)
        assert np.isclose(blocks.cost, one.cost, rtol=1e-12)


def test_a_million_readings_are_refused_at_the_limit_in_bounded_memory(tmp_path):
    """A 10⁶-row measurement file (51 MB) is refused at the first row beyond ``MAX_MEASUREMENT_ROWS``, naming
    that row, and the reader's peak memory stays within three times the file's size
    (it held a StringIO of four bytes per character and every line split, 7.7 times,
    before): the rest of the file is never parsed into cells."""
    path = tmp_path / "million.csv"
    path.write_bytes(b"position,probe,ball,x_mm,y_mm,z_mm,time_min\n"
                     + b"BP111,1,1,333.999306,233.998938,-0.001962,0.000000\n" * 10**6)
    tracemalloc.start()
    try:
        with pytest.raises(DataError) as exc:
            read_measurements(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert f"more than {MAX_MEASUREMENT_ROWS} data rows (row {MAX_MEASUREMENT_ROWS + 2} " \
        in str(exc.value) and "million.csv" in str(exc.value)
    assert peak < 3 * path.stat().st_size, peak


_PEAK_RSS = """import resource, sys
from cmm_core.cli import main
code = main(sys.argv[1:])
sys.stderr.write(f"\\npeak_kb={resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}\\n")
sys.exit(code)
"""


def _diagnose_peak(folder: Path, meas: Path, out: Path) -> tuple[int, str, int]:
    """``diagnose`` of ``meas`` in a process of its own, its result to ``out``: exit code,
    stderr, peak RSS (kB)."""
    args = [sys.executable, "-c", _PEAK_RSS, "diagnose", str(meas), "--setup",
            str(folder / "setup.json"), "--certificate", str(folder / "certificate.csv"),
            "--json", str(out)]
    done = subprocess.run(args, capture_output=True, text=True, timeout=600)
    peak = int(done.stderr.rsplit("peak_kb=", 1)[1])
    return done.returncode, done.stderr.rsplit("\npeak_kb=", 1)[0], peak


def test_a_diagnosis_beyond_its_limit_is_refused_before_any_fit(tmp_path):
    """The sample simulation's 300 readings repeated to 1.5 × ``diagnosis.MAX_READINGS``
    (each repeat numbered): refused in one line naming the file and the limit, exit 2, at
    a peak memory within 150 MB of the 300-reading diagnosis's own (reading 30 000 rows
    costs about 30 MB; diagnosing them would cost about 0.8 GB more, 26 kB a reading)."""
    from cmm_core.diagnosis import MAX_READINGS

    sample = Path(__file__).resolve().parents[1] / "sample_data" / "simulated"
    lines = (sample / "measurements.csv").read_text(encoding="utf-8").splitlines()
    body = lines[1:]
    n = int(1.5 * MAX_READINGS)
    rows = [f"{body[i % len(body)]},{i // len(body)}" for i in range(n)]
    big = tmp_path / "big.csv"
    big.write_text("\n".join([lines[0] + ",repeat", *rows]) + "\n", encoding="utf-8")
    code, err, peak = _diagnose_peak(sample, big, tmp_path / "big.json")
    assert code == 2, err
    assert err.strip() == (
        f"error: big.csv: {n} probed ball centres; a diagnosis takes at most {MAX_READINGS} "
        "(it holds every candidate's Jacobian in memory, about 26 kB a reading). Hint: "
        "diagnose fewer placements or styli (positions=, probes=), or average repeated "
        "readings of a ball.")
    code0, err0, peak0 = _diagnose_peak(sample, sample / "measurements.csv",
                                        tmp_path / "small.json")
    assert code0 == 0, err0
    assert peak < peak0 + 150_000, (peak, peak0)

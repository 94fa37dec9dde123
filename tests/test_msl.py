"""The MSL cmm-error-map reader (cmm_core.io.msl): files written here in MSL's format from
this project's own simulator, read back and fitted; each convention pinned by a
hand-computed value; bad files refused naming file, row and column."""

from __future__ import annotations

import io
import math

import numpy as np
import pandas as pd
import pytest

from cmm_core.io import DataError, msl, read_machine
from cmm_core.model import (
    fit,
    instrument_observations,
    read_instrument,
    simulate,
    simulate_step_gauge,
)

RANGE = [800.0, 600.0, 600.0]
PITCH = 110.0
# MSL-style linear parameters (power-series slope: mm/mm for T, rad/mm for R)
MSL_TRUTH = {"Txx": 1.33e-05, "Tyx": -1.12e-05, "Tyy": -5.09e-06, "Tzx": 2.6e-05,
             "Tzy": 4.6e-06, "Tzz": 3.34e-08, "Rxx": 7.49e-09, "Rxy": 1.54e-08,
             "Rxz": 5e-09, "Ryx": -4.58e-09, "Ryy": -1.43e-08, "Ryz": 2.19e-08,
             "Rzx": 2.49e-09, "Rzy": -7.94e-10, "Rzz": 4.78e-08}
POSITIONS = {  # tip centre of ball 1, plate axes, probe
    "XY": ([150.0, 50.0, 100.0], [1, 0, 0], [0, 1, 0], "1"),
    "XZ": ([150.0, 300.0, 20.0], [1, 0, 0], [0, 0, 1], "2"),
    "YZ": ([400.0, 60.0, 20.0], [0, 1, 0], [0, 0, 1], "3"),
}
PROBES = {"1": [0.0, 0.0, -100.0], "2": [0.0, 100.0, -60.0], "3": [100.0, 0.0, -60.0]}
FLAGS = {v: k for k, v in msl.MSL_LAYOUTS.items()}


# ------------------------------------------------------------------ an MSL-format writer


def _header(title, name, nx, ny, pitch, location, angles):
    return ["save time,2025-01-01 00:00:00.000000", f"title,{title}", f"name,{name}",
            "artefact.title,test plate", f"artefact.nballs,{nx},{ny} ",
            f"artefact.ball_spacing,{pitch}",
            "location," + ", ".join(repr(float(v)) for v in location),
            "rotation/deg," + ", ".join(repr(float(v)) for v in angles)]


def _angles(R):
    """(rx, ry, rz) in degrees with R = Rz Ry Rx."""
    return np.degrees([math.atan2(R[2, 1], R[2, 2]), -math.asin(R[2, 0]),
                       math.atan2(R[1, 0], R[0, 0])])


def _realign(tips, nx, ny):
    """MSL's artefact frame: origin ball 0, x through ball nx-1, xy plane through ball
    nx (ny-1)."""
    o = tips[0]
    ex = tips[nx - 1] - o
    ex /= np.linalg.norm(ex)
    ez = np.cross(ex, tips[nx * (ny - 1)] - o)
    ez /= np.linalg.norm(ez)
    return (tips - o) @ np.column_stack([ex, np.cross(ez, ex), ez])


def write_msl(folder, name, plate_xyz, nx, ny, pitch, location, angles, layout, probe,
              params=None):
    """Write snapshot.csv and metadata.csv in MSL's format; returns their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    head = _header(f"Plate {name}", name, nx, ny, pitch, location, angles)
    rows = [f"{k},{x:.5f},{y:.5f},{z:.5f}" for k, (x, y, z) in enumerate(plate_xyz)]
    (folder / "snapshot.csv").write_text("\n".join(head + ["id,mmt_x,mmt_y,mmt_z"] + rows)
                                         + "\n")
    fixed, bridge = FLAGS[layout]
    params = params or {}
    meta = head + ["cmm_model.title,test CMM", "cmm_model.size," + ",".join(
        f"{v:g}" for v in RANGE), f"cmm_model.fixed_table,{fixed}",
        f"cmm_model.bridge_axis,{bridge}", "probe.title,P", f"probe.name,p{name}",
        "probe.length," + ",".join(repr(float(v)) for v in probe), "model parameters"]
    meta += [f"{p},{params.get(p, [0.0, 0.0])}" for p in msl.MSL_PARAMETERS]
    (folder / "metadata.csv").write_text("\n".join(meta) + "\n")
    return folder / "snapshot.csv", folder / "metadata.csv"


def simulated_machine(layout):
    """This project's simulator with MSL_TRUTH on ``layout``, noise-free: the dataset and
    the truth as this project's coefficients."""
    coef = msl.msl_coefficients(MSL_TRUTH, layout, RANGE, order=1)
    setup = {"units": "mm", "frame": "machine",
             "machine": {"layout": layout, "range_mm": RANGE},
             "positions": {p: {"origin_mm": o, "u_axis": u, "v_axis": v, "probe": q}
                           for p, (o, u, v, q) in POSITIONS.items()},
             "probes": PROBES}
    sim = simulate({"seed": 1, "noise_um": 0.0, "setup": setup,
                    "kinematic": {"spec": "kinematic21", "order": 1, "random_um": 0.0,
                                  "random_urad": 0.0, "coefficients": coef},
                    "plate": {"rows": 5, "cols": 5, "pitch_mm": PITCH, "form_um": 0.0,
                              "certificate_u_um": 0.0},
                    "order": "row"})
    return sim, coef


def msl_files_of(sim, folder, kind, layout):
    """One MSL snapshot + metadata per position of ``sim``: indicated coordinates
    (``measured``) or nominal + (true - indicated) (``simulated``)."""
    meas, setup = sim.dataset.meas, sim.dataset.setup
    nominal = sim.true_plate_mm
    out = []
    for pos, pl in setup.positions.items():
        g = meas[meas["position"] == pos].sort_values("ball")
        tips = g[["mx_mm", "my_mm", "mz_mm"]].to_numpy()
        plate = _realign(tips, 5, 5)
        if kind == "simulated":
            plate = 2 * nominal - plate
        probe = setup.probes[pl.probe]
        out.append(write_msl(folder / pos, pos, plate, 5, 5, PITCH, pl.origin_mm - probe,
                             _angles(pl.rotation), layout, probe, MSL_TRUTH))
    return out


CERT_U = {"U_um": [0.01, 0.0], "k": 2, "combine": "quadrature"}


@pytest.mark.parametrize("layout,kind", [
    ("fixed_bridge_xfyz", "simulated"), ("fixed_bridge_yfxz", "measured"),
    ("moving_bridge_fxyz", "measured"), ("moving_bridge_fyxz", "simulated")])
def test_files_written_from_the_simulator_fit_back_to_the_truth(tmp_path, layout, kind):
    sim, truth = simulated_machine(layout)
    files = msl_files_of(sim, tmp_path, kind, layout)
    cu = None if kind == "simulated" else CERT_U
    parts = [msl.read_msl_plate(s, m, kind=kind, certificate_u=cu) for s, m in files]
    assert parts[0].setup["machine"]["layout"] == layout
    ds = msl.combine_plates(parts).to_dataset()
    assert ds.positions == list(POSITIONS)
    res = fit(ds, "kinematic21", order=1, plate="fixed", sigma_um=msl.MSL_ROUNDING_U_UM)
    assert res.status == "converged"
    assert res.chi2_dof < 2.0  # the model at the truth explains the files to their rounding
    # one stylus per placement: the z carriage's rotations act on the stylus only and,
    # with its scale and the z squareness, form combinations these placements cannot split
    undetermined = {lab for lab in res.unidentifiable if "." not in lab}
    assert undetermined == {"dzz[1]", "rzx[1]", "rzy[1]", "rzz[1]", "sxz", "syz"}
    got = dict(zip(res.labels, res.values, strict=False))
    unc = dict(zip(res.labels, res.u, strict=False))
    for lab in set(truth) - undetermined:
        assert abs(got[lab] - truth[lab]) < max(5 * unc[lab], 0.01), (lab, got[lab], truth[lab])


def test_one_plate_determines_the_table_scale_and_names_what_it_cannot(tmp_path):
    sim, truth = simulated_machine("fixed_bridge_xfyz")
    s, m = msl_files_of(sim, tmp_path, "simulated", "fixed_bridge_xfyz")[1]  # XZ plate
    res = fit(msl.read_msl_plate(s, m, kind="simulated").to_dataset(), "kinematic21",
              order=1, plate="fixed", sigma_um=msl.MSL_ROUNDING_U_UM)
    got = dict(zip(res.labels, res.values, strict=False))
    for lab in ("dxx[1]", "rxx[1]", "rxy[1]", "rxz[1]"):  # the table's, seen along x and z
        assert lab not in res.unidentifiable
        assert abs(got[lab] - truth[lab]) < 0.02
    assert {"dyy[1]", "ryy[1]", "sxy"} <= set(res.unidentifiable)
    assert res.null_combinations


# ------------------------------------------------------------------ conventions by hand


def _plate_files(tmp_path, rows=None, location=(100.0, 200.0, 300.0), angles=(0, 0, 0),
                 probe=(0.0, 0.0, -150.0), layout="moving_bridge_fxyz", nx=5, ny=5):
    xyz = msl._grid(nx, ny, 133.0) if rows is None else rows
    return write_msl(tmp_path, "t", xyz, nx, ny, 133.0, location, angles, layout, probe)


def test_origin_is_location_plus_probe(tmp_path):
    ds = msl.read_msl_plate(*_plate_files(tmp_path), kind="simulated")
    assert ds.setup["positions"]["t"]["origin_mm"] == [100.0, 200.0, 150.0]
    first = pd.read_csv(io.StringIO(ds.measurements_csv)).iloc[0]
    assert (first["ball"], first["x_mm"], first["y_mm"], first["z_mm"]) == (1, 100, 200, 150)
    assert any(n.startswith("origin: ") for n in ds.notes)


@pytest.mark.parametrize("angles,u,v", [
    ((90, 0, 0), [1, 0, 0], [0, 0, 1]),      # MSL's "Plate XZ"
    ((90, 0, 90), [0, 1, 0], [0, 0, 1]),     # a YZ plate
    ((0, 90, 90), [0, 0, -1], [-1, 0, 0]),   # Rz Ry Rx, not Rx Ry Rz (that gives u = +y)
])
def test_angles_are_rz_ry_rx_in_degrees(tmp_path, angles, u, v):
    ds = msl.read_msl_plate(*_plate_files(tmp_path, location=(300, 300, 300),
                                          angles=angles), kind="simulated")
    pos = ds.setup["positions"]["t"]
    np.testing.assert_allclose(pos["u_axis"], u, atol=1e-12)
    np.testing.assert_allclose(pos["v_axis"], v, atol=1e-12)


def test_ball_numbering_and_sign_of_each_kind(tmp_path):
    xyz = msl._grid(5, 5, 133.0)
    xyz[1] += [0.00108, 0.00082, 0.00027]   # id 1, the second ball of the first row
    xyz[6] += [0.00225, 0.0, 0.0]           # id 6: row 2, column 2
    files = _plate_files(tmp_path, rows=xyz)
    sim = pd.read_csv(io.StringIO(msl.read_msl_plate(*files, kind="simulated")
                                  .measurements_csv))
    mea = pd.read_csv(io.StringIO(msl.read_msl_plate(*files, kind="measured",
                                                     certificate_u=CERT_U).measurements_csv))
    # ball 2 = id 1, nominal (133, 0, 0) placed at (100, 200, 150)
    row = sim[sim["ball"] == 2].iloc[0]
    assert row["x_mm"] == pytest.approx(100 + 133 - 0.00108, abs=1e-9)  # true - indicated
    assert row["y_mm"] == pytest.approx(200 - 0.00082, abs=1e-9)
    assert mea[mea["ball"] == 2].iloc[0]["x_mm"] == pytest.approx(233.00108, abs=1e-9)
    assert sim[sim["ball"] == 7].iloc[0]["x_mm"] == pytest.approx(233 - 0.00225, abs=1e-9)
    cert = pd.read_csv(io.StringIO(msl.read_msl_plate(*files, kind="simulated")
                                   .certificate_csv))
    assert cert.iloc[6][["ball", "x_mm", "y_mm", "z_mm"]].tolist() == [7, 133, 133, 0]


def test_layout_flags_map_to_the_four_layouts():
    assert msl.msl_layout(False, 1) == "fixed_bridge_xfyz"   # MSL's "old PMM866"
    assert msl.msl_layout(False, 0) == "fixed_bridge_yfxz"   # Mitutoyo Legex
    assert msl.msl_layout(True, 0) == "moving_bridge_fyxz"   # Hexagon Global
    assert msl.msl_layout(True, 1) == "moving_bridge_fxyz"
    with pytest.raises(ValueError, match="bridge_axis"):
        msl.msl_layout(True, 2)


def test_coefficients_flip_odd_powers_of_the_table_and_fold_straightness():
    # +1.2 µm/m on the table x of an 800 mm stroke: dxx(u) = T(-u) = -1.2e-3 µm/mm · u,
    # the Chebyshev coefficient of 2u/800 is -0.48 µm
    c = msl.msl_coefficients({"Txx": [0.0, 1.2e-6]}, "fixed_bridge_xfyz", RANGE)
    assert c["dxx[1]"] == pytest.approx(-0.48)
    assert msl.msl_coefficients({"Txx": 1.2e-6}, "moving_bridge_fxyz", RANGE)["dxx[1]"] == \
        pytest.approx(0.48)
    # 10 µm/m of y motion in x is sxy = 10 µrad; Txy adds to it (up to a rotation)
    c = msl.msl_coefficients({"Tyx": 1e-5, "Txy": 2e-6, "Rzz": 1e-8}, "moving_bridge_fxyz",
                             RANGE)
    assert c["sxy"] == pytest.approx(12.0) and c["rzz[1]"] == pytest.approx(3.0)
    with pytest.raises(ValueError, match="constant"):
        msl.msl_coefficients({"Tyy": [1e-3, 0.0]}, "moving_bridge_fxyz", RANGE)


def test_kind_and_certificate_are_required(tmp_path):
    files = _plate_files(tmp_path)
    with pytest.raises(DataError, match="simulated or measured") as exc:
        msl.read_msl_plate(*files)
    assert "\n" not in str(exc.value) and "snapshot.csv" in str(exc.value)
    with pytest.raises(DataError, match="certificate_u"):
        msl.read_msl_plate(*files, kind="measured")
    ds = msl.read_msl_plate(*files, kind="simulated")
    assert ds.setup["certificate"]["exact"] is True
    assert any("exact" in n for n in ds.notes)
    ds = msl.read_msl_plate(*files, kind="measured", certificate_u=CERT_U)
    assert ds.setup["certificate"]["U_um"] == [0.01, 0.0]


def test_bar_becomes_a_step_gauge_file(tmp_path):
    xyz = msl._grid(31, 1, 20.0)
    xyz[:, 0] *= 1 + 1.2e-6  # MSL's deviation of +1.2 µm/m
    xyz = np.round(xyz, 5)
    s, m = write_msl(tmp_path, "bar", xyz, 31, 1, 20.0, (0, 0, 0), (0, 0, 0),
                     "fixed_bridge_xfyz", (0.0, 0.0, 0.0), {"Txx": [0.0, 1.2e-6]})
    bar = msl.read_msl_bar(s, m, kind="simulated")
    sg = read_instrument(io.BytesIO(bar.step_gauge_csv.encode()), "step_gauge")
    assert len(sg.measured_mm) == 30
    assert sg.measured_mm[-1] == pytest.approx(600 - 0.00072, abs=1e-9)
    assert sg.certified_mm[-1] == 600.0
    slope = np.polyfit(sg.certified_mm, sg.measured_mm - sg.certified_mm, 1)[0]
    assert slope * 1e6 == pytest.approx(-1.2, abs=0.01)  # indicated - true, µm/m
    assert any("needs no plate" in n for n in bar.notes)
    with pytest.raises(DataError, match="read_msl_bar"):
        msl.read_msl_plate(s, m, kind="simulated")
    with pytest.raises(DataError, match="read_msl_plate"):
        msl.read_msl_bar(*_plate_files(tmp_path / "p"), kind="simulated")


@pytest.mark.parametrize("kind", msl.MSL_KINDS)
def test_a_bar_written_from_the_simulator_gives_its_x_scale_alone(tmp_path, kind):
    """A step gauge of 31 balls at 20 mm along x, measured by this project's simulator on
    a machine whose only error is an x scale of −1.2 µm/m (MSL's validation bar's figure),
    written in MSL's bar format, read back by ``read_msl_bar`` and fitted without a plate.

    Hand reference: ``dxx = c1·2x/R`` (order 1, ``machine.terms.basis``), so the scale is
    ``2000 c1 / R`` µm/m; lengths k·20 mm, k = 1..30, each rounded by the file to 0.01 µm
    (u = 0.01/√12 µm): a slope through the origin has ``u = u_L / √ΣL²`` = 0.0015 µm/m,
    the figure MSL's file gives."""
    scale_um_per_m = -1.2
    c1 = scale_um_per_m * RANGE[0] / 2000.0
    setup = {"units": "mm", "frame": "machine",
             "machine": {"layout": "fixed_bridge_xfyz", "range_mm": RANGE},
             "positions": {p: {"origin_mm": o, "u_axis": u, "v_axis": v, "probe": q}
                           for p, (o, u, v, q) in POSITIONS.items()},
             "probes": PROBES}
    sim = simulate({"seed": 1, "noise_um": 0.0, "setup": setup,
                    "kinematic": {"spec": "kinematic21", "order": 1, "random_um": 0.0,
                                  "random_urad": 0.0, "coefficients": {"dxx[1]": c1}},
                    "plate": {"form_um": 0.0, "certificate_u_um": 0.0}})
    probe = np.array([0.0, 0.0, -100.0])
    start = np.array([100.0, 300.0, 150.0])  # tip centre of ball 1
    lengths = np.arange(1, 31) * 20.0
    sg = simulate_step_gauge(sim, start, start + [600.0, 0, 0], lengths, offset_mm=probe,
                             u_um=0.0, seed=1)
    tips = np.vstack([sg.r1_mm[:1], sg.r2_mm])  # indicated: on the x line (no other error)
    bar = tips - tips[0]  # MSL's bar frame: ball 1 at the origin, x along the bar
    if kind == "simulated":  # nominal + (true - indicated)
        bar = 2.0 * msl._grid(31, 1, 20.0) - bar
    cu = None if kind == "simulated" else {"U_um": [0.0058, 0.0], "k": 2,
                                            "combine": "quadrature"}
    snap, meta = write_msl(tmp_path, "bar", np.round(bar, 5), 31, 1, 20.0, tips[0] - probe,
                           (0, 0, 0), "fixed_bridge_xfyz", probe)
    read = msl.read_msl_bar(snap, meta, kind=kind, certificate_u=cu)
    gauge = read_instrument(io.BytesIO(read.step_gauge_csv.encode()), "step_gauge")
    obs = instrument_observations([gauge], *read_machine(read.setup))
    res = fit(obs, "dxx", order=1, sigma_um=msl.MSL_ROUNDING_U_UM)
    assert res.status == "converged" and res.plate == "none"
    got, u = res.values[0] * 2000.0 / RANGE[0], res.u[0] * 2000.0 / RANGE[0]
    u_hand = 1e3 * gauge.u_um[0] / np.sqrt(lengths @ lengths)
    assert u == pytest.approx(u_hand, rel=1e-3)  # the fit's u is the hand formula's
    assert u == pytest.approx(0.0015, abs=0.0001)
    assert abs(got - scale_um_per_m) < 4 * u  # rounding of 0.01 µm: within 4 u
    # the 21 errors: the bar sees the x scale with its Abbe terms, nothing else
    full = fit(obs, "kinematic21", order=1, sigma_um=msl.MSL_ROUNDING_U_UM)
    alone = {c.split("·")[1] for c in full.null_combinations if c.count("·") == 1}
    assert {"dyy[1]", "dzz[1]", "sxy", "sxz", "syz"} <= alone
    assert "dxx[1]" not in alone and full.rank == 1


def test_snapshots_of_two_artefacts_are_not_one_dataset(tmp_path):
    """One certificate statement is never stretched over two artefacts: snapshots whose
    headers name different artefacts are refused naming the snapshot, the key and the fix;
    two snapshots of one artefact combine, each read with its statement."""
    a = _plate_files(tmp_path / "a")
    b = _plate_files(tmp_path / "b", location=(100.0, 200.0, 350.0))
    same = msl.combine_plates([msl.read_msl_plate(*f, kind="measured", certificate_u=CERT_U,
                                                  snapshot_name=f"{k}.csv")
                               for k, f in (("a", a), ("b", b))])
    assert same.setup["certificate"]["U_um"] == CERT_U["U_um"]
    for path in b:  # the snapshot and the metadata saved with it
        _edit(path, 4, "artefact.title,another plate")
    parts = [msl.read_msl_plate(*f, kind="measured", certificate_u=CERT_U,
                                snapshot_name=f"{k}.csv") for k, f in (("a", a), ("b", b))]
    assert [p.artefact for p in parts] == ["test plate", "another plate"]
    with pytest.raises(DataError, match="one dataset is one plate") as exc:
        msl.combine_plates(parts)
    assert exc.value.file == "b.csv" and exc.value.column == "artefact.title"
    assert "\n" not in str(exc.value)


# ------------------------------------------------------------------ bad files, sniffing


def _edit(path, row, text):
    lines = path.read_text().split("\n")
    lines[row - 1] = text
    path.write_text("\n".join(lines))


def test_bad_cells_are_named_by_file_row_and_column(tmp_path):
    s, m = _plate_files(tmp_path)
    _edit(s, 12, "2,266.0000x,0.00000,0.00000")
    _edit(s, 14, "4,532.00000,0.00000")
    with pytest.raises(DataError) as exc:
        msl.read_msl_plate(s, m, kind="simulated")
    err = exc.value
    assert (err.file, err.row, err.column) == ("snapshot.csv", 12, "mmt_x")
    assert err.n_problems == 2 and err.problems[1].row == 14
    assert "\n" not in str(err)


@pytest.mark.parametrize("row,text,column,match", [
    (10, "1,0.00000,0.00000,0.00000", "id", "expected id 0"),
    (11, "1,134.50000,0.00000,0.00000", "mmt_x", "from its nominal"),
    (5, "artefact.nballs,5,x ", "artefact.nballs", "whole numbers"),
    (2, "titel,x", "title", "not an MSL"),
    (8, "rotation/deg,90, 0", "rotation/deg", "three angles"),
])
def test_bad_snapshots_are_refused(tmp_path, row, text, column, match):
    s, m = _plate_files(tmp_path)
    _edit(s, row, text)
    with pytest.raises(DataError, match=match) as exc:
        msl.read_msl_plate(s, m, kind="simulated")
    assert (exc.value.row, exc.value.column) == (row, column)


def test_short_file_and_foreign_metadata_are_refused(tmp_path):
    s, m = _plate_files(tmp_path)
    s.write_text("\n".join(s.read_text().split("\n")[:20]))
    with pytest.raises(DataError, match="5 × 5 = 25") as exc:
        msl.read_msl_plate(s, m, kind="simulated")
    assert exc.value.column == "id"
    s, m = _plate_files(tmp_path / "b")
    _edit(m, 7, "location,1.0, 2.0, 3.0")
    with pytest.raises(DataError, match="differs from the snapshot") as exc:
        msl.read_msl_plate(s, m, kind="simulated")
    assert (exc.value.file, exc.value.row, exc.value.column) == ("metadata.csv", 7, "location")
    _edit(m, 7, "location,100.0, 200.0, 300.0")
    _edit(m, 11, "cmm_model.fixed_table,maybe")
    with pytest.raises(DataError) as exc:
        msl.read_msl_plate(s, m, kind="simulated")
    assert (exc.value.row, exc.value.column) == (11, "cmm_model.fixed_table")
    with pytest.raises(DataError, match="metadata file, not a snapshot"):
        msl.read_msl_plate(m, m, kind="simulated")
    with pytest.raises(DataError, match="give metadata or layout"):
        msl.read_msl_plate(s, kind="simulated")
    ds = msl.read_msl_plate(s, kind="simulated", layout="moving_bridge_fxyz",
                            range_mm=RANGE, probe_mm=[0, 0, -150])
    assert ds.setup["positions"]["t"]["origin_mm"] == [100.0, 200.0, 150.0]


def test_sniff_names_the_reader_and_leaves_other_files_alone(tmp_path):
    s, m = _plate_files(tmp_path)
    assert "MSL cmm-error-map plate snapshot" in msl.sniff(s)
    assert "read_msl_plate" in msl.sniff(s.read_bytes())
    assert "metadata" in msl.sniff(m)
    full = s.read_text().replace("id,mmt_x,mmt_y,mmt_z", "id,cmm_nom_x,cmm_nom_y,cmm_nom_z,"
                                 "cmm_dev_x,cmm_dev_y,cmm_dev_z,")
    assert "full-data" in msl.sniff(full.encode())
    bar = write_msl(tmp_path / "bar", "b", msl._grid(31, 1, 20.0), 31, 1, 20.0, (0, 0, 0),
                    (0, 0, 0), "fixed_bridge_xfyz", (0, 0, 0))[0]
    assert "read_msl_bar" in msl.sniff(bar)
    assert msl.sniff(b"position,probe,ball,x_mm,y_mm,z_mm\nA,1,1,0,0,0\n") is None
    assert msl.sniff(tmp_path / "missing.csv") is None
    assert msl.sniff(b"\xff\xfe\x00") is None

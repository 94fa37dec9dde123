"""A lab's own machine as its files come (issue 24): the certificate's uncertainty is
never assumed, and long styli are judged by their scale readings on every layout."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from cmm_core.io import THESIS_DIR, DataError, load_dataset, thesis_dataset
from cmm_core.machine import LAYOUTS
from cmm_core.model import fit, simulate, thesis_machine_setup

ROOT = Path(__file__).resolve().parents[1]
SETUP = json.loads((THESIS_DIR / "setup.json").read_text())
CERT_NO_U = (THESIS_DIR / "certificate.csv").read_bytes()  # the thesis file has no u columns
MEAS = [THESIS_DIR / f"{p}.csv" for p in ("BP111", "BP112")]


def _setup(**certificate) -> dict:
    raw = json.loads(json.dumps(SETUP))
    raw.pop("certificate")
    if certificate:
        raw["certificate"] = certificate
    return raw


def _load(setup_bytes, cert_bytes=CERT_NO_U):
    return load_dataset([(p.open("rb"), p.name) for p in MEAS], setup_bytes,
                        (io.BytesIO(cert_bytes), "certificate.csv"))


def test_a_certificate_without_uncertainty_and_no_statement_is_refused_in_one_line():
    with pytest.raises(DataError) as exc:
        _load(_setup())
    msg = str(exc.value)
    assert exc.value.file == "certificate.csv" and exc.value.column == "u_x_um"
    assert "\n" not in msg and '"exact": true' in msg and "U_um" in msg


def test_the_thesis_statement_gives_appendix_1_by_hand():
    """Appendix 1: U(k=2) = sqrt(0.26² + (1.9e-3 L)²) µm. Ball 2 of the certificate lies
    133.0029 mm from ball 1 (x 133.00290, y -0.00227, z 0.02431): U = 0.362574 µm,
    u = 0.181287 µm (hand computation, 6 digits)."""
    data = thesis_dataset()
    assert data.certificate.u_um[0] == pytest.approx([0.13] * 3, abs=1e-9)
    assert data.certificate.u_um[1] == pytest.approx([0.181287] * 3, abs=2e-6)
    assert "thesis appendix 1" in data.certificate.u_source
    assert "U(k=2) = sqrt(0.26² + (0.0019·L)²) µm" in data.certificate.u_source


def test_a_linear_statement_and_its_coverage_factor():
    data = _load(_setup(U_um=[0.5, 0.002], k=3, combine="linear"))
    L = np.linalg.norm(data.certificate.xyz_mm - data.certificate.xyz_mm[0], axis=1)
    assert data.certificate.u_um[:, 2] == pytest.approx((0.5 + 0.002 * L) / 3, rel=1e-12)


def test_an_exact_certificate_carries_no_uncertainty_into_the_fit():
    data = _load(_setup(exact=True, source="noise-free simulation"))
    assert data.certificate.u_um is None and "exact" in data.certificate.u_source
    res = fit(data, "kinematic21", positions=["BP111", "BP112"], sigma_um=0.5)
    stated = fit(_load(_setup(U_um=[0.26, 0.0019], k=2)), "kinematic21",
                 positions=["BP111", "BP112"], sigma_um=0.5)
    # the stated certificate's uncertainty propagates into every parameter: larger u
    assert np.all(np.sqrt(np.diag(stated.covariance)) >= np.sqrt(np.diag(res.covariance))
                  - 1e-12)
    assert np.sqrt(np.diag(stated.covariance)).max() > 1.1 * np.sqrt(
        np.diag(res.covariance)).max()


def test_file_columns_win_over_a_statement_and_say_so():
    sim = simulate({"seed": 3, "noise_um": 0.2})
    cert = sim.dataset.certificate
    text = "ball,x_mm,y_mm,z_mm,u_x_um,u_y_um,u_z_um\n" + "\n".join(
        f"{b},{x:.6f},{y:.6f},{z:.6f},0.1,0.1,0.1" for b, (x, y, z) in zip(
            cert.balls, cert.xyz_mm, strict=True))
    data = _load(_setup(exact=True), text.encode())
    assert data.certificate.u_um == pytest.approx(np.full((25, 3), 0.1))
    assert "u_x_um" in data.certificate.u_source and "not used" in data.certificate.u_source


@pytest.mark.parametrize("bad, column", [
    ({"U_um": [0.26]}, "certificate.U_um"),
    ({"U_um": [0.26, 0.0019]}, "certificate.k"),
    ({"U_um": [-1, 0.0019], "k": 2}, "certificate.U_um"),
    ({"U_um": [0.26, 0.0019], "k": 2, "combine": "sum"}, "certificate.combine"),
    ({"exact": "yes"}, "certificate.exact"),
    ({"exact": True, "U_um": [0.1, 0]}, "certificate"),
    ({"Exact": True}, None),
])
def test_a_bad_statement_is_named(bad, column):
    with pytest.raises(DataError) as exc:
        _load(_setup(**bad))
    assert exc.value.file == "setup.json"
    if column:
        assert exc.value.column == column


# ------------------------------------------------------------------ long styli

def _long_stylus_setup(layout: str, length_mm: float, axis: int) -> dict:
    """The thesis placements with every stylus ``length_mm`` long along -axis and the
    plates moved the same way until the lowest ball 1 stands at -(length - 100) mm: the
    tips lie up to length - 100 mm outside the strokes, the carriage inside them."""
    raw = thesis_machine_setup()
    raw["machine"]["layout"] = layout
    for k, name in enumerate(sorted(raw["probes"])):
        p = np.zeros(3)
        p[axis] = -length_mm
        p[(axis + 1) % 3] = 15.0 * k  # six distinct styli
        raw["probes"][name] = p.tolist()
    shift = min(p["origin_mm"][axis] for p in raw["positions"].values()) + length_mm - 100.0
    for pos in raw["positions"].values():
        pos["origin_mm"][axis] -= shift
    return raw


@pytest.mark.parametrize("length_mm", [250.0, 600.0])
@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_long_styli_are_accepted_and_fitted_on_every_layout(layout, length_mm, tmp_path):
    axis = 1 if layout.startswith("horizontal_arm") else 2
    sim = simulate({"seed": 11, "noise_um": 0.3,
                    "setup": _long_stylus_setup(layout, length_mm, axis)})
    sim.write(tmp_path)
    tips = sim.dataset.meas[["x_mm", "y_mm", "z_mm"]].to_numpy()
    assert tips[:, axis].min() < -140.0  # refused by the old check on tips alone
    data = load_dataset([tmp_path / "measurements.csv"], tmp_path / "setup.json",
                        tmp_path / "certificate.csv")
    res = fit(data, "kinematic21", sigma_um=0.3)
    assert res.status == "converged", res.message
    assert res.rms_um < 0.5


def test_a_ball_two_metres_outside_the_machine_is_still_refused(tmp_path):
    raw = _long_stylus_setup("moving_bridge_fxyz", 250.0, 2)
    sim = simulate({"seed": 1, "noise_um": 0.3, "setup": raw})
    sim.write(tmp_path)
    text = (tmp_path / "measurements.csv").read_text().splitlines()
    head = text[0].split(",")
    row = text[5].split(",")
    row[head.index("x_mm")] = str(float(row[head.index("x_mm")]) + 2000.0)
    text[5] = ",".join(row)
    (tmp_path / "measurements.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(DataError) as exc:
        load_dataset([tmp_path / "measurements.csv"], tmp_path / "setup.json",
                     tmp_path / "certificate.csv")
    assert exc.value.row == 6 and "scale reading" in str(exc.value)


# ------------------------------------------------------------------ other tools' files, CLI

def _cli(argv, capsys):
    from cmm_core.cli import main

    rc = main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.out, out.err.strip().splitlines()


def test_msl_files_fit_from_the_command_line_and_are_named_when_given_as_ours(tmp_path,
                                                                                capsys):
    from test_msl import msl_files_of, simulated_machine

    sim, coef = simulated_machine("fixed_bridge_xfyz")
    pairs = msl_files_of(sim, tmp_path, "simulated", "fixed_bridge_xfyz")
    argv = ["fit", "--order", "1", "--sigma-um", "0.01", "--msl-kind", "simulated"]
    for snapshot, meta in pairs:
        argv += ["--msl", snapshot, "--msl-metadata", meta]
    rc, out, _ = _cli(argv, capsys)
    assert rc == 0
    res = json.loads(out)
    assert res["status"] == "converged" and "exact" in res["certificate_u_source"]
    got = res["parameters"]["dxx[1]"]
    assert got["value"] == pytest.approx(coef["dxx[1]"], abs=max(3 * got["u"], 0.02))
    rc, _, err = _cli(["fit", pairs[0][0], "--setup", THESIS_DIR / "setup.json"], capsys)
    assert rc == 2 and len(err) == 1 and "MSL" in err[0] and "--msl" in err[0]

"""Benchmark: ``compensate`` of 10^5 and 10^6 points from the command line (issue 25:
10^6 points in under 20 s and 300 MB).

Ours: ``python -m cmm_core compensate MODEL POINTS --out OUT`` in a child process, which
streams the points a chunk at a time (``export.correction.compensate`` with ``out``). Peer
in the same run: the previous implementation, copied below (:func:`previous_compensate`:
the whole file read at once, the Jacobian of every point at once, ``diag(J V Jᵀ)`` by
``einsum``, ``DataFrame.to_csv``), run the same way in a child process. Each child
reports its wall time from start to exit (interpreter and imports included, as a user
waits for them) and its peak resident memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss``
at exit). The outputs of both on the same points are compared (largest difference of any
number).

The model is ``kinematic21`` fitted to ``sample_data/simulated`` (six placements, two
styli); the points are drawn uniformly (``np.random.default_rng(0)``) in the box its
placements measured, each with one of its probes.
Run: ``.venv/bin/python bench/compensate.py`` (``--quick``: the peer on 10^5 points
only; on 10^6 it takes minutes and gigabytes).
"""

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cmm_core.cli import main as cli_main  # noqa: E402
from cmm_core.export import load_model, read_points, save_model  # noqa: E402
from cmm_core.export.correction import extrapolation_note  # noqa: E402
from cmm_core.export.model_file import COMPENSATING  # noqa: E402
from cmm_core.io import DataError, atomic_write_text, load_dataset  # noqa: E402
from cmm_core.io.delimited import file_rows  # noqa: E402
from cmm_core.model import fit, propagate_error  # noqa: E402
from cmm_core.units import UM  # noqa: E402

SIM = ROOT / "sample_data" / "simulated"
COLUMNS = ["xc_mm", "yc_mm", "zc_mm", "ex_um", "ey_um", "ez_um", "u_x_um", "u_y_um",
           "u_z_um"]


def previous_compensate(model, points):
    """``compensate`` as it was before issue 25 (commit 377400b), for comparison."""

    m = model
    name = points.attrs.get("source", "points")
    probes = points["probe"].astype(str).str.strip().to_numpy()
    rows_in_file = file_rows(points)
    for i, q in enumerate(probes):
        if q not in m.probes_mm:
            raise DataError(f"probe {q!r} is not in the model.", file=name,
                            row=int(rows_in_file[i]), column="probe")
    r = points[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    p = np.array([m.probes_mm[q] for q in probes]).reshape(-1, 3)
    x = r - p
    fixes = [b.correct(part, points, x, name) for b in COMPENSATING
             if (part := m.parts.get(b.token)) is not None]
    if not fixes:
        e_um, u = propagate_error(m.terms, m.coef, m.cov, x, p)
    else:
        e_um, u = propagate_error(m.terms, m.coef, m.joint_cov, x, p,
                                  extra_jac=np.concatenate([f.jac for f in fixes], axis=2))
        for f in fixes:
            e_um = e_um + f.delta_um
    out = points.copy()
    out["xc_mm"], out["yc_mm"], out["zc_mm"] = (r + e_um * UM).T
    out["ex_um"], out["ey_um"], out["ez_um"] = e_um.T
    out["u_x_um"], out["u_y_um"], out["u_z_um"] = u.T
    out["extrapolated"] = extrapolation_note(m, x)
    return out


def child(which, model_path, points_path, out_path):
    """Run one implementation (in a child process) and print its peak memory."""
    if which == "ours":
        status = cli_main(["--json", str(out_path) + ".json", "compensate", str(model_path),
                       str(points_path), "--out", str(out_path)])
        if status:
            raise SystemExit(status)
    else:
        out = previous_compensate(load_model(model_path), read_points(points_path))
        atomic_write_text(out_path, out.to_csv(index=False, float_format="%.6f"))
    print(json.dumps({"maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def run(which, model_path, points_path, out_path):
    """Wall time (s) and peak memory (MB) of one child run."""
    t = time.perf_counter()
    done = subprocess.run([sys.executable, __file__, "--child", which, str(model_path),
                           str(points_path), str(out_path)], capture_output=True, text=True,
                          check=True)
    seconds = time.perf_counter() - t
    return seconds, json.loads(done.stdout.strip().splitlines()[-1])["maxrss_mb"]


def setup(folder, sizes):
    """The model file and a points file of each size in ``folder``."""

    data = load_dataset([SIM / "measurements.csv"], SIM / "setup.json",
                        SIM / "certificate.csv")
    r = fit(data, "kinematic21")
    model_path = folder / "model.json"
    save_model(r, model_path)
    lo, hi = r.problem.obs.r_mm.min(0), r.problem.obs.r_mm.max(0)
    probes = list(r.problem.obs.probes)
    rng = np.random.default_rng(0)
    files = {}
    for n in sizes:
        pts = pd.DataFrame(lo + rng.uniform(size=(n, 3)) * (hi - lo),
                           columns=["x_mm", "y_mm", "z_mm"])
        pts["probe"] = rng.choice(probes, n)
        files[n] = folder / f"points_{n}.csv"
        pts.to_csv(files[n], index=False, float_format="%.4f")
    return model_path, files


def largest_difference(a, b):
    """Largest absolute difference of the numeric output columns of two CSV files."""
    x = pd.read_csv(a, usecols=COLUMNS)[COLUMNS].to_numpy()
    y = pd.read_csv(b, usecols=COLUMNS)[COLUMNS].to_numpy()
    return float(np.abs(x - y).max())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="run the previous implementation on 10^5 points only")
    ap.add_argument("--repeats", type=int, default=3,
                    help="runs of each implementation per size (median reported)")
    args = ap.parse_args()
    sizes = (100_000, 1_000_000)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        model_path, files = setup(folder, sizes)
        print(f"{'points':>9s} {'implementation':<34s} {'median s':>9s} {'peak MB':>8s} "
              f"{'time ratio':>10s}")
        for n in sizes:
            peers = ("ours", "previous") if n < 1_000_000 or not args.quick else ("ours",)
            res = {}
            for which in peers:
                runs = [run(which, model_path, files[n], folder / f"{which}_{n}.csv")
                        for _ in range(args.repeats if which == "ours" or n < 1_000_000
                                       else 1)]
                res[which] = (float(np.median([s for s, _ in runs])),
                              max(mb for _, mb in runs))
            for which, (sec, mb) in res.items():
                label = ("ours (streamed, CLI)" if which == "ours"
                         else "previous (whole file, CLI body)")
                print(f"{n:>9,d} {label:<34s} {sec:9.1f} {mb:8.0f} "
                      f"{res['ours'][0] / sec:10.2f}", flush=True)
            if "previous" in res:
                d = largest_difference(folder / f"ours_{n}.csv", folder / f"previous_{n}.csv")
                print(f"{'':>9s} largest difference of any output number: {d:.1e}", flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(*sys.argv[2:6])
    else:
        main()

"""Benchmark: the start of the command line, ``cmm-error-lab --help`` and
``cmm-error-lab fit --help`` (target: under 0.5 s each; they took about 1.8 s when
``cmm_core.cli`` imported every command module and with them numpy, scipy, pandas and
plotly).

Ours: the console script of this interpreter's environment (``cmm-error-lab`` beside
``sys.executable``; ``python -m cmm_core`` if it is not installed) run on this checkout
(``PYTHONPATH``), in a child process, the wall time from start to exit as a user waits for
it. Peer in the same run: ``python -c pass``, the interpreter's own start, which no
command line can beat; the ratio is ours over it. Runs alternate (peer, help, fit help)
so that a slow spell of the machine touches all three alike; medians reported.
Run: ``.venv/bin/python bench/cli_start.py [--repeats N]``.
"""

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 0.5


def _command_line() -> list[str]:
    script = Path(sys.executable).parent / "cmm-error-lab"
    return [str(script)] if script.is_file() else [sys.executable, "-m", "cmm_core"]


def _wall(argv, env) -> float:
    """Wall time (s) of one child process, start to exit."""
    t = time.perf_counter()
    subprocess.run(argv, env=env, cwd=ROOT, stdout=subprocess.DEVNULL, check=True)
    return time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=15,
                    help="runs of each command (median reported; default: %(default)s)")
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    cli = _command_line()
    cases = [("python -c pass (peer)", [sys.executable, "-c", "pass"]),
             (f"{Path(cli[-1]).name} --help", [*cli, "--help"]),
             (f"{Path(cli[-1]).name} fit --help", [*cli, "fit", "--help"])]
    for _, argv in cases:  # warm the file cache (the first run reads every .pyc from disk)
        _wall(argv, env)
    times: dict[str, list[float]] = {name: [] for name, _ in cases}
    for _ in range(args.repeats):
        for name, argv in cases:
            times[name].append(_wall(argv, env))
    peer = statistics.median(times[cases[0][0]])
    print(f"{'command':32s} {'median s':>9s} {'min s':>7s} {'ratio to peer':>14s} "
          f"{'target':>8s}")
    for name, _ in cases:
        med = statistics.median(times[name])
        target = "" if name == cases[0][0] else ("met" if med < TARGET_S else "MISSED")
        print(f"{name:32s} {med:9.3f} {min(times[name]):7.3f} {med / peer:14.2f} {target:>8s}")


if __name__ == "__main__":
    main()

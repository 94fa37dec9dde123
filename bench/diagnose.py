"""Benchmark: ranking the candidate effects (issue 4: ~30 candidates on ~450 observations
in under a second; issue 18: 43 candidates on 450 observations in under 0.3 s).

Prints the median time of ``diagnose`` (score test for every candidate, full refit of the
best three) and, in the same run, of the peer method it replaces: a full Gauss-Newton refit
of the model with each candidate added (the exact χ² reduction), with the ratio, and
whether both rank the same effect first. With ``--previous``, the same diagnosis by the
previous release (``cmm_core`` at commit ``PREVIOUS``, extracted with git into a temporary
directory and timed in a child process on the same data), with the ratio and whether the
verdict and every candidate's Δχ² agree; off by default, as that release no longer runs
beside today's package (its child process fails on an import), and the refit peer above
is the comparison that runs today.
Run: ``.venv/bin/python bench/diagnose.py [--previous]``.
"""

import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _timing import median_time  # noqa: E402

from cmm_core.diagnosis import diagnose  # noqa: E402
from cmm_core.model import fit, parse_spec, simulate  # noqa: E402

PREVIOUS = "718abca"  # last commit before the issue-18 diagnosis (one evaluation per candidate)
REPEATS = 7
BASELINE = "kinematic21"
# six placements x 25 balls x 3 probes = 450 observations
THREE = {"BP111": ["1", "2", "3"], "BP112": ["1", "2", "4"], "BP211": ["3", "4", "5"],
         "BP212": ["3", "4", "6"], "BP311": ["5", "6", "1"], "BP312": ["5", "6", "2"]}
CONFIG = {"seed": 3, "probes_per_position": THREE,
          "effects": {"plate_sag": {"uu": -2.0, "uv": 0.5, "vv": -1.5}}}


def refit_all(data, baseline, tokens):
    """Peer: refit with every candidate; rank by BIC."""
    base = parse_spec(baseline)
    bics = {tok: fit(data, base.with_token(tok)).bic for tok in tokens}
    return min(bics, key=bics.get)


def timed_diagnosis():
    """Median time and result of the diagnosis of the benchmark data with this package."""
    data = simulate(CONFIG).dataset
    # the default candidates: the next two orders of every function, the physical effects
    # and the periodic scale errors (period scanned): about 50
    tokens = parse_spec(BASELINE).candidates()
    return data, *median_time(lambda: diagnose(data, BASELINE, candidates=tokens), REPEATS)


def previous_release():
    """``(median s, verdict, {effect: Δχ²})`` of the previous release, or None."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            arch = subprocess.run(["git", "archive", PREVIOUS, "cmm_core", "sample_data",
                                   "bench/_timing.py"],
                                  cwd=ROOT, capture_output=True, check=True).stdout
            subprocess.run(["tar", "-x", "-C", tmp], input=arch, check=True)
        except (OSError, subprocess.CalledProcessError):
            return None
        code = (f"import sys, json; sys.path[:0] = [{tmp!r}, {tmp + '/bench'!r}, "
                f"{str(ROOT / 'bench')!r}]\n"
                "import cmm_core  # the previous release, before the bench imports ROOT's\n"
                "assert cmm_core.__file__.startswith(sys.path[0])\n"
                "import diagnose as b\n"
                "_, t, d = b.timed_diagnosis()\n"
                "print(json.dumps([t, d.verdict, {c.effect: c.delta_chi2 "
                "for c in d.candidates}]))\n")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             cwd=tmp)
        if out.returncode:
            print(out.stderr[-2000:])
            return None
        return json.loads(out.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    if "cmm_core" not in sys.modules or not sys.modules["cmm_core"].__file__.startswith(
            str(ROOT)):
        raise SystemExit("run from the repository")
    data, ours, d = timed_diagnosis()
    tokens = [c.effect for c in d.candidates]
    peer, best = median_time(lambda: refit_all(data, BASELINE, tokens), 2)
    print(f"diagnose: {len(data.meas)} observations, {len(tokens)} candidates "
          f"(+{len(d.skipped)} skipped)  median {ours * 1e3:.0f} ms  "
          f"refit-every-candidate {peer * 1e3:.0f} ms  ratio {ours / peer:.2f}  "
          f"first: ours {d.verdict} / peer {best}", flush=True)
    if "--previous" in sys.argv:
        prev = previous_release()
        if prev is None:
            print("previous release: not compared (git unavailable or its run failed)")
        else:
            t_prev, verdict, dchi2 = prev
            ours_d = {c.effect: c.delta_chi2 for c in d.candidates}
            worst = max(abs(ours_d[k] - v) / max(abs(v), 1e-300) for k, v in dchi2.items()
                        if abs(v) > 1e-3)
            print(f"previous release ({PREVIOUS}): median {t_prev * 1e3:.0f} ms, ratio "
                  f"ours/previous {ours / t_prev:.2f}, verdict {verdict} "
                  f"({'same' if verdict == d.verdict else 'DIFFERENT'}), largest relative "
                  f"Δχ² difference {worst:.1e} (candidates with Δχ² > 1e-3)")

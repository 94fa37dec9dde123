"""Benchmark: ranking the candidate effects (issue 4: ~30 candidates on ~450 observations
in under a second).

Prints the median time of ``diagnose`` (score test for every candidate, full refit of the
best three) and, in the same run, of the peer method it replaces: a full Gauss-Newton refit
of the model with each candidate added (the exact χ² reduction), with the ratio, and
whether both rank the same effect first.
Run: ``.venv/bin/python bench/diagnose.py``.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import median_time  # noqa: E402

from cmm_core.diagnose import diagnose  # noqa: E402
from cmm_core.effects import parse_spec  # noqa: E402
from cmm_core.fit import fit  # noqa: E402
from cmm_core.simulate import simulate  # noqa: E402


def refit_all(data, baseline, tokens):
    """Peer: refit with every candidate; rank by BIC."""
    base = parse_spec(baseline)
    bics = {tok: fit(data, base.with_token(tok)).bic for tok in tokens}
    return min(bics, key=bics.get)


if __name__ == "__main__":
    # six placements x 25 balls x 3 probes = 450 observations
    three = {"BP111": ["1", "2", "3"], "BP112": ["1", "2", "4"], "BP211": ["3", "4", "5"],
             "BP212": ["3", "4", "6"], "BP311": ["5", "6", "1"], "BP312": ["5", "6", "2"]}
    data = simulate({"seed": 3, "probes_per_position": three,
                     "effects": {"plate_sag": {"uu": -2.0, "uv": 0.5, "vv": -1.5}}}).dataset
    baseline = "kinematic21"
    # the default candidates: the next two orders of every function, the physical effects
    # and the periodic scale errors (period scanned): about 50
    tokens = parse_spec(baseline).candidates()
    ours, d = median_time(lambda: diagnose(data, baseline, candidates=tokens), 7)
    tokens = [c.effect for c in d.candidates]
    peer, best = median_time(lambda: refit_all(data, baseline, tokens), 2)
    print(f"diagnose: {len(data.meas)} observations, {len(tokens)} candidates "
          f"(+{len(d.skipped)} skipped)  median {ours * 1e3:.0f} ms  "
          f"refit-every-candidate {peer * 1e3:.0f} ms  ratio {ours / peer:.2f}  "
          f"first: ours {d.verdict} / peer {best}")

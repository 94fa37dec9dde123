"""``compare`` of two calibrations made with one plate and certificate (issue 39 item 4).

Each seed: a calibration of a simulated machine (``tests/scenarios.py`` layout, plate
fixed to its certificate of standard uncertainty ``--certificate-u`` µm per coordinate),
the same machine recalibrated on the *same* plate with the same certificate
(``monitor.remeasured(..., same_plate=True)``), unchanged and with an xy squareness step
of ``--step`` u (u of the change between independent calibrations, ``sqrt(2) u_sxy``).
Each pair is compared twice: with the shared certificate counted (the model files'
``certificate`` sensitivities, ``monitor.difference_covariance``) and as if the
calibrations were independent (the sensitivities dropped). Printed per way: the
parameter-by-parameter Holm test's false alarms and the standard deviation of the sxy
change's standard score on the unchanged machine (1 when its u is right), the
explanation's false alarms, and the share of seeds whose first named change is sxy, and
whose Holm test finds sxy, after the step; binomial standard errors beside each. The
certificate errors are shared by construction, and the counted covariance is checked
against this independent Monte Carlo of them.

Run: ``.venv/bin/python bench/shared_certificate.py [--seeds N] [--layouts a,b]
[--step 1] [--certificate-u 0.5]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import scenarios as sc  # noqa: E402

from cmm_core.export import model_from_result  # noqa: E402
from cmm_core.model import fit  # noqa: E402
from cmm_core.monitor import compare_calibrations, remeasured  # noqa: E402


def share(k: int, n: int) -> str:
    p = k / n
    return f"{100 * p:5.1f} % ± {100 * np.sqrt(p * (1 - p) / n):.1f}"


def _fitted(data):
    return model_from_result(fit(data, "kinematic21", plate="fixed"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=100, help="seeds per layout")
    ap.add_argument("--layouts", default="pitch100_4pos,pitch150_5pos",
                    help="layouts, comma-separated")
    ap.add_argument("--step", type=float, default=1.0, help="sxy step in u of the change")
    ap.add_argument("--certificate-u", type=float, default=0.5,
                    help="the certificate's standard uncertainty per coordinate, µm")
    args = ap.parse_args()
    print(f"seeds {args.seeds}, certificate u {args.certificate_u:g} µm, sxy step "
          f"{args.step:g} u")
    for layout in args.layouts.split(","):
        tally = {w: {"holm0": 0, "expl0": 0, "z": [], "holm": 0, "expl": 0}
                 for w in ("counted", "independent")}
        share_of_var = []
        for s in range(args.seeds):
            cal = sc.simulated(layout, 300 + s,
                               plate={"certificate_u_um": args.certificate_u})
            m1 = _fitted(cal.dataset)
            j = m1.terms.labels.index("sxy")
            S = m1.certificate["sensitivity"]
            share_of_var.append(float(S[j] @ S[j] / m1.cov[j, j]))
            step = args.step * float(np.sqrt(2 * m1.cov[j, j]))
            m0 = _fitted(remeasured(cal, 9000 + s, same_plate=True).dataset)
            m2 = _fitted(remeasured(cal, 9500 + s, same_plate=True,
                                    changes={"sxy": step}).dataset)
            for way, t in tally.items():
                a, b0, b2 = (m1, m0, m2) if way == "counted" else [
                    dataclasses.replace(m, certificate=None) for m in (m1, m0, m2)]
                h0 = compare_calibrations([(a, "2024-01-01"), (b0, "2025-01-01")])
                h2 = compare_calibrations([(a, "2024-01-01"), (b2, "2025-01-01")])
                t["holm0"] += bool(h0.significant)
                t["expl0"] += bool(h0.explanations[0].steps)
                row = h0.changes.set_index("label").loc["sxy"]
                t["z"].append(row.change / row.u_change)
                first = h2.explanations[0].first
                t["expl"] += bool(first and first.hypothesis.key == "sxy")
                t["holm"] += any(x.startswith("sxy ") for x in h2.significant)
        n = args.seeds
        print(f"{layout}: the certificate is {100 * np.mean(share_of_var):.0f} % of u(sxy)²")
        for way, t in tally.items():
            print(f"  {way:11s} unchanged: Holm {share(t['holm0'], n)}, explanation "
                  f"{share(t['expl0'], n)}, sd of z(sxy) {np.std(t['z']):.2f}; "
                  f"step: sxy first {share(t['expl'], n)}, Holm finds sxy "
                  f"{share(t['holm'], n)}", flush=True)


if __name__ == "__main__":
    main()

"""Walk the missing-effect loop on the thesis tables and write it into docs/thesis-data.md.

Each step is what the app's diagnosis page does: diagnose, read the verdict, apply it
(an effect, or the certificate fix the diagnosis offers), diagnose again, until the data
are explained to noise, σ is the suspect, or the verdict is "outside the catalogue". The
section between the markers in docs/thesis-data.md is replaced, so the document stays
true to the code (``tests/test_thesis_walk.py`` runs this script).

Usage: ``python scripts/thesis_walk.py [--print]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cmm_core.diagnosis import OUTSIDE, detect_outliers, diagnose  # noqa: E402
from cmm_core.io import thesis_dataset  # noqa: E402
from cmm_core.model import parse_spec  # noqa: E402

DOC = ROOT / "docs" / "thesis-data.md"
BEGIN, END = "<!-- thesis-walk:begin -->", "<!-- thesis-walk:end -->"


def walk(max_steps: int = 5) -> list[str]:
    """The loop's steps as markdown lines."""
    data = thesis_dataset()
    exclude = detect_outliers(data).exclusions
    lines = [f"Blunders excluded first: {', '.join(f'{p}/{q} ball {b}' for p, q, b in exclude)}"
             " (robust median/MAD flags). σ = 0.5 µm as stated in thesis §4.4.2.", ""]
    spec, plate = parse_spec("kinematic21"), "fixed"
    for step in range(1, max_steps + 1):
        d = diagnose(data, spec.to_string(), plate=plate, exclude=exclude)
        b = d.baseline
        head = (f"{step}. **{b.spec}, certificate {plate}**: RMS {b.rms_um:.2f} µm, χ²/dof "
                f"{b.chi2_dof:.2f} at {b.dof} dof "
                f"({'fails' if b.fails_chi2_test else 'passes'} the χ² test).")
        lines.append(head)
        cert = d.certificate
        if cert is not None and cert.suspect and plate == "fixed":
            named = ", ".join(f"ball {e['ball']} {e['axis']} {e['deviation_um']:+.1f} µm"
                              for e in cert.entries[:4])
            fx = cert.fixes
            lines.append(f"   The certificate is named a suspect (p = {cert.p_value:.2g}): "
                         f"{named}. χ²/dof fixed {fx['certificate fixed']['chi2_dof']:.1f}, "
                         f"prior {fx['certificate as prior']['chi2_dof']:.1f}, "
                         f"self-calibrated {fx['self-calibrated (free)']['chi2_dof']:.1f}. "
                         "Reading: ball 16 X is the printed certificate's transcription slip "
                         "(every table has about −0.05 mm). Applied: self-calibrate the plate.")
            plate = "free"
            continue
        if d.verdict not in (None, OUTSIDE):
            c = d.candidates[0]
            h = next((x for x in d.holdout if x.effect == d.verdict), None)
            lines.append(f"   Verdict `{d.verdict}`: Δχ² {c.delta_chi2:.0f} for {c.n_params} "
                         f"parameter(s), p = {c.p_value:.2g}"
                         + (f"; leave-one-placement-out: {h.reason}" if h else "")
                         + f". Applied: add `{d.verdict}`.")
            spec = spec.with_token(d.verdict)
            continue
        if d.verdict == OUTSIDE:
            where = "; ".join(f"{k} {v['name']} {100 * v['chi2_share']:.0f} % of χ² "
                              f"({100 * v['expected_share']:.0f} % of the data)"
                              for k, v in d.where.items())
            lines.append(f"   Verdict **outside the catalogue**. Where the residual lives: "
                         f"{where}.")
        else:
            lines.append("   Nothing significant left.")
        if d.sigma is not None:
            s = d.sigma
            lines.append(f"   σ estimated from the data: {s.value_um:.2f} ± {s.u_um:.2f} µm "
                         f"({s.method}); at that σ χ²/dof would be "
                         f"{b.chi2_dof * (b.sigma_um / s.value_um) ** 2:.2f}. Reading: six "
                         "single measurements of one plate cannot tell repeatability from "
                         "structure the catalogue lacks (the z-height-dependent bowl, see "
                         "above); both are reported, neither hidden.")
        break
    return lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--print", action="store_true", help="print instead of writing the doc")
    args = ap.parse_args()
    text = "\n".join([BEGIN, "", *walk(), "", END])
    if args.print:
        print(text)
        return
    doc = DOC.read_text(encoding="utf-8")
    if BEGIN in doc:
        doc = doc[: doc.index(BEGIN)] + text + doc[doc.index(END) + len(END):]
    else:
        doc += "\n## The loop, step by step (written by scripts/thesis_walk.py)\n\n" + text + "\n"
    DOC.write_text(doc, encoding="utf-8")


if __name__ == "__main__":
    main()

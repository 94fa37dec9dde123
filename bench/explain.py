"""Validation of ``monitor.explain_change`` on simulated machine histories (issue 39).

For each layout of ``tests/scenarios.py`` (none of them the sample data's) a calibration
is simulated and fitted (kinematic21, plate fixed), and the machine is measured again
``--seeds`` times (new noise, new plate and certificate draws) in each event:

- ``none``: nothing changed: the share of seeds whose check fails *and* whose explanation
  names a change (the false alarm of the headline), and of seeds naming a change at all;
- ``sxy``: the xy squareness moved by ``--step`` u (u of the stored model's sxy);
- ``rxz``: the x carriage's yaw, linear term, moved by ``--step`` u of ``rxz[1]``;
- ``warm``: the three scales 17 ppm long (1.5 K warm steel scales), with the full plate
  and with one placement (``warm1``);
- ``stylus``: the layout's second stylus bent by ``--stylus-um`` µm along x (its
  ``probe_offset``), the rest of the machine unchanged.

For each event: the share of seeds whose check fails (power), whose first named change
is the true one (``scale`` for warm scales, ``sxy``, ``rxz`` or its linear form), and
whose first named change is something else; binomial standard errors beside each.

With ``--compare``, the same events between two calibrations (``compare``,
``monitor.explain_difference``): each seed a first calibration (seed 100 + s) and a
second of the same machine measured again (seed 20 000 + s), both fitted; the steps are
in u of the change, ``sqrt(u₁² + u₂²)`` of the parameter (each calibration's u).

Run: ``.venv/bin/python bench/explain.py [--seeds N] [--layouts a,b] [--step 3]
[--compare]``.
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import scenarios as sc  # noqa: E402

from cmm_core.export import model_from_result  # noqa: E402
from cmm_core.model import fit  # noqa: E402
from cmm_core.monitor import (  # noqa: E402
    VERDICTS,
    change_system,
    compare_calibrations,
    remeasured,
    run_check,
)

PPM = 17.0
"""Warm scales: 1.5 K on steel's 11.5 ppm/K."""


@functools.cache
def calibrated(layout: str):
    cal = sc.simulated(layout, 3)
    return cal, model_from_result(fit(cal.dataset, "kinematic21", plate="fixed"))


def events(layout: str, step: float, stylus_um: float = 1.0) -> dict:
    """Event -> (changes, placements of the new measurement or None, true first keys,
    simulator effects or None)."""
    cal, model = calibrated(layout)
    labels = model.terms.labels
    u = {lab: float(np.sqrt(model.cov[i, i])) for i, lab in enumerate(labels)}
    rng = dict(zip("xyz", model.terms.range_mm, strict=True))
    warm = {f"d{a}{a}[1]": PPM * rng[a] / 2000.0 for a in "xyz"}
    first = next(iter(sc.LAYOUTS[layout]["positions"].items()))
    one = {first[0]: first[1][1]}
    second = list(sc.LAYOUTS[layout]["probes"])[1]
    bent = {**cal.config.get("effects", {}),
            "probe_offset": {second: [stylus_um, 0.0, 0.0]}}
    return {"none": ({}, None, (), None),
            "sxy": ({"sxy": step * u["sxy"]}, None, ("sxy",), None),
            "rxz": ({"rxz[1]": step * u["rxz[1]"]}, None, ("rxz_linear", "rxz"), None),
            "warm": (warm, None, ("scale",), None),
            "warm1": (warm, one, ("scale",), None),
            "stylus": ({}, None, (f"stylus_{second}",), bent)}


def compare_events(layout: str, step: float) -> dict:
    """Event -> (changes, true first keys) between two calibrations: steps in u of the
    change (``sqrt(2)`` times one calibration's u)."""
    _, model = calibrated(layout)
    labels = model.terms.labels
    u = {lab: float(np.sqrt(2 * model.cov[i, i])) for i, lab in enumerate(labels)}
    return {"none": ({}, ()), "sxy": ({"sxy": step * u["sxy"]}, ("sxy",)),
            "rxz": ({"rxz[1]": step * u["rxz[1]"]}, ("rxz_linear", "rxz"))}


def run_compare(layout: str, seeds: int, step: float, names: list) -> None:
    for name, (changes, truth) in compare_events(layout, step).items():
        if name not in names:
            continue
        named = right = 0
        for s in range(seeds):
            cal = sc.simulated(layout, 100 + s)
            m1 = model_from_result(fit(cal.dataset, "kinematic21", plate="fixed"))
            new = remeasured(cal, 20_000 + s, changes=changes)
            m2 = model_from_result(fit(new.dataset, "kinematic21", plate="fixed"))
            e = compare_calibrations([(m1, "2024-01-01"), (m2, "2025-01-01")]).explanations[0]
            if e.first is not None:
                named += 1
                right += e.first.hypothesis.key in truth
        line = f"{layout:14s} compare {name:5s} names a change {share(named, seeds)}"
        if truth:
            line += f"; first named is the truth {share(right, seeds)}"
        print(line, flush=True)


def share(k: int, n: int) -> str:
    p = k / n
    return f"{100 * p:5.1f} % ± {100 * np.sqrt(p * (1 - p) / n):.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=400, help="seeds per layout and event")
    ap.add_argument("--layouts", default=",".join(sc.LAYOUTS), help="layouts, comma-separated")
    ap.add_argument("--step", type=float, default=3.0, help="squareness and yaw steps in u")
    ap.add_argument("--events", default="none,sxy,rxz,warm,warm1,stylus",
                    help="events to run")
    ap.add_argument("--stylus-um", type=float, default=1.0,
                    help="offset error of the bent stylus, µm along x")
    ap.add_argument("--compare", action="store_true",
                    help="between two calibrations (compare) instead of interim checks")
    args = ap.parse_args()
    print(f"seeds {args.seeds}, step {args.step:g} u, warm scales {PPM:g} ppm; "
          "shares with binomial standard errors")
    for layout in args.layouts.split(","):
        if args.compare:
            run_compare(layout, args.seeds, args.step, args.events.split(","))
            continue
        cal, model = calibrated(layout)
        for name, (changes, one, truth, effects) in events(layout, args.step,
                                                           args.stylus_um).items():
            if name not in args.events.split(","):
                continue
            fails = named = right = among = 0
            u_first = []
            words: dict = {}
            for s in range(args.seeds):
                new = remeasured(cal, 50_000 + s, changes=changes, probes_per_position=one,
                                 effects=effects)
                out = run_check(model, new.dataset, name_effects=False)
                if out.verdict != VERDICTS[2]:
                    continue
                fails += 1
                step = out.explanation.first if out.explanation else None
                if not words:  # the hypotheses' words, the styli's included
                    words = {h.key: h.words for h in change_system(model, out.check).hypotheses}
                if step is not None:
                    named += 1
                    right += step.hypothesis.key in truth
                    # the truth first or named as the first change's equal (its alias)
                    among += (step.hypothesis.key in truth
                              or any(words.get(t) in step.aliases for t in truth))
                    if step.hypothesis.key in truth:
                        u_first.append(step.u[0])
            n = args.seeds
            line = (f"{layout:14s} {name:6s} check fails {share(fails, n)}; names a change "
                    f"{share(named, n)}")
            if truth:
                line += (f"; first named is the truth {share(right, n)} (of the failing "
                         f"checks: {share(right, fails) if fails else '-'})")
            if truth:
                line += f"; the truth first or as its alias {share(among, n)}"
            if name == "stylus" and u_first:
                # the bend in units of the check's own u of the stylus's x offset change
                line += (f"; u(x offset) median {np.median(u_first):.3f} µm: the bend is "
                         f"{args.stylus_um / np.median(u_first):.1f} u")
            print(line, flush=True)


if __name__ == "__main__":
    main()

"""Power of the diagnosis against an ideal test, at a multiple of the detection limit.

For each layout of ``tests/scenarios.py`` and each catalogue effect of
``bench/honesty.py`` hidden at ``--scale`` times its detection limit (the size a clean
diagnosis predicts it finds with 80 % probability at its own level), over ``--seeds``
seeds: how often the loop's verdict names the hidden effect, beside an ideal test that
knows which effect is hidden (the F-test of adding it, at 1 %). The gap is what
multiplicity and aliases cost. With ``--pairs``: two effects hidden together, the loop
(diagnose, add the verdict, diagnose again) against the ideal tests of each effect given
the other. Usage: ``python bench/power.py [--seeds N] [--scale S] [--pairs]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]

import scenarios as sc  # noqa: E402
from honesty import hidden_configs, limits, loop  # noqa: E402

from cmm_core.diagnosis import diagnose  # noqa: E402
from cmm_core.model import fit  # noqa: E402


def _scaled(o, f):
    """``hidden_configs`` hides effects at 2x their limit: every size times ``f``."""
    if isinstance(o, dict):
        return {k: _scaled(v, f) for k, v in o.items()}
    if isinstance(o, list):
        return [_scaled(v, f) for v in o]
    return o * f if isinstance(o, float) else o


def ideal_detects(data, base: str, token: str, alpha: float = 0.01) -> bool:
    """The known-truth test: F-test of adding ``token`` to ``base`` at level ``alpha``."""
    b, a = fit(data, base), fit(data, f"{base},{token}")
    dk = a.rank - b.rank
    F = ((b.chi2 - a.chi2) / dk) / (a.chi2 / a.dof)
    return bool(stats.f.sf(F, dk, a.dof) < alpha)


def _merged(a, b):
    """Two simulator configurations in one (nested dictionaries merged)."""
    out = dict(a)
    for k, v in b.items():
        out[k] = _merged(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


PAIRS = [("plate_sag", "backlash"), ("probe_offset", "dyz:3"), ("backlash", "dyz:3")]
"""Effects hidden together (both with the baseline kinematic21)."""


def pairs(args) -> int:
    """Two hidden effects: does the loop name both (in either order)?"""
    total = [0, 0, 0]
    print(f"{'layout':15s} {'effects':22s} {'both':>5s} {'ideal':>6s} {'of':>4s}")
    for layout in sc.LAYOUTS:
        cfgs = {name: cfg for name, _, cfg in hidden_configs(layout, limits(layout))}
        for e1, e2 in PAIRS:
            if e1 not in cfgs or e2 not in cfgs:
                continue
            cfg = _scaled(_merged(cfgs[e1], cfgs[e2]), args.scale / 2)
            both = ideal = 0
            for seed in range(args.seeds):
                data = sc.simulated(layout, 5000 + seed, order="serpentine", **cfg).dataset
                path = loop(data, "kinematic21")[0]
                both += set(path[:2]) == {e1, e2}
                ideal += (ideal_detects(data, f"kinematic21,{e1}", e2)
                          and ideal_detects(data, f"kinematic21,{e2}", e1))
            total = [total[0] + both, total[1] + ideal, total[2] + args.seeds]
            print(f"{layout:15s} {e1 + ' + ' + e2:22s} {both:5d} {ideal:6d} {args.seeds:4d}")
    print(f"all: both named {total[0]}/{total[2]}, ideal tests {total[1]}/{total[2]}")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=25, help="seeds per effect and layout")
    ap.add_argument("--scale", type=float, default=1.0, help="size in detection limits")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="first seed (offset from 3000; a run split in parts adds up)")
    ap.add_argument("--pairs", action="store_true",
                    help="two effects hidden together (the loop against the ideal tests)")
    args = ap.parse_args(argv)
    if args.pairs:
        return pairs(args)
    total = [0, 0, 0]
    print(f"{'layout':15s} {'effect':13s} {'named':>6s} {'ideal':>6s} {'of':>4s}")
    for layout in sc.LAYOUTS:
        for name, base, cfg in hidden_configs(layout, limits(layout)):
            cfg = _scaled(cfg, args.scale / 2)
            named = ideal = 0
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                data = sc.simulated(layout, 3000 + seed, order="serpentine", **cfg).dataset
                named += diagnose(data, base).verdict == name
                ideal += ideal_detects(data, base, name)
            total = [total[0] + named, total[1] + ideal, total[2] + args.seeds]
            print(f"{layout:15s} {name:13s} {named:6d} {ideal:6d} {args.seeds:4d}")
    print(f"all: named {total[0]}/{total[2]}, ideal test {total[1]}/{total[2]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

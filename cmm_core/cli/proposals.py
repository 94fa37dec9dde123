"""Command-line front end of ``next``: propose the measurement that settles what the data
cannot (issue 29, ``plan.proposals``; docs/proposals.md).

Registered by ``cli`` with :func:`add_parser`; :func:`run` returns the JSON-ready result
(``cli.main`` prints it and turns errors into one line on stderr).
"""

from __future__ import annotations

import argparse
import json

from ..io import atomic_write_text
from ..plan import (
    PSEUDO,
    TARGET_POWER,
    instrument_candidates,
    measurement_candidates,
    plan_file,
    propose,
    simulate_outcomes,
)
from .inputs import (
    _order_arg,
    _sigma_arg,
    _spec_arg,
    add_data_args,
    dataset_of,
    number_arg,
    sigma_of,
)

_MAX_TOP = 100
"""Most proposals ``--top`` lists."""


def _rivals_arg(text):
    """Two different model tokens separated by a comma (``sxy,rxz:4``)."""
    parts = [t.strip() for t in str(text).split(",")]
    if len(parts) != 2 or not all(parts) or parts[0] == parts[1]:
        raise argparse.ArgumentTypeError(
            f"expected two different effect tokens separated by a comma (e.g. "
            f"'probe_offset,drift'), found {text[:60]!r}")
    return tuple(parts)


def _add_arguments(p) -> None:
    """Options of ``next``."""
    add_data_args(p)
    p.add_argument("--baseline", default="kinematic21", metavar="SPEC", type=_spec_arg,
                   help="model the diagnosis starts from, as a model spec "
                        "(docs/formats.md#model-specs), e.g. 'kinematic21,-sxy' "
                        "(default: %(default)s)")
    p.add_argument("--order", type=_order_arg, default=2, metavar="N",
                   help="default polynomial order of the error functions (default: "
                        "%(default)s)")
    p.add_argument("--plate", choices=("fixed", "prior", "free"),
                   help="plate geometry in the fits: certificate fixed, as a prior, or free "
                        "(default: fixed with a certificate)")
    p.add_argument("--sigma-um", type=_sigma_arg, default=0.5, metavar="UM|auto",
                   help="repeatability of one probed coordinate in µm (0.001 to 1000), or "
                        "'auto' to estimate it from the data (default: %(default)s µm)")
    p.add_argument("--rivals", type=_rivals_arg, metavar="A,B", default=None,
                   help="the two effects to tell apart, as model tokens separated by a "
                        "comma, e.g. 'probe_offset,drift'; second may be 'placement_scale' "
                        "(each placement's own scale) or 'baseline' (the model as it is: "
                        "for an effect the data cannot determine in full) (default: the "
                        "diagnosis's first candidate and its alias, or its runner-up)")
    p.add_argument("--top", type=number_arg(int, 1, _MAX_TOP), default=5, metavar="N",
                   help=f"how many proposals to list, best first, 1 to {_MAX_TOP} (default: "
                        "%(default)s)")
    p.add_argument("--reference", metavar="PLACEMENT", default=None,
                   help="placement the candidates are derived from (default: the first "
                        "horizontal one)")
    p.add_argument("--target-power", type=number_arg(float, 0.01, 0.999), default=TARGET_POWER,
                   metavar="P",
                   help="power at which a proposal counts as deciding the pair (default: "
                        "%(default)s)")
    p.add_argument("--instruments", action="store_true",
                   help="also score instrument candidates: laser positioning runs along X, "
                        "Y, Z, step gauges along X and Y, a ball bar in XY (default: plate "
                        "placements and styli only; --plan-out takes plate proposals only)")
    p.add_argument("--simulate", action="store_true",
                   help="also simulate the top proposal (a placement, stylus, repeat or "
                        "instrument run) with each rival as the truth, append it to the data "
                        "and run the diagnosis (adds a few seconds)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the noise of --simulate (default: %(default)s)")
    p.add_argument("--plan-out", metavar="PLAN.json", default=None,
                   help="write the top placement, stylus or repeat proposal as a plan file "
                        "for 'plan' (docs/planning.md: a repeat is the strategy's "
                        "repeat_at_end; an instrument run cannot be a plan: the next one "
                        "down is written; default: not written)")


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``next`` sub-command to the sub-parsers of ``cli.build_parser``."""
    p = subparsers.add_parser(
        "next", help="propose the measurement that tells two rival effects apart")
    _add_arguments(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> dict:
    """``next``: rank candidate measurements; optionally simulate the best and write it
    as a plan file."""
    data = dataset_of(args)
    sigma, sigma_rec = sigma_of(args, data, [], args.baseline)
    settings = {"baseline": args.baseline, "order": args.order, "plate": args.plate,
                "sigma_um": sigma}
    cands = measurement_candidates(data, reference=args.reference)
    if args.instruments:
        cands += instrument_candidates(data, reference=args.reference)
    pr = propose(data, args.rivals, cands=cands, target=args.target_power, **settings)
    plates = [p for p in pr.ranked if not p.candidate.instrument]
    out = pr.to_dict()
    out["proposals"] = out["proposals"][:args.top]
    out["sigma"] = sigma_rec
    if pr.ranked and args.simulate and set(pr.rivals) & PSEUDO:
        out["simulated"] = {"skipped": f"{pr.rivals[1]} cannot be simulated as the truth"}
    elif pr.ranked and args.simulate:  # the top proposal, a placement, repeat or instrument
        outs = simulate_outcomes(data, pr.ranked[0], seed=args.seed, **settings)
        out["simulated"] = {t: {"verdict": o.verdict, "aliases": o.aliases,
                                "separated": o.separated, "message": o.message}
                            for t, o in outs.items()}
    if plates and args.plan_out:  # a plan holds placements, styli and repeats
        # checked against the inputs before any work (cli.commands), written atomically
        atomic_write_text(args.plan_out, json.dumps(
            plan_file(data, plates[0], baseline=args.baseline, order=args.order,
                      noise_um=sigma), indent=1))
        out["plan_file"] = {"path": str(args.plan_out), "proposal": plates[0].candidate.name}
    elif args.plan_out:
        out["plan_file"] = {"skipped": "no placement, stylus or repeat proposal to write: "
                                       "a plan file cannot hold instruments"}
    return out

"""Command-line front end of ``next``: propose the measurement that settles what the data
cannot (issue 29, ``plan.proposals``; docs/proposals.md).

Registered by ``cli`` (its options in :mod:`.parser`; :func:`add_parser` adds it to a
parser of one's own); :func:`run` returns the JSON-ready result (``cli.main`` prints it
and turns errors into one line on stderr). The result opens with the conclusion
(``message``, ``decided``: "No candidate decides between A and B: ..." when none
does); each candidate out of the machine's reach is a ``skipped`` record and a
``note: skipped: ...`` line on stderr.
"""

from __future__ import annotations

import argparse
import json

from ..io import atomic_write_text
from ..plan import (
    PSEUDO,
    decide_bar,
    instrument_candidates,
    measurement_candidates,
    plan_file,
    propose,
    simulate_outcomes,
)
from .inputs import dataset_of, notes_of, settle_defaults, sigma_of
from .parser import add_command
from .records import provenance_of


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``next`` sub-command to ``subparsers`` (as ``cli.build_parser`` does; its
    options are in :mod:`.parser`)."""
    return add_command(subparsers, "next")


def run(args: argparse.Namespace) -> dict:
    """``next``: rank candidate measurements; optionally simulate the best and write it
    as a plan file."""
    settle_defaults(args)  # --order, --sigma-um from the MSL files where they state them
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
    # on stderr, one line each (cli.main prints notes): a candidate left out is said,
    # not silently missing from the ranking; the JSON's "skipped" holds the records
    out["notes"] = [*notes_of(args, data), *(s.line() for s in pr.infeasible)]
    if pr.ranked and args.simulate and set(pr.rivals) & PSEUDO:
        out["simulated"] = {"skipped": f"{pr.rivals[1]} cannot be simulated as the truth"}
    elif pr.ranked and args.simulate:  # the top proposal, a placement, repeat or instrument
        outs = simulate_outcomes(data, pr.ranked[0], seed=args.seed, **settings)
        out["simulated"] = {t: {"verdict": o.verdict, "aliases": o.aliases,
                                "separated": o.separated, "message": o.message}
                            for t, o in outs.items()}
    if plates and args.plan_out:  # a plan holds placements, styli and repeats
        # checked against the inputs before any work (cli.commands), written atomically
        doc = plan_file(data, plates[0], baseline=args.baseline, order=args.order,
                        noise_um=sigma)
        doc["provenance"] = provenance_of(args, data).to_dict()  # the data it extends
        atomic_write_text(args.plan_out, json.dumps(doc, indent=1))
        out["plan_file"] = {"path": str(args.plan_out), "proposal": plates[0].candidate.name,
                            "decides": plates[0].power_min >= decide_bar(pr.target)}
    elif args.plan_out:
        out["plan_file"] = {"skipped": "no placement, stylus or repeat proposal to write: "
                                       "a plan file cannot hold instruments"}
    return out

"""``compensate``: points corrected with a saved model (registered in :mod:`.parser`)."""

from __future__ import annotations

import argparse

from ..export import compensate, load_model


def cmd_compensate(args: argparse.Namespace) -> dict:
    # streamed a chunk at a time: the memory does not grow with the number of points
    return compensate(load_model(args.model), args.points, out=args.out,
                      allow_extrapolation=args.allow_extrapolation)

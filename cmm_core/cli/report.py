"""``report``: the HTML report of an analysis record (registered in :mod:`.parser`)."""

from __future__ import annotations

import argparse

from ..analysis import write_report


def cmd_report(args: argparse.Namespace) -> dict:
    return write_report(args.analysis, args.out, confine=not args.any_path)

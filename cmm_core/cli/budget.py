"""``budget`` and ``air``: the commands of the GUM wing (registered in :mod:`.parser`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..gum import air_from_args, read_budget


def cmd_budget(args: argparse.Namespace) -> dict:
    return read_budget(Path(args.budget))


def cmd_air(args: argparse.Namespace) -> dict:
    return air_from_args(args.t_C, args.p_Pa, args.rh_percent, args.wavelength_nm)

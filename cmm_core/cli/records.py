"""What a command's records say of their origin: every file it read, with its SHA-256
(docs/formats.md "Provenance of every record"). The io wing only: ``cli.main`` adds it to
every command's JSON, whatever the command loads."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from ..io import DataError, InputFile, Provenance, input_file, provenance, read_bytes


def command_inputs(args: argparse.Namespace, *, leave_out: Sequence = ()) -> list[InputFile]:
    """Every file the command reads (``cli.main`` lists them as ``args.input_files`` for its
    output checks), each with its SHA-256; ``leave_out``: digests already named (a model
    file the record names as its own)."""
    seen = {f.sha256 for f in leave_out if f is not None}
    out = []
    for path in getattr(args, "input_files", []):
        try:
            f = input_file(Path(path).name, read_bytes(Path(path), None)[0])
        except (DataError, OSError):  # read, and refused, by the command itself
            continue
        if f.sha256 not in seen:
            seen.add(f.sha256)
            out.append(f)
    return out


def provenance_of(args: argparse.Namespace, data: object = None) -> Provenance:
    """The provenance of what the command writes: its input files, and the machine and
    calibration date of ``data``'s setup when it has one."""
    setup = getattr(data, "setup", None)
    return provenance(command_inputs(args), machine=getattr(setup, "machine_id", None),
                      calibration_date=getattr(setup, "calibration_date", None))

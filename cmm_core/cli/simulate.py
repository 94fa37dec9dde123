"""``simulate``: a virtual CMM's files (registered in :mod:`.parser`)."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from ..io import atomic_write_all, read_json
from ..model import simulate
from .parser import _SIM_FILES
from .records import provenance_of


def cmd_simulate(args: argparse.Namespace) -> dict:
    # read like every JSON input (a byte-order mark tolerated), refusals name the file
    cfg, name = read_json(Path(args.config))
    sim = simulate(cfg, name=name)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:  # all four made, then written all or none
        sim.write(tmp, provenance_of(args, sim.dataset))
        atomic_write_all({out / f: (Path(tmp) / f).read_bytes() for f in _SIM_FILES})
    return {"out": str(args.out), "n_obs": len(sim.dataset.meas), "files": list(_SIM_FILES)}

"""``python -m cmm_core export``: compensation tables and results files from a saved model.

Formats in docs/compensation.md. :func:`add_parser` adds the sub-command to the main
parser (its ``func`` returns the JSON summary ``cli.main`` prints); :func:`run` runs it on
its own: the summary on stdout, exit status 0; bad input exits with status 2 and one line
on stderr naming the file, row and column. No output may be the model file or another
output (:func:`output_files`, ``io.check_outputs``); each file is written whole or not at
all, and the files of one run all or none (``io.atomic_write_all``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from ..export import comp_tables as ct
from ..export import load_model
from ..export import results as rx
from ..io import DataError, atomic_write_all, check_outputs
from ..machine import AXES

_MODEL_HELP = ("fitted model written by 'fit --save' (its kinematic coefficients, their "
               "covariance, the layout, strokes and probe offsets). At least one of --grid, "
               "--axis-tables, --results-json, --results-xml is required; formats in "
               "docs/compensation.md")
_GRID_STEP_HELP = ("spacing of the 3-D compensation grid along each axis, mm, 0.1 to 10000; "
                   "one number for all axes or three (x,y,z), e.g. 100 or 100,100,50. Each "
                   "axis runs "
                   "from 0 to its stroke, the last interval shorter when the stroke is not "
                   "a multiple (default: %(default)s mm)")
_AXIS_STEP_HELP = ("spacing of the rows of the per-axis tables, mm, 0.1 to 10000 (default: "
                   "the grid step; the first of three)")
_PROBE_HELP = ("stylus of the model whose tip the grid corrects; default: none, the ram "
               "reference point (offset 0 0 0 mm), as a controller's table. The per-axis "
               "tables do not depend on the stylus")
_GRID_HELP = ("write the 3-D grid compensation table to this CSV: at each node the "
              "correction (true minus indicated, µm, added to the reading) in x, y, z and "
              "its standard uncertainty (k = 1), with a header block (units, sign, layout, "
              "probe, grid, model and its χ² test). Default: not written")
_AXES_HELP = ("write the per-axis tables to this directory (created if missing): "
              "axis_x.csv, axis_y.csv, axis_z.csv (positioning, two straightness, three "
              "rotations along each axis, µm and µrad, with standard uncertainties) and "
              "squareness.csv (µrad). Default: not written")
_JSON_HELP = ("write the fitted parameters with standard and expanded uncertainties and "
              "the χ² test outcome as a results JSON document (schema version 1). Default: "
              "not written")
_XML_HELP = ("write the same results as QIF-like XML (MeasurementResults: machine, "
             "artefact, one characteristic per parameter with value, unit, standard "
             "uncertainty, coverage factor, expanded uncertainty; the χ² test). Default: "
             "not written")
_K_HELP = ("coverage factor k of the expanded uncertainties U = k·u in the results files, "
           "1 to 10 (default: %(default)s, about 95 %% for a normal distribution)")
_UNDET_HELP = ("write the tables even when the model has parameter combinations the data "
               "do not determine (their corrections are then an arbitrary choice and the "
               "uncertainties empty); without it such a model is refused (exit 2)")


def _step(text: str):
    """A positive step in mm, or three comma-separated ones."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a step in mm (e.g. 100) or three (100,100,50), found {text[:40]!r}"
        ) from None
    if len(vals) not in (1, 3) or not all(math.isfinite(v) and 0.1 <= v <= 1e4 for v in vals):
        raise argparse.ArgumentTypeError(
            f"expected one or three steps from 0.1 to 10000 mm, found {text[:40]!r}")
    return vals[0] if len(vals) == 1 else tuple(vals)


def _coverage(text: str) -> float:
    try:
        k = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a coverage factor (e.g. 2), found {text[:40]!r}") from None
    if not (math.isfinite(k) and 1.0 <= k <= 10.0):
        raise argparse.ArgumentTypeError(f"expected a coverage factor from 1 to 10, found {k:g}")
    return k


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``export`` (every one with the help text a metrologist reads)."""
    p.add_argument("model", metavar="MODEL.json", help=_MODEL_HELP)
    p.add_argument("--grid-step-mm", type=_step, default=100.0, metavar="MM",
                   help=_GRID_STEP_HELP)
    p.add_argument("--axis-step-mm", type=_step, default=None, metavar="MM",
                   help=_AXIS_STEP_HELP)
    p.add_argument("--probe", default=None, metavar="NAME", help=_PROBE_HELP)
    p.add_argument("--grid", metavar="OUT.csv", help=_GRID_HELP)
    p.add_argument("--axis-tables", metavar="DIR", help=_AXES_HELP)
    p.add_argument("--results-json", metavar="OUT.json", help=_JSON_HELP)
    p.add_argument("--results-xml", metavar="OUT.xml", help=_XML_HELP)
    p.add_argument("--coverage-factor", type=_coverage, default=2.0, metavar="K",
                   help=_K_HELP)
    p.add_argument("--allow-undetermined", action="store_true", help=_UNDET_HELP)


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``export`` sub-command to the sub-parsers of ``cli.build_parser``."""
    p = subparsers.add_parser(
        "export", help="compensation tables (3-D grid, per-axis) and results files (JSON, "
                       "QIF-like XML) from a saved model")
    add_arguments(p)
    p.set_defaults(func=command)
    return p


AXIS_TABLE_FILES = (*(f"axis_{a}.csv" for a in AXES), "squareness.csv")
"""The files ``--axis-tables DIR`` writes into its folder."""


def output_files(args: argparse.Namespace) -> tuple[dict, dict]:
    """``(outputs, folders)`` of ``export`` for ``io.check_outputs``: option -> file(s)
    written, option -> folder created."""
    outs = {"--grid": args.grid, "--results-json": args.results_json,
            "--results-xml": args.results_xml}
    folders = {}
    if args.axis_tables:
        folders["--axis-tables"] = args.axis_tables
        outs["--axis-tables"] = [Path(args.axis_tables) / f for f in AXIS_TABLE_FILES]
    return outs, folders


def command(args: argparse.Namespace) -> dict:
    """Write the files asked for; the JSON summary (what was written where).

    Raises DataError / OSError on bad input (one line each): an output that is the model
    file, a folder or another output is refused before any work. Every file is computed
    before the first is written, so a refusal leaves none behind, and each is written
    whole or not at all.
    """

    source = Path(args.model).name
    outs = (args.grid, args.axis_tables, args.results_json, args.results_xml)
    if not any(outs):
        raise DataError("nothing to write: give --grid, --axis-tables, --results-json "
                        "and/or --results-xml.", file=source)
    files, folders = output_files(args)
    check_outputs(files, [args.model], folders=folders)
    model = load_model(args.model)
    try:
        return _write(args, model, source)
    except DataError:
        raise
    except ValueError as exc:  # a step or coverage the model's strokes cannot take
        raise DataError(str(exc), file=source) from None


def _write(args, model, source) -> dict:
    """Compute the files of ``args`` from ``model``, then write them; the summary."""

    step = args.grid_step_mm
    axis_step = args.axis_step_mm if args.axis_step_mm is not None else step
    if isinstance(axis_step, tuple):
        axis_step = axis_step[0]
    out = {"model": source, "spec": model.spec, "layout": model.terms.layout,
           "fails_chi2_test": model.summary.get("fails_chi2_test")}
    texts = {}  # path -> text
    if args.grid:
        g = ct.compensation_grid(model, step, probe=args.probe,
                                 allow_undetermined=args.allow_undetermined)
        texts[Path(args.grid)] = ct.grid_csv(model, g, args.probe, source)
        out["grid"] = {"file": str(args.grid), "nodes": len(g),
                       "max_correction_um": float(g[["cx_um", "cy_um", "cz_um"]].abs()
                                                  .max().max())}
    if args.axis_tables:
        d = Path(args.axis_tables)
        files = ct.axis_tables_csv(model, axis_step, source,
                                   allow_undetermined=args.allow_undetermined)
        texts.update({d / name: text for name, text in files.items()})
        out["axis_tables"] = {"dir": str(d), "files": sorted(files)}
    kw = {"coverage_factor": args.coverage_factor, "source": source}
    if args.results_json:
        texts[Path(args.results_json)] = rx.results_json(model, **kw)
        out["results_json"] = str(args.results_json)
    if args.results_xml:
        texts[Path(args.results_xml)] = rx.results_xml(model, **kw)
        out["results_xml"] = str(args.results_xml)
    if args.axis_tables:
        Path(args.axis_tables).mkdir(parents=True, exist_ok=True)
    atomic_write_all(texts)  # all or nothing: never a grid beside another model's tables
    return out


def run(args: argparse.Namespace) -> int:
    """Run ``export`` on parsed arguments: summary JSON on stdout and 0, or one line on
    stderr naming the file, row and column and 2."""
    try:
        out = command(args)
    except (DataError, ValueError, KeyError, OSError) as exc:
        text = " ".join(str(exc).split()) or type(exc).__name__
        if isinstance(exc, OSError) and exc.filename:
            text = f"{Path(str(exc.filename)).name}: {exc.strerror or text}"
        name = Path(args.model).name
        if name not in text and not isinstance(exc, OSError):
            text = f"{name}: {text}"
        print(f"error: {text[:400]}", file=sys.stderr)
        return 2
    print(json.dumps(out, indent=1))
    return 0

"""``python -m cmm_core export``: compensation tables and results files from a saved model.

Formats in docs/compensation.md; the QIF 3.0 document of ``--qif`` in docs/formats.md ("QIF
3.0"). A model file is detached from its data, and a QIF document holds the measured ball
centres too: ``--qif`` reads the data the model was fitted to, as the fitting commands read
them, and refuses any data file that is not one of the inputs the model file records (by
SHA-256), so that a document never pairs one fit's parameters with other measurements. :func:`add_parser` adds the sub-command to a parser (its
options are in :mod:`.parser`; its ``func`` runs :func:`command`, which returns the JSON
summary ``cli.main`` prints); :func:`run` runs it on its own: the summary on stdout, exit
status 0; bad input exits with status 2 and one line on stderr naming the file, row and
column. No output may be the model file or another output (:func:`output_files`,
``io.check_outputs``); each file is written whole or not at all, and the files of one run
all or none (``io.atomic_write_all``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .. import __version__
from ..export import comp_tables as ct
from ..export import load_model, probe_offset, qif_document
from ..export import results as rx
from ..export.model_file import Model
from ..io import (
    MSL_PARAMETERS,
    MSL_SQUARENESS_CARRIERS,
    DataError,
    Dataset,
    InputFile,
    atomic_write_all,
    check_outputs,
    input_file,
    msl_metadata_text,
    msl_parameters,
    read_bytes,
)
from ..machine import AXES
from .inputs import dataset_of
from .options import msl_metadata_beside
from .parser import add_command


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``export`` sub-command to ``subparsers`` (as ``cli.build_parser`` does; its
    options: ``parser.add_export_arguments``)."""
    return add_command(subparsers, "export")


AXIS_TABLE_FILES = (*(f"axis_{a}.csv" for a in AXES), "squareness.csv")
"""The files ``--axis-tables DIR`` writes into its folder."""


_QIF_DATA = ("meas", "setup", "certificate", "mapping", "msl", "msl_metadata")
"""The options of ``export`` naming the data files ``--qif`` reads."""


def _data_files(args: argparse.Namespace) -> list:
    """The data files given for ``--qif`` (measurements, setup, certificate, mapping, MSL
    snapshots and metadata), in the order of :data:`_QIF_DATA`."""
    out = []
    for attr in _QIF_DATA:
        v = getattr(args, attr, None)
        out += v if isinstance(v, list) else ([v] if v else [])
    return out + msl_metadata_beside(args)  # read by --msl-metadata's default


def output_files(args: argparse.Namespace) -> tuple[dict, dict]:
    """``(outputs, folders)`` of ``export`` for ``io.check_outputs``: option -> file(s)
    written, option -> folder created."""
    outs = {"--grid": args.grid, "--results-json": args.results_json,
            "--results-xml": args.results_xml, "--qif": getattr(args, "qif", None),
            "--msl-parameters": getattr(args, "msl_parameters", None)}
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
    qif = getattr(args, "qif", None)
    outs = (args.grid, args.axis_tables, args.results_json, args.results_xml, qif,
            getattr(args, "msl_parameters", None))
    if not any(outs):
        raise DataError("nothing to write: give --grid, --axis-tables, --results-json, "
                        "--results-xml, --qif and/or --msl-parameters.", file=source)
    data = _data_files(args)
    if data and not qif:  # data nothing reads would look as if it shaped the tables
        raise DataError("measurement, setup and certificate files are read for --qif "
                        "only; the tables and results come from the model file alone.",
                        file=Path(data[0]).name, hint="give --qif OUT.qif, or leave the "
                        "data files out.")
    files, folders = output_files(args)
    check_outputs(files, [args.model, *data], folders=folders)
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
    texts: dict[Path, str | bytes] = {}  # path -> text (the QIF document as bytes)
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
    notes: list[str] = []
    if getattr(args, "qif", None):
        doc, qif_notes = _qif_bytes(args, model, source)
        texts[Path(args.qif)] = doc
        out["qif"] = str(args.qif)
        notes += qif_notes
    if getattr(args, "msl_parameters", None):
        text, msl_notes = msl_parameters_text(model, source, probe=args.probe,
                                              allow_undetermined=args.allow_undetermined)
        texts[Path(args.msl_parameters)] = text
        out["msl_parameters"] = str(args.msl_parameters)
        notes += msl_notes
    if notes or getattr(args, "qif", None):
        out["notes"] = notes
    if args.axis_tables:
        Path(args.axis_tables).mkdir(parents=True, exist_ok=True)
    atomic_write_all(texts)  # all or nothing: never a grid beside another model's tables
    return out


def msl_parameters_text(model: Model, source: str, *, probe: str | None = None,
                        allow_undetermined: bool = False) -> tuple[str, list[str]]:
    """The model as an MSL cmm-error-map metadata file (``io.msl_metadata_text``): the
    machine this program fitted in the form MSL's app saves, read back by
    ``io.read_msl_metadata`` (MSL's app itself loads snapshots only: its parameters are
    set by hand, docs/msl-format.md); and the notes on what it holds.

    The coefficients become MSL's parameters by the inverse of the reader's conventions
    (``io.msl_parameters``: power series in mm and rad, a moving table's odd powers and
    the squareness back in MSL's sign). No provenance line: MSL's files start with
    ``save time`` and the readers take every line after ``model parameters`` to be a
    parameter; the header's ``title`` names this program, the model file and its SHA-256.

    Raises
    ------
    DataError
        A model with undetermined combinations (unless ``allow_undetermined``: they are
        then written at the fit's minimum-norm choice), a layout MSL does not know, a
        probe the model lacks.
    """
    if model.undetermined and not allow_undetermined:
        raise DataError("the model has parameter combinations the data do not determine: "
                        "their MSL parameters would be an arbitrary (minimum-norm) choice.",
                        file=model.name, column="undetermined",
                        hint="measure more placements and refit, or give "
                             "--allow-undetermined to write them as the fit chose them.")
    terms = model.terms
    coefficients = dict(zip(terms.labels, (float(v) for v in model.coef), strict=True))
    try:
        params, left_out = msl_parameters(coefficients, terms.layout, terms.range_mm)
        digest = model.source.sha256[:12] if model.source is not None else "unknown"
        title = f"cmm-error-lab {__version__} fit {source} sha256 {digest} {model.spec}"
        named = model.provenance.machine if model.provenance is not None else None
        text = msl_metadata_text(params, terms.layout, terms.range_mm,
                                 probe_name=probe or "ram",
                                 probe_mm=probe_offset(model, probe), title=title,
                                 name=Path(source).stem,
                                 machine=named or f"cmm-error-lab fit {Path(source).stem}")
    except ValueError as exc:  # MSL knows four layouts
        raise DataError(str(exc), file=source,
                        hint="MSL's model has no gantry or horizontal arm.") from None
    present = {n for n, _ in terms.functions} | set(terms.labels)
    absent = [p for p in MSL_PARAMETERS[:18]
              if ("d" if p[0] == "T" else "r") + p[1:].lower() not in present
              and not (p in MSL_SQUARENESS_CARRIERS.values()
                       and {k for k, v in MSL_SQUARENESS_CARRIERS.items() if v == p}
                       & present)]
    order = max((o for _, o in terms.functions), default=1)
    notes = [f"msl parameters: {len(MSL_PARAMETERS)} lines in MSL's form (power series, "
             "lowest power first, mm and rad; a moving table's odd powers and each "
             "squareness, in Tyx, Tzx, Tzy, back in MSL's sign), "
             + ("2 coefficients each, as MSL's own files." if order <= 1 else
                f"{order + 1} coefficients each (order {order}); MSL's own files have 2.")]
    if absent:
        notes.append(f"msl parameters: {', '.join(absent)} are not in the model "
                     f"({model.spec}): written as zero; the W terms are zero.")
    if left_out or model.parts:
        notes.append("msl parameters: MSL's form cannot hold "
                     + ", ".join([*left_out, *model.parts]) + ": left out.")
    if model.undetermined:
        notes.append("msl parameters: the model's undetermined combinations are written at "
                     "the fit's minimum-norm choice (--allow-undetermined), not measured.")
    notes.append("msl parameters: the header's artefact lines say no artefact (one ball at "
                 "the origin); probe " + (probe or "none, the ram reference point") + ".")
    notes.append("msl parameters: MSL's app loads snapshots only, no metadata file: enter "
                 "the parameters there by hand (docs/msl-format.md, 'Writing MSL's form').")
    return text, notes


def _qif_bytes(args: argparse.Namespace, model: Model, source: str) -> tuple[bytes, list]:
    """The QIF 3.0 document of ``model`` and the data of ``args`` (``export.qif_document``);
    and the notes on how the data were read.

    Raises DataError (one line) without data, with a data file that is not one of the
    model's recorded inputs, or without a certificate (QIF's nominal centres)."""
    given = [input_file(Path(p).name, read_bytes(Path(p), None)[0]) for p in _data_files(args)]
    if not given:
        raise DataError("--qif needs the data the model was fitted to: the document holds "
                        "the measured ball centres, which a model file does not.",
                        file=source, hint="give the MEAS files, --setup and --certificate "
                        "that 'fit --save' read.")
    _refuse_other_data(model, given, source)
    ds = dataset_of(args)
    if ds.certificate is None:
        raise DataError("--qif needs the plate certificate: a QIF calibration document "
                        "states the nominal ball centres.", file="command line",
                        hint="give --certificate CERT.csv, the one the model was fitted with.")
    # the provenance of the other outputs (the model file, the machine and date it names)
    # with the data files read: the document's inputs are both
    doc = qif_document(model, ds, provenance=model.derived_provenance(given),
                       coverage_factor=args.coverage_factor)
    return doc, [*ds.notes, *_left_out(ds, model)]


def _refuse_other_data(model: Model, given: list[InputFile], source: str) -> None:
    """Refuse data files that are not among the inputs the model file records."""
    p = model.provenance
    if p is None or not p.inputs:
        raise DataError("records no input files (a model file of release 0.7 or earlier), "
                        "so the data of --qif cannot be checked against it.", file=source,
                        hint="fit the data again with 'fit --save' and export that model.")
    known = {f.sha256 for f in p.inputs}
    for f in given:
        if f.sha256 not in known:
            names = ", ".join(g.name for g in p.inputs[:8]) + (" ..." if len(p.inputs) > 8
                                                                else "")
            raise DataError(f"is not one of the files {source} was fitted to (its SHA-256 "
                            f"{f.sha256[:12]}... is not among the model's inputs: {names}); "
                            "the QIF document would pair the model's parameters with other "
                            "measurements.", file=f.name,
                            hint="give the files 'fit --save' read, unchanged, or fit these "
                            "data and export that model.")


def _left_out(ds: Dataset, model: Model) -> list:
    """The note on placements of the data the model was not fitted to (the document
    leaves them out, ``export.qif_document``); none when the data are the fit's."""
    keep = model.summary.get("placements")
    left = sorted(set(ds.positions) - set(keep)) if isinstance(keep, list) else []
    return [f"placement(s) {', '.join(left)} left out of the QIF document: the model was "
            "not fitted to them."] if left else []


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

"""``fit``, ``diagnose`` and ``gp``: the fitting commands (registered in :mod:`.parser`;
each returns the JSON-ready result ``cli.main`` prints)."""

from __future__ import annotations

import argparse
from dataclasses import replace

from ..analysis import measured_error_from_residuals_um
from ..diagnosis import diagnose, kinematic_basis
from ..export import save_model
from ..gp import gp_components
from ..model import Observations, fit, select, summary
from .inputs import (
    data_of,
    dataset_of,
    exclusions_of,
    fit_args_of,
    instruments_of,
    notes_of,
    settle_defaults,
    sigma_of,
)
from .records import provenance_of


def cmd_fit(args: argparse.Namespace) -> dict:
    settle_defaults(args)  # --order, --sigma-um from the MSL files where they state them
    instruments = instruments_of(args)
    data = data_of(args, instruments)
    outliers, exclude = exclusions_of(data, args.exclude_outliers)
    sigma_um, sigma = sigma_of(args, data, exclude, args.model)
    r = fit(data, args.model, instruments=instruments or None,
            **fit_args_of(args, args.model, exclude, sigma_um=sigma_um))
    if args.save:
        save_model(r, args.save, provenance_of(args, data))
    return {**r.summary(), "sigma": sigma,
            "parameters": {lab: {"value": v, "u": u, "u_inflated": ui, "unit": un}
                           for lab, v, u, ui, un in zip(r.labels, r.values, r.u, r.u_inflated,
                                                        r.units, strict=True)},
            "unidentifiable": r.unidentifiable, "null_combinations": r.null_combinations,
            "null_words": r.null_words,
            "instruments": summary(r),
            "outliers": outliers, "excluded": [list(e) for e in exclude],
            "notes": notes_of(args, data)}


def cmd_diagnose(args: argparse.Namespace) -> dict:
    settle_defaults(args)
    instruments = instruments_of(args)
    data = data_of(args, instruments)
    notes = notes_of(args, data)
    outliers, exclude = exclusions_of(data, args.exclude_outliers)
    sigma_um, sigma = sigma_of(args, data, exclude, args.baseline)
    if instruments and not isinstance(data, Observations):  # they ride on the observations into every model the diagnosis fits
        data = replace(select(data, exclude=exclude), instruments=tuple(instruments))
    d = diagnose(data, args.baseline,
                 **fit_args_of(args, args.baseline, exclude, sigma_um=sigma_um))
    out = d.to_dict()
    out["certificate_u_source"] = d.baseline.certificate_u_source
    out["sigma"] = sigma
    out["outliers"] = outliers
    out["notes"] = notes
    return out


def cmd_gp(args: argparse.Namespace) -> dict:
    settle_defaults(args)
    data = dataset_of(args)
    _, exclude = exclusions_of(data, args.exclude_outliers)
    spec = "kinematic21" if args.mean == "kinematic" else "rigid"
    r = fit(data, spec, **fit_args_of(args, spec, exclude))
    obs = r.problem.obs
    basis = None
    if args.mean == "kinematic":

        basis = kinematic_basis(r)
    comps = gp_components(obs.r_mm, measured_error_from_residuals_um(r.residuals_um),
                          mean="zero" if basis is not None
                          else args.mean, kernel=args.kernel, basis=basis,
                          probe_mm=obs.p_mm if args.inputs == "probe" else None)
    return {"mean": args.mean, "kernel": args.kernel, "notes": notes_of(args, data),
            "inputs": "ram position and probe offset" if comps.probe_input else "tip",
            "loo_coverage_95": comps.loo_coverage(0.95), "components": comps.summary()}

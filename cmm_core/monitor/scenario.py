"""The same simulated machine measured again: for tests, benches and the sample history.

A calibration is simulated by ``model.simulate`` with random kinematic coefficients; an
interim check of *that* machine must be simulated with the same coefficients (the
machine's truth), another seed (new noise, a new plate certificate) and, for a machine
that changed, some coefficients moved (a squareness after a crash).
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..io import Dataset, resolve
from ..machine import KinematicTerms
from ..model import Simulation, parse_spec, simulate, thesis_machine_setup


def remeasured(calibration: Simulation, seed: int, *, changes: dict | None = None,
               probes_per_position: dict | None = None,
               effects: dict | None = None, same_plate: bool = False) -> Simulation:
    """The machine of ``calibration`` measured again with seed ``seed``.

    Parameters
    ----------
    calibration : Simulation
        A simulation (its ``config`` and ``truth``).
    seed : int
        Seed of the new measurement (noise, plate form and certificate draws).
    changes : dict, optional
        Label -> change of the true kinematic coefficient (µm, µrad), e.g. ``{"sxy": 2.0}``.
    probes_per_position : dict, optional
        Placement -> styli of the new measurement (default the calibration's): one entry
        simulates a check with one placement.
    effects : dict, optional
        Simulator effects of the new measurement (``simulate``'s ``effects``, e.g. a
        ``drift`` the stored model does not have); default the calibration's.
    same_plate : bool
        The same plate and certificate as the calibration's (a yearly recalibration with
        the lab's own plate): the new readings are those of the calibration's true plate
        (shifted by its form's difference from the new draw's, in each placement's
        frame; the machine's error changes by well under a nanometre over such µm
        shifts) and the certificate is the calibration's, so both share its errors.

    Returns
    -------
    Simulation
    """
    cfg = copy.deepcopy(calibration.config)
    km = cfg["kinematic"]
    truth = {lab: float(v) for lab, v in calibration.truth.items()
             if lab in set(km.get("coefficients", {})) | _kinematic_labels(calibration)}
    for lab, dv in (changes or {}).items():
        if lab not in truth:
            raise ValueError(f"{lab!r} is not a kinematic coefficient of the simulation "
                             f"(known: {', '.join(sorted(truth))}).")
        truth[lab] += float(dv)
    km["coefficients"] = truth
    cfg["seed"] = int(seed)
    if effects is not None:
        cfg["effects"] = copy.deepcopy(effects)
    if cfg["setup"] is None:
        cfg["setup"] = thesis_machine_setup()
    setup = cfg["setup"]
    # the stored configuration has the defaults merged in: the default placements'
    # styli are dropped, as those of placements the new measurement leaves out
    ppp = probes_per_position if probes_per_position is not None else \
        {p: q for p, q in cfg["probes_per_position"].items() if p in setup["positions"]}
    cfg["probes_per_position"] = copy.deepcopy(ppp)
    setup["positions"] = {p: setup["positions"][p] for p in ppp}
    new = simulate(cfg)
    return _on_the_plate_of(new, calibration) if same_plate else new


def _on_the_plate_of(new: Simulation, calibration: Simulation) -> Simulation:
    """``new`` measured on ``calibration``'s plate, with its certificate."""
    data, cert = new.dataset, calibration.dataset.certificate
    if cert is None:
        raise ValueError("same_plate needs a calibration with a certificate.")
    m = data.meas.copy()
    shift = calibration.true_plate_mm - new.true_plate_mm  # (B, 3) plate frame, mm
    index = {int(b): i for i, b in enumerate(cert.balls)}
    for p, rows in m.groupby("position").groups.items():
        R = data.setup.positions[p].rotation
        d = shift[[index[int(b)] for b in m.loc[rows, "ball"]]] @ R.T
        m.loc[rows, ["x_mm", "y_mm", "z_mm"]] += d
    fresh = m.drop(columns=["mx_mm", "my_mm", "mz_mm"], errors="ignore")
    meas = resolve(fresh, data.setup, cert)
    return dataclasses.replace(new, dataset=Dataset(meas, data.setup, cert, data.name),
                               true_plate_mm=np.array(calibration.true_plate_mm))


def _kinematic_labels(sim: Simulation) -> set:
    """The kinematic coefficient labels of a simulation's truth (its effects' labels are
    the blocks' own: they start with the block's token)."""
    km = sim.config["kinematic"]
    spec = parse_spec(km["spec"], default_order=int(km["order"]))
    setup = sim.dataset.setup
    return set(KinematicTerms(spec.active, tuple(setup.range_mm), spec.periods).labels)

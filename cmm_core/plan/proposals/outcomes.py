"""What a chosen proposal leads to: one click simulated (:func:`simulate_outcomes`: each
rival in turn the truth at its size fitted on the current data, :func:`truth_config`; the
proposal simulated, appended and the data diagnosed again) and the proposal as a ``plan``
file (:func:`plan_file`, docs/planning.md).
"""

from __future__ import annotations

import copy
from collections.abc import Iterable
from dataclasses import dataclass, replace

from ..._blas import single_blas_thread
from ...diagnosis import diagnose
from ...io import Dataset
from ...model import BY_TOKEN, FitResult, Observations, select
from .append import _machine, append_measurement, instrument_of, repeat_from_fit
from .candidates import plate_grid
from .ranking import Proposal
from .rivals import BASELINE, PLACEMENT_SCALE, fit_rivals


def truth_config(fitted: FitResult, exclude_positions: Iterable[str] = ()) -> dict:
    """Simulator keys (``kinematic``, ``effects``) that make a rival's fit the truth: all
    its kinematic coefficients and its effects' fitted parameters (``Block.injection``);
    parameters of the data's own placements (drift, ...) are left out, since a new
    placement has its own."""
    exclude_positions = tuple(exclude_positions)
    vals = dict(zip(fitted.labels, fitted.values, strict=True))
    groups = dict(zip(fitted.labels, fitted.groups, strict=True))
    kin = {lab: float(v) for lab, v in vals.items() if groups[lab] == "kinematic"}
    spec = ",".join(t for t in fitted.problem.spec.to_string().split(",")
                    if t.partition(":")[0] not in BY_TOKEN)
    effects = {}
    for tok, block in BY_TOKEN.items():
        own = {lab: float(v) for lab, v in vals.items() if groups[lab] == tok
               and not any(lab.startswith(f"{p}.") for p in exclude_positions)}
        body = block.injection(own) if own else None
        if body:
            effects[tok] = body
    return {"kinematic": {"spec": spec, "order": int(fitted.problem.spec.orders[0][1])
                          if fitted.problem.spec.orders else 2, "coefficients": kin},
            "effects": effects}


@dataclass(frozen=True)
class Outcome:
    """The diagnosis of the data with a proposal appended, simulated with one rival as
    the truth.

    Attributes
    ----------
    truth : str
        The rival taken as the truth (at its size fitted on the current data).
    verdict : str or None
        The diagnosis's verdict on the augmented data.
    aliases : list of str
        The aliases it still reports for its first candidate.
    separated : bool
        The verdict is the truth and no other rival is still its alias.
    message : str
        The diagnosis's message.
    """

    truth: str
    verdict: str | None
    aliases: list
    separated: bool
    message: str


@single_blas_thread
def simulate_outcomes(data: Dataset, proposal: Proposal, *, baseline: str = "kinematic21",
                      order: int = 2, plate: str | None = None, sigma_um: float = 0.5,
                      seed: int = 0) -> dict:
    """One click, simulated: for each rival as the truth (its fit on the current data; each
    rival of an alias set of three or more), simulate the proposal with noise σ, append
    it to the data and run the diagnosis. Returns ``{rival: Outcome}``.

    An instrument candidate is measured on the machine of each rival's fitted kinematic
    errors (its effects belong to the plate's placements and styli, which an instrument
    does not see), with the instrument simulator's own noise, and fitted jointly with the
    data as every instrument file is."""
    if PLACEMENT_SCALE in proposal.rivals:
        raise ValueError(f"{PLACEMENT_SCALE} is outside the catalogue: the virtual CMM "
                         "cannot simulate it as the truth (score the proposal instead).")
    if BASELINE in proposal.rivals:
        raise ValueError(f"against the {BASELINE} the outcome is the effect's own test: "
                         "its power is the proposal's score (nothing to simulate).")
    rf = fit_rivals(data, proposal.rivals, baseline=baseline, order=order, plate=plate,
                    sigma_um=sigma_um)
    out = {}
    cand = proposal.candidate
    aug: Dataset | Observations
    for t in proposal.rivals:
        others = [o for o in proposal.rivals if o != t]
        if cand.repeat:  # the same placements: their fitted poses, plate and drift
            aug = repeat_from_fit(data, cand, rf.fits[t], noise_um=sigma_um, seed=seed)
        elif cand.instrument:
            machine = _machine(data, truth_config(rf.fits[t])["kinematic"])
            obs = select(data)
            aug = replace(obs, instruments=(*obs.instruments,
                                            instrument_of(cand, machine, seed=seed)))
        else:
            cfg = {**truth_config(rf.fits[t], data.setup.raw["positions"]),
                   "noise_um": sigma_um}
            aug = append_measurement(data, cand, config=cfg, seed=seed)
        d = diagnose(aug, baseline, order=order, plate=plate, sigma_um=sigma_um)
        al = list(d.candidates[0].aliases) if d.candidates else []
        out[t] = Outcome(t, d.verdict, al, bool(d.verdict == t and not set(others) & set(al)),
                         d.message)
    return out


def plan_file(data: Dataset, proposal: Proposal, *, baseline: str = "kinematic21",
              order: int = 2, noise_um: float = 0.5) -> dict:
    """The proposal as a ``plan`` JSON document (docs/planning.md, "The plan file"): the
    data set's setup with the proposal's placement and styli added, its plate, and two
    strategies: the current placements alone and with the proposal (a repeat: the same
    placements with its balls measured again, ``repeat_at_end``, timed after the data's
    last reading with the set-up of a plate set up again, :func:`_timed_repeat`)."""
    c = proposal.candidate
    if c.instrument:
        raise ValueError(f"{c.name} is an instrument: a plan file holds plate placements, "
                         "styli and repeats only; measure the instrument as proposed (its "
                         "kind, path and offset are in the proposal).")
    grid = plate_grid(data)
    raw = copy.deepcopy(data.setup.raw)
    for pl in raw["positions"].values():
        for key in ("temp_C", "rh_percent"):
            pl.pop(key, None)
    raw["frame"] = "machine"
    raw["positions"] = {**raw["positions"], **copy.deepcopy(c.positions)}
    raw["probes"] = {**raw["probes"], **c.probes}
    now = {p: list(dict.fromkeys(data.meas.loc[data.meas["position"] == p, "probe"]))
           for p in data.setup.raw["positions"]}
    return {"name": f"measure next: {c.name}", "setup": raw,
            "plate": {"rows": grid.rows, "cols": grid.cols, "pitch_mm": grid.pitch_mm},
            "model": {"spec": baseline, "order": order}, "noise_um": noise_um,
            "strategies": [{"name": "current data", "placements": now},
                           {"name": f"with {c.description}",
                            "placements": {**now, **c.probes_of}}
                           | ({"repeat_at_end": {p: _timed_repeat(r)
                                                 for p, r in c.repeat.items()}}
                              if c.repeat else {})]}


def _timed_repeat(r: dict) -> dict:
    """A repeat as a plan strategy's ``repeat_at_end`` entry: its stylus and balls, when
    each is read (``time_min``: after the data's last reading, on the data's clock) and
    the set-up before them (``setup_min``: 0 appended to the current placement, the
    minutes per placement in the next session)."""
    return {"probe": r["probe"], "balls": list(r["balls"]),
            "time_min": [float(t) for t in r["time_min"]],
            "setup_min": float(r.get("setup_min", 0.0))}

"""Virtual CMM: simulate ball-plate measurements with known errors and effects.

The simulation is the exact inverse of the fit's measurement model (see ``fit``): for
every probed ball the true tip centre ``s = R_k c_b' + t_k`` is computed (plate form,
thermal expansion and sag included in ``c_b'``), the scale readings ``x`` that reach it are
found by solving ``x*(x, p_true) = s + drift`` with exact rotations
(``kinematics.invert``), and the CMM reports ``r = x + p_nominal`` plus noise. The effects
are the fit's own blocks (``cmm_core.model.blocks``): each draws its true parameters
(``Block.draw``) and the fit's model at the truth gives the targets (``Problem.targets``).

Configuration keys (all optional; see ``DEFAULT_CONFIG``): ``seed``, ``setup`` (a setup
dict in the documented format (docs/formats.md), frame ``machine``; default the thesis placements),
``probes_per_position``, ``plate`` (``rows, cols, pitch_mm, form_um, certificate_u_um``),
``kinematic`` (``spec``, ``order``, ``coefficients`` by label, ``random_um``,
``random_urad``; the spec may carry periodic scale errors, e.g.
``"kinematic21,periodic_x:180"`` with coefficients ``dxx[sin180]``, ``dxx[cos180]``), ``noise_um``, ``effects`` (``plate_thermal``: ``cte_per_K`` and
``temp_C`` per position [start, finish]; ``plate_sag``: ``uu, uv, vv`` µm;
``probe_offset``: per-probe vectors in µm or ``sd_um``; ``drift``: per-position vectors in
µm/h or ``sd_um_per_h``; ``backlash``: reversal span ``x_um, y_um, z_um``), ``order`` (``row``, ``serpentine``, ``random``),
``probes_interleaved``, ``minutes_per_ball``, ``repeats``, ``repeat_at_end`` (position ->
``{"probe": stylus, "balls": [numbers]}``: those balls measured once more with that stylus
after the position's last reading, before the plate is moved; their ``repeat`` is
``repeats``; with ``time_min``, one per ball, they are read at those times instead, e.g.
in a later session, which must be after the position's own readings), ``artefact`` (``"hole_plate"``:
the plate's features are holes, of which the fit uses the in-plane coordinates only;
default the setup's, a ball plate).
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ..io import (
    THESIS_DIR,
    Certificate,
    DataError,
    Dataset,
    Provenance,
    read_setup,
    resolve,
    write_certificate,
    write_long_csv,
)
from ..io import provenance as make_provenance
from ..machine import KinematicTerms
from ..machine import kinematics as kin
from .blocks import BY_TOKEN
from .blocks.simulation import SimContext
from .effects import parse_spec
from .observations import Observations, approach_directions, setup_layout
from .problem import Problem
from .simulation_config import (
    DEFAULT_CONFIG,
    _check_against_setup,
    _check_config,
    _check_plate_in_machine,
)
from .state import State


def thesis_machine_setup() -> dict:
    """The thesis placements as a machine-frame setup dict (a copy)."""
    raw = json.loads((THESIS_DIR / "setup.json").read_text())
    raw["frame"] = "machine"
    for p in raw["positions"].values():
        p.pop("temp_C", None)
        p.pop("rh_percent", None)
    return raw


@dataclass(frozen=True)
class Simulation:
    """A simulated dataset and the truth behind it.

    Attributes
    ----------
    dataset : Dataset
        Measurements (machine frame), setup and certificate as a user would load them.
    truth : dict
        True parameter values by fit label (kinematic coefficients in µm / µrad, effects).
    true_plate_mm : ndarray (B, 3)
        The true ball centres (the certificate adds its own calibration noise).
    config : dict
        The full configuration used (defaults filled in).
    """

    dataset: Dataset
    truth: dict
    true_plate_mm: np.ndarray
    config: dict

    def write(self, out_dir: str | Path, provenance: Provenance | None = None) -> None:
        """Write ``measurements.csv``, ``setup.json``, ``certificate.csv``, ``truth.json``.

        ``provenance`` (default this process, no inputs) is written as the
        ``provenance`` object of ``setup.json`` (a key the setup reader leaves alone) and
        of ``truth.json``: the simulated data name the software and configuration that
        made them."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        prov = (provenance or make_provenance()).to_dict()
        write_long_csv(self.dataset.meas, out / "measurements.csv")
        (out / "setup.json").write_text(json.dumps({**self.dataset.setup.raw,
                                                    "provenance": prov}, indent=1))
        if self.dataset.certificate is None:
            raise ValueError("a simulation's dataset has a certificate; this one has none")
        write_certificate(self.dataset.certificate, out / "certificate.csv")
        (out / "truth.json").write_text(json.dumps({"truth": self.truth,
                                                    "config": self.config,
                                                    "provenance": prov}, indent=1))


def _merge(base, over):
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) \
            else copy.deepcopy(v)
    return out


def _visit_order(rows, cols, how, rng):
    idx = np.arange(rows * cols).reshape(rows, cols)
    if how == "row":
        return idx.ravel()
    if how == "serpentine":
        idx[1::2] = idx[1::2, ::-1]
        return idx.ravel()
    if how == "random":
        return rng.permutation(rows * cols)
    raise ValueError(f"order must be 'row', 'serpentine' or 'random', got {how!r}.")


def _design(df, setup, plate) -> Observations:
    """The observations a simulated schedule makes, before any reading exists: what the
    fit's model needs to place every ball (``Problem.targets``)."""
    positions = list(dict.fromkeys(df["position"]))
    probes = list(dict.fromkeys(df["probe"]))
    pos = df["position"].map({p: i for i, p in enumerate(positions)}).to_numpy()
    prb = df["probe"].map({q: i for i, q in enumerate(probes)}).to_numpy()
    tm = df["time_min"].to_numpy(float)
    hours = np.zeros(len(df))
    for i in range(len(positions)):
        hours[pos == i] = (tm[pos == i] - tm[pos == i].mean()) / 60.0
    pnom = np.array([setup.probes[q] for q in probes], float)[prb]
    return Observations(
        df, np.zeros((len(df), 3)), pnom, pos, prb, df["ball"].to_numpy() - 1, positions,
        probes, np.arange(1, len(plate) + 1), plate, None,
        df["temp_C"].to_numpy(float) - 20.0, True, hours,
        np.array([setup.positions[p].horizontal for p in positions]),
        np.array([setup.positions[p].rotation for p in positions]),
        np.array([setup.positions[p].origin_mm for p in positions]),
        np.asarray(setup.range_mm, float), False, np.zeros((len(df), 3)),
        setup_layout(setup), artefact=setup.artefact)


def simulate(config: dict | None = None, *, name: str = "simulation config") -> Simulation:
    """Simulate a virtual CMM measuring a ball plate (see the module docstring).

    Parameters
    ----------
    config : dict, optional
        The configuration (see the module docstring); checked completely first.
    name : str
        Name of the configuration (its file) in error messages.

    Raises
    ------
    DataError
        Naming the key that is wrong, what was expected and, for a misspelt label,
        position or probe, the name it resembles.
    """
    config = {} if config is None else config
    _check_config(config, name)
    cfg = _merge(DEFAULT_CONFIG, config)
    rng = np.random.default_rng(cfg["seed"])
    setup_raw = copy.deepcopy(cfg["setup"] or thesis_machine_setup())
    setup_raw["frame"] = "machine"
    if cfg["artefact"] is not None:
        setup_raw["artefact"] = cfg["artefact"]
    pl = cfg["plate"]
    rows, cols, pitch = int(pl["rows"]), int(pl["cols"]), float(pl["pitch_mm"])
    gx, gy = np.meshgrid(np.arange(cols) * pitch, np.arange(rows) * pitch)
    nominal = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(rows * cols)])
    plate = nominal + rng.normal(0, pl["form_um"], nominal.shape) * 1e-3
    plate -= plate[0]
    setup_raw.setdefault("plate", {})["cte_per_K"] = cfg["effects"].get(
        "plate_thermal", {}).get("cte_per_K", setup_raw.get("plate", {}).get("cte_per_K",
                                                                           11.5e-6))
    setup = read_setup(setup_raw, name=f"{name} (setup)")
    if not setup.probes:
        raise DataError("the setup defines no probes; expected at least one offset.",
                        file=name, column="setup.probes")
    _check_plate_in_machine(setup, nominal, name, cfg["probes_per_position"])
    positions = list(setup.positions)
    ppp = cfg["probes_per_position"] or {}
    probes_of = {p: [str(q) for q in ppp.get(p, [setup.positions[p].probe
                                                 or next(iter(setup.probes))])]
                 for p in positions}

    km = cfg["kinematic"]
    try:
        spec = parse_spec(km["spec"], default_order=int(km["order"]))
    except ValueError as exc:
        raise DataError(str(exc), file=name, column="kinematic.spec") from None
    terms = KinematicTerms(spec.active, tuple(setup.range_mm), spec.periods,
                               setup_layout(setup))
    _check_against_setup(cfg, setup, terms, name, config.get("probes_per_position"))
    coef = np.zeros(terms.n)
    for i, lab in enumerate(terms.labels):
        sd = km["random_um"] if terms.unit(lab) == "um" else km["random_urad"]
        coef[i] = km["coefficients"].get(lab, rng.normal(0, sd) if sd else 0.0)
    truth = dict(zip(terms.labels, coef.tolist(), strict=True))

    eff = cfg["effects"]
    sim = SimContext(positions, [str(q) for q in setup.probes],
                     {p: (20.0, 20.0) for p in positions})
    for token, block in BY_TOKEN.items():
        if token in eff:
            truth.update(block.draw(eff[token], sim, rng))
    temps = sim.temps_C

    records = []
    clock = 0.0
    visit = _visit_order(rows, cols, cfg["order"], rng)
    for p in positions:
        seq = [(b, q) for b in visit for q in probes_of[p]] if cfg["probes_interleaved"] \
            else [(b, q) for q in probes_of[p] for b in visit]
        seq = seq * int(cfg["repeats"])
        n_seq = len(seq)
        # balls measured once more at the end of the placement, the plate not moved
        again = cfg["repeat_at_end"].get(p)
        if again:
            seq = seq + [(int(b) - 1, str(again["probe"])) for b in again["balls"]]
        t_start = clock
        times = t_start + np.arange(len(seq)) * cfg["minutes_per_ball"]
        if again and again.get("time_min") is not None:
            # timed repeats (a later session: the plate set up again) are read when
            # given, and the next position follows the position's own readings
            given = np.asarray(again["time_min"], float)
            if given.min() <= times[n_seq - 1]:
                raise ValueError(f"repeat_at_end.{p}.time_min: {given.min():g} min is not "
                                 f"after the position's last reading at "
                                 f"{times[n_seq - 1]:g} min.")
            times[n_seq:] = given
        clock = times[n_seq - 1 if again and again.get("time_min") is not None else -1] \
            + 10.0  # re-fixturing the plate takes time
        t0, t1 = temps[p]
        # start to finish over the position's own readings; balls repeated at its end
        # are read at the finish temperature (the setup's [start, finish] are those of
        # the readings, so a repeat does not change theirs)
        frac = np.minimum((times - times[0]) / max(times[n_seq - 1] - times[0], 1e-9), 1.0)
        for j, (b, q) in enumerate(seq):
            records.append((p, q, int(b) + 1, times[j], t0 + (t1 - t0) * frac[j],
                            j // (len(visit) * len(probes_of[p])) if j < n_seq
                            else int(cfg["repeats"]), j >= n_seq))
    df = pd.DataFrame(records, columns=["position", "probe", "ball", "time_min", "temp_C",
                                        "repeat", "at_end"])
    for col, by_pos in sim.columns.items():
        # recorded like temp_C: start to finish over each position's own readings
        df[col] = np.nan
        for p, (t0, t1) in by_pos.items():
            sel = (df["position"] == p).to_numpy()
            tm = df.loc[sel, "time_min"].to_numpy()
            own = tm[~df.loc[sel, "at_end"].to_numpy()]
            df.loc[sel, col] = t0 + (t1 - t0) * np.minimum(
                (tm - own[0]) / max(np.ptp(own), 1e-9), 1.0)
    df = df.drop(columns="at_end")
    # the fit's own model at the truth, inverted (see the module docstring)
    model = parse_spec(",".join([km["spec"], *(t for t in BY_TOKEN if t in eff)]),
                       default_order=int(km["order"]))
    prob = Problem(_design(df, setup, plate), model, "fixed")
    state = State(plate.copy(), prob.obs.R0.copy(), prob.obs.t0_mm.copy(),
                  np.array([truth.get(lab, 0.0) for lab in prob.layout.labels]))
    x = kin.invert(terms, coef, *prob.targets(state))
    if eff:
        # effects of the readings themselves (the approach direction of backlash, the
        # scale reading of machine_thermal) are known once the machine has moved: a
        # second inversion with the first readings (their change is below 1e-9 mm)
        prob = Problem(replace(prob.obs, r_mm=x + prob.obs.p_mm,
                               approach=approach_directions(x)), model, "fixed")
        x = kin.invert(terms, coef, *prob.targets(state))
    pnom = prob.obs.p_mm
    r = x + pnom + rng.normal(0, cfg["noise_um"], x.shape) * 1e-3
    df["x_mm"], df["y_mm"], df["z_mm"] = r.T
    if cfg["repeats"] <= 1 and not cfg["repeat_at_end"]:
        df = df.drop(columns="repeat")
    df["source"] = "measurements.csv"
    df["row"] = np.arange(2, len(df) + 2)
    cu = float(pl["certificate_u_um"])
    cert_xyz = plate + rng.normal(0, cu, plate.shape) * 1e-3 if cu > 0 else plate.copy()
    cert = Certificate(np.arange(1, rows * cols + 1), cert_xyz,
                       np.full(plate.shape, max(cu, 1e-3)))
    meas = resolve(df, setup, cert)
    return Simulation(Dataset(meas, setup, cert, name=f"simulated (seed {cfg['seed']})"),
                      truth, plate, cfg)

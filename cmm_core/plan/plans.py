"""Plan before you measure: evaluate a ball-plate measurement plan from its design alone.

A plan is a machine and its placements (a setup), a plate (rows, columns, pitch,
certificate uncertainty), the styli used in each placement, repeats, the measurement
order, the probing noise σ and the model the data will be fitted with. Without any
measurement this module reports what a fit of such data would report:

- the parameter combinations the design leaves undetermined (by name, as the fit writes
  them), and the parameters involved;
- U1, U2, U3 as thesis §4.5.3 and tables 4.1-4.3 define them (``uncertainty.evaluate``);
- the standard uncertainty of every error function over its stroke;
- the detection limit of every catalogue effect (``detect``);
- the measuring time.

How. The plan is simulated on the virtual CMM without noise and without errors
(``simulate``) and fitted with the real fit (``model.fit``). At zero residual the fit stands
at the nominal linearisation, so its covariance is the design's ``σ² (JᵀJ)⁺`` on the
constrained problem (law of propagation of uncertainty, JCGM 100 §5.1.2; thesis
appendix 2 constraints) and its null space is the design's: the undetermined
combinations are found by the same code, with the same rank rule, as on real data. The
only approximation is the linearisation point: a fit of real data linearises at its
estimate, micrometres from nominal, which changes uncertainties by parts per million.

The plan file format (``files``) is described in ``docs/planning.md``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any, Literal, overload

import numpy as np

from ..io import Certificate, Dataset
from ..model import FitResult, fit, simulate

STROKE_POINTS = 11
"""Points along each stroke at which error-function uncertainties are reported."""


@dataclass(frozen=True)
class Plan:
    """One measurement strategy, fully specified (defaults filled in).

    Attributes
    ----------
    name : str
        Name of the strategy (shown in tables and the JSON).
    setup : dict
        Setup in the documented setup format (machine frame) holding this strategy's
        placements only.
    probes_of : dict
        Placement name -> tuple of stylus names measured in it.
    plate : dict
        ``rows``, ``cols``, ``pitch_mm`` (mm), ``certificate_u_um`` (µm, standard
        uncertainty of each certified coordinate) and ``geometry`` (fixed, prior, free).
    model : dict
        ``spec`` and ``order`` of the model the data will be fitted with; ``prior_um`` and
        ``prior_urad``, the expected size of the kinematic coefficients (simulations and
        the designer's Bayesian regulariser); ``alpha``, the diagnosis's family-wise
        false-alarm rate; ``periods_mm``, the period (mm) per axis at which periodic scale
        errors are judged.
    noise_um : float
        Probing repeatability σ, standard deviation of one coordinate in µm.
    measurement : dict
        ``order`` (row, serpentine, random), ``probes_interleaved``, ``repeats``,
        ``minutes_per_ball`` and ``minutes_per_placement`` (minutes).
    seed : int
        Seed of the random measurement order (order ``random``) and of U2/U3's points.
    repeat_at_end : dict
        Placement -> ``{"probe": stylus, "balls": [numbers]}``: balls measured once more
        with one of the placement's styli after its last reading, before the plate is
        moved (a repeat tells a placement's drift from a stylus's offset,
        docs/proposals.md); optional ``time_min`` (one per ball: read then, e.g. in the
        next session) and ``setup_min`` (the plate set up again first: counted in
        :attr:`time_min`); empty: none.
    """

    name: str
    setup: dict
    probes_of: dict
    plate: dict
    model: dict
    noise_um: float
    measurement: dict
    seed: int = 0
    repeat_at_end: dict = field(default_factory=dict)

    @property
    def n_probings(self) -> int:
        """Probed ball centres the plan measures."""
        balls = self.plate["rows"] * self.plate["cols"]
        return balls * sum(len(q) for q in self.probes_of.values()) * int(
            self.measurement["repeats"]) + sum(len(r["balls"])
                                               for r in self.repeat_at_end.values())

    @property
    def time_min(self) -> float:
        """Measuring time in minutes: probings × minutes per ball plus placements ×
        minutes per placement (fixturing and alignment), plus the set-up of each plate
        set up again for its repeat (``repeat_at_end``'s ``setup_min``)."""
        m = self.measurement
        return float(self.n_probings * m["minutes_per_ball"]
                     + len(self.probes_of) * m["minutes_per_placement"]
                     + sum(r.get("setup_min", 0.0) for r in self.repeat_at_end.values()))

    def with_units(self, probes_of: dict, name: str | None = None) -> Plan:
        """The same plan measuring other placements/styli (placements from ``setup``)."""
        return _build(self, probes_of, name or self.name)


def _build(plan: Plan, probes_of: dict, name: str, repeat_at_end: dict | None = None
           ) -> Plan:
    """The plan measuring ``probes_of``; its repeats at the end are ``repeat_at_end``
    (default: the plan's own, those of placements and styli still measured)."""
    setup = copy.deepcopy(plan.setup)
    setup["positions"] = {p: {**setup["positions"][p], "probe": probes_of[p][0]}
                          for p in probes_of}
    again = plan.repeat_at_end if repeat_at_end is None else repeat_at_end
    again = {p: r for p, r in again.items() if r["probe"] in probes_of.get(p, ())}
    return Plan(name, setup, dict(probes_of), plan.plate, plan.model, plan.noise_um,
                plan.measurement, plan.seed, again)


def simulation_config(plan: Plan, *, seed: int = 0, noise_um: float = 0.0,
                      prior: bool = False, coefficients: dict | None = None,
                      spec: str | None = None, effects: dict | None = None) -> dict:
    """Virtual-CMM configuration (``simulate``) measuring the plan.

    ``noise_um = 0`` and ``prior = False`` give the noise-free, error-free design data;
    ``prior = True`` draws every kinematic coefficient from N(0, prior size²).
    ``coefficients``/``spec``/``effects`` add a hidden effect (detection checks).
    """
    m = plan.measurement
    # recorded plate temperatures go into the data (cte 0: no expansion unless asked), so
    # that the design knows what plate_thermal can see; unrecorded placements are at 20 °C
    pos = plan.setup["positions"]
    eff = copy.deepcopy(effects or {})
    if any(len(pl.get("temp_C", ())) for pl in pos.values()):
        th = eff.setdefault("plate_thermal", {"cte_per_K": 0.0})
        th["temp_C"] = {p: (list(pl.get("temp_C", ())) * 2 or [20.0, 20.0])[:2]
                        for p, pl in pos.items()}
    return {"seed": int(seed), "setup": copy.deepcopy(plan.setup),
            "probes_per_position": {p: list(q) for p, q in plan.probes_of.items()},
            "plate": {"rows": plan.plate["rows"], "cols": plan.plate["cols"],
                      "pitch_mm": plan.plate["pitch_mm"], "form_um": 0.0,
                      "certificate_u_um": 0.0},
            "kinematic": {"spec": spec or plan.model["spec"], "order": plan.model["order"],
                          "coefficients": dict(coefficients or {}),
                          "random_um": plan.model["prior_um"] if prior else 0.0,
                          "random_urad": plan.model["prior_urad"] if prior else 0.0},
            "noise_um": float(noise_um), "effects": eff, "order": m["order"],
            "probes_interleaved": m["probes_interleaved"],
            "minutes_per_ball": m["minutes_per_ball"], "repeats": m["repeats"],
            "repeat_at_end": {p: {"probe": r["probe"], "balls": list(r["balls"])}
                              | ({"time_min": list(r["time_min"])} if "time_min" in r
                                 else {})
                              for p, r in plan.repeat_at_end.items()}}


@overload
def simulate_plan(plan: Plan, *, with_truth: Literal[False] = ...,
                  **kwargs: Any) -> Dataset: ...
@overload
def simulate_plan(plan: Plan, *, with_truth: Literal[True],
                  **kwargs: Any) -> tuple[Dataset, dict]: ...
@overload
def simulate_plan(plan: Plan, *, with_truth: bool,
                  **kwargs: Any) -> Dataset | tuple[Dataset, dict]: ...
def simulate_plan(plan: Plan, *, with_truth: bool = False,
                  **kwargs: Any) -> Dataset | tuple[Dataset, dict]:
    """Data of the plan from the virtual CMM (see :func:`simulation_config`) with the plan's
    certificate uncertainty: the certificate at the true plate for the noise-free design
    data, and off it by N(0, u²) per coordinate for noisy data (studies, Monte Carlo
    checks), as a real certificate is, since fits with the certificate fixed count that
    uncertainty. Returns the Dataset, or ``(Dataset, truth by parameter label)``."""
    sim = simulate(simulation_config(plan, **kwargs), name=f"plan {plan.name!r}")
    d = sim.dataset
    u_um = plan.plate["certificate_u_um"]
    xyz = sim.true_plate_mm.copy()
    if kwargs.get("noise_um", 0.0) > 0:
        rng = np.random.default_rng([int(kwargs.get("seed", 0)), 20261124])
        xyz = xyz + rng.normal(0.0, u_um * 1e-3, xyz.shape)
    if d.certificate is None:
        raise ValueError("the simulated dataset has no certificate")
    cert = Certificate(d.certificate.balls, xyz, np.full(xyz.shape, u_um))
    data = Dataset(d.meas, d.setup, cert, name=f"plan {plan.name}")
    return (data, sim.truth) if with_truth else data


def fit_plan_data(plan: Plan, data: Dataset, spec: str | None = None) -> FitResult:
    """The fit the plan's data will get: the plan's model, order, plate geometry and σ."""
    return fit(data, spec or plan.model["spec"], order=plan.model["order"],
               plate=plan.plate["geometry"], sigma_um=plan.noise_um, max_iter=2000)


def design_fit(plan: Plan) -> FitResult:
    """Fit of the plan's noise-free, error-free data: its covariance and null space are
    the design's (see the module docstring)."""
    return fit_plan_data(plan, simulate_plan(plan, seed=plan.seed))

"""Plan before you measure: evaluate a ball-plate measurement plan from its design alone.

A plan is a machine and its placements (a setup), a plate (rows, columns, pitch,
certificate uncertainty), the styli used in each placement, repeats, the measurement
order, the probing noise σ and the model the data will be fitted with. Without any
measurement this module reports what a fit of such data would report:

- the parameter combinations the design leaves undetermined (by name, as the fit writes
  them), and the parameters involved;
- U1, U2, U3 as thesis §4.5.3 and tables 4.1-4.3 define them (``uncertainty.evaluate``);
- the standard uncertainty of every error function over its stroke;
- the detection limit of every catalogue effect (``plan_detect``);
- the measuring time.

How. The plan is simulated on the virtual CMM without noise and without errors
(``simulate``) and fitted with the real fit (``fit.fit``). At zero residual the fit stands
at the nominal linearisation, so its covariance is the design's ``σ² (JᵀJ)⁺`` on the
constrained problem (law of propagation of uncertainty, JCGM 100 §5.1.2; thesis
appendix 2 constraints) and its null space is the design's: the undetermined
combinations are found by the same code, with the same rank rule, as on real data. The
only approximation is the linearisation point: a fit of real data linearises at its
estimate, micrometres from nominal, which changes uncertainties by parts per million.

The plan file format is described in ``docs/planning.md``.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._blas import single_blas_thread
from .dataset import Dataset
from .effects import MAX_ORDER, parse_spec
from .fit import PLATE_MODES, FitResult, fit
from .io import Certificate, DataError, _cut, read_json, read_setup
from .simulate import simulate
from .uncertainty import evaluate as evaluate_u

TOP_KEYS = ("name", "setup", "plate", "model", "noise_um", "measurement", "strategies",
            "design", "seed")
PLATE_DEFAULTS = {"rows": 5, "cols": 5, "pitch_mm": 133.0, "certificate_u_um": 0.13,
                  "geometry": "fixed"}
MODEL_DEFAULTS = {"spec": "kinematic21", "order": 2, "prior_um": 1.0, "prior_urad": 1.0,
                  "alpha": 0.01, "periods_mm": {}}
MEASUREMENT_DEFAULTS = {"order": "row", "probes_interleaved": False, "repeats": 1,
                        "minutes_per_ball": 0.5, "minutes_per_placement": 10.0}
STRATEGY_KEYS = ("name", "placements", "noise_um", "measurement")
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
    """

    name: str
    setup: dict
    probes_of: dict
    plate: dict
    model: dict
    noise_um: float
    measurement: dict
    seed: int = 0

    @property
    def n_probings(self) -> int:
        """Probed ball centres the plan measures."""
        balls = self.plate["rows"] * self.plate["cols"]
        return balls * sum(len(q) for q in self.probes_of.values()) * int(
            self.measurement["repeats"])

    @property
    def time_min(self) -> float:
        """Measuring time in minutes: probings × minutes per ball plus placements ×
        minutes per placement (fixturing and alignment)."""
        m = self.measurement
        return float(self.n_probings * m["minutes_per_ball"]
                     + len(self.probes_of) * m["minutes_per_placement"])

    def with_units(self, probes_of: dict, name: str | None = None) -> Plan:
        """The same plan measuring other placements/styli (placements from ``setup``)."""
        return _build(self, probes_of, name or self.name)


@dataclass(frozen=True)
class PlanFile:
    """A plan file read and checked.

    Attributes
    ----------
    strategies : list of Plan
        The strategies to evaluate side by side.
    base : Plan
        Every placement of the setup with its default stylus (the pool's geometry).
    design : dict or None
        The ``design`` section (pool, target, criterion), checked by ``plan_design``.
    name : str
        File name for messages.
    """

    strategies: list
    base: Plan
    design: dict | None
    name: str


def _bad(name, column, message, hint=None):
    return DataError(message, file=name, column=column, hint=hint)


def _number(name, column, value, lo, hi, *, integer=False):
    ok = isinstance(value, int | float) and not isinstance(value, bool) and np.isfinite(
        value) and lo <= value <= hi and (not integer or float(value).is_integer())
    if not ok:
        what = "a whole number" if integer else "a number"
        raise _bad(name, column, f"expected {what} from {lo:g} to {hi:g}, found "
                   f"{_cut(value)}.")
    return int(value) if integer else float(value)


def _section(raw, key, defaults, name, prefix=""):
    val = raw.get(key, {})
    if not isinstance(val, dict):
        raise _bad(name, prefix + key, f"expected a JSON object, found {_cut(val)}.")
    extra = sorted(set(map(str, val)) - set(defaults))
    if extra:
        raise _bad(name, f"{prefix}{key}.{extra[0]}", f"unknown key {extra[0]!r}; expected "
                   f"some of {sorted(defaults)}.")
    return {**copy.deepcopy(defaults), **val}


def _check_measurement(m, name, prefix):
    if m["order"] not in ("row", "serpentine", "random"):
        raise _bad(name, prefix + ".order", f"expected 'row', 'serpentine' or 'random', "
                   f"found {_cut(m['order'])}.")
    if not isinstance(m["probes_interleaved"], bool):
        raise _bad(name, prefix + ".probes_interleaved",
                   f"expected true or false, found {_cut(m['probes_interleaved'])}.")
    m["repeats"] = _number(name, prefix + ".repeats", m["repeats"], 1, 100, integer=True)
    m["minutes_per_ball"] = _number(name, prefix + ".minutes_per_ball",
                                    m["minutes_per_ball"], 1e-3, 1440)
    m["minutes_per_placement"] = _number(name, prefix + ".minutes_per_placement",
                                         m["minutes_per_placement"], 0, 1440)
    return m


def read_plan(source, *, name: str | None = None) -> PlanFile:
    """Read a plan file (path, JSON text, bytes or an already parsed dict) and check it.

    A ``setup`` given as a file name is read relative to the plan file. Every refusal is a
    :class:`~cmm_core.io.DataError` naming the file and the key (``plate.rows``), what
    was expected and what was found.
    """
    base_dir = Path(".")
    if isinstance(source, dict):
        raw, name = source, name or "plan"
    else:
        if isinstance(source, str | Path) and not str(source).lstrip().startswith("{"):
            base_dir = Path(source).resolve().parent
        raw, name = read_json(source, name)
    if not isinstance(raw, dict):
        raise _bad(name, None, f"expected a JSON object with some of {list(TOP_KEYS)}, "
                   f"found {type(raw).__name__}.")
    extra = sorted(set(map(str, raw)) - set(TOP_KEYS))
    if extra:
        raise _bad(name, extra[0], f"unknown key {extra[0]!r}; expected some of "
                   f"{list(TOP_KEYS)}.")
    if "setup" not in raw:
        raise _bad(name, "setup", "missing: expected the machine and its placements (a "
                   "setup object, or the name of a setup file).")
    setup_raw = raw["setup"]
    if isinstance(setup_raw, str):
        path = (base_dir / setup_raw)
        setup_raw, _ = read_json(path)
    if not isinstance(setup_raw, dict):
        raise _bad(name, "setup", f"expected a setup object or file name, found "
                   f"{_cut(setup_raw)}.")
    setup_raw = copy.deepcopy(setup_raw)
    setup_raw["frame"] = "machine"  # a plan places the plate: its tables are not read
    setup = read_setup(setup_raw, name=f"{name} (setup)")
    plate = _section(raw, "plate", PLATE_DEFAULTS, name)
    plate["rows"] = _number(name, "plate.rows", plate["rows"], 2, 100, integer=True)
    plate["cols"] = _number(name, "plate.cols", plate["cols"], 2, 100, integer=True)
    plate["pitch_mm"] = _number(name, "plate.pitch_mm", plate["pitch_mm"], 1, 5000)
    plate["certificate_u_um"] = _number(name, "plate.certificate_u_um",
                                        plate["certificate_u_um"], 1e-3, 1000)
    if plate["geometry"] not in PLATE_MODES:
        raise _bad(name, "plate.geometry", f"expected one of {list(PLATE_MODES)}, found "
                   f"{_cut(plate['geometry'])}.")
    model = _section(raw, "model", MODEL_DEFAULTS, name)
    model["order"] = _number(name, "model.order", model["order"], 1, MAX_ORDER, integer=True)
    try:
        parse_spec(str(model["spec"]), default_order=model["order"])
    except ValueError as exc:
        raise _bad(name, "model.spec", str(exc)) from None
    for k in ("prior_um", "prior_urad"):
        model[k] = _number(name, f"model.{k}", model[k], 0, 1e4)
    model["alpha"] = _number(name, "model.alpha", model["alpha"], 1e-6, 0.5)
    per = model["periods_mm"]
    if not isinstance(per, dict) or set(per) - set("xyz"):
        raise _bad(name, "model.periods_mm", f"expected an object axis (x, y, z): period "
                   f"in mm, found {_cut(per)}.")
    model["periods_mm"] = {a: _number(name, f"model.periods_mm.{a}", v, 1, 1e5)
                           for a, v in per.items()}
    noise = _number(name, "noise_um", raw.get("noise_um", 0.5), 1e-4, 1000)
    meas = _check_measurement(_section(raw, "measurement", MEASUREMENT_DEFAULTS, name),
                              name, "measurement")
    seed = _number(name, "seed", raw.get("seed", 0), 0, 2**32 - 1, integer=True)
    default_probe = next(iter(setup.probes), None)
    if default_probe is None:
        raise _bad(name, "setup.probes", "no probes defined; expected at least one stylus "
                   "offset (mm).")
    everything = {p: (pl.probe or default_probe,) for p, pl in setup.positions.items()}
    proto = Plan(str(raw.get("name", "plan")), setup_raw, everything, plate, model, noise,
                 meas, seed)
    base = _build(proto, everything, proto.name)
    strategies = []
    items = raw.get("strategies", [{"name": proto.name}])
    if not isinstance(items, list) or not items:
        raise _bad(name, "strategies", f"expected a non-empty list of strategies, found "
                   f"{_cut(items)}.")
    for i, st in enumerate(items):
        where = f"strategies[{i}]"
        if not isinstance(st, dict):
            raise _bad(name, where, f"expected an object with some of {list(STRATEGY_KEYS)}, "
                       f"found {_cut(st)}.")
        extra = sorted(set(map(str, st)) - set(STRATEGY_KEYS))
        if extra:
            raise _bad(name, f"{where}.{extra[0]}", f"unknown key {extra[0]!r}; expected "
                       f"some of {list(STRATEGY_KEYS)}.")
        units = units_of(st.get("placements", list(everything)), setup, everything,
                         name, f"{where}.placements")
        m = _check_measurement(_section(st, "measurement", meas, name, f"{where}."), name,
                               f"{where}.measurement")
        p = Plan(str(st.get("name", f"strategy {i + 1}")), setup_raw, units, plate, model,
                 _number(name, f"{where}.noise_um", st.get("noise_um", noise), 1e-4, 1000),
                 m, seed)
        strategies.append(_build(p, units, p.name))
    names = [s.name for s in strategies]
    if len(set(names)) != len(names):
        raise _bad(name, "strategies", f"strategy names must differ, found {names}.")
    design = raw.get("design")
    if design is not None and not isinstance(design, dict):
        raise _bad(name, "design", f"expected an object (pool, target, criterion), found "
                   f"{_cut(design)}.")
    return PlanFile(strategies, base, design, name)


def units_of(spec, setup, defaults, name, column) -> dict:
    """Placements and styli of a strategy: a list of placement names (each with its
    setup stylus) or an object placement: [styli]; every name checked against the setup."""
    if isinstance(spec, list):
        spec = {p: list(defaults.get(p, ())) for p in spec}
    if not isinstance(spec, dict) or not spec:
        raise _bad(name, column, f"expected a non-empty list of placements or an object "
                   f"placement: [styli], found {_cut(spec)}.")
    out = {}
    for pos, qs in spec.items():
        if pos not in setup.positions:
            raise _bad(name, f"{column}.{pos}", f"placement {_cut(pos)} is not in the setup "
                       f"(known: {', '.join(setup.positions)}).")
        if isinstance(qs, str):
            qs = [qs]
        if not isinstance(qs, list) or not qs:
            raise _bad(name, f"{column}.{pos}", f"expected a non-empty list of styli, found "
                       f"{_cut(qs)}.")
        for q in qs:
            if str(q) not in setup.probes:
                raise _bad(name, f"{column}.{pos}", f"stylus {_cut(q)} is not among the "
                           f"setup's probes {sorted(setup.probes)}.")
        out[str(pos)] = tuple(dict.fromkeys(str(q) for q in qs))
    return out


def _build(plan: Plan, probes_of: dict, name: str) -> Plan:
    setup = copy.deepcopy(plan.setup)
    setup["positions"] = {p: {**setup["positions"][p], "probe": probes_of[p][0]}
                          for p in probes_of}
    return Plan(name, setup, dict(probes_of), plan.plate, plan.model, plan.noise_um,
                plan.measurement, plan.seed)


def simulation_config(plan: Plan, *, seed: int = 0, noise_um: float = 0.0,
                      prior: bool = False, coefficients=None, spec=None,
                      effects=None) -> dict:
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
            "minutes_per_ball": m["minutes_per_ball"], "repeats": m["repeats"]}


def simulate_plan(plan: Plan, **kwargs) -> Dataset:
    """Data of the plan from the virtual CMM (see :func:`simulation_config`), with the
    certificate at the plate's nominal geometry and the plan's certificate uncertainty."""
    sim = simulate(simulation_config(plan, **kwargs), name=f"plan {plan.name!r}")
    d = sim.dataset
    cert = Certificate(d.certificate.balls, sim.true_plate_mm.copy(),
                       np.full(sim.true_plate_mm.shape, plan.plate["certificate_u_um"]))
    return Dataset(d.meas, d.setup, cert, name=f"plan {plan.name}")


def fit_plan_data(plan: Plan, data: Dataset, spec=None) -> FitResult:
    """The fit the plan's data will get: the plan's model, order, plate geometry and σ."""
    return fit(data, spec or plan.model["spec"], order=plan.model["order"],
               plate=plan.plate["geometry"], sigma_um=plan.noise_um, max_iter=2000)


def design_fit(plan: Plan) -> FitResult:
    """Fit of the plan's noise-free, error-free data: its covariance and null space are
    the design's (see the module docstring)."""
    return fit_plan_data(plan, simulate_plan(plan, seed=plan.seed))


@dataclass(frozen=True)
class PlanEvaluation:
    """What a plan will deliver, from its design alone.

    Attributes
    ----------
    name : str
        Strategy name.
    n_obs : int
        Probed ball centres.
    undetermined : list of str
        Parameter combinations the data cannot determine, written as the fit writes them
        (any basis of that space is as valid: compare spaces, not strings).
    undetermined_parameters : list of str
        Parameters carrying weight in those combinations.
    U1_um, U2_um, U3_um : dict or None
        Thesis U1 (ball centres; None with the plate fixed), U2 (evaluated region) and U3
        (working volume), average standard uncertainty per axis in µm; None when
        undetermined.
    functions : dict
        Error function -> ``{"unit", "at_mm", "u", "u_max"}``: standard uncertainty of
        the function at ``STROKE_POINTS`` points of its stroke (µm or µrad; None when the
        function is undetermined).
    detection_limits : dict
        Catalogue effect -> ``plan_detect.DetectionLimit``.
    skipped : dict
        Effects the diagnosis would not try with these data, with the reason.
    time_min : float
        Measuring time in minutes.
    message : str
        What was evaluated and how.
    fit : FitResult
        The design fit (covariance, layout, null space).
    """

    name: str
    n_obs: int
    undetermined: list
    undetermined_parameters: list
    U1_um: dict | None
    U2_um: dict | None
    U3_um: dict | None
    functions: dict
    detection_limits: dict
    skipped: dict
    time_min: float
    message: str
    fit: FitResult = field(repr=False)

    @property
    def determined(self) -> bool:
        """True when the design determines every parameter of the model."""
        return not self.undetermined

    def to_dict(self) -> dict:
        """JSON-ready record (the ``strategies`` entries of ``plan``'s output)."""
        return {"name": self.name, "n_obs": self.n_obs, "undetermined": self.undetermined,
                "undetermined_parameters": self.undetermined_parameters,
                "U1_um": self.U1_um, "U2_um": self.U2_um, "U3_um": self.U3_um,
                "detection_limits": {k: v.to_dict() for k, v in
                                     self.detection_limits.items()},
                "skipped": self.skipped, "functions": self.functions,
                "time_min": self.time_min, "message": self.message}


def function_uncertainty(result: FitResult, n: int = STROKE_POINTS) -> dict:
    """Standard uncertainty of every error function over its stroke, from the kinematic
    covariance: ``u(f(t)) = sqrt(b(t)ᵀ V_f b(t))`` with ``b`` the function's Chebyshev
    basis (thesis eq. 4.1-4.9 parameterisation) and ``V_f`` its coefficient block."""
    terms = result.terms
    cov = result.kinematic_cov
    bad = set(result.unidentifiable)
    out = {}
    for fn, sl in terms.slices.items():
        a = {"sxy": 1, "sxz": 2, "syz": 2}.get(fn, "xyz".index(fn[1]))
        t = np.linspace(0.0, float(terms.range_mm[a]), n)
        labels = terms.labels[sl]
        if any(lab in bad for lab in labels):
            u = None
        else:
            B = terms.design(fn, t)
            u = np.sqrt(np.clip(np.einsum("ik,kl,il->i", B, cov[sl, sl], B), 0, None))
        out[fn] = {"unit": "urad" if fn[0] in "rs" else "um", "at_mm": t.tolist(),
                   "u": None if u is None else u.tolist(),
                   "u_max": None if u is None else float(u.max())}
    return out


@single_blas_thread
def evaluate(plan: Plan, *, detection: bool = True, n_random: int = 200) -> PlanEvaluation:
    """Evaluate a plan from its design alone (module docstring).

    Parameters
    ----------
    plan : Plan
    detection : bool
        Compute the detection limit of every catalogue effect (``plan_detect``).
    n_random : int
        Random points of U2 and U3 (thesis: 200).

    Returns
    -------
    PlanEvaluation
    """
    t0 = time.perf_counter()
    r = design_fit(plan)
    u = evaluate_u(r, n_random=n_random, seed=plan.seed)
    limits, skipped = {}, {}
    if detection:
        from .plan_detect import detection_limits

        limits, skipped = detection_limits(r, plan)
    msg = (f"Evaluated from the design alone (noise-free virtual data, σ = "
           f"{plan.noise_um:g} µm) in {time.perf_counter() - t0:.2f} s. {u.message}")
    if r.null_combinations:
        msg += (f" The design leaves {len(r.null_combinations)} combination(s) undetermined:"
                " add placements or styli that exercise them, or remove those functions.")
    return PlanEvaluation(plan.name, r.n_obs, list(r.null_combinations),
                          list(r.unidentifiable), u.U1_um, u.U2_um, u.U3_um,
                          function_uncertainty(r), limits, skipped, plan.time_min, msg, r)


def evaluate_file(pf: PlanFile, *, detection: bool = True) -> dict:
    """``{"strategies": [...]}``: every strategy of a plan file, evaluated."""
    return {"strategies": [evaluate(p, detection=detection).to_dict()
                           for p in pf.strategies]}

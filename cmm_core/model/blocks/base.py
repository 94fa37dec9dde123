"""The protocol every effect block implements, and the evaluation context they share.

The residual of an observation (µm) is built in stages (``fit`` module docstring)::

    p' = probe stage(p)                    probe_offset
    x* = kinematic model(r - p, p')        kinematic (thesis eq. 4.13)
    c' = plate stage(c_b)                  plate_thermal, plate_sag
    d  = (x* - (R_k c' + t_k)) / UM        placement
    d  = reading stage(d)                  drift, backlash, machine_thermal

A block takes part in the stages it overrides; each writes its own columns of the
Jacobian. Adding an effect is adding one block module and listing it in
``blocks.REGISTRY``. A block that also acts on new points (``compensate``: backlash,
machine_thermal) says what the model file keeps of it (:meth:`Block.compensation`,
:meth:`Block.part_to_file`, :meth:`Block.part_from_file`) and how it corrects a point
(:meth:`Block.correct`); a block checks its own simulator configuration
(:meth:`Block.check_sim`).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import pandas as pd

from ...io import DataError
from ...io.errors import cut_repr
from ...io.setup import check_celsius
from ...machine import DEFAULT_LAYOUT, KinematicTerms
from ..observations import Observations
from ..state import State

Column = tuple[str, Sequence[str], str | Sequence[str]]
"""A layout entry :meth:`Block.columns` adds: ``(name, labels, unit)``, the unit one
string for every label or one per label."""

Jacobian = list[tuple[np.ndarray, np.ndarray]]
"""What :meth:`Block.jacobian` returns: ``[(cols, values)]``, ``values`` (n, 3, k) the
derivatives of the three residual components with respect to the ``k`` columns ``cols``
((n, 3, k) or broadcastable to it, e.g. (n, k))."""

Shape = tuple[str, dict[str, float]]
"""A detection shape of :meth:`Block.detection_shapes`: ``(name, {label: weight})``."""


class LayoutLike(Protocol):
    """What a block reads of the problem's parameter layout (``problem._Layout``)."""

    @property
    def blocks(self) -> dict[str, slice]:
        """Layout name -> slice of the parameter vector."""
        ...

    @property
    def n(self) -> int:
        """Length of the parameter vector."""
        ...


class ProblemLike(Protocol):
    """What a block reads of the problem it belongs to (``problem.Problem``). A protocol,
    not the class: ``problem`` imports the blocks, so importing it here would close an
    import circle (``tests/test_wings.py``)."""

    @property
    def obs(self) -> Observations:
        """The observations fitted."""
        ...

    @property
    def layout(self) -> LayoutLike:
        """Column layout of the parameter vector."""
        ...

    @property
    def terms(self) -> KinematicTerms:
        """The kinematic model's terms."""
        ...

    @property
    def plate_centre(self) -> np.ndarray:
        """Centre of the plate (3,) mm, about which it expands."""
        ...

    @property
    def sag_basis(self) -> np.ndarray:
        """Sag shapes of every ball (B, 3)."""
        ...


class SpecLike(Protocol):
    """What :meth:`Block.wanted` reads of a model spec (``effects.ModelSpec``; a protocol,
    as ``effects`` imports the blocks)."""

    @property
    def effects(self) -> Collection[str]:
        """Physical effects present (catalogue tokens)."""
        ...


class FitLike(Protocol):
    """What :meth:`Block.compensation` reads of a fit (``result.FitResult``; a protocol,
    as ``result`` imports the problem, which imports the blocks)."""

    @property
    def problem(self) -> ProblemLike:
        """The fitted problem."""
        ...

    @property
    def labels(self) -> Sequence[str]:
        """One label per parameter."""
        ...

    @property
    def values(self) -> np.ndarray:
        """Parameter estimates (p,)."""
        ...

    @property
    def covariance(self) -> np.ndarray:
        """Parameter covariance (p, p)."""
        ...


@dataclass
class Eval:
    """Working values of one residual evaluation, shared by the blocks.

    Attributes
    ----------
    problem : fit.Problem
        The problem being evaluated (observations, layout, blocks).
    state : fit_state.State
        Plate coordinates, placements and the parameter vector.
    want_jac : bool
        Whether the Jacobian is wanted.
    p_mm : ndarray (n, 3)
        Probe offsets after the probe stage.
    plate_mm : ndarray (n, 3)
        Plate coordinates of each observation after the plate stage.
    plate_scale : ndarray (n,) or float
        Thermal scale factor applied to the plate coordinates (plate Jacobian).
    Rk : ndarray (n, 3, 3)
        Rotation of each observation's placement.
    kin_jac : ndarray (n, 3, k) or None
        Kinematic model Jacobian (µm per coefficient unit).
    """

    problem: ProblemLike
    state: State
    want_jac: bool
    p_mm: np.ndarray | None = None
    plate_mm: np.ndarray | None = None
    plate_scale: np.ndarray | float = 1.0
    Rk: np.ndarray | None = None
    kin_jac: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    @property
    def obs(self) -> Observations:
        """The problem's observations."""
        return self.problem.obs

    def x(self, name: str) -> np.ndarray:
        """Parameters of one layout slice."""
        return self.state.x[self.problem.layout.blocks[name]]

    def start(self, name: str) -> int:
        """First column of one layout slice."""
        return self.problem.layout.blocks[name].start


@dataclass(frozen=True)
class Effect:
    """One catalogue entry: what it is, what it needs, what it is confused with.

    Attributes
    ----------
    name : str
        Catalogue name used in model specs (``dyz``, ``dyz:3``, ``plate_sag``).
    title : str
        Short human title.
    explanation : str
        What a metrologist would write about the physical effect.
    needs : str
        The data it needs to be identifiable.
    confused_with : str
        Effects it can be mistaken for with common measurement plans.
    separate_by : str
        The measurement that separates it from those.
    """

    name: str
    title: str
    explanation: str
    needs: str
    confused_with: str
    separate_by: str


@dataclass
class SimContext:
    """What a block's :meth:`Block.draw` sees of a simulation, and may set.

    Attributes
    ----------
    positions, probes : list of str
        Positions and probes of the setup.
    temps_C : dict
        Plate temperature of each position at its start and finish (°C); 20 °C unless a
        block (plate_thermal) sets it.
    columns : dict
        Further columns a block records: column -> {position: (start, finish)},
        interpolated over each position's measuring time like ``temp_C``.
    """

    positions: list
    probes: list
    temps_C: dict = field(default_factory=dict)
    columns: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SimCheck:
    """What a block's :meth:`Block.check_sim` checks its configuration against, and the
    refusals it raises (every one a ``DataError`` naming the file and the key).

    Attributes
    ----------
    name : str
        The configuration's file name, for messages.
    positions : tuple of str
        Positions of the setup being simulated.
    probes : tuple of str
        Probes of that setup.
    layout : str
        The simulated machine's layout ("" when not known).
    """

    name: str
    positions: tuple
    probes: tuple
    layout: str = ""

    def bad(self, column: str, message: str, hint: str | None = None) -> DataError:
        """A refusal of the key ``column``."""
        return DataError(message, file=self.name, column=column, hint=hint)

    def known(self, column: str, key: object, names: Collection[str], what: str) -> None:
        """Refuse ``key`` unless it is one of ``names`` (a position or probe of the setup);
        a close name is offered (a typo would silently drop the entry)."""
        if str(key) not in names:
            close = difflib.get_close_matches(str(key), list(names), n=1, cutoff=0.6)
            raise self.bad(column, f"{what} {cut_repr(key)} is not in the setup (known: "
                           f"{cut_repr(', '.join(names), 200)})" + (
                               f"; did you mean {close[0]!r}?" if close else "."))

    def vectors_by_name(self, cfg: dict, where: str, skip: str, names: Collection[str],
                        what: str) -> None:
        """Every key of ``cfg`` but ``skip`` one of ``names`` (positions or probes of the
        setup), each with a vector of 3 numbers (drift per position, offset per probe)."""
        for key, v in cfg.items():
            if key != skip:
                self.known(f"{where}.{key}", key, names, what)
                self.vector(f"{where}.{key}", v)

    def vector(self, column: str, v: object) -> None:
        """Refuse anything but 3 finite numbers."""
        if not (isinstance(v, list | tuple) and len(v) == 3 and all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                for x in v)):
            raise self.bad(column, f"expected 3 finite numbers (µm or µm/h), found "
                           f"{cut_repr(v)}.")

    def start_finish_C(self, column: str, temps: object) -> None:
        """Refuse ``temps`` unless it maps positions of the setup to [start, finish]
        temperatures in °C."""
        if temps is None:
            return
        if not isinstance(temps, dict):
            raise self.bad(column, f"expected an object position: [start, finish] in °C, "
                           f"found {cut_repr(temps)}.")
        for pos, t in temps.items():
            col = f"{column}.{pos}"
            self.known(col, pos, self.positions, "position")
            if not (isinstance(t, list) and len(t) == 2 and all(
                    isinstance(x, int | float) and not isinstance(x, bool) for x in t)):
                raise self.bad(col, f"expected [start, finish] in °C, found {cut_repr(t)}.")
            check_celsius(np.asarray(t, float), self.name, col)


@dataclass(frozen=True)
class ModelPart:
    """What a model file keeps of one block to correct new points (``compensate``).

    Attributes
    ----------
    labels : tuple of str
        The block's parameters applied to new points (fit labels: ``backlash.x``,
        ``machine_thermal.cte_z``).
    values : ndarray (k,)
        Their fitted values, in the block's units.
    cov : ndarray (n + m + k, n + m + k)
        Joint covariance of the n kinematic coefficients, the m parameters of the
        compensating blocks before this one in ``REGISTRY`` order, and these k: the
        correction's uncertainty needs their correlations with the error map.
    """

    labels: tuple
    values: np.ndarray
    cov: np.ndarray
    context: dict = field(default_factory=dict, compare=False)
    """What else the block's :meth:`Block.correct` needs of the fit (the machine's
    range and layout: ``bridge_twist``), written and read by the block with its keys."""


@dataclass(frozen=True)
class SimParam:
    """One number of a simulator panel's effect: what a UI needs to draw its input.

    Attributes
    ----------
    key : str
        Key under ``effects.<token>`` in the simulator configuration.
    label : str
        Input label, with its unit (``"sag uu (µm)"``).
    unit : str
        Unit of the value as the configuration takes it (``um``, ``urad``, ``1/K``).
    default, low, high : float
        Default value and the input's range, in the input's unit (times ``scale``:
        within the block's ``sim_ranges``).
    step : float
        Input step.
    """

    key: str
    label: str
    unit: str
    default: float
    low: float
    high: float
    step: float = 0.1
    scale: float = 1.0
    """The configuration's value is the input times ``scale`` (an input in 10⁻⁶/K for a
    key in 1/K: 1e-6)."""


@dataclass(frozen=True)
class SimulatorEffect:
    """One hidden effect of the simulator panel (:func:`simulator_effects`): a checkbox
    labelled ``label`` (tooltip ``help``) and an input per parameter.

    Attributes
    ----------
    token : str
        The effect's token: the key of ``effects`` in the simulator configuration.
    label, help : str
        Checkbox label and tooltip.
    params : tuple of SimParam
        The inputs to draw when the box is ticked (may be empty: defaults only).
    fixed : dict
        Keys always passed besides the inputs (``plate_sag``: ``uv`` 0).
    """

    token: str
    label: str
    help: str
    params: tuple = ()
    fixed: dict = field(default_factory=dict)

    def config(self, values: dict | None = None) -> dict:
        """The ``effects.<token>`` body for the inputs' ``values`` (key -> number; the
        defaults for keys not given)."""
        values = values or {}
        return {**self.fixed, **{p.key: float(values.get(p.key, p.default)) * p.scale
                                 for p in self.params}}


@dataclass(frozen=True)
class Correction:
    """A block's correction of new points (:meth:`Block.correct`).

    Attributes
    ----------
    delta_um : ndarray (m, 3)
        Added to the kinematic correction ``e`` (true minus reported tip centre, µm).
    jac : ndarray (m, 3, k)
        Derivative of ``delta_um`` with respect to the part's values (µm per unit): the
        columns that follow the kinematic Jacobian in the propagation through
        :attr:`ModelPart.cov`.
    var_um2 : ndarray (m, 3) or None
        Variance the covariance does not hold (µm²), added to the propagated one.
    columns : dict
        Output columns the block adds (name -> (m,) array).
    """

    delta_um: np.ndarray
    jac: np.ndarray
    var_um2: np.ndarray | None = None
    columns: dict = field(default_factory=dict)


class Block:
    """One physical effect: its parameters, the data it needs, its residual contribution,
    Jacobian and gauge constraints, its simulation, its planning knowledge and its
    correction of new points.

    Subclasses set :attr:`token` (the catalogue name that adds it to a model; ``None``
    for blocks always present) and override what they take part in. Every hook the fit,
    the simulator, the planner and the compensation call is declared here with a no-op
    default, so that callers never ask ``hasattr`` (docs/effects.md lists them):

    - model: :meth:`wanted`, :meth:`needs`, :meth:`columns`, the stages
      :meth:`probe_stage`, :meth:`plate_stage`, :meth:`reading_stage`, :meth:`jacobian`,
      :meth:`constraints`, :meth:`update`, :meth:`report`;
    - simulation: :attr:`sim_keys`, :attr:`sim_ranges`, :meth:`draw`, :meth:`check_sim`,
      :attr:`sim_label`, :attr:`sim_help`, :attr:`sim_params`, :attr:`sim_fixed`;
    - planning: :meth:`detection_shapes`, :meth:`injection`, :attr:`physical_check`;
    - compensation: :attr:`model_keys`, :meth:`compensation`, :meth:`part_to_file`,
      :meth:`part_from_file`, :meth:`correct`, :attr:`comp_units`,
      :meth:`correction_columns`.
    """

    token: str | None = None
    """Catalogue name that puts the block in a model (``None``: always in the model)."""
    entry: Effect | None = None
    """Its catalogue entry (what it is, needs, is confused with, is separated by)."""

    sim_keys: frozenset | None = frozenset()
    """Keys the simulator accepts under ``effects.<token>`` (None: position or probe names
    besides those of :attr:`sim_ranges`, checked against the setup)."""
    sim_ranges: dict = {}
    """Numeric simulator keys and their allowed (low, high) range."""

    def __init__(self, problem: ProblemLike) -> None:
        self.problem = problem

    @classmethod
    def draw(cls, cfg: dict, sim: SimContext, rng: np.random.Generator) -> dict[str, float]:
        """True parameter values (by fit label) for the simulator's ``effects.<token>``
        configuration ``cfg``; random draws come from ``rng``."""
        return {}

    @classmethod
    def wanted(cls, spec: SpecLike, plate: str) -> bool:
        """Whether a model with this spec and plate mode contains the block."""
        return cls.token is not None and cls.token in spec.effects

    @staticmethod
    def needs(obs: Observations) -> str | None:
        """Why these observations cannot determine the effect (None: they can)."""
        return None

    def columns(self, obs: Observations) -> list[Column]:
        """Layout entries ``(name, labels, unit)`` the block adds (unit: str or list)."""
        return []

    # --- stages ---------------------------------------------------------------------
    def probe_stage(self, ev: Eval, p: np.ndarray) -> np.ndarray:
        """Probe offsets (n, 3) mm after the block's change (``probe_offset``)."""
        return p

    def plate_stage(self, ev: Eval, c: np.ndarray) -> np.ndarray:
        """Plate coordinates of every observation (n, 3) mm after the block's change
        (``plate_thermal``, ``plate_sag``)."""
        return c

    def reading_stage(self, ev: Eval, d: np.ndarray) -> np.ndarray:
        """Residuals (n, 3) µm after the block's term on the readings (``drift``,
        ``backlash``, ``machine_thermal``, ``bridge_twist``); linear in ``d`` (the
        simulator inverts it: ``Problem.targets``)."""
        return d

    def jacobian(self, ev: Eval) -> Jacobian:
        """``[(cols (n, 3, k) or broadcastable, values (n, 3, k))]``: derivatives of the
        three residual components with respect to ``k`` columns."""
        return []

    def constraints(self) -> np.ndarray | None:
        """Gauge constraint rows on the block's own columns (``C x = 0``), or None."""
        return None

    def update(self, new: State) -> State:
        """The state after a Gauss-Newton step ``new`` (``Problem.update``): a block whose
        parameters are increments moves them into the state (placements, plate) and
        zeroes them; the default keeps the step in the parameter vector."""
        return new

    def report(self, state: State, v: np.ndarray) -> None:
        """Write the block's reported values into ``v`` (the parameter vector in the
        block's units, ``fitting._report_values``) where they differ from
        ``state.x`` (placements and plate relative to the nominal setup); the default
        reports ``state.x`` as it is."""

    # --- planning (plan.detect, plan.study) -------------------------------------------
    physical_check: bool = False
    """Whether plan studies check the effect by default (``plan.PHYSICAL_CHECKS``): its
    detection limit is hidden in simulated data (:meth:`injection`) and the diagnosis's
    test of it is run."""

    @classmethod
    def detection_shapes(cls, labels: Sequence[str], positions: Sequence[str],
                         probes: Sequence[str]) -> list[Shape]:
        """Shapes ``[(name, {label: weight})]`` along which the planner computes the
        effect's detection limit (largest weight 1; the worst shape is reported).
        ``labels``: the effect's new parameters in the plan's model; ``positions``,
        ``probes``: the plan's. Default: each parameter alone."""
        return [(f"{lab} alone", {lab: 1.0}) for lab in labels]

    @classmethod
    def injection(cls, values: dict[str, float]) -> dict | None:
        """The simulator's ``effects.<token>`` body that hides the effect with these
        parameter values (fit label -> value in the block's units); None: the block cannot
        be simulated from its parameters."""
        return None

    # --- simulator panel (simulation_config.simulator_effects) ---------------------------
    sim_label: str = ""
    """Checkbox label of the simulator panel ("" : not offered in the panel)."""
    sim_help: str = ""
    """Tooltip of that checkbox."""
    sim_params: tuple = ()
    """:class:`SimParam` inputs drawn when the box is ticked."""
    sim_fixed: dict = {}
    """Keys always passed with the inputs."""

    # --- simulator configuration ------------------------------------------------------
    @classmethod
    def check_sim(cls, cfg: dict, where: str, check: SimCheck) -> None:
        """Refuse what :attr:`sim_keys` and :attr:`sim_ranges` cannot say is wrong in
        ``effects.<token>`` (``where``): names of positions or probes the setup lacks,
        malformed vectors or temperatures (``check`` raises the refusals)."""

    # --- compensation of new points -----------------------------------------------------
    model_keys: tuple = ()
    """Keys the block writes in a model file (empty: it does not act on new points)."""
    model_what: str = ""
    """What those keys hold, for messages ("backlash spans")."""
    comp_units: str = ""
    """Unit of every parameter the block applies to new points (the compensation tables'
    extra rows: ``export.model_extras``)."""
    model_keys_optional: bool = False
    """Whether a model file whose spec has the block may lack its keys (written before the
    block kept them): it is then read without the part and corrects as it did; False:
    such a file is refused."""

    @classmethod
    def compensation(cls, result: FitLike, before: np.ndarray) -> ModelPart | None:
        """What a model file must keep of this block to correct new points (None: the
        block is not in the fit, or does not act on new points).

        Parameters
        ----------
        result : FitResult
        before : ndarray of int
            Parameter indices of the kinematic coefficients and of the compensating
            blocks before this one (the leading rows of :attr:`ModelPart.cov`).
        """
        if not cls.model_keys or cls.token is None:
            return None
        s = result.problem.layout.blocks.get(cls.token)
        if s is None:
            return None
        idx = np.r_[before, np.arange(s.start, s.stop)]
        return ModelPart(tuple(result.labels[s]), result.values[s].copy(),
                         result.covariance[np.ix_(idx, idx)].copy(),
                         cls.part_context(result))

    part_in_machine_frame: bool = False
    """True: the block's terms are normalised to the machine's strokes and depend on its
    layout, so its model part keeps both (:meth:`part_context`)."""

    @classmethod
    def part_context(cls, result: FitLike) -> dict:
        """What the part's correction needs of the fit besides its values (the
        :attr:`ModelPart.context`): the strokes and layout for a block
        :attr:`part_in_machine_frame`, else nothing."""
        if not cls.part_in_machine_frame:
            return {}
        obs = result.problem.obs
        return {"range_mm": tuple(map(float, obs.range_mm)), "layout": obs.layout}

    @classmethod
    def part_to_file(cls, part: ModelPart) -> dict:
        """The model-file keys (:attr:`model_keys`) holding ``part``."""
        return {}

    @classmethod
    def part_from_file(cls, d: dict, n_before: int, name: str) -> ModelPart | None:
        """The part a model file ``d`` holds (None: none), every field checked; a
        ``DataError`` naming the file ``name`` and the key otherwise. ``n_before``: the
        parameters before the block's in the joint covariance."""
        return None

    @classmethod
    def correct(cls, part: ModelPart, points: pd.DataFrame, x_mm: np.ndarray,
                name: str) -> Correction:
        """The block's correction of new ``points`` (a table with ``x_mm, y_mm, z_mm``
        and what the block needs) at scale readings ``x_mm`` (m, 3); refusals name the
        points file ``name``."""
        raise NotImplementedError(f"{cls.__name__} does not correct new points")

    @classmethod
    def correction_columns(cls, labels: Sequence[str] | None = None) -> tuple[str, ...]:
        """Columns (besides ``x_mm, y_mm, z_mm, probe``) that points need to be corrected
        by this block; ``labels``: the part's fitted labels when known (a block may need
        columns only for some of them). Default: none."""
        return ()


MAX_MODEL_U = 1e6
"""Largest standard uncertainty (µm, µrad) a model file's covariance may give a
parameter: a metre or a radian is no CMM's error, and larger variances overflow the
propagation (a grid's J V Jᵀ)."""


class LayoutBlock(Block):
    """A block that only some machine layouts have (bridge twist, column bending): its
    parameters move the tip by ``motion(ev) @ x`` at the readings, terms normalised to
    the strokes (:attr:`part_in_machine_frame`); on any other layout it fits nothing and
    its model file has no section, which is refused on a layout that has it when the
    spec names it.

    A subclass sets :attr:`layouts`, :attr:`labels`, :attr:`lacks` (what a layout without
    the block lacks: "horizontal arm on a column"), :attr:`layouts_what` ("a horizontal-arm
    layout"), :attr:`section_keys` (its values' key and ``cov_joint``),
    :attr:`values_what` ("finite twists (µrad)") and :meth:`motion`;
    :meth:`labels_in_file` for files of an earlier version, :attr:`sim_shape_keys` for
    simulator keys that are not sizes."""

    layouts: Collection[str] = ()
    labels: tuple[str, ...] = ()
    lacks: str = ""
    layouts_what: str = ""
    sim_shape_keys: frozenset = frozenset()
    section_keys: tuple[str, str] = ("values", "cov_joint")
    values_what: str = "finite values"
    model_keys_optional = True
    part_in_machine_frame = True

    def motion(self, ev: Eval) -> np.ndarray:
        """Each parameter's motion of the tip at the observations' readings (n, 3, k)."""
        raise NotImplementedError

    @classmethod
    def check_sim(cls, cfg: dict, where: str, check: SimCheck) -> None:
        """A size asked of a layout without the block would be dropped without a word:
        refused."""
        sizes = (cls.sim_keys or frozenset()) - cls.sim_shape_keys
        if check.layout and check.layout not in cls.layouts and any(
                float(cfg.get(k, 0.0)) != 0.0 for k in sizes):
            raise check.bad(where, f"the {check.layout} layout has no {cls.lacks}, so it has "
                            f"no {cls.model_what} to simulate.",
                            hint=f"remove effects.{cls.token}, or simulate "
                                 f"{cls.layouts_what} (machine.layout).")

    def columns(self, obs: Observations) -> list[Column]:
        return ([(str(self.token), list(self.labels), self.comp_units)]
                if obs.layout in self.layouts else [])

    def reading_stage(self, ev: Eval, d: np.ndarray) -> np.ndarray:
        if ev.obs.layout not in self.layouts:
            return d
        return d + self.motion(ev) @ ev.x(str(self.token))

    def jacobian(self, ev: Eval) -> Jacobian:
        if ev.obs.layout not in self.layouts:
            return []
        cols = self.motion(ev)
        return [(shared_cols(ev.start(str(self.token)), len(self.labels), len(cols)), cols)]

    @classmethod
    def part_to_file(cls, part: ModelPart) -> dict:
        return {cls.model_keys[0]: {cls.section_keys[0]: part.values.tolist(),
                                    cls.section_keys[1]: part.cov.tolist()}}

    @classmethod
    def labels_in_file(cls, k: int) -> tuple[str, ...] | None:
        """The labels of a file holding ``k`` values (None: no version holds ``k``)."""
        return cls.labels if k == len(cls.labels) else None

    @classmethod
    def part_from_file(cls, d: dict, n_before: int, name: str) -> ModelPart | None:
        col = cls.model_keys[0]
        sec = d.get(col)
        layout = d.get("layout", DEFAULT_LAYOUT)
        refit = "refit and save the model again (fit --save)"
        if sec is None:
            spec = d.get("spec")
            if layout in cls.layouts and isinstance(spec, str) and col in spec:
                raise DataError(f"the model's spec has {col} but the file holds no "
                                f"{cls.model_what}.", file=name, hint=f"{refit}; do not "
                                "edit it.")
            return None
        keys = cls.section_keys
        if not isinstance(sec, dict) or set(map(str, sec)) != set(keys):
            raise DataError(f"expected an object with the keys {', '.join(keys)}, "
                            f"found {cut_repr(sec)}.", file=name, column=col,
                            hint=f"{refit}; do not edit it.")
        if layout not in cls.layouts:
            raise DataError(f"the {cut_repr(layout)} layout has no {cls.lacks}; the file "
                            f"holds a {cls.model_what}.", file=name, column=col,
                            hint=f"{refit}.")
        try:
            values = np.asarray(sec[keys[0]], float)
            cov = np.asarray(sec[keys[1]], float)
            rng = tuple(float(x) for x in d["range_mm"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"expected numbers ({cut_repr(str(exc), 80)}).", file=name,
                            column=col) from None
        labels = cls.labels_in_file(values.shape[0]) if values.ndim == 1 else None
        if labels is None or not np.isfinite(values).all():
            raise DataError(f"expected {len(cls.labels)} {cls.values_what}, found "
                            f"{cut_repr(sec[keys[0]])}.", file=name,
                            column=f"{col}.{keys[0]}")
        checked_cov(cov, n_before + len(labels), name, f"{col}.{keys[1]}")
        return ModelPart(labels, values, cov, {"range_mm": rng, "layout": layout})


def checked_cov(cov: np.ndarray, n: int, name: str | None, column: str) -> None:
    """Refuse a model file's covariance unless it is an n × n finite, symmetric, positive
    semi-definite matrix: a NaN or a negative variance would give NaN or imaginary
    uncertainties, silently."""
    if cov.shape != (n, n):
        raise DataError(f"expected a {n}x{n} covariance, found shape {cov.shape}.", file=name,
                        column=column)
    if not np.isfinite(cov).all():
        raise DataError("the covariance holds NaN or infinite entries; expected finite "
                        "numbers.", file=name, column=column,
                        hint="refit and save the model again (fit --save).")
    scale = max(float(np.abs(cov).max()), 1e-300) if n else 1.0
    if n and np.abs(cov - cov.T).max() > 1e-9 * scale:
        raise DataError("the covariance is not symmetric.", file=name, column=column,
                        hint="refit and save the model again (fit --save).")
    if n and (np.diag(cov) < 0).any():
        k = int(np.flatnonzero(np.diag(cov) < 0)[0])
        raise DataError(f"entry {k} of the covariance's diagonal is negative "
                        f"({cov[k, k]:g}); expected variances >= 0.", file=name, column=column)
    if n and np.sqrt(np.diag(cov)).max() > MAX_MODEL_U:
        k = int(np.argmax(np.diag(cov)))
        raise DataError(f"entry {k} of the covariance's diagonal ({cov[k, k]:.3g}) is a "
                        f"standard uncertainty above {MAX_MODEL_U:g} (µm or µrad); no CMM "
                        "model is that uncertain.", file=name, column=column,
                        hint="refit and save the model again (fit --save).")
    unit = cov / scale  # scaled: eigvalsh of entries near 1e308 overflows
    if n and np.linalg.eigvalsh((unit + unit.T) / 2).min() < -1e-8:
        raise DataError("the covariance is not positive semi-definite; expected a "
                        "covariance matrix.", file=name, column=column,
                        hint="refit and save the model again (fit --save).")


def per_group_cols(start: int, group: np.ndarray) -> np.ndarray:
    """Columns ``start + 3 g + (0, 1, 2)`` of per-group xyz parameters, (n, 3)."""
    return start + 3 * group[:, None] + np.arange(3)


def shared_cols(start: int, k: int, n: int) -> np.ndarray:
    """The same ``k`` columns for every observation, (n, k)."""
    return np.broadcast_to(np.arange(start, start + k), (n, k))

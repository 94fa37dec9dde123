"""The protocol every effect block implements (:class:`Block`), its catalogue entry
(:class:`Effect`), and the kind of block only some machine layouts have
(:class:`LayoutBlock`).

The residual of an observation (µm) is built in stages (``problem`` module docstring)::

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

The types a block works with are kept by role: the evaluation context and what a block
reads of the problem (:mod:`.context`), the simulator's (:mod:`.simulation`), the
correction of new points' (:mod:`.compensation`).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import ClassVar

import numpy as np
import pandas as pd

from ...io import DataError
from ...io.errors import cut_repr
from ...machine import DEFAULT_LAYOUT
from ..observations import Observations
from ..state import State
from .compensation import Correction, ModelPart, checked_cov
from .context import Column, Eval, FitLike, Jacobian, ProblemLike, Shape, SpecLike, shared_cols
from .simulation import SimCheck, SimContext


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
    sim_ranges: ClassVar[Mapping[str, tuple[float, float]]] = MappingProxyType({})
    """Numeric simulator keys and their allowed (low, high) range (read-only: one mapping
    per class, shared by its instances)."""

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
    sim_fixed: ClassVar[Mapping[str, float]] = MappingProxyType({})
    """Keys always passed with the inputs (read-only)."""

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

"""What a block's simulation sees and checks: the simulation a block's
:meth:`~.base.Block.draw` reads and may set (:class:`SimContext`), what its
:meth:`~.base.Block.check_sim` checks the configuration against and the refusals it
raises (:class:`SimCheck`), and the simulator panel's inputs (:class:`SimParam`,
:class:`SimulatorEffect`).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Collection
from dataclasses import dataclass, field

import numpy as np

from ...io import DataError
from ...io.errors import cut_repr
from ...io.setup import check_celsius


@dataclass
class SimContext:
    """What a block's :meth:`~.base.Block.draw` sees of a simulation, and may set.

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
    """What a block's :meth:`~.base.Block.check_sim` checks its configuration against, and
    the refusals it raises (every one a ``DataError`` naming the file and the key).

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

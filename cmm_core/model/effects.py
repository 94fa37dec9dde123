"""The effect catalogue and the model-spec language (docs/formats.md "Model specs").

A model is a comma-separated effect list applied left to right: names of the 21 errors,
groups (``kinematic21``, ``translational``, ``rotational``, ``squareness``), ``name:order``
and ``-name``; plus the physical effects of the effect blocks (``blocks.REGISTRY``:
``plate_thermal``, ``plate_sag``, ``probe_offset``, ``drift``, ``backlash``,
``machine_thermal``), and periodic scale errors ``periodic_x:PERIOD_MM`` (and ``_y``, ``_z``). Rigid placement of each position is always in the model.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from ..machine import ERROR_NAMES, ROTATIONAL, SQUARENESS, TRANSLATIONAL
from .blocks import BY_TOKEN, REGISTRY
from .blocks.base import Block, Effect
from .blocks.periodic import PERIODIC

GROUPS = {
    "kinematic21": ERROR_NAMES,
    "translational": TRANSLATIONAL,
    "rotational": ROTATIONAL,
    "squareness": SQUARENESS,
}
PHYSICAL = tuple(BY_TOKEN)
"""Physical effect tokens, one per effect block (``blocks.REGISTRY`` order)."""
MAX_ORDER = 5

_AXIS = {"x": "X", "y": "Y", "z": "Z"}


def rotation_kind(name: str) -> str:
    """ISO 230-1's word for a carriage's rotation error ``r<axis><about>`` (``rxx``,
    ``ryx``, ``rzy``...): ``"roll"`` about its own axis; a horizontal carriage's
    ``"yaw"`` is about the vertical (z), its ``"pitch"`` about the other horizontal axis;
    the vertical ram has no pitch or yaw, it tilts (``"tilt"``) about x or y (ISO 230-1:2012
    EAZ, EBZ). The catalogue's titles and the interim check's words for what it cannot
    see (``monitor.unseen``) both use it.

    Parameters
    ----------
    name : str
        A rotation error's name (``rotational`` group), e.g. ``"ryx"``.

    Returns
    -------
    str
        ``"roll"``, ``"pitch"``, ``"yaw"`` or ``"tilt"``.
    """
    return ("roll" if name[1] == name[2] else "tilt" if name[1] == "z"
            else "yaw" if name[2] == "z" else "pitch")


def _kinematic_effect(name: str) -> Effect:
    if name in SQUARENESS:
        a, b = _AXIS[name[1]], _AXIS[name[2]]
        return Effect(name, f"squareness {a}{b}",
                      f"the {a} and {b} axes are not at 90°: {a} readings drift in "
                      f"proportion to {b}.",
                      f"a placement spanning {a} and {b} (diagonal or rotated positions).",
                      f"a rotation of the plate or the straightness of the {a}/{b} axes.",
                      "two placements rotated by 90° (reversal).")
    ax, d = _AXIS[name[1]], _AXIS[name[2]]
    if name[0] == "d" and name[1] == name[2]:
        return Effect(name, f"{ax} positioning (scale)",
                      f"the {ax} scale reads wrong by an amount that varies along {ax}: "
                      f"lengths along {ax} come out too long or too short.",
                      f"balls spread along {ax} against a calibrated length.",
                      "plate thermal expansion (a uniform scale in every axis).",
                      "a certificate at 20 °C and a recorded plate temperature.")
    if name[0] == "d":
        return Effect(name, f"{ax} straightness in {d}",
                      f"the {ax} carriage does not move in a straight line: it wanders in "
                      f"{d} as {ax} changes (a bow, not a tilt).",
                      f"balls spread along {ax}; {d} readings of them.",
                      f"rotation errors of the {ax} axis seen through a probe offset, or "
                      "plate form.",
                      "the same balls with two probe offsets.")
    kind = rotation_kind(name)
    return Effect(name, f"{ax} carriage {kind} (about {d})",
                  f"the {ax} carriage tilts about {d} as it moves: points away from the "
                  f"axis line (Abbe offset) shift in proportion to their lever arm.",
                  f"balls spread along {ax} measured at different lever arms (probe "
                  "offsets or heights).",
                  f"straightness of the {ax} axis when all points share one lever arm.",
                  "two probe offsets or two heights of the plate.")


_PHYSICAL: dict[str, Effect] = {token: block.entry for token, block in BY_TOKEN.items()
                                 if block.entry is not None}


def _periodic_effect(name: str, period: str) -> Effect:
    ax = _AXIS[name[-1]]
    per = f"a period of {period} mm" if period else "a period found by scanning"
    return Effect(name if not period else f"{name}:{period}",
                  f"{ax} periodic scale error" + (f" ({period} mm)" if period else ""),
                  f"the {ax} reading is off by a sine wave along {ax} with {per}: a lead "
                  "screw, rack or pinion, or a scale's own periodic error. A polynomial "
                  "cannot follow it once the period is shorter than about a third of the "
                  "stroke.",
                  f"balls at several phases of the period along {ax}: placements shifted "
                  "along the axis by a fraction of the ball pitch.",
                  f"higher orders of the {ax} positioning error (long periods) and aliasing "
                  "of periods shorter than twice the ball spacing.",
                  f"a second placement shifted along {ax} by a quarter of the period.")


def catalogue_entry(name: str) -> Effect:
    """Catalogue entry for an effect name (``dyz``, ``dyz:3``, ``periodic_x:200`` or a
    physical effect)."""
    base, _, order = name.partition(":")
    if base in _PHYSICAL:
        return _PHYSICAL[base]
    if base in PERIODIC:
        return _periodic_effect(base, order)
    if base in ERROR_NAMES:
        e = _kinematic_effect(base)
        if order:
            ax = _AXIS[base[1]]
            # a higher order competes with the neighbouring orders and with long-period
            # errors along the same axis, not with what the function itself is confused with
            return Effect(name, f"{e.title}, order {order}",
                          f"{e.explanation} The current polynomial is too stiff: a "
                          f"higher-order term (Chebyshev degree {order}) bends it.",
                          e.needs,
                          f"the neighbouring orders of {base} and a periodic error along "
                          f"{ax} of a long period.",
                          f"balls at more positions along {ax}: a placement shifted along "
                          f"{ax} by part of the ball pitch, or a plate with a finer pitch.")
        return e
    raise KeyError(name)


@dataclass(frozen=True)
class ModelSpec:
    """A parsed model: kinematic function orders and physical effect blocks.

    Attributes
    ----------
    orders : tuple of (str, int)
        Every one of the 21 errors with its order (0 = absent), in ``ERROR_NAMES`` order.
    effects : tuple of str
        Physical effects present, in ``PHYSICAL`` order.
    default_order : int
        Order used for functions named without ``:order``.
    periods : tuple of (str, float)
        ``(positioning function, period mm)`` of the periodic scale errors present.
    """

    orders: tuple
    effects: tuple
    default_order: int = 2
    periods: tuple = ()

    def order(self, name: str) -> int:
        """Order of one error function (0 when absent)."""
        return dict(self.orders)[name]

    @property
    def active(self) -> tuple:
        """``(name, order)`` for the functions present."""
        return tuple((n, o) for n, o in self.orders if o > 0)

    def to_string(self, explicit: bool = False) -> str:
        """Canonical spec string that parses back to this model.

        By default orders are written relative to this model's own default order, so that
        a reader parsing with another default order (the app's order selector) re-orders
        the model. ``explicit=True`` writes them relative to the default order 2
        ("kinematic21" at order 3 becomes "kinematic21:3"): the form for reports, files
        and the CLI, read back with the default order.
        """
        o_ref = self.default_order if not explicit else 2
        o_mod = self.default_order
        act = dict(self.active)
        # squareness is one constant whatever its order: never worth an ":o"
        same = {n: n in SQUARENESS or o == o_mod for n, o in act.items()}
        tokens = []
        if len(act) > len(ERROR_NAMES) // 2:  # "kinematic21,-sxy" rather than 20 names
            tokens.append("kinematic21" if o_mod == o_ref else f"kinematic21:{o_mod}")
            gone = [n for n in ERROR_NAMES if n not in act]
            for g in ("translational", "rotational", "squareness"):
                if set(GROUPS[g]) <= set(gone):
                    tokens.append(f"-{g}")
                    gone = [n for n in gone if n not in GROUPS[g]]
            tokens += [f"-{n}" for n in gone]
            tokens += [n if o == o_ref else f"{n}:{o}" for n, o in act.items() if not same[n]]
        else:
            tokens += [n if o == o_ref or n in SQUARENESS else f"{n}:{o}"
                       for n, o in act.items()]
        tokens += list(self.effects)
        inv = {v: k for k, v in PERIODIC.items()}
        tokens += [f"{inv[n]}:{p:g}" for n, p in self.periods]
        return ",".join(tokens) if tokens else "rigid"

    def with_token(self, token: str) -> ModelSpec:
        """This model with one more token applied (``plate_sag``, ``-sxy``, ``dyz:3``)."""
        return parse_spec(self.to_string() + "," + token, default_order=self.default_order)

    def candidates(self) -> list:
        """Tokens not yet in the model: absent errors, the next two orders of each present
        function (up to ``MAX_ORDER``) and absent physical effects.

        Two orders, because a function whose true shape is two degrees above the model
        (an order-4 bow on an order-2 model) is only partly followed by the next order:
        offered both, the ranking names the one the data support (ΔBIC charges the extra
        coefficient; when the next order explains as much, it wins)."""
        out = []
        for n, o in self.orders:
            if o == 0:
                out.append(n)
            elif n not in SQUARENESS:
                out += [f"{n}:{k}" for k in range(o + 1, min(o + 2, MAX_ORDER) + 1)]
        out += [e for e in PHYSICAL if e not in self.effects]
        # without a period: diagnose scans the period (``blocks.periodic.PERIOD_SCAN``)
        have = {n for n, _ in self.periods}
        out += [t for t, n in PERIODIC.items() if n not in have]
        return out


def parse_spec(spec: str, *, default_order: int = 2) -> ModelSpec:
    """Parse a model spec string (the grammar of docs/formats.md "Model specs"), raising ValueError on unknown tokens.

    ``""`` or ``"rigid"`` is the rigid-placement-only model.
    """
    if not 1 <= default_order <= MAX_ORDER:
        raise ValueError(f"order must be 1-{MAX_ORDER}, got {default_order}.")
    orders = dict.fromkeys(ERROR_NAMES, 0)
    effects: set[str] = set()
    periods: dict[str, float] = {}
    for raw in str(spec).split(","):
        tok = raw.strip().lower()  # "Kinematic21", "DYZ:3" read as the documented names
        if not tok or tok == "rigid":
            continue
        remove = tok.startswith("-")
        tok = tok.lstrip("-+").strip()
        base, _, ordtxt = tok.partition(":")
        if base in PERIODIC:
            if remove:
                periods.pop(PERIODIC[base], None)
                continue
            try:
                period = float(ordtxt)
            except ValueError:
                period = float("nan")
            if not 1.0 <= period <= 1e5:
                raise ValueError(f"model token {raw.strip()!r}: give the period in mm after "
                                 f"':', e.g. {base}:200 (1 to 100000 mm).")
            periods[PERIODIC[base]] = period
            continue
        order = default_order
        if ordtxt:
            try:
                order = int(ordtxt)
            except ValueError:
                raise ValueError(f"model token {raw.strip()!r}: the order after ':' must be "
                                 "a whole number 1-5.") from None
            if not 1 <= order <= MAX_ORDER:
                raise ValueError(f"model token {raw.strip()!r}: order must be 1-{MAX_ORDER}.")
        if base in PHYSICAL:
            (effects.discard if remove else effects.add)(base)
            continue
        names = GROUPS.get(base, (base,) if base in ERROR_NAMES else None)
        if names is None:
            known = ", ".join(list(GROUPS) + list(PHYSICAL))
            raise ValueError(f"unknown model token {raw.strip()!r}; expected one of the 21 "
                             f"error names (dxx ... syz), name:order (dyz:3), {known}, "
                             "or periodic_x:PERIOD_MM (and _y, _z).")
        for n in names:
            orders[n] = 0 if remove else order
    return ModelSpec(tuple(orders.items()), tuple(e for e in PHYSICAL if e in effects),
                     default_order, tuple((n, periods[n]) for n in PERIODIC.values()
                                          if n in periods))


def correction_columns(model: str | ModelSpec | Iterable) -> tuple:
    """Columns (besides ``x_mm, y_mm, z_mm, probe``) that points need to be corrected by a
    model: each compensating block's :meth:`~blocks.base.Block.correction_columns`, in
    ``blocks.REGISTRY`` order, without repeats.

    ``model``: a spec string or :class:`ModelSpec`; an iterable of tokens, block classes
    or block instances (a fit's ``problem.layout.blocks`` or ``problem.blocks``; names that
    are not effect tokens are skipped); or a saved model's ``parts`` (token -> part: then
    only the fitted axes' columns of ``machine_thermal``)."""
    labels = {}
    if isinstance(model, str):
        model = parse_spec(model)
    if isinstance(model, ModelSpec):
        tokens = set(model.effects)
    else:
        tokens = set()
        for item in model:
            if isinstance(item, Block) or (isinstance(item, type) and issubclass(item, Block)):
                item = item.token
            if isinstance(item, str) and item in BY_TOKEN:
                tokens.add(item)
                part = model[item] if isinstance(model, dict) else None
                if part is not None and hasattr(part, "labels"):  # a saved model's part
                    labels[item] = part.labels
    out = []
    for b in REGISTRY:
        if b.token is not None and b.token in tokens and b.model_keys:
            out += [c for c in b.correction_columns(labels.get(b.token)) if c not in out]
    return tuple(out)

"""Units: files are in mm, parameters and screens in µm and µrad (one definition each).

Parameter units are short ASCII codes in results and JSON (``um``, ``urad``, ``um/h``,
``1e-6/K``); :func:`label` turns them into what a metrologist reads on screen.
:func:`number`, :func:`p_text` and :func:`value_u` write the numbers of a verdict (no
``-0.0``, no ``p = 0``, no ``± nan``).
"""

from __future__ import annotations

import math

UM = 1e-3
"""Millimetres per micrometre: ``value_mm = value_um * UM``."""
URAD = 1e-6
"""Radians per microradian."""
PPM = 1e-6
"""Relative units per part per million (``1e-6/K`` is ppm per kelvin)."""

LABELS = {"um": "µm", "urad": "µrad", "um/h": "µm/h", "1e-6/K": "10⁻⁶/K", "mm": "mm",
          "um/m": "µm/m"}


def label(unit: str) -> str:
    """Screen label of a unit code (``"um"`` -> ``"µm"``); unknown codes pass through."""
    return LABELS.get(unit, unit)


# --- small number formatters: the one place the verdict's words take their numbers from
# (the diagnosis's headline, shared by the app, the report and the CLI's JSON)

P_FLOOR = 1e-16
"""Below this a p-value is written ``p < 1e-16``: a double's tail near 1 cannot resolve
smaller values (``1 - cdf`` rounds to 0), so a printed ``p = 0`` would claim certainty."""


def number(value: float, fmt: str = ".3g") -> str:
    """``value`` formatted with ``fmt``, a zero without its sign: ``-0.0`` and a small
    negative that rounds to zero (``-0.004`` at ``.2f``) print ``0.0``, ``0.00``, never
    ``-0.0``. Not a number and infinities print ``nan``, ``inf``, ``-inf``."""
    v = float(value)
    if not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    text = format(v, fmt)
    if text[:1] in "-+" and float(text) == 0:
        return text[1:]
    return text


def p_text(p: float) -> str:
    """``p = 0.0013``; below :data:`P_FLOOR` ``p < 1e-16`` (never ``p = 0``); a p-value
    not computed (NaN) ``p not computed``."""
    v = float(p)
    if math.isnan(v):
        return "p not computed"
    if v < P_FLOOR:
        return f"p < {P_FLOOR:g}"
    return f"p = {number(v, '.2g')}"


def value_u(value: float, u: float, unit: str = "", why: str = "") -> str:
    """``12.7 ± 2.8 µrad`` (``unit``: a unit code, :func:`label`); a ``u`` that is not
    determinable (NaN, infinite, or not positive) is never printed as ``± nan``: the
    value alone and the reason, ``-0.012 µm (u not determinable: aliased with drift)``
    (``why``; without one: ``the data do not determine it``)."""
    tail = f" {label(unit)}" if unit else ""
    v = number(value)
    uf = float(u)
    if math.isfinite(uf) and uf > 0:
        return f"{v} ± {number(uf, '.2g')}{tail}"
    return f"{v}{tail} (u not determinable: {why or 'the data do not determine it'})"

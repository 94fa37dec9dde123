"""Units: files are in mm, parameters and screens in µm and µrad (one definition each).

Parameter units are short ASCII codes in results and JSON (``um``, ``urad``, ``um/h``,
``1e-6/K``); :func:`label` turns them into what a metrologist reads on screen.
"""

from __future__ import annotations

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

"""The machine's geometry: error names, the eight layouts' kinematic chains, the forward
model of the 21 error functions and rigid-body helpers (thesis ch. 4, eq. 4.1-4.9, 4.13).

Owns: :mod:`.terms` (error names, layouts, Chebyshev terms), :mod:`.layouts` (chains other
than the moving bridge FXYZ, table axes inverted), :mod:`.kinematics` (tip position, error,
Jacobians, inversion), :mod:`.geometry` (skew matrices, rigid fits, plate-effect basis).
May import: numpy, scipy and the ground modules ``cmm_core.units`` and ``cmm_core._blas``.
"""

from __future__ import annotations

from .geometry import plate_effect_basis, rigid_fit, skew
from .kinematics import error, invert, jacobian, model_point, probe_jacobian
from .layouts import forward_block, probe_rotation, split_chain
from .terms import (
    AXES,
    DEFAULT_LAYOUT,
    ERROR_NAMES,
    LAYOUTS,
    POSITIONING,
    ROTATIONAL,
    SQUARENESS,
    STRAIGHTNESS,
    TRANSLATIONAL,
    KinematicTerms,
    axis_of,
    basis,
    check_layout,
    direction_of,
    n_coefficients,
    periodic_basis,
)

__all__ = [
    "AXES", "axis_of", "basis", "check_layout", "DEFAULT_LAYOUT", "direction_of", "error",
    "ERROR_NAMES", "forward_block", "invert", "jacobian", "KinematicTerms", "LAYOUTS",
    "model_point", "n_coefficients", "periodic_basis", "plate_effect_basis", "POSITIONING",
    "probe_jacobian", "probe_rotation", "rigid_fit", "ROTATIONAL", "skew", "split_chain",
    "SQUARENESS", "STRAIGHTNESS", "TRANSLATIONAL"
]

"""Gaussian-process regression and its use on CMM errors (thesis ch. 7; Rasmussen &
Williams 2006, ch. 2 and 5).

Owns: :mod:`.regression` (:func:`fit_gp`, marginal likelihood), :mod:`.basis` (explicit
mean functions), :mod:`.likelihood` (kernels, Cholesky), :mod:`.optimise`, :mod:`.prepare`,
:mod:`.degeneracy`, :mod:`.result` (:class:`GPResult`), :mod:`.cmm` (per-component GPs
of a kinematic fit's residuals or of the raw errors). May import: ground modules only.
"""

from __future__ import annotations

from .basis import MEANS, polynomial_basis
from .cmm import (
    COMPONENTS,
    Appendix3Result,
    GPComponents,
    Grid,
    appendix3_workflow,
    box_grid,
    gp_components,
    plate_grid,
    predict_grid,
)
from .likelihood import KERNELS
from .regression import fit_gp, log_marginal_likelihood
from .result import GPResult

__all__ = [
    "appendix3_workflow", "Appendix3Result", "box_grid", "COMPONENTS", "fit_gp",
    "gp_components", "GPComponents", "GPResult", "Grid", "KERNELS", "log_marginal_likelihood",
    "MEANS", "plate_grid", "polynomial_basis", "predict_grid"
]

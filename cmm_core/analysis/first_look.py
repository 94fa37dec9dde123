"""What the loaded data show at first sight, and the one next step: the Data page's
headline, above everything else (a metrologist's first screen).

The state of an analysis decides the step, in the order a calibration is worked through:
a fit that failed or did not converge first, then flagged outliers still in the fit (one
blunder of tens of µm poses as an effect), then a fit that fails its χ² test (a missing
effect: the diagnosis), and with a passing fit the uncertainties.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..io import Dataset
from ..model import FitResult
from ..units import p_text

__all__ = ["FIRST_STEPS", "FirstLook", "first_look"]

FIRST_STEPS = ("refit", "exclude_outliers", "diagnose", "uncertainty")
"""The next steps :func:`first_look` can name, in the order they are taken."""


@dataclass(frozen=True)
class FirstLook:
    """The first screen's summary of an analysis."""

    title: str
    """One line: the dataset and what its fit says."""
    text: str
    """The fit's numbers with their units: RMS, the χ² test, outliers."""
    step: str
    """The next step, one of :data:`FIRST_STEPS`."""
    action: str
    """The next step in plain words."""
    level: str
    """``"success"``, ``"info"`` or ``"warning"``: how the page draws it."""


def first_look(dataset: Dataset, fit: FitResult | None, pending_outliers: int) -> FirstLook:
    """The summary of ``dataset`` fitted by the current model (``fit``, None when the fit
    failed) with ``pending_outliers`` flagged observations still in it."""
    where = (f"{dataset.name}: {len(dataset.meas)} probed ball centres in "
             f"{len(dataset.positions)} placement(s), {len(dataset.probes)} stylus(es), "
             + ("a certificate" if dataset.certificate is not None
                else "no certificate (the plate is self-calibrated)"))
    if fit is None or fit.status != "converged":
        return FirstLook(where, "The current model could not be fitted to these data"
                         + ("." if fit is None else f" ({fit.message})."), "refit",
                         "Check the model and its settings on the Kinematic model page.",
                         "warning")
    test = (f"fails its χ² test ({p_text(fit.chi2_p_value)}: the model leaves more than "
            "the noise)" if fit.fails_chi2_test else
            f"passes its χ² test ({p_text(fit.chi2_p_value)})")
    text = (f"The {fit.spec} fit: RMS residual {fit.rms_um:.3f} µm, χ²/dof "
            f"{fit.chi2_dof:.2f}, {test}.")
    if pending_outliers:
        return FirstLook(where, text + f" {pending_outliers} flagged outlier(s) are still in "
                         "the fit.", "exclude_outliers",
                         "Exclude the flagged outliers first (below): one blunder of tens "
                         "of µm can hide a real effect or pose as one.", "warning")
    if fit.fails_chi2_test:
        return FirstLook(where, text, "diagnose",
                         "Find the missing effect: run the diagnosis on the Diagnose page.",
                         "info")
    return FirstLook(where, text, "uncertainty",
                     "The model explains the data to their noise: look at the uncertainties "
                     "and the compensation.", "success")

"""The discrepancy between the kinematic model and the data as a Gaussian process with
the model's own functions as its explicit basis (thesis chapter 7): what is left once
the kinematic model has taken what it can."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._blas import single_blas_thread
from ..gp import gp_components
from ..model import FitResult


def kinematic_basis(result: FitResult) -> list[np.ndarray]:
    """Per-component design matrices of a fit at its observations, for a GP mean.

    Returns a list of three arrays (n, m_c): an orthonormal basis of the columns of the
    model's Jacobian restricted to the x, y and z residual rows, so that a GP over the
    residuals with this explicit basis cannot absorb what the model already explains.
    """
    _, J = result.problem.residual(result.state, True)
    J = J.toarray()
    out = []
    for c in range(3):
        Jc = J[c::3]
        Jc = Jc[:, np.linalg.norm(Jc, axis=0) > 0]
        U, s, _ = np.linalg.svd(Jc, full_matrices=False)
        keep = s > 1e-8 * s.max() if s.size else s.astype(bool)
        k = min(int(keep.sum()), Jc.shape[0] - 3)
        out.append(U[:, :k])
    return out


@dataclass(frozen=True)
class Discrepancy:
    """GP over a fit's residuals with the model's own design matrix as explicit basis.

    Attributes
    ----------
    amplitude_um : dict
        Signal standard deviation (hyperparameter) of each component's GP (x, y, z), µm.
        Poorly determined when the length scale runs to the size of the machine; use
        ``structure_um`` to compare models.
    length_scale_mm : dict
        Length scale(s) of each component's GP, mm.
    noise_sd_um : dict
        Fitted noise standard deviation per component, µm.
    structure_um : dict
        RMS over the observations of the GP's posterior mean of the discrepancy (the
        part of the residual the GP attributes to smooth structure rather than noise), µm.
    rms_amplitude_um : float
        sqrt(mean over components of ``structure_um`` squared): the one number of the
        add-and-watch history; it falls towards zero when the missing effect is added.
    components : object
        The fitted ``gp.cmm.GPComponents`` (for surfaces).
    """

    amplitude_um: dict
    length_scale_mm: dict
    noise_sd_um: dict
    structure_um: dict
    rms_amplitude_um: float
    components: object = field(repr=False)


@single_blas_thread
def discrepancy_gp(result: FitResult, *, kernel: str = "se_iso", restarts: int = 2,
                   seed: int = 0) -> Discrepancy:
    """Structure left in the residuals: one GP per component over the machine
    coordinates of the observations, with :func:`kinematic_basis` as explicit basis
    (marginalised, R&W §2.7) so the GP cannot absorb what the model already explains. Its
    amplitude shrinks towards zero (the noise takes over) when the missing effect is added.
    """

    o = result.problem.obs
    comps = gp_components(o.r_mm - o.p_mm, result.residuals_um, kernel=kernel,
                          basis=kinematic_basis(result), restarts=restarts, seed=seed)
    amp = {c: float(comps[c].signal_sd_um) for c in comps.names}
    ls = {c: [float(v) for v in comps[c].length_scale_mm] for c in comps.names}
    noise = {c: float(comps[c].noise_sd_um) for c in comps.names}
    X = o.r_mm - o.p_mm
    struct = {c: float(np.sqrt(np.mean(comps[c].predict(X, include_mean=False)[0] ** 2)))
              for c in comps.names}
    return Discrepancy(amp, ls, noise, struct,
                       float(np.sqrt(np.mean(np.square(list(struct.values()))))), comps)

"""What a block keeps to correct new points (``export.correction``): its part of a model
file (:class:`ModelPart`), its correction of points (:class:`Correction`), and the check
of a model file's covariance (:func:`checked_cov`, :data:`MAX_MODEL_U`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...io import DataError


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
    """What else the block's :meth:`~.base.Block.correct` needs of the fit (the machine's
    range and layout: ``bridge_twist``), written and read by the block with its keys."""


@dataclass(frozen=True)
class Correction:
    """A block's correction of new points (:meth:`~.base.Block.correct`).

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


MAX_MODEL_U = 1e6
"""Largest standard uncertainty (µm, µrad) a model file's covariance may give a
parameter: a metre or a radian is no CMM's error, and larger variances overflow the
propagation (a grid's J V Jᵀ)."""


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

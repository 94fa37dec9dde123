"""What an interim check cannot see, in words (docs/monitoring.md, "What changed").

The refit of the stored model on the new data (:func:`.changes.what_changed`) finds the
combinations of the kinematic parameters the new data cannot determine: directions ``v``
over the parameters, each weight in units of its parameter's prior standard uncertainty.
A metrologist reads them as errors of the machine, so each direction is said in words
from the labels of the parameters that carry it (``machine.KinematicTerms.labels``, the
names of the 21 errors, ISO 230-1; the Chebyshev degree in brackets):

- ``dAA[1]``: the A **scale** (``dAA linear``); ``dAA[k]``, k ≥ 2, its **curvature**;
  ``dAA[sinP]``, ``dAA[cosP]``: its periodic error of period P mm;
- ``dAB[k]`` (A ≠ B): the A **straightness** in B (no linear part: the straightness
  functions start at degree 2);
- ``rAB[1]``: the A carriage's **roll**, **pitch**, **yaw** or **tilt** about B
  (``model.rotation_kind``, ISO 230-1's words) growing along A; ``rAB[k]``, k ≥ 2, its
  curvature;
- ``sAB``: the AB **squareness** (a constant angle).

The words are the model's (:func:`model.direction_phrase`, shared with the fit's
undetermined combinations): the parameters that carry a direction (a weight of at least
``CARRIER_WEIGHT`` of the largest, at most ``MAX_CARRIERS`` of them) are grouped by
error function and by the axis the function varies with (``machine.axis_of``: an error of the z axis, and the
squareness ``sxz``, ``syz`` of x and y readings in proportion to z, vary with z alone).
A direction carried by functions of one axis only reads "anything that varies only with
z: ...": one placement of a plate at one height hardly sees them (each is a constant
over the plate, taken up by the placement's pose; a rotation is seen only through the
styli's different offsets).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..model import CARRIER_WEIGHT, MAX_CARRIERS, direction_phrase, distinct_words

__all__ = ["CARRIER_WEIGHT", "MAX_CARRIERS", "unseen_words", "combination_text",
           "distinct_words", "unseen_example"]


def unseen_words(directions: np.ndarray | Sequence, labels: Sequence[str]) -> list[str]:
    """Each undetermined combination of the parameters in plain words.

    Parameters
    ----------
    directions : array_like (m, k)
        One direction per row over the ``k`` parameters ``labels``, each weight in units
        of its parameter's prior standard uncertainty (``Changes.unseen_directions``);
        the sign and the scale of a row do not matter.
    labels : sequence of str
        The parameters' labels (``KinematicTerms.labels``: ``dzz[1]``, ``ryx[2]``,
        ``sxy``, ``dxx[sin200]``); a label outside the 21 errors is named as it is.

    Returns
    -------
    list of str
        One sentence per direction, e.g. ``"the z scale (dzz linear)"``, ``"anything that
        varies only with z: the z straightness in y (dzy[2]) and the curvature of the z
        carriage's tilt about x (rzx[2])"``, ``"the xy squareness (sxy)"``.

    Raises
    ------
    ValueError
        When a direction's length is not the number of labels.

    Notes
    -----
    The names are ISO 230-1:2012's (positioning, straightness, roll, pitch, yaw,
    squareness), as the effect catalogue gives them (``model.catalogue_entry``). The
    directions are one basis of the unseen subspace, not unique (only the subspace is a
    property of the check's design; ``what_changed`` rotates its basis to few parameters
    per direction); the words name the errors that carry each basis vector.
    """
    D = np.asarray(directions, float)
    D = D.reshape(0, len(labels)) if not D.size else np.atleast_2d(D)
    if D.ndim != 2 or D.shape[1] != len(labels):
        raise ValueError(f"each direction needs {len(labels)} weights (one per label), got "
                         f"shape {np.shape(directions)}.")
    return [direction_phrase(v, labels) for v in D]


def combination_text(direction: np.ndarray, labels: Sequence[str], *, shown: int = 3) -> str:
    """One direction as its largest prior-scaled weights, e.g. ``"1.00 sxz - 0.70 ryy[1]"``
    (the form for experts: ``unseen_combinations`` of the results).

    Parameters
    ----------
    direction : array_like (k,)
        Weights over ``labels`` in units of each parameter's prior standard uncertainty.
    labels : sequence of str
        The parameters' labels.
    shown : int
        At most this many weights, largest first (those below 0.2 of the largest left out).

    Returns
    -------
    str
    """
    v = np.asarray(direction, float)
    top = np.abs(v).max() if v.size else 0.0
    if not top > 0:
        return ""
    v = v / v[int(np.argmax(np.abs(v)))]  # the largest weight +1
    big = [b for b in np.argsort(-np.abs(v), kind="stable")[:shown] if abs(v[b]) >= 0.2]
    return " ".join(f"{'+' if v[b] >= 0 else '-'} {abs(v[b]):.2f} {labels[b]}"
                    for b in big).lstrip("+ ")


def unseen_example(words: Sequence[str], most: int = 2) -> str:
    """The first ``most`` distinct sentences of :func:`unseen_words`, joined by "; " (the
    messages' example of what a check cannot see)."""
    return "; ".join(w for w, _ in distinct_words(words)[:most])

"""The fit's parameters in words: what a combination the data cannot determine is, as a
metrologist says it (issue 41: "the styli's z offsets and the placements' heights cannot
be told apart", not "−1.00·B2.tz − 1.00·B1.tz − 1.00·probeG1.z").

A direction ``v`` over the parameters (a null vector of the fit, or an interim check's
unseen direction) is said from the labels of the parameters that carry it: a weight of
at least :data:`CARRIER_WEIGHT` of the largest, largest first. The labels are the
parameter layout's (``Problem.layout.labels``):

- the 21 errors (``machine.ERROR_NAMES``, ISO 230-1; the Chebyshev degree in brackets):
  ``dAA[1]`` the A **scale**, ``dAA[k]`` (k ≥ 2) its **curvature**, ``dAA[sinP]`` its
  periodic error of period P mm; ``dAB[k]`` (A ≠ B) the A **straightness** in B;
  ``rAB[1]`` the A carriage's **roll**, **pitch**, **yaw** or **tilt** about B
  (:func:`.effects.rotation_kind`), ``rAB[k]`` its curvature; ``sAB`` the AB
  **squareness**;
- a placement's pose, ``P.tx`` (its x position) and ``P.rx`` (its rotation about x);
- a stylus's offset, ``probeS.x``; a placement's drift, ``P.drift_x``;
- any other effect's parameter, ``token.name``, by its catalogue title.

Parameters of one kind and component are said together ("the z offsets of styli 1, 2
and 4"); functions of the 21 errors that vary with one axis only are said to do so (one
placement of a plate at one height hardly sees them: each is a constant over the plate,
taken up by the placement's pose).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from ..machine import (
    ERROR_NAMES,
    POSITIONING,
    ROTATIONAL,
    SQUARENESS,
    STRAIGHTNESS,
    axis_of,
)
from .effects import BY_TOKEN, catalogue_entry, rotation_kind

__all__ = ["CARRIER_WEIGHT", "MAX_CARRIERS", "direction_phrase", "distinct_words",
           "null_carriers", "null_words", "parameter_name"]

CARRIER_WEIGHT = 0.25
"""A parameter carries a direction when its weight is at least this fraction of the
direction's largest."""

MAX_CARRIERS = 4
"""At most this many parameters of a direction are named by :func:`direction_phrase`
unless asked for more (largest weights first)."""

_GROUPED = {  # label kind -> (its noun for one parameter, for several)
    "probe": ("offset of stylus", "offsets of styli"),
    "position": ("position of placement", "positions of placements"),
    "rotation": ("rotation of placement", "rotations of placements"),
    "drift": ("drift of placement", "drifts of placements"),
}


def direction_phrase(v: np.ndarray, labels: Sequence[str], *,
                     most: int = MAX_CARRIERS) -> str:
    """One direction over the parameters as a noun phrase.

    Parameters
    ----------
    v : array_like (k,)
        Weights over ``labels``; the sign and scale do not matter. For an interim check's
        directions each weight is in units of its parameter's prior standard uncertainty.
    labels : sequence of str
        The parameters' labels (module docstring).
    most : int
        At most this many carrying parameters, largest weights first.

    Returns
    -------
    str
        E.g. ``"the z scale (dzz linear)"``, ``"anything that varies only with z: the z
        straightness in y (dzy[2]) and the curvature of the z carriage's tilt about x
        (rzx[2])"``, ``"the z offsets of styli 1 and 2 together with the z positions of
        placements B1 and B2"``; ``"no parameter"`` for a zero direction.
    """
    groups = _carriers(v, labels, most)
    if not groups:
        return "no parameter"
    # the functions of one axis side by side (the first axis met first), then the rest
    by_axis: dict = {}
    for kind, key in groups:
        by_axis.setdefault("xyz"[axis_of(key)] if kind == "error" else None,
                           []).append((kind, key))
    phrases = [_phrase(kind, key, groups[(kind, key)]) for keys in by_axis.values()
               for kind, key in keys]
    if len(phrases) == 1:
        return phrases[0]
    if axis := _one_axis(groups):
        return f"anything that varies only with {axis}: {_join(phrases)}"
    return f"{phrases[0]} together with {_join(phrases[1:])}"


def null_words(null: np.ndarray, labels: Sequence[str]) -> list[str]:
    """Each combination a fit cannot determine as a sentence a metrologist reads.

    Parameters
    ----------
    null : array_like (k, m)
        One null vector per column over the ``k`` parameters ``labels``
        (:func:`.solver.describe_null`'s input).
    labels : sequence of str
        The parameters' labels.

    Returns
    -------
    list of str
        One sentence per column, e.g. ``"The z offsets of styli 1, 2 and 4 and the z
        positions of placements B1 and B2 cannot be told apart."`` or ``"The curvature
        of the y carriage's tilt ... (ryz[2]) is not determined."``.
    """
    if not len(labels):
        return []
    null = np.asarray(null, float).reshape(len(labels), -1)
    out = []
    for v in null.T:
        groups = _carriers(v, labels, _MOST_NULL)
        if not groups:
            out.append("No parameter.")
            continue
        phrases = [_phrase(kind, key, tokens) for (kind, key), tokens in groups.items()]
        more = len(_carrier_labels(v, labels, len(labels))) - sum(map(len, groups.values()))
        if more:  # named up to _MOST_NULL; the rest counted, never dropped silently
            phrases.append(f"{more} more parameter{'s' if more > 1 else ''}")
        text = _join(phrases)
        text = text[:1].upper() + text[1:] if text.startswith("the ") else text
        if sum(map(len, groups.values())) == 1 and not more:
            out.append(f"{text} is not determined.")
            continue
        if len(groups) == 1 and not more and _sine_and_cosine(next(iter(groups.values()))):
            # one periodic error's two terms: its phase, not two errors
            out.append(f"{text}: its sine and cosine terms cannot be told apart.")
            continue
        axis = _one_axis(groups) if len(groups) > 1 and not more else None
        why = f" (each varies only with {axis})" if axis else ""
        out.append(f"{text} cannot be told apart{why}.")
    return out


_MOST_NULL = 12
"""A fit's null vector is named by at most this many parameters: a stylus offset aliased
with the placements' positions carries six or more of equal weight."""


def _carriers(v, labels: Sequence[str], most: int) -> dict[tuple, list[str]]:
    """The carrying parameters of ``v`` grouped by ``(kind, key)`` (:func:`_parse`), the
    groups and their tokens in order of weight; empty for a zero direction."""
    groups: dict[tuple, list[str]] = {}
    for label in _carrier_labels(v, labels, most):
        kind, key, token = _parse(label)
        groups.setdefault((kind, key), []).append(token)
    return groups


def _carrier_labels(v, labels: Sequence[str], most: int) -> list[str]:
    """The labels of ``v``'s weights of at least :data:`CARRIER_WEIGHT` of the largest,
    largest first, at most ``most``."""
    a = np.abs(np.asarray(v, float))
    top = a.max() if a.size else 0.0
    if not top > 0:
        return []
    return [labels[int(j)] for j in np.argsort(-a, kind="stable")[:most]
            if a[j] >= CARRIER_WEIGHT * top]


def _sine_and_cosine(tokens: list) -> bool:
    """The tokens are the sine and cosine terms of one period (``sin200``, ``cos200``)."""
    return sorted(t[:3] for t in tokens) == ["cos", "sin"] and len({t[3:] for t in tokens}) == 1


def _one_axis(groups: dict) -> str | None:
    """The axis every group varies with, when all are functions of the 21 errors of one
    axis (``machine.axis_of``); else None."""
    axes = {"xyz"[axis_of(key)] if kind == "error" else None for kind, key in groups}
    return next(iter(axes)) if len(axes) == 1 and None not in axes else None


def null_carriers(null: np.ndarray, labels: Sequence[str]) -> list[tuple[str, ...]]:
    """The labels each sentence of :func:`null_words` names, per null vector (a column of
    ``null``), largest weight first."""
    if not len(labels):
        return []
    null = np.asarray(null, float).reshape(len(labels), -1)
    return [tuple(_carrier_labels(v, labels, _MOST_NULL)) for v in null.T]


def parameter_name(label: str) -> str:
    """One parameter's name in words, for a table beside its label.

    Parameters
    ----------
    label : str
        A parameter layout's label (module docstring).

    Returns
    -------
    str
        E.g. ``"z scale"`` for ``dzz[1]``, ``"curvature of the y carriage's yaw about z"``
        for ``ryz[2]``, ``"x offset of stylus 1"`` for ``probe1.x``, ``"plate sag
        (gravity bending): uu"`` for ``plate_sag.uu``; an unknown label as it is.
    """
    kind, key, token = _parse(label)
    if kind == "effect":
        return f"{catalogue_entry(key).title}: {token}"
    if kind != "error":
        return _phrase(kind, key, [token]).removeprefix("the ")
    noun = _function_phrase(key, [], codes=False).removeprefix("the ")
    if key in SQUARENESS or token == "1":
        return noun
    if token.isdigit() and int(token) >= 2:
        return f"{noun}, degree {token}"
    if token[:3] in ("sin", "cos") and token[3:]:
        return f"{noun}, {'sine' if token[:3] == 'sin' else 'cosine'} of period {token[3:]} mm"
    return f"{noun} ({label})"  # a term this release does not know by name


def distinct_words(words: Sequence[str]) -> list[tuple[str, int]]:
    """The sentences once each, in order, with how many directions read so (for a list on
    a page or in a message: a basis of an undetermined space often repeats a sentence)."""
    out: dict[str, int] = {}
    for w in words:
        out[w] = out.get(w, 0) + 1
    return list(out.items())


def _parse(label: str) -> tuple[str, str, str]:
    """``(kind, key, token)``: ``("error", "dzz", "2")`` for ``dzz[2]``, ``("probe", "z",
    "1")`` for ``probe1.z``, ``("position", "x", "B1")`` for ``B1.tx``."""
    base, _, rest = label.partition("[")
    if base in ERROR_NAMES:
        return "error", base, rest.rstrip("]")
    head, dot, tail = label.rpartition(".")
    if not dot:
        return "other", label, ""
    if head.startswith("probe") and tail in ("x", "y", "z"):
        return "probe", tail, head[len("probe"):]
    if tail in ("tx", "ty", "tz"):
        return "position", tail[1], head
    if tail in ("rx", "ry", "rz"):
        return "rotation", tail[1], head
    if tail.startswith("drift_"):
        return "drift", tail[len("drift_"):], head
    if head in BY_TOKEN or head.startswith("periodic_"):
        return "effect", head, tail
    return "other", label, ""


def _phrase(kind: str, key: str, tokens: list) -> str:
    if kind == "error":
        return _function_phrase(key, tokens)
    if kind == "effect":
        return f"the {catalogue_entry(key).title} ({', '.join(f'{key}.{t}' for t in tokens)})"
    if kind == "other":
        return key
    one, many = _GROUPED[kind]
    tokens = sorted(tokens, key=_natural)  # styli 1, 2 and 10; placements B1 and B2
    axis = f"about {key}" if kind == "rotation" else key
    noun = one if len(tokens) == 1 else many
    if kind == "rotation":  # "the rotations about z of placements B1 and B2"
        word, _, whose = noun.partition(" of ")
        return f"the {word} {axis} of {whose} {_join(tokens)}"
    return f"the {axis} {noun} {_join(tokens)}"


def _natural(name: str) -> list:
    """Sort key reading the digits of a name as numbers (``B2`` before ``B10``)."""
    return [(0, int(p), "") if p.isdigit() else (1, 0, p)
            for p in re.split(r"(\d+)", name) if p]


def _join(parts: list) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]


def _code(base: str, token: str) -> str:
    """The label as the sentence quotes it: degree 1 is ``linear``."""
    return base if not token else f"{base} linear" if token == "1" else f"{base}[{token}]"


def _function_phrase(base: str, tokens: list, codes: bool = True) -> str:
    """One error function with the terms of it that carry a direction (their codes in
    brackets unless ``codes`` is False); no terms: the function's noun alone."""
    tokens = sorted(tokens, key=lambda t: (0, int(t), "") if t.isdigit() else (1, 0, t))
    said = f" ({', '.join(_code(base, t) for t in tokens)})" if codes else ""
    a, d = base[1], base[2]
    if base in SQUARENESS:
        return f"the {a}{d} squareness" + (f" ({base})" if codes else "")
    if base in STRAIGHTNESS:
        return f"the {a} straightness in {d}{said}"  # no terms: the noun alone
    if base in POSITIONING:
        noun = f"the {a} scale"
    elif base in ROTATIONAL:
        kind = rotation_kind(base)
        noun = f"the {a} carriage's {kind}" + ("" if kind == "roll" else f" about {d}")
    else:  # pragma: no cover - ERROR_NAMES is the three groups
        return f"{base}{said}"
    if not tokens:
        return noun
    linear = "1" in tokens
    curved = any(t.isdigit() and int(t) >= 2 for t in tokens)
    periods = sorted({t[3:] for t in tokens if t[:3] in ("sin", "cos")})
    aspects = (["curvature"] if curved else []) + [f"periodic error of {p} mm"
                                                   for p in periods]
    if linear:
        text = noun + (f" and its {_join(aspects)}" if aspects else "")
    else:
        text = f"the {_join(aspects)} of {noun}"
    return f"{text}{said}"

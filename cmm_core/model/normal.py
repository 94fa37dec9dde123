"""The normal equations of a fit, accumulated block by block of observations.

A fit needs ``JᵀJ`` and ``Jᵀr`` of its weighted Jacobian, never ``J`` itself. Building
the sparse ``J`` of 10^5 observations (a dense kinematic block in every row) and then
multiplying it out held several copies of it at once (~450 MB). Here each block of
``rows`` observations is evaluated on its own (a :class:`fit.Problem` over those rows,
with the same layout and state), its Jacobian rows are written densely over the columns
the block touches, and ``AᵀA`` and ``Aᵀr`` are added in: the memory is one block's rows
(a few MB) whatever the number of observations. Observations are taken in the order of
their placement, so that a block touches one placement's columns (39 of 69 for the
kinematic21 model on six placements), not every placement's; with the plate in the
model, in the order of their ball (its 75 columns outnumber the placements' 36). A
block's rows are picked out of every per-observation field; the measurement table's text
columns (position, probe, source file) are held as categories for that, made once per
problem and kept beside it: picking 8192 rows out of 10^6 strings (pyarrow's take) took a
third of the time of a fit of 10^6 observations, and a reordered copy of the whole table
would double its memory (200 MB).
"""

from __future__ import annotations

import copy
import dataclasses
import weakref
from collections.abc import Iterable
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from .blocks.kinematic import Kinematic
from .blocks.plate import Plate
from .observations import Observations
from .state import State

__all__ = ["NormalEquations", "accumulate", "rows_of", "dense_rows"]

ROWS = 8192
"""Observations per block (3 residual rows each): 8192 keeps a block's kinematic Jacobian
and dense rows near 7 MB each."""

_PER_GROUP = frozenset({"positions", "probes", "balls", "plate0_mm", "cert_u_um",
                        "horizontal", "R0", "t0_mm", "range_mm"})
"""Observation fields indexed by placement, probe or ball, not by observation."""


class NormalEquations(NamedTuple):
    """One linearisation of a weighted fit problem.

    Attributes
    ----------
    d : ndarray (n, 3)
        Residuals (µm), in the observations' order.
    cost : float
        ``r·r`` of the weighted residual (plate-prior and instrument rows included).
    N, g : ndarray (p, p), (p,)
        ``JᵀJ`` and ``Jᵀr``.
    rows : int
        Number of weighted residual rows (``3 n`` plus the prior and instrument rows).
    """

    d: np.ndarray
    cost: float
    N: np.ndarray
    g: np.ndarray
    rows: int


def rows_of(obs: Observations, idx: np.ndarray | slice) -> Observations:
    """The observations ``idx`` of ``obs`` (every per-observation field sliced; a slice
    gives views)."""
    n = len(obs.r_mm)
    change = {}
    for f in dataclasses.fields(obs):
        v = getattr(obs, f.name)
        if f.name in _PER_GROUP:
            continue
        if isinstance(v, pd.DataFrame) and len(v) == n:
            change[f.name] = v.iloc[idx]
        elif isinstance(v, np.ndarray) and v.ndim and v.shape[0] == n:
            change[f.name] = v[idx]
    return dataclasses.replace(obs, **change)


def _subproblem(prob, obs, idx):
    """``prob`` restricted to the observations ``idx`` of ``obs`` (``prob.obs`` or its
    reordering): same layout, terms and blocks."""
    sub = copy.copy(prob)
    sub.obs = rows_of(obs, idx)
    sub.n_obs = len(sub.obs.r_mm)
    sub.blocks = [type(b)(sub) for b in prob.blocks]
    sub._kinematic = next(b for b in sub.blocks if isinstance(b, Kinematic))
    return sub


def dense_rows(prob: Any, ev: Any) -> tuple[np.ndarray, np.ndarray]:
    """Jacobian rows of one evaluation ``ev`` of ``prob`` as a dense ``(3 n, k)`` array
    over the ``k`` columns they touch, and those columns (sorted)."""
    n, p = prob.n_obs, prob.layout.n
    used = np.zeros(p, bool)
    pieces = []
    for b in prob.blocks:
        for cols, M in b.jacobian(ev):
            cols = np.asarray(cols)
            # the same columns in every row (shared, or one placement's in a block cut
            # along the placements): written as a slice, not scattered
            shared = cols.ndim == 2 and (cols.strides[0] == 0 or cols.shape[0] == 1
                                         or bool((cols == cols[0]).all()))
            if shared:
                cols = cols[0]
            used[cols] = True
            pieces.append((cols, M, shared))
    u = np.flatnonzero(used)
    loc = np.full(p, -1)
    loc[u] = np.arange(u.size)
    A = np.zeros((n, 3, u.size))
    rows = np.arange(n)[:, None, None]
    comp = np.arange(3)[None, :, None]
    for cols, M, shared in pieces:
        lc = loc[cols]
        if shared and lc.size and np.all(np.diff(lc) == 1):
            A[:, :, lc[0]:lc[-1] + 1] = M
        elif shared:
            A[:, :, lc] = M
        else:
            A[rows, comp, lc[:, None, :]] = M
    return A.reshape(3 * n, u.size), u


_PER_POSITION = frozenset({"rotation", "translation", "drift"})


def _block_key(prob):
    """What blocks of observations are cut along: the placement, or the ball when the
    plate's columns (3 per ball) outnumber the placements' (a block then touches a few
    balls' columns instead of every ball's)."""
    groups = prob.layout.groups
    per_ball = sum(g == "plate" for g in groups)
    per_pos = sum(g in _PER_POSITION for g in groups)
    return prob.obs.ball if per_ball > per_pos else prob.obs.pos


_ORDERED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""Problem -> (its observations, their order along the block key, the observations with
the table's text columns as categories): made by the first accumulation, reused by the
next ones."""


def _ordered(prob: Any) -> tuple[np.ndarray, Observations]:
    """The order of ``prob``'s observations along :func:`_block_key`, and the observations
    to pick blocks from: ``prob.obs`` with its table's text columns as categories (the
    same values; a pick is then a take of small integer codes)."""
    kept = _ORDERED.get(prob)
    if kept is not None and kept[0] is prob.obs:
        return kept[1], kept[2]
    order = np.argsort(_block_key(prob), kind="stable")
    obs = prob.obs
    table = getattr(obs, "table", None)
    if isinstance(table, pd.DataFrame):
        text = [c for c in table.columns
                if not pd.api.types.is_numeric_dtype(table[c])
                and not isinstance(table[c].dtype, pd.CategoricalDtype)]
        if text:
            table = table.copy(deep=False)
            for c in text:
                table[c] = table[c].astype("category")
            obs = dataclasses.replace(obs, table=table)
    _ORDERED[prob] = (prob.obs, order, obs)
    return order, obs


def accumulate(prob: Any, state: State, sigma_um: float, rows: int = ROWS
           ) -> NormalEquations:
    """Weighted normal equations of ``prob`` at ``state`` (``fit.Problem.normal_equations``).

    Residual rows are divided by σ; with a plate prior its rows ``(c - c_cert)/u`` are
    added as in ``fit.weighted_residual``, and so are the instruments' weighted rows
    (laser runs, step gauges: ``instruments``), on the kinematic columns only.
    """
    n, p = prob.n_obs, prob.layout.n
    N, g = np.zeros((p, p)), np.zeros(p)
    d = np.empty((n, 3))
    cost = 0.0
    rp = Jp = None
    if prob.plate == "prior":
        rp, Jp = prob.block(Plate).prior_rows(state, True)
        Jp = Jp.toarray()
    parts: Iterable[tuple[Any, Any]]
    if n <= rows:
        parts = [(slice(None), prob)]
    else:
        order, light = _ordered(prob)
        parts = ((idx, _subproblem(prob, light, idx))
                 for idx in (order[lo:lo + rows] for lo in range(0, n, rows)))
    for idx, sub in parts:
        db, ev = sub._evaluate(state, True)
        A, u = dense_rows(sub, ev)
        del ev
        A *= 1.0 / sigma_um
        rb = db.ravel() / sigma_um
        d[idx] = db
        if Jp is not None and sub is prob and not np.delete(Jp, u, axis=1).any():
            # one block: the prior rows join it (one product, as a full J would be)
            A, rb = np.vstack([A, Jp[:, u]]), np.concatenate([rb, rp])
            Jp = None
        N[np.ix_(u, u)] += A.T @ A
        g[u] += A.T @ rb
        cost += float(rb @ rb)
        del A
    if Jp is not None and rp is not None:  # set together by the prior
        N += Jp.T @ Jp
        g += Jp.T @ rp
        cost += float(rp @ rp)
    ri, Ji = prob.instruments.rows(state, True)
    if ri.size:
        assert Ji is not None  # rows(..., want_jac=True) gives the Jacobian
        k = prob.instruments.cols
        N[k, k] += Ji.T @ Ji
        g[k] += Ji.T @ ri
        cost += float(ri @ ri)
    return NormalEquations(d, cost, N, g, 3 * n + (0 if rp is None else rp.size) + ri.size)


def cost_of(prob: Any, state: State, sigma_um: float) -> tuple[np.ndarray, float]:
    """Residuals (µm, (n, 3)) and ``r·r`` of the weighted residual, without a Jacobian."""
    d, _ = prob.residual(state, False)
    r = d.ravel() / sigma_um
    cost = float(r @ r)
    if prob.plate == "prior":
        rp, _ = prob.block(Plate).prior_rows(state, False)
        cost += float(rp @ rp)
    ri = prob.instruments.rows(state, False)[0]
    return d, cost + float(ri @ ri)

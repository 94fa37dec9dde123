"""The normal equations of a fit, accumulated block by block of observations.

A fit needs ``JᵀJ`` and ``Jᵀr`` of its weighted Jacobian, never ``J`` itself. Building
the sparse ``J`` of 10^5 observations (a dense kinematic block in every row) and then
multiplying it out held several copies of it at once (~450 MB). Here each block of
``rows`` observations is evaluated on its own (a :class:`problem.Problem` over those rows,
with the same layout and state) and its products are added in: the memory is one block's
rows (a few MB) whatever the number of observations.

Blocks follow the placements, so that a block touches one placement's columns (39 of 69
for the kinematic21 model on six placements), not every placement's; with the plate in
the model, the balls (its 75 columns outnumber the placements' 36). A run of
observations of one placement that follow each other in the data (a measurement file)
is cut into blocks that are views of the problem's fields; only observations in short
runs are picked out of every per-observation field, the table's text columns held as
categories for that (picking 8192 rows out of 10^6 strings took a third of a fit).

In a block, the kinematic Jacobian ``K`` (``kinematics.jacobian``: coefficient-major, one
C-ordered ``(k, m)`` matrix per component) is used where it lies, and the other pieces
(placements, effects) are written densely as ``S`` with the residual as a last column:
``KᵀK`` (BLAS dsyrk), ``Kᵀ[S d]`` and ``[S d]ᵀ[S d]`` give every entry of ``JᵀJ``,
``Jᵀd`` and ``d·d`` (thesis eq. 4.15's normal equations, weighted by 1/σ²). With the
certificate fixed, the plate columns the fit does not have are accumulated beside them
for the certificate's terms (``certificate_prior``).

Bench (``bench/fit.py``): a fit of 10^6 observations makes two accumulations and one
evaluation of its cost alone (``fitting.fit``'s last step).
"""


from __future__ import annotations

import copy
import dataclasses
import weakref
from collections.abc import Iterable
from typing import Any, NamedTuple

import numpy as np
import pandas as pd
import scipy.sparse as sp
from scipy.linalg.blas import dsyrk

from .blocks.kinematic import Kinematic
from .blocks.plate import Plate
from .hole_plate import is_hole_plate
from .observations import Observations
from .state import State

__all__ = ["NormalEquations", "accumulate", "rows_of"]

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


def _block_pieces(prob: Any, ev: Any) -> list:
    """Every block's Jacobian pieces of one evaluation ``[(cols, M (n, 3, k), shared)]``;
    ``shared``: the same columns in every row (shared, or one placement's in a block cut
    along the placements), ``cols`` then (k,), written as a slice, not scattered."""
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
            pieces.append((cols, M, shared))
    return pieces


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
"""Problem -> [its observations, their order along the block key, the table's columns to
pick rows from or None, (block size, the blocks that are views, the rest of the order) or
None]: made by the first accumulation, reused by the next ones."""


def _ordered(prob: Any) -> np.ndarray:
    """The order of ``prob``'s observations along :func:`_block_key` (kept per problem)."""
    kept = _ORDERED.get(prob)
    if kept is not None and kept[0] is prob.obs:
        return kept[1]
    order = np.argsort(_block_key(prob), kind="stable")
    _ORDERED[prob] = [prob.obs, order, None, None]
    return order


def _columns(prob: Any) -> dict:
    """The columns of ``prob``'s table to pick a block's rows from: numeric ones as numpy
    arrays (views), text as categories (the same values; a pick is then a take of small
    integer codes), others as their pandas arrays; kept beside :func:`_ordered`."""
    _ordered(prob)
    kept = _ORDERED[prob]
    if kept[2] is not None:
        return kept[2]
    columns: dict = {}
    table = getattr(prob.obs, "table", None)
    if isinstance(table, pd.DataFrame) and table.columns.is_unique:
        for c in table.columns:
            col = table[c]
            if isinstance(col.dtype, np.dtype) and col.dtype.kind in "biufcmM":
                columns[f"col:{c}"] = col.to_numpy()
            elif pd.api.types.is_numeric_dtype(col) or isinstance(
                    col.dtype, pd.CategoricalDtype):
                columns[f"col:{c}"] = col.array
            else:
                columns[f"col:{c}"] = pd.Categorical(col)
        columns[""] = table.index
    kept[2] = columns
    return columns


def _blocks(prob: Any, rows: int, key: np.ndarray | None = None
            ) -> Iterable[tuple[Any, Any]]:
    """``prob``'s blocks of at most ``rows`` observations along :func:`_block_key`, each
    with its sub-problem (same layout, terms and blocks).

    Observations that follow each other in the data with the same key (a measurement
    file is one placement) make a block of their own when at least ``rows / 2`` long: its
    fields are views of the problem's, not picked. Picking 8192 rows spread over 10^6
    (ten arrays and the table) cost 9 ms a block, half the time of a fit. Shorter runs are
    picked together into blocks of ``rows``. ``key``: another key than
    :func:`_block_key` (one number per observation)."""
    kept = _ORDERED.get(prob) if key is None else None
    if kept is not None and kept[0] is prob.obs and kept[3] is not None \
            and kept[3][0] == rows:
        views, rest = kept[3][1:]
    else:
        order = _ordered(prob) if key is None else np.argsort(key, kind="stable")
        ordered_key = (_block_key(prob) if key is None else key)[order]
        # runs: consecutive observations with one key, as [start, stop) into ``order``
        cut = np.flatnonzero((np.diff(order) != 1) | (np.diff(ordered_key) != 0)) + 1
        starts = np.r_[0, cut]
        lengths = np.diff(np.r_[starts, order.size])
        long = lengths >= max(rows // 2, 1)
        views = []  # the blocks that are views: kept, they hold no copy of the data
        for a, n in zip(starts[long].tolist(), lengths[long].tolist(), strict=True):
            for lo in range(a, a + n, rows):
                hi = min(lo + rows, a + n)
                sl = slice(int(order[lo]), int(order[hi - 1]) + 1)
                views.append((sl, _subproblem(prob, sl)))
        rest = order[~np.repeat(long, lengths)]
        if key is None:
            _ORDERED[prob][3] = (rows, views, rest)
    yield from views
    for lo in range(0, rest.size, rows):
        idx = rest[lo:lo + rows]
        yield idx, _subproblem(prob, idx, _columns(prob))


def _subproblem(prob, idx, columns=None):
    """``prob`` restricted to the observations ``idx``: same layout, terms and blocks. The
    table's rows are picked from ``columns`` (:func:`_ordered`) when given: a pandas take
    of 8192 rows of a 10^6-row table cost 6 ms, a third of the fit."""
    obs = prob.obs
    table = obs.table if isinstance(getattr(obs, "table", None), pd.DataFrame) else None
    sub = copy.copy(prob)
    if columns and table is not None:
        picked = pd.DataFrame({k[4:]: v[idx] for k, v in columns.items() if k},
                              index=columns[""][idx], copy=False)
        sub.obs = dataclasses.replace(rows_of(dataclasses.replace(obs, table=_NO_TABLE),
                                              idx), table=picked)
    else:
        sub.obs = rows_of(obs, idx)
    sub.n_obs = len(sub.obs.r_mm)
    sub.blocks = [type(b)(sub) for b in prob.blocks]
    sub._kinematic = next(b for b in sub.blocks if isinstance(b, Kinematic))
    return sub


_NO_TABLE = pd.DataFrame()
"""Stands for the table while the other fields are picked (:func:`_subproblem`)."""


def _pieces(prob: Any, ev: Any) -> tuple[list, Any]:
    """The blocks' Jacobian pieces of one evaluation ``[(cols, M (n, 3, k), shared)]``
    (``shared``: the same columns in every row, ``cols`` then (k,)), and the widest
    shared piece of at least 8 columns whose columns no other piece touches (the
    kinematic coefficients), taken out of the list; None when there is none."""
    p = prob.layout.n
    pieces = _block_pieces(prob, ev)
    wide = [i for i, (c, _, sh) in enumerate(pieces) if sh and c.size >= 8]
    if not wide:
        return pieces, None
    i = max(wide, key=lambda j: pieces[j][0].size)
    mine = np.zeros(p, bool)
    mine[pieces[i][0]] = True
    if any(mine[c].any() for j, (c, _, _) in enumerate(pieces) if j != i):
        return pieces, None
    return pieces[:i] + pieces[i + 1:], pieces[i]


def _dense(n: int, p: int, pieces: list, extra: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
    """Jacobian pieces written densely as ``(3, n, k)`` over the ``k`` columns they touch
    (component-major: each component's rows are one C-ordered matrix for BLAS), and those
    columns (sorted); ``extra`` (n, 3) is appended as a last column."""
    used = np.zeros(p, bool)
    for cols, _, _ in pieces:
        used[cols] = True
    u = np.flatnonzero(used)
    loc = np.full(p, -1)
    loc[u] = np.arange(u.size)
    A3 = np.zeros((3, n, u.size + (extra is not None)))
    A = A3.transpose(1, 0, 2)  # (n, 3, k) view
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
    if extra is not None:
        A[:, :, -1] = extra
    return A3, u


def _syrk(A: np.ndarray) -> np.ndarray:
    """``Aᵀ A`` of a (rows, k) array, upper triangle only (BLAS dsyrk on the array as it
    lies in memory, C- or Fortran-ordered, without a copy); the lower triangle is zero."""
    if A.shape[1] == 0:
        return np.zeros((0, 0))
    if A.flags.f_contiguous:
        return dsyrk(1.0, A, trans=1)
    return dsyrk(1.0, np.ascontiguousarray(A).T, trans=0)


_PLATE_CROSS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""Fixed-certificate problem -> (the state of its last accumulation, and there the
weighted ``Jᵀ J_c`` (p, 3B), ``J_cᵀ r`` (3B,) and ``J_cᵀ J_c`` (3B, 3B) of the plate
columns ``J_c`` it does not fit): the certificate's terms at the fit's solution
(``certificate_prior``) without another pass over the observations."""


def _plate_rows(sub: Any, ev: Any, width: int) -> tuple[list, np.ndarray]:
    """The plate columns' Jacobian rows of one evaluation, for a problem whose plate is
    fixed (no Plate block): the Plate block's ``-R_k s`` (``blocks.plate``) at the ball's
    three columns. Returned as their transpose per component, ``(width, m)`` sparse
    (CSC: the rows' own arrays, no conversion), and their ``J_cᵀ J_c`` (width, width),
    summed per ball (3 × 3 blocks on the diagonal)."""
    M = -ev.Rk * np.reshape(ev.plate_scale, (-1, 1, 1))
    m = M.shape[0]
    ball = sub.obs.ball
    cols = (3 * ball[:, None] + np.arange(3)).ravel()
    ptr = np.arange(m + 1) * 3
    Et = [sp.csc_matrix((np.ascontiguousarray(M[:, c, :]).ravel(), cols, ptr),
                        shape=(width, m)) for c in range(3)]
    MtM = np.einsum("nca,ncb->nab", M, M).reshape(m, 9)
    B = width // 3
    Ncc = np.zeros((B, 3, 3))
    for e in range(9):
        Ncc[:, e // 3, e % 3] = np.bincount(ball, weights=MtM[:, e], minlength=B)
    out = np.zeros((width, width))
    for a in range(3):
        for b in range(3):
            out[a::3, b::3][np.arange(B), np.arange(B)] = Ncc[:, a, b]
    return Et, out


def _plate_cross(prob: Any, state: State) -> tuple | None:
    """``(Jᵀ J_c, J_cᵀ r, J_cᵀ J_c)`` of a fixed-certificate problem's plate columns at
    ``state`` when its last accumulation was there (:data:`_PLATE_CROSS`), else None."""
    kept = _PLATE_CROSS.get(prob)
    return kept[1:] if kept is not None and kept[0] is state else None


def accumulate(prob: Any, state: State, sigma_um: float, rows: int = ROWS,
               plate_cross: bool = True) -> NormalEquations:
    """Weighted normal equations of ``prob`` at ``state`` (``problem.Problem.normal_equations``).

    Residual rows are divided by σ; with a plate prior its rows ``(c - c_cert)/u`` are
    added as in ``problem.weighted_residual``, and so are the instruments' weighted rows
    (laser runs, step gauges: ``instruments``), on the kinematic columns only.

    Each block's Jacobian is taken in two parts: the kinematic coefficients ``K`` (the
    view of ``kinematics.jacobian``'s coefficient-major array, never copied) and the rest
    ``S`` (placements, effects) written densely with the residual ``d`` as a last column,
    so that ``KᵀK`` (dsyrk per component), ``Kᵀ[S d]`` and ``[S d]ᵀ[S d]`` give every
    entry of ``JᵀJ``, ``Jᵀd`` and ``d·d`` in three products (all divided by σ² at the end).

    ``plate_cross``: with the certificate fixed, keep its plate columns beside them
    (:func:`_plate_cross`); a fit skips them where it knows more accumulations follow.
    """
    n, p = prob.n_obs, prob.layout.n
    N, g = np.zeros((p, p)), np.zeros(p)
    d = np.empty((n, 3))
    cost = 0.0
    parts: Iterable[tuple[Any, Any]]
    parts = [(slice(None), prob)] if n <= rows else _blocks(prob, rows)
    # a fixed certificate's plate columns, for its terms (``certificate_prior``): the
    # prior problem's columns that the fixed one lacks, from the same Jacobian rows
    cross = None
    if plate_cross and prob.plate == "fixed" and prob.obs.cert_u_um is not None:
        W = 3 * len(prob.obs.balls)
        cross = (np.zeros((p, W)), np.zeros(W), np.zeros((W, W)))
    for idx, sub in parts:
        db, ev = sub._evaluate(state, True)
        d[idx] = db
        pieces, kin = _pieces(sub, ev)
        plate = None if cross is None else _plate_rows(sub, ev, cross[1].size)
        del ev
        S3, u = _dense(sub.n_obs, p, pieces, extra=db)
        SS = _syrk(S3.reshape(-1, S3.shape[2]))
        N[np.ix_(u, u)] += SS[:-1, :-1]
        g[u] += SS[:-1, -1]
        cost += float(SS[-1, -1])
        Kt = None
        if kin is not None:
            kc, K, _ = kin
            Kt = K.transpose(1, 2, 0)  # (3, k, m): rows of contiguous points, no copy
            N[np.ix_(kc, kc)] += sum(_syrk(Kt[c].T) for c in range(3))
            KS = sum(Kt[c] @ S3[c] for c in range(3))
            N[np.ix_(kc, u)] += KS[:, :-1]
            g[kc] += KS[:, -1]
        if cross is not None and plate is not None:
            G, gc, Ncc = cross
            Et, EE = plate
            for c in range(3):
                ES = Et[c] @ S3[c]
                G[u] += ES[:, :-1].T
                gc += ES[:, -1]
                if Kt is not None:
                    G[kin[0]] += (Et[c] @ Kt[c].T).T
            Ncc += EE
        del S3, pieces, kin, Kt, plate
    # the blocks filled the upper triangle of JᵀJ (row < column); a column's own entry
    # may sit in either part's product: mirror the strict upper triangle only
    upper = np.triu(N, 1)
    low = np.tril(N, -1)
    N = np.diag(np.diag(N)) + upper + low + upper.T + low.T
    w = 1.0 / sigma_um**2
    N *= w
    g *= w
    cost *= w
    if cross is not None:
        _PLATE_CROSS[prob] = (state, *(a * w for a in cross))
    rp = None
    if prob.plate == "prior":
        rp, Jp = prob.block(Plate).prior_rows(state, True)
        Jp = Jp.toarray()
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


def _normal_columns(prob: Any, state: State, sigma_um: float, cols: np.ndarray,
                    rows: int = ROWS, key: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Columns ``cols`` of the weighted ``JᵀJ`` of ``prob``'s observation rows at
    ``state``, ``(p, len(cols))``, and the entries ``cols`` of ``Jᵀr``; the plate prior's
    and the instruments' rows are not included. One Jacobian pass, but only products with
    the wanted columns: the certificate's terms (``certificate_prior``) need the plate
    columns of a prior problem whose other columns the fixed fit already has.

    A piece of the Jacobian wholly in ``cols`` (the plate's: three columns per ball, one
    ball per row) enters as a sparse matrix per component, so that blocks may be cut
    along ``key`` (the placements, runs of the data: views) and still cost a few products
    per row; any other piece touching ``cols`` is written densely."""
    p = prob.layout.n
    cols = np.asarray(cols)
    where = np.full(p, -1)
    where[cols] = np.arange(cols.size)
    Nc, gc = np.zeros((p, cols.size)), np.zeros(cols.size)
    parts: Iterable[tuple[Any, Any]]
    parts = [(slice(None), prob)] if prob.n_obs <= rows else _blocks(prob, rows, key)
    for _, sub in parts:
        db, ev = sub._evaluate(state, True)
        pieces, kin = _pieces(sub, ev)
        del ev
        if kin is not None and (where[kin[0]] >= 0).any():
            pieces, kin = pieces + [kin], None
        sparse = [pc for pc in pieces if (where[pc[0]] >= 0).all()]
        dense = [pc for pc in pieces if not (where[pc[0]] >= 0).all()]
        S3, u = _dense(sub.n_obs, p, dense, extra=db)
        sel = np.flatnonzero(where[u] >= 0)
        C3 = S3[:, :, sel]
        to = where[u[sel]]
        Kt = None if kin is None else kin[1].transpose(1, 2, 0)  # (3, k, m)
        if sel.size:
            SC = sum(S3[c].T @ C3[c] for c in range(3))  # (k + 1, wanted): d last
            Nc[np.ix_(u, to)] += SC[:-1]
            gc[to] += SC[-1]
            if Kt is not None:
                Nc[np.ix_(kin[0], to)] += sum(Kt[c] @ C3[c] for c in range(3))
        for pcols, M, shared in sparse:
            m, _, k = M.shape
            pc = np.broadcast_to(pcols if shared else pcols[:, None, :], (m, 3, k))
            for c in range(3):
                # (m, wanted) sparse rows of component c: the piece's k entries per row
                Cc = sp.csr_matrix((np.ascontiguousarray(M[:, c, :]).ravel(),
                                    where[pc[:, c, :]].ravel(), np.arange(m + 1) * k),
                                   shape=(m, cols.size))
                CtS = (Cc.T @ S3[c]).T  # (dense columns + d, wanted)
                Nc[u] += CtS[:-1]
                gc += CtS[-1]
                if sel.size:  # the sparse rows against the dense wanted columns
                    Nc[np.ix_(cols, to)] += Cc.T @ C3[c]
                if Kt is not None:
                    Nc[kin[0]] += (Cc.T @ Kt[c].T).T
                Nc[cols] += (Cc.T @ Cc).toarray()
                for qcols, Q, qshared in sparse:  # other sparse wanted pieces
                    if Q is M:
                        continue
                    mq, _, kq = Q.shape
                    qc = np.broadcast_to(qcols if qshared else qcols[:, None, :],
                                         (mq, 3, kq))
                    Qc = sp.csr_matrix((np.ascontiguousarray(Q[:, c, :]).ravel(),
                                        where[qc[:, c, :]].ravel(), np.arange(mq + 1) * kq),
                                       shape=(mq, cols.size))
                    Nc[cols] += (Qc.T @ Cc).toarray()
    w = 1.0 / sigma_um**2
    return Nc * w, gc * w


def cost_of(prob: Any, state: State, sigma_um: float, rows: int = ROWS
            ) -> tuple[np.ndarray, float]:
    """Residuals (µm, (n, 3)) and ``r·r`` of the weighted residual, without a Jacobian;
    in the blocks of :func:`accumulate` (one evaluation's temporaries of 10^6
    observations at once doubled a fit's peak memory)."""
    if prob.n_obs <= rows or is_hole_plate(prob.obs):  # projected rows: whole
        d, _ = prob.residual(state, False)
    else:
        d = np.empty((prob.n_obs, 3))
        for idx, sub in _blocks(prob, rows):
            d[idx] = sub.residual(state, False)[0]
    r = d.ravel() / sigma_um
    cost = float(r @ r)
    if prob.plate == "prior":
        rp, _ = prob.block(Plate).prior_rows(state, False)
        cost += float(rp @ rp)
    ri = prob.instruments.rows(state, False)[0]
    return d, cost + float(ri @ ri)

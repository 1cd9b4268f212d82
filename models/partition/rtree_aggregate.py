"""The finest level of an rtree hierarchy from the operator's graph (issue 24, round five).

Smoothed-aggregation multigrid on rtree's box parts needed 1.09x (2D) and 1.14x (3D) pyamg's
iterations; at pyamg's own count of elements the box parts still needed up to 1.14x at a higher
operator complexity, while pyamg's aggregates under our cut coarser levels needed 1.00x (the finest
level decides, docs/hierarchy.md). So the finest level of a default hierarchy is made as algebraic
multigrid makes it, a standard aggregation of the cells' graph (the neighbourhood graph: every
TPFA coupling is strong for pyamg's default threshold 0):

1. roots: a maximal distance-2 independent set, by priority (the cells' order: the lowest index
   first, as pyamg's sequential pass takes them), found in Luby rounds (a cell becomes a root when
   it has the highest priority among the undecided cells within two steps; with a fixed total
   order that is exactly the sequential greedy set), vectorized: two neighbourhood maxima per round;
2. every root with its neighbours is an element (roots are at least three steps apart, so no cell
   has two root neighbours);
3. every other cell (within two steps of a root, by maximality) joins the neighbouring element it
   couples to most (pyamg's symmetric strength |a_ij| / sqrt(a_ii a_jj)), ties the lowest element.

Every element is connected (a star around its root, plus cells adjacent to it). No loop over cells.
"""

from __future__ import annotations

import numpy as np


def _closed_max(indptr: np.ndarray, indices: np.ndarray, v: np.ndarray) -> np.ndarray:
    """max of v over every node's closed neighbourhood (the node and its neighbours)."""
    out = v.copy()
    deg = np.diff(indptr)
    has = np.flatnonzero(deg > 0)
    if has.size:
        out[has] = np.maximum(out[has], np.maximum.reduceat(v[indices], indptr[has]))
    return out


def normalized_coupling(
    indptr: np.ndarray, indices: np.ndarray, coupling: np.ndarray, diag: np.ndarray | None = None
) -> np.ndarray:
    """(nnz,) w_ij / sqrt(d_i d_j): the symmetric strength of a coupling, d the operator's diagonal
    (default: the row sums of the couplings)."""
    n = indptr.size - 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    w = np.asarray(coupling, dtype=np.float64)
    s = np.bincount(rows, weights=w, minlength=n) if diag is None else np.asarray(diag, dtype=np.float64)
    s = np.maximum(s, 1e-300)
    return w / np.sqrt(s[rows] * s[indices])


def standard_aggregates(
    indptr: np.ndarray,
    indices: np.ndarray,
    strength: np.ndarray,
    priority: np.ndarray | None = None,
) -> np.ndarray:
    """(N,) element labels 0..k-1 of a standard aggregation of the symmetric graph (indptr, indices)
    (see the module doc). strength: (nnz,) symmetric weights, used to choose the element of a cell
    that is no root's neighbour; priority: (N,) distinct values, higher first (default: lower index
    first). Nodes without neighbours are elements of their own. Elements are numbered by their
    roots' order (increasing cell index)."""
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    n = indptr.size - 1
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    prio = -np.arange(n, dtype=np.float64) if priority is None else np.asarray(priority, dtype=np.float64)
    state = np.zeros(n, dtype=np.int8)  # 0 undecided, 1 root, 2 within two steps of a root
    while True:  # Luby rounds: about log(n), each vectorized
        und = state == 0
        if not und.any():
            break
        v = np.where(und, prio, -np.inf)
        new = und & (v == _closed_max(indptr, indices, _closed_max(indptr, indices, v)))
        state[new] = 1
        near = _closed_max(indptr, indices, _closed_max(indptr, indices, new.astype(np.float64))) > 0
        state[near & (state == 0)] = 2
    roots = np.flatnonzero(state == 1)
    k = roots.size
    lab = np.full(n, -1, dtype=np.int64)
    lab[roots] = np.arange(k)
    rows = np.repeat(np.arange(n), np.diff(indptr))
    e = (state[indices] == 1) & (lab[rows] < 0)  # a root's neighbours (one root each)
    lab[rows[e]] = lab[indices[e]]
    return _join_rest(rows, indices, lab, k, strength)


def _join_rest(rows: np.ndarray, indices: np.ndarray, lab: np.ndarray, k: int, strength) -> np.ndarray:
    """Cells not yet in an element (lab < 0) join the neighbouring element they couple to most (the
    summed strength), ties the lowest element; cells that cannot (no neighbour): own elements."""
    w = np.asarray(strength, dtype=np.float64)
    for _ in range(3):  # the rest: adjacent to an element after one round (maximality); a spare round or two
        left = lab < 0
        if not left.any():
            break
        e = left[rows] & (lab[indices] >= 0)
        if not e.any():
            break
        r, a = rows[e], lab[indices[e]]
        key, inv = np.unique(r * (k + 1) + a, return_inverse=True)
        s = np.bincount(inv, weights=w[e])
        s = np.round(s / max(float(s.max()), 1e-300), 9)  # ties within rounding: the lowest element
        kr, ka = key // (k + 1), key % (k + 1)
        o = np.lexsort((ka, -s, kr))  # per cell: the largest coupling, ties the lowest element
        f = o[np.r_[True, kr[o][1:] != kr[o][:-1]]]
        lab[kr[f]] = ka[f]
    left = np.flatnonzero(lab < 0)  # unreachable only for a graph that breaks maximality: own elements
    lab[left] = k + np.arange(left.size)
    return lab


def pyamg_aggregates(
    indptr: np.ndarray, indices: np.ndarray, strength: np.ndarray | None = None
) -> np.ndarray:
    """(N,) element labels 0..k-1 of pyamg's own compiled standard aggregation of the symmetric graph
    (indptr, indices) (amg_core.standard_aggregation: one sequential pass in the cells' order, no
    rounds, whatever the numbering). pyamg's pass 1 makes the same roots and stars as
    standard_aggregates; its pass 2 puts every other cell into the first aggregated neighbour's
    element (by column order). With strength ((nnz,) symmetric weights) those cells instead join the
    element they couple to most, as standard_aggregates does (then the two agree). Cells pyamg leaves
    out (no neighbour) are elements of their own. Elements are numbered by their roots' order."""
    from pyamg import amg_core

    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    n = indptr.size - 1
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    it = np.int32 if indices.size < np.iinfo(np.int32).max else np.int64
    tj = np.empty(n, dtype=it)
    cpts = np.empty(n, dtype=it)
    k = int(amg_core.standard_aggregation(n, indptr.astype(it), indices.astype(it), tj, cpts))
    lab = tj.astype(np.int64)
    rows = np.repeat(np.arange(n), np.diff(indptr))
    if strength is not None and k:  # keep the stars (a root and its neighbours), rejoin the rest
        roots = cpts[:k].astype(np.int64)
        is_root = np.zeros(n, dtype=bool)
        is_root[roots] = True
        star = is_root.copy()
        star[rows[is_root[indices] & (lab[rows] == lab[indices])]] = True
        lab[~star] = -1
        return _join_rest(rows, indices, lab, k, strength)
    left = np.flatnonzero(lab < 0)  # isolated cells: own elements
    lab[left] = k + np.arange(left.size)
    return lab

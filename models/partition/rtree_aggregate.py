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


def pair_quality(
    d: np.ndarray, e: np.ndarray, c: np.ndarray, rows: np.ndarray, cols: np.ndarray
) -> np.ndarray:
    """(nnz,) the two-grid quality mu({i, j}) of every pair (Napov & Notay 2012, with the operator's
    diagonal as the smoother): the pair's local matrix is [[c + e_i, -c], [-c, c + e_j]] (c = -a_ij,
    e the row-sum excess, the couplings outside the pair lumped), and mu = sup over v of
    v^T D (I - Pi) v / v^T A_G v, in closed form (d_i d_j / (d_i + d_j)) / (c + e_i e_j / (e_i + e_j)).
    d: (N,) diagonal, e: (N,) d minus the couplings' row sums (>= 0), c: (nnz,) couplings (> 0)."""
    di, dj, ei, ej = d[rows], d[cols], e[rows], e[cols]
    s = ei + ej
    harm = np.where(s > 0, ei * ej / np.maximum(s, 1e-300), 0.0)
    return (di * dj / np.maximum(di + dj, 1e-300)) / np.maximum(c + harm, 1e-300)


def _quality_matching(
    indptr: np.ndarray, indices: np.ndarray, mu: np.ndarray, bound: float, rounds: int = 12
) -> np.ndarray:
    """(N,) the partner of every node (itself when unmatched) of a locally dominant matching: each
    round every free node points at its free neighbour of least mu below `bound` (ties the lowest
    index); mutual pointers are matched. Vectorized per round."""
    n = indptr.size - 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    mate = np.arange(n)
    free = np.ones(n, dtype=bool)
    ok = (mu < bound) & (rows != indices)
    for _ in range(rounds):
        e = ok & free[rows] & free[indices]
        if not e.any():
            break
        r, cidx, w = rows[e], indices[e], mu[e]
        o = np.lexsort((cidx, w, r))
        first = o[np.r_[True, r[o][1:] != r[o][:-1]]]
        pick = np.full(n, -1)
        pick[r[first]] = cidx[first]
        has = np.flatnonzero(pick >= 0)
        mutual = has[pick[pick[has]] == has]
        mate[mutual] = pick[mutual]
        free[mutual] = False
    return mate


def quality_aggregates(
    indptr: np.ndarray,
    indices: np.ndarray,
    coupling: np.ndarray,
    diag: np.ndarray,
    passes: int = 2,
    bound: float = 8.0,
    join_singletons: bool = True,
    maxsize: int | None = None,
) -> np.ndarray:
    """(N,) element labels of quality-controlled pairwise aggregation (Notay's AGMG, Napov & Notay
    2012): `passes` matchings, each on the Galerkin operator of the previous one's aggregates (so
    elements of up to 2^passes cells), a pair accepted only when its quality mu (pair_quality) is below
    `bound`. join_singletons: cells no pass could pair join the neighbouring element they couple to
    most (fewer, larger elements, as smoothed aggregation wants); maxsize: a pair accepted only when it
    holds at most that many cells. Vectorized per matching round."""
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    n = indptr.size - 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    c = np.asarray(coupling, dtype=np.float64)
    d = np.asarray(diag, dtype=np.float64)
    e = np.maximum(d - np.bincount(rows, weights=c, minlength=n), 0.0)
    lab = np.arange(n)
    ip, ii, cc, dd, ee, k = indptr, indices, c, d, e, n
    cnt = np.ones(n)
    for _ in range(passes):
        rr = np.repeat(np.arange(k), np.diff(ip))
        mu = pair_quality(dd, ee, cc, rr, ii)
        if maxsize is not None:
            mu = np.where(cnt[rr] + cnt[ii] > maxsize, np.inf, mu)
        mate = _quality_matching(ip, ii, mu, bound)
        rep = np.minimum(np.arange(k), mate)
        new, inv = np.unique(rep, return_inverse=True)
        k2 = new.size
        if k2 == k:
            break
        lab = inv[lab]
        # the Galerkin operator of the pairs: couplings summed, the excess e additive, diagonal
        # = the couplings' row sums + e
        a, b = inv[rr], inv[ii]
        x = a != b
        key, kinv = np.unique(a[x] * k2 + b[x], return_inverse=True)
        cc = np.bincount(kinv, weights=cc[x])
        ra, ii = key // k2, key % k2
        ip = np.zeros(k2 + 1, dtype=np.int64)
        np.cumsum(np.bincount(ra, minlength=k2), out=ip[1:])
        ee = np.bincount(inv, weights=ee, minlength=k2)
        cnt = np.bincount(inv, weights=cnt, minlength=k2)
        dd = np.bincount(ra, weights=cc, minlength=k2) + ee
        k = k2
    if join_singletons:
        size = np.bincount(lab, minlength=k)
        single = size[lab] == 1
        if single.any() and not single.all():
            lab2 = np.where(single, -1, lab)
            _, lab2 = np.unique(np.where(lab2 < 0, -1, lab2), return_inverse=True)
            lab2 = lab2 - 1  # -1 stays -1 (it sorts first)
            w = c / np.sqrt(np.maximum(d[rows] * d[indices], 1e-300))
            lab = _join_rest(rows, indices, lab2, int(lab2.max()) + 1, w)
    _, lab = np.unique(lab, return_inverse=True)
    return lab


def merge_smallest(
    indptr: np.ndarray,
    indices: np.ndarray,
    strength: np.ndarray,
    lab: np.ndarray,
    k_target: int,
    rounds: int = 8,
) -> np.ndarray:
    """(N,) labels 0..k-1 with k down to k_target where the graph allows: in rounds, the smallest
    elements (in nodes; as many as the excess) join the neighbouring element they couple to most
    (the summed strength over the graph (indptr, indices), so only along its edges), ties the lowest
    element. An element another, smaller, element joins in the same round stays (no cycles); chains
    are followed to their end. Elements stay connected (each joins a neighbour). Vectorized per
    round."""
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    lab = np.unique(np.asarray(lab, dtype=np.int64), return_inverse=True)[1].astype(np.int64)
    n = lab.size
    rows = np.repeat(np.arange(n), np.diff(indptr))
    w = np.asarray(strength, dtype=np.float64)
    for _ in range(rounds):
        k = int(lab.max()) + 1 if n else 0
        excess = k - int(k_target)
        if excess <= 0:
            break
        a, b = lab[rows], lab[indices]
        e = a != b
        if not e.any():
            break
        key, inv = np.unique(a[e] * k + b[e], return_inverse=True)
        s = np.bincount(inv, weights=w[e])
        ka, kb = key // k, key % k
        o = np.lexsort((kb, -s, ka))  # per element: the strongest neighbour, ties the lowest
        f = o[np.r_[True, ka[o][1:] != ka[o][:-1]]]
        best = np.full(k, -1, dtype=np.int64)
        best[ka[f]] = kb[f]
        size = np.bincount(lab, minlength=k)
        cand = np.flatnonzero(best >= 0)
        cand = cand[np.lexsort((cand, size[cand]))][:excess]  # the smallest first, ties the lowest
        rank = np.full(k, np.iinfo(np.int64).max, dtype=np.int64)
        rank[cand] = np.arange(cand.size)
        # an element joined by a smaller selected one stays where it is (breaks mutual pairs, cycles)
        joined_by = np.full(k, np.iinfo(np.int64).max, dtype=np.int64)
        np.minimum.at(joined_by, best[cand], rank[cand])
        sel = cand[joined_by[cand] > rank[cand]]
        if sel.size == 0:
            break
        to = np.arange(k)
        to[sel] = best[sel]
        for _ in range(64):  # chains to their end (pointer jumping)
            nxt = to[to]
            if np.array_equal(nxt, to):
                break
            to = nxt
        lab = np.unique(to[lab], return_inverse=True)[1].astype(np.int64)
    return lab


def strong_couplings(
    indptr: np.ndarray, indices: np.ndarray, strength: np.ndarray, theta: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The symmetric graph (indptr, indices) with its strengths ((nnz,) symmetric), without its weak
    couplings: an edge stays where its strength is at least theta times the strongest coupling of
    either end that has the weaker strongest one (the classical strength of connection, relative to
    the row's largest, made symmetric). On a mesh whose cells are about as wide as long every
    coupling stays (theta well below their spread); a 50:1 boundary layer loses the couplings along
    the wall (thousands of times weaker than those across it)."""
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    w = np.asarray(strength, dtype=np.float64)
    n = indptr.size - 1
    top = np.zeros(n)
    has = np.diff(indptr) > 0
    if w.size:
        top[has] = np.maximum.reduceat(w, indptr[:-1][has])
    from models.mesh.dual import kept_indptr

    rows = np.repeat(np.arange(n), np.diff(indptr))
    keep = w >= theta * np.minimum(top[rows], top[indices])
    return kept_indptr(rows, keep, n), indices[keep], w[keep]

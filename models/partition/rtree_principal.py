"""Principal-axis cuts for rtree hierarchies: the twin of rtree.split_counts whose cuts run across
each part's own principal axis instead of its box's longest extent, so that the cuts follow the
shape of curved parts (tori, rings, bent channels). Numpy only: it has no compiled twin in
models/graph/_fastgraph.c (rtree_levels(axes="principal") runs this path; axes="box", the default,
keeps the compiled cuts)."""

from __future__ import annotations

import numpy as np

from models.partition.rtree_split import _count_split


def split_principal(grp: np.ndarray, need: np.ndarray, x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """split_counts' recursive weighted cuts across each part's own principal axis (the weighted
    covariance's leading eigenvector of its cells' centroids) instead of its box's longest extent:
    cuts follow the shape of curved parts (tori, rings). Numpy only (one sort of the active cells
    per halving step; no compiled twin, no tight cuts). Returns (N,) labels, the parts of group g
    numbered need[:g].sum() onwards."""
    n, dim = x.shape
    lab = np.asarray(grp, dtype=np.int64).copy()
    need = np.minimum(np.asarray(need, dtype=np.int64), np.maximum(np.bincount(lab, minlength=need.size), 1))
    root = np.arange(need.size)
    while True:
        k = need.size
        act = need > 1
        if not act.any():
            break
        cells = np.flatnonzero(act[lab])
        e, xa, wa = lab[cells], x[cells], w[cells]
        W = np.maximum(np.bincount(e, weights=wa, minlength=k), 1e-300)
        mu = (
            np.column_stack([np.bincount(e, weights=wa * xa[:, d], minlength=k) for d in range(dim)])
            / W[:, None]
        )
        dx = xa - mu[e]
        C = np.zeros((k, dim, dim))
        for i in range(dim):  # a loop over pairs of axes
            for j in range(i, dim):
                C[:, i, j] = C[:, j, i] = np.bincount(e, weights=wa * dx[:, i] * dx[:, j], minlength=k)
        ai = np.flatnonzero(act)
        v = np.zeros((k, dim))
        v[ai] = np.linalg.eigh(C[ai])[1][:, :, -1]
        t = (dx * v[e]).sum(axis=1)
        order = np.lexsort((cells, t, e))  # by part, then along its axis (ties: cell id)
        e, t, wa, cells = e[order], t[order], wa[order], cells[order]
        starts = np.flatnonzero(np.r_[True, e[1:] != e[:-1]])
        ends = np.r_[starts[1:], e.size] - 1
        parts = e[starts]
        cum = np.cumsum(wa)
        base = cum[starts] - wa[starts]
        vol = cum[ends] - base
        m = need[parts]
        m1, target = _count_split(m, base, vol, t[ends] - t[starts], dim)
        mid = cum - 0.5 * wa
        cut = np.searchsorted(mid, target) - starts
        size = ends - starts + 1
        n0 = np.clip(cut, m1, size - (m - m1))
        new = k + np.arange(parts.size)
        side1 = np.arange(e.size) >= np.repeat(starts + n0, size)
        lab[cells[side1]] = np.repeat(new, size)[side1]
        need = np.concatenate([need, m - m1])
        need[parts] = m1
        root = np.concatenate([root, root[parts]])
    # number the parts group by group (creation order inside a group)
    part_order = np.lexsort((np.arange(need.size), root))
    rank = np.empty(need.size, dtype=np.int64)
    rank[part_order] = np.arange(need.size)
    return rank[lab]

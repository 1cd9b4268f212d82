"""Connected parts (every part split into its connected pieces) and exactly k elements: a partition whose count drifted (a part split into connected fragments, a
partitioner that left parts empty) is brought back to the count asked for.

Too many parts: the smallest merge into the neighbour with which they share the longest interface.
Too few: the largest parts (by measure) are cut in two at the measure-weighted median of their
cell centroids along their widest extent, then split into connected pieces again. Rounds repeat
until the count is met. Every step is vectorized over cells; the loop runs over rounds only.
A count that cannot be met (more separate pieces of mesh than k, more elements than cells) is
refused with the reason (ParameterError).
"""

from __future__ import annotations

import numpy as np

from models.errors import ParameterError
from models.graph.csr import connected_components
from models.mesh.celldata import CellData, compact_labels

MAX_ROUNDS = 200


def connected_parts(data: CellData, labels: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, int]:
    """Split every part into its connected components. Returns (new labels over nodes, parts split).

    Linear: the edges inside parts are kept in the original CSR numbering, no sort."""
    if nodes.size == 0:
        return labels, 0
    g = data.graph
    n = g.n
    lab = np.full(n, -1, dtype=np.int64)
    lab[nodes] = labels
    # the cells outside `nodes` (label -1) form pieces of their own, dropped by the renumbering below
    _, comp = connected_components(g.indptr, g.indices, lab)
    comp = comp[nodes]
    present = np.zeros(int(comp.max()) + 1, dtype=bool)
    present[comp] = True
    remap = np.cumsum(present) - 1
    new = remap[comp]
    part_of = np.empty(int(new.max()) + 1, dtype=np.int64)
    part_of[new] = labels
    split = int(np.count_nonzero(np.bincount(part_of) > 1))
    return new, split


def pieces(data: CellData, nodes: np.ndarray) -> int:
    """The number of connected pieces the cells `nodes` form (no element can span two)."""
    g = data.graph
    lab = np.full(g.n, -1, dtype=np.int64)
    lab[nodes] = 0
    _, comp = connected_components(g.indptr, g.indices, lab)
    return int(np.unique(comp[nodes]).size)


def exact_count(
    data: CellData, labels: np.ndarray, nodes: np.ndarray, k: int, asked: str = "k"
) -> tuple[np.ndarray, int, int]:
    """Labels over `nodes` (connected parts) with exactly k parts, each connected. asked: how the
    count was asked for ("k", "2^nref"), in the refusals. Returns (labels, parts merged, parts split)."""
    if k > nodes.size:
        raise ParameterError(f"k = {k} is larger than the number of cells to agglomerate ({nodes.size})")
    labels = compact_labels(labels).astype(np.int64)
    if int(labels.max()) + 1 == k:
        return labels, 0, 0
    n_pieces = pieces(data, nodes)
    if n_pieces > k:
        raise ParameterError(
            f"{asked} = {k} cannot be met: the cells to agglomerate form {n_pieces} separate pieces and an "
            f"element cannot span two; ask for {asked} >= {n_pieces}, or allow extra elements "
            "(options.allow_extra), or, where the pieces are cut apart by coincident points (`magnet check` "
            "says so), merge them with options.weld (a distance)"
        )
    merged = split = 0
    for _ in range(MAX_ROUNDS):
        m = int(labels.max()) + 1
        if m == k:
            return labels, merged, split
        if m > k:
            labels, d = _merge_smallest(data, labels, nodes, m - k)
            merged += d
        else:
            labels, d = _split_largest(data, labels, nodes, k - m)
            labels, _ = connected_parts(data, labels, nodes)
            split += d
        labels = compact_labels(labels).astype(np.int64)
    raise ParameterError(
        f"k = {k} could not be met after {MAX_ROUNDS} rounds of merging and splitting "
        f"({int(labels.max()) + 1} elements); allow extra elements (options.allow_extra) to keep them"
    )


def _merge_smallest(
    data: CellData, labels: np.ndarray, nodes: np.ndarray, excess: int
) -> tuple[np.ndarray, int]:
    g = data.graph
    k = int(labels.max()) + 1
    lab = np.full(g.n, -1, dtype=np.int64)
    lab[nodes] = labels
    a = np.repeat(lab, np.diff(g.indptr))
    b = lab[g.indices]
    e = (a >= 0) & (b >= 0) & (a != b)
    import scipy.sparse as sp  # here only: most runs never come here (~0.2 s of start-up)

    inter = sp.csr_matrix((g.weights[e], (a[e], b[e])), shape=(k, k)).tocsr()
    inter.sum_duplicates()
    size = np.bincount(labels, weights=data.measures[nodes], minlength=k)
    has = np.diff(inter.indptr) > 0
    best = np.full(k, -1, dtype=np.int64)
    r = np.repeat(np.arange(k), np.diff(inter.indptr))
    order = np.lexsort((-inter.data, r))
    firsts = order[np.r_[True, r[order][1:] != r[order][:-1]]] if order.size else order
    best[r[firsts]] = inter.indices[firsts]
    cand = np.flatnonzero(has)
    cand = cand[np.lexsort((cand, size[cand]))][:excess]  # the smallest first
    chosen = np.zeros(k, dtype=bool)
    chosen[cand] = True
    tgt = best[cand]
    # a chain only runs towards larger (size, then lower id) parts: no circle
    ok = ~chosen[tgt] | (size[tgt] > size[cand]) | ((size[tgt] == size[cand]) & (tgt < cand))
    src, tgt = cand[ok], tgt[ok]
    mapping = np.arange(k)
    mapping[src] = tgt
    for _ in range(64):
        nxt = mapping[mapping]
        if np.array_equal(nxt, mapping):
            break
        mapping = nxt
    return mapping[labels], int(src.size)


def _split_largest(
    data: CellData, labels: np.ndarray, nodes: np.ndarray, deficit: int
) -> tuple[np.ndarray, int]:
    k = int(labels.max()) + 1
    count = np.bincount(labels, minlength=k)
    size = np.bincount(labels, weights=data.measures[nodes], minlength=k)
    cand = np.flatnonzero(count >= 2)
    cand = cand[np.argsort(-size[cand], kind="stable")][:deficit]
    if cand.size == 0:
        return labels, 0
    pick = np.full(k, -1, dtype=np.int64)
    pick[cand] = np.arange(cand.size)
    sel = np.flatnonzero(pick[labels] >= 0)  # positions (into nodes) of the cells to cut
    p = pick[labels[sel]]
    x = data.centroids[nodes[sel]]
    dim = x.shape[1]
    lo = np.full((cand.size, dim), np.inf)
    hi = np.full((cand.size, dim), -np.inf)
    np.minimum.at(lo, p, x)
    np.maximum.at(hi, p, x)
    axis = np.argmax(hi - lo, axis=1)
    coord = x[np.arange(sel.size), axis[p]]
    order = np.lexsort((coord, p))
    w = data.measures[nodes[sel]][order]
    po = p[order]
    cum = np.cumsum(w)
    start = np.r_[0, np.flatnonzero(po[1:] != po[:-1]) + 1]
    base = np.repeat(cum[start] - w[start], np.diff(np.r_[start, po.size]))
    total = np.bincount(po, weights=w, minlength=cand.size)
    mid = cum - base - 0.5 * w  # the measure before each cell's middle, within its part
    upper = mid > 0.5 * total[po]
    last = np.r_[start[1:] - 1, po.size - 1]
    upper[last] = True  # both halves non-empty: the last cell up, the first down
    upper[start] = False
    out = labels.copy()
    moved = sel[order[upper]]
    out[moved] = k + pick[labels[moved]]
    return out, int(cand.size)

"""Levels of the k-way models (metis, kmeans) made on the dual graph of the level below: that graph
(coarse_graph), and a k-way cut that no physical group crosses (kway_apart)."""

from __future__ import annotations

import numpy as np

from models.mesh.celldata import compact_labels


def coarse_graph(batch_or_data, labels: np.ndarray):
    """The dual graph of the agglomerates (a GraphBatch of one graph): shared face measures summed,
    measures summed, centroids measure-weighted, edge counts and volumes kept for cuts."""
    import scipy.sparse as sp

    from models.graph.batch import GraphBatch

    g = batch_or_data.graph if hasattr(batch_or_data, "graph") else batch_or_data
    indptr, indices, weights = g.indptr, g.indices, g.weights
    meas, cen = batch_or_data.measures, batch_or_data.centroids
    n = indptr.size - 1
    k = int(labels.max()) + 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    a, b = labels[rows], labels[indices]
    off = a != b
    W = sp.csr_matrix((weights[off], (a[off], b[off])), shape=(k, k))
    W.sum_duplicates()
    C = sp.csr_matrix((np.ones(int(off.sum())), (a[off], b[off])), shape=(k, k))
    C.sum_duplicates()
    m = np.bincount(labels, weights=meas, minlength=k)
    c = np.column_stack(
        [np.bincount(labels, weights=meas * cen[:, d], minlength=k) for d in range(cen.shape[1])]
    )
    c /= np.maximum(m, 1e-300)[:, None]
    vol = np.bincount(labels, weights=np.diff(indptr).astype(np.float64), minlength=k)
    below = getattr(batch_or_data, "cells", None)  # a coarse graph's own cells per node, else one each
    return GraphBatch(
        indptr=W.indptr.astype(np.int64),
        indices=W.indices.astype(np.int64),
        weights=W.data,
        graph_ptr=np.array([0, k], dtype=np.int64),
        centroids=c,
        measures=m,
        tags=None,
        node_ids=np.arange(k),
        edge_count=C.data,
        volume=vol,
        cells=np.bincount(labels, weights=below, minlength=k),
    )


def kway_apart(part, g, k: int, groups: np.ndarray) -> np.ndarray:
    """k parts of the graph g (a GraphBatch of one graph) by part.kway, none across a physical group
    (groups: each node's): each connected piece of a group gets its share of the k by cells (one at
    least), cut on its own and made connected. A label per node."""
    from models.graph.batch import GraphBatch
    from models.graph.csr import connected_components
    from models.hierarchy.repair import shares
    from models.mesh.dual import subgraph_by_labels
    from models.partition.rtree import make_connected

    npieces, piece = connected_components(g.indptr, g.indices, groups)
    piece = piece.astype(np.int64)
    cells = g.cell_counts()
    share = shares(np.bincount(piece, weights=cells, minlength=npieces), max(int(k), npieces))
    order, ptr, ip, ix, w = subgraph_by_labels(g.indptr, g.indices, g.weights, piece)
    split = GraphBatch(
        indptr=ip,
        indices=ix,
        weights=w,
        graph_ptr=ptr,
        centroids=g.centroids[order],
        measures=g.measures[order],
        tags=None,
        node_ids=order,
        cells=None if g.cells is None else cells[order],
    )
    lab, nxt = np.empty(g.n_nodes, dtype=np.int64), 0
    for b in range(npieces):  # a loop over the pieces of the groups (few)
        sub = split.subgraph(b)
        m = min(int(share[b]), sub.n_nodes)
        raw = (
            np.asarray(part.kway(sub, m), dtype=np.int64) if m > 1 else np.zeros(sub.n_nodes, dtype=np.int64)
        )
        raw, _ = make_connected(
            sub.indptr, sub.indices, sub.weights, compact_labels(raw), measures=sub.measures
        )
        raw = compact_labels(raw)
        lab[order[ptr[b] : ptr[b + 1]]] = nxt + raw
        nxt += int(raw.max()) + 1
    return lab

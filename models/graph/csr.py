"""Small vectorized helpers for CSR arrays and sorted runs, shared by the graph algorithms."""

from __future__ import annotations

import numpy as np

from models.native import compiled


def run_starts(a: np.ndarray) -> np.ndarray:
    """(len(a),) bool: where a run of equal values of `a` starts (np.r_ costs ~10 us a call)."""
    out = np.empty(a.size, dtype=bool)
    if a.size:
        out[0] = True
        np.not_equal(a[1:], a[:-1], out=out[1:])
    return out


def row_pointers(counts: np.ndarray) -> np.ndarray:
    """CSR row pointers (len(counts) + 1,) of rows with these entry counts."""
    ptr = np.zeros(counts.size + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    return ptr


def kept_pointers(keep: np.ndarray, indptr: np.ndarray) -> np.ndarray:
    """The row pointers of a CSR (indptr[0] = 0) after keeping only the entries `keep` (bool)."""
    return row_pointers(keep)[indptr]


def connected_components(
    indptr: np.ndarray, indices: np.ndarray, labels: np.ndarray | None = None
) -> tuple[int, np.ndarray]:
    """The connected components of a CSR graph, each entry an edge either way (scipy's
    connected_components with directed=False, or directed=True and connection="weak"); with
    `labels`, only the edges joining two nodes of the same label count. Returns (number, (n,) int32
    component of each node), components numbered in the order of their first node (scipy's
    numbering). The compiled union-find (models/graph/_fastgraph.c `pieces`) where it was built,
    else scipy's (imported here only: scipy.sparse costs ~0.2 s of a command's start-up)."""
    n = indptr.size - 1
    if n <= 0:
        return 0, np.zeros(0, dtype=np.int32)
    lab = np.zeros(n, dtype=np.int64) if labels is None else np.ascontiguousarray(labels, dtype=np.int64)
    fc = compiled("graph._fastgraph")
    if fc is not None:
        comp = np.empty(n, dtype=np.int32)
        count = fc.pieces(
            np.ascontiguousarray(indptr, dtype=np.int64),
            np.ascontiguousarray(indices, dtype=np.int64),
            lab,
            np.empty(0, dtype=np.int64),
            comp,
        )
        return int(count), comp
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components as scipy_components

    ptr, nb = indptr, indices
    if labels is not None:  # the edges inside a label only
        keep = np.repeat(lab, np.diff(indptr)) == lab[indices]
        ptr, nb = kept_pointers(keep, indptr), indices[keep]
    g = sp.csr_matrix((np.ones(nb.size, dtype=np.int8), nb, ptr), shape=(n, n))
    count, comp = scipy_components(g, directed=False)
    return int(count), comp.astype(np.int32, copy=False)


def edge_components(n: int, a: np.ndarray, b: np.ndarray) -> tuple[int, np.ndarray]:
    """connected_components of the n nodes joined by the edges (a[i], b[i]) (either way)."""
    a = np.asarray(a, dtype=np.int64)
    order = np.argsort(a, kind="stable")
    return connected_components(
        row_pointers(np.bincount(a, minlength=n)), np.asarray(b, dtype=np.int64)[order]
    )

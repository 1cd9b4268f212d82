"""Partition statistics on the fine dual graph: cut, normalized cut, balance, connectivity of parts."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from models.errors import ParameterError
from models.quality.geometry import _compiled, _unique

# --------------------------------------------------------------------------------------------------
# partition statistics on the fine dual graph


def _equals_transpose(indptr: np.ndarray, indices: np.ndarray) -> bool:
    """Whether a CSR pattern equals its transpose array for array (scipy's O(nnz) counting
    transpose has rows in increasing order, so then the rows are sorted and the pattern symmetric)."""
    if indices.size == 0:
        return True
    n = indptr.size - 1
    t = sparse.csr_matrix((np.ones(indices.size, dtype=bool), indices, indptr), shape=(n, n)).T.tocsr()
    return np.array_equal(t.indptr, indptr) and np.array_equal(t.indices, indices)


def partition_statistics(indptr: np.ndarray, indices: np.ndarray, labels: np.ndarray) -> dict:
    """Cut, normalized cut, volume imbalance, part count and connectivity of a partition.

    The CSR graph is symmetrised; each undirected edge counts once, self loops are ignored.
    normalized_cut = sum_i cut(S_i) / vol(S_i), vol = sum of degrees; volume_imbalance = largest
    part / mean part size (cells); connected: every part induces a connected subgraph.
    """
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    labels = np.asarray(labels, dtype=np.int64)
    nc = labels.size
    if indptr.size != nc + 1:
        raise ParameterError(f"indptr has {indptr.size} entries for {nc} labels")
    if indices.size and (indices.min() < 0 or indices.max() >= nc):
        raise ParameterError("graph indices out of range")
    part, parts = _compact(labels)
    sizes = np.bincount(part, minlength=parts)
    ext = _compiled()
    symmetric = _equals_transpose(indptr, indices)  # and every row sorted (maybe with duplicates)
    if ext is not None and symmetric:
        # one compiled pass (union-find for the components) where the pattern is symmetric with
        # strictly increasing rows, the usual dual graph; None if a row is not strictly increasing
        vol = np.zeros(parts)
        cut_i = np.zeros(parts)
        r = ext.partition_stats(indptr, np.ascontiguousarray(indices), np.ascontiguousarray(part), vol, cut_i)
        if r is not None:
            return _partition_summary(r[0], cut_i, vol, sizes, parts, r[1])
    u = np.repeat(np.arange(nc, dtype=np.int64), np.diff(indptr))
    if symmetric and np.all((indices[1:] > indices[:-1]) | (u[1:] != u[:-1])):  # no duplicates
        # the usual dual graph: every undirected edge twice, once per direction, no duplicates;
        # no COO -> CSR sort needed
        off = u != indices
        deg = np.bincount(u[off], minlength=nc)
        cross = off & (part[u] != part[indices])
        cut = int(cross.sum()) // 2
        cut_i = np.bincount(part[u[cross]], minlength=parts)
        keep = off & ~cross
        kept_ptr = np.zeros(nc + 1, dtype=np.int64)
        np.cumsum(np.bincount(u[keep], minlength=nc), out=kept_ptr[1:])
        # float64 data and int32 indices, as csgraph wants them (no conversion copies); the
        # pattern is symmetric, so weak components of the directed graph are the components
        idx = indices[keep].astype(np.int32) if nc < 2**31 else indices[keep]
        ptr = kept_ptr.astype(np.int32) if kept_ptr[-1] < 2**31 and nc < 2**31 else kept_ptr
        g = sparse.csr_matrix((np.ones(int(kept_ptr[-1])), idx, ptr), shape=(nc, nc))
        directed = True
    else:
        lo, hi = np.minimum(u, indices), np.maximum(u, indices)
        off = lo != hi
        # upper-triangular pattern; the COO -> CSR conversion merges duplicate (and mirrored) entries
        up = sparse.csr_matrix((np.ones(int(off.sum()), dtype=bool), (lo[off], hi[off])), shape=(nc, nc))
        a = np.repeat(np.arange(nc, dtype=np.int64), np.diff(up.indptr))
        b = up.indices.astype(np.int64)
        deg = np.bincount(a, minlength=nc) + np.bincount(b, minlength=nc)
        cut_mask = part[a] != part[b]
        cut = int(cut_mask.sum())
        cut_i = np.bincount(part[a][cut_mask], minlength=parts) + np.bincount(
            part[b][cut_mask], minlength=parts
        )
        inner = ~cut_mask
        g = sparse.csr_matrix((np.ones(int(inner.sum()), dtype=bool), (a[inner], b[inner])), shape=(nc, nc))
        directed = False
    vol = np.bincount(part, weights=deg, minlength=parts)
    ncomp = connected_components(g, directed=directed, connection="weak")[0] if nc else 0
    return _partition_summary(cut, cut_i, vol, sizes, parts, ncomp)


def _partition_summary(cut, cut_i, vol, sizes, parts, ncomp) -> dict:
    with np.errstate(divide="ignore", invalid="ignore"):
        ncut = float(np.where(vol > 0, cut_i / np.where(vol > 0, vol, 1), 0.0).sum())
    return {
        "cut": cut,
        "normalized_cut": ncut,
        "volume_imbalance": float(sizes.max() / sizes.mean()) if parts else 0.0,
        "parts": parts,
        "connected": bool(ncomp == parts),
    }


def _compact(values: np.ndarray) -> tuple[np.ndarray, int]:
    """Group index 0..k-1 of each value (in sorted value order) and k; O(n) for small integers."""
    v = np.asarray(values).ravel()
    if v.size == 0:
        return np.zeros(0, dtype=np.int64), 0
    if np.issubdtype(v.dtype, np.integer):
        lo, hi = int(v.min()), int(v.max())
        if hi - lo <= 4 * v.size + 1024:
            present = np.bincount(v - lo) > 0
            code = np.cumsum(present) - 1
            return code[v - lo], int(present.sum())
    u, inv, _ = _unique(v)
    return inv, int(u.size)

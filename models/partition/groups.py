"""Physical groups (material tags) in refinement: keep the refiners from mixing materials.

The refiners (`fm`, `rl-refiner`, models.partition.refine / models.partition.rl) minimize the normalized
cut of the batch they are given, counted with its edge counts and degree volumes. On a mesh with
physical groups that objective does not know that a cut along a material interface is free: a
heterogeneity-preserving agglomerate has faces on every interface anyway, so only a cut through a
material adds element boundary. Left alone, a refiner moves cells across an interface whenever
that shortens the cut or evens the sides, and elements then straddle two materials.

The rule (`group_weighted`): every edge between two cells of different groups counts `weight`
times (default 0.01) in the cut and in the degree volumes, so the refiner minimizes the normalized
cut of the graph in which material interfaces are almost free; cuts are drawn to interfaces, and a
move that takes a cell away from its material's side costs the full edges it then cuts inside its
material. (Not 0: the flows' integer capacities and the volumes stay positive, and among cuts on an
interface the shorter one still wins.) Graphs holding one group are unchanged.

The guard (`keep_purer`): per graph of the batch, the refined bisection is kept only if it puts no
more fine cells outside the majority group of their side than the refiner's input did (`impurity`),
else the input stays. So, with groups, refinement never makes a bisection less homogeneous.
Coarse nodes never mix groups (models.partition.coarsen), so the weights and counts are exact on every level.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from models.graph.batch import GraphBatch

DEFAULT_GROUP_WEIGHT = 0.01


def _group_codes(tags: np.ndarray) -> tuple[np.ndarray, int]:
    _, code = np.unique(np.asarray(tags), return_inverse=True)
    return code.ravel().astype(np.int64), int(code.max()) + 1 if code.size else 0


def cross_edges(batch: GraphBatch) -> np.ndarray | None:
    """(nnz,) bool: edges between two groups; None when the batch has no tags or no such edge."""
    if batch.tags is None or batch.n_nodes == 0:
        return None
    tags = np.asarray(batch.tags)
    rows = np.repeat(np.arange(batch.n_nodes), np.diff(batch.indptr))
    cross = tags[rows] != tags[batch.indices]
    return cross if cross.any() else None


def group_weighted(batch: GraphBatch, weight: float = DEFAULT_GROUP_WEIGHT) -> GraphBatch:
    """The batch with every edge between two groups counted `weight` times in the edge counts and
    in both end nodes' degree volumes (the same batch object when nothing changes)."""
    if not 0 < weight <= 1:
        raise ValueError(f"group weight must be in (0, 1], got {weight}")
    cross = cross_edges(batch)
    if cross is None or weight == 1:
        return batch
    n = batch.n_nodes
    rows = np.repeat(np.arange(n), np.diff(batch.indptr))
    ec = batch.edge_counts()
    drop = (1.0 - weight) * ec * cross
    return dataclasses.replace(
        batch, edge_count=ec - drop, volume=batch.volumes() - np.bincount(rows, weights=drop, minlength=n)
    )


def impurity(batch: GraphBatch, side: np.ndarray, counts: np.ndarray | None = None) -> np.ndarray:
    """(B,) per graph of a bisection: fine cells outside the majority group of their side (counts
    (N,): fine cells per node of a coarse batch; None = one each). Zero without tags."""
    B = batch.n_graphs
    if batch.tags is None or batch.n_nodes == 0:
        return np.zeros(B)
    code, ng = _group_codes(batch.tags)
    key = (batch.graph_index() * 2 + np.asarray(side, dtype=np.int64)) * ng + code
    c = np.ones(batch.n_nodes) if counts is None else np.asarray(counts, dtype=np.float64)
    tab = np.bincount(key, weights=c, minlength=2 * B * ng).reshape(B, 2, ng)
    return (tab.sum(axis=2) - tab.max(axis=2)).sum(axis=1)


def keep_purer(
    batch: GraphBatch, before: np.ndarray, after: np.ndarray, counts: np.ndarray | None = None
) -> np.ndarray:
    """`after` in the graphs where its impurity is not higher than `before`'s, else `before`."""
    if batch.tags is None:
        return after
    worse = impurity(batch, after, counts) > impurity(batch, before, counts) + 1e-9
    if not worse.any():
        return after
    return np.where(worse[batch.graph_index()], before, after)


def kway_impurity(tags: np.ndarray, labels: np.ndarray) -> float:
    """Fine cells outside the majority group of their part, over all parts."""
    code, ng = _group_codes(tags)
    k = int(labels.max()) + 1 if labels.size else 0
    tab = np.bincount(np.asarray(labels, dtype=np.int64) * ng + code, minlength=k * ng).reshape(k, ng)
    return float((tab.sum(axis=1) - tab.max(axis=1)).sum())

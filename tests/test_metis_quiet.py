"""METIS's own complaints (printed with C's printf) never reach the user's terminal."""

from __future__ import annotations

import numpy as np

from models.graph.batch import GraphBatch
from models.partition import get_partitioner


def _path_graph(n: int, measures: np.ndarray) -> GraphBatch:
    rows = np.repeat(np.arange(n), 2)
    cols = np.stack([np.arange(n) - 1, np.arange(n) + 1], axis=1).ravel()
    keep = (cols >= 0) & (cols < n)
    rows, cols = rows[keep], cols[keep]
    indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=n))].astype(np.int64)
    return GraphBatch(
        indptr=indptr,
        indices=cols.astype(np.int64),
        weights=np.ones(cols.size),
        graph_ptr=np.array([0, n], dtype=np.int64),
        centroids=np.column_stack([np.arange(n, dtype=float), np.zeros(n)]),
        measures=measures,
        tags=None,
        node_ids=np.arange(n),
    )


def test_metis_chatter_is_not_printed(capfd):
    """Measure weights a million times apart and nearly as many parts as nodes (a 1000:1 graded mesh
    asked for many elements): METIS prints '***Cannot bisect a graph with 0 vertices!' and '***You
    are trying to partition a graph into too many parts!' on the process's standard output; nothing
    of it reaches ours, and the partition still comes back (every node labelled)."""
    m = np.ones(40)
    m[:3] = 1e6
    labels = get_partitioner("metis").kway(_path_graph(40, m), 30)
    out, err = capfd.readouterr()
    assert "***" not in out and "***" not in err
    assert labels.shape == (40,) and labels.min() >= 0
    print("after")  # the standard output works again after the call
    assert capfd.readouterr().out == "after\n"

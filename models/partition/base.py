"""The one interface every partitioner implements (scikit-learn style: hyper-parameters in the
constructor, work in methods, inputs validated at the boundary).

A partitioner works on a `GraphBatch`: the disjoint union of one or more subgraphs of the dual
graph, nodes sorted by subgraph (the torch-geometric Batch idea in plain numpy). Recursive
bisection runs level by level and hands every subgraph of a level to `bisect_batch` at once.
"""

from __future__ import annotations

import numpy as np

from models.graph.batch import GraphBatch


class Partitioner:
    """Base class. Subclasses set `name`, `dims` and implement `bisect_batch`, and `kway` if they can."""

    name: str = "base"
    dims: tuple[int, ...] = (2, 3)
    supports_kway: bool = False
    description: str = ""

    def bisect_batch(self, batch: GraphBatch) -> np.ndarray:
        """Split every graph of the batch in two: returns (N,) int labels in {0, 1}."""
        raise NotImplementedError

    def kway(self, batch: GraphBatch, k: int) -> np.ndarray:
        """Split the (single) graph of the batch into k parts: returns (N,) labels in 0..k-1."""
        raise NotImplementedError(f"{self.name} has no direct k-way mode")

"""GraphBatch: the disjoint union of subgraphs of the dual graph that partitioners, refiners and
coarsening work on (the torch-geometric Batch idea in plain numpy)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class GraphBatch:
    """Disjoint union of B graphs with N nodes in total (local ids 0..N-1).

    indptr (N+1,), indices (nnz,): symmetric CSR adjacency, no self loops, edges only inside a graph.
    weights (nnz,) float: shared face measure of each edge (edge length in 2D, face area in 3D).
    graph_ptr (B+1,): nodes of graph b are graph_ptr[b]:graph_ptr[b+1].
    centroids (N, dim), measures (N,): cell centroid and area/volume.
    tags (N,) int or None: physical group of each cell.
    node_ids (N,): the fine-cell id of each node (for callers; partitioners may ignore it).
    edge_count (nnz,) or None: how many fine dual-graph edges each edge stands for (a coarsened
    graph, models.partition.coarsen); None = 1 each. volume (N,) or None: sum of fine degrees of each node;
    None = degrees(). The normalized cut of a coarse graph uses these, so it equals the fine one.
    cell_boxes: the cells' own bounding boxes, filled by agglomerate() for partitioners that set
    `wants_cell_boxes` (rtree), else None.
    """

    indptr: np.ndarray
    indices: np.ndarray
    weights: np.ndarray
    graph_ptr: np.ndarray
    centroids: np.ndarray
    measures: np.ndarray
    tags: np.ndarray | None
    node_ids: np.ndarray
    edge_count: np.ndarray | None = None
    volume: np.ndarray | None = None
    cell_boxes: tuple | None = None  # ((N, dim) lower, (N, dim) upper corners of each cell), if asked
    cells: np.ndarray | None = None  # (N,) cells of the mesh each node holds (None: one each)

    @property
    def n_nodes(self) -> int:
        return int(self.indptr.shape[0] - 1)

    @property
    def n_graphs(self) -> int:
        return int(self.graph_ptr.shape[0] - 1)

    @property
    def dim(self) -> int:
        return int(self.centroids.shape[1])

    def graph_index(self) -> np.ndarray:
        """(N,) which graph each node belongs to (torch-geometric's `batch` vector)."""
        return np.repeat(np.arange(self.n_graphs), np.diff(self.graph_ptr))

    def degrees(self) -> np.ndarray:
        return np.diff(self.indptr)

    def cell_counts(self) -> np.ndarray:
        """(N,) cells of the mesh each node holds, as floats (ones on the cells' own graph)."""
        return np.ones(self.n_nodes) if self.cells is None else np.asarray(self.cells, dtype=np.float64)

    def edge_counts(self) -> np.ndarray:
        """(nnz,) fine edges per edge (ones on a fine graph)."""
        return (
            np.ones(self.indices.size)
            if self.edge_count is None
            else np.asarray(self.edge_count, dtype=np.float64)
        )

    def volumes(self) -> np.ndarray:
        """(N,) degree volume of each node (its degree on a fine graph)."""
        return (
            self.degrees().astype(np.float64)
            if self.volume is None
            else np.asarray(self.volume, dtype=np.float64)
        )

    def subgraph(self, b: int) -> GraphBatch:
        """Graph b alone, as a batch of one (local ids)."""
        lo, hi = int(self.graph_ptr[b]), int(self.graph_ptr[b + 1])
        e0, e1 = int(self.indptr[lo]), int(self.indptr[hi])
        return GraphBatch(
            indptr=self.indptr[lo : hi + 1] - e0,
            indices=self.indices[e0:e1] - lo,
            weights=self.weights[e0:e1],
            graph_ptr=np.array([0, hi - lo], dtype=np.int64),
            centroids=self.centroids[lo:hi],
            measures=self.measures[lo:hi],
            tags=None if self.tags is None else self.tags[lo:hi],
            node_ids=self.node_ids[lo:hi],
            edge_count=None if self.edge_count is None else self.edge_count[e0:e1],
            volume=None if self.volume is None else self.volume[lo:hi],
            cells=None if self.cells is None else self.cells[lo:hi],
        )

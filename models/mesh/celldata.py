"""The cells as partitioners see them (CellData) and label compaction: a small module, so the paths
that need only these (the rtree hierarchy) do not import models.partition.agglomerate."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.mesh.dual import DualGraph


@dataclass
class CellData:
    """What partitioners need about the cells: graph + geometry (+ tags)."""

    graph: DualGraph
    measures: np.ndarray
    centroids: np.ndarray
    points: np.ndarray
    offsets: np.ndarray
    connectivity: np.ndarray
    tags: np.ndarray | None


def compact_labels(labels: np.ndarray) -> np.ndarray:
    """Renumber labels to 0..K-1 keeping their order (linear, no sort)."""
    if labels.size == 0:
        return labels
    present = np.zeros(int(labels.max()) + 1, dtype=bool)
    present[labels] = True
    return (np.cumsum(present) - 1)[labels]

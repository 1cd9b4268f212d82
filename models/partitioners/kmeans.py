"""k-means (scikit-learn) on cell centroids: seeded and deterministic."""

from __future__ import annotations

import numpy as np

from .base import GraphBatch, Partitioner


class KMeansPartitioner(Partitioner):
    """Lloyd's k-means on the cell centroids (k-means++ init, fixed seed)."""

    name = "kmeans"
    supports_kway = True
    description = "k-means clustering of cell centroids (scikit-learn), seeded; parts split into connected components afterwards."

    def __init__(self, seed: int = 0, n_init: int = 1):
        self.seed = int(seed)
        self.n_init = int(n_init)

    def _fit(self, x: np.ndarray, k: int) -> np.ndarray:
        from sklearn.cluster import KMeans

        km = KMeans(n_clusters=k, n_init=self.n_init, random_state=self.seed, algorithm="lloyd")
        return km.fit_predict(x).astype(np.int64)

    def kway(self, batch: GraphBatch, k: int) -> np.ndarray:
        if k == 1:
            return np.zeros(batch.n_nodes, dtype=np.int64)
        return self._fit(batch.centroids, k)

    def bisect_batch(self, batch: GraphBatch) -> np.ndarray:
        out = np.zeros(batch.n_nodes, dtype=np.int64)
        for b in range(batch.n_graphs):  # one 2-means per subgraph (a loop over parts)
            lo, hi = int(batch.graph_ptr[b]), int(batch.graph_ptr[b + 1])
            if hi - lo < 2:
                continue
            x = batch.centroids[lo:hi]
            if np.ptp(x, axis=0).max() == 0:
                out[lo + (hi - lo) // 2 : hi] = 1
                continue
            out[lo:hi] = self._fit(x, 2)
        return out

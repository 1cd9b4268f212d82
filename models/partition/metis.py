"""METIS through pymetis: k-way or recursive k-way, and batched bisection (one call per subgraph)."""

from __future__ import annotations

import contextlib
import os
import sys
import warnings

import numpy as np

from models.errors import ParameterError
from models.graph.batch import GraphBatch
from models.graph.csr import connected_components
from models.partition.base import Partitioner


def integer_weights(measures: np.ndarray, resolution: int = 1000) -> np.ndarray:
    """Cell measures as positive integer node weights (mean cell -> `resolution`)."""
    m = np.asarray(measures, dtype=np.float64)
    mean = float(m.mean()) if m.size else 1.0
    if not np.isfinite(mean) or mean <= 0:
        return np.ones(m.size, dtype=np.int64)
    return np.clip(np.rint(m * (resolution / mean)), 1, 2**30 // max(m.size, 1)).astype(np.int64)


@contextlib.contextmanager
def _quiet_c_stdout():
    """METIS prints its own complaints ("***You are trying to partition a graph into too many
    parts!", "***Cannot bisect a graph with 0 vertices!") with C's printf to the process's standard
    output, where a user would read a library's raw text: for the call, file descriptor 1 goes to the
    null device (C's buffers flushed before it is restored) and what METIS printed is dropped; the
    partition it returns is checked by the callers (empty and disconnected parts) as any other."""
    global _SINK
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError, AttributeError):  # no standard output to guard
        yield
        return
    if _SINK is None:  # the null device and C's library, opened once per process
        import ctypes

        _SINK = (os.open(os.devnull, os.O_WRONLY), ctypes.CDLL(None))
    sink, libc = _SINK
    os.dup2(sink, 1)
    try:
        yield
    finally:
        libc.fflush(None)
        os.dup2(saved, 1)
        os.close(saved)


_SINK = None  # (null device's descriptor, libc) for _quiet_c_stdout


def _connected(indptr: np.ndarray, indices: np.ndarray) -> bool:
    if indptr.size - 1 <= 1:
        return True
    return connected_components(indptr, indices)[0] == 1


class MetisPartitioner(Partitioner):
    """METIS (Karypis & Kumar) with cell measures as node weights and contiguous parts."""

    name = "metis"
    supports_kway = True
    description = "METIS multilevel graph partitioning (pymetis): k-way or recursive, cell measures as node weights, contiguous parts."

    def __init__(
        self,
        method: str = "kway",
        seed: int = 0,
        use_weights: bool = True,
        contiguous: bool = True,
        balance: str = "measure",
    ):
        if method not in ("kway", "recursive"):
            raise ParameterError(f"METIS method must be 'kway' or 'recursive', not {method!r}")
        if balance not in ("measure", "cells"):
            raise ParameterError(f"balance must be 'measure' or 'cells', got {balance!r}")
        self.method = method
        self.seed = int(seed)
        self.use_weights = use_weights
        self.contiguous = contiguous
        # "cells" (hierarchies): node weights are the cells each node holds (a coarse graph's
        # `cells`, 1 per cell of the mesh), so parts hold comparable numbers of cells, not areas
        self.balance = balance

    def _call(self, nparts: int, indptr, indices, measures, recursive: bool) -> np.ndarray:
        import pymetis

        dt = pymetis.zero_copy_dtype()
        adj = pymetis.CSRAdjacency(
            np.ascontiguousarray(indptr, dtype=dt), np.ascontiguousarray(indices, dtype=dt)
        )
        vw = integer_weights(measures).astype(dt) if self.use_weights else None
        contiguous = self.contiguous and _connected(
            indptr, indices
        )  # METIS rejects contig on a disconnected graph
        attempts = [(vw, contiguous)]
        if vw is not None:
            attempts.append((None, self.contiguous))
        if contiguous:
            attempts.append((None, False))
        last = None
        for i, (w, contig) in enumerate(attempts):
            try:
                opts = pymetis.Options(seed=self.seed, contig=int(contig))
                with warnings.catch_warnings(), _quiet_c_stdout():
                    warnings.simplefilter("ignore", DeprecationWarning)
                    res = pymetis.part_graph(nparts, adj, vweights=w, recursive=recursive, options=opts)
                if i > 0:
                    what = "unit node weights" if w is None and vw is not None else "weights"
                    what += "" if contig else ", without the contiguity option"
                    warnings.warn(
                        f"METIS rejected the first attempt ({last}); retried with {what}",
                        RuntimeWarning,
                        stacklevel=3,
                    )
                return np.asarray(res.vertex_part, dtype=np.int64)
            except Exception as exc:  # pymetis raises RuntimeError on METIS_ERROR_INPUT etc.
                last = str(exc) or type(exc).__name__
        raise ParameterError(f"METIS could not partition the graph: {last}")

    def kway(self, batch: GraphBatch, k: int) -> np.ndarray:
        n = batch.n_nodes
        if k == 1 or n == 0:
            return np.zeros(n, dtype=np.int64)
        weights = batch.cell_counts() if self.balance == "cells" else batch.measures
        return self._call(k, batch.indptr, batch.indices, weights, recursive=self.method == "recursive")

    def bisect_batch(self, batch: GraphBatch) -> np.ndarray:
        out = np.zeros(batch.n_nodes, dtype=np.int64)
        for b in range(batch.n_graphs):  # one METIS call per subgraph (a loop over parts, not cells)
            lo, hi = int(batch.graph_ptr[b]), int(batch.graph_ptr[b + 1])
            if hi - lo < 2:
                continue
            g = batch.subgraph(b)
            out[lo:hi] = self._call(2, g.indptr, g.indices, g.measures, recursive=True)
        return out

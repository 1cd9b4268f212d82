"""SAGE-Base and SAGE-Heterogeneous: bisection by a trained graph neural network.

`bisect_batch` runs ONE forward pass over every graph of the batch (the disjoint union of all the
subgraphs of a recursion level): with torch on the GPU when there is one, otherwise in numpy
(gnn_numpy: the same function, without torch's ~1 s import). The 2D or 3D network is chosen from
the batch's dimension; weights ship in models/weights/.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import numpy as np

from models.errors import ModelError
from models.graph.batch import GraphBatch
from models.partition.base import Partitioner

WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
_CACHE: dict[tuple[str, str], object] = {}
_LOCK = threading.Lock()
# present where a CUDA (NVIDIA) or ROCm (AMD) GPU can be used; without them torch sees no GPU either
_GPU_DRIVER_FILES = ("/proc/driver/nvidia/version", "/dev/kfd")


def _load(path: Path, device: str):
    """The network stored at `path`, loaded once per process and device."""
    key = (str(path), device)
    with _LOCK:
        if key not in _CACHE:
            if not path.is_file():
                raise ModelError(
                    f"weights file {path} is missing: reinstall the package or train it with "
                    f"`magnet train {path.stem} -o {path}`"
                )
            from models.nets.gnn import load_model

            try:
                _CACHE[key] = load_model(path, device=device)[0]
            except Exception as exc:  # a corrupt or foreign file
                raise ModelError(f"cannot load weights {path}: {exc}") from exc
        return _CACHE[key]


def _load_numpy(path: Path) -> dict:
    """The weights stored at `path` as numpy arrays (gnn_numpy), read once per process."""
    key = (str(path), "numpy")
    with _LOCK:
        if key not in _CACHE:
            if not path.is_file():
                raise ModelError(
                    f"weights file {path} is missing: reinstall the package or train it with "
                    f"`magnet train {path.stem} -o {path}`"
                )
            from models.nets.gnn_numpy import read_weights

            try:
                _CACHE[key] = read_weights(path)
            except Exception as exc:  # a corrupt or foreign file
                raise ModelError(f"cannot load weights {path}: {exc}") from exc
        return _CACHE[key]


def warm_up(device: str | None = None) -> list[str]:
    """Load every shipped network into this process's cache (numpy weights on the CPU, torch modules
    on a GPU), so a worker's first neural job pays no import or weight load; returns what it loaded."""
    device = device or SageBasePartitioner()._device()
    loaded = []
    for path in sorted(WEIGHTS_DIR.glob("sage-*.pt")):
        if device == "cpu":
            _load_numpy(path)
        else:
            _load(path, device)
        loaded.append(path.stem)
    return loaded


def batch_features(batch: GraphBatch, hetero: bool) -> np.ndarray:
    """Raw node features: centroid, cell measure and, for the heterogeneous model, the group p
    (0 for the smallest tag of the node's graph, 1 for the other one)."""
    cols = [batch.centroids, batch.measures[:, None]]
    if hetero:
        cols.append(group_of_batch(batch)[:, None])
    return np.column_stack(cols).astype(np.float32)


def group_of_batch(batch: GraphBatch) -> np.ndarray:
    """p per node, per graph; a graph holding more than two groups is refused (use segregated mode)."""
    if batch.tags is None or batch.n_nodes == 0:
        return np.zeros(batch.n_nodes)
    tags = np.asarray(batch.tags)
    starts = batch.graph_ptr[:-1]
    nonempty = np.diff(batch.graph_ptr) > 0
    gmin = np.zeros(batch.n_graphs, dtype=tags.dtype)
    gmax = np.zeros(batch.n_graphs, dtype=tags.dtype)
    gmin[nonempty] = np.minimum.reduceat(tags, starts[nonempty])
    gmax[nonempty] = np.maximum.reduceat(tags, starts[nonempty])
    gi = batch.graph_index()
    if np.any((tags != gmin[gi]) & (tags != gmax[gi])):
        raise ModelError("sage-hetero handles at most two physical groups per subgraph; use segregated mode")
    return (tags != gmin[gi]).astype(np.float64)


class _SagePartitioner(Partitioner):
    dims = (2, 3)
    supports_kway = False
    hetero = False
    stem = "sage-base"
    min_side = 0.05  # fraction of a graph's nodes below which a side counts as a failed bisection

    def __init__(
        self,
        device: str | None = None,
        weights_dir: str | Path | None = None,
        contiguous: bool = True,
        smooth: int = 2,
        seed: int | None = None,
        model=None,
    ):
        self.model = model  # an in-memory BisectionGNN instead of the weights files (training checks)
        self.smooth = int(smooth)
        self.device = device
        self.weights_dir = weights_dir
        self.contiguous = contiguous
        self.seed = seed  # inference is deterministic; accepted for a uniform interface

    def weights_path(self, dim: int) -> Path:
        return Path(self.weights_dir or WEIGHTS_DIR) / f"{self.stem}-{dim}d.pt"

    def _device(self) -> str:
        if self.device:
            return self.device
        if "torch" not in sys.modules and not any(Path(p).exists() for p in _GPU_DRIVER_FILES):
            return "cpu"  # no GPU driver: no need to import torch (about 1 s) to ask
        import torch

        return "cuda" if torch.cuda.is_available() else "cpu"

    def probabilities(self, batch: GraphBatch) -> np.ndarray:
        """(N, 2) soft bisection of every graph of the batch, in one forward pass."""
        if batch.dim not in self.dims:
            raise ModelError(f"{self.name} works on 2D and 3D meshes, not {batch.dim}D")
        device = self._device()
        if self.model is None and device == "cpu":  # numpy: the same function, without importing torch
            from models.nets import gnn_numpy

            weights = _load_numpy(self.weights_path(batch.dim))
            gi = batch.graph_index()
            x = gnn_numpy.normalize_features(
                batch_features(batch, self.hetero), gi, batch.n_graphs, batch.dim
            )
            return gnn_numpy.probabilities(weights, x, batch.indptr, batch.indices)
        import torch

        from models.nets.gnn import neighbour_lists, normalize_features

        model = self.model if self.model is not None else _load(self.weights_path(batch.dim), device)
        with torch.inference_mode():
            x = torch.from_numpy(batch_features(batch, self.hetero)).to(device)
            gi = torch.from_numpy(batch.graph_index()).to(device)
            x = normalize_features(x, gi, batch.n_graphs, batch.dim)
            if str(device).startswith("cuda"):  # gather/scatter messages: the well-trodden GPU path
                rows = np.repeat(np.arange(batch.n_nodes), np.diff(batch.indptr))
                adj = torch.from_numpy(np.stack([batch.indices, rows]).astype(np.int64)).to(device)
                return model(x, adj).float().cpu().numpy()
            # CPU: one mean gather + two fused multiply-adds per layer
            return model.infer(x, neighbour_lists(batch.indptr, batch.indices)).float().numpy()

    def bisect_batch(self, batch: GraphBatch) -> np.ndarray:
        """(N,) labels in {0, 1}: each node takes its most probable side. A graph the network leaves
        whole, or (SAGE-Base) with a side under 5% of its nodes, is split at the median of its side-1
        probability instead (rare: tiny or odd graphs). Then, by default, two cheap clean-ups (set
        contiguous=False, smooth=0 for the network's raw argmax):
        - `smooth` sweeps: a node with more neighbours on the other side than on its own moves
          (straightens the jagged cut a per-node classifier leaves; not across physical groups);
        - `contiguous` (the analogue of METIS's contig option): stray islands go to the side around
          them, so that both sides of every connected graph are connected."""
        if batch.n_nodes == 0:
            return np.zeros(0, dtype=np.int64)
        y = self.probabilities(batch)
        labels = (y[:, 1] > y[:, 0]).astype(np.int64)
        sizes = np.diff(batch.graph_ptr)
        ones = np.add.reduceat(labels, batch.graph_ptr[:-1][sizes > 0]) if np.any(sizes > 0) else labels[:0]
        full = np.zeros(batch.n_graphs, dtype=np.int64)
        full[sizes > 0] = ones
        small = np.minimum(full, sizes - full) < np.maximum(self.min_side * sizes, 1)
        for b in np.flatnonzero((sizes >= 2) & small):
            lo, hi = batch.graph_ptr[b], batch.graph_ptr[b + 1]
            order = np.argsort(-y[lo:hi, 1], kind="stable")
            labels[lo:hi] = 0
            labels[lo + order[: (hi - lo) // 2]] = 1
        p = group_of_batch(batch) if self.hetero else None
        if self.smooth > 0:
            labels = _unless_emptied(batch, labels, smooth_cut(batch, labels, self.smooth, p))
        if not self.contiguous:
            return labels
        return contiguous_sides(batch, labels, p)


def _unless_emptied(batch: GraphBatch, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """`after`, except in the graphs where it left a side empty: there `before`."""
    gi = batch.graph_index()
    sizes = np.diff(batch.graph_ptr)
    ones = np.bincount(gi, weights=after, minlength=batch.n_graphs)
    bad = (sizes >= 2) & ((ones == 0) | (ones == sizes))
    return np.where(bad[gi], before, after)


def smooth_cut(batch: GraphBatch, labels: np.ndarray, sweeps: int, p: np.ndarray | None = None) -> np.ndarray:
    """Move every node that has more neighbours on the other side than on its own (all at once),
    `sweeps` times; each such move shortens the cut. With groups p, only nodes whose neighbours all
    share their group may move, so group interfaces are left as they are."""
    n = batch.n_nodes
    rows = np.repeat(np.arange(n), np.diff(batch.indptr))
    cols = batch.indices
    deg = np.diff(batch.indptr)
    frozen = None
    if p is not None:
        frozen = np.bincount(rows, weights=(p[rows] != p[cols]), minlength=n) > 0
    labels = labels.copy()
    for _ in range(sweeps):
        other = np.bincount(rows, weights=(labels[rows] != labels[cols]), minlength=n)
        move = 2 * other > deg
        if frozen is not None:
            move &= ~frozen
        if not move.any():
            break
        labels[move] ^= 1
    return labels


def contiguous_sides(
    batch: GraphBatch, labels: np.ndarray, p: np.ndarray | None = None, max_rounds: int = 10
) -> np.ndarray:
    """Give every connected component of a side, except the largest one of its side within its
    connected piece of the graph, to the other side; repeat until both sides are connected.

    With the physical group p (SAGE-Heterogeneous), in graphs that hold both groups only the
    components whose majority group belongs to the other side move (side 1 is group 1's side), so
    that disconnected inclusions stay on their own side."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    n = batch.n_nodes
    rows = np.repeat(np.arange(n), np.diff(batch.indptr))
    cols = batch.indices
    ones = np.ones(len(cols), dtype=np.int8)
    _, piece = connected_components(csr_matrix((ones, cols, batch.indptr), shape=(n, n)), directed=False)
    labels = labels.copy()
    mixed_node = None
    if p is not None:
        gi = batch.graph_index()
        counts = np.maximum(np.bincount(gi, minlength=batch.n_graphs), 1)
        pm = np.bincount(gi, weights=p, minlength=batch.n_graphs) / counts
        mixed_node = ((pm > 0) & (pm < 1))[gi]
    for _ in range(max_rounds):
        same = labels[rows] == labels[cols]
        m = csr_matrix((ones[same], (rows[same], cols[same])), shape=(n, n))
        n_comp, comp = connected_components(m, directed=False)
        size = np.bincount(comp, minlength=n_comp)
        first = np.full(n_comp, n, dtype=np.int64)
        np.minimum.at(first, comp, np.arange(n))
        key = piece[first] * 2 + labels[first]  # (connected piece, side) of each component
        order = np.lexsort((first, -size, key))  # per key: largest first (ties: lowest node id)
        keep = np.zeros(n_comp, dtype=bool)
        keep[order[np.r_[True, key[order][1:] != key[order][:-1]]]] = True
        move = ~keep
        if mixed_node is not None:
            comp_p = np.bincount(comp, weights=p, minlength=n_comp) / size
            wrong = np.where(labels[first] == 1, comp_p < 0.5, comp_p > 0.5)
            move &= ~mixed_node[first] | wrong
        flip = move[comp]
        if not flip.any():
            break
        labels[flip] ^= 1
    return labels


class SageBasePartitioner(_SagePartitioner):
    name = "sage-base"
    stem = "sage-base"
    hetero = False
    description = (
        "SAGE-Base: graph neural network bisection (4 SAGEConv + 4 dense), trained to minimize "
        "the expected normalized cut; recursive bisection, batched level by level"
    )


class SageHeteroPartitioner(_SagePartitioner):
    name = "sage-hetero"
    stem = "sage-hetero"
    hetero = True
    min_side = 0.0  # a small inclusion may rightly be cut off alone
    description = (
        "SAGE-Heterogeneous: SAGE-Base with the physical group as a feature and a penalty for "
        "mixing two groups in one part; at most two groups per subgraph"
    )

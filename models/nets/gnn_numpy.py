"""CPU inference of the bisection networks in numpy: the same function as gnn.BisectionGNN.infer, from
the same weight files, without importing torch (its import alone is about 1 s of a command whose work
takes 0.2 s). Training, and inference on a GPU, stay in gnn.py.

The weight file is torch's zip format (gnn.save_model): a pickle of plain types and tensors whose
storages lie in the archive as raw little-endian arrays. `read_weights` unpickles it with a restricted
unpickler that accepts exactly those few globals, so no code from the file is run.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import numpy as np
import scipy.sparse as sp

SMALL_BATCH = 200_000  # nodes; below this the products run on one BLAS thread

_DTYPES = {
    "FloatStorage": np.float32,
    "DoubleStorage": np.float64,
    "HalfStorage": np.float16,
    "LongStorage": np.int64,
    "IntStorage": np.int32,
    "BoolStorage": np.bool_,
}


class _StorageType:
    def __init__(self, name: str):
        self.dtype = np.dtype(_DTYPES[name]).newbyteorder("<")


def _rebuild_tensor(storage, offset, size, stride, *_rest):
    """A tensor of the pickle as a numpy array (a copy, C-contiguous)."""
    item = storage.itemsize
    return np.lib.stride_tricks.as_strided(
        storage[offset:], shape=tuple(size), strides=tuple(s * item for s in stride)
    ).copy()


class _WeightsUnpickler(pickle.Unpickler):
    def __init__(self, fh, archive: zipfile.ZipFile, prefix: str, byteorder: str):
        super().__init__(fh)
        self.archive, self.prefix, self.byteorder = archive, prefix, byteorder

    def find_class(self, module: str, name: str):
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if (module, name) == ("collections", "OrderedDict"):
            return dict
        if module == "torch" and name in _DTYPES:
            return _StorageType(name)
        raise pickle.UnpicklingError(f"unexpected object {module}.{name} in a weights file")

    def persistent_load(self, pid):
        kind, storage_type, key, _location, numel = pid
        if kind != "storage" or not isinstance(storage_type, _StorageType):
            raise pickle.UnpicklingError(f"unexpected storage {pid!r} in a weights file")
        dtype = storage_type.dtype if self.byteorder == "little" else storage_type.dtype.newbyteorder(">")
        raw = self.archive.read(f"{self.prefix}data/{key}")
        return np.frombuffer(raw, dtype=dtype, count=int(numel))


def read_weights(path: str | Path) -> dict:
    """The dict gnn.save_model wrote ({"config", "state_dict", "meta"}), tensors as numpy arrays."""
    with zipfile.ZipFile(path) as archive:
        names = archive.namelist()
        pkl = next(n for n in names if n.endswith("data.pkl"))
        prefix = pkl[: -len("data.pkl")]
        byteorder = archive.read(prefix + "byteorder").decode() if prefix + "byteorder" in names else "little"
        with archive.open(pkl) as fh:
            return _WeightsUnpickler(fh, archive, prefix, byteorder).load()


def _per_graph_sum(values: np.ndarray, gi: np.ndarray, n_graphs: int) -> np.ndarray:
    """Sum of the rows of `values` (N, ...) per graph -> (B, ...)."""
    flat = values.reshape(len(values), -1)
    out = np.stack(
        [np.bincount(gi, weights=flat[:, j], minlength=n_graphs) for j in range(flat.shape[1])], axis=1
    )
    return out.reshape((n_graphs,) + values.shape[1:])


def normalize_features(
    x: np.ndarray, gi: np.ndarray, n_graphs: int, dim: int, eps: float = 1e-12
) -> np.ndarray:
    """gnn.normalize_features in numpy (float64 inside, float32 out): per graph, coordinates on their
    principal axes (widest first, sign by skewness) at unit variance, the measure at zero mean and
    unit relative spread, the group p as 2p - 1 in graphs holding both groups."""
    x = np.asarray(x, dtype=np.float64)
    coords, measure, rest = x[:, :dim], x[:, dim : dim + 1], x[:, dim + 1 :]
    counts = np.maximum(np.bincount(gi, minlength=n_graphs).astype(np.float64), 1.0)[:, None]

    centred = coords - (_per_graph_sum(coords, gi, n_graphs) / counts)[gi]
    outer = centred[:, :, None] * centred[:, None, :]
    cov = _per_graph_sum(outer, gi, n_graphs) / counts[:, :, None]
    eigval, eigvec = np.linalg.eigh(cov)
    eigvec = eigvec[..., ::-1]
    proj = np.einsum("nd,nde->ne", centred, eigvec[gi])
    skew = np.sign(_per_graph_sum(proj**3, gi, n_graphs))
    skew[skew == 0] = 1.0
    proj = proj * skew[gi]
    proj = proj / np.sqrt(np.maximum(eigval[:, ::-1], 0.0) + eps)[gi]

    m_mean = _per_graph_sum(measure, gi, n_graphs) / counts
    m_centred = measure - m_mean[gi]
    m_std = np.sqrt(_per_graph_sum(m_centred**2, gi, n_graphs) / counts)
    m_scale = np.where(m_std > 1e-6 * np.abs(m_mean), m_std, 1.0)
    m_norm = m_centred / m_scale[gi]
    if rest.shape[1]:
        p = rest[:, :1]
        p_mean = _per_graph_sum(p, gi, n_graphs) / counts
        mixed = ((p_mean > 0) & (p_mean < 1)).astype(np.float64)
        rest = np.concatenate([(2 * p - 1) * mixed[gi], rest[:, 1:]], axis=1)
    return np.concatenate([proj, m_norm, rest], axis=1).astype(np.float32)


def probabilities(weights: dict, x: np.ndarray, indptr: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(N, 2) softmax output of the network `weights` (read_weights) on normalized features x (N, F):
    per SAGE layer tanh(W_l mean(neighbours' x) + b_l + W_r x), then the dense layers."""
    n = len(x)
    if n >= SMALL_BATCH:
        return _probabilities(weights, x, indptr, indices)
    from threadpoolctl import threadpool_limits

    # one BLAS thread: on a small batch, waking the BLAS worker threads costs more than the product
    # (4x slower on two busy cores)
    with threadpool_limits(limits=1, user_api="blas"):
        return _probabilities(weights, x, indptr, indices)


def _probabilities(weights: dict, x: np.ndarray, indptr: np.ndarray, indices: np.ndarray) -> np.ndarray:
    config, state = weights["config"], weights["state_dict"]
    n = len(x)
    deg = np.diff(indptr)
    mean = sp.csr_matrix(
        (np.repeat(1.0 / np.maximum(deg, 1), deg).astype(np.float32), indices, indptr), shape=(n, n)
    )
    h = np.ascontiguousarray(x, dtype=np.float32)
    for i in range(config["n_sage"]):
        pre = f"convs.{i}."
        out = (mean @ h) @ state[pre + "lin_l.weight"].T
        out += h @ state[pre + "lin_r.weight"].T
        out += state[pre + "lin_l.bias"]
        h = np.tanh(out, out=out)
    for i in range(config["n_dense"]):
        h = h @ state[f"dense.{i}.weight"].T + state[f"dense.{i}.bias"]
        if i < config["n_dense"] - 1:
            np.tanh(h, out=h)
    h -= h.max(axis=1, keepdims=True)
    np.exp(h, out=h)
    return h / h.sum(axis=1, keepdims=True)

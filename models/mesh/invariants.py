"""The array invariants a reader's answer must hold before anything indexes with it, as
predicates: models.mesh.answer checks a Mesh sent back from the reading child with them,
models.mesh.deferred the builders' arguments sent back instead (each words a failure its own way)."""

from __future__ import annotations

import numpy as np


def ids(a, ndim: int = 1) -> bool:
    """An integer array of `ndim` dimensions."""
    return isinstance(a, np.ndarray) and a.dtype.kind in "iu" and a.ndim == ndim


def in_range(a: np.ndarray, n: int) -> bool:
    """Every id in [0, n): one pass (signed ids seen as unsigned: a negative one is past n)."""
    if a.size == 0:
        return True
    if a.dtype.kind == "i":
        a = a.view(np.dtype(f"u{a.dtype.itemsize}"))
    return int(a.max()) < n


def csr_sizes(offsets, values) -> np.ndarray | None:
    """The row sizes of a CSR whose integer offsets run from 0, never decreasing, to len(values)
    (integers too); None when it is not one."""
    if not (ids(offsets) and ids(values) and offsets.size >= 1):
        return None
    if int(offsets[0]) != 0 or int(offsets[-1]) != values.size:
        return None
    sizes = np.diff(offsets)
    return sizes if sizes.size == 0 or int(sizes.min()) >= 0 else None

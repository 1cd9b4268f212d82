"""Small vectorized helpers for CSR arrays and sorted runs, shared by the graph algorithms."""

from __future__ import annotations

import numpy as np


def run_starts(a: np.ndarray) -> np.ndarray:
    """(len(a),) bool: where a run of equal values of `a` starts (np.r_ costs ~10 us a call)."""
    out = np.empty(a.size, dtype=bool)
    if a.size:
        out[0] = True
        np.not_equal(a[1:], a[:-1], out=out[1:])
    return out


def row_pointers(counts: np.ndarray) -> np.ndarray:
    """CSR row pointers (len(counts) + 1,) of rows with these entry counts."""
    ptr = np.zeros(counts.size + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    return ptr


def kept_pointers(keep: np.ndarray, indptr: np.ndarray) -> np.ndarray:
    """The row pointers of a CSR (indptr[0] = 0) after keeping only the entries `keep` (bool)."""
    return row_pointers(keep)[indptr]

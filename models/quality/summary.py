"""Five-number summaries of per-element values (a small module: the hierarchy writer uses it
without importing models.metrics, whose source is large and costs a compile where no bytecode is
cached)."""

from __future__ import annotations

import numpy as np


def summarize(values) -> dict:
    """Five-number summary plus mean of the finite values: min, q1, median, q3, max, mean."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    keys = ("min", "q1", "median", "q3", "max", "mean")
    if v.size == 0:
        return dict.fromkeys(keys)
    q = np.percentile(v, [0, 25, 50, 75, 100])
    return dict(zip(keys, [float(x) for x in q] + [float(v.mean())], strict=True))

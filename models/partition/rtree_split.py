"""How many of a part's pieces go to each side of a cut (shared by rtree's box cuts and
rtree_principal's principal-axis cuts)."""

from __future__ import annotations

import numpy as np


def _count_split(m, base, vol, length, dim):
    """(m1, target): of each active part's m parts, m1 go to side 0, which ends at measure `target`
    (base: the measure before the part in the step's running sum; vol: its own)."""
    side_len = (np.maximum(vol, 1e-300) / np.maximum(m, 1)) ** (1.0 / dim)
    cols = np.maximum(2, np.rint(length / np.maximum(side_len, 1e-300))).astype(np.int64)
    m1 = np.clip(np.rint(m * (cols // 2) / cols).astype(np.int64), 1, np.maximum(m - 1, 1))
    target = base + m1 / np.maximum(m, 1) * vol
    return m1, target

"""Box fitting of nested levels (issue 24, R3MG's box measures): a post-pass that moves units on the
boundary of the elements to a neighbouring element where that raises the elements' box ratios
|K| / |B_K| (B_K the axis-aligned bounding box), keeping every element connected, its size within
+-slack of what it was, the element counts exact and the levels nested.

From the finest level to the coarsest, the units moved at a level are the elements of the level
below it (the cells at the finest level), so every finer element moves whole and the levels stay
nested; the coarser levels follow (an element of a coarser level is the union of the same finer
elements as before, whichever element of this level they now belong to), and a move that would
split an element of this or of any coarser level is undone.

Two kinds of sweeps, vectorized over the units (no loop over cells or elements):
  fit     a unit goes to the neighbouring element whose ideal box (its bounding box shrunk about its
          centre to the element's measure, same aspect) covers more of the unit's box than its own
          element's ideal box does (by `margin` of the unit's box);
  ratio   a unit on a cut goes to a neighbour when that raises the sum of the two elements' box
          ratios (exactly: at most one move touches each element in a sweep, the best).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components


def _group_box(labels, k, lo, hi):
    """(k, dim) min of lo and max of hi over each label's units."""
    dim = lo.shape[1]
    Elo = np.full((k, dim), np.inf)
    Ehi = np.full((k, dim), -np.inf)
    for d in range(dim):
        np.minimum.at(Elo[:, d], labels, lo[:, d])
        np.maximum.at(Ehi[:, d], labels, hi[:, d])
    return Elo, Ehi


def _without_self(labels, vals, k, take_min):
    """Per unit: the min (take_min) or max of vals over its label's other units (+-inf if none)."""
    n = labels.size
    key = vals if take_min else -vals
    order = np.lexsort((key, labels))
    ls = labels[order]
    starts = np.flatnonzero(np.r_[True, ls[1:] != ls[:-1]])
    first = np.full(k, np.inf)
    second = np.full(k, np.inf)
    g = ls[starts]
    first[g] = key[order[starts]]
    has2 = np.r_[starts[1:], n] - starts > 1
    second[g[has2]] = key[order[starts[has2] + 1]]
    is_first = np.zeros(n, dtype=bool)
    is_first[order[starts]] = True
    out = np.where(is_first, second[labels], first[labels])
    return out if take_min else -out


def _pieces(src, dst, n, labels, k):
    """(k,) number of connected pieces of each label on the unit graph (src, dst)."""
    same = labels[src] == labels[dst]
    A = sp.csr_matrix((np.ones(int(same.sum())), (src[same], dst[same])), shape=(n, n))
    nc, comp = connected_components(A, directed=False)
    return np.bincount(np.unique(labels * np.int64(nc + 1) + comp) // (nc + 1), minlength=k)


def _box_volume(lo, hi):
    return np.prod(np.maximum(hi - lo, 0.0), axis=1)


def boxfit_units(
    labels: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    measure: np.ndarray,
    weight: np.ndarray,
    indptr: np.ndarray,
    indices: np.ndarray,
    above: list[np.ndarray] | None = None,
    passes: tuple[str, ...] = ("fit", "ratio"),
    sweeps: int = 30,
    slack: float = 0.15,
    margin: float = 0.05,
) -> np.ndarray:
    """New labels of the units (one level): labels (n,) element of each unit; lo, hi (n, dim) the
    units' bounding boxes; measure (n,) their areas / volumes; weight (n,) their sizes for the
    +-slack balance (cells); indptr, indices the CSR graph of the units; above: for each coarser
    level an (k,) map element of this level -> element of that level (connectivity is kept there too).
    """
    labels = np.asarray(labels, dtype=np.int64).copy()
    n = labels.size
    k = int(labels.max()) + 1
    dim = lo.shape[1]
    above = above or []
    w = np.asarray(weight, dtype=np.float64)
    size0 = np.bincount(labels, weights=w, minlength=k)
    smin, smax = size0 * (1.0 - slack), size0 * (1.0 + slack)
    src = np.repeat(np.arange(n), np.diff(indptr))
    dst = np.asarray(indices, dtype=np.int64)
    keep = src != dst
    src, dst = src[keep], dst[keep]
    uvol = np.maximum(_box_volume(lo, hi), 1e-300)
    up_k = [int(a.max()) + 1 for a in above]

    def split_sources(old, mu):
        """Moves (units mu, from old) to undo: those whose source element, or an ancestor of it at a
        coarser level, is no longer connected."""
        bad = _pieces(src, dst, n, labels, k)[old] > 1
        for a, ka in zip(above, up_k, strict=True):
            pa = _pieces(src, dst, n, a[labels], ka)
            bad |= (pa[a[old]] > 1) | (pa[a[labels[mu]]] > 1)
        return bad

    for kind in passes:
        for _ in range(sweeps):
            Elo, Ehi = _group_box(labels, k, lo, hi)
            area = np.bincount(labels, weights=measure, minlength=k)
            cut = labels[src] != labels[dst]
            u, F = src[cut], labels[dst[cut]]
            E = labels[u]
            if kind == "fit":
                s = (area / np.maximum(_box_volume(Elo, Ehi), 1e-300)) ** (1.0 / dim)
                c = 0.5 * (Elo + Ehi)
                Rlo = c - 0.5 * s[:, None] * (Ehi - Elo)
                Rhi = c + 0.5 * s[:, None] * (Ehi - Elo)

                def cover(uu, e, Rlo=Rlo, Rhi=Rhi):
                    inter = np.minimum(hi[uu], Rhi[e]) - np.maximum(lo[uu], Rlo[e])
                    return np.prod(np.clip(inter, 0.0, None), axis=1) / uvol[uu]

                gain = cover(u, F) - cover(u, E)
                ok = gain > margin
            else:
                nlo = np.stack([_without_self(labels, lo[:, d], k, True) for d in range(dim)], 1)
                nhi = np.stack([_without_self(labels, hi[:, d], k, False) for d in range(dim)], 1)
                vE = np.maximum(_box_volume(Elo, Ehi), 1e-300)
                vE_wo = np.where(np.isfinite(nlo).all(1), _box_volume(nlo, nhi), 0.0)
                vF_new = _box_volume(np.minimum(Elo[F], lo[u]), np.maximum(Ehi[F], hi[u]))
                rE_new = (area[E] - measure[u]) / np.maximum(vE_wo[u], 1e-300)
                rF_new = (area[F] + measure[u]) / np.maximum(vF_new, 1e-300)
                gain = rE_new + rF_new - area[E] / vE[E] - area[F] / vE[F]
                ok = gain > 1e-9
            size = np.bincount(labels, weights=w, minlength=k)
            ok &= (size[E] - w[u] >= smin[E]) & (size[F] + w[u] <= smax[F])
            u, F, E, gain = u[ok], F[ok], E[ok], gain[ok]
            if u.size == 0:
                break
            # the best move touching each element (its source and target), so that the gains add up
            key = gain + 1e-12 * np.arange(u.size) / u.size
            best = np.full(k, -np.inf)
            np.maximum.at(best, E, key)
            np.maximum.at(best, F, key)
            acc = (best[E] == key) & (best[F] == key)
            mu, mF, mE = u[acc], F[acc], E[acc]
            labels[mu] = mF
            while True:  # undo the moves that split an element (of this level or a coarser one)
                live = labels[mu] == mF
                if not live.any():
                    break
                bad = split_sources(mE, mu) & live
                if not bad.any():
                    break
                labels[mu[bad]] = mE[bad]
            if not (labels[mu] == mF).any():
                break
    return labels


def boxfit_levels(
    levels: list[np.ndarray],
    lo: np.ndarray,
    hi: np.ndarray,
    measures: np.ndarray,
    indptr: np.ndarray,
    indices: np.ndarray,
    **options,
) -> list[np.ndarray]:
    """Box-fitted nested levels (coarsest first, (cells,) labels each): from the finest level to the
    coarsest, boxfit_units with the finer level's elements as the units (the cells at the
    finest); the coarser levels follow the moved units. lo, hi: (cells, dim) the cells' bounding boxes;
    indptr, indices: the cells' dual graph; options: boxfit_units' (passes, sweeps, slack, margin)."""
    out = [np.asarray(lv, dtype=np.int64).copy() for lv in levels]
    n = out[-1].size
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    measures = np.asarray(measures, dtype=np.float64)
    src = np.repeat(np.arange(n), np.diff(indptr))
    dst = np.asarray(indices, dtype=np.int64)
    for L in range(len(out) - 1, -1, -1):
        if L == len(out) - 1:
            unit = np.arange(n)
        else:
            unit = out[L + 1]
        m = int(unit.max()) + 1
        # a representative cell per unit: the units' element at this level and every coarser one
        rep = np.zeros(m, dtype=np.int64)
        rep[unit] = np.arange(n)
        ulab = out[L][rep]
        k = int(out[L].max()) + 1
        erep = np.zeros(k, dtype=np.int64)
        erep[out[L]] = np.arange(n)
        above = [out[j][erep] for j in range(L)]
        ulo, uhi = _group_box(unit, m, lo, hi)
        umeas = np.bincount(unit, weights=measures, minlength=m)
        uw = np.bincount(unit, minlength=m).astype(np.float64)
        a, b = unit[src], unit[dst]
        e = a != b
        G = sp.csr_matrix((np.ones(int(e.sum())), (a[e], b[e])), shape=(m, m))
        G.sum_duplicates()
        new = boxfit_units(ulab, ulo, uhi, umeas, uw, G.indptr, G.indices, above=above, **options)
        out[L] = new[unit]
        for j in range(L):
            out[j] = above[j][out[L]]
    return out

"""k-means on cell centroids: seeded and deterministic, in numpy, sized for millions of cells.

k-way: k-means++ (greedy, as scikit-learn does it) and Lloyd's iterations on a random sample of the
centroids (a few hundred per cluster, several starts, the best kept), then Lloyd's iterations on all
of them from those centres until they settle. On 2M triangles at k=128 this lands within a fraction
of a percent of scikit-learn's KMeans inertia (bench/bench_kmeans.py) at a small part of its time:
the sample does the many cheap iterations, the full set the few that remain.

Bisection (`bisect_batch`): one 2-means on every graph of the batch at once, vectorized over the
graphs (k-means++ start, then Lloyd's iterations until no node moves).
"""

from __future__ import annotations

import numpy as np

from models.errors import ParameterError
from models.graph.batch import GraphBatch
from models.partition.base import Partitioner

_CHUNK = 16384  # points per block of the brute-force nearest-centre search


def _brute_nearest(x: np.ndarray, centers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(label, squared distance) of each point's nearest centre, brute force in blocks (|x|^2 - 2 x.c
    + |c|^2, one matrix product per block); a k-d tree for many centres."""
    n, k = len(x), len(centers)
    if k > 256:
        from scipy.spatial import cKDTree

        d, lab = cKDTree(centers).query(x)
        return lab.astype(np.int64), (d**2).astype(x.dtype)
    ct = np.ascontiguousarray(centers.T)
    cc = np.einsum("ij,ij->i", centers, centers)
    labels = np.empty(n, dtype=np.int64)
    dist = np.empty(n, dtype=x.dtype)
    block = np.empty((min(n, _CHUNK), k), dtype=x.dtype)
    for s in range(0, n, _CHUNK):
        xs = x[s : s + _CHUNK]
        d = block[: len(xs)]
        np.matmul(xs, ct, out=d)
        d *= -2.0
        d += cc
        lab = d.argmin(axis=1)
        labels[s : s + len(xs)] = lab
        dist[s : s + len(xs)] = np.take_along_axis(d, lab[:, None], axis=1)[:, 0] + np.einsum(
            "ij,ij->i", xs, xs
        )
    return labels, np.maximum(dist, 0.0)


def nearest_center(
    x: np.ndarray, centers: np.ndarray, guess: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(label, squared distance) of each point's nearest centre, exactly.

    With a guess (a label per point, e.g. the previous iteration's), only the guess and its L nearest
    centres are tried; the answer is certified by the triangle inequality: if |x - a| <= s(a) / 2,
    with s(a) the distance from a to its (L+1)-th nearest centre, every centre beyond those L is at
    least s(a) - |x - a| >= |x - a| away. The points that fail the test go through the brute force."""
    k = len(centers)
    n_near = 8 if x.shape[1] == 2 else 20
    if guess is None or k <= 2 * n_near:
        return _brute_nearest(x, centers)
    if k <= 256:
        cdist = np.sum((centers[:, None, :] - centers[None, :, :]) ** 2, axis=2)
        order = np.argsort(cdist, axis=1)[:, : n_near + 2]  # itself first, then its nearest
        reach = cdist[np.arange(k), order[:, n_near + 1]] / 4.0  # (s(a) / 2)^2
    else:  # a k-d tree: O(k log k), not a k x k table
        from scipy.spatial import cKDTree

        dd, order = cKDTree(centers).query(centers, k=n_near + 2)
        reach = dd[:, n_near + 1] ** 2 / 4.0
    cols = [np.ascontiguousarray(x[:, d]) for d in range(x.shape[1])]
    ccols = [np.ascontiguousarray(centers[:, d]) for d in range(x.shape[1])]

    def dist2(c: np.ndarray) -> np.ndarray:
        out = (cols[0] - ccols[0][c]) ** 2
        for xd, cd in zip(cols[1:], ccols[1:], strict=True):
            out += (xd - cd[c]) ** 2
        return out

    best = dist2(guess)
    unsure = np.flatnonzero(best > reach[guess])
    labels = guess.copy()
    for j in range(1, n_near + 1):
        c = order[:, j][guess]
        d = dist2(c)
        better = d < best
        best[better] = d[better]
        labels[better] = c[better]
    if unsure.size:
        labels[unsure], best[unsure] = _brute_nearest(x[unsure], centers)
    return labels, best


def _centers_of(
    x: np.ndarray, labels: np.ndarray, old: np.ndarray, w: np.ndarray | None = None
) -> np.ndarray:
    """(Weighted) mean of each cluster (an empty cluster keeps its old centre)."""
    k = len(old)
    counts = np.bincount(labels, weights=w, minlength=k)
    wx = x if w is None else x * w[:, None]
    sums = np.stack([np.bincount(labels, weights=wx[:, d], minlength=k) for d in range(x.shape[1])], axis=1)
    out = old.copy()
    ok = counts > 0
    out[ok] = (sums[ok] / counts[ok, None]).astype(old.dtype)
    return out


def kmeans_plus_plus(
    x: np.ndarray, k: int, rng: np.random.Generator, w: np.ndarray | None = None, greedy: bool = True
) -> np.ndarray:
    """Greedy k-means++: each new centre is the best of 2 + log(k) candidates (1 when not greedy)
    drawn with probability proportional to the (weighted) squared distance to the nearest centre."""
    n = len(x)
    w = np.ones(n) if w is None else w
    trials = 2 + int(np.log(k)) if greedy else 1
    centers = np.empty((k, x.shape[1]), dtype=x.dtype)
    first = min(int(np.searchsorted(np.cumsum(w), rng.random() * w.sum(), side="right")), n - 1)
    centers[0] = x[first]
    cols = [np.ascontiguousarray(x[:, j]) for j in range(x.shape[1])]

    def dist2(p: np.ndarray) -> np.ndarray:  # (len(p), n) squared distances of the points to x[p]
        out = (cols[0][None, :] - cols[0][p][:, None]) ** 2
        for xd in cols[1:]:
            out += (xd[None, :] - xd[p][:, None]) ** 2
        return out

    closest = dist2(np.array([first]))[0]
    for c in range(1, k):
        cum = np.cumsum(closest * w, dtype=np.float64)
        if cum[-1] <= 0:  # fewer distinct points than clusters
            centers[c:] = x[rng.integers(n, size=k - c)]
            break
        cand = np.minimum(np.searchsorted(cum, rng.random(trials) * cum[-1], side="right"), n - 1)
        d = np.minimum(dist2(cand), closest)
        best = int(np.argmin(d @ w))
        centers[c] = x[cand[best]]
        closest = d[best]
    return centers


def bisection_seeds(
    x: np.ndarray, k: int, w: np.ndarray | None = None, density: np.ndarray | None = None
) -> np.ndarray:
    """(k, dim) starting centres for many clusters: the (weighted) means of k parts of a recursive
    bisection of the points (each part of k_p clusters cut across its longest extent at the weighted
    quantile floor(k_p / 2) / k_p, every part keeping at least one point per cluster). All parts of a
    level at once: O(m log m log k), where k-means++ takes k sequential O(m) steps. Needs m >= k.
    density: the points' density when known (the weights of equal bins), else from 8-NN distances."""
    from scipy.spatial import cKDTree

    m, dim = x.shape
    w = np.ones(m) if w is None else np.asarray(w, dtype=np.float64)
    # optimal quantisers put centres with a density proportional to p^(d / (d + 2)) for a point
    # density p: the parts are balanced on u = w p^(-2 / (d + 2)), p estimated as w / r^d with r the
    # distance to the 8th nearest point (equal counts instead: 1.2x scikit-learn's inertia on graded data)
    if density is None:
        nb = min(8, m - 1)
        r = cKDTree(x).query(x, k=nb + 1)[0][:, nb] if nb > 0 else np.ones(m)
        density = w / np.maximum(r, 1e-12 * max(float(np.ptp(x, axis=0).max()), 1e-300)) ** dim
    u = w * np.asarray(density, dtype=np.float64) ** (-2.0 / (dim + 2))
    perm = np.arange(m)
    start = np.array([0, m])
    kk = np.array([k])  # segments [start[i], start[i+1]) with kk[i] clusters
    while kk.max() > 1:
        xs = x[perm]
        ptr = start[:-1]
        size = np.diff(start)
        lo = np.stack([np.minimum.reduceat(xs[:, d], ptr) for d in range(dim)], 1)
        ext = np.stack([np.maximum.reduceat(xs[:, d], ptr) for d in range(dim)], 1) - lo
        axis = ext.argmax(axis=1)
        seg = np.repeat(np.arange(len(kk)), size)
        a = axis[seg]
        # one argsort of segment + position in [0, 1) along the segment's axis (a lexsort is 3x slower)
        key = (xs[np.arange(m), a] - lo[seg, a]) / np.maximum(ext[seg, a], 1e-300) * 0.999 + seg
        o = np.argsort(key)
        perm = perm[o]
        cw = np.cumsum(u[perm])
        before = np.r_[0.0, cw][ptr]
        tot = cw[start[1:] - 1] - before
        kl = kk // 2
        target = before + tot * kl / kk
        cut = np.searchsorted(cw, target, side="left") + 1  # first index of the right half
        cut = np.clip(cut, ptr + kl, start[1:] - (kk - kl))
        split = kk > 1
        new_start = np.sort(np.r_[start, cut[split]])
        new_kk = np.empty(len(kk) + int(split.sum()), dtype=np.int64)
        pos = np.arange(len(kk)) + np.r_[0, np.cumsum(split)[:-1]]
        new_kk[pos] = np.where(split, kl, kk)
        new_kk[pos[split] + 1] = (kk - kl)[split]
        start, kk = new_start, new_kk
    seg = np.repeat(np.arange(k), np.diff(start))
    ww = w[perm]
    sw = np.bincount(seg, weights=ww, minlength=k)
    return (
        np.stack([np.bincount(seg, weights=ww * x[perm, d], minlength=k) for d in range(dim)], 1)
        / sw[:, None]
    )


_BOUNDS_FROM_K = 128  # from this many centres Lloyd's assignment keeps Hamerly's bounds


class _BoundedAssign:
    """Nearest centres across Lloyd's passes with Hamerly's bounds: each point keeps a lower bound
    on its distance to every centre but its own, lowered by the largest centre move of each pass;
    a point whose exact distance to its own centre is within that bound keeps its centre, and only
    the others go through a k-d tree (nearest two, which also renews the bound). Exact, and after
    the first passes most points are settled (the certified search looked at 21 centres per point
    on every pass)."""

    def __init__(self, x: np.ndarray, labels: np.ndarray | None = None, low: np.ndarray | None = None):
        self.x = x
        self.labels = labels  # with low: known bounds (e.g. from binned points), else a first full search
        self.low = low

    def __call__(self, centers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from scipy.spatial import cKDTree

        x = self.x
        if self.labels is None:
            d, idx = cKDTree(centers).query(x, k=2)
            self.labels, self.low = idx[:, 0].astype(np.int64), d[:, 1]
            return self.labels.copy(), d[:, 0] ** 2
        own = centers[self.labels]
        dist = (x[:, 0] - own[:, 0]) ** 2
        for j in range(1, x.shape[1]):
            dist += (x[:, j] - own[:, j]) ** 2
        redo = np.flatnonzero(dist > np.maximum(self.low, 0.0) ** 2)  # a bound below 0 says nothing
        if redo.size:
            d, idx = cKDTree(centers).query(x[redo], k=2)
            self.labels[redo] = idx[:, 0]
            self.low[redo] = d[:, 1]
            dist[redo] = d[:, 0] ** 2
        return self.labels.copy(), dist

    def moved(self, shift: np.ndarray) -> None:
        """The centres moved by `shift` (distances): every lower bound drops by the largest move."""
        self.low -= float(shift.max()) if shift.size else 0.0


def lloyd(
    x: np.ndarray,
    centers: np.ndarray,
    max_iter: int,
    tol: float,
    w: np.ndarray | None = None,
    labels: np.ndarray | None = None,
    rel_tol: float | None = None,
    assign: _BoundedAssign | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """(Weighted) Lloyd's iterations until the centres move less than tol (sum of squared shifts) ->
    (centres, labels, inertia), labels and inertia those of the returned centres."""
    ww = np.ones(len(x)) if w is None else w
    if assign is None and len(centers) > _BOUNDS_FROM_K:
        assign = _BoundedAssign(x)
    for _ in range(max_iter):
        labels, dist = nearest_center(x, centers, labels) if assign is None else assign(centers)
        new = _centers_of(x, labels, centers, w)
        shifts = np.sum((new - centers) ** 2, axis=1)
        centers = new
        if assign is not None:
            assign.moved(np.sqrt(shifts))
        if rel_tol is not None:
            # moving the centres to the means lowers the inertia by exactly sum_j W_j |shift_j|^2:
            # stop when that is under rel_tol of the inertia (a test that does not tighten as k grows,
            # unlike the summed squared shifts, whose passes grew from 31 to 112 as k went 10 -> 413)
            if float(np.bincount(labels, weights=ww, minlength=len(centers)) @ shifts) <= rel_tol * float(
                dist @ ww
            ):
                break
        elif float(shifts.sum()) <= tol:
            break
    labels, dist = nearest_center(x, centers, labels) if assign is None else assign(centers)
    return centers, labels, float(dist @ (np.ones(len(x)) if w is None else w))


def grid_summary(
    x: np.ndarray, n_bins: int, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points binned on a uniform grid of about n_bins cells over their bounding box -> (mean of each
    non-empty bin, number of points in it, bin of each point). k-means on the weighted bin means
    approximates k-means on the points when bins are much smaller than clusters."""
    lo = np.array([x[:, d].min() for d in range(x.shape[1])])
    hi = np.array([x[:, d].max() for d in range(x.shape[1])])
    ext = np.maximum(hi - lo, 1e-300)
    dim = x.shape[1]
    h = (np.prod(ext) / n_bins) ** (1.0 / dim) if np.all(hi > lo) else ext.max() / n_bins
    shape = np.maximum(np.ceil(ext / h).astype(np.int64), 1)
    cell = np.minimum(((x - lo) / h).astype(np.int64), shape - 1)
    lin = np.ravel_multi_index(tuple(cell.T), tuple(shape))
    counts = np.bincount(lin, minlength=int(np.prod(shape)))
    used = np.flatnonzero(counts)
    remap = np.zeros(counts.size, dtype=np.int64)
    remap[used] = np.arange(used.size)
    bins = remap[lin]
    if weights is None:
        w = counts[used].astype(np.float64)
        wx = [x[:, d] for d in range(dim)]
    else:  # the points' weights summed per bin, the means weighted
        w = np.bincount(bins, weights=weights, minlength=used.size)
        wx = [x[:, d] * weights for d in range(dim)]
    means = (
        np.stack([np.bincount(bins, weights=wx[d], minlength=used.size) for d in range(dim)], axis=1)
        / w[:, None]
    )
    return means, w, bins


def kmeans(
    x: np.ndarray,
    k: int,
    seed: int = 0,
    n_init: int = 1,
    bins_per_cluster: int = 256,
    max_iter: int = 30,
    tol: float = 1e-4,
    polish: int = 2,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """(N,) cluster of each point. On many points: weighted k-means (k-means++ then Lloyd, n_init
    starts, the best kept) on the means of a fine grid of bins (about bins_per_cluster per cluster),
    then `polish` Lloyd's iterations on all the points. The first Lloyd's iterations stop when one
    lowers the inertia by less than tol of it (a test that does not tighten as k grows), or after
    max_iter passes: the passes needed to settle grow with k (35 at k = 413, 51 at k = 998 on 3D
    cubes of 1000 cells per cluster), and the last ones gain little (30 passes: +0.8% inertia at
    k = 998), so the cap keeps the cost linear in the number of points when k grows with it."""
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    rng = np.random.default_rng(seed)
    xc = x - [
        float(x[:, d].mean()) for d in range(x.shape[1])
    ]  # centred: |x|^2 - 2 x.c + |c|^2 keeps its precision
    if n > 2 * bins_per_cluster * k:
        pts, w, bins = grid_summary(xc, bins_per_cluster * k, weights)
    else:
        pts, w, bins = xc, weights, None
    best = None
    for _ in range(max(1, n_init)):
        # k-means++ costs O(m k trials) on m points: greedy on a random subset of max(64 k, 32768)
        # points for a few clusters; for many, k sequential steps on even 8 k points grow as k^2
        # (7.7 s of a 9.4 s k-means hierarchy on 54k tetrahedra), so the start is a recursive
        # bisection of all the points (O(m log m log k)), which Lloyd's iterations then refine
        if k <= 512 or len(pts) < k:
            m = min(len(pts), max(64 * k, 32768))
            sub = np.arange(len(pts)) if m == len(pts) else np.sort(rng.choice(len(pts), m, replace=False))
            c0 = kmeans_plus_plus(pts[sub], k, rng, None if w is None else w[sub], greedy=k <= 512)
        else:
            # equal bins: the density is the weight; points of their own (weighted or not): their
            # density is estimated (w as the density of raw points put the seeds where w is large:
            # on a mesh graded 1000:1, half the clusters single cells and others of 400)
            c0 = bisection_seeds(pts, k, w, density=w if bins is not None else None)
        state = _BoundedAssign(pts) if k > _BOUNDS_FROM_K else None
        c, lab, inertia = lloyd(pts, c0, max_iter, 0.0, w, rel_tol=tol, assign=state)
        if best is None or inertia < best[1]:
            best = (c, inertia, lab, state)
        if k > 512 and len(pts) >= k:  # the bisection start has no randomness: one start is all
            break
    centers, _, labels, state = best
    if bins is None:
        return _no_empty(xc, labels, k)
    labels = labels[bins]
    start = None
    if state is not None:
        # the bins' bounds carry over: no centre but its bin's is nearer to a point than the bin's
        # bound minus the point's distance to its bin's mean (saves a full search on all the points)
        off = np.sqrt(sum((xc[:, d] - pts[bins, d]) ** 2 for d in range(xc.shape[1])))
        start = _BoundedAssign(xc, labels.copy(), state.low[bins] - off)
    centers, labels, _ = lloyd(xc, centers, polish, 0.0, weights, labels=labels, assign=start)
    return _no_empty(xc, labels, k)


def _no_empty(x: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    """labels with every one of the k clusters used (where there are k points): each cluster Lloyd's
    iterations left empty takes the far half of the cluster of the most points, cut across its
    longest extent (weighted k-means on a graded hierarchy's level: 777 clusters for 794). By points,
    not weights: the weights of a hierarchy's k-means favour small cells, and halving the heaviest
    cluster again and again left clusters of one cell."""
    n = len(x)
    count = np.bincount(labels, minlength=k)
    for m in np.flatnonzero(count[:k] == 0):  # a loop over the empty clusters (few)
        big = int(np.argmax(count))
        if count[big] < 2 or n < k:
            break
        idx = np.flatnonzero(labels == big)
        axis = int(np.argmax(np.ptp(x[idx], axis=0)))
        far = idx[np.argsort(x[idx, axis], kind="stable")][idx.size // 2 :]
        labels[far] = m
        count[m], count[big] = far.size, count[big] - far.size
    return labels


def two_means_batch(batch: GraphBatch, seed: int = 0, max_iter: int = 100) -> np.ndarray:
    """(N,) 2-means labels of the centroids of every graph of the batch, all graphs at once: k-means++
    start (a random node, then one drawn proportionally to the squared distance), Lloyd's iterations
    until no node changes side. Graphs under 2 nodes get 0; a graph whose centroids all coincide is
    split in halves."""
    x = np.asarray(batch.centroids, dtype=np.float64)
    n, b = batch.n_nodes, batch.n_graphs
    ptr = np.asarray(batch.graph_ptr, dtype=np.int64)
    sizes = np.diff(ptr)
    gi = batch.graph_index()
    rng = np.random.default_rng(seed)
    labels = np.zeros(n, dtype=np.int64)
    if n == 0:
        return labels
    live = sizes >= 2
    first = ptr[:-1] + np.minimum((rng.random(b) * sizes).astype(np.int64), np.maximum(sizes - 1, 0))
    first = np.where(live, first, 0)
    c0 = x[first]
    d0 = np.sum((x - c0[gi]) ** 2, axis=1)
    cum = np.cumsum(d0)
    before = np.where(ptr[:-1] > 0, cum[np.maximum(ptr[:-1] - 1, 0)], 0.0)
    total = cum[np.maximum(ptr[1:] - 1, 0)] - before
    live &= total > 0
    target = before + rng.random(b) * total
    second = np.clip(np.searchsorted(cum, target, side="right"), ptr[:-1], np.maximum(ptr[1:] - 1, 0))
    c1 = x[np.where(live, second, 0)]
    node_live = live[gi]
    for _ in range(max_iter):
        new = (np.sum((x - c1[gi]) ** 2, axis=1) < np.sum((x - c0[gi]) ** 2, axis=1)) & node_live
        if _ > 0 and np.array_equal(new, labels.astype(bool)):
            break
        labels = new.astype(np.int64)
        key = 2 * gi + labels
        counts = np.bincount(key, minlength=2 * b).reshape(b, 2)
        sums = np.stack([np.bincount(key, weights=x[:, d], minlength=2 * b) for d in range(x.shape[1])], 1)
        sums = sums.reshape(b, 2, -1)
        c0 = np.where(counts[:, :1] > 0, sums[:, 0] / np.maximum(counts[:, :1], 1), c0)
        c1 = np.where(counts[:, 1:] > 0, sums[:, 1] / np.maximum(counts[:, 1:], 1), c1)
    # graphs of >= 2 nodes whose centroids coincide: the second half of the nodes goes to side 1
    flat = (sizes >= 2) & ~live
    if flat.any():
        pos = np.arange(n) - ptr[gi]
        labels[flat[gi] & (pos >= (sizes // 2)[gi])] = 1
    return labels


class KMeansPartitioner(Partitioner):
    """Lloyd's k-means on the cell centroids (k-means++ init, fixed seed)."""

    name = "kmeans"
    supports_kway = True
    description = (
        "k-means clustering of cell centroids, seeded; parts split into connected components afterwards."
    )

    def __init__(self, seed: int = 0, n_init: int = 1, balance: str = "space"):
        if balance not in ("space", "cells"):
            raise ParameterError(f"balance must be 'space' or 'cells', got {balance!r}")
        self.seed = int(seed)
        self.n_init = int(n_init)
        self.balance = balance

    def kway_labels(self, x: np.ndarray, k: int, weights: np.ndarray | None = None) -> np.ndarray:
        """(N,) k-means clusters of the points x (N, dim), weighted by `weights` where given."""
        if k == 1:
            return np.zeros(len(x), dtype=np.int64)
        return kmeans(x, k, seed=self.seed, n_init=self.n_init, weights=weights)

    def kway(self, batch: GraphBatch, k: int) -> np.ndarray:
        return self.kway_labels(
            batch.centroids, k, self.cell_weights(batch) if self.balance == "cells" else None
        )

    @staticmethod
    def cell_weights(batch: GraphBatch) -> np.ndarray:
        """Weights under which k-means' clusters hold about equal numbers of cells (balance="cells",
        hierarchies): Lloyd's centres settle with a density proportional to (point density x
        weight)^(d / (d + 2)) (Gersho's asymptotic law), so weights cells^((d + 2) / d) x
        measure^(-2 / d) per point make it proportional to the density of cells: on a mesh graded
        100:1 the unweighted clusters hold many more cells where the mesh is fine."""
        d = batch.centroids.shape[1]
        m = np.maximum(np.abs(np.asarray(batch.measures, dtype=np.float64)), 1e-300)
        w = batch.cell_counts() ** ((d + 2.0) / d) * m ** (-2.0 / d)
        return w / w.mean()

    def bisect_batch(self, batch: GraphBatch) -> np.ndarray:
        return two_means_batch(batch, seed=self.seed)

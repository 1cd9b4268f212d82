"""The numpy k-means behind the kmeans partitioner: exact nearest-centre search, inertia against
scikit-learn's KMeans, batched 2-means equal to one graph at a time."""

from __future__ import annotations

import numpy as np
import pytest

from models.graph.batch import GraphBatch
from models.partition.kmeans import _brute_nearest, bisection_seeds, kmeans, nearest_center, two_means_batch


def _inertia(x, labels):
    k = labels.max() + 1
    c = np.stack([np.bincount(labels, weights=x[:, d], minlength=k) for d in range(x.shape[1])], 1)
    c /= np.maximum(np.bincount(labels, minlength=k), 1)[:, None]
    return float(((x - c[labels]) ** 2).sum())


@pytest.mark.parametrize("dim", [2, 3])
def test_nearest_center_with_a_guess_is_exact(dim):
    """The certified neighbour search (from any guess, even a random one) finds the nearest centre."""
    rng = np.random.default_rng(dim)
    x = rng.normal(size=(20_000, dim)) * [1.0, 3.0, 0.5][:dim]
    centers = x[rng.choice(len(x), 100, replace=False)]
    ref, ref_d = _brute_nearest(x, centers)
    for guess in (ref, rng.integers(0, 100, len(x)), (ref + 1) % 100):
        lab, d = nearest_center(x, centers, guess)
        assert np.allclose(d, ref_d, rtol=1e-9, atol=1e-9)
        assert np.mean(lab == ref) > 0.9999  # exact ties aside


@pytest.mark.parametrize("dim,k", [(2, 16), (3, 12)])
def test_kmeans_inertia_close_to_scikit_learn(dim, k):
    """On points enough to be binned first, the inertia stays within 1% of scikit-learn's (same seed)."""
    from sklearn.cluster import KMeans

    rng = np.random.default_rng(0)
    x = np.vstack([rng.random((60_000, dim)), rng.normal(0.3, 0.05, (20_000, dim))])  # graded density
    ours = _inertia(x, kmeans(x, k, seed=0))
    ref = KMeans(n_clusters=k, n_init=1, random_state=0).fit(x).inertia_
    assert ours <= 1.01 * ref, (ours, ref)
    assert np.array_equal(kmeans(x, k, seed=0), kmeans(x, k, seed=0))


def test_two_means_batch_is_per_graph():
    """Batched 2-means: each graph's labels depend only on its own nodes' positions in the batch;
    tiny and flat graphs handled; both sides non-empty on graphs with distinct points."""
    rng = np.random.default_rng(1)
    sizes = [1, 2, 7, 300, 50, 4]
    pts = [rng.random((s, 2)) for s in sizes]
    pts[-1] = np.zeros((4, 2))  # all centroids equal: split in halves
    x = np.vstack(pts)
    ptr = np.r_[0, np.cumsum(sizes)]
    n = len(x)
    batch = GraphBatch(
        indptr=np.zeros(n + 1, dtype=np.int64),
        indices=np.zeros(0, dtype=np.int64),
        weights=np.zeros(0),
        graph_ptr=ptr,
        centroids=x,
        measures=np.ones(n),
        tags=None,
        node_ids=np.arange(n),
    )
    lab = two_means_batch(batch, seed=3)
    assert np.array_equal(lab, two_means_batch(batch, seed=3))
    assert lab[0] == 0
    for b in range(1, len(sizes)):
        side = lab[ptr[b] : ptr[b + 1]]
        assert 0 < side.sum() < sizes[b]
    assert lab[ptr[-2] :].tolist() == [0, 0, 1, 1]
    # 2-means optimality on the big graph: every point is nearer its own side's mean
    g = pts[3]
    s = lab[ptr[3] : ptr[4]]
    c = np.stack([g[s == 0].mean(0), g[s == 1].mean(0)])
    d = ((g[:, None, :] - c[None]) ** 2).sum(-1)
    assert np.all(d[np.arange(len(g)), s] <= d[np.arange(len(g)), 1 - s] + 1e-12)


def test_bisection_seeds_one_nonempty_part_per_cluster():
    """The many-cluster start: k centres, each the (weighted) mean of a non-empty part, even with
    k close to the number of points, duplicates and skewed weights."""
    rng = np.random.default_rng(4)
    x = np.vstack([rng.random((997, 3)), np.zeros((50, 3))])
    w = rng.random(len(x)) ** 4 + 1e-3
    for k, ww in ((1047, None), (600, w), (3, w)):
        c = bisection_seeds(x, k, ww)
        assert c.shape == (k, 3) and np.all(np.isfinite(c))
        assert np.all(c >= x.min(0) - 1e-12) and np.all(c <= x.max(0) + 1e-12)
    c = bisection_seeds(x[:997], 997)  # one point per part: the centres are the points themselves
    assert np.array_equal(np.unique(c, axis=0), np.unique(x[:997], axis=0))


@pytest.mark.parametrize("dim,k", [(2, 1500), (3, 2000)])
def test_kmeans_many_clusters(dim, k):
    """k ~ n / 8 (the kmeans hierarchy's finest level): exactly k non-empty clusters and an inertia
    within 5% of scikit-learn's (same data, n_init 1), deterministic."""
    from sklearn.cluster import KMeans

    rng = np.random.default_rng(dim)
    x = np.vstack([rng.random((12_000, dim)), rng.normal(0.3, 0.05, (4_000, dim))])
    lab = kmeans(x, k, seed=0)
    assert np.unique(lab).size == k
    ref = KMeans(n_clusters=k, n_init=1, random_state=0, max_iter=100).fit(x).inertia_
    assert _inertia(x, lab) <= 1.05 * ref, (_inertia(x, lab), ref)
    assert np.array_equal(lab, kmeans(x, k, seed=0))


def test_lloyd_passes_do_not_grow_with_k():
    """The stopping test is relative to the inertia: on uniform 3D points with about 1000 points per
    cluster, k = 40 and k = 400 take comparable numbers of Lloyd passes (the summed-shift test took
    39 and 112)."""
    from models.partition import kmeans as km

    calls = []
    real = km.nearest_center

    def counting(*a, **kw):
        calls.append(1)
        return real(*a, **kw)

    rng = np.random.default_rng(0)
    passes = []
    for k in (40, 400):
        x = rng.random((1000 * k, 3))
        calls.clear()
        try:
            km.nearest_center = counting
            km.kmeans(x, k, seed=0)
        finally:
            km.nearest_center = real
        passes.append(len(calls))
    assert passes[1] <= 1.5 * passes[0] + 5, passes


def test_lloyd_with_bounds_is_exact():
    """Lloyd's passes with Hamerly's bounds (many centres) give, pass for pass, the labels of the
    exact nearest-centre search: same centres, labels and inertia as the plain passes."""
    from models.partition import kmeans as km

    rng = np.random.default_rng(5)
    x = np.vstack([rng.random((30_000, 3)), rng.normal(0.3, 0.05, (10_000, 3))])
    c0 = x[rng.choice(len(x), 300, replace=False)]
    for passes in (1, 3, 12):
        c1, l1, i1 = km.lloyd(x, c0, passes, 0.0)  # 300 centres: bounds
        old = km._BOUNDS_FROM_K
        try:
            km._BOUNDS_FROM_K = 10**9
            c2, l2, i2 = km.lloyd(x, c0, passes, 0.0)
        finally:
            km._BOUNDS_FROM_K = old
        assert np.allclose(c1, c2, rtol=0, atol=1e-12) and np.mean(l1 == l2) > 0.9999
        assert abs(i1 - i2) <= 1e-9 * i2


def test_kmeans_bounds_carried_from_bins_are_exact():
    """With many centres on binned points, the bins' bounds start the passes on all the points; the
    labels are those of the plain exact search (bounds off)."""
    from models.partition import kmeans as km

    rng = np.random.default_rng(6)
    x = np.vstack([rng.random((90_000, 3)), rng.normal(0.3, 0.05, (30_000, 3))])
    with_bounds = km.kmeans(x, 200, seed=0)
    old = km._BOUNDS_FROM_K
    try:
        km._BOUNDS_FROM_K = 10**9
        plain = km.kmeans(x, 200, seed=0)
    finally:
        km._BOUNDS_FROM_K = old
    assert np.mean(with_bounds == plain) > 0.9999


def test_no_cluster_is_left_empty():
    """Lloyd's iterations leave clusters empty where points coincide (or under strong weights: a
    graded hierarchy's level got 777 clusters for 794): each takes half of the heaviest cluster."""
    rng = np.random.default_rng(0)
    x = np.vstack([np.zeros((90, 2)), rng.random((10, 2)) + 5])
    lab = kmeans(x, 20)
    assert np.unique(lab).size == 20 and lab.min() == 0 and lab.max() == 19
    assert np.unique(lab[:90]).size >= 10  # the 10 other points hold 10 clusters at most


@pytest.mark.parametrize("grading", [1.0, 100.0, 1000.0])
def test_weighted_kmeans_holds_equal_counts_on_graded_cells(grading):
    """The hierarchies' k-means (KMeans.cell_weights: weights 1 / area in 2D) on a tensor grid of
    quads graded `grading`:1 in both directions, many clusters (5 cells each, no binning): the seeds
    come from the points' estimated weighted density. Taking the weights as that density put the
    seeds where the cells are small: half the clusters were single cells and others held hundreds
    (a k-means hierarchy then took 52 iterations where pyamg takes 18)."""
    n = 120
    t = np.linspace(0.0, 1.0, n + 1)
    x = (grading**t - 1.0) / (grading - 1.0) if grading > 1 else t  # cell widths from 1 to grading
    h = np.diff(x)
    cx, cy = np.meshgrid(0.5 * (x[1:] + x[:-1]), 0.5 * (x[1:] + x[:-1]))
    area = np.outer(h, h).ravel()
    w = 1.0 / area
    k = n * n // 5
    labels = kmeans(np.c_[cx.ravel(), cy.ravel()], k, weights=w / w.mean())
    counts = np.bincount(labels, minlength=k)
    assert counts.min() >= 1
    assert np.count_nonzero(counts == 1) <= 0.05 * k
    assert counts.max() <= 4 * np.median(counts)

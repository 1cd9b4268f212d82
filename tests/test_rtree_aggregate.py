"""The finest level of a default hierarchy: a standard aggregation of the cells' graph
(models/partition/rtree_aggregate.py, issue 24 round five)."""

import numpy as np
import pytest
from conftest import pieces
from meshes import quads, tets, triangles

from models.hierarchy.multigrid import mgcheck, tpfa_poisson
from models.hierarchy.nested import build_hierarchy, default_ratio, is_nested
from models.mesh.read import mesh_from_arrays
from models.partition.rtree import level_counts
from models.partition.rtree_aggregate import (
    merge_smallest,
    normalized_coupling,
    pyamg_aggregates,
    standard_aggregates,
    strong_couplings,
)
from models.pipeline import prepare


def _mesh(make, cell):
    p, c = make()
    m = mesh_from_arrays(p, [(cell, c)])
    g, d = prepare(m)
    return m, g, d


@pytest.mark.parametrize("make,cell", [(lambda: quads(30), "quad"), (lambda: tets(8), "tetra")])
def test_roots_neighbours_and_connected_elements(make, cell):
    m, g, d = _mesh(make, cell)
    ip, ii = np.asarray(d.graph.indptr, dtype=np.int64), np.asarray(d.graph.indices, dtype=np.int64)
    A, _ = tpfa_poisson(m, d)
    lab = standard_aggregates(
        ip,
        ii,
        normalized_coupling(ip, ii, -A[np.repeat(np.arange(m.n_cells), np.diff(ip)), ii].A1, A.diagonal()),
    )
    k = int(lab.max()) + 1
    assert np.array_equal(np.unique(lab), np.arange(k)) and pieces(g, lab) == k
    # every element holds a root with all its neighbours: a cell whose whole neighbourhood is inside
    rows = np.repeat(np.arange(m.n_cells), np.diff(ip))
    outside = np.bincount(rows, weights=(lab[rows] != lab[ii]).astype(float), minlength=m.n_cells)
    assert np.all(np.bincount(lab, weights=(outside == 0).astype(float), minlength=k) >= 1)
    # the same roots as pyamg's sequential greedy pass (lowest index first): the same count
    pyamg = pytest.importorskip("pyamg")
    C = pyamg.strength.symmetric_strength_of_connection(A, 0.0)
    assert pyamg.aggregation.standard_aggregation(C)[0].shape[1] == k


def test_aggregated_hierarchy_no_more_iterations_than_pyamg():
    pytest.importorskip("pyamg")
    m, g, d = _mesh(lambda: tets(10), "tetra")
    levels, info = build_hierarchy(m, d, model="rtree", coarsest=10, model_options={"finest": "aggregation"})
    assert info["finest"] == "aggregation" and is_nested(levels)
    assert all(pieces(g, lv) == int(lv.max()) + 1 for lv in levels)
    rep = mgcheck(m, d, levels)
    assert rep["smoothed"]["iterations"] <= rep["pyamg_sa"]["iterations"]
    assert rep["ratios"]["smoothed_complexity_vs_pyamg"] <= 1.1


def test_isolated_nodes_are_their_own_elements():
    ip = np.array([0, 1, 2, 2])  # 0 - 1, node 2 alone
    lab = standard_aggregates(ip, np.array([1, 0]), np.ones(2))
    assert lab[0] == lab[1] and lab[2] != lab[0]


@pytest.mark.parametrize("make,cell", [(lambda: quads(30), "quad"), (lambda: tets(8), "tetra")])
def test_pyamg_compiled_pass_matches_the_vectorized_one(make, cell):
    """Round six: pyamg's compiled standard aggregation (one pass, whatever the numbering) with the
    cells off the stars joined by strength gives exactly the round-five aggregates; without strength
    it is pyamg's own AggOp (its pass 2 takes the first aggregated neighbour)."""
    pyamg = pytest.importorskip("pyamg")
    m, g, d = _mesh(make, cell)
    ip, ii = np.asarray(d.graph.indptr, dtype=np.int64), np.asarray(d.graph.indices, dtype=np.int64)
    A, _ = tpfa_poisson(m, d)
    s = normalized_coupling(ip, ii, -A[np.repeat(np.arange(m.n_cells), np.diff(ip)), ii].A1, A.diagonal())
    lab = pyamg_aggregates(ip, ii, s)
    assert np.array_equal(lab, standard_aggregates(ip, ii, s))
    k = int(lab.max()) + 1
    assert pieces(g, lab) == k
    # shuffled numbering: still a valid aggregation (connected elements, one root star each)
    perm = np.random.default_rng(0).permutation(m.n_cells)
    inv = np.argsort(perm)
    B = A[perm][:, perm].tocsr()
    B.sort_indices()
    rows = np.repeat(np.arange(m.n_cells), np.diff(B.indptr))
    off = B.indices != rows
    bp = np.r_[0, np.cumsum(np.bincount(rows[off], minlength=m.n_cells))]
    lab_p = pyamg_aggregates(bp, B.indices[off], -B.data[off])[inv]
    assert pieces(g, lab_p) == int(lab_p.max()) + 1
    raw = pyamg_aggregates(ip, ii)
    C = pyamg.strength.symmetric_strength_of_connection(A, 0.0)
    agg = pyamg.aggregation.standard_aggregation(C)[0]
    assert np.array_equal(raw, agg.indices) and pieces(g, raw) == agg.shape[1]


def test_pyamg_pass_isolated_nodes_are_their_own_elements():
    pytest.importorskip("pyamg")
    ip = np.array([0, 1, 2, 2])  # 0 - 1, node 2 alone
    for s in (None, np.ones(2)):
        lab = pyamg_aggregates(ip, np.array([1, 0]), s)
        assert lab[0] == lab[1] and lab[2] != lab[0] and sorted(set(lab.tolist())) == [0, 1]


def test_pair_quality_closed_form_matches_the_eigenproblem():
    """mu({i, j}) = sup v^T D (I - Pi) v / v^T A_G v, checked against a dense 2x2 solve."""
    from models.partition.rtree_aggregate import pair_quality

    rng = np.random.default_rng(3)
    for _ in range(20):
        c = rng.uniform(0.1, 2.0)
        e = rng.uniform(0.0, 1.0, 2)
        d = np.array([c, c]) + e + rng.uniform(0.0, 3.0, 2)  # couplings outside the pair too
        ex = e  # the row-sum excess: d minus all the row's couplings (c and the ones outside)
        AG = np.array([[c + ex[0], -c], [-c, c + ex[1]]])
        D = np.diag(d)
        one = np.ones(2)
        N = D - np.outer(D @ one, D @ one) / (one @ D @ one)
        u = np.array([1.0, -1.0])  # N's range; A_G's pseudo-inverse on it
        want = (u @ N @ u) / 2.0 * (u @ np.linalg.pinv(AG) @ u) / 2.0
        got = pair_quality(d, ex, np.array([c]), np.array([0]), np.array([1]))[0]
        assert abs(got - want) < 1e-9 * max(want, 1.0)


def test_quality_aggregates_pairs_then_pairs_of_pairs():
    """A 1D chain of 16 cells (Dirichlet at both ends): two passes make elements of up to 4 adjacent
    cells, every element connected, every cell labelled, counts between 16/4 and 16/2."""
    from models.partition.rtree_aggregate import quality_aggregates

    n = 16
    rows = np.r_[np.arange(n - 1), np.arange(1, n)]
    cols = np.r_[np.arange(1, n), np.arange(n - 1)]
    o = np.lexsort((cols, rows))
    rows, cols = rows[o], cols[o]
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    c = np.ones(cols.size)
    diag = np.full(n, 2.0)
    lab = quality_aggregates(indptr, cols, c, diag, passes=2, bound=8.0)
    k = int(lab.max()) + 1
    sizes = np.bincount(lab)
    assert 4 <= k <= 8 and sizes.max() <= 4 and sizes.min() >= 2
    for a in range(k):  # contiguous on a chain = connected
        idx = np.flatnonzero(lab == a)
        assert idx.max() - idx.min() + 1 == idx.size
    one = quality_aggregates(indptr, cols, c, diag, passes=2, bound=1.0)  # no pair good enough
    assert int(one.max()) + 1 == n


@pytest.mark.parametrize("make,cell", [(lambda: quads(40), "quad"), (lambda: tets(10), "tetra")])
def test_nested_aggregation_inside_the_cuts(make, cell):
    # finest="nested" (round eight): the coarser levels are the cells' cuts, the finest level pyamg's
    # aggregation inside each element of the level above, merged back to the unrestricted count
    m, g, d = _mesh(make, cell)
    levels, info = build_hierarchy(m, d, model="rtree", coarsest=10, model_options={"finest": "nested"})
    assert info["finest"] == "nested" and is_nested(levels)
    sizes = [int(lv.max()) + 1 for lv in levels]
    assert all(pieces(g, lv) == s for lv, s in zip(levels, sizes, strict=True))
    ip, ii = np.asarray(d.graph.indptr, dtype=np.int64), np.asarray(d.graph.indices, dtype=np.int64)
    k0 = int(pyamg_aggregates(ip, ii).max()) + 1  # the unrestricted aggregation's count
    step = default_ratio(m.dim)[1]  # the schedule's coarser step (2D 8, 3D 16)
    assert (
        info["requested"] == [*level_counts(k0, step, 10, given=0, stretch=info["stretch"]), k0]
        and sizes == info["requested"]
    )
    for r in info["report"]:
        assert abs(r["ratio_vs_requested"] - 1) <= 0.25
    # the finest aggregates nest in the coarser levels, which are the cells' own cuts (finest="cuts"
    # with those counts): the same elements as rtree_levels makes them on the cells
    plain, infop = build_hierarchy(
        m, d, model="rtree", coarsest=10, model_options={"finest": "nested", "merge": False}
    )
    assert is_nested(plain) and all(
        np.array_equal(a, b) for a, b in zip(plain[:-1], levels[:-1], strict=True)
    )
    kp = int(plain[-1].max()) + 1
    assert kp >= sizes[-1] and np.unique(plain[-1] * sizes[-1] + levels[-1]).size == kp  # merges only


def test_merge_smallest_joins_the_smallest_to_the_strongest_neighbour():
    # a path 0-1-2-3-4, elements {0}, {1, 2}, {3, 4}: the singleton joins its only neighbour
    ip = np.array([0, 1, 3, 5, 7, 8])
    ii = np.array([1, 0, 2, 1, 3, 2, 4, 3])
    lab = merge_smallest(ip, ii, np.ones(8), np.array([0, 1, 1, 2, 2]), 2)
    assert lab[0] == lab[1] == lab[2] and lab[3] == lab[4] != lab[0]
    # down to one element at most as far as the graph connects (two components stay two)
    ip2 = np.array([0, 1, 2, 3, 4])
    lab2 = merge_smallest(ip2, np.array([1, 0, 3, 2]), np.ones(4), np.arange(4), 1)
    assert int(lab2.max()) + 1 == 2 and lab2[0] == lab2[1] and lab2[2] == lab2[3]


def _stretched(make, cell, sx):
    p, c = make()
    p = np.asarray(p, dtype=np.float64).copy()
    p[:, 0] *= sx  # cells sx times longer along x: couplings along x sx^2 times weaker than across
    return _mesh(lambda: (p, c), cell)


def test_strong_couplings_leave_out_only_the_weak_ones():
    for sx, kept_all in ((1.0, True), (50.0, False)):
        m, g, d = _stretched(lambda: quads(12, 10), "quad", sx)
        ip, ii = np.asarray(d.graph.indptr, dtype=np.int64), np.asarray(d.graph.indices, dtype=np.int64)
        A, _ = tpfa_poisson(m, d)
        rows = np.repeat(np.arange(m.n_cells), np.diff(ip))
        s = normalized_coupling(ip, ii, -A[rows, ii].A1, A.diagonal())
        sp_, si_, sw_ = strong_couplings(ip, ii, s, 0.05)
        assert (si_.size == ii.size) == kept_all
        if not kept_all:  # only the couplings across the long faces (the same column, x index) stay
            r2 = np.repeat(np.arange(m.n_cells), np.diff(sp_))
            assert np.allclose(d.centroids[r2, 0], d.centroids[si_, 0]) and si_.size > 0
        assert np.all(np.diff(sp_) >= 0) and sp_[-1] == si_.size == sw_.size


@pytest.mark.parametrize(
    "make,cell", [(lambda: triangles(40, 40), "triangle"), (lambda: quads(40, 40), "quad")]
)
def test_the_default_aggregation_follows_strong_couplings(make, cell):
    pytest.importorskip("pyamg")
    for sx in (1.0, 50.0):
        m, g, d = _stretched(make, cell, sx)
        levels, info = build_hierarchy(m, d, model="rtree", coarsest=10)
        plain, _ = build_hierarchy(m, d, model="rtree", coarsest=10, model_options={"theta": 0.0})
        assert info["finest"] == "aggregation" and is_nested(levels)
        assert all(pieces(g, lv) == int(lv.max()) + 1 for lv in levels)
        # the same counts at every level (the strong graph's aggregates merged back to the count)
        assert [int(lv.max()) + 1 for lv in levels] == [int(lv.max()) + 1 for lv in plain]
        if sx == 1.0:  # no coupling that weak: the same levels
            assert all(np.array_equal(a, b) for a, b in zip(levels, plain, strict=True))
            continue
        rep, rep0 = mgcheck(m, d, levels), mgcheck(m, d, plain)
        # pyamg's aggregates and ours without the threshold take about pyamg's ~48 iterations here
        assert rep0["smoothed"]["iterations"] >= 0.9 * rep0["pyamg_sa"]["iterations"]
        assert rep["smoothed"]["iterations"] <= 0.6 * rep["pyamg_sa"]["iterations"]

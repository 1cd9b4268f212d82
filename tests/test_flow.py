"""Flow refinement of pairs of parts (models.partition.flow): known optima on grids, guarantees on the brain."""

from pathlib import Path

import numpy as np
import pytest

from models.graph.batch import GraphBatch
from models.partition import get_partitioner
from models.partition.agglomerate import make_batch
from models.partition.flow import flow_bisections, flow_kway, pair_mincut, part_components
from models.partition.refine import FMRefiner, bisection_ncut
from models.quality.partition_stats import partition_statistics

DATA = Path(__file__).parent / "data"


def grid(nx, ny):
    """nx x ny 4-neighbour grid as a one-graph batch; node x * ny + y, unit measures."""
    ids = np.arange(nx * ny).reshape(nx, ny)
    a = np.r_[ids[:-1, :].ravel(), ids[:, :-1].ravel()]
    b = np.r_[ids[1:, :].ravel(), ids[:, 1:].ravel()]
    r, c = np.r_[a, b], np.r_[b, a]
    o = np.lexsort((c, r))
    r, c = r[o], c[o]
    indptr = np.r_[0, np.cumsum(np.bincount(r, minlength=nx * ny))]
    xy = np.stack(np.divmod(np.arange(nx * ny), ny), axis=1).astype(np.float64)
    return GraphBatch(
        indptr=indptr,
        indices=c,
        weights=np.ones(c.size),
        graph_ptr=np.array([0, nx * ny]),
        centroids=xy,
        measures=np.ones(nx * ny),
        tags=None,
        node_ids=np.arange(nx * ny),
    )


def cut(b, lab):
    rows = np.repeat(np.arange(b.n_nodes), np.diff(b.indptr))
    return int((lab[rows] != lab[b.indices]).sum() // 2)


def zigzag(nx=12, ny=6):
    """Two halves of a grid split by a staircase boundary (cut well above the straight ny)."""
    b = grid(nx, ny)
    x, y = b.centroids[:, 0], b.centroids[:, 1]
    lab = (x >= nx / 2 + np.where(y % 2 == 0, -1, 1)).astype(np.int64)
    return b, lab


def test_two_parts_of_a_grid_get_the_straight_cut():
    b, lab = zigzag()
    assert cut(b, lab) > 6
    out = flow_kway(b, lab, tolerance=0.1)
    assert cut(b, out) == 6  # the optimum: a straight cut across the 6 rows
    w = np.bincount(out, weights=b.measures)
    assert w.max() <= 1.1 * 36 + 1e-9
    assert np.all(part_components(np.repeat(np.arange(b.n_nodes), np.diff(b.indptr)), b.indices, out, 2) == 1)


def test_no_room_no_move():
    # both parts at the cap (tolerance 0): only moves that keep 36 / 36 are allowed, and the
    # balanced straight cut is still found; with a band factor of 1 nothing heavier can appear
    b, lab = zigzag()
    out = flow_kway(b, lab, tolerance=0.0, alpha=1.0, max_alpha=1.0)
    assert np.array_equal(np.bincount(out), [36, 36])
    assert cut(b, out) <= cut(b, lab)


def test_pair_mincut_bands_stay_within_their_budget():
    # with room = cap - w(other) every cut in the band is balanced: checked on the proposal itself
    b, lab = zigzag(16, 8)
    caps = np.ones(b.indices.size, dtype=np.int32)
    w = np.bincount(lab, weights=b.measures)
    cap = 68.0
    new, ok, band = pair_mincut(
        b.indptr,
        b.indices,
        caps,
        b.measures,
        lab,
        np.array([0]),
        np.array([1]),
        np.array([cap - w[1]]),
        np.array([cap - w[0]]),
        np.array([cap]),
        20,
    )
    assert ok.all()
    assert np.bincount(new, weights=b.measures).max() <= cap
    assert np.all(new[band < 0] == lab[band < 0])  # only band nodes move
    assert cut(b, new) <= cut(b, lab)


def test_pair_mincut_bands_stop_at_max_hops():
    # a wide budget: the band is bounded by the hops alone, max_hops - 1 layers beyond the boundary
    b, lab = zigzag(16, 8)
    caps = np.ones(b.indices.size, dtype=np.int32)
    big = np.array([1e9])
    _, _, band = pair_mincut(
        b.indptr, b.indices, caps, b.measures, lab, np.array([0]), np.array([1]), big, big, big, 3
    )
    rows = np.repeat(np.arange(b.n_nodes), np.diff(b.indptr))
    hop = np.where(np.isin(np.arange(b.n_nodes), rows[lab[rows] != lab[b.indices]]), 0, -1)
    for d in range(1, b.n_nodes):  # BFS layers inside each side
        grow = (hop[rows] == d - 1) & (hop[b.indices] < 0) & (lab[rows] == lab[b.indices])
        if not grow.any():
            break
        hop[b.indices[grow]] = d
    assert band.max() == 0 and np.all(hop[band >= 0] <= 2)
    assert np.all(band[(hop >= 0) & (hop <= 2)] == 0)  # and it reaches that far


def test_fm_refiner_kway_band_hops_follow_the_part_size(brain_kway):
    g, b, lab = brain_kway
    auto = FMRefiner(kway_flow_rounds=6).refine_kway(b, lab)  # 64 parts of ~225 cells: 4 hops
    assert np.array_equal(auto, FMRefiner(kway_flow_rounds=6, flow_hops=4).refine_kway(b, lab))
    assert not np.array_equal(auto, FMRefiner(kway_flow_rounds=6, flow_hops=6).refine_kway(b, lab))
    assert stats(g, b, auto)["connected"] and stats(g, b, auto)["cut"] < stats(g, b, lab)["cut"]


@pytest.fixture(scope="module")
def brain_kway(brain):
    m, g, d = brain
    b = make_batch(d, np.zeros(m.n_cells, dtype=np.int64))
    return g, b, get_partitioner("metis").kway(b, 64)


def stats(g, b, lab):
    full = np.empty_like(lab)
    full[b.node_ids] = lab
    return partition_statistics(g.indptr, g.indices, full)


def test_flow_kway_on_metis_lowers_the_cut_within_the_cap_and_connected(brain_kway):
    g, b, lab = brain_kway
    out = flow_kway(b, lab, tolerance=0.03, rounds=15, alpha=8.0, max_alpha=16.0, schedule="matching")
    s0, s1 = stats(g, b, lab), stats(g, b, out)
    assert s1["connected"] and s1["parts"] == 64
    assert s1["cut"] <= 0.98 * s0["cut"]  # METIS's own refinement leaves >= 2% to the flows
    w0 = np.bincount(lab, weights=b.measures)
    w1 = np.bincount(out, weights=b.measures)
    cap = 1.03 * b.measures.sum() / 64
    assert np.all((w1 <= cap * (1 + 1e-9)) | (w1 <= w0 + 1e-9))


@pytest.mark.parametrize("schedule", ["all", "matching"])
def test_flow_kway_never_worse_and_ncut_objective(brain_kway, schedule):
    g, b, lab = brain_kway
    out = flow_kway(b, lab, rounds=4, schedule=schedule, seed=3)
    assert stats(g, b, out)["cut"] <= stats(g, b, lab)["cut"]
    nc = flow_kway(b, lab, rounds=4, objective="ncut", seed=3)
    s = stats(g, b, nc)
    assert s["normalized_cut"] < stats(g, b, lab)["normalized_cut"] and s["connected"]


def test_fm_refiner_kway_and_polish_use_the_flows(brain_kway):
    g, b, lab = brain_kway
    with_flow = FMRefiner(kway_flow_rounds=15).refine_kway(b, lab)
    without = FMRefiner(flow_rounds=0).refine_kway(b, lab)
    assert stats(g, b, with_flow)["cut"] < stats(g, b, without)["cut"]
    assert stats(g, b, with_flow)["connected"]


def test_flow_bisections_straighten_every_graph_of_a_batch():
    # two zigzag grids in one batch: each graph's bisection gets its straight cut, both at once
    b1, l1 = zigzag()
    n = b1.n_nodes
    b = GraphBatch(
        indptr=np.r_[b1.indptr, b1.indptr[1:] + b1.indptr[-1]],
        indices=np.r_[b1.indices, b1.indices + n],
        weights=np.r_[b1.weights, b1.weights],
        graph_ptr=np.array([0, n, 2 * n]),
        centroids=np.r_[b1.centroids, b1.centroids],
        measures=np.ones(2 * n),
        tags=None,
        node_ids=np.arange(2 * n),
    )
    side = np.r_[l1, 1 - l1]
    before = bisection_ncut(b, side)
    out = flow_bisections(b, side, tolerance=0.1)
    after = bisection_ncut(b, out)
    assert np.all(after < before)
    assert cut(b, out) == 12  # 6 per graph: the optimum
    meas = np.bincount(b.graph_index() * 2 + out, minlength=4).reshape(2, 2)
    assert np.all(meas.max(axis=1) <= 1.1 / 2 * n + 1e-9)


def test_flow_bisections_on_metis_never_worse_and_within_tolerance(brain):
    m, g, d = brain
    lab = (d.centroids[:, 0] > np.median(d.centroids[:, 0])).astype(np.int64)
    b = make_batch(d, lab)
    side = get_partitioner("metis").bisect_batch(b)
    out = flow_bisections(b, side, tolerance=0.05)
    nb, na = bisection_ncut(b, side), bisection_ncut(b, out)
    assert np.all(na <= nb + 1e-12) and na.sum() < nb.sum()
    gi = b.graph_index()
    m0 = np.bincount(gi * 2 + side, weights=b.measures, minlength=4).reshape(2, 2)
    m1 = np.bincount(gi * 2 + out, weights=b.measures, minlength=4).reshape(2, 2)
    assert np.all(m1.max(axis=1) <= np.maximum(0.525 * m1.sum(axis=1), m0.max(axis=1)) + 1e-9)
    # each side as connected as before
    rows = np.repeat(np.arange(b.n_nodes), np.diff(b.indptr))
    assert np.all(
        part_components(rows, b.indices, 2 * gi + out, 4)
        <= part_components(rows, b.indices, 2 * gi + side, 4)
    )


def test_flow_kway_never_swallows_a_part():
    """Unequal parts, as sage-hetero makes them on a mesh with an inclusion (sizes 7 to 89): under
    the k-way normalized cut an emptied part adds nothing, so taking a small part whole looked like
    a gain (14 of 16 parts were left); every part must keep a cell, whatever the objective."""
    from models.mesh.read import read_mesh
    from models.partition.agglomerate import agglomerate
    from models.pipeline import prepare

    mesh = read_mesh(DATA / "square_inclusion.msh")
    _, data = prepare(mesh)
    lab = agglomerate(mesh, data, model="sage-hetero", mode="nref", nref=4).labels
    b = make_batch(data, np.zeros(mesh.n_cells, dtype=np.int64))
    for objective in ("ncut", "cut"):
        out = flow_kway(b, lab[b.node_ids], 0.05, 40, alpha=8.0, max_alpha=16.0, seed=0, objective=objective)
        assert np.bincount(out, minlength=16).min() > 0, objective


def test_part_components_of_some_parts_agree_with_the_whole_graph():
    import scipy.sparse as sp

    rng = np.random.default_rng(1)
    n = 300
    r, c = rng.integers(0, n, 700), rng.integers(0, n, 700)
    a = sp.csr_matrix((np.ones(r.size), (r, c)), shape=(n, n))
    a = ((a + a.T) > 0).tocsr()
    a.setdiag(0)
    a.eliminate_zeros()
    a.sort_indices()
    rows = np.repeat(np.arange(n), np.diff(a.indptr))
    lab = rng.integers(0, 20, n)
    whole = part_components(rows, a.indices, lab, 20)
    assert whole.max() > 1  # random labels: parts in pieces
    for _ in range(10):
        parts = rng.random(20) < 0.5
        some = part_components(rows, a.indices, lab, 20, parts, a.indptr)
        assert np.array_equal(some, np.where(parts, whole, 0))
        assert np.array_equal(some, part_components(rows, a.indices, lab, 20, parts))

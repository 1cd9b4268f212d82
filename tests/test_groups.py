"""Refiners and coarsening keep physical groups apart (models.partition.groups): on meshes with materials
(tests/data/square_inclusion.msh, cube_inclusion.msh: a matrix and an inclusion), sage-hetero
multilevel + fm / rl-refiner must not make the heterogeneity preservation worse than the
unrefined partition, where the group-blind refiners (keep_groups=False) do."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from models.mesh.read import read_mesh
from models.partition.agglomerate import agglomerate, make_batch
from models.partition.coarsen import coarsen
from models.partition.groups import group_weighted, impurity, keep_purer, kway_impurity
from models.partition.refine import bisection_ncut, pairwise_fm
from models.pipeline import prepare
from models.quality.shape import heterogeneity_preservation

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def square():
    m = read_mesh(DATA / "square_inclusion.msh")
    return m, *prepare(m)


@pytest.fixture(scope="module")
def cube():
    m = read_mesh(DATA / "cube_inclusion.msh")
    return m, *prepare(m)


def hetero(mesh, agg) -> float:
    return float(np.nanmean(heterogeneity_preservation(agg.labels, mesh.tags)))


def test_group_weighted_counts_interface_edges_at_the_weight(square):
    m, g, d = square
    b = make_batch(d, np.zeros(m.n_cells, dtype=np.int64))
    w = group_weighted(b, 0.25)
    rows = np.repeat(np.arange(b.n_nodes), np.diff(b.indptr))
    cross = b.tags[rows] != b.tags[b.indices]
    assert cross.any()
    np.testing.assert_allclose(w.edge_counts(), np.where(cross, 0.25, 1.0))
    # volumes are the weighted degrees: the normalized cut is that of the reweighted graph
    np.testing.assert_allclose(w.volumes(), np.bincount(rows, weights=w.edge_counts(), minlength=b.n_nodes))
    side = (b.tags == b.tags.max()).astype(np.int64)  # the cut along the material interface
    ncut_plain, ncut_w = bisection_ncut(b, side)[0], bisection_ncut(w, side)[0]
    assert ncut_w < 0.3 * ncut_plain
    assert group_weighted(b, 1.0) is b
    untagged = dataclasses.replace(b, tags=None)
    assert group_weighted(untagged, 0.1) is untagged


def test_coarse_nodes_never_mix_groups_and_impurity_is_exact_on_every_level(cube):
    m, g, d = cube
    b = make_batch(d, np.zeros(m.n_cells, dtype=np.int64))
    levels = coarsen(b, threshold=50, seed=3)
    assert len(levels) >= 3
    cmap = np.arange(b.n_nodes)
    counts = np.ones(b.n_nodes)
    rng = np.random.default_rng(0)
    for lv in levels:
        cmap = lv.cmap[cmap]
        counts = np.bincount(lv.cmap, weights=counts, minlength=lv.batch.n_nodes)
        # every fine cell has its coarse node's group
        np.testing.assert_array_equal(lv.batch.tags[cmap], b.tags)
        # the guard's count on a coarse level equals the fine count of the projected bisection
        side = rng.integers(0, 2, lv.batch.n_nodes)
        assert impurity(lv.batch, side, counts)[0] == impurity(b, side[cmap])[0] > 0


def test_keep_purer_reverts_only_the_graphs_that_mix_more():
    from models.graph.batch import GraphBatch

    # two graphs, paths of 4 nodes: groups 0 0 1 1 each
    ip = np.array([0, 1, 3, 5, 6, 7, 9, 11, 12])
    ix = np.array([1, 0, 2, 1, 3, 2, 5, 4, 6, 5, 7, 6])
    b = GraphBatch(
        indptr=ip,
        indices=ix,
        weights=np.ones(12),
        graph_ptr=np.array([0, 4, 8]),
        centroids=np.zeros((8, 2)),
        measures=np.ones(8),
        tags=np.array([0, 0, 1, 1] * 2),
        node_ids=np.arange(8),
    )
    before = np.array([0, 0, 1, 1, 0, 0, 1, 1])
    after = np.array([0, 1, 1, 1, 0, 0, 1, 1])  # graph 0: a group-0 cell joins the group-1 side
    np.testing.assert_array_equal(impurity(b, before), [0, 0])
    np.testing.assert_array_equal(impurity(b, after), [1, 0])
    np.testing.assert_array_equal(keep_purer(b, before, after), before)
    after2 = np.array([0, 0, 1, 1, 0, 1, 1, 1])
    better = np.array([0, 0, 1, 1, 0, 1, 1, 1])
    np.testing.assert_array_equal(keep_purer(b, np.array([0, 1, 1, 1, 0, 1, 1, 1]), after2), better)
    assert kway_impurity(b.tags, after) == 1.0


def test_pairwise_fm_honours_edge_counts_and_volumes(square):
    """Explicit unit edge counts and degree volumes give the plain graph's result; the groups'
    weights are then what the polish optimizes."""
    m, g, d = square
    b = make_batch(d, np.zeros(m.n_cells, dtype=np.int64))
    lab = agglomerate(m, d, model="metis", mode="kway", k=8).labels[b.node_ids]
    plain = pairwise_fm(b, lab, 0.05, 3, 3, 0, "ncut")
    unit = dataclasses.replace(b, edge_count=np.ones(b.indices.size), volume=b.degrees().astype(float))
    np.testing.assert_array_equal(pairwise_fm(unit, lab, 0.05, 3, 3, 0, "ncut"), plain)
    assert not np.array_equal(plain, lab)


@pytest.mark.parametrize("refiner", ["fm", "rl-refiner"])
@pytest.mark.parametrize("mesh", ["square", "cube"])
def test_refined_sage_hetero_multilevel_keeps_the_groups(request, mesh, refiner):
    m, g, d = request.getfixturevalue(mesh)
    kw = dict(model="sage-hetero", mode="multilevel", nref=4, threshold=100)
    plain = hetero(m, agglomerate(m, d, **kw))
    agg = agglomerate(m, d, refiner=refiner, **kw)  # auto: on for sage-hetero
    kept = hetero(m, agg)
    assert kept >= plain - 1e-12
    assert agg.parts_before_split == 16  # a refinement that empties a part is refused too
    assert kept == hetero(m, agglomerate(m, d, refiner=refiner, keep_groups=True, **kw))
    if (mesh, refiner) != ("square", "rl-refiner"):  # there the blind rl-refiner happens not to mix
        blind = hetero(m, agglomerate(m, d, refiner=refiner, keep_groups=False, **kw))
        assert blind < kept


def test_keep_groups_is_off_for_group_blind_models_unless_asked(square):
    m, g, d = square
    kw = dict(model="metis", mode="nref", nref=4, refiner="fm")
    auto = agglomerate(m, d, **kw)
    np.testing.assert_array_equal(auto.labels, agglomerate(m, d, keep_groups=False, **kw).labels)
    asked = agglomerate(m, d, keep_groups=True, **kw)
    plain = agglomerate(m, d, model="metis", mode="nref", nref=4)
    assert hetero(m, asked) >= hetero(m, plain) - 1e-12
    with pytest.raises(Exception, match="group_weight"):
        agglomerate(m, d, keep_groups=True, group_weight=0.0, **kw)

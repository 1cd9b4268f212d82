"""Strength-aware cut axes for rtree hierarchies (rtree_levels(axes="strength"), issue 24 round four):
each part is cut across the axis whose quantile plane crosses the least TPFA transmissibility per
unit of cut; near-ties keep the longest extent."""

import numpy as np
import pytest
from conftest import pieces
from meshes import quads, tets

from models.errors import ParameterError
from models.hierarchy.nested import build_hierarchy, is_nested
from models.mesh.read import mesh_from_arrays
from models.partition.rtree import rtree_levels
from models.partition.rtree_strength import StrengthAxes, tpfa_coupling
from models.pipeline import prepare


def _extent_ratio(d, labels, h=1 / 64):
    """Geometric mean over elements of (x extent / y extent) of their cells (centroids' extent + h)."""
    c, k = d.centroids, int(labels.max()) + 1
    ext = []
    for a in range(2):
        hi, lo = np.full(k, -np.inf), np.full(k, np.inf)
        np.maximum.at(hi, labels, c[:, a])
        np.minimum.at(lo, labels, c[:, a])
        ext.append(hi - lo)
    return float(np.exp(np.mean(np.log((ext[0] + h) / (ext[1] + h)))))


def _batch(m, d):
    from models.graph.batch import GraphBatch

    G, n = d.graph, m.n_cells
    return GraphBatch(
        indptr=G.indptr,
        indices=G.indices,
        weights=G.weights,
        graph_ptr=np.array([0, n]),
        centroids=d.centroids,
        measures=d.measures,
        tags=d.tags,
        node_ids=np.arange(n),
    )


@pytest.mark.parametrize("axes", ["strength", "strength-mincut", "strength-position"])
def test_strength_levels_nested_connected_exact(axes):
    p, c = tets(8)
    m = mesh_from_arrays(p, [("tetra", c)])
    g, d = prepare(m)
    levels, info = build_hierarchy(m, d, model="rtree", coarsest=10, model_options={"axes": axes})
    sizes = [int(lv.max()) + 1 for lv in levels]
    assert sizes == info["requested"] and is_nested(levels)
    assert all(pieces(g, lv) == s for lv, s in zip(levels, sizes, strict=True))


def test_isotropic_grid_keeps_square_elements_and_tensor_stretches_them():
    p, q = quads(64)
    m = mesh_from_arrays(p, [("quad", q)])
    g, d = prepare(m)
    b = _batch(m, d)
    iso = rtree_levels(b, [16, 256], balance="cells", axes="strength")
    assert 0.6 < _extent_ratio(d, iso[-1]) < 1.7  # equal couplings both ways: the longest extent
    # couplings 16x stronger along x (K = diag(16, 1)): cuts cross the weak y couplings
    t = tpfa_coupling(b.indptr, b.indices, b.weights, b.centroids, np.array([16.0, 1.0]))
    ani = rtree_levels(b, [16, 256], balance="cells", axes="strength", coupling=t)
    assert _extent_ratio(d, ani[-1]) > 2.5
    assert all(pieces(g, lv) == int(lv.max()) + 1 for lv in ani) and is_nested(ani)


def test_bad_axes_refused():
    p, q = quads(8)
    m = mesh_from_arrays(p, [("quad", q)])
    _, d = prepare(m)
    with pytest.raises(ParameterError, match="axes must be"):
        rtree_levels(_batch(m, d), [4], axes="diagonal")


def test_cut_position_crosses_the_weakest_coupling_in_the_window():
    # six cells in a row, couplings 5 5 5 1 5: the quantile cut (after 3 cells) would cross a 5;
    # within the window (one cell either way) the cut after 4 cells crosses the weak 1
    indptr = np.array([0, 1, 3, 5, 7, 9, 10])
    indices = np.array([1, 0, 2, 1, 3, 2, 4, 3, 5, 4])
    t = np.array([5, 5, 5, 5, 5, 5, 1, 1, 5, 5], dtype=float)
    rule = StrengthAxes(indptr, indices, t, np.zeros((6, 1)))
    order = np.arange(6)
    axis = rule(order[None, :], np.ones(6), np.array([0]), np.array([6]), np.array([2]), np.array([[5.0]]))
    assert axis.tolist() == [0]
    mid = np.arange(6) + 0.5
    cut = rule.cut(order, np.array([0]), np.array([5]), mid, np.array([3.0]), np.array([1.2]), np.array([3]))
    assert cut.tolist() == [4]
    # an empty window keeps the quantile's cut
    cut = rule.cut(order, np.array([0]), np.array([5]), mid, np.array([3.0]), np.array([0.1]), np.array([3]))
    assert cut.tolist() == [3]


def test_build_hierarchy_default_is_the_min_cut_rule_and_kappa_keeps_box_cuts():
    p, q = quads(40)
    m = mesh_from_arrays(p, [("quad", q)])
    _, d = prepare(m)
    default, _ = build_hierarchy(m, d, model="rtree", coarsest=10)
    mincut, _ = build_hierarchy(m, d, model="rtree", coarsest=10, model_options={"axes": "strength-mincut"})
    assert all(np.array_equal(a, b) for a, b in zip(default, mincut, strict=True))
    k = np.array([4.0, 1.0])
    ak, _ = build_hierarchy(m, d, model="rtree", coarsest=10, kappa=k)
    bk, _ = build_hierarchy(m, d, model="rtree", coarsest=10, kappa=k, model_options={"axes": "box"})
    assert all(np.array_equal(a, b) for a, b in zip(ak, bk, strict=True))

"""The compiled helpers of the rtree model (models/graph/_fastgraph.c) against their numpy twins in
models/partition/rtree.py: the same cuts, pieces and coarse graphs bit for bit (the twins are the
fallback where the module is not built, and the reference here)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import pieces
from meshes import mixed_2d, mixed_3d, tets

import models.partition.rtree as rt
from models.mesh.read import mesh_from_arrays
from models.partition.agglomerate import make_batch
from models.pipeline import prepare


def test_the_compiled_cuts_are_built():
    """setup.py builds them with every install; rtree would still work without them, only slower."""
    assert rt._compiled() is not None, (
        "models/graph/_fastgraph.c was not compiled: reinstall (pip install -e .)"
    )


def _both(monkeypatch, fn):
    """fn() with the compiled module, then with the numpy twins."""
    assert rt._compiled() is not None
    a = fn()
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    assert rt._compiled() is None
    b = fn()
    monkeypatch.delenv("MAGNET_NO_COMPILED")
    return a, b


def _mesh(kind):
    if kind == "tets":  # structured: ties in every coordinate, equal measures
        p, t = tets(9)
        return mesh_from_arrays(p, [("tetra", t)])
    if kind == "mixed3d":
        return mesh_from_arrays(*mixed_3d(6))
    if kind == "mixed2d":
        return mesh_from_arrays(*mixed_2d(24))
    raise ValueError(kind)


@pytest.mark.parametrize("kind", ["brain", "tets", "mixed3d", "mixed2d"])
@pytest.mark.parametrize("slack", [0.0, 0.3, 1.0])
def test_split_counts_same_cuts(monkeypatch, brain, kind, slack):
    """Labels, every axis order and the parts' ranges equal, tight cuts (boxes) or plain quantiles,
    several groups at once, measures or unit weights."""
    if kind == "brain":
        m, _, d = brain
    else:
        m = _mesh(kind)
        _, d = prepare(m)
    n = m.n_cells
    lo, hi = rt.cell_boxes(d.points, d.offsets, d.connectivity)
    rng = np.random.default_rng(3)
    grp = (d.centroids[:, 0] > np.median(d.centroids[:, 0])).astype(np.int64)  # two groups
    need = np.array([max(2, n // 11), max(3, n // 7)])
    for w in (np.maximum(d.measures, 1e-300), np.ones(n), rng.random(n) + 0.5):

        def cut(w=w):
            seg = rt._Segments(d.centroids, grp, 2)
            lab = rt.split_counts(grp, need, d.centroids, w, lo, hi, slack, segments=seg)
            return lab, seg.P.copy(), seg.start, seg.size

        (la, Pa, sa, za), (lb, Pb, sb, zb) = _both(monkeypatch, cut)
        assert np.array_equal(la, lb) and np.array_equal(Pa, Pb)
        assert np.array_equal(sa, sb) and np.array_equal(za, zb)
        assert la.max() + 1 == need.sum()


@pytest.mark.parametrize("kind", ["brain", "tets", "mixed3d"])
def test_rtree_levels_same_hierarchy(monkeypatch, brain, kind):
    """Whole hierarchies (cuts, connected pieces, coarse graphs, numbering) equal, with the graphs of
    the levels' elements; physical groups on the structured tets."""
    if kind == "brain":
        m, _, d = brain
    else:
        m = _mesh(kind)
        _, d = prepare(m)
    batch = make_batch(d, np.zeros(m.n_cells, dtype=np.int64))
    boxes = rt.cell_boxes(d.points, d.offsets, d.connectivity)
    groups = (d.centroids[:, 1] > d.centroids[:, 1].mean()).astype(np.int64) if kind == "tets" else None
    counts = rt.level_counts(m.n_cells, 4, coarsest=3)

    def build():
        graphs = []
        levels = rt.rtree_levels(batch, counts, groups=groups, boxes=boxes, graphs=graphs)
        return levels, graphs

    (la, ga), (lb, gb) = _both(monkeypatch, build)
    assert all(np.array_equal(a, b) for a, b in zip(la, lb, strict=True))
    for (pa, ia), (pb, ib) in zip(ga, gb, strict=True):
        assert np.array_equal(pa, pb) and np.array_equal(ia, ib)
    g, _ = prepare(m)
    assert [pieces(g, lab) for lab in la] == [int(lab.max()) + 1 for lab in la]


def test_pieces_numbered_like_scipy(monkeypatch, brain):
    """Connected pieces of scattered labels (many pieces per part): the same count and numbering (by
    first cell) as scipy's connected_components, over all cells and over a subset of whole parts."""
    m, g, d = brain
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 40, m.n_cells)
    labels[d.centroids[:, 0] > np.median(d.centroids[:, 0])] = 40  # one big part too
    cells = np.flatnonzero(np.isin(labels, [3, 17, 40]))

    def run():
        return rt._label_pieces(g.indptr, g.indices, labels), rt._label_pieces(
            g.indptr, g.indices, labels, cells
        )

    ((na, ca), (nsa, csa)), ((nb, cb), (nsb, csb)) = _both(monkeypatch, run)
    assert na == nb == pieces(g, labels) and np.array_equal(ca, cb)
    assert nsa == nsb and np.array_equal(csa, csb)
    assert ca.max() + 1 == na and np.all(np.diff(np.maximum.accumulate(ca)) <= 1)  # numbered by first cell


def test_components_of_a_disconnected_graph(monkeypatch):
    """Two separate blocks of cells, and groups that cut one of them: the numbering of the twin."""
    p, t = tets(5)
    p2 = p + np.array([3.0, 0, 0])
    m = mesh_from_arrays(np.vstack([p, p2]), [("tetra", np.vstack([t, t + len(p)]))])
    _, d = prepare(m)
    batch = make_batch(d, np.zeros(m.n_cells, dtype=np.int64))
    within = (d.centroids[:, 1] > 0.5).astype(np.int64)
    (a, aw), (b, bw) = _both(monkeypatch, lambda: (rt.components(batch), rt.components(batch, within)))
    assert np.array_equal(a, b) and np.array_equal(aw, bw)
    assert a.max() == 1 and aw.max() == 3


def test_quotient_same_graph(monkeypatch, brain):
    m, g, d = brain
    labels = rt.split_counts(np.zeros(m.n_cells, dtype=np.int64), np.array([300]), d.centroids, d.measures)
    (pa, ia, wa), (pb, ib, wb) = _both(
        monkeypatch, lambda: rt._quotient(g.indptr, g.indices, g.weights, labels, 300)
    )
    assert np.array_equal(pa, pb) and np.array_equal(ia, ib) and np.array_equal(wa, wb)
    assert pa.size == 301 and np.all(ia != np.repeat(np.arange(300), np.diff(pa)))  # no self loops


def test_bad_buffers_are_refused():
    ext = rt._compiled()
    z8, zi = np.zeros(4), np.zeros(4, dtype=np.int64)
    with pytest.raises(TypeError):  # a missing array
        ext.pieces(zi, zi, zi, zi[:0])
    with pytest.raises(TypeError):  # 4-byte items where 8-byte ones are expected
        ext.pieces(np.zeros(5, dtype=np.int32), zi, zi, zi[:0], np.zeros(4, dtype=np.int32))
    with pytest.raises(ValueError):  # indptr of the wrong length
        ext.pieces(np.zeros(3, dtype=np.int64), zi, zi, zi[:0], np.zeros(4, dtype=np.int32))
    with pytest.raises(ValueError):  # a part range outside the orders
        ext.cut_prepare(np.arange(4), z8, z8, np.array([3]), np.array([2]), zi, z8, zi, z8, z8, z8)
    with pytest.raises(ValueError):  # a neighbour index outside the graph
        ext.cross_edges(
            np.array([0, 1]),
            np.array([5]),
            np.zeros(1),
            np.zeros(1, dtype=np.int64),
            np.zeros(1, dtype=np.int32),
            np.zeros(1, dtype=np.int32),
            np.zeros(1),
        )


@pytest.mark.parametrize("case", ["kway", "holes", "pinched"])
def test_merge_2d_loops_same_polygons(monkeypatch, brain, case):
    """merge_2d's boundary loops from the compiled hash-and-walk equal _pair_edges + _list_rank:
    connected elements; elements with holes (a ring of cells around others); random labels, whose
    elements touch themselves at vertices (the compiled pass declines, numpy decides)."""
    import models.polytope.merge as M

    m, g, d = brain
    batch = make_batch(d, np.zeros(m.n_cells, dtype=np.int64))
    labels = rt.rtree_levels(batch, [200])[0]  # connected elements
    if case == "holes":  # the elements around a middle one (sharing a vertex with it) merged: a ring
        c = labels[np.argmin(np.linalg.norm(d.centroids - d.centroids.mean(axis=0), axis=1))]
        owner = np.repeat(np.arange(m.n_cells), np.diff(m.offsets))  # the cell of every vertex slot
        verts = np.unique(m.connectivity[labels[owner] == c])
        around = np.unique(labels[owner[np.isin(m.connectivity, verts)]])
        ring = np.isin(labels, around[around != c])
        labels = labels.copy()
        labels[ring] = around[around != c].min()
        labels = np.unique(labels, return_inverse=True)[1]
    elif case == "pinched":
        labels = np.random.default_rng(3).integers(0, 40, m.n_cells)
    f = g.faces
    bf = M.boundary_faces(g, labels)
    key = labels[f.cell[bf]] * np.int64(m.n_points)
    start, end = key + f.nodes[2 * bf], key + f.nodes[2 * bf + 1]
    loops = M._compiled_loops(start, end)
    if case == "pinched":
        assert loops is None  # a repeated start key: the search with the turning rule decides
    else:
        nxt, cyc, pos = loops
        ref = M._pair_edges(start, end)
        rc, rp = M._list_rank(ref)
        assert np.array_equal(nxt, ref) and np.array_equal(cyc, rc) and np.array_equal(pos, rp)
    (pa, ha), (pb, hb) = _both(monkeypatch, lambda: M.merge_2d(m, g, labels, d.measures))
    for name in ("elem_offsets", "loop_offsets", "loop_nodes", "measure", "n_fine", "labels"):
        assert np.array_equal(getattr(pa, name), getattr(pb, name)), name
    assert np.array_equal(ha.elements, hb.elements) and np.array_equal(ha.centers, hb.centers)
    if case == "holes":
        assert ha.elements.size > 0


def test_loops_decline_what_numpy_must_judge():
    ext = rt._compiled()
    out = [np.empty(4, dtype=np.int64) for _ in range(3)]
    ks = np.array([5, 7, 9, 11])
    assert ext.loops(ks, np.array([7, 5, 11, 9]), *out) == 2  # two loops of two edges
    assert np.array_equal(out[1], [0, 0, 1, 1]) and np.array_equal(out[2], [0, 1, 0, 1])
    assert ext.loops(ks, np.array([7, 5, 11, 12]), *out) == -1  # open: 12 starts no edge
    assert ext.loops(np.array([5, 5, 9, 11]), np.array([7, 5, 11, 9]), *out) == -1  # a repeated start
    assert ext.loops(ks, np.array([7, 7, 11, 9]), *out) == -1  # two edges into one
    with pytest.raises(ValueError):
        ext.loops(ks, ks[:3], *out)

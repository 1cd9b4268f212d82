"""Orientation by topology: folded cells are kept and reported, impossible orientations refused."""

from __future__ import annotations

import numpy as np
import pytest
from defects import folded_tet, write_folded_brain
from meshes import hexes

from models import pipeline
from models.errors import MeshError
from models.mesh.container import VTK_HEXAHEDRON
from models.mesh.geometry import FACE_TEMPLATES
from models.mesh.read import mesh_from_arrays, read_mesh


def _vtk_polygon_areas(path):
    """Total area of the polygons of a VTU, as loaded by VTK's own reader (shoelace in 3D)."""
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(path))
    r.Update()
    g = r.GetOutput()
    pts = vtk_to_numpy(g.GetPoints().GetData())
    offsets = vtk_to_numpy(g.GetCells().GetOffsetsArray())
    conn = vtk_to_numpy(g.GetCells().GetConnectivityArray())
    nxt = np.arange(1, conn.size + 1)
    nxt[offsets[1:] - 1] = offsets[:-1]
    cross = np.cross(pts[conn], pts[conn[nxt]])
    cell = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))
    return g.GetNumberOfCells(), 0.5 * np.bincount(cell, weights=cross[:, 2])


@pytest.fixture(scope="module")
def folded_brain(tmp_path_factory):
    path = tmp_path_factory.mktemp("fb") / "folded_brain.vtu"
    cell = write_folded_brain(str(path))
    return path, cell


def test_folded_sliver_is_kept_and_reported(folded_brain):
    path, cell = folded_brain
    m = read_mesh(path)
    o = m.meta["orientation"]
    assert o["folded"] == 1 and o["folded_cells"] == [cell]
    assert o["flipped"] > 1000  # the file mixes clockwise and counter-clockwise triangles
    assert m.meta["signed_measures"][cell] < 0
    assert np.count_nonzero(m.meta["signed_measures"] < 0) == 1


@pytest.mark.parametrize(
    "mode,kw",
    [
        ("kway", {"k": 40}),
        ("nref", {"nref": 5}),
        ("target-size", {"target_size": 40.0}),
        ("mult-factor", {"mult_factor": 0.1}),
        ("segregated", {"mult_factor": 0.1}),
        ("coarsen", {"k": 10}),
    ],
)
@pytest.mark.parametrize("model", ["metis", "kmeans"])
def test_folded_brain_agglomerates_in_every_mode(folded_brain, tmp_path, mode, kw, model):
    path, cell = folded_brain
    m = read_mesh(path)
    total = m.meta["signed_measures"].sum()
    if mode == "segregated":  # two physical groups: left and right half
        m.tags = (m.meta["centroids"][:, 0] > np.median(m.meta["centroids"][:, 0])).astype(np.int64) + 1
    if mode == "coarsen":
        kw = dict(kw, subset=np.flatnonzero(m.meta["centroids"][:, 1] > np.median(m.meta["centroids"][:, 1])))
    res = pipeline.run(m, model=model, mode=mode, compute_metrics=False, **kw)
    assert np.isclose(res.poly.measure.sum(), total, rtol=1e-9, atol=0)
    out = tmp_path / "out.vtu"
    pipeline.write_outputs(res, vtu=str(out))
    n, areas = _vtk_polygon_areas(out)
    assert n == res.poly.n_elements
    assert np.isclose(abs(areas.sum()), total, rtol=1e-9, atol=0)
    # the element holding the folded cell is a closed polygon of the right area
    e = res.agglomeration.labels[cell]
    assert np.isclose(abs(areas[e]), res.poly.measure[e], rtol=1e-9)


def test_folded_tetrahedron_agglomerates():
    p, t, cell = folded_tet()
    t = t.copy()
    t[::3] = t[::3][:, [0, 2, 1, 3]]  # mixed orientation in the input
    m = mesh_from_arrays(p, [("tetra", t)])
    assert m.meta["orientation"]["folded_cells"] == [cell]
    total = m.meta["signed_measures"].sum()
    assert np.isclose(total, 1.0, rtol=1e-12)
    for k in (2, 7, 30):
        res = pipeline.run(m, model="metis", mode="kway", k=k, compute_metrics=False)
        assert np.isclose(res.poly.measure.sum(), 1.0, rtol=1e-9)
        assert res.poly.n_elements >= k


def test_moebius_strip_is_refused_with_the_cells():
    n = 12
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    inner = np.column_stack([np.cos(ang), np.sin(ang)])
    outer = 2.3 * np.column_stack([np.cos(ang + 0.1), np.sin(ang + 0.1)])
    pts = np.vstack([inner, outer])
    i, o = np.arange(n), n + np.arange(n)
    q = np.column_stack([i[:-1], i[1:], o[1:], o[:-1]])
    twisted = np.array([[i[-1], o[0], i[0], o[-1]]])  # glued back with a half twist
    with pytest.raises(MeshError, match=r"not orientable.*cells \d"):
        mesh_from_arrays(pts, [("quad", np.vstack([q, twisted]))])


def test_a_polyhedron_face_turned_inside_out_is_reversed_back():
    p, h = hexes(2)
    cells = [[h[c, list(f)] for f in FACE_TEMPLATES[VTK_HEXAHEDRON]] for c in range(len(h))]
    ok = mesh_from_arrays(p, [("polyhedron", cells)])
    assert ok.meta["orientation"]["folded"] == 0 and ok.meta["orientation"]["flipped"] == 0
    inside_out = mesh_from_arrays(p, [("polyhedron", [[f[::-1] for f in c] for c in cells])])
    assert inside_out.meta["orientation"]["flipped"] == len(h)
    assert np.allclose(inside_out.meta["signed_measures"], 1 / 8)
    cells[3][2] = cells[3][2][::-1]  # one face of one cell turned inside out (as a file that
    # stores each face once, for both its cells, writes it): reversed back, said (before: refused)
    turned = mesh_from_arrays(p, [("polyhedron", cells)])
    assert turned.meta["reversed_faces"]["count"] == 1
    assert turned.meta["orientation"]["folded"] == 0 and np.allclose(turned.meta["signed_measures"], 1 / 8)


@pytest.mark.parametrize("n", [3, 6])
def test_faces_kept_by_reading_give_the_same_graph(n, monkeypatch):
    """Reading without the compiled validation (MAGNET_NO_COMPILED=1: the numpy path) keeps its
    faces and face pairing for the dual graph (one sort, not two); with cells flipped by the
    orientation they must equal the faces and graph built from scratch."""
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    from models.mesh.dual import cached_faces, dual_graph
    from models.mesh.geometry import cell_faces

    g = np.linspace(0, 1, n + 1)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    m1 = n + 1
    i, j, k = (a.ravel() for a in np.meshgrid(*(np.arange(n),) * 3, indexing="ij"))
    c0 = (i * m1 + j) * m1 + k
    d = [m1 * m1, m1, 1]
    tets = []
    for a, b in ((0, 1), (1, 0), (0, 2), (2, 0), (1, 2), (2, 1)):  # 6 tetrahedra along the diagonal
        p1 = c0 + d[a]
        tets.append(np.column_stack([c0, p1, p1 + d[b], c0 + sum(d)]))
    t = np.vstack(tets)
    rng = np.random.default_rng(n)
    t = t[rng.permutation(len(t))]
    sw = rng.random(len(t)) < 0.3
    t[sw] = t[sw][:, [1, 0, 2, 3]]
    mesh = mesh_from_arrays(pts, [("tetra", t)])
    assert mesh.meta["orientation"]["flipped"] > 0
    kept = cached_faces(mesh)
    assert kept is not None and kept["pairs"] is not None and kept["order"] is None
    fresh = cell_faces(mesh)
    for a in ("cell", "offsets", "nodes"):
        assert np.array_equal(getattr(kept["faces"], a), getattr(fresh, a))
    _assert_kept_pairs_are_fresh_pairs(mesh, kept, fresh)
    g1 = dual_graph(mesh)
    assert g1.faces is kept["faces"]
    assert "areas" not in kept and "pairs" not in kept  # the graph took them (areas: its per-face measures)
    g2 = dual_graph(mesh, fresh)
    g3 = dual_graph(mesh)  # the kept faces again: pairs sorted and areas measured anew
    for a in ("indptr", "indices", "weights", "partner"):
        assert np.array_equal(getattr(g1, a), getattr(g2, a)), a
        assert np.array_equal(getattr(g1, a), getattr(g3, a)), a
    assert g1.n_edges == 2 * 6 * n**3 - 6 * n * n  # every inner face once (4 faces per tetrahedron)
    # the all-tetrahedra CSR (built from partner) is scipy's canonical CSR of the shared faces
    import scipy.sparse as sp

    from models.mesh.geometry import face_measures

    f = np.flatnonzero(g1.partner >= 0)
    rows, cols = fresh.cell[f], fresh.cell[g1.partner[f]]
    a = sp.csr_matrix((face_measures(mesh.points, fresh, f), (rows, cols)), shape=(mesh.n_cells,) * 2)
    a.sum_duplicates()
    a.sort_indices()
    assert np.array_equal(g1.indptr, a.indptr) and np.array_equal(g1.indices, a.indices)
    assert np.array_equal(g1.weights, a.data)
    mesh.connectivity = mesh.connectivity.copy()  # another connectivity: the kept faces are not used
    assert cached_faces(mesh) is None


def _assert_kept_pairs_are_fresh_pairs(mesh, kept, fresh):
    """The face pairs reading kept (renumbered for cells flipped after the pairing) are the pairs
    of a fresh stable sort of the fresh faces' keys."""
    from models.mesh.dual import face_keys, sort_keys

    order, same = sort_keys(face_keys(fresh, mesh.n_points))
    i = np.flatnonzero(same)
    fa, fb = kept["pairs"]
    assert np.array_equal(fa, order[i]) and np.array_equal(fb, order[i + 1])


def test_faces_kept_by_reading_of_a_folded_tetrahedron_give_the_same_graph():
    """A folded tetrahedron is flipped again after the faces were paired: its faces and their ids
    in the kept pairs are renumbered; the graph must be the one built from fresh faces."""
    from models.mesh.dual import cached_faces, dual_graph
    from models.mesh.geometry import cell_faces

    p, t, cell = folded_tet()
    t = t.copy()
    t[::3] = t[::3][:, [0, 2, 1, 3]]  # mixed orientation in the input
    mesh = mesh_from_arrays(p, [("tetra", t)])
    assert mesh.meta["orientation"]["folded_cells"] == [cell]
    kept = cached_faces(mesh)
    assert kept is not None and kept["pairs"] is not None
    fresh = cell_faces(mesh)
    for a in ("cell", "offsets", "nodes"):
        assert np.array_equal(getattr(kept["faces"], a), getattr(fresh, a))
    _assert_kept_pairs_are_fresh_pairs(mesh, kept, fresh)
    g1, g2 = dual_graph(mesh), dual_graph(mesh, fresh)
    for a in ("indptr", "indices", "weights", "partner"):
        assert np.array_equal(getattr(g1, a), getattr(g2, a)), a


def test_face_areas_kept_by_reading_are_face_measures_bit_for_bit(monkeypatch):
    """All tetrahedra, the numpy path (MAGNET_NO_COMPILED=1): reading computes every face's area with
    the volumes (one gather of the corners); with generic coordinates and mirrored cells they must
    be face_measures' values exactly, and the graph built from them the graph built from fresh faces."""
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    from models.mesh.dual import cached_faces, dual_graph
    from models.mesh.geometry import cell_faces, face_measures

    n = 5
    g = np.linspace(0, 1, n + 1)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    rng = np.random.default_rng(7)
    pts = np.column_stack([x.ravel(), y.ravel(), z.ravel()]) + rng.normal(scale=0.02, size=((n + 1) ** 3, 3))
    pts = pts * 3.7 + 1e3  # far from the origin: rounding differs between node orders
    m1 = n + 1
    i, j, k = (a.ravel() for a in np.meshgrid(*(np.arange(n),) * 3, indexing="ij"))
    c0 = (i * m1 + j) * m1 + k
    d = [m1 * m1, m1, 1]
    t = np.vstack(
        [
            np.column_stack([c0, c0 + d[a], c0 + d[a] + d[b], c0 + sum(d)])
            for a, b in ((0, 1), (1, 0), (0, 2), (2, 0), (1, 2), (2, 1))
        ]
    )
    t = t[rng.permutation(len(t))]
    for perm in ([1, 0, 2, 3], [2, 3, 0, 1], [3, 1, 0, 2]):  # rotate / mirror some cells' node order
        sw = rng.random(len(t)) < 0.3
        t[sw] = t[sw][:, perm]
    mesh = mesh_from_arrays(pts, [("tetra", t)])
    assert mesh.meta["orientation"]["flipped"] > 0
    kept = cached_faces(mesh)
    fresh = cell_faces(mesh)
    assert np.array_equal(kept["areas"], face_measures(mesh.points, fresh))
    g1, g2 = dual_graph(mesh), dual_graph(mesh, fresh)
    for a in ("indptr", "indices", "weights", "partner"):
        assert np.array_equal(getattr(g1, a), getattr(g2, a)), a
    # the reference: a stable sort of the keys, each shared face measured on its lower face id (the
    # pairing sorts without stability and orders each pair itself: the same pairs, the same bits)
    import scipy.sparse as sp

    from models.mesh.dual import face_keys

    keys = face_keys(fresh, mesh.n_points)
    order = np.argsort(keys, kind="stable")
    i = np.flatnonzero(keys[order][1:] == keys[order][:-1])
    fa, fb = order[i], order[i + 1]
    assert np.all(fa < fb)
    fm = face_measures(mesh.points, fresh, fa)
    assert not np.array_equal(fm, face_measures(mesh.points, fresh, fb))  # the sides differ by bits
    ca, cb = fresh.cell[fa], fresh.cell[fb]
    ref = sp.csr_matrix((np.r_[fm, fm], (np.r_[ca, cb], np.r_[cb, ca])), shape=(mesh.n_cells,) * 2)
    ref.sort_indices()
    assert np.array_equal(g1.indptr, ref.indptr) and np.array_equal(g1.indices, ref.indices)
    assert np.array_equal(g1.weights, ref.data)


@pytest.mark.parametrize("n", [3, 6])
def test_compiled_validation_defers_the_faces_and_gives_the_same_mesh_and_graph(n, monkeypatch):
    """With models/mesh/_fastmesh.c, reading all tetrahedra (cells mirrored in the input) keeps no
    faces: the dual graph builds them. Mesh, orientation record and graph are those of the numpy
    path, which keeps its faces."""
    from models.mesh.dual import cached_faces, dual_graph
    from models.native import compiled

    assert compiled("mesh._fastmesh") is not None
    g = np.linspace(0, 1, n + 1)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    rng = np.random.default_rng(n)
    pts = np.column_stack([x.ravel(), y.ravel(), z.ravel()]) + rng.normal(scale=0.02, size=((n + 1) ** 3, 3))
    m1 = n + 1
    i, j, k = (a.ravel() for a in np.meshgrid(*(np.arange(n),) * 3, indexing="ij"))
    c0 = (i * m1 + j) * m1 + k
    d = [m1 * m1, m1, 1]
    t = np.vstack(
        [
            np.column_stack([c0, c0 + d[a], c0 + d[a] + d[b], c0 + sum(d)])
            for a, b in ((0, 1), (1, 0), (0, 2), (2, 0), (1, 2), (2, 1))
        ]
    )
    sw = rng.random(len(t)) < 0.3
    t[sw] = t[sw][:, [1, 0, 2, 3]]
    fast = mesh_from_arrays(pts, [("tetra", t)])
    assert cached_faces(fast) is None and fast.meta["orientation"]["flipped"] > 0
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    ref = mesh_from_arrays(pts, [("tetra", t)])
    assert cached_faces(ref) is not None
    assert np.array_equal(fast.connectivity, ref.connectivity)
    for key in ("measures", "centroids", "signed_measures"):
        assert np.array_equal(fast.meta[key], ref.meta[key]), key
    assert fast.meta["orientation"] == ref.meta["orientation"]
    g1, g2 = dual_graph(fast), dual_graph(ref)
    for a in ("indptr", "indices", "weights", "partner"):
        assert np.array_equal(getattr(g1, a), getattr(g2, a)), a

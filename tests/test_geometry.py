"""Closed-form fast paths of models.mesh.geometry against the general face-based formulas."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from models.mesh import geometry
from models.mesh.container import VTK_TETRA, Mesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import structured  # noqa: E402


def _tet_mesh(n: int = 4, flip_every: int = 3) -> Mesh:
    p, t = structured.cube(n)
    rng = np.random.default_rng(0)
    p = p + rng.normal(0, 0.02, p.shape)  # irregular tetrahedra
    t = t.copy()
    t[::flip_every] = t[::flip_every][:, [1, 0, 2, 3]]  # some negatively oriented
    return Mesh(
        points=p,
        offsets=np.arange(0, 4 * len(t) + 1, 4),
        connectivity=t.ravel(),
        cell_types=np.full(len(t), VTK_TETRA, dtype=np.uint8),
    )


def test_tetra_measures_equal_face_formula(monkeypatch):
    mesh = _tet_mesh()
    assert geometry._all_tetrahedra(mesh)
    vol, cen = geometry._measures_and_centroids(mesh)
    monkeypatch.setattr(geometry, "_all_tetrahedra", lambda m: False)  # the general path
    vol2, cen2 = geometry._measures_and_centroids(mesh)
    assert np.allclose(vol, vol2, rtol=1e-12, atol=1e-15)
    assert np.allclose(cen, cen2, rtol=1e-10, atol=1e-12)
    assert (vol < 0).any() and (vol > 0).any()


def test_face_measures_of_triangles_equal_fan_formula():
    mesh = _tet_mesh(3)
    faces = geometry.cell_faces(mesh)
    fast = geometry.face_measures(mesh.points, faces)
    owner, tri = geometry.fan_triangles(faces.offsets, faces.nodes)
    p = mesh.points
    ref = 0.5 * np.linalg.norm(np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]), axis=1)
    assert np.allclose(fast, np.bincount(owner, weights=ref), rtol=1e-12)
    which = np.array([5, 0, 17])
    assert np.allclose(geometry.face_measures(mesh.points, faces, which), fast[which], rtol=1e-12)


def test_cross_matches_numpy():
    rng = np.random.default_rng(1)
    u, v = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    assert np.allclose(geometry._cross(u, v), np.cross(u, v), rtol=1e-14, atol=1e-14)


def test_tetra_faces_keys_and_directions_equal_general_path(monkeypatch):
    """The all-tetrahedra / all-triangle fast paths of cell_faces, face_keys and the orientation
    bit give what the general (padded) code gives."""
    from models.mesh import orientation
    from models.mesh.dual import face_keys

    mesh = _tet_mesh(3)
    fast = geometry.cell_faces(mesh)
    keys = face_keys(fast, mesh.n_points)
    bits = orientation._face_direction(fast)
    monkeypatch.setattr(geometry, "_all_tetrahedra", lambda m: False)
    slow = geometry.cell_faces(mesh)
    assert np.array_equal(fast.cell, slow.cell) and np.array_equal(fast.offsets, slow.offsets)
    assert np.array_equal(fast.nodes, slow.nodes)
    # the general code on faces padded with one quad (so that the fast path does not apply)
    nodes = np.r_[slow.nodes, [0, 1, 2, 3]]
    offsets = np.r_[slow.offsets, slow.offsets[-1] + 4]
    mixed = geometry.Faces(cell=np.r_[slow.cell, 0], offsets=offsets, nodes=nodes)
    assert np.array_equal(face_keys(mixed, mesh.n_points)[:-1], keys)
    assert np.array_equal(orientation._face_direction(mixed)[:-1], bits)


def test_triangle_rotation_matches_padded_argmin():
    from models.mesh import orientation

    rng = np.random.default_rng(2)
    t = np.array([rng.permutation(50)[:3] for _ in range(300)])
    m, nxt, prv = orientation._triangle_rotation(t)
    j = t.argmin(axis=1)
    r = np.arange(len(t))
    assert (
        np.array_equal(m, t[r, j])
        and np.array_equal(nxt, t[r, (j + 1) % 3])
        and np.array_equal(prv, t[r, (j - 1) % 3])
    )


def test_direct_csr_and_2d_edges_equal_the_general_paths(monkeypatch):
    """Triangles, quads and tetrahedra in random order with jittered points: the dual graph's direct
    CSR (a sorting network per row) equals scipy's COO->CSR of the shared faces, and 2D edges of
    one-size cells equal the general next-in-cycle edges, bit for bit."""
    from meshes import quads, tets, triangles

    from models.mesh import dual as graph
    from models.mesh.read import mesh_from_arrays

    rng = np.random.default_rng(11)
    for kind, (p, c) in (("triangle", triangles(9, 7)), ("quad", quads(8, 9)), ("tetra", tets(4))):
        p = np.asarray(p, dtype=np.float64)
        p = p + rng.normal(scale=0.01, size=p.shape)
        c = np.asarray(c)[rng.permutation(len(c))]
        mesh = mesh_from_arrays(p, [(kind, c)])
        fast = graph.dual_graph(mesh, geometry.cell_faces(mesh))
        if mesh.dim == 2:
            n, k = mesh.n_cells, c.shape[1]
            nxt = geometry.next_in_cycle(mesh.offsets)
            assert np.array_equal(
                fast.faces.nodes, np.column_stack([mesh.connectivity, mesh.connectivity[nxt]]).ravel()
            )
            assert (
                np.array_equal(fast.faces.cell, geometry.cell_index(mesh.offsets)) and fast.faces.n == n * k
            )
        with monkeypatch.context() as mp:
            mp.setattr(graph, "_fixed_layout", lambda faces, n: False)
            slow = graph.dual_graph(mesh, geometry.cell_faces(mesh))
        for a in ("indptr", "indices", "weights", "partner"):
            assert np.array_equal(getattr(fast, a), getattr(slow, a)), (kind, a)
            assert getattr(fast, a).dtype == getattr(slow, a).dtype
        assert fast.n_edges > 0

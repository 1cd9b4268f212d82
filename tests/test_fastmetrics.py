"""The compiled inscribed-ball searches (models/quality/_fastmetrics.c in 3D, _fastcircle.c in 2D)
against closed forms, against the numpy search they replace (both certified to rel_tol x diameter),
and their fallbacks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_metrics import (
    R_L,
    SQ2,
    cube,
    inside_even_odd,
    l_prism,
    point_tri_dist,
    poly2d,
    poly3d,
    seg_dist,
    tetra,
)

import models.quality.inscribed as _inscribed_module
from models.quality.distance import _inside_bruteforce
from models.quality.geometry import _compiled, _enclosing_balls, _prepare
from models.quality.inscribed import _inscribed, largest_inscribed_ball
from models.quality.shape import element_diameters


def test_the_compiled_search_is_built():
    """setup.py builds it with every install; metrics would still work without it, only slower."""
    assert _compiled() is not None, (
        "models/quality/_fastmetrics.c was not compiled: reinstall (pip install -e .)"
    )
    assert hasattr(_compiled(), "inscribed2d"), "_fastmetrics was built without _fastcircle.c"


@pytest.mark.parametrize("method", ["bnb", "bnb-numpy"])
@pytest.mark.parametrize("rel_tol", [1e-3, 1e-5])
def test_closed_forms(method, rel_tol):
    """Cube (r = 1/2), regular tetrahedron (r = sqrt(3)/3), the L prism (two walls and the reflex
    edge: r = 2 - sqrt(2)), the L prism with its faces reversed, and a cube scaled by 1e-6 and
    moved far from the origin; every radius within rel_tol x diameter below the true one."""
    v, f = l_prism(1.5)
    vc, fc = cube(1e-6)
    pm = poly3d(
        [cube(), tetra(), (v, f), (v, [x[::-1] for x in f]), (vc + 1e3, fc)],
        offsets=[(0, 0, 0), (5, 0, 0), (10, 0, 0), (15, 0, 0), (0, 0, 0)],
    )
    _, r = largest_inscribed_ball(pm, rel_tol=rel_tol, method=method)
    true = np.array([0.5, math.sqrt(3) / 3, R_L, R_L, 0.5e-6])
    eps = rel_tol * element_diameters(pm)
    assert np.all(r <= true * (1 + 1e-12))
    assert np.all(r >= true - eps - 1e-15)
    assert element_diameters(pm)[1] == pytest.approx(2 * SQ2)


def _jagged(n=8, seed=0, parts=12):
    """Agglomerates of a tetrahedral cube with staircase (reflex) boundaries: random seeds, each
    fine cell to its nearest seed under a wavy metric."""
    from meshes import tets

    from models.mesh.read import mesh_from_arrays
    from models.pipeline import prepare
    from models.polytope.merge import merge

    p, t = tets(n)
    m = mesh_from_arrays(p, [("tetra", t)])
    g, d = prepare(m)
    c = p[t].mean(axis=1)
    rng = np.random.default_rng(seed)
    seeds = rng.random((parts, 3))
    w = c + 0.08 * np.sin(9 * c[:, [1, 2, 0]])
    labels = np.argmin(((w[:, None, :] - seeds[None]) ** 2).sum(-1), axis=1)
    labels = np.unique(labels, return_inverse=True)[1]
    poly, _ = merge(m, g, labels, d.measures)
    return poly


def _certify(poly, centres, radii):
    """Each centre is inside its element (winding number) and its exact distance to the element's
    boundary triangles is the radius."""
    g = _prepare(poly)
    for e in range(g.n):
        tri = g.prim[g.prim_ptr[e] : g.prim_ptr[e + 1]]
        x = centres[e]
        assert np.isfinite(x).all()
        assert point_tri_dist(x[None], tri).min() == pytest.approx(radii[e], rel=1e-9, abs=1e-15)
    assert _inside_bruteforce(g, centres, np.arange(g.n)).all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_and_numpy_searches_agree_on_jagged_agglomerates(seed):
    poly = _jagged(seed=seed)
    eps = 1e-3 * element_diameters(poly)
    c1, r1 = largest_inscribed_ball(poly, method="bnb")
    c2, r2 = largest_inscribed_ball(poly, method="bnb-numpy")
    assert np.all(r1 > 0)
    # both certified: each within eps below the true radius, hence within eps of each other
    assert np.all(np.abs(r1 - r2) <= eps + 1e-12)
    _certify(poly, c1, r1)
    # a tighter tolerance only raises a radius, and by less than the looser eps
    _, r3 = largest_inscribed_ball(poly, rel_tol=1e-5, method="bnb")
    assert np.all(r3 >= r1 - 1e-5 * element_diameters(poly) - 1e-12)
    assert np.all(r3 <= r1 + eps + 1e-12)


def test_cell_budget_hands_elements_to_the_numpy_search(monkeypatch):
    """An element whose compiled search runs out of cells is searched again by numpy: same
    guarantee."""
    poly = _jagged(seed=3)
    _, ref = largest_inscribed_ball(poly, method="bnb")
    monkeypatch.setattr(_inscribed_module, "_EXT_MAX_CELLS", 1)
    c, r = largest_inscribed_ball(poly, method="bnb")
    eps = 1e-3 * element_diameters(poly)
    assert np.all(np.abs(r - ref) <= eps + 1e-12)
    _certify(poly, c, r)


def test_without_the_compiled_module(monkeypatch):
    """MAGNET_NO_COMPILED=1 (or a failed build): the numpy search, same guarantee."""
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    assert _compiled() is None
    poly = _jagged(seed=4)
    c, r = largest_inscribed_ball(poly)
    monkeypatch.delenv("MAGNET_NO_COMPILED")
    _, ref = largest_inscribed_ball(poly)
    assert np.all(np.abs(r - ref) <= 1e-3 * element_diameters(poly) + 1e-12)


def _jagged_2d(n=40, seed=0, parts=25):
    """Agglomerates of a triangulated square with four holes cut out of it (cells whose centroid
    lies in a disc dropped): staircase (reflex) boundaries, and elements with a hole of their own
    (each fine cell to its nearest seed under a wavy metric; no hole policy applied)."""
    from meshes import triangles

    from models.mesh.read import mesh_from_arrays
    from models.pipeline import prepare
    from models.polytope.merge import merge

    p, t = triangles(n)
    c = p[t].mean(axis=1)
    holes = np.array([[0.3, 0.3], [0.7, 0.3], [0.3, 0.7], [0.7, 0.72]])
    t = t[(((c[:, None, :] - holes[None]) ** 2).sum(-1) > 0.09**2).all(axis=1)]
    m = mesh_from_arrays(p, [("triangle", t)])
    g, d = prepare(m)
    c = d.centroids[:, :2]
    rng = np.random.default_rng(seed)
    seeds = rng.random((parts, 2))
    w = c + 0.05 * np.sin(11 * c[:, [1, 0]])
    labels = np.argmin(((w[:, None, :] - seeds[None]) ** 2).sum(-1), axis=1)
    labels = np.unique(labels, return_inverse=True)[1]
    poly, _ = merge(m, g, labels, d.measures)
    return poly


def _certify_2d(poly, centres, radii):
    """Each centre is inside its element (even-odd over all its loops, so not in a hole) and its
    exact distance to the element's boundary segments is the radius."""
    g = _prepare(poly)
    for e in range(g.n):
        s = g.prim[g.prim_ptr[e] : g.prim_ptr[e + 1]]
        a, b = s[:, 0], s[:, 1]
        x = centres[e][None]
        assert np.isfinite(x).all()
        assert seg_dist(x, a, b)[0] == pytest.approx(radii[e], rel=1e-9, abs=1e-15)
        assert inside_even_odd(x, a, b)[0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_2d_compiled_and_numpy_searches_agree_on_jagged_agglomerates(seed):
    poly = _jagged_2d(seed=seed)
    g = _prepare(poly)
    assert (g.n_loops > 1).any()  # elements with a hole are searched too
    eps = 1e-3 * element_diameters(poly)
    c1, r1 = largest_inscribed_ball(poly, method="bnb")
    c2, r2 = largest_inscribed_ball(poly, method="bnb-numpy")
    assert np.all(r1 > 0)
    assert np.all(np.abs(r1 - r2) <= eps + 1e-12)
    _certify_2d(poly, c1, r1)
    # against a fine grid of interior points: the true radius is at least the grid's best
    for e in range(0, g.n, 5):
        s = g.prim[g.prim_ptr[e] : g.prim_ptr[e + 1]]
        lo, hi = g.bbox_lo[e], g.bbox_hi[e]
        h = 2e-3
        xs, ys = np.meshgrid(np.arange(lo[0], hi[0], h), np.arange(lo[1], hi[1], h))
        x = np.column_stack([xs.ravel(), ys.ravel()])
        x = x[inside_even_odd(x, s[:, 0], s[:, 1])]
        grid = seg_dist(x, s[:, 0], s[:, 1]).max()
        assert grid - eps[e] - 1e-12 <= r1[e] <= grid + h / SQ2 + 1e-12


def test_2d_channel_between_parallel_walls_is_cheap():
    """A 1 x 40 channel with a notch (so not convex): the pairs of walls bound the ridge, so the
    search does not refine every cell along it (the Lipschitz bound alone keeps ~40 / eps of them)."""
    a = 40.0
    outline = np.array([[0, 0], [a, 0], [a, 1], [a / 2 + 0.1, 1], [a / 2, 0.9], [a / 2 - 0.1, 1], [0, 1]])
    pm = poly2d([[outline]])
    g = _prepare(pm)
    c, r, ev = np.full((1, 2), np.nan), np.zeros(1), np.zeros(1, dtype=np.int64)
    _compiled().inscribed2d(
        g.prim, g.prim_ptr, np.array([0]), g.diameter, g.bbox_lo, g.bbox_hi, 1e-5, 10**6, c, r, ev
    )
    assert 0.5 - 1e-5 * g.diameter[0] <= r[0] <= 0.5
    assert ev[0] < 5000


def test_2d_cell_budget_hands_elements_to_the_numpy_search(monkeypatch):
    poly = _jagged_2d(seed=3)
    _, ref = largest_inscribed_ball(poly, method="bnb")
    monkeypatch.setattr(_inscribed_module, "_EXT_MAX_CELLS", 1)
    c, r = largest_inscribed_ball(poly, method="bnb")
    assert np.all(np.abs(r - ref) <= 1e-3 * element_diameters(poly) + 1e-12)
    _certify_2d(poly, c, r)


def test_bad_buffers_are_refused():
    ext = _compiled()
    z = np.zeros(1)
    with pytest.raises(TypeError):
        ext.inscribed(*([np.zeros(3, dtype=np.int32)] * 8), 1e-3, 10, z, z, z)
    with pytest.raises(TypeError):
        ext.inscribed2d(*([np.zeros(3, dtype=np.int32)] * 6), 1e-3, 10, z, z, z)


def _two_cubes(shift):
    v1, f1 = cube()
    v2, f2 = cube()
    v = np.vstack([v1, v2 + np.asarray(shift, float)])
    return v, f1 + [[k + 8 for k in f] for f in f2]


def test_hull_free_geometry_matches_qhull(monkeypatch):
    """The compiled path skips Qhull: the farthest pair (the diameter) by brute force and convexity
    from the edges (closed, locally convex, V - E + F = 2). Same diameters and the same convex
    elements as the hulls give: cube, tetrahedron and a cube made of 48 fine tetrahedra (flat
    faces of many triangles) are convex; the L prism, two cubes sharing an edge (non-manifold)
    or a vertex (pinched: locally convex everywhere, but not a sphere) and jagged agglomerates
    are not."""
    from meshes import tets

    from models.mesh.read import mesh_from_arrays
    from models.pipeline import prepare
    from models.polytope.merge import merge

    p, t = tets(2)
    m = mesh_from_arrays(p, [("tetra", t)])
    g, d = prepare(m)
    one, _ = merge(m, g, np.zeros(len(t), dtype=np.int64), d.measures)

    def faces_of(pm, e):
        lo = pm.loop_offsets
        return [
            list(pm.loop_nodes[lo[k] : lo[k + 1]]) for k in range(pm.elem_offsets[e], pm.elem_offsets[e + 1])
        ]

    v1, faces = one.points, faces_of(one, 0)  # the 48-tet cube as one polyhedron (faces as merged)
    jag = _jagged(n=5, seed=5, parts=6)
    jag_elems = [(jag.points, faces_of(jag, e)) for e in range(jag.elem_offsets.size - 1)]
    pm = poly3d(
        [cube(), tetra(), (v1, faces), l_prism(1.5), _two_cubes((1, 1, 0)), _two_cubes((1, 1, 1))]
        + jag_elems,
        offsets=[(3 * i, 0, 0) for i in range(6 + len(jag_elems))],
    )
    g1 = _prepare(pm)
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    g0 = _prepare(pm)
    assert np.array_equal(g1.convex, g0.convex)
    assert list(g1.convex[:6]) == [True, True, True, False, False, False]
    assert not g1.convex[6:].any()
    np.testing.assert_allclose(g1.diameter, g0.diameter, rtol=1e-15)
    for e in range(g1.n):
        assert np.linalg.norm(g1.hull_pts[e][0] - g1.hull_pts[e][1]) == pytest.approx(
            g1.diameter[e], rel=1e-15
        )
    # the enclosing balls from all boundary vertices equal those from the hull vertices
    np.testing.assert_allclose(
        _enclosing_balls(g1.hull_pts, 3)[1], _enclosing_balls(g0.hull_pts, 3)[1], rtol=1e-12
    )
    # convex elements keep their exact Chebyshev centres (LP over the triangle planes)
    _, r1 = _inscribed(g1, 1e-3)
    _, r0 = _inscribed(g0, 1e-3)
    np.testing.assert_allclose(r1[:3], [0.5, math.sqrt(3) / 3, 0.5], rtol=1e-9)
    np.testing.assert_allclose(r1[:3], r0[:3], rtol=1e-9)


def test_compiled_geometry_tables_match_numpy(monkeypatch):
    """Triangle constants, neighbours across edges (including non-manifold and inconsistently
    oriented edges: -1) and bounding balls from the compiled pass equal numpy's."""
    v, f = _two_cubes((1, 1, 0))
    vf, ff = l_prism(1.5)
    flipped = [ff[0][::-1]] + ff[1:]  # one face against the others: its edges get -1
    pm = poly3d([(v, f), (vf, flipped), tetra()] + [(p, q) for p, q in [l_prism(0.7)]])
    g1 = _prepare(pm)
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    g0 = _prepare(pm)
    np.testing.assert_array_equal(g1.prim, g0.prim)
    np.testing.assert_array_equal(g1.tri_adj, g0.tri_adj)
    assert (g1.tri_adj < 0).any() and (g1.tri_adj >= 0).any()
    np.testing.assert_allclose(g1.table, g0.table, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(g1.cen, g0.cen, rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(g1.rad, g0.rad, rtol=1e-13)
    # the jagged agglomerates (some edges non-manifold): the same neighbours
    poly = _jagged(seed=6)
    a = _prepare(poly).tri_adj
    monkeypatch.delenv("MAGNET_NO_COMPILED")
    b = _prepare(poly).tri_adj
    np.testing.assert_array_equal(a, b)


def test_empty_and_degenerate_3d_elements():
    """No triangles at all, and a flat element (two faces back to back, zero volume): no crash,
    radius 0 and no centre in both searches (it has no interior)."""
    from models.mesh.container import PolyMesh

    empty = PolyMesh(
        points=np.zeros((0, 3)),
        elem_offsets=np.array([0]),
        loop_offsets=np.array([0]),
        loop_nodes=np.zeros(0, dtype=np.int64),
        measure=np.zeros(0),
        n_fine=np.zeros(0, int),
        labels=np.zeros(0, int),
    )
    c, r = largest_inscribed_ball(empty)
    assert c.shape == (0, 3) and r.shape == (0,)
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    flat = poly3d([(sq, [[0, 1, 2, 3], [3, 2, 1, 0]])])
    for method in ("auto", "bnb", "bnb-numpy"):
        c, r = largest_inscribed_ball(flat, method=method)
        assert r[0] == 0.0 and np.isnan(c[0]).all()


def test_certified_centres_on_a_larger_mesh():
    """Deeper searches (about 700 tetrahedra per element): every centre is inside with its exact
    distance as the radius, and no radius is above the true one, which a tighter search bounds
    from below."""
    poly = _jagged(n=14, seed=7, parts=24)
    c, r = largest_inscribed_ball(poly, method="bnb")
    _certify(poly, c, r)
    _, fine = largest_inscribed_ball(poly, rel_tol=1e-6, method="bnb")
    diam = element_diameters(poly)
    assert np.all(r <= fine + 1e-6 * diam + 1e-12)  # r <= r_true <= fine + 1e-6 diam
    assert np.all(r >= fine - 1e-3 * diam - 1e-12)  # r >= r_true - eps >= fine - eps


def test_compiled_enclosing_balls_match_numpy():
    """The compiled pivoting gives numpy's exact enclosing balls: random clouds, co-spherical and
    co-planar points (a cube's corners, a flat grid), one and two points, and the jagged elements."""
    ext = _compiled()
    rng = np.random.default_rng(0)
    sets = [rng.random((n, 3)) for n in (1, 2, 3, 5, 40, 300)]
    sets.append(np.array(list(__import__("itertools").product((0.0, 1.0), repeat=3))))
    g = np.stack(np.meshgrid(np.arange(5.0), np.arange(4.0), [0.0]), -1).reshape(-1, 3)
    sets.append(g)
    sets.append(rng.normal(size=(200, 3)) / np.linalg.norm(rng.normal(size=(200, 3)), axis=1)[:, None])
    gj = _prepare(_jagged(seed=8))
    sets += list(gj.hull_pts)
    # the farthest pair first, as _prepare hands them over
    ordered = []
    for p in sets:
        if len(p) > 1:
            d = np.linalg.norm(p[:, None] - p[None], axis=2)
            i, j = np.unravel_index(d.argmax(), d.shape)
            rest = [k for k in range(len(p)) if k not in (i, j)]
            p = p[[i, j] + rest]
        ordered.append(np.ascontiguousarray(p, dtype=np.float64))
    ptr = np.r_[0, np.cumsum([len(p) for p in ordered])].astype(np.int64)
    c = np.zeros((len(ordered), 3))
    r = np.zeros(len(ordered))
    ext.enclosing_balls(np.concatenate(ordered), ptr, c, r)
    c0, r0 = _enclosing_balls(ordered, 3)
    np.testing.assert_allclose(r, r0, rtol=1e-12, atol=1e-15)
    assert r[6] == pytest.approx(math.sqrt(3) / 2, rel=1e-12)  # the cube
    assert r[7] == pytest.approx(math.hypot(2, 1.5), rel=1e-12)  # the 5 x 4 grid
    for p, ci, ri in zip(ordered, c, r, strict=True):  # every point inside
        assert np.linalg.norm(p - ci, axis=1).max() <= ri * (1 + 1e-12) + 1e-15

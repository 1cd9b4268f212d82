"""Quality metrics on hand-built polygons / polyhedra with closed-form answers."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from models.errors import ParameterError
from models.mesh.container import PolyMesh
from models.quality.distance import _POLISH_STEPS
from models.quality.geometry import smallest_enclosing_ball
from models.quality.inscribed import largest_inscribed_ball
from models.quality.partition_stats import _equals_transpose, partition_statistics
from models.quality.report import metrics_report
from models.quality.shape import (
    area_perimeter_ratio,
    circle_ratio,
    element_diameters,
    heterogeneity_preservation,
    sphericity,
    uniformity_factor,
    volume_difference,
)
from models.quality.summary import summarize

SQ2 = math.sqrt(2.0)
R_L = 2.0 - SQ2  # inscribed radius of the unit-width L-shape (touches x=0, y=0 and the reflex corner)


# ---------------------------------------------------------------- fixtures (built by hand)


def shoelace(p) -> float:
    p = np.asarray(p, float)
    q = np.roll(p, -1, axis=0)
    return 0.5 * float((p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]).sum())


def poly2d(elements, offsets=None) -> PolyMesh:
    """elements: list of elements, each a list of loops ((n, 2) arrays; outer CCW, holes CW)."""
    pts, nodes, loop_off, elem_off, measure = [], [], [0], [0], []
    base = 0
    for i, loops in enumerate(elements):
        shift = np.zeros(2) if offsets is None else np.asarray(offsets[i], float)
        for lp in loops:
            lp = np.asarray(lp, float) + shift
            pts.append(lp)
            nodes.extend(range(base, base + len(lp)))
            base += len(lp)
            loop_off.append(len(nodes))
        elem_off.append(len(loop_off) - 1)
        measure.append(sum(shoelace(lp) for lp in loops))
    n = len(elements)
    return PolyMesh(
        points=np.vstack(pts),
        elem_offsets=np.array(elem_off),
        loop_offsets=np.array(loop_off),
        loop_nodes=np.array(nodes),
        measure=np.array(measure),
        n_fine=np.ones(n, int),
        labels=np.arange(n),
    )


def poly3d(elements, offsets=None) -> PolyMesh:
    """elements: list of (vertices (n, 3), faces: lists of vertex ids, outward by right-hand rule)."""
    pts, nodes, loop_off, elem_off, measure = [], [], [0], [0], []
    base = 0
    for i, (v, faces) in enumerate(elements):
        v = np.asarray(v, float) + (0 if offsets is None else np.asarray(offsets[i], float))
        pts.append(v)
        vol = 0.0
        for f in faces:
            nodes.extend(base + k for k in f)
            loop_off.append(len(nodes))
            for j in range(1, len(f) - 1):
                vol += np.dot(v[f[0]], np.cross(v[f[j]], v[f[j + 1]])) / 6.0
        base += len(v)
        elem_off.append(len(loop_off) - 1)
        measure.append(vol)
    n = len(elements)
    return PolyMesh(
        points=np.vstack(pts),
        elem_offsets=np.array(elem_off),
        loop_offsets=np.array(loop_off),
        loop_nodes=np.array(nodes),
        measure=np.array(measure),
        n_fine=np.ones(n, int),
        labels=np.arange(n),
    )


def ngon(n, r=1.0, phase=0.0):
    t = phase + 2 * np.pi * np.arange(n) / n
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


SQUARE = [(0, 0), (1, 0), (1, 1), (0, 1)]
TRIANGLE = [(0, 0), (1, 0), (0.5, math.sqrt(3) / 2)]
L_SHAPE = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]
# the same L with collinear points on every edge, as an agglomerate of fine cells would have
L_FINE = [
    (0, 0),
    (0.5, 0),
    (1, 0),
    (1.5, 0),
    (2, 0),
    (2, 0.5),
    (2, 1),
    (1.5, 1),
    (1, 1),
    (1, 1.5),
    (1, 2),
    (0.5, 2),
    (0, 2),
    (0, 1.5),
    (0, 1),
    (0, 0.5),
]
FRAME = [[(0, 0), (3, 0), (3, 3), (0, 3)], [(1, 1), (1, 2), (2, 2), (2, 1)]]  # hole clockwise


def cube(s=1.0):
    v = s * np.array(list(itertools.product((0, 1), repeat=3)), float)  # index = 4x + 2y + z
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    return v, faces


def tetra():
    v = np.array([(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)], float)
    faces = [[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]]
    return v, orient_out(v, faces)


def orient_out(v, faces):
    c = v.mean(0)
    out = []
    for f in faces:
        a, b, d = v[f[0]], v[f[1]], v[f[2]]
        out.append(list(f) if np.dot(np.cross(b - a, d - a), a - c) > 0 else list(f)[::-1])
    return out


def prism(poly2, quads, h):
    """Right prism over a 2D polygon (CCW outline `poly2`, convex pieces `quads` of the cap)."""
    p = np.asarray(poly2, float)
    n = len(p)
    v = np.vstack([np.column_stack([p, np.zeros(n)]), np.column_stack([p, np.full(n, h)])])
    faces = [list(q)[::-1] for q in quads] + [[k + n for k in q] for q in quads]
    faces += [[i, (i + 1) % n, (i + 1) % n + n, i + n] for i in range(n)]
    return v, faces


# L-prism: L_FINE outline (16 points) split into three unit squares on each cap, height 1.5
_L_IDX = {tuple(map(float, q)): i for i, q in enumerate(L_FINE)}


L_CAPS = [
    [_L_IDX[(0.0, 0.0)], _L_IDX[(1.0, 0.0)], _L_IDX[(1.0, 1.0)], _L_IDX[(0.0, 1.0)]],
    [_L_IDX[(1.0, 0.0)], _L_IDX[(2.0, 0.0)], _L_IDX[(2.0, 1.0)], _L_IDX[(1.0, 1.0)]],
    [_L_IDX[(0.0, 1.0)], _L_IDX[(1.0, 1.0)], _L_IDX[(1.0, 2.0)], _L_IDX[(0.0, 2.0)]],
]


def l_prism(h=1.5):
    # caps as the three squares, with the collinear outline points inserted so there are no T-junctions
    caps = []
    for q in L_CAPS:
        ring = []
        for a, b in zip(q, q[1:] + q[:1], strict=True):
            pa, pb = np.array(L_FINE[a]), np.array(L_FINE[b])
            ring.append(a)
            mid = tuple(map(float, (pa + pb) / 2))
            if mid in _L_IDX:
                ring.append(_L_IDX[mid])
        caps.append(ring)
    return prism(L_FINE, caps, h)


# ---------------------------------------------------------------- independent brute-force references


def brute_enclosing(p):
    """Smallest enclosing ball by trying every subset of <= d+1 points (least-squares circumcentre)."""
    d = p.shape[1]
    best = (None, np.inf)
    for k in range(1, d + 2):
        for sub in itertools.combinations(range(len(p)), k):
            q = p[list(sub)]
            if k == 1:
                c = q[0]
            else:
                A = 2 * (q[1:] - q[0])
                b = (q[1:] ** 2).sum(1) - (q[0] ** 2).sum()
                # centre restricted to the affine hull: c = q0 + A^T mu / 2
                M = A @ (q[1:] - q[0]).T
                if abs(np.linalg.det(M)) < 1e-12:
                    continue
                mu = np.linalg.solve(M, b - A @ q[0])
                c = q[0] + (q[1:] - q[0]).T @ mu
            r = np.linalg.norm(q - c, axis=1).max()
            if np.linalg.norm(p - c, axis=1).max() <= r * (1 + 1e-9) and r < best[1]:
                best = (c, r)
    return best


def seg_dist(x, a, b):
    ab = b - a
    t = np.clip(((x[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    return np.linalg.norm(x[:, None] - (a + t[..., None] * ab), axis=-1).min(1)


def inside_even_odd(x, a, b):
    cond = (a[:, 1] > x[:, None, 1]) != (b[:, 1] > x[:, None, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[:, 0] + (x[:, None, 1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return ((cond & (x[:, None, 0] < xi)).sum(1) % 2) == 1


def grid_inscribed_2d(loops, h):
    """max over grid points inside of the exact distance to the boundary; the true radius lies in
    [result, result + h / sqrt 2]."""
    segs = [(np.asarray(lp, float), np.roll(np.asarray(lp, float), -1, axis=0)) for lp in loops]
    a = np.vstack([s[0] for s in segs])
    b = np.vstack([s[1] for s in segs])
    lo, hi = a.min(0), a.max(0)
    xs = np.arange(lo[0], hi[0] + h, h)
    ys = np.arange(lo[1], hi[1] + h, h)
    x = np.column_stack([c.ravel() for c in np.meshgrid(xs, ys)])
    best = 0.0
    for chunk in np.array_split(x, max(1, len(x) // 2000)):
        ins = inside_even_odd(chunk, a, b)
        if ins.any():
            best = max(best, seg_dist(chunk[ins], a, b).max())
    return best


def star_polygon(rng, n=200, rough=0.35):
    t = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = 1.0 + rough * (rng.uniform(-1, 1, n) + 0.5 * np.sin(3 * t + rng.uniform(0, 6)))
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


# ---------------------------------------------------------------- 2D closed forms


def test_unit_square():
    pm = poly2d([[SQUARE]])
    assert circle_ratio(pm)[0] == pytest.approx(1 / SQ2, rel=1e-9)
    assert area_perimeter_ratio(pm)[0] == pytest.approx(np.pi / 4, rel=1e-12)
    c, r = largest_inscribed_ball(pm)
    assert r[0] == pytest.approx(0.5, rel=1e-9) and c[0] == pytest.approx([0.5, 0.5], abs=1e-7)


def test_equilateral_triangle_and_hexagon():
    pm = poly2d([[TRIANGLE], [ngon(6)]])
    cr = circle_ratio(pm)
    assert cr[0] == pytest.approx(0.5, rel=1e-9)
    assert cr[1] == pytest.approx(math.sqrt(3) / 2, rel=1e-9)
    apr = area_perimeter_ratio(pm)
    assert apr[0] == pytest.approx(math.pi * math.sqrt(3) / 9, rel=1e-12)
    assert apr[1] == pytest.approx(math.pi / (2 * math.sqrt(3)), rel=1e-12)


def test_400_gon_approaches_circle():
    pm = poly2d([[ngon(400, r=3.0)]])
    assert circle_ratio(pm)[0] == pytest.approx(math.cos(math.pi / 400), rel=1e-9)
    assert area_perimeter_ratio(pm)[0] == pytest.approx(1.0, abs=1e-4)
    assert area_perimeter_ratio(pm)[0] < 1.0


@pytest.mark.parametrize("outline", [L_SHAPE, L_FINE])
def test_l_shape_nonconvex(outline):
    pm = poly2d([[outline]])
    c, r = largest_inscribed_ball(pm)
    eps = 1e-3 * 2 * SQ2  # rel_tol * diameter
    assert R_L - eps <= r[0] <= R_L + 1e-12
    assert c[0] == pytest.approx([R_L, R_L], abs=0.02)
    _, R = smallest_enclosing_ball(pm.points)
    assert R == pytest.approx(SQ2, rel=1e-12)
    assert circle_ratio(pm)[0] == pytest.approx(SQ2 - 1, abs=eps / SQ2 + 1e-12)


@pytest.mark.parametrize("rel_tol", [0.2, 0.05, 1e-2, 1e-4])
def test_inscribed_bound_holds_for_every_tolerance(rel_tol):
    pm = poly2d([[L_SHAPE], FRAME], offsets=[(0, 0), (10, 0)])
    _, r = largest_inscribed_ball(pm, rel_tol=rel_tol)
    diam = element_diameters(pm)
    assert diam == pytest.approx([2 * SQ2, 3 * SQ2])
    for k in range(2):
        assert R_L - rel_tol * diam[k] - 1e-12 <= r[k] <= R_L + 1e-12


def test_square_with_square_hole():
    pm = poly2d([FRAME])
    assert pm.measure[0] == pytest.approx(8.0)
    assert area_perimeter_ratio(pm)[0] == pytest.approx(math.pi / 8, rel=1e-12)
    c, r = largest_inscribed_ball(pm)
    eps = 1e-3 * 3 * SQ2
    assert R_L - eps <= r[0] <= R_L + 1e-12
    # the centre is in one of the four corners of the frame, never in the hole
    assert np.min(np.abs(np.abs(c[0] - 1.5) - (1.5 - R_L))) < 0.05
    assert circle_ratio(pm)[0] == pytest.approx(R_L / (3 / SQ2), abs=eps / (3 / SQ2) + 1e-12)


def test_polygonal_annulus():
    ro, ri, n = 2.0, 1.0, 256
    pm = poly2d([[ngon(n, ro), ngon(n, ri)[::-1]]])
    _, r = largest_inscribed_ball(pm)
    eps = 1e-3 * 2 * ro
    assert (ro - ri) / 2 - eps - ro * (1 - math.cos(math.pi / n)) <= r[0] <= (ro - ri) / 2 + 1e-12


def test_random_star_polygons_against_grid_search():
    rng = np.random.default_rng(7)
    polys = [star_polygon(rng, n=60) for _ in range(4)]
    pm = poly2d([[p] for p in polys], offsets=[(10.0 * i, 0) for i in range(4)])
    rel = 1e-3
    _, r = largest_inscribed_ball(pm, rel_tol=rel)
    diam = element_diameters(pm)
    h = 0.01
    for k, p in enumerate(polys):
        g = grid_inscribed_2d([p], h)
        assert g - rel * diam[k] <= r[k] <= g + h / SQ2 + 1e-12
        assert pm.measure[k] < 0.97 * ConvexHull(p).volume  # really non-convex


def test_branch_and_bound_matches_lp_on_convex_shapes():
    pm = poly2d([[SQUARE], [TRIANGLE], [ngon(7, 2.0)]])
    _, r_lp = largest_inscribed_ball(pm)
    _, r_bb = largest_inscribed_ball(pm, method="bnb")
    eps = 1e-3 * element_diameters(pm)
    assert np.all(r_bb <= r_lp + 1e-12) and np.all(r_bb >= r_lp - eps)
    assert r_lp[1] == pytest.approx(math.sqrt(3) / 6, rel=1e-9)


def test_pinched_outline_two_squares_touching_at_a_vertex():
    # one loop visiting (1, 1) twice: the vertex-wedge inside test must not be used there
    loop = [(0, 0), (1, 0), (1, 1), (2, 1), (2, 2), (1, 2), (1, 1), (0, 1)]
    pm = poly2d([[loop]])
    assert pm.measure[0] == pytest.approx(2.0)
    for method in ("auto", "bnb"):
        _, r = largest_inscribed_ball(pm, method=method)
        assert 0.5 - 1e-3 * 2 * SQ2 <= r[0] <= 0.5 + 1e-12


def test_sliver_thinner_than_tolerance_terminates():
    w = 1e-5
    thin_l = [(0, 0), (2, 0), (2, w), (w, w), (w, 2), (0, 2)]
    pm = poly2d([[thin_l]])
    _, r = largest_inscribed_ball(pm, method="bnb")
    r_true = (2 - SQ2) * w  # the unit-width L scaled by w (the corner region is the same)
    assert r_true - 1e-3 * element_diameters(pm)[0] <= r[0] <= r_true + 1e-15
    # a tolerance finer than the width: the long arms (a plateau of the distance) must be pruned
    eps = 1e-6 * element_diameters(pm)[0]
    _, r = largest_inscribed_ball(pm, rel_tol=1e-6, method="bnb")
    assert eps < 0.3 * w and r_true - eps <= r[0] <= r_true * (1 + 1e-9)


def test_reversed_outline_is_tolerated():
    pm = poly2d([[L_SHAPE[::-1]]])
    pm.measure = np.abs(pm.measure)
    _, r = largest_inscribed_ball(pm)
    assert R_L - 1e-2 <= r[0] <= R_L + 1e-12


# ---------------------------------------------------------------- 3D closed forms


def test_unit_cube():
    pm = poly3d([cube()])
    assert pm.measure[0] == pytest.approx(1.0)
    assert circle_ratio(pm)[0] == pytest.approx(1 / math.sqrt(3), rel=1e-9)
    assert sphericity(pm)[0] == pytest.approx((math.pi / 6) ** (1 / 3), rel=1e-12)
    _, r = largest_inscribed_ball(pm, method="bnb")
    assert 0.5 - 1e-3 * math.sqrt(3) <= r[0] <= 0.5 + 1e-12


def test_regular_tetrahedron():
    pm = poly3d([tetra()])
    assert pm.measure[0] == pytest.approx(8 / 3)
    assert circle_ratio(pm)[0] == pytest.approx(1 / 3, rel=1e-9)
    _, r = largest_inscribed_ball(pm, method="bnb")
    r_true = math.sqrt(3) / 3  # circumradius sqrt(3), inradius one third of it
    assert r_true - 1e-3 * 2 * SQ2 <= r[0] <= r_true + 1e-12


def test_l_prism_nonconvex_3d():
    v, faces = l_prism(1.5)
    pm = poly3d([(v, faces), cube()], offsets=[(0, 0, 0), (5, 5, 5)])
    assert pm.measure[0] == pytest.approx(4.5)
    c, r = largest_inscribed_ball(pm)
    diam = element_diameters(pm)
    assert diam[0] == pytest.approx(math.sqrt(8 + 2.25))
    assert R_L - 1e-3 * diam[0] <= r[0] <= R_L + 1e-12
    assert c[0][:2] == pytest.approx([R_L, R_L], abs=0.03)
    assert R_L - 0.01 <= c[0][2] <= 1.5 - R_L + 0.01  # any height where the ball fits
    assert r[1] == pytest.approx(0.5, rel=1e-9)
    R = math.sqrt(2 + 0.75**2)
    cr = circle_ratio(pm)
    assert cr[0] == pytest.approx(R_L / R, abs=1e-3 * diam[0] / R + 1e-12)
    assert sphericity(pm)[0] == pytest.approx((36 * math.pi * 4.5**2) ** (1 / 3) / 18.0, rel=1e-12)


def test_two_cubes_sharing_an_edge_nonmanifold():
    v1, f1 = cube()
    v2, f2 = cube()
    v = np.vstack([v1, v2 + [1.0, 1.0, 0.0]])
    faces = f1 + [[k + 8 for k in f] for f in f2]
    pm = poly3d([(v, faces)])
    assert pm.measure[0] == pytest.approx(2.0)
    c, r = largest_inscribed_ball(pm)
    assert 0.5 - 1e-3 * element_diameters(pm)[0] <= r[0] <= 0.5 + 1e-12
    # enclosing ball: centre (1, 1, 0.5) through (0, 0, 0) and (2, 2, 1), radius 1.5
    assert circle_ratio(pm)[0] == pytest.approx(0.5 / 1.5, abs=2e-3)


def test_inward_faces_are_tolerated_3d():
    v, faces = l_prism(1.5)
    pm = poly3d([(v, [f[::-1] for f in faces])])
    pm.measure = np.abs(pm.measure)
    _, r = largest_inscribed_ball(pm, method="bnb")
    assert R_L - 1e-3 * element_diameters(pm)[0] <= r[0] <= R_L + 1e-12


@pytest.mark.parametrize("rel_tol", [0.1, 0.02])
def test_l_prism_bound_for_coarse_tolerances(rel_tol):
    pm = poly3d([l_prism(1.5)])
    _, r = largest_inscribed_ball(pm, rel_tol=rel_tol)
    assert R_L - rel_tol * element_diameters(pm)[0] - 1e-12 <= r[0] <= R_L + 1e-12


def test_polish_raises_the_lower_bound_to_certified_points_only():
    """The local ascent after the dive (3D): from a poor interior point of the L prism it reaches the
    closed-form radius (two walls and the reflex edge), never above it, at a point that is inside
    and whose distance is the exact one; an element without a start point is left alone."""
    from models.quality.distance import _polish
    from models.quality.geometry import _prepare

    pm = poly3d([l_prism(1.5), cube()], offsets=[(0, 0, 0), (5, 5, 5)])
    g = _prepare(pm)
    x0 = np.array([0.3, 0.35, 0.7])  # in the corner square, 0.3 from the wall x = 0
    best = np.array([0.3, 0.0])
    best_pt = np.array([x0, [np.nan] * 3])
    for _ in range(3):  # a few ascent steps each
        _polish(g, np.arange(2), best, best_pt, g.signed_measure >= 0)
    assert R_L - 1e-6 <= best[0] <= R_L + 1e-12
    x = best_pt[0]
    tri = _l_prism_triangles()
    A, B, C = (tri[:, k] - x for k in range(3))
    la, lb, lc = (np.linalg.norm(M, axis=-1) for M in (A, B, C))
    num = (A * np.cross(B, C)).sum(-1)
    den = la * lb * lc + (A * B).sum(-1) * lc + (A * C).sum(-1) * lb + (B * C).sum(-1) * la
    assert abs(2 * np.arctan2(num, den).sum()) > 2 * np.pi  # winding number 1: inside
    with np.errstate(invalid="ignore", divide="ignore"):  # the caps' degenerate fan triangles
        exact = point_tri_dist(x[None], tri).min()
    assert best[0] == pytest.approx(exact, abs=1e-12)
    assert best[1] == 0.0 and np.isnan(best_pt[1]).all()


def _l_prism_triangles():
    v, faces = l_prism(1.5)
    return np.array([[v[f[0]], v[f[j]], v[f[j + 1]]] for f in faces for j in range(1, len(f) - 1)])


def test_polish_off_gives_the_same_certified_radii(monkeypatch):
    """With and without the ascent the radii of the jagged agglomerated tets stay within eps of
    each other (both certified to rel_tol x diameter)."""
    from meshes import tets

    from models.mesh.read import mesh_from_arrays
    from models.pipeline import prepare
    from models.polytope.merge import merge

    p, t = tets(8)
    m = mesh_from_arrays(p, [("tetra", t)])
    g, d = prepare(m)
    c = p[t].mean(axis=1)
    labels = (np.floor(3 * (c[:, 0] + 0.12 * np.sin(7 * c[:, 1]))) + 3 * (c[:, 2] > 0.5)).astype(np.int64)
    labels = np.unique(labels, return_inverse=True)[1]
    poly, _ = merge(m, g, labels, d.measures)
    eps = 1e-3 * element_diameters(poly)
    _, r_on = largest_inscribed_ball(poly, method="bnb-numpy")
    monkeypatch.setitem(_POLISH_STEPS, 3, 0)
    _, r_off = largest_inscribed_ball(poly, method="bnb-numpy")
    assert np.all(np.abs(r_on - r_off) <= eps + 1e-12)
    assert np.all(r_on > 0)


def _classify_points(pm, q):
    """Fast (closest-feature) and brute-force inside tests of points q against element 0."""
    from models.quality.distance import _classify, _inside_bruteforce, _prim_distance
    from models.quality.geometry import _prepare

    g = _prepare(pm)
    S = g.prim_ptr[1]
    row = np.repeat(np.arange(len(q)), S)
    p = np.tile(np.arange(S), len(q))
    d2, loc, side = _prim_distance(g, q[row], p)
    k = (d2.reshape(len(q), S)).argmin(1) + np.arange(len(q)) * S
    elem = np.zeros(len(q), dtype=np.int64)
    fast = _classify(g, q, elem, p[k], loc[k], side[k], g.signed_measure >= 0)
    return fast == 1, _inside_bruteforce(g, q, elem)


def _probe(rng, lo, hi, n, dim):
    q = rng.uniform(lo, hi, size=(n, dim))
    # plus points near the special features (vertices, edges) where ties between facets happen
    q[: n // 4] = np.round(q[: n // 4] * 2) / 2 + rng.normal(scale=0.05, size=(n // 4, dim))
    return q


def test_inside_tests_2d_pinch_and_hole():
    rng = np.random.default_rng(5)
    pinch = [(0, 0), (1, 0), (1, 1), (2, 1), (2, 2), (1, 2), (1, 1), (0, 1)]
    for loops, truth in (
        (
            [pinch],
            lambda x, y: ((x > 0) & (x < 1) & (y > 0) & (y < 1)) | ((x > 1) & (x < 2) & (y > 1) & (y < 2)),
        ),
        (
            FRAME,
            lambda x, y: (x > 0) & (x < 3) & (y > 0) & (y < 3) & ~((x > 1) & (x < 2) & (y > 1) & (y < 2)),
        ),
        ([L_FINE], lambda x, y: (x > 0) & (y > 0) & (((x < 2) & (y < 1)) | ((x < 1) & (y < 2)))),
    ):
        q = _probe(rng, -0.5, 3.5, 1500, 2)
        fast, brute = _classify_points(poly2d([loops]), q)
        want = truth(q[:, 0], q[:, 1])
        assert np.array_equal(brute, want)
        assert np.array_equal(fast, want)


def test_inside_tests_3d_l_prism_and_nonmanifold_edge():
    rng = np.random.default_rng(6)
    v1, f1 = cube()
    v2, f2 = cube()
    two = (np.vstack([v1, v2 + [1.0, 1.0, 0.0]]), f1 + [[k + 8 for k in f] for f in f2])
    for shape, truth in (
        (
            l_prism(1.5),
            lambda x, y, z: (
                (z > 0) & (z < 1.5) & (x > 0) & (y > 0) & (((x < 2) & (y < 1)) | ((x < 1) & (y < 2)))
            ),
        ),
        (
            two,
            lambda x, y, z: (
                (z > 0)
                & (z < 1)
                & (((x > 0) & (x < 1) & (y > 0) & (y < 1)) | ((x > 1) & (x < 2) & (y > 1) & (y < 2)))
            ),
        ),
    ):
        q = _probe(rng, -0.5, 2.5, 1200, 3)
        fast, brute = _classify_points(poly3d([shape]), q)
        want = truth(q[:, 0], q[:, 1], q[:, 2])
        assert np.array_equal(brute, want)
        assert np.array_equal(fast, want)


def test_star_polyhedron_against_grid_search():
    rng = np.random.default_rng(3)
    u = rng.normal(size=(40, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    faces = orient_out(u, ConvexHull(u).simplices)  # outward on the sphere, stays valid after bumping
    v = u * rng.uniform(0.6, 1.2, size=(40, 1))
    pm = poly3d([(v, faces)])
    _, r = largest_inscribed_ball(pm)
    # reference: grid points, winding-number inside test, exact point-triangle distances
    tri = v[np.array(faces)]
    h = 0.04
    ax = np.arange(-1.2, 1.2 + h, h)
    x = np.column_stack([c.ravel() for c in np.meshgrid(ax, ax, ax)])
    x = x[np.linalg.norm(x, axis=1) < 1.2]
    best = grid_inscribed_radius(x, tri, 40)
    diam = element_diameters(pm)[0]
    assert best - 1e-3 * diam <= r[0] <= best + h * math.sqrt(3) / 2 + 1e-12
    assert pm.measure[0] < 0.97 * ConvexHull(v).volume  # really non-convex


def point_tri_dist(p, tri):
    """(n, T) distances from points p (n, 3) to triangles tri (T, 3, 3)."""
    a, b, c = (tri[None, :, k] for k in range(3))
    p = p[:, None]
    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n, axis=-1)[..., None]
    h = ((p - a) * n).sum(-1)
    q = p - h[..., None] * n
    s1 = (np.cross(b - a, q - a) * n).sum(-1)
    s2 = (np.cross(c - b, q - b) * n).sum(-1)
    s3 = (np.cross(a - c, q - c) * n).sum(-1)
    inside = (s1 >= 0) & (s2 >= 0) & (s3 >= 0)
    edges = np.minimum.reduce([seg_dist1(p, a, b), seg_dist1(p, b, c), seg_dist1(p, c, a)])
    return np.where(inside, np.abs(h), edges)


def grid_inscribed_radius(x: np.ndarray, tri: np.ndarray, chunks: int) -> float:
    """Reference for the 3D inscribed radius: the largest distance to the surface `tri` (T, 3, 3)
    over the grid points x inside it (winding number), in `chunks` batches."""
    best = 0.0
    for xc in np.array_split(x, chunks):
        A, B, C = (tri[None, :, k] - xc[:, None] for k in range(3))
        la, lb, lc = (np.linalg.norm(M, axis=-1) for M in (A, B, C))
        num = (A * np.cross(B, C)).sum(-1)
        den = la * lb * lc + (A * B).sum(-1) * lc + (A * C).sum(-1) * lb + (B * C).sum(-1) * la
        inside = np.abs(2 * np.arctan2(num, den).sum(1)) > 2 * np.pi
        if inside.any():
            best = max(best, point_tri_dist(xc[inside], tri).min(1).max())
    return best


def seg_dist1(p, a, b):
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


# ---------------------------------------------------------------- enclosing ball


@pytest.mark.parametrize("dim,n,seed", [(2, 25, 0), (2, 40, 1), (3, 18, 2), (3, 22, 3)])
def test_smallest_enclosing_ball_vs_brute_force(dim, n, seed):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, dim)) * rng.uniform(0.5, 2, size=dim)
    c, r = smallest_enclosing_ball(p)
    cb, rb = brute_enclosing(p)
    assert r == pytest.approx(rb, rel=1e-9)
    assert c == pytest.approx(cb, abs=1e-7)
    assert np.linalg.norm(p - c, axis=1).max() <= r * (1 + 1e-12)


def test_smallest_enclosing_ball_degenerate_sets():
    c, r = smallest_enclosing_ball(np.array([[1.0, 2.0]]))
    assert r == 0 and c == pytest.approx([1, 2])
    line = np.column_stack([np.linspace(0, 4, 9), np.linspace(0, 3, 9)])
    c, r = smallest_enclosing_ball(line)
    assert r == pytest.approx(2.5) and c == pytest.approx([2, 1.5])
    plane = np.column_stack([np.random.default_rng(1).uniform(size=(30, 2)), np.zeros(30)])
    plane[:4, :2] = [(0, 0), (1, 0), (0, 1), (1, 1)]
    c, r = smallest_enclosing_ball(plane)
    assert r == pytest.approx(SQ2 / 2) and c == pytest.approx([0.5, 0.5, 0])
    c, r = smallest_enclosing_ball(np.vstack([ngon(50, 2.0)] * 3))
    assert r == pytest.approx(2.0) and c == pytest.approx([0, 0], abs=1e-12)


# ---------------------------------------------------------------- other metrics


def test_uniformity_and_volume_difference():
    pm = poly2d(
        [[SQUARE], [[(2 * x, 2 * y) for x, y in SQUARE]], [[(3 * x, 3 * y) for x, y in SQUARE]]],
        offsets=[(0, 0), (5, 0), (10, 0)],
    )
    assert uniformity_factor(pm) == pytest.approx([1 / 3, 2 / 3, 1.0])
    vd = volume_difference(pm.measure)  # areas 1, 4, 9: mean 14/3
    m = 14 / 3
    assert vd == pytest.approx([1 / (1 + abs(a - m) / m) for a in (1, 4, 9)])
    assert volume_difference(np.array([2.0, 2.0])) == pytest.approx([1, 1])


def test_heterogeneity_preservation():
    labels = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2])
    tags = np.array([5, 5, 5, 7, 7, 7, 7, 5, 7, 9])
    hp = heterogeneity_preservation(labels, tags)
    assert hp == pytest.approx([0.75, 1.0, 1 / 3])
    binary = heterogeneity_preservation(labels, (tags == 7).astype(int))
    p = np.array([0.25, 1.0, 1 / 3])  # mean of the 0/1 tag per element
    assert binary == pytest.approx(np.maximum(p, 1 - p))


def _csr(n, edges):
    # both directions plus a duplicate and a self loop, which must be ignored
    e = np.array(edges + [(b, a) for a, b in edges] + [edges[0], (0, 0)])
    order = np.argsort(e[:, 0], kind="stable")
    e = e[order]
    indptr = np.zeros(n + 1, int)
    np.cumsum(np.bincount(e[:, 0], minlength=n), out=indptr[1:])
    return indptr, e[:, 1]


TWO_TRIANGLES = [(0, 1), (1, 2), (0, 2), (3, 4), (4, 5), (3, 5), (2, 3)]


def test_partition_statistics_hand_graph():
    indptr, indices = _csr(6, TWO_TRIANGLES)
    s = partition_statistics(indptr, indices, np.array([0, 0, 0, 1, 1, 1]))
    assert s == {
        "cut": 1,
        "normalized_cut": pytest.approx(2 / 7),
        "volume_imbalance": 1.0,
        "parts": 2,
        "connected": True,
    }
    s = partition_statistics(indptr, indices, np.array([0, 1, 1, 0, 1, 1]))
    assert s["cut"] == 5
    assert s["normalized_cut"] == pytest.approx(5 / 5 + 5 / 9)
    assert s["volume_imbalance"] == pytest.approx(4 / 3)
    assert s["parts"] == 2 and s["connected"] is False


def test_partition_statistics_one_directional_csr():
    # each edge stored once (u < v only): the graph is symmetrised, the answer is the same
    e = np.array(sorted(TWO_TRIANGLES))
    indptr = np.zeros(7, int)
    np.cumsum(np.bincount(e[:, 0], minlength=6), out=indptr[1:])
    s = partition_statistics(indptr, e[:, 1], np.array([0, 0, 0, 1, 1, 1]))
    assert s["cut"] == 1 and s["normalized_cut"] == pytest.approx(2 / 7) and s["connected"]
    s = partition_statistics(indptr, e[:, 1], np.array([3, 3, 7, 7, 3, 3]))  # labels need not be 0..k-1
    assert s["parts"] == 2 and s["connected"] is False


def test_summarize():
    s = summarize([4.0, 1.0, 3.0, 2.0, 5.0, np.nan])
    assert s == {"min": 1.0, "q1": 2.0, "median": 3.0, "q3": 4.0, "max": 5.0, "mean": 3.0}
    assert summarize([])["median"] is None


def test_metrics_report_2d_json():
    pm = poly2d([[SQUARE], [L_SHAPE]], offsets=[(0, 0), (1, 0)])
    pm.labels = np.array([0, 0, 1, 1, 1])
    indptr, indices = _csr(5, [(0, 1), (1, 2), (2, 3), (3, 4)])
    rep = metrics_report(pm, indptr, indices)
    json.dumps(rep, allow_nan=False)
    assert rep["elements"] == 2 and rep["dim"] == 2
    keys = [
        "circle_ratio",
        "area_perimeter_ratio",
        "uniformity_factor",
        "volume_difference",
        "box_ratio",
        "box_circle_ratio",
    ]
    assert list(rep["per_element"]) == keys and list(rep["summary"]) == keys
    assert rep["per_element"]["circle_ratio"][0] == pytest.approx(1 / SQ2)
    # boxes (R3MG's measures): the square fills its box, the L three quarters of its 2 x 2 box
    assert rep["per_element"]["box_ratio"] == pytest.approx([1.0, 0.75])
    assert rep["coverage"] == pytest.approx((1 + 4) / (1 + 3))
    assert rep["per_element"]["box_circle_ratio"][0] == pytest.approx(0.5 / (SQ2 / 2))
    assert rep["per_element"]["uniformity_factor"] == pytest.approx([0.5, 1.0])
    assert rep["partition"] == {
        "cut": 1,
        "normalized_cut": pytest.approx(1 / 3 + 1 / 5),
        "volume_imbalance": pytest.approx(1.2),
        "parts": 2,
        "connected": True,
    }
    tagged = metrics_report(pm, indptr, indices, fine_tags=np.array([1, 1, 0, 0, 1]))
    json.dumps(tagged, allow_nan=False)
    assert tagged["per_element"]["heterogeneity_preservation"] == pytest.approx([1.0, 2 / 3])
    assert tagged["summary"]["heterogeneity_preservation"]["min"] == pytest.approx(2 / 3)
    for v in tagged["per_element"].values():
        assert all(type(x) is float and 0.0 <= x <= 1.0 for x in v)


def test_metrics_report_3d_keys():
    pm = poly3d([cube(), tetra()], offsets=[(0, 0, 0), (4, 0, 0)])
    indptr, indices = _csr(2, [(0, 1)])
    rep = metrics_report(pm, indptr, indices)
    json.dumps(rep, allow_nan=False)
    assert rep["dim"] == 3
    assert list(rep["per_element"]) == [
        "circle_ratio",
        "sphericity",
        "uniformity_factor",
        "volume_difference",
        "box_ratio",
        "box_circle_ratio",
    ]
    assert rep["per_element"]["box_ratio"] == pytest.approx([1.0, 1 / 3])  # regular tetra in its cube
    assert rep["coverage"] == pytest.approx(9 / (1 + 8 / 3))
    assert rep["per_element"]["circle_ratio"] == pytest.approx([1 / math.sqrt(3), 1 / 3])
    assert rep["summary"]["sphericity"]["max"] == pytest.approx((math.pi / 6) ** (1 / 3))


def test_bad_parameters():
    pm = poly2d([[SQUARE]])
    with pytest.raises(ParameterError):
        largest_inscribed_ball(pm, rel_tol=0)
    with pytest.raises(ParameterError):
        largest_inscribed_ball(pm, method="grid")
    with pytest.raises(ParameterError):
        sphericity(pm)


def test_agglomerated_tets_bnb_within_eps_of_reference():
    """Non-convex, jagged elements of a real agglomerated tetrahedral mesh (Kuhn-subdivided cube
    grid, wavy slabs): the default rel_tol result stays within eps of a near-exact reference
    (rel_tol = 1e-4: r_ref >= r_true - 1e-4 diam) and of an independent grid search (lower bound of the true radius)."""
    from meshes import tets

    from models.mesh.read import mesh_from_arrays
    from models.pipeline import prepare
    from models.polytope.merge import merge

    p, t = tets(10)
    m = mesh_from_arrays(p, [("tetra", t)])
    g, d = prepare(m)
    c = p[t].mean(axis=1)
    labels = (
        np.floor(3 * (c[:, 0] + 0.12 * np.sin(7 * c[:, 1]) + 0.1 * np.cos(5 * c[:, 2])) + 0.5)
        + 4 * (c[:, 2] > 0.5 + 0.15 * np.sin(6 * c[:, 0]))
    ).astype(np.int64)
    labels = np.unique(labels, return_inverse=True)[1]
    poly, _ = merge(m, g, labels, d.measures)
    diam = element_diameters(poly)
    _, r = largest_inscribed_ball(poly, rel_tol=1e-3, method="bnb")
    _, r_ref = largest_inscribed_ball(poly, rel_tol=1e-4, method="bnb")
    eps = 1e-3 * diam
    assert np.all(r <= r_ref + 1e-4 * diam + 1e-12)
    assert np.all(r >= r_ref - eps)
    # independent check on a few elements: grid points inside the element (fine cells' labels),
    # exact distances to the element's boundary triangles
    lo, nodes = poly.loop_offsets, poly.loop_nodes
    eo = poly.elem_offsets
    h = 0.04
    ax = np.arange(h / 2, 1, h)
    x = np.column_stack([v.ravel() for v in np.meshgrid(ax, ax, ax, indexing="ij")])
    for e in range(min(poly.n_elements, 2)):
        tri = []
        for f in range(eo[e], eo[e + 1]):
            ring = nodes[lo[f] : lo[f + 1]]
            tri += [[ring[0], ring[j], ring[j + 1]] for j in range(1, ring.size - 1)]
        tri = poly.points[np.array(tri)]
        xe = x[np.all((x >= tri.min((0, 1))) & (x <= tri.max((0, 1))), axis=1)]
        best = grid_inscribed_radius(xe, tri, max(1, xe.shape[0] // 500))
        assert best > 0
        assert best - eps[e] <= r[e] <= best + h * math.sqrt(3) / 2 + 1e-12


def test_vectorized_2d_hulls_match_qhull():
    """_hulls_2d (all elements at once) against one qhull call per point set: same vertices, same
    area, edge equations that hold every point, diameter equal to the largest pairwise distance,
    farthest pair first; collinear runs, duplicates and degenerate sets included."""
    from scipy.spatial.distance import pdist

    from models.quality.geometry import _hulls_2d

    rng = np.random.default_rng(3)
    sets = [rng.random((int(rng.integers(3, 60)), 2)) for _ in range(40)]
    sets.append(np.array([[0, 0], [1, 0], [2, 0], [2, 1], [1, 1], [0, 1], [1, 0.5]], float))  # collinear runs
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    sets.append(np.vstack([sq, sq]))  # every point twice
    ang = np.linspace(0, 2 * np.pi, 700, endpoint=False)
    sets.append(np.column_stack([np.cos(ang), np.sin(ang)]) * 3.0 + rng.random((1, 2)))  # 700-vertex hull
    sets.append(np.array([[0, 0], [1, 1], [2, 2]], float))  # collinear: no hull
    sets.append(np.array([[5.0, 5.0]]))  # one point
    ptr = np.r_[0, np.cumsum([len(s) for s in sets])]
    hull_pts, hull_eq, measure, diameter = _hulls_2d(np.vstack(sets), ptr)
    for e, p in enumerate(sets):
        assert diameter[e] == pytest.approx(np.sqrt(pdist(p, "sqeuclidean").max()) if len(p) > 1 else 0.0)
        if len(p) >= 2:
            assert np.linalg.norm(hull_pts[e][0] - hull_pts[e][1]) == pytest.approx(diameter[e])
        if e >= len(sets) - 2:
            assert hull_eq[e] is None and measure[e] == 0.0
            continue
        ref = ConvexHull(p)
        assert measure[e] == pytest.approx(ref.volume, rel=1e-12)
        got = {tuple(x) for x in hull_pts[e]}
        assert got == {tuple(x) for x in p[ref.vertices]}
        assert np.all(p @ hull_eq[e][:, :2].T + hull_eq[e][:, 2] <= 1e-12)
        assert np.allclose(np.linalg.norm(hull_eq[e][:, :2], axis=1), 1.0)


def test_triangle_neighbours_one_key_sort_matches_lexsort_and_brute_force():
    """_triangle_neighbours sorts one int64 key when (elements x points^2) fits, else two keys
    (lexsort): both give the same neighbours, equal to a brute-force edge match (two elements)."""
    from models.quality.geometry import _triangle_neighbours

    v, faces = l_prism(1.5)
    tri = np.array([[f[0], f[j], f[j + 1]] for f in faces for j in range(1, len(f) - 1)])
    tri = np.vstack([tri, tri + len(v)])  # a second element on its own points
    elem = np.repeat([0, 1], len(tri) // 2)
    npts = 2 * len(v)
    fast = _triangle_neighbours(tri, elem, npts)
    slow = _triangle_neighbours(tri, elem, 1 << 31)  # elements x points^2 >= 2^62: the lexsort path
    assert np.array_equal(fast, slow)
    want = np.full_like(fast, -1)
    for i, t in enumerate(tri):
        for k, (a, b) in enumerate(((t[0], t[1]), (t[0], t[2]), (t[1], t[2]))):
            hits = [
                j for j, s in enumerate(tri) if j != i and elem[j] == elem[i] and {a, b} <= set(s.tolist())
            ]
            if len(hits) == 1:
                want[i, k] = hits[0]
    # the brute force ignores orientation: compare where the fast one found a pair (nearly all)
    assert (fast >= 0).sum() > 0.9 * fast.size
    assert np.array_equal(fast[fast >= 0], want[fast >= 0])


def _partition_paths(seed, monkeypatch):
    """A symmetric CSR with sorted rows (a self loop included) takes the compiled path, or without
    it numpy's sort-free one; the same graph given one way only (with a duplicate thrown in) takes
    the general one: the same statistics, connected or not."""
    from scipy import sparse

    rng = np.random.default_rng(seed)
    n = 300
    u, v = rng.integers(0, n, 900 + 300 * seed), rng.integers(0, n, 900 + 300 * seed)
    u, v = np.r_[u, np.arange(n - 1)], np.r_[v, np.arange(1, n)]  # and a path through the numbering
    keep = u != v
    A = sparse.csr_matrix((np.ones(keep.sum()), (u[keep], v[keep])), shape=(n, n))
    A = ((A + A.T + sparse.diags((np.arange(n) == 5).astype(float))) > 0).astype(np.float64).tocsr()
    A.sort_indices()
    # parts: stripes of the numbering (connected along the path); odd seeds scatter a few cells
    labels = (np.arange(n) * 7 // n + 1) * (rng.random(n) < 0.9 + 0.1 * (seed % 2))
    indptr, indices = A.indptr.astype(np.int64), A.indices.astype(np.int64)
    assert _equals_transpose(indptr, indices)
    compiled = partition_statistics(indptr, indices, labels)
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    fast = partition_statistics(indptr, indices, labels)
    monkeypatch.delenv("MAGNET_NO_COMPILED")
    U = sparse.triu(A, k=0).tocoo()
    rows = np.r_[U.row, U.row[:1]]
    cols = np.r_[U.col, U.col[:1]]  # one duplicated edge
    order = np.argsort(rows, kind="stable")
    indptr1 = np.r_[0, np.cumsum(np.bincount(rows, minlength=n))]
    assert not _equals_transpose(indptr1, cols[order])
    slow = partition_statistics(indptr1, cols[order], labels)
    for r in (compiled, fast):
        assert r["cut"] == slow["cut"] and r["parts"] == slow["parts"]
        assert r["connected"] == slow["connected"]
        assert r["normalized_cut"] == pytest.approx(slow["normalized_cut"], rel=1e-12)
        assert r["volume_imbalance"] == slow["volume_imbalance"]
    return slow["connected"]


def test_partition_statistics_fast_paths_match_the_general_one(monkeypatch):
    seen = {_partition_paths(seed, monkeypatch) for seed in range(4)}
    assert seen == {True, False}  # connected and disconnected partitions both compared

"""Euler characteristics of elements and of unions of neighbours (models.polytope.euler): the union's
predicted value equals the merged element's, in 2D and 3D; elements touching themselves at a vertex
are found and cut; agglomerations of domains with many holes keep the count asked for."""

import numpy as np
import pytest
from meshes import hexes, quads
from test_hierarchy_holes import _gmsh_2d, _plate

from models.mesh.celldata import compact_labels
from models.mesh.read import mesh_from_arrays
from models.partition.agglomerate import agglomerate
from models.pipeline import prepare, run, split_holes
from models.polytope.euler import element_euler, merge_safely, pinched, union_euler
from models.polytope.merge import merge


def _grid_labels(n, cells):
    """A quad grid n x n; labels from a dict {(i, j): element} (the rest: element 0)."""
    p, q = quads(n)
    m = mesh_from_arrays(p, [("quad", q)])
    c = np.floor(p[q].mean(axis=1) * n).astype(int)
    lab = np.zeros(m.n_cells, dtype=np.int64)
    for (i, j), e in cells.items():
        lab[(c[:, 0] == i) & (c[:, 1] == j)] = e
    return m, lab


def _pinch():
    """3 x 3 quads: the centre cell is element 1; element 0 goes around it and closes the ring only
    at the vertex (1, 2) where cells (0, 1) and (1, 2) meet corner to corner; cell (0, 2) is
    element 2."""
    return _grid_labels(3, {(1, 1): 1, (0, 2): 2})


def test_a_ring_and_a_pinch_have_euler_characteristic_zero():
    # 5 x 5 quads: element 1 the 8 cells around the centre cell (element 2); element 0, the outer
    # 16 cells, goes around all of them: two rings and a disk
    ring = {(i, j): 1 for i in (1, 2, 3) for j in (1, 2, 3)}
    ring[(2, 2)] = 2
    m, lab = _grid_labels(5, ring)
    g, _ = prepare(m)
    assert element_euler(m, g, lab).tolist() == [0, 0, 1]
    assert pinched(m, g, lab)[0].size == 0  # rings, not touches: polygon merging finds their holes
    mp, lp = _pinch()
    gp, _ = prepare(mp)
    assert element_euler(mp, gp, lp).tolist() == [0, 1, 1]
    el, v = pinched(mp, gp, lp)
    assert el.tolist() == [0]
    assert np.allclose(mp.points[v[0]], [1 / 3, 2 / 3])


def test_split_holes_cuts_an_element_that_touches_itself_at_a_vertex():
    m, lab = _pinch()
    g, d = prepare(m)
    _, holes = merge(m, g, lab, d.measures)
    assert holes.elements.size == 0  # one boundary walk: merging alone sees nothing wrong
    poly, new, n_split = split_holes(m, g, d, lab)
    assert n_split == 1
    assert np.all(element_euler(m, g, new) == 1)
    assert pinched(m, g, new)[0].size == 0


@pytest.fixture(scope="module")
def holed_plate():
    pts, tri = _gmsh_2d(lambda occ: _plate(occ, 6), 0.02)
    mesh = mesh_from_arrays(pts, [("triangle", tri)])
    graph, data = prepare(mesh)
    return mesh, graph, data


@pytest.mark.parametrize("model", ["metis", "kmeans"])
def test_union_euler_is_the_merged_elements(holed_plate, model):
    mesh, g, d = holed_plate
    lab = agglomerate(mesh, d, model=model, mode="kway", k=24, seed=0).labels
    chi = element_euler(mesh, g, lab)
    a, b, u, w = union_euler(mesh, g, lab, chi)
    assert a.size > 24 and np.all(a < b) and np.all(w > 0)
    assert set(u.tolist()) - {1} and 1 in u  # some unions are rings (holes between), some disks
    for i in range(a.size):  # a loop over the element pairs of one small agglomeration
        merged = compact_labels(np.where(lab == b[i], a[i], lab))
        e = merged[np.flatnonzero(lab == a[i])[0]]
        assert element_euler(mesh, g, merged)[e] == u[i]


def test_union_euler_in_3d():
    mesh, _ = _block_with_tunnel()
    g, d = prepare(mesh)
    lab = agglomerate(mesh, d, model="metis", mode="kway", k=12, seed=0).labels
    chi = element_euler(mesh, g, lab)
    assert np.all(chi == 1)
    a, b, u, _ = union_euler(mesh, g, lab, chi)
    for i in range(a.size):  # a loop over the element pairs
        merged = compact_labels(np.where(lab == b[i], a[i], lab))
        e = merged[np.flatnonzero(lab == a[i])[0]]
        assert element_euler(mesh, g, merged)[e] == u[i]
    # one element around the tunnel: a handle, 1 - 1
    ring = compact_labels(np.zeros(mesh.n_cells, dtype=np.int64))
    assert element_euler(mesh, g, ring).tolist() == [0]


def test_merge_safely_never_encloses_anything(holed_plate):
    mesh, g, d = holed_plate
    lab = agglomerate(mesh, d, model="metis", mode="kway", k=200, seed=0).labels
    new, merged = merge_safely(mesh, g, lab, 60)
    assert merged == 200 - int(new.max()) - 1 and int(new.max()) + 1 >= 60
    assert np.all(element_euler(mesh, g, new) == 1)
    _, holes = merge(mesh, g, new, d.measures)
    assert holes.elements.size == 0


@pytest.mark.parametrize("k", [3, 6, 16])
@pytest.mark.parametrize("model", ["metis", "rtree", "kmeans"])
def test_many_holes_keep_the_count_asked_for(holed_plate, model, k):
    """36 holes and k = 3 to 16 elements: the cut elements are merged back where the union encloses
    nothing, or the holes are threaded (a path of cells from the hole to a neighbour). Before,
    merging the smallest back made new holes and every one of these was refused."""
    mesh, g, _ = holed_plate
    res = run(mesh, model=model, k=k, compute_metrics=False)
    assert res.poly.n_elements == k
    assert np.all(np.diff(res.poly.elem_offsets) == 1)  # one boundary loop each
    assert np.all(element_euler(mesh, g, res.poly.labels) == 1)
    assert pinched(mesh, g, res.poly.labels)[0].size == 0
    if k < 6:  # fewer elements than holes' rows: only threads can do it
        assert res.agglomeration.recount.get("threaded", 0) > 0


def _block_with_tunnel(n=6):
    p, h = hexes(n)
    p = np.asarray(p, dtype=np.float64)
    c = p[h].mean(axis=1)
    keep = ~((np.abs(c[:, 0] - 0.5) < 0.2) & (np.abs(c[:, 1] - 0.5) < 0.2))  # a square tunnel along z
    mesh = mesh_from_arrays(p, [("hexahedron", h[keep])])
    return mesh, c[keep]


def test_a_ring_around_a_tunnel_is_cut():
    mesh, c = _block_with_tunnel()
    g, d = prepare(mesh)
    lab = (c[:, 2] > 0.5).astype(np.int64)  # two slices across the tunnel: two rings
    assert element_euler(mesh, g, lab).tolist() == [0, 0]
    _, new, n_split = split_holes(mesh, g, d, lab)
    assert n_split >= 2 and np.all(element_euler(mesh, g, new) == 1)
    _, kept, _ = split_holes(mesh, g, d, lab, rings=False)  # as before: rings are left
    assert np.array_equal(kept, lab)


def test_k_that_needs_a_ring_keeps_it_and_says_so():
    mesh, _ = _block_with_tunnel()
    res = run(mesh, model="metis", k=1, compute_metrics=False)
    assert res.poly.n_elements == 1
    assert res.summary()["recount"]["rings_kept"] == 1
    res = run(mesh, model="metis", k=4, compute_metrics=False)
    assert res.summary()["recount"]["rings_kept"] == 0
    assert np.all(element_euler(mesh, res.graph, res.poly.labels) == 1)


def test_a_cavity_touching_the_outside_along_an_edge_is_cut():
    """3 x 3 x 3 hexahedra less the centre (a cubic cavity); element 0 is the 25 cells around it but
    one that shares only an edge with the cavity (element 1): the cavity's surface meets element 0's
    outer surface along that edge, one non-manifold shell, so polyhedron merging finds no inner
    shell; its cells' characteristic is 2."""
    p, h = hexes(3)
    p = np.asarray(p, dtype=np.float64)
    ijk = np.floor(p[h].mean(axis=1) * 3).astype(int)
    keep = ~np.all(ijk == 1, axis=1)
    mesh = mesh_from_arrays(p, [("hexahedron", h[keep])])
    ijk = ijk[keep]
    lab = np.all(ijk == [0, 0, 1], axis=1).astype(np.int64)
    g, d = prepare(mesh)
    assert element_euler(mesh, g, lab).tolist() == [2, 1]
    _, holes = merge(mesh, g, lab, d.measures)
    assert holes.elements.size == 0
    _, new, n_split = split_holes(mesh, g, d, lab, rings=False)  # (always cut, rings or not)
    assert n_split >= 1 and np.all(element_euler(mesh, g, new) == 1)


def test_rings_that_cannot_be_cut_away_are_kept_not_refused():
    """hole_policy="error" refuses holes and cavities; a ring around a tunnel that the count needs is
    kept and said, as before rings were looked for."""
    mesh, _ = _block_with_tunnel()
    res = run(mesh, model="metis", k=1, hole_policy="error", compute_metrics=False)
    assert res.poly.n_elements == 1 and res.summary()["recount"]["rings_kept"] == 1
    res = run(mesh, model="rtree", mode="nref", nref=2, compute_metrics=False)  # no exact count
    assert np.all(element_euler(mesh, res.graph, res.poly.labels) == 1)


def test_a_3d_coarsest_level_above_its_count_is_merged_without_rings():
    from models.hierarchy.nested import is_nested
    from models.hierarchy.rethread import coarse_end
    from models.hierarchy.topology import handle_elements

    mesh, _ = _block_with_tunnel()
    g, d = prepare(mesh)
    coarse = agglomerate(mesh, d, model="metis", mode="kway", k=12, seed=0).labels
    assert np.all(element_euler(mesh, g, coarse) == 1)
    levels = [coarse, np.arange(mesh.n_cells)]
    report = [{"elements": 12, "ratio": mesh.n_cells / 12}, {"elements": mesh.n_cells, "ratio": 1.0}]
    new, polys, report = coarse_end(mesh, d, levels, [None, None], report, (None, None), 4, None)
    k = int(new[0].max()) + 1
    assert 4 <= k < 12 and report[0]["elements"] == k and report[0]["safe_merges"] == 12 - k
    assert is_nested(new) and np.all(element_euler(mesh, g, new[0]) == 1)
    assert handle_elements(mesh, g, new[0]).size == 0  # no ring around the tunnel made


def _unit_cases():
    """(mesh, graph, units per cell, element per unit) on a holed plate (2D) and a block with a
    tunnel (3D): METIS units, grouped at random into fewer elements (some disconnected, some
    rings), and by METIS again (nested)."""
    from models.hierarchy.nested import coarse_graph
    from models.partition import get_partitioner

    mesh2 = mesh_from_arrays(*_gmsh_case())
    mesh3, _ = _block_with_tunnel(8)
    rng = np.random.default_rng(3)
    for mesh, k in ((mesh2, 60), (mesh3, 40)):
        g, d = prepare(mesh)
        units = agglomerate(mesh, d, model="metis", mode="kway", k=k, seed=0).labels
        yield mesh, g, units, compact_labels(rng.integers(0, k // 4, size=k))
        part = np.asarray(get_partitioner("metis").kway(coarse_graph(d, units), k // 6), dtype=np.int64)
        yield mesh, g, units, compact_labels(part)


def _gmsh_case():
    pts, tri = _gmsh_2d(lambda occ: _plate(occ, 6), 0.04)
    return pts, [("triangle", tri)]


def test_unit_euler_is_element_euler_of_the_unions():
    """UnitEuler reads only what units share; its characteristics and its pairs' unions equal
    element_euler and union_euler computed on the cells, at two levels up."""
    from models.polytope.euler import UnitEuler, level_euler

    for mesh, g, units, el in _unit_cases():
        ue = UnitEuler.of_cells(mesh, g, units)
        assert np.array_equal(ue.chi, element_euler(mesh, g, units))
        cells = el[units]
        assert np.array_equal(ue(el), element_euler(mesh, g, cells))
        a, b, u, w = ue.unions(el)
        a0, b0, u0, _ = union_euler(mesh, g, cells)
        assert np.array_equal(a, a0) and np.array_equal(b, b0) and np.array_equal(u, u0)
        assert np.all(w > 0)
        top = np.arange(int(el.max()) + 1) % 3  # a level above (element -> its element): the coarser skeleton
        assert np.array_equal(ue.coarser(el)(top), element_euler(mesh, g, top[cells]))
        # the coarser skeleton is condensed (items shared by the same elements one weighted class)
        a, b, u, _ = ue.coarser(el).unions(top)
        a0, b0, u0, _ = union_euler(mesh, g, top[cells])
        assert np.array_equal(a, a0) and np.array_equal(b, b0) and np.array_equal(u, u0)
        got = level_euler(mesh, g, [top[cells], cells, units])
        assert all(
            np.array_equal(x, element_euler(mesh, g, lv))
            for x, lv in zip(got, [top[cells], cells, units], strict=True)
        )


def test_merge_safely_over_units_makes_balls():
    from models.polytope.euler import UnitEuler

    mesh, _ = _block_with_tunnel(8)
    g, d = prepare(mesh)
    units = agglomerate(mesh, d, model="metis", mode="kway", k=40, seed=0).labels
    ue = UnitEuler.of_cells(mesh, g, units)
    assert np.all(ue.chi == 1)
    new, merged = merge_safely(mesh, g, np.arange(40), 4, unions=ue.unions)
    k = int(new.max()) + 1
    assert merged == 40 - k and k <= 6  # (a ring around the tunnel needs 2 at least)
    assert np.all(element_euler(mesh, g, new[units]) == 1)


def test_merge_ahead_makes_balls_one_merge_at_a_time():
    from models.polytope.euler import UnitEuler, merge_ahead

    mesh, _ = _block_with_tunnel(8)
    g, d = prepare(mesh)
    units = agglomerate(mesh, d, model="metis", mode="kway", k=40, seed=0).labels
    ue = UnitEuler.of_cells(mesh, g, units)
    new, merged = merge_ahead(mesh, g, np.arange(40), 4, unions=ue.unions, width=3)
    k = int(new.max()) + 1
    assert merged == 40 - k and k <= 6
    assert np.all(element_euler(mesh, g, new[units]) == 1)
    # groups kept apart (a group per unit: the half its centroid lies in): no element across them
    cx = np.bincount(units, weights=d.centroids[:, 0], minlength=40) / np.bincount(units, minlength=40)
    unit_half = (cx > np.median(cx)).astype(np.int64)
    kept, _ = merge_ahead(mesh, g, np.arange(40), 2, unions=ue.unions, keep=unit_half)
    assert int(kept.max()) + 1 >= 2
    assert all(np.unique(unit_half[kept == e]).size == 1 for e in range(int(kept.max()) + 1))


def test_unique_rows_is_numpys():
    from models.polytope.euler import UnitEuler

    rng = np.random.default_rng(3)
    t = rng.integers(-1, 6, size=(500, 4))
    t = np.vstack([t, t[:100]])
    rows, inv = UnitEuler._unique_rows(t)
    r0, i0 = np.unique(t, axis=0, return_inverse=True)
    assert np.array_equal(
        np.sort(rows.view([("", rows.dtype)] * 4), axis=0).view(rows.dtype).reshape(-1, 4), r0
    )
    assert np.array_equal(rows[inv], t) and rows.shape[0] == r0.shape[0]
    assert i0.size == inv.size


def _tall_cup(n=10):
    """Hexahedra: a cup n x n x n (stretched 4x in z), walls and bottom one cell thick. Genus 0, one
    boundary shell: a slab of its wall is a ring around the bottom's neighbours, nothing else."""
    p, h = hexes(n)
    p = np.asarray(p, dtype=np.float64)
    c = p[h].mean(axis=1) * n
    inner = (c[:, 0] > 1) & (c[:, 0] < n - 1) & (c[:, 1] > 1) & (c[:, 1] < n - 1) & (c[:, 2] > 1)
    p[:, 2] *= 4
    return mesh_from_arrays(p, [("hexahedron", h[~inner])])


@pytest.mark.parametrize("model", ["rtree", "kmeans"])
def test_flat_rings_around_a_neighbour_on_a_plain_domain_are_cut(model):
    """rtree cuts a tall cup across its height: slabs of the wall above the bottom were rings (1-4
    of them at k = 2-8, looked for only on domains with a tunnel or a cavity); now the merge's
    surfaces say which elements to look at, on every domain."""
    mesh = _tall_cup()
    g, _ = prepare(mesh)
    for k in (2, 3, 4, 6):
        res = run(mesh, model=model, k=k, compute_metrics=False)
        assert res.poly.n_elements == k
        assert np.all(element_euler(mesh, g, res.poly.labels) == 1)

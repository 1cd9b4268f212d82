"""Coarse 3D levels repaired into balls (models.hierarchy.repair): single units moved between
neighbouring elements until no element has a handle or a cavity; levels cut anew above a unit level
that way stay nested and meet their counts."""

import numpy as np
from meshes import hexes

from models.graph.csr import connected_components
from models.hierarchy.repair import balls_above, unit_repair
from models.mesh.read import mesh_from_arrays
from models.pipeline import prepare
from models.polytope.euler import element_euler


def _grid(n):
    p, h = hexes(n)
    mesh = mesh_from_arrays(p, [("hexahedron", h)])
    _, data = prepare(mesh)
    ijk = np.floor(data.centroids * n).astype(int)
    return mesh, data, ijk


def _balls(rep, lab):
    chi = rep.ue(lab)
    return [rep.judge(np.flatnonzero(lab == e), chi[e]) for e in range(int(lab.max()) + 1)]


def test_a_ring_and_the_rest_around_it_are_repaired_into_two_balls():
    # 6 x 6 x 6 cubes: element 1 a ring of cells around the central column at two heights, element 0
    # the rest (it runs through the ring and holds it in a cavity: a handle and a cavity, chi 1)
    mesh, data, ijk = _grid(6)
    i, j, k = ijk.T
    ring = (i >= 1) & (i <= 4) & (j >= 1) & (j <= 4) & (k >= 2) & (k <= 3)
    ring &= ~((i >= 2) & (i <= 3) & (j >= 2) & (j <= 3))
    lab = ring.astype(np.int64)
    rep = unit_repair(mesh, data, np.arange(mesh.n_cells))
    assert element_euler(mesh, data.graph, lab).tolist() == [1, 0]
    assert _balls(rep, lab) == [2, 1]
    got, left, moves = rep.run(lab.copy(), 0, mesh.n_cells)
    assert left == 0 and moves > 0
    assert _balls(rep, got) == [0, 0]
    assert element_euler(mesh, data.graph, got).tolist() == [1, 1]


def test_a_move_that_would_enclose_a_cavity_is_not_a_ball():
    # element 1: a hollow 3 x 3 x 3 shell of cells around one cell of element 0 (chi 2: a cavity)
    mesh, data, ijk = _grid(5)
    i, j, k = ijk.T
    shell = np.all((ijk >= 1) & (ijk <= 3), axis=1) & ~((i == 2) & (j == 2) & (k == 2))
    lab = shell.astype(np.int64)
    rep = unit_repair(mesh, data, np.arange(mesh.n_cells))
    assert _balls(rep, lab)[1] == 1  # one cavity
    assert _balls(rep, lab)[0] is None  # the enclosed cell is cut off from the rest of element 0


def test_levels_cut_anew_above_a_unit_level_are_nested_balls_of_the_planned_counts():
    mesh, data, ijk = _grid(10)
    units = (ijk // 2) @ np.array([25, 5, 1])  # 125 units of 2 x 2 x 2 cells
    plan = [3, 17, 125]
    levels = [np.zeros(mesh.n_cells, dtype=np.int64)] * 2 + [units]
    got = balls_above(mesh, data, levels, 2, plan)
    assert got is not None
    assert [int(lv.max()) + 1 for lv in got] == plan
    for lv in got:
        assert np.all(element_euler(mesh, data.graph, lv) == 1)
        assert connected_components(data.graph.indptr, data.graph.indices, labels=lv)[0] == int(lv.max()) + 1
    for coarse, fine in zip(got[:-1], got[1:], strict=True):  # each element inside one of the level above
        pairs = np.unique(fine * np.int64(1000) + coarse)
        assert np.unique(pairs // 1000).size == pairs.size
    rep = unit_repair(mesh, data, units)
    assert all(c == 0 for c in _balls(rep, got[0][np.unique(units, return_index=True)[1]]))


def test_two_separate_solids_each_get_their_share_of_balls():
    p, h = hexes(8)
    mesh = mesh_from_arrays(np.vstack([p, p + [2.0, 0, 0]]), [("hexahedron", np.vstack([h, h + len(p)]))])
    _, data = prepare(mesh)
    ijk = np.floor(data.centroids * 8).astype(int) % 8
    body = (data.centroids[:, 0] > 1.5).astype(np.int64)
    units = body * 64 + (ijk // 2) @ np.array([16, 4, 1])  # 2 x 64 units of 2 x 2 x 2 cells
    plan = [5, 22, 128]
    got = balls_above(mesh, data, [units, units, units], 2, plan)
    assert got is not None and [int(lv.max()) + 1 for lv in got] == plan
    for lv in got[:2]:
        assert np.all(element_euler(mesh, data.graph, lv) == 1)
        assert np.all(np.bincount(lv, weights=body) % np.bincount(lv) == 0)  # no element in both solids


def _tube_and_core():
    """A 12 x 12 x 36 block of cubes, its 4 x 4 core column through its length a second physical
    group: the rest is a tube (a tunnel: two elements at least)."""
    p, h = hexes(12)
    pts = np.vstack([p + [0, 0, s] for s in range(3)])
    hx = np.vstack([h + s * len(p) for s in range(3)])
    pts, inv = np.unique(np.round(pts, 9), axis=0, return_inverse=True)
    hx = inv.reshape(-1)[hx]
    cen = pts[hx].mean(axis=1)
    core = np.all(np.abs(cen[:, :2] - 0.5) < 0.17, axis=1)
    mesh = mesh_from_arrays(pts, [("hexahedron", hx)], tags=[core.astype(np.int64) + 1])
    return mesh, core.astype(np.int64)


def test_physical_groups_plan_two_elements_for_a_piece_around_another():
    from models.hierarchy.plan import group_pieces

    mesh, core = _tube_and_core()
    _, data = prepare(mesh)
    assert group_pieces(data, core, 1, "", mesh)[0] == 3  # the core, and the tube around it twice
    halves = (data.centroids[:, 0] > 0.5).astype(np.int64)
    assert group_pieces(data, halves, 1, "", mesh)[0] == 2


def test_a_tube_is_cut_along_its_length_by_planes():
    # the tube's longest principal axis runs along the core: a slice across it makes two rings
    from models.hierarchy.repair import _planes

    mesh, core = _tube_and_core()
    _, data = prepare(mesh)
    ijk = np.floor(data.centroids * [12, 12, 12]).astype(int)
    units = (ijk // 2) @ np.array([1, 6, 36])  # 6 x 6 x 18 units of 2 x 2 x 2 cells
    ku = int(units.max()) + 1
    ug = np.zeros(ku, dtype=np.int64)
    ug[units] = core
    rep = unit_repair(mesh, data, units, groups=ug)
    cen = np.zeros((ku, 3))
    np.add.at(cen, units, data.centroids / 8)
    tube = np.flatnonzero(ug == 0)
    lab = _planes(rep, tube, 2, cen)
    chi = rep.ue(np.where(ug == 0, 0, 2)[np.arange(ku)] + np.isin(np.arange(ku), tube[lab == 1]))
    for part in (0, 1):
        assert rep.judge(tube[lab == part], chi[part]) == 0  # a ball each
    assert np.ptp(cen[tube[lab == 0], 2]) > 2.5  # along the whole length (3), not across


def test_levels_with_physical_groups_are_repaired_apart():
    from models.hierarchy.nested import build_hierarchy

    mesh, core = _tube_and_core()
    graph, data = prepare(mesh)
    levels, info = build_hierarchy(mesh, data, model="rtree", groups=True, coarsest=3)
    assert info["requested"][0] == 3 and [int(lv.max()) + 1 for lv in levels] == info["requested"]
    assert info["report"][0]["repaired_from_level"] >= 1
    for lv in levels:
        assert np.all(element_euler(mesh, graph, lv) == 1)
        assert np.all(np.bincount(lv, weights=core) % np.bincount(lv) == 0)  # no element in both groups
    for coarse, fine in zip(levels[:-1], levels[1:], strict=True):
        pairs = np.unique(fine * np.int64(10**6) + coarse)
        assert np.unique(pairs // 10**6).size == pairs.size


def _grouped_block(axes):
    """16^3 cubes, a second physical group of 2 x 2 cells (along `axes`) in each octant: 8 cube
    inclusions (all three axes) or 4 fibres (x and y); units of 2 x 2 x 2 cells. (mesh, data, units,
    each cell's group)."""
    _, _, ijk = _grid(16)
    group = np.all((ijk[:, axes] % 8 >= 2) & (ijk[:, axes] % 8 <= 3), axis=1).astype(np.int64)
    p, h = hexes(16)
    mesh = mesh_from_arrays(p, [("hexahedron", h)], tags=[group + 1])
    _, data = prepare(mesh)
    return mesh, data, (ijk // 2) @ np.array([64, 8, 1]), group


def _balls_apart(mesh, data, levels, groups):
    for lv in levels:
        assert np.all(element_euler(mesh, data.graph, lv) == 1)
        assert np.all(np.bincount(lv, weights=groups) % np.bincount(lv) == 0)  # no element in both


def test_a_matrix_around_more_inclusions_than_its_share_is_cut_by_planes_through_them():
    """8 cube inclusions (a physical group) in a 16^3 block, 10 coarsest planned: the matrix's share
    is 2, with 8 cavities that single moves cannot open; planes through the inclusions give it 3
    balls (11 coarsest, within the count's 25%), where the repair gave up before."""
    mesh, data, units, groups = _grouped_block([0, 1, 2])
    got = balls_above(mesh, data, [units, units, units], 2, [10, 60, 512], groups=groups)
    assert got is not None and 10 < int(got[0].max()) + 1 <= 12
    _balls_apart(mesh, data, got[:2], groups)
    rep = unit_repair(mesh, data, units)
    first = np.unique(units, return_index=True)[1]
    assert all(c == 0 for c in _balls(rep, got[0][first]))  # no element encloses an inclusion


def test_a_matrix_around_more_fibres_than_its_share_is_cut_through_them():
    """4 square fibres (a physical group) through a 16^3 block, 6 coarsest planned: the matrix (4
    tunnels) gets 2; planes through the fibres and a repair of the matrix alone give it 3 balls."""
    mesh, data, units, groups = _grouped_block([0, 1])
    got = balls_above(mesh, data, [units, units, units], 2, [6, 60, 512], groups=groups)
    assert got is not None and 6 < int(got[0].max()) + 1 <= 7
    _balls_apart(mesh, data, got[:2], groups)


def _local(indptr, indices, lab, ku, u, elem, same, budget=512, count=1):
    """local_pieces on a small graph, a fresh mark each call."""
    from models.native import compiled

    fast = compiled("graph._fastgraph")
    n = indptr.size - 1
    mark, queue = np.full(n, -1, dtype=np.int64), np.empty(n, dtype=np.int64)
    args = (np.asarray(indptr, np.int64), np.asarray(indices, np.int64), np.asarray(lab, np.int64))
    return fast.local_pieces(*args, mark, queue, ku, u, elem, same, budget, 1, count)


def _csr(n, edges):
    a = np.array(edges + [(b, a) for a, b in edges], dtype=np.int64)
    a = a[np.lexsort((a[:, 1], a[:, 0]))]
    return np.searchsorted(a[:, 0], np.arange(n + 1)), np.ascontiguousarray(a[:, 1])


def test_the_pieces_a_set_falls_into_without_one_node_are_found_near_it():
    # a cycle of 8 units (0..7) and a path 8-9-10 hanging off unit 0; node 11: the outside, next to
    # units 4 and 9
    edges = [(i, (i + 1) % 8) for i in range(8)] + [(0, 8), (8, 9), (9, 10), (4, 11), (9, 11)]
    ptr, ind = _csr(12, edges)
    lab = np.zeros(11, dtype=np.int64)  # every unit in element 0
    assert _local(ptr, ind, lab, 11, 2, 0, 1) == 1  # a cycle less a node: one piece
    assert _local(ptr, ind, lab, 11, 0, 0, 1) == 2  # unit 0 joins the cycle and the path
    assert _local(ptr, ind, lab, 11, 9, 0, 1) == 2
    assert _local(ptr, ind, lab, 11, 0, 0, 1, count=0) == 2  # (two or more)
    assert _local(ptr, ind, lab, 11, 10, 0, 1) == 1  # an end of the path
    assert _local(ptr, ind, lab, 11, 0, 0, 1, budget=-1) == 3  # its neighbours, counted
    assert _local(ptr, ind, lab, 11, 0, 0, 1, budget=2) == -1  # over budget: unknown
    # the complement of element 1 = {8}: units 0..7, 9, 10 and the outside; less unit 9 (in it), the
    # pieces 10 alone and the rest through the outside
    lab1 = lab.copy()
    lab1[8] = 1
    assert _local(ptr, ind, lab1, 11, 9, 1, 0) == 2
    # element 1 = {4, 9}: its complement less unit 0 falls into the arcs 1-3 and 5-7 and unit 8 (the
    # units next to the outside are 4 and 9, not in it)
    lab2 = lab.copy()
    lab2[[4, 9]] = 1
    assert _local(ptr, ind, lab2, 11, 0, 1, 0) == 3
    # two special nodes: pieces that reach different ones may meet through them: unknown
    edges2 = [(0, 1), (1, 2), (0, 3), (3, 4), (2, 5), (4, 6), (5, 7), (6, 7)]  # units 0..5, nodes 6, 7
    ptr2, ind2 = _csr(8, edges2)
    assert _local(ptr2, ind2, np.zeros(6, dtype=np.int64), 6, 0, 1, 0) == -1


def test_the_repair_checks_near_a_move_give_the_whole_graphs_answers(monkeypatch):
    """Repair._near against the whole graph's check on every move tried (VERIFY asserts each pair),
    and the same repair with the whole graph's checks only: the same labels."""
    import models.hierarchy.repair as rp

    mesh, data, ijk = _grid(6)
    i, j, k = ijk.T
    ring = (i >= 1) & (i <= 4) & (j >= 1) & (j <= 4) & (k >= 2) & (k <= 3)
    ring &= ~((i >= 2) & (i <= 3) & (j >= 2) & (j <= 3))
    lab = ring.astype(np.int64)
    got = {}
    for mode in (True, "whole"):
        monkeypatch.setattr(rp, "VERIFY", mode)
        rep = unit_repair(mesh, data, np.arange(mesh.n_cells))
        got[mode] = rep.run(lab.copy(), 0, mesh.n_cells)
        if mode is True:
            assert rep.near > 0
        else:
            assert rep.near == 0
    assert np.array_equal(got[True][0], got["whole"][0]) and got[True][1:] == got["whole"][1:]
    # the fibres' matrix cut by planes and repaired: every check verified
    monkeypatch.setattr(rp, "VERIFY", True)
    mesh, data, units, groups = _grouped_block([0, 1])
    assert balls_above(mesh, data, [units, units, units], 2, [6, 60, 512], groups=groups) is not None

"""Nested hierarchies: every level's element is exactly a union of elements of the next finer level."""

import json

import numpy as np
import pytest
from conftest import BRAIN
from meshes import tets

from models.errors import ParameterError
from models.hierarchy.nested import is_nested, nested_levels
from models.mesh.read import mesh_from_arrays, read_mesh
from models.pipeline import run, write_hierarchy


def check_nested_files(out, index, n_cells):
    levels = [np.asarray(json.load(open(out / lv["labels"]))) for lv in index["levels"]]
    assert all(lab.size == n_cells for lab in levels)
    counts = [int(lab.max()) + 1 for lab in levels]
    assert counts == [lv["elements"] for lv in index["levels"]]
    assert counts == sorted(counts) and len(set(counts)) == len(counts)
    for L in range(1, len(levels)):
        parent = np.asarray(json.load(open(out / index["levels"][L]["parent"])))
        assert parent.size == counts[L]
        # exact nesting: the coarse label of every cell is the parent of its fine element
        assert np.array_equal(parent[levels[L]], levels[L - 1])
        assert (out / index["levels"][L]["mesh"]).is_file()
    return levels


@pytest.mark.parametrize(
    "mode,extra",
    [
        ("nref", {"nref": 4}),
        ("multilevel", {"nref": 4, "refiner": "fm"}),
        ("mult-factor", {"mult_factor": 0.3}),
    ],
)
def test_brain_hierarchy_is_nested(tmp_path, mode, extra):
    mesh = read_mesh(BRAIN)
    res = run(mesh, model="metis", mode=mode, record_levels=True, compute_metrics=False, **extra)
    index = write_hierarchy(res, str(tmp_path), metrics=False)
    assert index["nested"]
    levels = check_nested_files(tmp_path, index, mesh.n_cells)
    assert np.array_equal(levels[-1], res.agglomeration.labels)  # the finest level is the result
    assert levels[0].max() == 0  # the coarsest is the whole (connected) mesh
    if mode != "mult-factor":
        assert len(levels) == 5
    json.load(open(tmp_path / "level_2.metrics.json"))["partition"]["normalized_cut"]


def test_3d_hierarchy_with_metrics(tmp_path):
    p, t = tets(6)
    mesh = mesh_from_arrays(p, [("tetra", t)])
    res = run(mesh, model="metis", mode="nref", nref=3, record_levels=True, compute_metrics=False)
    index = write_hierarchy(res, str(tmp_path), metrics=True)
    check_nested_files(tmp_path, index, mesh.n_cells)
    rep = json.load(open(tmp_path / "level_3.metrics.json"))
    assert "sphericity" in rep["summary"]


def test_nesting_survives_fragment_absorption(tmp_path):
    mesh = read_mesh(BRAIN)
    res = run(
        mesh,
        model="kmeans",
        mode="nref",
        nref=5,
        absorb_fraction=0.3,
        record_levels=True,
        compute_metrics=False,
    )
    levels = nested_levels(
        res.data, res.agglomeration.labels, res.agglomeration.levels, res.agglomeration.nodes, mesh
    )
    assert is_nested(levels)
    assert np.array_equal(levels[-1], res.agglomeration.labels)


def test_kway_has_no_hierarchy(tmp_path):
    mesh = read_mesh(BRAIN)
    res = run(mesh, model="metis", mode="kway", k=8, record_levels=True, compute_metrics=False)
    with pytest.raises(ParameterError, match="recursive mode"):
        write_hierarchy(res, str(tmp_path))


def brain_or_cube(dim: int, n: int):
    """The brain (dim 2) or a structured cube of n^3 x 6 tetrahedra (dim 3)."""
    if dim == 2:
        return read_mesh(BRAIN)
    p, t = tets(n)
    return mesh_from_arrays(p, [("tetra", t)])


@pytest.mark.parametrize("dim", [2, 3])
def test_level_statistics_equal_the_per_level_metrics(dim):
    """The batched statistics write_hierarchy writes without --metrics are metrics' own numbers."""
    from models.hierarchy.nested import build_hierarchy, level_statistics
    from models.pipeline import prepare
    from models.quality.partition_stats import partition_statistics
    from models.quality.report import box_measures
    from models.quality.summary import summarize

    mesh = brain_or_cube(dim, 6)
    graph, data = prepare(mesh)
    levels, _ = build_hierarchy(mesh, data, model="rtree", ratio=4, coarsest=4)
    # the finest level with two non-adjacent children of one parent merged: nested, one element
    # disconnected, which the batched connectedness must tell (then from the fine graph)
    fine, par = levels[-1], levels[-2]
    rows = np.repeat(np.arange(fine.size), np.diff(graph.indptr))
    touching = set(zip(fine[rows].tolist(), fine[graph.indices].tolist(), strict=True))
    pmap = np.zeros(int(fine.max()) + 1, dtype=np.int64)
    pmap[fine] = par
    pair = next(
        (e1, e2)
        for e1 in range(pmap.size)
        for e2 in range(e1 + 1, pmap.size)
        if pmap[e1] == pmap[e2] and (e1, e2) not in touching
    )
    broken = np.unique(np.where(fine == pair[1], pair[0], fine), return_inverse=True)[1]
    for lv in (levels, levels[:-1] + [broken]):
        assert is_nested(lv)
        stats = level_statistics(mesh, graph, lv, data.measures)
        for lab, st in zip(lv, stats, strict=True):
            bm = box_measures(mesh.points, mesh.offsets, mesh.connectivity, lab, data.measures)
            assert st["coverage"] == pytest.approx(bm["coverage"], rel=1e-12)
            assert st["summary"]["box_ratio"] == pytest.approx(summarize(bm["box_ratio"]), rel=1e-12)
            ps = partition_statistics(graph.indptr, graph.indices, lab)
            assert st["partition"] == pytest.approx(ps, rel=1e-12)
            assert st["elements"] == int(lab.max()) + 1
    assert not stats[-1]["partition"]["connected"] and stats[-2]["partition"]["connected"]


def test_int_list_json_reads_back():
    from models.hierarchy.nested import _int_list_json

    rng = np.random.default_rng(0)
    for v in (np.array([0]), np.array([7, 0, 10, 99, 100]), rng.integers(0, 10**7, 1000), np.zeros(0, int)):
        assert json.loads(_int_list_json(v)) == v.tolist()


def test_cavities_found_on_the_element_graph_as_merging_finds_them():
    """cavity_elements (3D, no merge) flags the elements merging finds with an inner shell."""
    from models.hierarchy.nested import _has_voids, build_hierarchy, cavity_elements
    from models.pipeline import prepare
    from models.polytope.merge import merge

    p, t = tets(6)
    mesh = mesh_from_arrays(p, [("tetra", t)])
    graph, data = prepare(mesh)
    assert not _has_voids(mesh, graph)
    c = data.centroids
    inner = np.all(np.abs(c - 0.5) < 1 / 6, axis=1)
    shell = np.all(np.abs(c - 0.5) < 2 / 6, axis=1) & ~inner
    nested_shells = np.where(inner, 1, np.where(shell, 0, 2))  # 0 encloses 1, and 2 encloses 0 and 1
    levels, _ = build_hierarchy(mesh, data, model="rtree", ratio=4, coarsest=4)
    for lab in [nested_shells, np.where(inner, 1, 0), *levels]:
        _, holes = merge(mesh, graph, lab, data.measures)
        assert np.array_equal(cavity_elements(graph, lab), np.unique(holes.elements))
    assert np.array_equal(cavity_elements(graph, nested_shells), [0, 2])


def test_mtx_written_by_numpy_reads_back(tmp_path):
    import scipy.io

    from models.hierarchy.nested import _write_mtx, aggregation_operators

    lab = np.random.default_rng(1).permutation(np.arange(1234) % 97)
    P = aggregation_operators([lab], lab.size)[0]
    _write_mtx(str(tmp_path / "p.mtx"), P.indices, P.shape[1], " test")
    M = scipy.io.mmread(tmp_path / "p.mtx")
    assert M.shape == P.shape and (abs(M.tocsr() - P) != 0).nnz == 0 and M.dtype.kind == "i"


@pytest.mark.parametrize("dim", [2, 3])
def test_level_vtus_with_the_shared_points_are_write_vtus_own(tmp_path, dim):
    """write_hierarchy encodes the Points array once for the levels that share it: every level's file
    is byte for byte what write_vtu writes for that level on its own."""
    import dataclasses

    from models.export.vtu import points_xml, write_vtu
    from models.hierarchy.nested import _same_points, build_hierarchy
    from models.hierarchy.nested import write_hierarchy as write_levels
    from models.pipeline import prepare
    from models.polytope.merge import merge, sort_by_vertex_count

    mesh = brain_or_cube(dim, 5)
    graph, data = prepare(mesh)
    levels, _ = build_hierarchy(mesh, data, model="rtree", ratio=8, coarsest=4)
    index = write_levels(tmp_path / "h", mesh, data, levels, metrics=False)
    assert len(index["levels"]) == len(levels) >= 2
    polys = [sort_by_vertex_count(merge(mesh, graph, lab, data.measures)[0]) for lab in levels]
    for poly, lv in zip(polys, index["levels"], strict=True):
        write_vtu(tmp_path / "own.vtu", poly)
        assert (tmp_path / "h" / lv["mesh"]).read_bytes() == (tmp_path / "own.vtu").read_bytes()
        write_vtu(tmp_path / "given.vtu", poly, points_xml=points_xml(poly))
        assert (tmp_path / "given.vtu").read_bytes() == (tmp_path / "own.vtu").read_bytes()
    assert _same_points(polys[0], polys[-1])
    assert not _same_points(polys[0], dataclasses.replace(polys[-1], points=polys[-1].points + 1.0))


def test_element_graph_from_the_rtree_quotient_is_the_cells_one():
    """_fix_holes takes the levels' element graphs from rtree_levels (outside node appended, in the
    numbering of the returned levels) instead of a pass over the cells' graph: the same entries row
    by row. And _has_voids finds a void (cells removed inside the cube) as merging does."""
    from models.graph.batch import GraphBatch
    from models.hierarchy.nested import _element_graph, _has_voids, _with_outside
    from models.partition.rtree import level_counts, rtree_levels
    from models.pipeline import prepare

    p, t = tets(6)
    mesh = mesh_from_arrays(p, [("tetra", t)])
    graph, data = prepare(mesh)
    n = mesh.n_cells
    batch = GraphBatch(
        indptr=graph.indptr,
        indices=graph.indices,
        weights=graph.weights,
        graph_ptr=np.array([0, n]),
        centroids=data.centroids,
        measures=data.measures,
        tags=data.tags,
        node_ids=np.arange(n),
    )
    graphs = []
    levels = rtree_levels(batch, level_counts(n, 4, 4), graphs=graphs)
    assert len(graphs) == len(levels) - 1
    for lab, (qp, qi) in zip(levels[::-1], graphs, strict=False):
        a, b = _element_graph(graph, lab), _with_outside(graph, lab, qp, qi)
        b.sort_indices()  # rows renumbered along the sweep keep their entries' order
        assert np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)
    inner = np.all(np.abs(data.centroids - 0.5) < 1 / 6, axis=1)
    hollow = mesh_from_arrays(p, [("tetra", t[~inner])])
    assert _has_voids(hollow, prepare(hollow)[0]) and not _has_voids(mesh, graph)


def test_digits_are_pythons_right_aligned_format():
    from models.hierarchy.nested import _digits

    rng = np.random.default_rng(3)
    for v in (np.array([0, 7, 10, 99, 100, 999, 1000, 1001, 123456, 10**6]), rng.integers(0, 10**10, 5000)):
        for width in range(len(str(int(v.max()))), len(str(int(v.max()))) + 4):
            assert _digits(v, width).tobytes().decode("ascii") == "".join(f"{x:{width}d}" for x in v)

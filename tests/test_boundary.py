"""Boundary groups survive agglomeration: gmsh physical curves / surfaces are read as tagged edges /
faces, every agglomerated boundary edge (face) keeps the tag of the side it lies on, boundary length
(area) per tag is unchanged, lymph's bc_tag and id say so, and the VTU output reads back with its
groups. Meshes: tests/data/{square_sides,square_inclusion,cube_faces}.msh (made by
tests/data/make_boundary_meshes.py with gmsh)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

from models import pipeline
from models.export.lymph import lymph_from_mat, lymph_structs
from models.mesh.boundary import NO_TAG, check_lines, fine_boundary, summary
from models.mesh.check import mesh_report
from models.mesh.read import describe, mesh_from_arrays, read_mesh

DATA = Path(__file__).parent / "data"
ROOT = Path(__file__).parent.parent
SQUARE, INCLUSION, CUBE = DATA / "square_sides.msh", DATA / "square_inclusion.msh", DATA / "cube_faces.msh"
SIDE_TAGS = {
    2: (1, 0.0),
    3: (0, 1.0),
    4: (1, 1.0),
    5: (0, 0.0),
}  # tag -> (axis, value): bottom right top left
CUBE_TAGS = {11 + 2 * a + s: (a, float(s)) for a in range(3) for s in (0, 1)}
RUNS = [
    ("metis", "kway", {"k": 12}),
    ("kmeans", "kway", {"k": 12}),
    ("sage-base", "nref", {"nref": 3}),
    ("sage-hetero", "nref", {"nref": 3}),
    ("metis", "segregated", {"mult_factor": 0.3}),
    ("kmeans", "segregated", {"mult_factor": 0.3}),
    ("sage-base", "segregated", {"mult_factor": 0.3}),
]


def side_of(mid: np.ndarray, sides: dict) -> np.ndarray:
    """The tag of the side each midpoint lies on (-1 if none)."""
    out = np.full(len(mid), -1)
    for tag, (axis, value) in sides.items():
        out[np.abs(mid[:, axis] - value) < 1e-12] = tag
    return out


def check_lymph(region: dict, fine_tags: np.ndarray | None = None) -> None:
    bc = region["connectivity_bc"] - 1
    mid = 0.5 * (region["coord"][bc[:, 0]] + region["coord"][bc[:, 1]])
    want = side_of(mid, SIDE_TAGS)
    assert (want > 0).all(), "a boundary edge whose midpoint is on no side"
    np.testing.assert_array_equal(region["bc_tag"], want)
    length = np.linalg.norm(region["coord"][bc[:, 1]] - region["coord"][bc[:, 0]], axis=1)
    for t in SIDE_TAGS:  # each side has length 1
        assert abs(length[region["bc_tag"] == t].sum() - 1.0) < 1e-12


def assert_boundary_report(rep: dict, kind: str) -> None:
    assert rep["kind"] == kind and rep["untagged"] == {}
    for g in rep["groups"].values():
        assert g["facets_before"] == g["facets_after"] > 0
        assert abs(g["measure_after"] - g["measure_before"]) <= 1e-12 * g["measure_before"]


@pytest.mark.parametrize(("model", "mode", "kw"), RUNS, ids=[f"{m}-{o}" for m, o, _ in RUNS])
def test_square_sides_keep_their_tags(tmp_path, model, mode, kw):
    mesh = read_mesh(SQUARE)
    res = pipeline.run(mesh, model=model, mode=mode, **kw)
    assert res.poly.n_elements >= 4
    out = pipeline.write_outputs(res, metrics=str(tmp_path / "m.json"), lymph=str(tmp_path / "l.mat"))
    region, _ = lymph_from_mat(out["lymph"])
    check_lymph(region)
    assert (region["id"] == 1).all()  # the surface's physical group
    rep = json.loads(Path(out["metrics"]).read_text())["boundary"]
    assert sorted(rep["groups"]) == ["2", "3", "4", "5"] and rep["groups"]["2"]["name"] == "bottom"
    assert_boundary_report(rep, "length")


@pytest.mark.parametrize(
    ("model", "mode", "kw"),
    [r for r in RUNS if r[1] != "nref"] + [("sage-hetero", "segregated", {"mult_factor": 0.3})],
    ids=lambda x: str(x) if not isinstance(x, dict) else "",
)
def test_inclusion_materials_and_interface(tmp_path, model, mode, kw):
    mesh = read_mesh(INCLUSION)
    assert mesh.physical_groups() == [1, 2]
    res = pipeline.run(mesh, model=model, mode=mode, **kw)
    poly = res.poly
    region, neighbor = lymph_structs(poly)
    check_lymph(region)
    labels = res.agglomeration.labels
    # id: the element's physical group (the majority of its fine cells; the only one when segregated)
    major = np.array([np.bincount(mesh.tags[labels == e]).argmax() for e in range(poly.n_elements)])
    np.testing.assert_array_equal(region["id"], major)
    rep = pipeline.write_outputs(res, metrics=str(tmp_path / "m.json"))
    rep = json.loads(Path(rep["metrics"]).read_text())["boundary"]
    assert_boundary_report(rep, "length")
    iface = rep["interfaces"]["6"]
    assert iface["name"] == "interface" and iface["facets_before"] == 23
    if mode != "segregated":
        return
    # segregated: every element is one material, and the interface curve stays an edge of both neighbours
    for e in range(poly.n_elements):
        assert np.unique(mesh.tags[labels == e]).size == 1
    assert (
        iface["facets_after"] == 23
        and abs(iface["measure_after"] - iface["measure_before"]) <= 1e-12 * iface["measure_before"]
    )
    on6 = poly.facet_tags == 6
    assert on6.sum() == 2 * 23 and not poly.facet_on_boundary[on6].any()
    # in lymph's neighbour struct, the interface edges have an element on the other side, of the other material
    conn = np.concatenate(region["connectivity"]) - 1
    nxt = np.concatenate([np.roll(c, -1) for c in region["connectivity"]]) - 1
    from models.mesh.boundary import edge_tags

    used = np.unique(poly.loop_nodes)  # lymph's compact numbering keeps the sorted used points
    t = edge_tags(poly, used[conn], used[nxt], default=0)
    nb = np.concatenate(neighbor["neigh"])
    owner = np.repeat(np.arange(region["ne"]), region["nedges"])
    assert (t == 6).sum() == 46 and (nb[t == 6] > 0).all()
    assert (region["id"][owner[t == 6]] != region["id"][nb[t == 6] - 1]).all()


@pytest.mark.parametrize(
    ("model", "mode", "kw"),
    [
        ("metis", "kway", {"k": 10}),
        ("kmeans", "kway", {"k": 10}),
        ("sage-base", "nref", {"nref": 3}),
        ("metis", "segregated", {"mult_factor": 0.5}),
    ],
)
def test_cube_faces_keep_their_tags(tmp_path, model, mode, kw):
    mesh = read_mesh(CUBE)
    res = pipeline.run(mesh, model=model, mode=mode, **kw)
    poly = res.poly
    fo = poly.loop_offsets
    on = poly.facet_on_boundary
    sizes = np.diff(fo)
    owner = np.repeat(np.arange(sizes.size), sizes)
    cen = np.column_stack([np.bincount(owner, poly.points[poly.loop_nodes, d]) / sizes for d in range(3)])
    np.testing.assert_array_equal(poly.facet_tags[on], side_of(cen[on], CUBE_TAGS))
    assert (poly.facet_tags[~on] == NO_TAG).all()
    out = pipeline.write_outputs(res, vtu=str(tmp_path / "c.vtu"), metrics=str(tmp_path / "m.json"))
    rep = json.loads(Path(out["metrics"]).read_text())["boundary"]
    assert sorted(rep["groups"]) == [str(t) for t in sorted(CUBE_TAGS)]
    assert_boundary_report(rep, "area")
    back = read_mesh(out["mesh"])  # polyhedra plus the tagged faces: groups read back
    assert back.n_cells == poly.n_elements
    assert describe(back)["boundary_groups"] == sorted(CUBE_TAGS)
    assert back.meta["boundary_names"] == {11: "x0", 12: "x1", 13: "y0", 14: "y1", 15: "z0", 16: "z1"}
    fb = pipeline.run(back, model="metis", mode="kway", k=3).boundary
    for t in CUBE_TAGS:
        assert abs(fb.measure[fb.tags == t].sum() - 1.0) < 1e-12


def test_vtu_round_trip_2d_keeps_groups(tmp_path):
    mesh = read_mesh(INCLUSION)
    res = pipeline.run(mesh, model="metis", mode="segregated", mult_factor=0.3)
    out = pipeline.write_outputs(res, vtu=str(tmp_path / "a.vtu"))
    m = meshio.read(out["mesh"])
    assert "line" in [c.type for c in m.cells] and "boundary_tag" in m.cell_data
    back = read_mesh(out["mesh"])
    assert back.n_cells == res.poly.n_elements and back.physical_groups() == [1, 2]
    s = describe(back)
    assert s["boundary_groups"] == [2, 3, 4, 5, 6]
    assert s["boundary"]["untagged_boundary_facets"] == 0 and s["boundary"]["interior_tagged_facets"] == 23
    assert [g["name"] for g in s["boundary"]["groups"]] == ["bottom", "right", "top", "left", "interface"]
    assert back.meta["group_names"] == {1: "matrix", 2: "inclusion"}
    # agglomerating the result again keeps its boundary
    res2 = pipeline.run(back, model="metis", mode="kway", k=3)
    region, _ = lymph_structs(res2.poly)
    check_lymph(region)


def test_vtk_reads_the_3d_output(tmp_path):
    vtk = pytest.importorskip("vtk")
    res = pipeline.run(read_mesh(CUBE), model="metis", mode="kway", k=6)
    out = pipeline.write_outputs(res, vtu=str(tmp_path / "c.vtu"))
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(out["mesh"])
    r.Update()
    g = r.GetOutput()
    n_faces = int(np.count_nonzero(res.poly.facet_on_boundary))
    assert g.GetNumberOfCells() == 6 + n_faces
    types = [g.GetCellType(i) for i in range(g.GetNumberOfCells())]
    assert types[:6] == [42] * 6 and set(types[6:]) <= {5, 9, 7}
    tags = g.GetCellData().GetArray("boundary_tag")
    vals = np.array([tags.GetValue(i) for i in range(g.GetNumberOfCells())])
    assert (vals[:6] == -1).all() and set(vals[6:].tolist()) == set(CUBE_TAGS)


@pytest.mark.parametrize(
    ("ext", "key"), [(".vtu", "CellEntityIds"), (".vtk", "CellEntityIds"), (".avs", "avsucd:material")]
)
def test_vtu_vtk_ucd_input_with_tagged_lines(tmp_path, ext, key):
    m = meshio.read(SQUARE)
    tri, lines = m.cells_dict["triangle"], np.vstack([c.data for c in m.cells if c.type == "line"])
    ltags = np.concatenate(
        [d for c, d in zip(m.cells, m.cell_data["gmsh:physical"], strict=True) if c.type == "line"]
    )
    path = tmp_path / f"sq{ext}"
    meshio.write(
        path,
        meshio.Mesh(
            m.points,
            [("line", lines[:, ::-1]), ("triangle", tri)],
            cell_data={key: [ltags, np.full(len(tri), 7)]},
        ),
        **({} if ext == ".avs" else {"binary": False}),
    )
    mesh = read_mesh(path)
    assert mesh.physical_groups() == [7]
    assert describe(mesh)["boundary_groups"] == [2, 3, 4, 5]
    region, _ = lymph_structs(pipeline.run(mesh, model="metis", mode="kway", k=5).poly)
    check_lymph(region)
    assert (region["id"] == 7).all()


def test_untagged_boundary_gets_the_default(tmp_path):
    m = meshio.read(SQUARE)
    tri = m.cells_dict["triangle"]
    keep = [
        (c.data, d)
        for c, d in zip(m.cells, m.cell_data["gmsh:physical"], strict=True)
        if c.type == "line" and d[0] != 3
    ]
    lines, ltags = np.vstack([k[0] for k in keep]), np.concatenate([k[1] for k in keep])
    # one extra line that is no cell edge (a diagonal): reported as unmatched
    lines = np.vstack([lines, [[tri[0, 0], tri[-1, 1]]]])
    ltags = np.r_[ltags, 9]
    mesh = mesh_from_arrays(m.points, [("triangle", tri), ("line", lines)], tags=[np.ones(len(tri)), ltags])
    s = summary(mesh)
    assert [g["tag"] for g in s["groups"]] == [2, 4, 5]
    assert s["untagged_boundary_facets"] == 13 and s["boundary_facets"] == 52 and s["unmatched_cells"] == 1
    lines = check_lines(s)  # what `magnet check` prints about the boundary
    assert lines == ["boundary groups: 2 (13 boundary edges), 4 (13 boundary edges), 5 (13 boundary edges)"]
    rep = mesh_report(mesh)
    kinds = {i["kind"]: i for i in rep["issues"]}
    assert kinds["untagged-boundary"]["count"] == 13 and kinds["untagged-boundary"]["severity"] == "info"
    assert kinds["mixed-dimension"]["count"] == 1  # the diagonal line: no edge of any cell
    res = pipeline.run(mesh, model="metis", mode="kway", k=6)
    region, _ = lymph_structs(res.poly, boundary_tag=3)
    check_lymph(region)  # the right side (tag 3) has no group: it gets --boundary-tag 3
    region, _ = lymph_structs(res.poly, boundary_tag=1)
    assert (region["bc_tag"] == 1).sum() == 13
    rep = pipeline.write_outputs(res, metrics=str(tmp_path / "m.json"))
    rep = json.loads(Path(rep["metrics"]).read_text())["boundary"]
    assert rep["untagged"]["facets_before"] == rep["untagged"]["facets_after"] == 13


def test_conflicting_and_interior_groups_are_reported():
    m = meshio.read(SQUARE)
    tri = m.cells_dict["triangle"]
    lines = np.vstack([c.data for c in m.cells if c.type == "line"])
    inner = tri[200, :2][None, :]  # an interior edge, tagged
    mesh = mesh_from_arrays(
        m.points,
        [("triangle", tri), ("line", np.vstack([lines, lines[:1], inner]))],
        tags=[np.ones(len(tri)), np.r_[np.full(len(lines), 2), 8, 9]],
    )
    fb = fine_boundary(mesh)
    assert fb.conflicts == 1 and fb.unmatched == 0
    s = summary(mesh)
    assert s["interior_tagged_facets"] == 1 and s["conflicting_facets"] == 1
    assert [g["tag"] for g in s["groups"]] == [2, 9]


def test_meshes_without_groups_are_unchanged(tmp_path):
    from meshes import triangles

    p, t = triangles(6)
    mesh = mesh_from_arrays(p, [("triangle", t)])
    assert describe(mesh)["boundary_groups"] == [] and describe(mesh)["boundary"] == {"groups": []}
    res = pipeline.run(mesh, model="metis", mode="kway", k=4)
    assert res.boundary is None and res.poly.facet_tags is None
    out = pipeline.write_outputs(res, vtu=str(tmp_path / "a.vtu"), metrics=str(tmp_path / "m.json"))
    assert "boundary" not in json.loads(Path(out["metrics"]).read_text())
    m = meshio.read(out["mesh"])
    assert "line" not in [c.type for c in m.cells] and "boundary_tag" not in m.cell_data
    region, _ = lymph_structs(res.poly, boundary_tag=4)
    assert (region["bc_tag"] == 4).all() and (region["id"] == 1).all()


def test_cli_boundary_tag_and_summary(tmp_path):
    env_py = [sys.executable, "-m", "models.cli"]
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "MPLBACKEND": "Agg"}
    info = subprocess.run([*env_py, "info", str(SQUARE)], capture_output=True, text=True, env=env, cwd=ROOT)
    assert info.returncode == 0, info.stderr
    s = json.loads(info.stdout)
    assert s["boundary_groups"] == [2, 3, 4, 5]
    assert [g["name"] for g in s["boundary"]["groups"]] == ["bottom", "right", "top", "left"]
    out = subprocess.run(
        [
            *env_py,
            "agglomerate",
            str(SQUARE),
            "-o",
            str(tmp_path / "o.vtu"),
            "--k",
            "6",
            "--lymph",
            str(tmp_path / "o.mat"),
            "--boundary-tag",
            "9",
        ],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    region, _ = lymph_from_mat(tmp_path / "o.mat")
    check_lymph(region)  # every edge is tagged: the default is not used


def test_match_with_wide_keys():
    """Meshes too big for one int64 face key use (F, 4) key rows; matching gives the same answer."""
    from models.mesh.boundary import _match

    rng = np.random.default_rng(0)
    ref = rng.permutation(np.arange(50)) * 7
    query = np.r_[ref[[3, 10, 0]], 1, 8 * 7 + 3]
    want = _match(query, ref)
    assert want.tolist()[:3] == [3, 10, 0] and want.tolist()[3:] == [-1, -1]
    wide = lambda k: np.column_stack([k // 100, (k // 10) % 10, k % 10, np.full(k.size, 3)])  # noqa: E731
    np.testing.assert_array_equal(_match(wide(query), wide(ref)), want)


@pytest.mark.parametrize(
    ("model", "mode", "kw"),
    [
        ("metis", "segregated", {"mult_factor": 0.6}),
        ("kmeans", "segregated", {"mult_factor": 0.6}),
        ("metis", "kway", {"k": 8}),
    ],
)
def test_cube_inclusion_interface_surface(tmp_path, model, mode, kw):
    """3D: the interface surface between two materials stays a face of both neighbours (segregated),
    its area is kept, the outer faces keep their tags; kway may cut through it (reported)."""
    mesh = read_mesh(DATA / "cube_inclusion.msh")
    assert mesh.physical_groups() == [1, 2] and describe(mesh)["boundary_groups"] == [*sorted(CUBE_TAGS), 20]
    res = pipeline.run(mesh, model=model, mode=mode, **kw)
    poly = res.poly
    on = poly.facet_on_boundary
    sizes = np.diff(poly.loop_offsets)
    owner = np.repeat(np.arange(sizes.size), sizes)
    cen = np.column_stack([np.bincount(owner, poly.points[poly.loop_nodes, d]) / sizes for d in range(3)])
    np.testing.assert_array_equal(poly.facet_tags[on], side_of(cen[on], CUBE_TAGS))
    out = pipeline.write_outputs(res, metrics=str(tmp_path / "m.json"))
    rep = json.loads(Path(out["metrics"]).read_text())["boundary"]
    assert_boundary_report(rep, "area")
    iface = rep["interfaces"]["20"]
    assert abs(iface["measure_before"] - 6 * 0.16) < 1e-12
    if mode == "segregated":
        assert iface["facets_after"] == iface["facets_before"]
        assert abs(iface["measure_after"] - iface["measure_before"]) <= 1e-12 * iface["measure_before"]
        face_elem = np.repeat(np.arange(poly.n_elements), np.diff(poly.elem_offsets))
        t20 = np.flatnonzero(poly.facet_tags == 20)
        assert t20.size == 2 * iface["facets_before"]
        # the two copies of every interface face belong to elements of different materials
        assert set(np.unique(poly.tags[face_elem[t20]]).tolist()) == {1, 2}
        assert (np.bincount(poly.tags[face_elem[t20]])[1:] == iface["facets_before"]).all()


def test_magnet_check_lists_the_groups(capsys):
    from models.cli.main import main as magnet

    assert magnet(["check", str(INCLUSION)]) == 0
    text = capsys.readouterr().out
    assert (
        "boundary groups: 2 'bottom' (15 boundary edges), 3 'right' (15 boundary edges), 4 'top' (15 boundary edges), "
        "5 'left' (15 boundary edges), 6 'interface' (0 boundary edges, 23 interior)"
    ) in text
    assert "info: 23 tagged edges lie inside the domain (interfaces, groups [6])" in text
    assert magnet(["check", str(CUBE), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert [g["tag"] for g in rep["boundary"]["groups"]] == sorted(CUBE_TAGS) and rep["verdict"] == "ok"


def test_lines_and_points_of_a_volume_mesh_are_said_to_be_ignored(tmp_path):
    """Cells two dimensions below the mesh's (lines and points of a volume mesh) are no faces, so no
    boundary group: read, counted and said, in check and in agglomerate (outside sweep V: said
    nowhere but in `magnet info`)."""
    import subprocess
    import sys

    import meshio
    import vtk_corpus as vc

    from models.mesh.check import check_file

    p, h = vc.grid(3, 3, 3)
    path = tmp_path / "mixed.vtu"
    meshio.write(
        str(path), meshio.Mesh(p, [("hexahedron", h), ("line", [[0, 1], [1, 2]]), ("vertex", [[0], [5]])])
    )
    rep = check_file(str(path))
    said = [i["message"] for i in rep["issues"] if i["kind"] == "ignored-lower-cells"]
    assert said == [
        "4 cells of lower dimension ignored (2 line, 2 vertex): only the faces of the mesh's cells "
        "(triangles and quadrilaterals) become boundary groups"
    ]
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "models.cli",
            "agglomerate",
            str(path),
            "-o",
            str(tmp_path / "o.vtu"),
            "--k",
            "3",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0 and "note: 4 cells of lower dimension ignored" in r.stdout, r.stderr

"""Reading: every format, every cell type, physical groups, and every kind of bad input."""

import json
import os

import meshio
import numpy as np
import pytest
from conftest import BRAIN, EMILIA
from meshes import hexes, mixed_2d, mixed_3d, quads, tets, triangles, wedges

from models.errors import MeshError, ParameterError
from models.mesh.container import VTK_POLYGON
from models.mesh.geometry import cell_measures
from models.mesh.read import mesh_from_arrays, read_mesh


def write(tmp_path, name, points, cells, **kw):
    path = str(tmp_path / name)
    fmt = {".msh2": {"file_format": "gmsh22", "binary": False}, ".msh": {"file_format": "gmsh"}}
    meshio.write(path, meshio.Mesh(points, cells, **kw), **fmt.get(os.path.splitext(name)[1], {}))
    return path


def test_brain_vtu_is_2d_with_z0():
    m = read_mesh(BRAIN)
    assert m.dim == 2 and m.n_cells == 14372
    assert m.cell_type_counts() == {"triangle": 14372}
    assert np.all(cell_measures(m) > 0)


def test_emilia_legacy_vtk_many_blocks_and_groups():
    m = read_mesh(EMILIA)
    assert m.n_cells == 4870 and m.dim == 2
    assert m.physical_groups() == [1, 2, 3, 4, 5, 6, 7]
    assert m.tag_name == "CellEntityIds"
    lo, hi = m.points.min(axis=0), m.points.max(axis=0)
    assert np.isclose(cell_measures(m).sum(), np.prod(hi - lo), rtol=1e-5)  # a rectangle
    assert np.any(m.cell_types == VTK_POLYGON)


@pytest.mark.parametrize("ext", ["vtu", "vtk", "msh2", "xdmf"])
def test_formats_roundtrip_with_groups(tmp_path, ext):
    p, t = triangles(6)
    tags = (p[t].mean(axis=1)[:, 0] > 0.5).astype(int) + 1
    if ext.startswith("msh"):
        kw = {"cell_data": {"gmsh:physical": [tags], "gmsh:geometrical": [tags]}}
    else:
        kw = {"cell_data": {"CellEntityIds": [tags]}}
    path = write(tmp_path, f"m.{ext}", np.column_stack([p, np.zeros(len(p))]), [("triangle", t)], **kw)
    if ext == "msh2":  # Gmsh 2.2 ASCII under the usual extension
        os.rename(path, path[:-1])
        path = path[:-1]
    m = read_mesh(path)
    assert m.n_cells == len(t) and m.dim == 2
    assert sorted(m.physical_groups()) == [1, 2]
    assert np.isclose(cell_measures(m).sum(), 1.0)


CELLS = {
    "triangle": lambda: (triangles(5)[0], [("triangle", triangles(5)[1])]),
    "quad": lambda: (quads(5)[0], [("quad", quads(5)[1])]),
    "mixed2d": lambda: mixed_2d(6),
    "tetra": lambda: (tets(3)[0], [("tetra", tets(3)[1])]),
    "hexahedron": lambda: (hexes(3)[0], [("hexahedron", hexes(3)[1])]),
    "wedge": lambda: (wedges(3)[0], [("wedge", wedges(3)[1])]),
    "mixed3d": lambda: mixed_3d(4),
}


@pytest.mark.parametrize("kind", sorted(CELLS))
def test_every_cell_type_measures_sum_to_unit(kind, tmp_path):
    p, cells = CELLS[kind]()
    pts = p if p.shape[1] == 3 else np.column_stack([p, np.zeros(len(p))])
    path = write(tmp_path, "m.vtu", pts, cells)
    m = read_mesh(path)
    assert m.n_cells == sum(len(c) for _, c in cells)
    assert np.isclose(cell_measures(m).sum(), 1.0)


def test_polygons_and_polyhedra(tmp_path):
    # general polygons: a hexagon + surrounding triangles
    ang = np.linspace(0, 2 * np.pi, 7)[:-1]
    p = np.vstack([[0, 0], np.column_stack([np.cos(ang), np.sin(ang)])])
    m = mesh_from_arrays(p, [("polygon", np.array([[1, 2, 3, 4, 5, 6]]))])
    assert np.isclose(cell_measures(m)[0], 3 * np.sqrt(3) / 2)
    # VTK polyhedra, written by our own writer, read back
    from models.export.vtu import write_vtu
    from models.pipeline import prepare
    from models.polytope.merge import merge

    hp, h = hexes(3)
    fine = mesh_from_arrays(hp, [("hexahedron", h)])
    g, d = prepare(fine)
    poly, _ = merge(fine, g, np.arange(fine.n_cells), d.measures)
    write_vtu(tmp_path / "poly.vtu", poly)
    m2 = read_mesh(tmp_path / "poly.vtu")
    assert m2.cell_type_counts() == {"polyhedron": 27}
    assert np.isclose(cell_measures(m2).sum(), 1.0)


def test_2d_mesh_in_a_tilted_plane_is_2d():
    p, t = triangles(4)
    n = np.array([1.0, 2.0, 2.0]) / 3
    e1 = np.cross(n, [0, 0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    pts = np.array([5, -1, 2]) + p[:, :1] * e1 + p[:, 1:2] * e2
    m = mesh_from_arrays(pts, [("triangle", t)])
    assert m.dim == 2
    assert np.isclose(cell_measures(m).sum(), 1.0)
    assert np.allclose(m.points3d(), pts)


def test_boundary_cells_kept_apart():
    p, t = triangles(4)
    lines = np.array([[0, 5], [5, 10]])
    m = mesh_from_arrays(p, [("triangle", t), ("line", lines)], tags=[np.ones(len(t)), np.full(2, 7)])
    assert m.n_cells == len(t)
    assert len(m.boundary_types) == 2 and m.boundary_tags.tolist() == [7, 7]
    hp, h = tets(2)
    faces = np.array([[0, 1, 2]])
    m3 = mesh_from_arrays(hp, [("tetra", h), ("triangle", faces)])
    assert m3.dim == 3 and m3.n_cells == len(h) and len(m3.boundary_types) == 1


def test_clockwise_and_inverted_cells_are_reoriented():
    p, t = triangles(3)
    t = t.copy()
    t[::2] = t[::2, ::-1]
    m = mesh_from_arrays(p, [("triangle", t)])
    assert np.all(np.diff(m.offsets) == 3)
    from models.mesh.geometry import signed_measures

    assert np.all(signed_measures(m) > 0)
    hp, h = tets(2)
    h = h.copy()
    h[::3] = h[::3][:, [0, 2, 1, 3]]
    m3 = mesh_from_arrays(hp, [("tetra", h)])
    assert np.all(signed_measures(m3) > 0)


def test_reading_orients_its_own_arrays_in_place_but_never_the_callers(tmp_path):
    """read_mesh gives its freshly read connectivity to the Mesh (mirrored in place, no copy);
    mesh_from_arrays / mesh_from_meshio must leave the caller's arrays as they were."""
    from models.mesh.read import mesh_from_meshio

    hp, h = tets(3)
    h = h.copy()
    h[::3] = h[::3][:, [0, 2, 1, 3]]  # a third of the cells inverted: orienting edits them
    before = h.copy()
    m1 = mesh_from_arrays(hp, [("tetra", h)])
    mm = meshio.Mesh(hp, [("tetra", h)])
    m2 = mesh_from_meshio(mm)
    assert m1.meta["orientation"]["flipped"] > 0
    assert np.array_equal(h, before) and np.array_equal(mm.cells[0].data, before)
    assert not np.shares_memory(m1.connectivity, h) and not np.shares_memory(m2.connectivity, h)
    for name in ("cube.vtu", "cube.msh"):
        m3 = read_mesh(write(tmp_path, name, hp, [("tetra", h)]))
        assert np.array_equal(h, before)
        for a in ("connectivity", "offsets", "cell_types", "points"):
            assert np.array_equal(getattr(m3, a), getattr(m1, a)), (name, a)
            assert getattr(m3, a).dtype == getattr(m1, a).dtype, (name, a)
        assert np.array_equal(m3.meta["signed_measures"], m1.meta["signed_measures"])


def test_named_physical_tag(tmp_path):
    p, t = triangles(3)
    path = write(
        tmp_path,
        "m.vtu",
        np.column_stack([p, np.zeros(len(p))]),
        [("triangle", t)],
        cell_data={"material": [np.arange(len(t)) % 3]},
    )
    assert read_mesh(path).physical_groups() == [0, 1, 2]  # found by its common name
    path2 = write(
        tmp_path,
        "n.vtu",
        np.column_stack([p, np.zeros(len(p))]),
        [("triangle", t)],
        cell_data={"zone_id": [np.arange(len(t)) % 2]},
    )
    assert read_mesh(path2).tags is None
    assert read_mesh(path2, physical_tag="zone_id").physical_groups() == [0, 1]
    with pytest.raises(ParameterError, match="nope"):
        read_mesh(path2, physical_tag="nope")


# ---- bad input: one clear MeshError each ----------------------------------------------------


def test_missing_file(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        read_mesh(tmp_path / "none.vtu")


def test_empty_file(tmp_path):
    (tmp_path / "e.vtu").write_bytes(b"")
    with pytest.raises(MeshError, match="empty"):
        read_mesh(tmp_path / "e.vtu")


def test_unknown_format(tmp_path):
    (tmp_path / "m.qqq").write_text("1 2 3\n")
    with pytest.raises(MeshError, match="unknown mesh format"):
        read_mesh(tmp_path / "m.qqq")


def test_truncated_file(tmp_path):
    data = open(BRAIN, "rb").read()
    (tmp_path / "t.vtu").write_bytes(data[: len(data) // 2])
    with pytest.raises(MeshError, match="cannot read"):
        read_mesh(tmp_path / "t.vtu")


def test_garbage_file(tmp_path):
    (tmp_path / "g.msh").write_bytes(b"\x00\x01garbage" * 100)
    with pytest.raises(MeshError):
        read_mesh(tmp_path / "g.msh")


def test_mesh_without_cells(tmp_path):
    with pytest.raises(MeshError, match="no cells"):
        mesh_from_arrays(np.random.rand(5, 3), [])
    path = tmp_path / "n.vtk"
    path.write_text(
        "# vtk DataFile Version 4.2\nno cells\nASCII\nDATASET UNSTRUCTURED_GRID\n"
        "POINTS 3 double\n0 0 0\n1 0 0\n0 1 0\nCELLS 0 0\nCELL_TYPES 0\n"
    )
    with pytest.raises(MeshError, match="no cells|cannot read"):
        read_mesh(path)


def test_gmsh4_physical_groups(tmp_path):
    gmsh = pytest.importorskip("gmsh")
    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("two")
        a = gmsh.model.occ.addRectangle(0, 0, 0, 0.5, 1)
        b = gmsh.model.occ.addRectangle(0.5, 0, 0, 0.5, 1)
        gmsh.model.occ.fragment([(2, a)], [(2, b)])
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [a], 11)
        gmsh.model.addPhysicalGroup(2, [b], 22)
        gmsh.model.addPhysicalGroup(1, [1, 2, 3], 5)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.2)
        gmsh.model.mesh.generate(2)
        path = str(tmp_path / "g.msh")
        gmsh.write(path)
    finally:
        gmsh.finalize()
    m = read_mesh(path)
    assert m.dim == 2 and m.physical_groups() == [11, 22]
    assert m.tag_name == "gmsh:physical"
    assert m.boundary_types is not None and set(m.boundary_tags.tolist()) == {5}
    assert np.isclose(cell_measures(m).sum(), 1.0)


def test_nan_coordinates():
    p, t = triangles(3)
    p[4] = np.nan
    with pytest.raises(MeshError, match="NaN or infinite"):
        mesh_from_arrays(p, [("triangle", t)])
    p[4] = [np.inf, 0]
    with pytest.raises(MeshError, match="NaN or infinite"):
        mesh_from_arrays(p, [("triangle", t)])


def test_missing_points():
    p, t = triangles(3)
    t = t.copy()
    t[0, 0] = len(p) + 10
    with pytest.raises(MeshError, match="missing points"):
        mesh_from_arrays(p, [("triangle", t)])


def test_degenerate_cells():
    p, t = triangles(3)
    t = t.copy()
    t[5] = [t[5, 0], t[5, 0], t[5, 1]]
    with pytest.raises(MeshError, match="degenerate"):
        mesh_from_arrays(p, [("triangle", t)])


def test_tiny_cells_of_a_graded_mesh_are_not_degenerate():
    """Cells far smaller than the domain but well shaped (a mesh graded 1000:1 toward a corner has
    tetrahedra of 3e-14 in a unit box) are kept; a flat cell of the same size is not. Before, both
    fell under the 1e-14-of-the-box threshold and the 13 small ones were left out."""
    p, t = tets(2)
    tiny = p * 2e-5 + 0.5  # the same tetrahedra, 50,000 times smaller, inside the box
    pts = np.vstack([p, tiny])
    mesh = mesh_from_arrays(pts, [("tetra", np.vstack([t, t + len(p)]))])
    assert mesh.n_cells == 2 * len(t)
    flat = tiny.copy()
    flat[:, 2] = 0.5  # the small copy crushed flat
    with pytest.raises(MeshError, match="degenerate"):
        mesh_from_arrays(np.vstack([p, flat]), [("tetra", np.vstack([t, t + len(p)]))])


def test_1d_mesh():
    p = np.column_stack([np.linspace(0, 1, 5), np.zeros(5)])
    with pytest.raises(MeshError, match="1D"):
        mesh_from_arrays(p, [("line", np.column_stack([np.arange(4), np.arange(1, 5)]))])


@pytest.mark.parametrize("ext", [".vtu", ".ply", ".stl", ".obj"])
def test_a_tilted_plane_in_single_precision_is_2d(tmp_path, ext):
    """A flat mesh off the axes, its points stored as float32 (PLY, binary STL, most VTK sources):
    rounding leaves them up to about 2^-24 of their size off the plane, which is planar (outside
    sweep U: refused as "non-planar" from all of these); a mesh bent by a thousandth is not."""
    from models.mesh.read import read_mesh

    p, t = triangles(12)
    n = np.array([1.0, 2.0, 2.0]) / 3
    e1 = np.cross(n, [0, 0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    pts = (np.array([5, -1, 2]) + p[:, :1] * e1 + p[:, 1:2] * e2).astype(np.float32)
    assert np.abs((pts - pts.mean(0)) @ n).max() > 1e-8  # (off the plane by rounding alone)
    path = str(tmp_path / f"tilted{ext}")
    meshio.write(
        path, meshio.Mesh(pts, [("triangle", t)]), **({"binary": True} if ext in (".stl", ".ply") else {})
    )
    m = read_mesh(path)
    assert m.dim == 2 and m.n_cells == len(t)
    assert float(cell_measures(m).sum()) == pytest.approx(1.0, rel=1e-6)
    bent = pts.astype(np.float64) + 1e-3 * np.sin(3 * p[:, :1]) * n
    with pytest.raises(
        MeshError, match=r"non-planar .* a point lies [0-9.e-]+ off the best plane, across a mesh"
    ):
        mesh_from_arrays(bent, [("triangle", t)])


def test_non_planar_surface_mesh():
    p, t = triangles(3)
    pts = np.column_stack([p, (p[:, 0] - 0.5) ** 2])
    with pytest.raises(MeshError, match="non-planar"):
        mesh_from_arrays(pts, [("triangle", t)])


def _same_as_meshio(path):
    from models.mesh.vtu import read_vtu_simple

    fast, ref = read_vtu_simple(path), meshio.read(path)
    if fast is None:
        return None
    assert np.array_equal(fast.points, ref.points) and fast.points.dtype == ref.points.dtype
    assert [(b.type, b.data.dtype) for b in fast.cells] == [(b.type, b.data.dtype) for b in ref.cells]
    assert all(np.array_equal(a.data, b.data) for a, b in zip(fast.cells, ref.cells, strict=True))
    assert sorted(fast.cell_data) == sorted(ref.cell_data)
    for k, v in ref.cell_data.items():
        assert [(a.dtype, a.shape) for a in fast.cell_data[k]] == [(a.dtype, a.shape) for a in v]
        assert all(np.array_equal(a, b) for a, b in zip(fast.cell_data[k], v, strict=True))
    return fast


def test_simple_vtu_reader_gives_meshio_arrays_or_leaves_the_file_to_meshio(tmp_path):
    """The common VTU layout (meshio's and VTK's inline binary, zlib or not; VTK's appended data,
    base64 or raw, zlib in base64 only) is read without
    meshio's XML tree, with exactly meshio.read's arrays; any other layout is left to meshio."""
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    p, t = tets(3)
    t = np.asarray(t, dtype=np.int64)
    tags = (np.arange(len(t)) % 3).astype(np.int32)
    cd = {"gmsh:physical": [tags], "vec": [np.linspace(0, 1, 3 * len(t)).reshape(-1, 3)]}
    fast = {
        "zlib": write(tmp_path, "zlib.vtu", p, [("tetra", t)], cell_data=cd),
        "raw": str(tmp_path / "raw.vtu"),
        "int32": write(tmp_path, "i32.vtu", p.astype(np.float32), [("tetra", t.astype(np.int32))]),
        "triangles": write(tmp_path, "tri.vtu", *(lambda q, c: (q, [("triangle", c)]))(*triangles(4))),
        "two blocks": write(tmp_path, "two.vtu", p, [("tetra", t[:3]), ("tetra", t[3:])]),
    }
    meshio.write(fast["raw"], meshio.Mesh(p, [("tetra", t)], cell_data=cd), compression=None)
    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.asarray(p, dtype=np.float64)))
    ug.SetPoints(pts)
    ca = vtk.vtkCellArray()
    ca.SetData(
        numpy_to_vtkIdTypeArray(np.arange(0, 4 * len(t) + 1, 4, dtype=np.int64), deep=True),
        numpy_to_vtkIdTypeArray(t.ravel().copy(), deep=True),
    )
    ug.SetCells(10, ca)
    arr = numpy_to_vtk(tags, deep=True)
    arr.SetName("gmsh:physical")
    ug.GetCellData().AddArray(arr)
    for comp in (True, False):  # VTK adds InformationKey children to the points
        for mode, encode in (("binary", True), ("appended", True), ("appended", False)):
            if mode == "appended" and comp and not encode:
                continue  # zlib in raw appended data: left to meshio (below)
            w = vtk.vtkXMLUnstructuredGridWriter()
            w.SetInputData(ug)
            getattr(w, f"SetDataModeTo{mode.capitalize()}")()
            w.SetEncodeAppendedData(encode)
            if not comp:
                w.SetCompressorTypeToNone()
            key = f"vtk {mode} {'base64' if encode else 'raw'} {comp}"
            fast[key] = str(tmp_path / f"{key.replace(' ', '_')}.vtu")
            w.SetFileName(fast[key])
            w.Write()
    for name, path in fast.items():
        assert _same_as_meshio(path) is not None, name
        assert (
            read_mesh(path).meta["orientation"]
            == mesh_from_arrays(
                *(lambda m: (m.points, [(b.type, b.data) for b in m.cells]))(meshio.read(path))
            ).meta["orientation"]
        )
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetInputData(ug)
    w.SetDataModeToAppended()
    w.SetEncodeAppendedData(False)  # raw bytes, zlib blocks
    w.SetFileName(str(tmp_path / "appended.vtu"))
    w.Write()
    others = [
        str(tmp_path / "appended.vtu"),
        write(tmp_path, "mixed.vtu", *mixed_3d(2)),
        write(
            tmp_path, "wedges.vtu", *(lambda q, c: (q, [("wedge", c)]))(*wedges(2))
        ),  # meshio reorders wedges
        write(tmp_path, "pd.vtu", p, [("tetra", t)], point_data={"u": np.asarray(p)[:, 0]}),
    ]
    meshio.write(str(tmp_path / "ascii.vtu"), meshio.Mesh(p, [("tetra", t)]), binary=False)
    meshio.write(str(tmp_path / "lzma.vtu"), meshio.Mesh(p, [("tetra", t)]), compression="lzma")
    others += [str(tmp_path / "ascii.vtu"), str(tmp_path / "lzma.vtu")]
    for path in others:
        assert _same_as_meshio(path) is None, path
    broken = tmp_path / "broken.vtu"
    broken.write_bytes(open(fast["zlib"], "rb").read()[:-3000])
    from models.mesh.vtu import read_vtu_simple

    assert read_vtu_simple(broken) is None
    with pytest.raises(MeshError):
        read_mesh(broken)


def test_zlib_blocks_inflate_to_meshio_concatenation_whatever_the_header_says():
    """_decode_zlib inflates the blocks straight into the array the header announces; equal blocks
    are inflated once; a header whose sizes disagree with the blocks gives meshio's answer (the
    inflated blocks concatenated), and a block of partial items is refused as meshio refuses it."""
    import base64
    import zlib

    from models.mesh.vtu import _decode_zlib

    rng = np.random.default_rng(3)
    u4 = np.dtype("<u4")
    a = rng.integers(0, 1000, 4096 * 3 + 1000, dtype=np.int64)
    a[4096 : 2 * 4096] = a[:4096]  # two equal blocks (compressed alike)
    raw = a.tobytes()
    blocks = [raw[i : i + 32768] for i in range(0, len(raw), 32768)]
    comp = [zlib.compress(b) for b in blocks]

    def encode(full: int, last: int) -> bytes:
        head = np.array([len(comp), full, last, *map(len, comp)], dtype=u4).tobytes()
        return base64.b64encode(head) + base64.b64encode(b"".join(comp))

    honest = _decode_zlib(encode(32768, len(blocks[-1])), np.dtype("<i8"), u4)
    assert np.array_equal(honest, a) and honest.flags.writeable and honest.dtype == np.dtype("<i8")
    for full, last in ((32768, 0), (32768, 8), (40000, 123), (8, 8)):  # headers that lie
        out = _decode_zlib(encode(full, last), np.dtype("<i8"), u4)
        assert np.array_equal(out, a) and out.flags.writeable
    comp[1] = zlib.compress(blocks[1][:-4])  # 4 bytes short of whole int64 items
    with pytest.raises(ValueError):
        _decode_zlib(encode(32768, len(blocks[-1])), np.dtype("<i8"), u4)


@pytest.mark.parametrize("kind", ["degenerate", "missing"])
def test_a_few_bad_cells_among_many_are_left_out_and_said(tmp_path, kind):
    """Non-negotiable 3: a few bad cells among thousands are left out and reported, the rest read
    and agglomerated (labels -1 for them); many bad cells (over 1%) still refuse the file."""
    from models import agglomerate
    from models.mesh.dropped import dropped_sentence

    p, t = triangles(40)  # 3,200 triangles
    bad_ids = [7, 1000, 2999]
    for many in (False, True):
        tt = t.copy()
        ids = bad_ids if not many else list(range(0, len(t), 50))  # 64 cells: 2%
        if kind == "degenerate":
            tt[ids, 2] = tt[ids, 1]  # a repeated node: zero area
        else:
            tt[ids, 0] = len(p) + 5
        if many:
            with pytest.raises(MeshError, match="degenerate" if kind == "degenerate" else "missing points"):
                mesh_from_arrays(p, [("triangle", tt)])
            continue
        mesh = mesh_from_arrays(p, [("triangle", tt)])
        assert mesh.n_cells == len(t) - 3 and mesh.meta["dropped_cells"]["ids_all"] == bad_ids
        assert mesh.meta["dropped_cells"]["file_cells"] == len(t)
        said = dropped_sentence(mesh.meta)
        assert said.startswith("3 of the file's 3,200 cells left out") and "(cells 7, 1000, 2999)" in said
        path = str(tmp_path / f"{kind}.vtu")
        meshio.write(path, meshio.Mesh(np.column_stack([p, np.zeros(len(p))]), [("triangle", tt)]))
        res = agglomerate(path, model="metis", k=4, metrics=False, allow_extra=True)
        out = tmp_path / f"{kind}.labels.json"
        res.write(str(out), kind="labels")
        labels = np.array(json.loads(out.read_text()))
        assert (
            labels.size == len(t)
            and np.all(labels[bad_ids] == -1)
            and np.all(labels[np.setdiff1d(np.arange(len(t)), bad_ids)] >= 0)
        )

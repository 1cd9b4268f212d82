"""What an outside sweep of files written by other tools found (session 47): meshpy's Gambit files,
a VTKHDF multiblock's block names, files ParaView opens by these extensions with other readers
(.xyz molecules, Movie.BYU .g surfaces), meshio's PLY of 2D points, and the format an Abaqus
refusal names."""

from __future__ import annotations

import numpy as np
import pytest

from models.errors import MeshError
from models.mesh.read import read_mesh


def _meshpy_neu(path, pts: np.ndarray, cells: np.ndarray, bcs: dict) -> None:
    """A Gambit neutral file laid out as meshpy's MeshInfo.write_neu writes it (meshpy 2026.1.1,
    meshpy/common.py): the count row a left-aligned table ("125   384   1     0      3     3"),
    coordinates as Python's repr, one element group of NFLAGS 0 followed by a "0" line anyway,
    boundary conditions of (element, type, face) rows. bcs: {name: [(element, face), ...]}, 0-based
    elements, faces numbered from 1 as Gambit (and meshpy) does."""
    dim = pts.shape[1]
    values = [len(pts), len(cells), 1, len(bcs), dim, dim]
    keys = ["NUMNP", "NELEM", "NGRPS", "NBSETS", "NDFCD", "NDFVL"]
    widths = [max(len(k), len(str(v))) for k, v in zip(keys, values, strict=True)]
    eltype = 3 if dim == 2 else 6
    out = [
        "CONTROL INFO 2.1.2",
        "** GAMBIT NEUTRAL FILE",
        "MeshPy Output",
        "PROGRAM: MeshPy VERSION: 2026.1.1",
    ]
    out.append("Tue Dec  8 00:41:34 2026")
    out.append(" ".join(k.ljust(w) for k, w in zip(keys, widths, strict=True)))
    out.append(" ".join(str(v).ljust(w) for v, w in zip(values, widths, strict=True)))
    out += ["ENDOFSECTION", "NODAL COORDINATES 2.1.2"]
    out += [f"{i + 1} " + " ".join(repr(float(c)) for c in p) for i, p in enumerate(pts)]
    out += ["ENDOFSECTION", "ELEMENTS/CELLS 2.1.2"]
    out += [
        f"{i + 1:>8d}{eltype:>3d}{len(c):>3d} " + "".join(f"{x + 1:>8d}" for x in c)
        for i, c in enumerate(cells)
    ]
    out += ["ENDOFSECTION", "ELEMENT GROUP 1.3.0"]
    out.append(f"GROUP:{1:>11d} ELEMENTS:{len(cells):>11d} MATERIAL:{1:>11} NFLAGS: {0:>11d}")
    out += ["epsilon: 1".rjust(31), "0"]
    ids = [str(i + 1).rjust(8) for i in range(len(cells))]
    out += [" ".join(ids[a : a + 10]) for a in range(0, len(ids), 10)]
    out.append("ENDOFSECTION")
    for code, (name, faces) in enumerate(bcs.items(), 1):
        out += ["BOUNDARY CONDITIONS 2.1.2", f"{name:>32}{1:>8d}{len(faces):>8d}{0:>8d}{code:>8d}"]
        out += [f"{e + 1:>10d}{eltype:>5d}{f:>5d}" for e, f in faces]
        out.append("ENDOFSECTION")
    path.write_text("\n".join(out) + "\n")


def _grid_triangles(nx: int, ny: int, lx: float, ly: float) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.linspace(0, lx, nx + 1), np.linspace(0, ly, ny + 1), indexing="ij")
    pts = np.c_[x.ravel(), y.ravel()]
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    a = (i * (ny + 1) + j).ravel()
    b, c, d = a + ny + 1, a + ny + 2, a + 1
    return pts, np.r_[np.c_[a, b, c], np.c_[a, c, d]]


def _cube_tetrahedra(n: int) -> tuple[np.ndarray, np.ndarray]:
    g = np.stack(np.meshgrid(*[np.linspace(0, 1, n + 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    i, j, k = (a.ravel() for a in np.meshgrid(*[np.arange(n)] * 3, indexing="ij"))

    def at(di, dj, dk):
        return ((i + di) * (n + 1) + j + dj) * (n + 1) + k + dk

    v = np.c_[
        at(0, 0, 0), at(1, 0, 0), at(1, 1, 0), at(0, 1, 0), at(0, 0, 1), at(1, 0, 1), at(1, 1, 1), at(0, 1, 1)
    ]
    split = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]
    return g, np.concatenate([v[:, s] for s in split])


def test_meshpy_gambit_2d_with_boundary_conditions_reads(tmp_path):
    """meshpy's count row ("72    ...", left-aligned) made VTK's reader die ("its cells cannot be
    read"); its element group's "0" flag line under NFLAGS 0 was taken for element 0."""
    pts, tris = _grid_triangles(4, 3, 2.0, 1.0)
    bottom = np.flatnonzero(np.all(pts[tris[: len(tris) // 2]][:, :2, 1] == 0, axis=1))  # a-b edges, face 1
    path = tmp_path / "plate.neu"
    _meshpy_neu(path, pts, tris, {"bottom": [(int(e), 1) for e in bottom]})
    assert "24    " in path.read_text()  # the left-aligned table itself
    m = read_mesh(str(path))
    assert m.n_cells == 24
    assert np.isclose(np.abs(m.meta["measures"]).sum(), 2.0, rtol=1e-12)
    assert m.meta["group_names"] == {1: "epsilon: 1"}
    assert "gambit_groups" not in m.meta  # no note: the "0" line is no element id
    assert list(m.meta["boundary_names"].values()) == ["bottom"]
    assert np.count_nonzero(m.boundary_tags) == 4


def test_meshpy_gambit_3d_reads(tmp_path):
    pts, tets = _cube_tetrahedra(4)
    path = tmp_path / "cube.neu"
    _meshpy_neu(path, pts, tets, {})
    m = read_mesh(str(path))
    assert m.n_cells == 384
    assert np.isclose(np.abs(m.meta["measures"]).sum(), 1.0, rtol=1e-12)
    assert m.meta["group_names"] == {1: "epsilon: 1"}


def _tetra_box(x0: float, n: int = 4):
    import vtk

    s = vtk.vtkImageData()
    s.SetDimensions(n + 1, n + 1, n + 1)
    s.SetSpacing(1.0 / n, 1.0 / n, 1.0 / n)
    s.SetOrigin(x0, 0, 0)
    t = vtk.vtkDataSetTriangleFilter()
    t.SetInputData(s)
    t.Update()
    return t.GetOutput()


def _vtkhdf(data, path) -> str:
    """`data` written by VTK's vtkHDFWriter to `path`; the path as a string."""
    import vtk

    w = vtk.vtkHDFWriter()
    w.SetFileName(str(path))
    w.SetInputData(data)
    w.Write()
    return str(path)


def test_vtkhdf_multiblock_block_names_are_group_names(tmp_path):
    """pyvista's MultiBlock({'steel': ..., 'rubber': ...}).save('x.vtkhdf') (vtkHDFWriter): the
    block names were dropped (group_names {}), where the same blocks as .vtm named their groups."""
    import vtk

    mb = vtk.vtkMultiBlockDataSet()
    for i, (name, x0) in enumerate([("steel", 0.0), ("rubber", 1.5)]):
        mb.SetBlock(i, _tetra_box(x0))
        mb.GetMetaData(i).Set(vtk.vtkCompositeDataSet.NAME(), name)
    for ext, writer in ((".vtkhdf", vtk.vtkHDFWriter()), (".vtm", vtk.vtkXMLMultiBlockDataWriter())):
        path = str(tmp_path / f"named{ext}")
        writer.SetFileName(path)
        writer.SetInputData(mb)
        writer.Write()
        m = read_mesh(path)
        assert m.n_cells == 2 * 4**3 * 5 and np.isclose(np.abs(m.meta["measures"]).sum(), 2.0, rtol=1e-12)
        assert {int(k): v for k, v in m.meta["group_names"].items()} == {1: "steel", 2: "rubber"}, ext
        assert np.bincount(m.tags)[1:].tolist() == [320, 320]


def test_vtkhdf_partitioned_collection_names_its_datasets(tmp_path):
    """A partitioned dataset collection names its partitioned datasets; a dataset of two partitions
    is two blocks, the second named "(2)"."""
    import vtk

    pdc = vtk.vtkPartitionedDataSetCollection()
    for i, (name, boxes) in enumerate([("steel", [0.0]), ("rubber", [1.5, 3.0])]):
        p = vtk.vtkPartitionedDataSet()
        for j, x0 in enumerate(boxes):
            p.SetPartition(j, _tetra_box(x0, 2))
        pdc.SetPartitionedDataSet(i, p)
        pdc.GetMetaData(i).Set(vtk.vtkCompositeDataSet.NAME(), name)
    m = read_mesh(_vtkhdf(pdc, tmp_path / "pdc.vtkhdf"))
    assert m.n_cells == 3 * 40
    names = {int(k): v for k, v in m.meta["group_names"].items()}
    assert names == {1: "steel", 2: "rubber", 3: "rubber (2)"}


def test_xyz_molecule_is_said_to_be_atoms_not_plot3d(tmp_path):
    """ParaView opens .xyz with its XYZ molecule reader: such a file was refused as a truncated
    PLOT3D grid."""
    path = tmp_path / "water.xyz"
    path.write_text("3\nwater molecule\nO 0.0 0.0 0.0\nH 0.757 0.586 0.0\nH -0.757 0.586 0.0\n")
    with pytest.raises(MeshError) as e:
        read_mesh(str(path))
    msg = str(e.value)
    assert msg.startswith("cannot read water.xyz as PLOT3D grid: it is not a PLOT3D grid")
    assert "XYZ list of 3 atoms" in msg and "give a volume or planar mesh" in msg
    assert "truncated" not in msg and msg.count("cannot read") == 1


def test_movie_byu_g_file_is_said_to_be_one(tmp_path):
    """ParaView reads .g as Movie.BYU too: the Exodus refusal says what the file may be."""
    import vtk

    src = vtk.vtkPlaneSource()
    src.SetResolution(4, 4)
    tri = vtk.vtkTriangleFilter()
    tri.SetInputConnection(src.GetOutputPort())
    path = str(tmp_path / "plate_byu.g")
    w = vtk.vtkBYUWriter()
    w.SetGeometryFileName(path)
    w.SetInputConnection(tri.GetOutputPort())
    w.Write()
    with pytest.raises(MeshError) as e:
        read_mesh(path)
    msg = str(e.value)
    assert msg.startswith("cannot read plate_byu.g as Exodus II: the file is neither netCDF nor HDF5")
    assert "it looks like a Movie.BYU surface" in msg and "save this surface from ParaView as .stl" in msg
    other = tmp_path / "junk.g"
    other.write_text("hello\n")
    with pytest.raises(MeshError, match="a .g file that is not Exodus II may be a Movie.BYU surface"):
        read_mesh(str(other))


@pytest.mark.parametrize("binary", [True, False])
def test_ply_of_2d_points_reads_as_a_planar_mesh(tmp_path, binary):
    """meshio writes 2D points to PLY as x and y only, which meshio's reader (and VTK's) refused
    ("corrupted or not in this format"): read with z = 0."""
    import meshio

    pts, tris = _grid_triangles(6, 5, 3.0, 2.0)
    path = tmp_path / "plate_2d.ply"
    meshio.write(path, meshio.Mesh(pts, [("triangle", tris)]), binary=binary)
    assert b"property double z" not in path.read_bytes()[:400]
    m = read_mesh(str(path))
    assert m.n_cells == 60 and m.dim == 2
    assert np.isclose(np.abs(m.meta["measures"]).sum(), 6.0, rtol=1e-12)


def test_ply_of_2d_points_with_extra_properties_big_endian(tmp_path):
    pts, tris = _grid_triangles(3, 3, 1.0, 1.0)
    vert = np.zeros(len(pts), [("x", ">f8"), ("y", ">f8"), ("t", ">f4")])
    vert["x"], vert["y"], vert["t"] = pts[:, 0], pts[:, 1], 7.0
    face = np.zeros(len(tris), [("n", "u1"), ("v", ">i4", 3)])
    face["n"], face["v"] = 3, tris
    head = (
        f"ply\nformat binary_big_endian 1.0\ncomment 2D\nelement vertex {len(pts)}\nproperty double x\n"
        f"property double y\nproperty float t\nelement face {len(tris)}\nproperty list uchar int vertex_indices\n"
        "end_header\n"
    )
    path = tmp_path / "be.ply"
    path.write_bytes(head.encode() + vert.tobytes() + face.tobytes())
    m = read_mesh(str(path))
    assert m.n_cells == 18 and np.isclose(np.abs(m.meta["measures"]).sum(), 1.0, rtol=1e-12)
    # the vertices not the first element: said what is wrong
    path.write_bytes(
        head.replace("element vertex", "element junk 0\nelement vertex").encode()
        + vert.tobytes()
        + face.tobytes()
    )
    with pytest.raises(MeshError) as e:
        read_mesh(str(path))
    assert str(e.value).startswith(
        "cannot read be.ply as PLY: its vertices have no z property (a PLY needs x, y and z)"
    )


def test_abaqus_refusal_names_abaqus_alone(tmp_path):
    """A meshio-written Abaqus .inp with 3% degenerate cells was refused "as Abaqus or AVS UCD"
    (the .inp extension's name): the file's keywords say Abaqus."""
    import meshio

    from models.mesh.check import check_file

    pts, tets = _cube_tetrahedra(4)
    flat = tets[:12].copy()  # 12 of 396 cells (3%, above the 1% left out) without a volume
    flat[:, 3] = flat[:, 0]
    path = tmp_path / "bad.inp"
    meshio.write(path, meshio.Mesh(pts, [("tetra", np.r_[tets, flat])]))
    with pytest.raises(MeshError) as e:
        read_mesh(str(path))
    assert str(e.value).startswith("cannot read bad.inp as Abaqus: ")
    assert "AVS" not in str(e.value)
    assert "AVS" not in str(check_file(str(path)))


def test_vtkhdf_partitions_of_one_mesh_are_no_groups(tmp_path):
    """A VTKHDF of one partitioned dataset holds one mesh cut into pieces (as a .pvtu): its
    partitions were physical groups 1, 2 (segregated agglomeration kept to them); now no groups,
    the pieces' shared points merged."""
    import vtk

    p = vtk.vtkPartitionedDataSet()
    p.SetPartition(0, _tetra_box(0.0, 2))
    p.SetPartition(1, _tetra_box(1.0, 2))
    m = read_mesh(_vtkhdf(p, tmp_path / "pieces.vtkhdf"))
    assert m.n_cells == 80 and len(m.points) == 5 * 3 * 3
    assert m.tags is None or np.unique(m.tags).size == 1

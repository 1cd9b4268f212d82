"""What an outside sweep of files written by other tools found (session 47): meshpy's Gambit files,
a VTKHDF multiblock's block names, files ParaView opens by these extensions with other readers
(.xyz molecules, Movie.BYU .g surfaces), meshio's PLY of 2D points, and the format an Abaqus
refusal names."""

from __future__ import annotations

import numpy as np

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
    path = str(tmp_path / "pdc.vtkhdf")
    w = vtk.vtkHDFWriter()
    w.SetFileName(path)
    w.SetInputData(pdc)
    w.Write()
    m = read_mesh(path)
    assert m.n_cells == 3 * 40
    names = {int(k): v for k, v in m.meta["group_names"].items()}
    assert names == {1: "steel", 2: "rubber", 3: "rubber (2)"}

"""What an outside sweep of physical groups across formats found (session 45: 69 files, the same
2D and 3D meshes written by gmsh, meshio and VTK): Abaqus sets were numbered by their size (the
same mesh's matrix was group 1 from .msh and 9 from .inp), a .vtm's block names were dropped,
FLAC3D's group names came with meshio's key text ('zone:matrix:1'), and --keep-groups on without a
refiner did nothing and said nothing."""

from __future__ import annotations

import numpy as np
import pytest
from meshes import triangles

from models import read_mesh
from models.errors import ParameterError


def _two_materials():
    """A square of triangles: the inclusion is the cells whose centroid is within 0.25 of the centre."""
    p, t = triangles(12)
    c = p[t].mean(axis=1)
    inner = np.linalg.norm(c - 0.5, axis=1) < 0.25
    return np.c_[p, np.zeros(len(p))], t, inner


def test_abaqus_sets_are_numbered_as_the_file_lists_them(tmp_path):
    import meshio

    p, t, inner = _two_materials()
    sets = {"matrix": [np.flatnonzero(~inner)], "inclusion": [np.flatnonzero(inner)]}  # the larger first
    path = str(tmp_path / "two.inp")
    meshio.write(path, meshio.Mesh(p, [("triangle", t)], cell_sets=sets))
    mesh = read_mesh(path)
    assert mesh.meta["group_names"] == {1: "matrix", 2: "inclusion"}
    assert np.array_equal(mesh.tags == 2, inner)


def test_a_multiblocks_block_names_are_its_groups_names(tmp_path):
    import vtk
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    p, t, inner = _two_materials()
    mb = vtk.vtkMultiBlockDataSet()
    for i, (name, sel) in enumerate((("matrix", ~inner), ("inclusion", inner))):
        ug = vtk.vtkUnstructuredGrid()
        pts = vtk.vtkPoints()
        pts.SetData(numpy_to_vtk(np.ascontiguousarray(p), deep=True))
        ug.SetPoints(pts)
        cells = vtk.vtkCellArray()
        tri = t[sel]
        cells.SetData(
            numpy_to_vtkIdTypeArray(np.arange(0, 3 * len(tri) + 1, 3, dtype=np.int64), deep=True),
            numpy_to_vtkIdTypeArray(np.ascontiguousarray(tri.reshape(-1), dtype=np.int64), deep=True),
        )
        ug.SetCells(vtk.VTK_TRIANGLE, cells)
        mb.SetBlock(i, ug)
        mb.GetMetaData(i).Set(vtk.vtkCompositeDataSet.NAME(), name)
    w = vtk.vtkXMLMultiBlockDataWriter()
    path = str(tmp_path / "two.vtm")
    w.SetFileName(path)
    w.SetInputData(mb)
    w.Write()
    mesh = read_mesh(path)
    assert mesh.meta["group_names"] == {1: "matrix", 2: "inclusion"}
    assert np.count_nonzero(mesh.tags == 2) == np.count_nonzero(inner)


def test_flac3d_group_names_are_the_files(tmp_path):
    import meshio
    from meshes import tets

    p, c = tets(4)
    cen = np.asarray(p)[c].mean(axis=1)
    inner = np.all(np.abs(cen - 0.5) < 0.25, axis=1)
    sets = {"matrix": [np.flatnonzero(~inner)], "core": [np.flatnonzero(inner)]}
    path = str(tmp_path / "block.f3grid")
    meshio.write(path, meshio.Mesh(np.asarray(p, dtype=float), [("tetra", c)], cell_sets=sets))
    mesh = read_mesh(path)
    assert set(mesh.meta["group_names"].values()) == {"matrix", "core"}


def test_keep_groups_without_a_refiner_is_refused():
    from models.agglomeration import agglomerate

    p, t, inner = _two_materials()
    with pytest.raises(ParameterError, match="acts on a refiner's cuts"):
        agglomerate(points=p, cells=[("triangle", t)], tags=[inner.astype(int) + 1], k=4, keep_groups=True)
    r = agglomerate(
        points=p, cells=[("triangle", t)], tags=[inner.astype(int) + 1], k=4, keep_groups=True, refiner="fm"
    )
    assert r.n_elements == 4

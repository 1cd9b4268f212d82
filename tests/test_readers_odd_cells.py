"""VTK cell types that VTK's own writers leave in files: VTK_EMPTY_CELL (0) among volume cells, and
VTK_CONVEX_POINT_SET (41) cells beside hexahedra and polyhedra (an outside sweep of session 43 found
both refused: "a cell of a kind without an area or a volume")."""

from __future__ import annotations

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")
import vtk_corpus as vc  # noqa: E402
from vtkmodules.util.numpy_support import numpy_to_vtk  # noqa: E402

from models.mesh.check import check_file  # noqa: E402
from models.mesh.read import read_mesh  # noqa: E402

_FACES = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]


def _grid(kinds):
    """A 3 x 3 x 3 grid of hexahedra mapped by vc.A, each cell written as kinds[i % len(kinds)]:
    'hex' (12), 'set' (41: its 8 corners, shuffled), 'poly' (42: six faces), 'empty' (0, an extra
    cell before it)."""
    p, hexes = vc.grid(3, 3, 3)
    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(p), deep=True))
    ug.SetPoints(pts)
    rng = np.random.default_rng(0)
    for i, h in enumerate(hexes):  # a test fixture of 27 cells
        kind = kinds[i % len(kinds)]
        ids = vtk.vtkIdList()
        if kind == "empty":
            ug.InsertNextCell(vtk.VTK_EMPTY_CELL, vtk.vtkIdList())
            kind = "hex"
        if kind == "poly":
            stream = [6] + [v for f in _FACES for v in [4, *h[f].tolist()]]
        else:
            stream = rng.permutation(h).tolist() if kind == "set" else h.tolist()
        for v in stream:
            ids.InsertNextId(int(v))
        ug.InsertNextCell({"hex": 12, "set": 41, "poly": 42}[kind], ids)
    return ug, 27 * abs(np.linalg.det(vc.A))


@pytest.mark.parametrize("kinds", [("set",), ("hex", "set"), ("set", "poly", "hex"), ("poly", "set")])
@pytest.mark.parametrize("writer", ["vtu", "legacy"])
def test_convex_point_sets_are_read_as_polyhedra(tmp_path, kinds, writer):
    """Each convex point set is the polyhedron of its points' hull: the grid's volume, its faces
    found by its hexahedral and polyhedral neighbours (one piece), agglomerated, and VTK's reading of
    our VTU gives the same volume."""
    ug, volume = _grid(kinds)
    path = (
        vc.write_xml(tmp_path / "sets.vtu", ug)
        if writer == "vtu"
        else vc.write_legacy(tmp_path / "sets.vtk", ug, binary=True)
    )
    mesh = read_mesh(path)
    assert mesh.n_cells == 27
    assert abs(np.abs(mesh.meta["measures"]).sum() - volume) <= 1e-9 * volume
    rep = check_file(path)
    assert rep["components"] == 1 and rep["boundary_facets"] == 54 and rep["verdict"] == "ok", rep
    res, n, total = vc.agglomerate_read_back(path, 4, tmp_path / "out.vtu")
    assert n == 4 and abs(total - volume) <= 1e-9 * volume


def test_empty_cells_are_left_out_and_said(tmp_path):
    """VTK_EMPTY_CELL among hexahedra: the hexahedra read, the empty cells counted in one line."""
    ug, volume = _grid(("empty", "hex", "hex"))
    path = vc.write_xml(tmp_path / "empty.vtu", ug)
    mesh = read_mesh(path)
    assert mesh.n_cells == 27 and abs(np.abs(mesh.meta["measures"]).sum() - volume) <= 1e-9 * volume
    assert mesh.meta["lower_dim_cells"] == {"empty cell": 9}
    said = [i for i in check_file(path)["issues"] if i["kind"] == "ignored-lower-cells"]
    assert said and said[0]["count"] == 9 and said[0]["message"] == "9 empty cells (no points) ignored"


def test_a_flat_convex_point_set_is_refused_in_our_words(tmp_path):
    ug, _ = _grid(("hex",))
    ids = vtk.vtkIdList()
    for v in (0, 1, 5, 4):  # four corners of one face: no volume
        ids.InsertNextId(v)
    ug.InsertNextCell(41, ids)
    path = vc.write_xml(tmp_path / "flat.vtu", ug)
    from models.errors import MeshError

    with pytest.raises(MeshError) as e:
        read_mesh(path)
    assert "a convex point set has all its points in one plane (no volume)" in str(e.value)
    assert "Qhull" not in str(e.value) and "QH" not in str(e.value)

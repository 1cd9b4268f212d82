"""Merging parts into polygons/polyhedra, holes handled explicitly, and the VTU read back by VTK."""

import numpy as np
import pytest
from conftest import BRAIN
from meshes import hexes, mixed_3d, quads, tets, triangles

from models.errors import MeshError, ParameterError
from models.export.vtu import write_vtu
from models.mesh.read import mesh_from_arrays, read_mesh
from models.pipeline import prepare, run, split_holes
from models.polytope.merge import merge

vtk = pytest.importorskip("vtk")
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402


def shoelace(p):
    x, y = p[:, 0], p[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


def test_polygons_ccw_and_areas():
    m = read_mesh(BRAIN)
    g, d = prepare(m)
    res = run(m, mode="kway", k=64, compute_metrics=False)
    poly = res.poly
    assert np.all(np.diff(poly.elem_offsets) == 1)
    lo = poly.loop_offsets
    areas = np.array(
        [shoelace(poly.points[poly.loop_nodes[lo[i] : lo[i + 1]]]) for i in range(poly.n_elements)]
    )
    assert np.all(areas > 0)  # counter-clockwise
    assert np.allclose(areas, poly.measure, rtol=1e-9)
    assert poly.n_fine.sum() == m.n_cells


def ring_labels(n=9):
    """A 9x9 quad grid: element 0 = a ring of cells around the centre 3x3 block (element 1), rest = 2."""
    p, q = quads(n)
    m = mesh_from_arrays(p, [("quad", q)])
    c = np.floor(p[q].mean(axis=1) * n).astype(int)
    ring = np.maximum(abs(c[:, 0] - 4), abs(c[:, 1] - 4)) == 2
    centre = np.maximum(abs(c[:, 0] - 4), abs(c[:, 1] - 4)) <= 1
    labels = np.full(m.n_cells, 2)
    labels[ring] = 0
    labels[centre] = 1
    # element 2 (outside) is also a ring around everything: keep it simple, split it off by cells
    return m, labels


def test_hole_detected_and_split():
    m, labels = ring_labels()
    g, d = prepare(m)
    _, holes = merge(m, g, labels, d.measures)
    assert 0 in holes.elements.tolist()  # the ring encloses the centre block
    poly, new_labels, n_split = split_holes(m, g, d, labels, "split")
    assert n_split >= 1
    assert np.all(np.diff(poly.elem_offsets) == 1)  # every element: one loop
    assert np.isclose(poly.measure.sum(), 1.0)
    lo = poly.loop_offsets
    areas = np.array(
        [shoelace(poly.points[poly.loop_nodes[lo[i] : lo[i + 1]]]) for i in range(poly.n_elements)]
    )
    assert np.allclose(areas, poly.measure)
    with pytest.raises(MeshError, match="enclose a hole"):
        split_holes(m, g, d, labels, "error")


def test_domain_with_hole():
    p, q = quads(8)
    c = p[q].mean(axis=1)
    keep = np.maximum(abs(c[:, 0] - 0.5), abs(c[:, 1] - 0.5)) > 0.2
    m = mesh_from_arrays(p, [("quad", q[keep])])
    with pytest.raises(ParameterError, match="hole|cannot be met"):  # exactly k, or the reason
        run(m, mode="kway", k=1)
    res = run(m, mode="kway", k=1, allow_extra=True)  # one element around the domain hole -> must be split
    assert res.holes_split >= 1 and res.poly.n_elements >= 2
    assert np.all(np.diff(res.poly.elem_offsets) == 1)
    assert np.isclose(res.poly.measure.sum(), 1 - 0.5**2)


def test_3d_cavity_split():
    p, h = hexes(3)
    m = mesh_from_arrays(p, [("hexahedron", h)])
    g, d = prepare(m)
    labels = np.zeros(m.n_cells, dtype=np.int64)
    labels[13] = 1  # the centre cube, enclosed by the 26 others
    _, holes = merge(m, g, labels, d.measures)
    assert holes.elements.tolist() == [0]
    poly, new_labels, n = split_holes(m, g, d, labels, "split")
    assert n == 1 and poly.n_elements >= 3
    _, holes2 = merge(m, g, new_labels, d.measures)
    assert holes2.elements.size == 0


def read_vtu(path):
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(path))
    r.Update()
    return r.GetOutput()


def vtk_total_area(grid):
    """Area through VTK's own polygon triangulation."""
    surf = vtk.vtkDataSetSurfaceFilter()
    surf.SetInputData(grid)
    tri = vtk.vtkTriangleFilter()
    tri.SetInputConnection(surf.GetOutputPort())
    size = vtk.vtkCellSizeFilter()
    size.SetInputConnection(tri.GetOutputPort())
    size.Update()
    return vtk_to_numpy(size.GetOutput().GetCellData().GetArray("Area")).sum()


def vtk_volumes(grid):
    """Per-cell volume from the faces VTK read (divergence theorem), and the volume enclosed by the
    grid's outer surface (vtkMassProperties). VTK's own polyhedron volume tetrahedralizes from the
    centroid and is wrong for non-convex cells, so it is not used."""
    vols = []
    for i in range(grid.GetNumberOfCells()):
        c = grid.GetCell(i)
        v = 0.0
        for f in range(c.GetNumberOfFaces()):
            pts = vtk_to_numpy(c.GetFace(f).GetPoints().GetData())
            for j in range(1, len(pts) - 1):
                v += np.dot(pts[0], np.cross(pts[j], pts[j + 1])) / 6
        vols.append(v)
    gf = vtk.vtkGeometryFilter()
    gf.SetInputData(grid)
    tri = vtk.vtkTriangleFilter()
    tri.SetInputConnection(gf.GetOutputPort())
    mp = vtk.vtkMassProperties()
    mp.SetInputConnection(tri.GetOutputPort())
    mp.Update()
    return np.array(vols), mp.GetVolume()


def test_vtu_2d_read_by_vtk(tmp_path):
    m = read_mesh(BRAIN)
    res = run(m, mode="kway", k=128)
    from models.pipeline import write_outputs

    write_outputs(res, vtu=str(tmp_path / "a.vtu"))
    grid = read_vtu(tmp_path / "a.vtu")
    assert grid.GetNumberOfCells() == res.poly.n_elements == 128
    assert {grid.GetCellType(i) for i in range(grid.GetNumberOfCells())} == {vtk.VTK_POLYGON}
    assert np.isclose(vtk_total_area(grid), res.poly.measure.sum(), rtol=1e-9)
    cd = grid.GetCellData()
    for name in ("element_id", "n_fine_cells", "circle_ratio"):
        assert cd.GetArray(name) is not None
    assert vtk_to_numpy(cd.GetArray("n_fine_cells")).sum() == m.n_cells


@pytest.mark.parametrize("kind", ["tetra", "mixed3d"])
def test_vtu_3d_read_by_vtk(tmp_path, kind):
    if kind == "tetra":
        p, t = tets(5)
        m = mesh_from_arrays(p, [("tetra", t)])
    else:
        m = mesh_from_arrays(*mixed_3d(6))
    res = run(m, mode="kway", k=12, compute_metrics=False)
    write_vtu(tmp_path / "b.vtu", res.poly)
    grid = read_vtu(tmp_path / "b.vtu")
    assert grid.GetNumberOfCells() == res.poly.n_elements
    assert {grid.GetCellType(i) for i in range(grid.GetNumberOfCells())} == {vtk.VTK_POLYHEDRON}
    vols, enclosed = vtk_volumes(grid)
    assert np.allclose(vols, res.poly.measure, rtol=1e-9)
    assert np.isclose(enclosed, 1.0, rtol=1e-9)


def test_vtu_tilted_2d_keeps_its_plane(tmp_path):
    p, t = triangles(6)
    pts = np.column_stack([p[:, 0], p[:, 1] * np.cos(0.3), p[:, 1] * np.sin(0.3)])
    m = mesh_from_arrays(pts, [("triangle", t)])
    res = run(m, mode="kway", k=4, compute_metrics=False)
    write_vtu(tmp_path / "c.vtu", res.poly)
    grid = read_vtu(tmp_path / "c.vtu")
    z = vtk_to_numpy(grid.GetPoints().GetData())
    assert np.allclose(z, pts)
    assert np.isclose(vtk_total_area(grid), 1.0)


@pytest.mark.parametrize("pinched", [False, True])
def test_merge_2d_pairs_edges_by_sorting_as_the_search_did(pinched):
    """merge_2d pairs the boundary edges by two sorts when every (element, vertex) has one edge out;
    the search it replaced (kept for elements that touch themselves at a vertex) finds the same."""
    import models.polytope.merge as M

    m = read_mesh(BRAIN)
    g, d = prepare(m)
    if pinched:  # random labels: elements touching themselves at vertices, holes
        labels = np.random.default_rng(3).integers(0, 40, m.n_cells)
    else:
        labels = run(m, mode="kway", k=200, compute_metrics=False).poly.labels
    f = g.faces
    bf = M.boundary_faces(g, labels)
    key = labels[f.cell[bf]] * np.int64(m.n_points)
    start, end = key + f.nodes[2 * bf], key + f.nodes[2 * bf + 1]
    nxt, pinch = M._next_edges(start, end)[:2]
    paired = M._pair_edges(start, end)
    if pinched:
        assert paired is None and pinch.size
    else:
        assert pinch.size == 0 and np.array_equal(paired, nxt)
    poly, _ = M.merge_2d(m, g, labels, d.measures)
    assert poly.n_elements == int(labels.max()) + 1

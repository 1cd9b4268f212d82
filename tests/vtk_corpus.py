"""A corpus of small mesh files written at test time by VTK's own writers, and VTK's own reading of
them (the reference: number of cells, total area / volume).

Geometry: affine images of unit grids, so every face is planar and every higher-order cell is
straight-sided (its mid-edge / face / interior nodes placed by the linear cell's shape functions at
the node's parametric coordinates, which VTK gives): the measure on corner nodes equals VTK's.
"""

from __future__ import annotations

import os

import numpy as np
import vtk
from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy

A = np.array([[1.0, 0.2, 0.1], [0.1, 1.3, 0.0], [0.0, 0.3, 0.9]])  # an affine map (planar faces)


def grid(nx: int, ny: int, nz: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (x fastest) and hexahedra (VTK order) of an nx x ny x nz cell grid, mapped by A."""
    x, y, z = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij")
    p = np.column_stack([x.ravel("F"), y.ravel("F"), z.ravel("F")]).astype(float)
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    b = (i + (nx + 1) * (j + (ny + 1) * k)).ravel("F")
    sx, sy, sz = 1, nx + 1, (nx + 1) * (ny + 1)
    hexes = np.stack([b, b + sx, b + sx + sy, b + sy, b + sz, b + sz + sx, b + sz + sx + sy, b + sz + sy], 1)
    return p @ A.T, hexes


def quad_grid(nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="ij")
    p = np.column_stack([x.ravel("F"), y.ravel("F"), np.zeros(x.size)]).astype(float)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    b = (i + (nx + 1) * j).ravel("F")
    p[:, :2] = p[:, :2] @ A[:2, :2].T
    return p, np.stack([b, b + 1, b + nx + 2, b + nx + 1], 1)


def linear_cells(family: int) -> tuple[np.ndarray, np.ndarray]:
    """Points and cells of one linear type (VTK id): hexahedra 12, wedges 13, tetra 10, pyramids 14,
    quads 9, triangles 5."""
    if family in (9, 5):
        p, q = quad_grid(3, 2)
        if family == 9:
            return p, q
        return p, np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    p, h = grid(2, 2, 1)
    if family == 12:
        return p, h
    if family == 13:
        return p, np.concatenate([h[:, [0, 1, 2, 4, 5, 6]], h[:, [0, 2, 3, 4, 6, 7]]])
    if family == 10:
        kuhn = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]
        return p, np.concatenate([h[:, k] for k in kuhn])
    # pyramids: each hexahedron's six faces around a new centre point
    centres = p[h].mean(axis=1)
    c = len(p) + np.arange(len(h))
    faces = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    pyr = np.concatenate([np.column_stack([h[:, f], c]) for f in faces])
    return np.concatenate([p, centres]), pyr


_FAMILY = {
    22: 5,
    23: 9,
    24: 10,
    25: 12,
    26: 13,
    27: 14,
    28: 9,
    29: 12,
    30: 9,
    31: 13,
    32: 13,
    33: 12,
    34: 5,
    69: 5,
    70: 9,
    71: 10,
    72: 12,
    73: 13,
    76: 5,
    77: 9,
    78: 10,
    79: 12,
    80: 13,
}
_LAGRANGE = {
    69: ("vtkLagrangeTriangle", 6, None),
    70: ("vtkLagrangeQuadrilateral", 9, (2, 2)),
    71: ("vtkLagrangeTetra", 10, None),
    72: ("vtkLagrangeHexahedron", 27, (2, 2, 2)),
    73: ("vtkLagrangeWedge", 18, (2, 2, 2)),
    76: ("vtkBezierTriangle", 6, None),
    77: ("vtkBezierQuadrilateral", 9, (2, 2)),
    78: ("vtkBezierTetra", 10, None),
    79: ("vtkBezierHexahedron", 27, (2, 2, 2)),
    80: ("vtkBezierWedge", 18, (2, 2, 2)),
}
HIGHER_ORDER = sorted(_FAMILY)  # 37 (triquadratic pyramid): its parametric space is not vtkPyramid's


def _parametric(t: int) -> np.ndarray:
    if t in _LAGRANGE:
        cls, n, order = _LAGRANGE[t]
        c = getattr(vtk, cls)()
        c.GetPointIds().SetNumberOfIds(n)
        c.GetPoints().SetNumberOfPoints(n)
        if order is not None:
            c.SetOrder(*order, n) if t in (73, 80) else c.SetOrder(*order)
        else:
            c.Initialize()
    else:
        c = vtk.vtkGenericCell()
        c.SetCellType(t)
        n = c.GetNumberOfPoints()
    return np.array(c.GetParametricCoords()).reshape(n, 3)


def _shape(family: int, pc: np.ndarray) -> np.ndarray:
    cell = vtk.vtkGenericCell()
    cell.SetCellType(family)
    n = cell.GetNumberOfPoints()
    w = np.zeros((len(pc), n))
    for i, r in enumerate(pc):  # a handful of nodes per cell type, once (not per cell)
        weights = [0.0] * n
        cell.InterpolateFunctions(list(r), weights)
        w[i] = weights
    return w


def higher_order(t: int) -> tuple[np.ndarray, np.ndarray]:
    """Points and cells of type t: straight-sided, the corners shared, the other nodes per cell."""
    fam = _FAMILY[t]
    p, cells = linear_cells(fam)
    pc = _parametric(t)
    w = _shape(fam, pc)
    k = cells.shape[1]
    assert np.allclose(w[:k], np.eye(k)), t  # VTK lists the corners first
    extra = np.einsum("nk,ckd->cnd", w[k:], p[cells])  # (cells, other nodes, 3)
    ids = len(p) + np.arange(extra.shape[0] * extra.shape[1]).reshape(extra.shape[:2])
    return np.concatenate([p, extra.reshape(-1, 3)]), np.concatenate([cells, ids], axis=1)


def unstructured(points: np.ndarray, blocks: list[tuple[int, np.ndarray]]) -> vtk.vtkUnstructuredGrid:
    """A vtkUnstructuredGrid of [(VTK type, (n, w) nodes)] blocks."""
    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=True))
    ug.SetPoints(pts)
    sizes = np.concatenate([np.full(len(c), c.shape[1]) for _, c in blocks])
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    conn = np.concatenate([c.reshape(-1) for _, c in blocks]).astype(np.int64)
    types = np.concatenate([np.full(len(c), t, np.uint8) for t, c in blocks])
    ca = vtk.vtkCellArray()
    ca.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True), numpy_to_vtkIdTypeArray(conn, deep=True))
    ug.SetCells(numpy_to_vtk(types, deep=True, array_type=vtk.VTK_UNSIGNED_CHAR), ca)
    return ug


def polyhedra(points: np.ndarray, hexes: np.ndarray) -> vtk.vtkUnstructuredGrid:
    """The hexahedra as VTK_POLYHEDRON cells (six faces each, outward)."""
    faces = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(points), deep=True))
    ug.SetPoints(pts)
    ug.Allocate(len(hexes))
    for h in hexes:  # a test fixture of a few cells
        stream = [6] + [v for f in faces for v in [4, *h[f].tolist()]]
        ids = vtk.vtkIdList()
        for v in stream:
            ids.InsertNextId(int(v))
        ug.InsertNextCell(vtk.VTK_POLYHEDRON, ids)
    return ug


def prisms() -> vtk.vtkUnstructuredGrid:
    """One pentagonal (15) and one hexagonal (16) prism side by side (not sharing faces)."""
    pts, blocks = [], []
    for n, t, dx in ((5, 15, 0.0), (6, 16, 3.0)):
        a = 2 * np.pi * np.arange(n) / n
        ring = np.column_stack([np.cos(a) + dx, np.sin(a), np.zeros(n)])
        base = sum(len(q) for q in pts)
        pts.append(np.concatenate([ring, ring + [0, 0, 1.5]]))
        blocks.append((t, base + np.arange(2 * n)[None, :]))
    return unstructured(np.concatenate(pts), blocks)


# ---- writers --------------------------------------------------------------------------------------


def write_legacy(path, ds, version: int = 51, binary: bool = False) -> str:
    w = vtk.vtkDataSetWriter()
    w.SetFileName(str(path))
    w.SetInputData(ds)
    if version == 42:
        w.SetFileVersion(42)
    if binary:
        w.SetFileTypeToBinary()
    assert w.Write() == 1
    return str(path)


def write_xml(
    path, ds, mode: str = "appended", compress: bool = False, pieces: int = 1, encode: bool = True
) -> str:
    ext = os.path.splitext(str(path))[1]
    cls = {
        ".vtu": vtk.vtkXMLUnstructuredGridWriter,
        ".vtp": vtk.vtkXMLPolyDataWriter,
        ".vti": vtk.vtkXMLImageDataWriter,
        ".vts": vtk.vtkXMLStructuredGridWriter,
        ".vtr": vtk.vtkXMLRectilinearGridWriter,
    }[ext]
    w = cls()
    w.SetFileName(str(path))
    w.SetInputData(ds)
    getattr(w, "SetDataModeTo" + mode.capitalize())()
    if not compress:
        w.SetCompressorTypeToNone()
    else:
        w.SetCompressorTypeToZLib()
    if mode == "appended":
        w.SetEncodeAppendedData(encode)
    if pieces > 1:
        w.SetNumberOfPieces(pieces)
    assert w.Write() == 1
    return str(path)


def write_pieces(path, writer, source, pieces: int, ghost_level: int = 0) -> str:
    """A parallel XML file (writer: a vtkXMLP*Writer) of what `source` (a piece-extracting filter)
    makes, cut into `pieces` pieces, each with `ghost_level` layers of ghost cells."""
    writer.SetFileName(str(path))
    writer.SetInputConnection(source.GetOutputPort())
    writer.SetNumberOfPieces(pieces)
    writer.SetStartPiece(0)
    writer.SetEndPiece(pieces - 1)
    writer.SetGhostLevel(ghost_level)
    assert writer.Write() == 1
    return str(path)


def write_exodus(path, ug) -> str:
    """Exodus II through vtkExodusIIWriter (it wants the block ids as an ObjectId cell array)."""
    if ug.GetCellData().GetArray("ObjectId") is None:
        ids = np.ones(ug.GetNumberOfCells(), np.int32)
        a = numpy_to_vtk(ids, deep=True)
        a.SetName("ObjectId")
        ug.GetCellData().AddArray(a)
    w = vtk.vtkExodusIIWriter()
    w.SetFileName(str(path))
    w.SetInputData(ug)
    w.WriteAllTimeStepsOff()
    w.Write()
    return str(path)


def image(dims=(5, 4, 3)) -> vtk.vtkImageData:
    im = vtk.vtkImageData()
    im.SetDimensions(*dims)
    im.SetSpacing(0.5, 1.0, 2.0)
    im.SetOrigin(1.0, -2.0, 3.0)
    return im


def structured_grid(dims=(5, 4, 3)) -> vtk.vtkStructuredGrid:
    p, _ = grid(dims[0] - 1, dims[1] - 1, dims[2] - 1)
    sg = vtk.vtkStructuredGrid()
    sg.SetDimensions(*dims)
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(p, deep=True))
    sg.SetPoints(pts)
    return sg


def rectilinear(dims=(5, 4, 3)) -> vtk.vtkRectilinearGrid:
    rg = vtk.vtkRectilinearGrid()
    rg.SetDimensions(*dims)
    for d, setter in zip(dims, (rg.SetXCoordinates, rg.SetYCoordinates, rg.SetZCoordinates), strict=True):
        setter(numpy_to_vtk(np.cumsum(np.linspace(0.5, 1.5, d)) if d > 1 else np.zeros(1), deep=True))
    return rg


def plane(kind: str) -> vtk.vtkPolyData:
    """A planar polydata: quads, triangles, triangle strips or polygons (a hexagon fan of pentagons)."""
    src = vtk.vtkPlaneSource()
    src.SetResolution(6, 4)
    src.SetOrigin(0, 0, 0)
    src.SetPoint1(3, 0.5, 0)
    src.SetPoint2(-0.5, 2, 0)
    src.Update()
    pd = _double(src.GetOutput())
    if kind == "quads":
        return pd
    tri = vtk.vtkTriangleFilter()
    tri.SetInputData(pd)
    tri.Update()
    if kind == "triangles":
        return tri.GetOutput()
    if kind == "strips":
        s = vtk.vtkStripper()
        s.SetInputData(tri.GetOutput())
        s.Update()
        out = s.GetOutput()
        assert out.GetNumberOfStrips() > 0
        return out
    # polygons: pairs of neighbouring quads merged into hexagons (6 nodes, collinear pairs kept)
    ids = vtk_to_numpy(pd.GetPolys().GetConnectivityArray()).reshape(-1, 4)
    polys = vtk.vtkCellArray()
    for a, b in zip(ids[0::2], ids[1::2], strict=True):
        polys.InsertNextCell(6, [int(a[0]), int(a[1]), int(b[1]), int(b[2]), int(a[2]), int(a[3])])
    out = vtk.vtkPolyData()
    out.SetPoints(pd.GetPoints())
    out.SetPolys(polys)
    return out


def _double(pd):
    """The polydata with float64 points (VTK's sources make float32 ones)."""
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(vtk_to_numpy(pd.GetPoints().GetData()).astype(np.float64), deep=True))
    pd.SetPoints(pts)
    return pd


# ---- VTK's own reading: the reference ------------------------------------------------------------


def vtk_read(path: str):
    ext = ".cas.h5" if path.lower().endswith(".cas.h5") else os.path.splitext(path)[1].lower()
    if ext == ".cas.h5":
        r = vtk.vtkFLUENTCFFReader()  # cell zones only (no face zones are read by default)
    elif ext == ".vtk":
        r = vtk.vtkDataSetReader()
    elif ext == ".pvtk":
        from vtkmodules.vtkIOParallel import vtkPDataSetReader

        r = vtkPDataSetReader()  # (as ParaView opens it: the pieces appended)
    elif ext in (".exo", ".e"):
        r = vtk.vtkExodusIIReader()
        r.SetFileName(path)
        r.UpdateInformation()
        r.SetAllArrayStatus(r.ELEM_BLOCK, 1)
        r.SetSqueezePoints(False)  # squeezed, the reader hands out float32 points; unsqueezed the file's
    elif ext in (".xdmf", ".xmf"):
        r = vtk.vtkXdmfReader()
    elif ext == ".cgns":
        r = vtk.vtkCGNSReader()
        r.SetFileName(path)
        r.UpdateInformation()
        r.EnableAllBases()
    elif ext == ".neu":
        r = vtk.vtkGAMBITReader()
    elif ext in (".dat", ".tec", ".tp", ".plt"):
        r = vtk.vtkTecplotReader()  # ASCII Tecplot, as ParaView reads it
    elif ext in (".inp", ".ucd", ".avs"):
        r = vtk.vtkAVSucdReader()
    elif ext in (".msh", ".cas"):
        r = vtk.vtkFLUENTReader()  # its cell zones: the face zones' blocks are not volume cells
        r.SetFileName(path)
        r.UpdateInformation()
        sel = r.GetZoneSectionSelection()
        for i in range(sel.GetNumberOfArrays()):
            if not sel.GetArrayName(i).endswith((":fluid", ":solid")):
                sel.DisableArray(sel.GetArrayName(i))
    else:
        r = vtk.vtkXMLGenericDataObjectReader()
    r.SetFileName(path)
    r.Update()
    out = r.GetOutputDataObject(0)
    if out.IsA("vtkCompositeDataSet"):
        app = vtk.vtkAppendFilter()
        app.MergePointsOn()
        it = out.NewIterator()
        it.InitTraversal()
        while not it.IsDoneWithTraversal():
            app.AddInputData(it.GetCurrentDataObject())
            it.GoToNextItem()
        app.Update()
        out = app.GetOutput()
    return out


def vtk_reference(path: str) -> tuple[int, float]:
    """(cells of the top dimension, their total |area| or |volume|), both by VTK (strips as their
    triangles, as vtkTriangleFilter makes them). Polygons: Newell's area on VTK's arrays, since
    vtkCellSizeFilter triangulates a non-convex polygon with collinear vertices wrongly; polyhedra:
    the divergence theorem on VTK's faces (fan triangles), for the same reason."""
    ds = vtk_read(path)
    if ds.IsA("vtkPolyData") and ds.GetNumberOfStrips():
        tf = vtk.vtkTriangleFilter()
        tf.SetInputData(ds)
        tf.Update()
        ds = tf.GetOutput()
    dims = np.array([ds.GetCell(i).GetCellDimension() for i in range(ds.GetNumberOfCells())])
    top = dims.max()
    f = vtk.vtkCellSizeFilter()
    f.SetInputData(ds)
    f.Update()
    name = {2: "Area", 3: "Volume"}[int(top)]
    size = vtk_to_numpy(f.GetOutput().GetCellData().GetArray(name)).copy()
    poly = np.flatnonzero([ds.GetCellType(i) == vtk.VTK_POLYGON for i in range(ds.GetNumberOfCells())])
    for i in poly:  # a test's few polygons
        q = np.array(
            [ds.GetPoint(ds.GetCell(i).GetPointId(j)) for j in range(ds.GetCell(i).GetNumberOfPoints())]
        )
        size[i] = 0.5 * np.linalg.norm(np.cross(q, np.roll(q, -1, axis=0)).sum(axis=0))
    for i in np.flatnonzero([ds.GetCellType(i) == vtk.VTK_POLYHEDRON for i in range(ds.GetNumberOfCells())]):
        cell, vol = ds.GetCell(i), 0.0
        for j in range(cell.GetNumberOfFaces()):
            f = cell.GetFace(j)
            q = np.array([f.GetPoints().GetPoint(k) for k in range(f.GetNumberOfPoints())])
            vol += np.einsum("ij,ij->", np.broadcast_to(q[0], q[1:-1].shape), np.cross(q[1:-1], q[2:])) / 6
        size[i] = vol
    return int((dims == top).sum()), float(np.abs(size[dims == top]).sum())


def agglomerate_read_back(path, k: int, out) -> tuple:
    """Agglomerate `path` into k elements with METIS through the public API, write our VTU to `out`
    and read it back with VTK: (the result, the VTU's cells and total measure by VTK)."""
    from models import agglomerate

    res = agglomerate(path, model="metis", k=k, metrics=False)
    res.write(str(out))
    return (res, *vtk_reference(str(out)))

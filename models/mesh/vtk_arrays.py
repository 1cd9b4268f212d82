"""VTK's datasets as our arrays (models.mesh.vtk_readers reads them): points, offsets,
connectivity and types by vtk_to_numpy, no loop over cells; polydata's verts, lines, polygons and
strips in one CSR; structured datasets' quads / hexahedra from their dimensions; blanked and ghost
cells (vtkGhostType) left out; composite outputs (element blocks, zones,
pieces) joined: blocks that share the file's point set keep it, others have their coincident points
merged, as vtkAppendFilter's MergePoints does; an OpenFOAM case's internal mesh and patches."""

from __future__ import annotations

import os

import numpy as np

from models.errors import MeshError
from models.mesh.cells import BOUNDARY_TAG_NAME, TAG_NAMES, ranges
from models.mesh.container import VTK_POLYHEDRON
from models.mesh.lattice import grid_points, image_points, structured_cells

HIDDEN_CELL, HIDDEN_POINT, DUPLICATE_CELL = 32, 2, 1  # vtkDataSetAttributes ghost bits


def _np(a) -> np.ndarray:
    from vtkmodules.util.numpy_support import vtk_to_numpy

    return vtk_to_numpy(a)


def _cell_data(ds) -> dict:
    cd = ds.GetCellData()
    out = {}
    for i in range(cd.GetNumberOfArrays()):
        a = cd.GetArray(i)
        if a is not None and a.GetName() and a.GetNumberOfComponents() == 1:
            out[a.GetName()] = _np(a)
    return out


def _field_data(data) -> dict:
    """The dataset's field data {name: array} (group names as meshio's field_data: [tag, dim])."""
    fd = data.GetFieldData()
    out = {}
    for i in range(fd.GetNumberOfArrays() if fd is not None else 0):
        a = fd.GetArray(i)
        if a is not None and a.GetName():
            out[a.GetName()] = _np(a).reshape(-1)
    return out


def _arrays(data, path: str, what: str, fmt: str, groups: bool = True, repeats: list | None = None):
    """(points, offsets, connectivity, types, cell data {name: array}, polyhedron faces or None).
    groups: a composite's blocks are physical groups (Exodus element blocks, CGNS zones); not a
    parallel file's pieces, which are one mesh cut for the processes that wrote it. repeats: where
    given, (blocks, cells) of the blocks left out as repeats of an earlier one is appended to it."""
    if data.IsA("vtkCompositeDataSet"):
        return _composite(data, path, what, fmt, groups, repeats)
    return _dataset(data, path, what, fmt)


def _dataset(ds, path, what, fmt):
    if ds.IsA("vtkUnstructuredGrid"):
        out = _unstructured(ds)
    elif ds.IsA("vtkPolyData"):
        out = _polydata(ds)
    elif ds.IsA("vtkImageData") or ds.IsA("vtkStructuredGrid") or ds.IsA("vtkRectilinearGrid"):
        out = _structured(ds)
    else:
        raise MeshError(
            f"cannot read {os.path.basename(path)} as {fmt}: it holds a {ds.GetClassName()[3:]}, not a mesh"
        )
    return _hide_blanked(ds, *out)


def _unstructured(ug):
    n = ug.GetNumberOfPoints()
    pts = _np(ug.GetPoints().GetData()) if n else np.zeros((0, 3))
    cells = ug.GetCells()
    if ug.GetNumberOfCells() == 0:
        return pts, np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8), {}, None
    offsets = _np(cells.GetOffsetsArray())
    conn = _np(cells.GetConnectivityArray())
    ct = ug.GetCellTypes()  # VTK >= 9.6: the type array (before: a vtkCellTypes)
    types = _np(ct if ct.IsA("vtkDataArray") else ug.GetCellTypesArray()).astype(np.uint8, copy=False)
    poly = None
    if np.any(types == 42):
        poly = _polyhedron_faces(ug, types)
    return pts, offsets, conn, types, _cell_data(ug), poly


def _polyhedron_faces(ug, types):
    """The polyhedra's faces, per polyhedron in cell order: (face offsets per polyhedron, face
    offsets, face nodes)."""
    faces, locs = ug.GetPolyhedronFaces(), ug.GetPolyhedronFaceLocations()
    if faces is None or locs is None:
        return None
    f_off, f_conn = _np(faces.GetOffsetsArray()).astype(np.int64), _np(faces.GetConnectivityArray())
    l_off, l_conn = _np(locs.GetOffsetsArray()).astype(np.int64), _np(locs.GetConnectivityArray())
    q = np.flatnonzero(types == 42)
    count = l_off[q + 1] - l_off[q]
    fids = np.asarray(l_conn[ranges(l_off[q], count)], dtype=np.int64)
    if fids.size and (fids.min() < 0 or fids.max() >= f_off.size - 1):
        raise MeshError("a polyhedron refers to a face that the file does not have")
    fsz = f_off[fids + 1] - f_off[fids]
    nodes = np.asarray(f_conn[ranges(f_off[fids], fsz)], dtype=np.int64)
    cell_face_off = np.zeros(q.size + 1, np.int64)
    np.cumsum(count, out=cell_face_off[1:])
    face_off = np.zeros(fsz.size + 1, np.int64)
    np.cumsum(fsz, out=face_off[1:])
    return cell_face_off, face_off, nodes


def _polydata(pd):
    """Verts, lines, polygons, strips (VTK's cell order for polydata) in one CSR."""
    n = pd.GetNumberOfPoints()
    pts = _np(pd.GetPoints().GetData()) if n else np.zeros((0, 3))
    offs, conns, types = [], [], []
    base = 0
    for arr, one, many in (
        (pd.GetVerts(), 1, 2),
        (pd.GetLines(), 3, 4),
        (pd.GetPolys(), 7, 7),
        (pd.GetStrips(), 6, 6),
    ):
        if arr is None or arr.GetNumberOfCells() == 0:
            continue
        o = _np(arr.GetOffsetsArray()).astype(np.int64)
        c = _np(arr.GetConnectivityArray())
        sizes = np.diff(o)
        offs.append(o[1:] + base)
        conns.append(c)
        types.append(np.where(sizes == (1 if one == 1 else 2), one, many).astype(np.uint8))
        base += int(o[-1])
    if not types:
        return pts, np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8), {}, None
    offsets = np.concatenate([np.zeros(1, np.int64), *offs])
    conn = conns[0] if len(conns) == 1 else np.concatenate([np.asarray(c, np.int64) for c in conns])
    return pts, offsets, conn, np.concatenate(types), _cell_data(pd), None


def _structured(ds):
    """Image data, structured and rectilinear grids: hexahedra (3D), quads (2D) or lines from the
    point dimensions, VTK's cell numbering (i fastest): lattice.structured_cells."""
    ext = ds.GetExtent()
    dims = [int(ext[2 * a + 1] - ext[2 * a] + 1) for a in range(3)]
    if ds.IsA("vtkImageData"):
        m = ds.GetDirectionMatrix()
        d = np.array([[m.GetElement(i, j) for j in range(3)] for i in range(3)])
        pts = image_points(ds.GetOrigin(), ds.GetSpacing(), ext, d)
    elif ds.IsA("vtkRectilinearGrid"):
        axes = [
            np.asarray(_np(c), np.float64) if c is not None else np.zeros(1)
            for c in (ds.GetXCoordinates(), ds.GetYCoordinates(), ds.GetZCoordinates())
        ]
        pts = grid_points(axes)
    else:
        pts = _np(ds.GetPoints().GetData()) if ds.GetNumberOfPoints() else np.zeros((0, 3))
    offsets, conn, types = structured_cells(dims)
    return pts, offsets, conn, types, _cell_data(ds) if types.size else {}, None


def _hide_blanked(ds, pts, offsets, conn, types, cell_data, poly):
    """Drop blanked (hidden) cells, and cells on hidden points, as VTK does when it draws them, and
    ghost cells (vtkGhostType DUPLICATECELL: copies of another piece's cells, in a parallel file's
    pieces, in a piece read alone, in a multiblock of pieces), which ParaView does not draw either;
    polyhedra with their faces. hidden_cells counts them."""
    hide = _hidden(ds, offsets, conn, types)
    cell_data.pop("vtkGhostType", None)
    if hide is None or not hide.any():
        return pts, offsets, conn, types, cell_data, poly
    keep = np.flatnonzero(~hide)
    sizes = np.diff(offsets)[keep]
    conn = np.asarray(conn)[ranges(offsets[keep], sizes)]
    if poly is not None:  # the kept polyhedra's faces
        poly = _kept_polyhedra(poly, ~hide[np.asarray(types) == VTK_POLYHEDRON])
    offsets = np.zeros(keep.size + 1, np.int64)
    np.cumsum(sizes, out=offsets[1:])
    cell_data = {k: v[keep] for k, v in cell_data.items() if len(v) == hide.size}
    return pts, offsets, conn, types[keep], cell_data, poly


def _hidden(ds, offsets, conn, types) -> np.ndarray | None:
    """(C,) bool: the cells VTK does not draw (HIDDENCELL, DUPLICATECELL, or on a HIDDENPOINT), or
    None without a ghost array. A ghost array of another number type is read as integers."""
    ghost = _ghosts(ds.GetCellData())
    pghost = _ghosts(ds.GetPointData())
    hide = None
    if ghost is not None:
        hide = (ghost & (HIDDEN_CELL | DUPLICATE_CELL)) != 0
    if pghost is not None and types.size:
        hp = (pghost & HIDDEN_POINT) != 0
        if hp.any():
            cell = np.repeat(np.arange(types.size), np.diff(offsets))
            on = np.bincount(cell, weights=hp[np.asarray(conn, np.int64)], minlength=types.size) > 0
            hide = on if hide is None else hide | on
    return hide


def _ghosts(attributes) -> np.ndarray | None:
    """The vtkGhostType array of cell or point data as int64 flags, or None where there is none or
    it is not one value per cell (a vector of that name: no ghost array for VTK's filters either)."""
    arr = attributes.GetArray("vtkGhostType")
    if arr is None or arr.GetNumberOfComponents() != 1:
        return None
    return _np(arr).astype(np.int64).reshape(-1)


def _kept_polyhedra(poly, keep: np.ndarray):
    """VTK's polyhedron faces (faces per polyhedron (Q+1,), nodes per face (F+1,), face nodes) of
    the polyhedra `keep` (Q,) keeps."""
    cell_face_off, face_off, face_nodes = (np.asarray(a, dtype=np.int64) for a in poly)
    q = np.flatnonzero(keep)
    nf = np.diff(cell_face_off)[q]
    faces = ranges(cell_face_off[q], nf)
    fsz = np.diff(face_off)[faces]
    new_cf, new_fo = np.zeros(q.size + 1, np.int64), np.zeros(faces.size + 1, np.int64)
    np.cumsum(nf, out=new_cf[1:])
    np.cumsum(fsz, out=new_fo[1:])
    return new_cf, new_fo, face_nodes[ranges(face_off[faces], fsz)]


def hidden_cells(data) -> tuple[int, int, int]:
    """(ghost cells, hidden cells, cells) of a dataset or of a composite's datasets: the cells
    _hide_blanked leaves out, by their vtkGhostType (DUPLICATECELL: copies of another piece's
    cells; HIDDENCELL or on a hidden point: blanked), and all of them."""
    leaves = _leaves(data) if data.IsA("vtkCompositeDataSet") else [data]
    dup = hid = total = 0
    for ds in leaves:
        total += ds.GetNumberOfCells()
        g = _ghosts(ds.GetCellData())
        if g is not None:
            dup += int(np.count_nonzero(g & DUPLICATE_CELL))
            hid += int(np.count_nonzero((g & HIDDEN_CELL) & ~(g & DUPLICATE_CELL)))
    return dup, hid, total


def _leaves(data) -> list:
    it = data.NewIterator()
    it.SkipEmptyNodesOn()
    it.InitTraversal()
    out = []
    while not it.IsDoneWithTraversal():
        ds = it.GetCurrentDataObject()
        if ds is not None and ds.IsA("vtkDataSet") and ds.GetNumberOfCells() > 0:
            out.append(ds)
        it.GoToNextItem()
    return out


def _composite(data, path, what, fmt, groups: bool = True, repeats: list | None = None):
    """Element blocks / zones joined in one cell set; a `block` tag (1, 2, ...) where the blocks
    carry no tag of their own and are groups (not a parallel file's pieces)."""
    leaves = _leaves(data)
    if not leaves:
        raise MeshError(f"cannot read {os.path.basename(path)} as {fmt}: the file has no cells")
    every = [_dataset(ds, path, what, fmt) for ds in leaves]
    parts = _distinct(every)
    if repeats is not None and len(parts) < len(every):
        repeats.append(
            (len(every) - len(parts), sum(len(p[3]) for p in every) - sum(len(p[3]) for p in parts))
        )
    if len(parts) == 1:
        pts, off, conn, types, cd, poly = parts[0]
        if groups and not any(k in cd for k in TAG_NAMES):
            cd = {**cd, "block": np.ones(len(types), np.int64)}
        return pts, off, conn, types, cd, poly
    shared = all(len(p[0]) == len(parts[0][0]) for p in parts) and all(
        p[0] is parts[0][0] or np.array_equal(p[0], parts[0][0]) for p in parts[1:]
    )
    offs, conns, types, polys, bad = [np.zeros(1, np.int64)], [], [], [], []
    base_c = base_p = 0
    for pts, off, conn, t, _, poly in parts:
        offs.append(np.asarray(off[1:], np.int64) + base_c)
        conn = np.asarray(conn, np.int64)
        # an id outside its own block's points must not name another block's point once joined
        bad.append((conn < 0) | (conn >= len(pts)))
        conns.append(conn + (0 if shared else base_p))
        types.append(t)
        polys.append(poly)
        base_c += int(off[-1])
        base_p += len(pts)
    keys = set(parts[0][4]).intersection(*(p[4] for p in parts[1:]))
    cd = {k: np.concatenate([p[4][k] for p in parts]) for k in keys}
    own = [next((k for k in TAG_NAMES if k in p[4] and len(p[4][k]) == len(p[3])), None) for p in parts]
    if not any(k in cd for k in TAG_NAMES) and all(own):  # each block tagged under its own name
        # (an XDMF of dolfinx: its cells' "cell_tags", its facets' "facet_tags"): one tag array
        cd[own[0]] = np.concatenate(
            [np.asarray(p[4][k]).reshape(-1) for p, k in zip(parts, own, strict=True)]
        )
    elif groups:
        cd["block"] = np.repeat(np.arange(1, len(parts) + 1), [len(p[3]) for p in parts])
    poly = _join_polys(polys, [p[0] for p in parts], shared) if any(p is not None for p in polys) else None
    conn = np.concatenate(conns)
    bad = np.concatenate(bad)
    if shared:
        pts = parts[0][0]
    else:
        pts = np.concatenate([np.asarray(p[0], np.float64) for p in parts])
        pts, inverse = np.unique(pts, axis=0, return_inverse=True)  # coincident points merged
        inverse = inverse.reshape(-1)
        conn = inverse[np.where(bad, 0, conn)]
        if poly is not None:
            poly = (poly[0], poly[1], inverse[poly[2]])
    if bad.any():  # (out of range of the joined points: the cells read later leaves out or refuses)
        conn[bad] = len(pts)
    return pts, np.concatenate(offs), conn, np.concatenate(types), cd, poly


def _distinct(parts: list) -> list:
    """The blocks, each one repeating an earlier block (same points and cells) dropped, its cell
    data given to that block where it lacks them: an XDMF time series holds its mesh once as a grid
    and once per time step, all of them the same mesh; dolfinx's XDMF holds its cells once more as
    the grid of their tags."""
    kept: list = []
    for part in parts:
        pts, off, conn, types = part[:4]
        same = next(
            (
                k
                for k in kept
                if len(k[3]) == len(types)
                and len(k[2]) == len(conn)
                and np.array_equal(k[3], types)
                and np.array_equal(k[2], conn)
                and np.array_equal(k[1], off)
                and (k[0] is pts or np.array_equal(k[0], pts))
            ),
            None,
        )
        if same is None:
            kept.append(part)
        else:
            for key, values in part[4].items():
                same[4].setdefault(key, values)
    return kept


def _join_polys(polys, pts_list, shared):
    cf, fo, fn = [np.zeros(1, np.int64)], [np.zeros(1, np.int64)], []
    base_f = base_n = base_p = 0
    for poly, pts in zip(polys, pts_list, strict=True):
        if poly is not None:
            cf.append(poly[0][1:] + base_f)
            fo.append(poly[1][1:] + base_n)
            fn.append(poly[2] + (0 if shared else base_p))
            base_f += int(poly[0][-1])
            base_n += int(poly[1][-1])
        base_p += len(pts)
    return np.concatenate(cf), np.concatenate(fo), np.concatenate(fn)


def _openfoam(data, path, what, fmt, decomposed: bool = False):
    """The internal mesh's cells (no group) and the boundary patches' faces as boundary cells
    tagged 1, 2, ... in the case's patch order, their names in the field data (as meshio's
    field_data: name -> [tag, 2]). The patches' points are found among the internal mesh's by their
    coordinates (the reader gives every patch its own copy); internal points that coincide (a
    baffle's two sides) stay apart, except in a decomposed case, whose processors' meshes the
    reader appends with the points on their cuts once per processor: there coincident points
    are merged (the processors' patches are not boundary groups: VTK's reader leaves them out)."""
    internal, patches, zones = None, [], []
    for i in range(data.GetNumberOfBlocks()):
        name = data.GetMetaData(i).Get(data.NAME()) if data.HasMetaData(i) else ""
        block = data.GetBlock(i)
        if block is None:
            continue
        if name == "internalMesh":
            internal = block
        elif name == "boundary" and block.IsA("vtkMultiBlockDataSet"):
            for j in range(block.GetNumberOfBlocks()):
                patch = block.GetBlock(j)
                if patch is not None and patch.GetNumberOfCells() > 0:
                    patches.append((block.GetMetaData(j).Get(data.NAME()), patch))
        elif name == "zones" and block.IsA("vtkMultiBlockDataSet"):
            for j in range(block.GetNumberOfBlocks()):
                kind = block.GetMetaData(j).Get(data.NAME()) if block.HasMetaData(j) else ""
                inner = block.GetBlock(j)
                if kind == "cellZones" and inner is not None and inner.IsA("vtkMultiBlockDataSet"):
                    for z in range(inner.GetNumberOfBlocks()):
                        grid = inner.GetBlock(z)
                        if grid is not None and grid.GetNumberOfCells() > 0:
                            zones.append((inner.GetMetaData(z).Get(data.NAME()), grid))
    if internal is None or internal.GetNumberOfCells() == 0:
        raise MeshError(
            f"cannot read {os.path.basename(path)} as {fmt}: its internal mesh has no cells "
            "(constant/polyMesh: points, faces, owner, neighbour, boundary, are empty or cannot be read)"
        )
    pts, offsets, conn, types, _, poly = _dataset(internal, path, what, fmt)
    pts = np.asarray(pts, np.float64)
    if decomposed:
        pts, inverse = np.unique(pts, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        conn = inverse[np.asarray(conn, np.int64)]
        if poly is not None:
            poly = (poly[0], poly[1], inverse[poly[2]])
    field = {}
    zone_tags = _cell_zones(zones, pts, offsets, conn, path, what, fmt, field)
    if patches:
        parts = [_dataset(p, path, what, fmt) for _, p in patches]
        ppts = np.concatenate([np.asarray(p[0], np.float64) for p in parts])
        _, first, inverse = np.unique(
            np.concatenate([pts, ppts]), axis=0, return_index=True, return_inverse=True
        )
        at = first[inverse.reshape(-1)[len(pts) :]]  # each patch point's first copy
        new = at >= len(pts)  # (a patch point the internal mesh lacks: kept, at the end)
        if new.any():
            keep, where = np.unique(at[new], return_inverse=True)
            at[new] = len(pts) + where
            pts = np.concatenate([pts, np.concatenate([pts, ppts])[keep]])
        base, offs, conns, tps, tags = (
            0,
            [np.asarray(offsets, np.int64)],
            [np.asarray(conn, np.int64)],
            [types],
            [],
        )
        end = int(offsets[-1])
        for t, ((name, _), part) in enumerate(zip(patches, parts, strict=True), start=1):
            _, o, c, ty = part[:4]
            offs.append(np.asarray(o[1:], np.int64) + end)
            conns.append(at[np.asarray(c, np.int64) + base])
            tps.append(ty)
            tags.append(np.full(len(ty), t, np.int64))
            end += int(o[-1])
            base += len(part[0])
            field[str(name).rsplit("/", 1)[-1]] = np.array([t, 2])
        offsets, conn, types = np.concatenate(offs), np.concatenate(conns), np.concatenate(tps)
        cell_data = {
            BOUNDARY_TAG_NAME: np.concatenate([np.zeros(internal.GetNumberOfCells(), np.int64), *tags])
        }
    else:
        cell_data = {}
    if zone_tags is not None:
        cell_data["group"] = np.concatenate([zone_tags, np.zeros(len(types) - len(zone_tags), np.int64)])
    return pts, offsets, conn, types, cell_data, poly, field


def _cell_zones(zones, pts, offsets, conn, path, what, fmt, field) -> np.ndarray | None:
    """The case's cellZones as groups: a tag per internal cell (1, 2, ... in the zones' order; 0
    in none, the first zone where a cell is in several), the names in `field` (dimension 3).
    VTK's reader gives each zone as a grid of its own with copies of its cells and no cell ids:
    a zone's cell is found among the internal mesh's by its points (found by their coordinates),
    keyed by their number, sum, sum of squares and smallest id."""
    if not zones:
        return None
    n = len(offsets) - 1
    offsets = np.asarray(offsets, np.int64)
    ids = np.asarray(conn, np.int64)

    def keys(o, c):
        counts = np.diff(o)
        if counts.size == 0 or np.any(counts == 0):
            return np.zeros((counts.size, 4), np.int64)
        at = o[:-1]
        c = c.astype(np.int64)
        return np.column_stack(
            [counts, np.add.reduceat(c, at), np.add.reduceat(c * c, at), np.minimum.reduceat(c, at)]
        )

    mine = keys(offsets, ids)
    tags = np.zeros(n, np.int64)
    for t, (name, grid) in enumerate(zones, start=1):
        zpts, zoff, zconn = _dataset(grid, path, what, fmt)[:3]
        zpts = np.asarray(zpts, np.float64)
        _, first, inverse = np.unique(
            np.concatenate([pts, zpts]), axis=0, return_index=True, return_inverse=True
        )
        at = first[inverse.reshape(-1)[len(pts) :]]
        if np.any(at >= len(pts)):
            continue  # (a zone with points the internal mesh lacks: not of this mesh)
        theirs = keys(np.asarray(zoff, np.int64), at[np.asarray(zconn, np.int64)])
        pos = _lex_find(mine, theirs)
        cells = pos[pos >= 0]
        free = cells[tags[cells] == 0]
        tags[free] = t
        if free.size:
            field[str(name)] = np.array([t, 3])
    return tags if tags.any() else None


def _lex_find(table: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The index in `table` of each of `rows` (its first equal row), -1 where absent."""
    both = np.concatenate([table, rows])
    _, inverse = np.unique(both, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    where = np.full(inverse.max() + 1 if inverse.size else 0, -1, np.int64)
    where[inverse[: len(table)][::-1]] = np.arange(len(table))[::-1]
    return where[inverse[len(table) :]]

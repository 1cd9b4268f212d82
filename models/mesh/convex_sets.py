"""VTK_CONVEX_POINT_SET cells (type 41) read as polyhedra (type 42).

A convex point set is a volume cell given by its points alone: VTK triangulates their convex hull
when it needs the cell's shape. Here each one becomes a polyhedron whose faces are the faces of its
points' convex hull (scipy's Qhull), the coplanar triangles Qhull returns merged back into one
polygon (a hexahedron's corners give 6 quadrilaterals, not 12 triangles, so the face it shares with
a neighbouring hexahedron or polyhedron is found as one face), ordered counter-clockwise seen from
outside. Points of a set inside its hull are left out of the cell.

The hulls are made one cell at a time: VTK's own writers are the only ones known to write this type
(vtkConvexPointSet cells of a dataset filtered in VTK), a few cells of a file.
"""

from __future__ import annotations

import numpy as np

from models.errors import MeshError

VTK_CONVEX_POINT_SET = 41
VTK_POLYHEDRON = 42


def _offsets(sizes: np.ndarray) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)])


def _hull_faces(xyz: np.ndarray, ids: np.ndarray) -> list[np.ndarray]:
    """The faces of the convex hull of points `xyz` (rows) as lists of `ids`, outward."""
    from scipy.spatial import ConvexHull, QhullError

    if ids.size < 4:
        raise MeshError(f"a convex point set has {ids.size} points: a volume needs 4 at least")
    try:
        hull = ConvexHull(xyz)
    except (QhullError, ValueError):
        raise MeshError("a convex point set has all its points in one plane (no volume)") from None
    scale = float(np.ptp(xyz, axis=0).max()) or 1.0
    eq = hull.equations  # (outward unit normal, offset) per triangle
    key = np.round(np.c_[eq[:, :3], eq[:, 3] / scale] * 1e6).astype(np.int64)
    _, plane = np.unique(key, axis=0, return_inverse=True)
    faces = []
    for p in range(int(plane.max()) + 1):  # a loop over the hull's planes (a few per cell)
        tri = hull.simplices[plane.ravel() == p]
        verts = np.unique(tri)
        normal = eq[plane.ravel() == p][0, :3]
        centre = xyz[verts].mean(axis=0)
        u = xyz[verts[0]] - centre
        u /= np.linalg.norm(u) or 1.0
        v = np.cross(normal, u)
        d = xyz[verts] - centre
        order = np.argsort(np.arctan2(d @ v, d @ u), kind="stable")  # counter-clockwise about the normal
        faces.append(ids[verts[order]])
    return faces


def as_polyhedra(points, offsets, conn, types, poly):
    """(offsets, conn, types, poly) with every convex point set a polyhedron (its hull's faces in
    `poly`, the polyhedra in cell order as vtk_readers hands them to cells.normalize); unchanged where
    there is none. poly: (face offsets per polyhedron cell, face offsets, face nodes) or None."""
    types = np.asarray(types)
    sets = np.flatnonzero(types == VTK_CONVEX_POINT_SET)
    if not sets.size:
        return offsets, conn, types, poly
    pts = np.asarray(points, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.int64)
    conn = np.asarray(conn, dtype=np.int64)
    new_count, new_sizes, new_nodes = [], [], []
    for c in sets:  # a loop over the convex point sets (rare: module docstring)
        ids = conn[offsets[c] : offsets[c + 1]]
        faces = _hull_faces(pts[ids], ids)
        new_count.append(len(faces))
        new_sizes += [f.size for f in faces]
        new_nodes += list(faces)
    old = np.flatnonzero(types == VTK_POLYHEDRON)
    if old.size:
        cf, fo, fn = (np.asarray(a, dtype=np.int64) for a in poly)
        if cf.size < old.size + 1:
            raise MeshError("the file has fewer polyhedron face lists than polyhedron cells")
        fcount_old = cf[1 : old.size + 1] - cf[: old.size]
        fids = _ranges(cf[: old.size], fcount_old)
        fsizes_old = fo[fids + 1] - fo[fids]
        nodes_old = fn[_ranges(fo[fids], fsizes_old)]
    else:
        fcount_old = fsizes_old = nodes_old = np.zeros(0, dtype=np.int64)
    cells = np.concatenate([old, sets])
    fcount = np.concatenate([fcount_old, np.asarray(new_count, dtype=np.int64)])
    fsizes = np.concatenate([fsizes_old, np.asarray(new_sizes, dtype=np.int64)])
    nodes = np.concatenate([nodes_old, *new_nodes])
    order = np.argsort(cells, kind="stable")
    forder = _ranges(_offsets(fcount)[:-1][order], fcount[order])
    norder = _ranges(_offsets(fsizes)[:-1][forder], fsizes[forder])
    types = types.copy()
    types[sets] = VTK_POLYHEDRON
    return offsets, conn, types, (_offsets(fcount[order]), _offsets(fsizes[forder]), nodes[norder])


def _ranges(starts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    from models.mesh.cells import ranges

    return ranges(np.asarray(starts, dtype=np.int64), np.asarray(sizes, dtype=np.int64))

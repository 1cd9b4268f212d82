"""Vectorized cell geometry: faces, measures, centroids, diameters (no Python loop over cells).

2D cells are node cycles (triangles, quads and polygons alike); their "faces" are edges.
3D cells come from per-type face templates (outward faces for a positively oriented VTK cell)
and, for VTK polyhedra, from their stored faces. Measures use the divergence theorem on the
fan-triangulated faces, so any star-shaped cell is exact.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from models.mesh.container import VTK_HEXAHEDRON, VTK_PYRAMID, VTK_TETRA, VTK_WEDGE, Mesh

# Outward faces of positively oriented VTK cells.
FACE_TEMPLATES: dict[int, list[tuple[int, ...]]] = {
    VTK_TETRA: [(0, 2, 1), (0, 1, 3), (1, 2, 3), (0, 3, 2)],
    VTK_HEXAHEDRON: [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)],
    VTK_WEDGE: [(0, 1, 2), (3, 5, 4), (0, 3, 4, 1), (1, 4, 5, 2), (2, 5, 3, 0)],
    VTK_PYRAMID: [(0, 3, 2, 1), (0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)],
}


NODES = {VTK_TETRA: 4, VTK_HEXAHEDRON: 8, VTK_WEDGE: 6, VTK_PYRAMID: 5}


def _one_fixed_type(mesh: Mesh) -> int | None:
    """The cell type when every cell is of one type of FACE_TEMPLATES (stored as rows of its node
    count, offsets k * i), else None."""
    n = mesh.n_cells
    if not n or mesh.poly_cells is not None:
        return None
    t = int(mesh.cell_types[0])
    k = NODES.get(t)
    if k is None or mesh.connectivity.size != k * n or mesh.offsets[-1] != k * n:
        return None
    if not (np.all(mesh.cell_types == t) and np.array_equal(mesh.offsets, np.arange(0, k * n + 1, k))):
        return None
    return t


def fixed_template(t: int) -> tuple[np.ndarray, np.ndarray]:
    """FACE_TEMPLATES[t] flat for models/mesh/_fastmesh.c: (local nodes of the faces, the triangles
    first, in template order, as cell_faces orders a cell's faces; (nf,) their sizes)."""
    faces = FACE_TEMPLATES[t]
    order = [f for f in faces if len(f) == 3] + [f for f in faces if len(f) != 3]
    return (
        np.array([j for f in order for j in f], dtype=np.int64),
        np.array([len(f) for f in order], dtype=np.int64),
    )


def fixed_layout_compiled(mesh: Mesh):
    """(compiled module, cell type) when the read stage can validate this mesh without a face array
    (3D, cells of one FACE_TEMPLATES type other than tetrahedra, models/mesh/_fastmesh.c built)."""
    from models.native import compiled

    if mesh.dim != 3:
        return None
    t = _one_fixed_type(mesh)
    if t is None or t == VTK_TETRA:
        return None
    fast = compiled("mesh._fastmesh")
    return None if fast is None else (fast, t)


@functools.cache
def _templates() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every FACE_TEMPLATES type's fixed_template for cells_validate: (ttab (256 * 4): per VTK type
    (nodes, faces, start in tmpl, start in tsize), zeros for the others; tmpl; tsize)."""
    ttab = np.zeros((256, 4), dtype=np.int64)
    tmpl, tsize = [], []
    for t in FACE_TEMPLATES:
        a, b = fixed_template(t)
        ttab[t] = (NODES[t], b.size, sum(x.size for x in tmpl), sum(x.size for x in tsize))
        tmpl.append(a)
        tsize.append(b)
    return ttab.reshape(-1), np.concatenate(tmpl), np.concatenate(tsize)


def cells_validate(mesh: Mesh, measures_only: bool = False):
    """The read stage's validation in one compiled pass per cell (models/mesh/_fastmesh.c
    cells_validate, in threads where the mesh is large), for 3D cells of FACE_TEMPLATES types (mixed
    or not) and 2D polygons: (signed measures, centroids, own-sign flips (C,) bool, consistent),
    consistent True when flipping every cell by its own sign orients all of them consistently (no
    face met twice in the same direction). Bit for bit _measures_and_centroids' values. None where it
    does not apply (polyhedra, other types, the module not built). measures_only: no face check
    (consistent is then False)."""
    from models.native import compiled, threads

    n, d = mesh.n_cells, mesh.dim
    if not n or mesh.poly_cells is not None or mesh.points.shape[1] != d:
        return None
    fast = compiled("mesh._fastmesh")
    if fast is None:
        return None
    vol, cen, flip = np.empty(n), np.empty((n, d)), np.empty(n, dtype=np.uint8)
    ok = fast.cells_validate(
        np.ascontiguousarray(mesh.points, dtype=np.float64),
        np.ascontiguousarray(mesh.offsets, dtype=np.int64),
        np.ascontiguousarray(mesh.connectivity, dtype=np.int64),
        np.ascontiguousarray(mesh.cell_types, dtype=np.uint8),
        *_templates(),
        vol,
        cen,
        flip,
        np.array([mesh.n_points], dtype=np.int64),
        np.array([threads()], dtype=np.int64),
        np.array([1 if measures_only else 0], dtype=np.int64),
    )
    return None if ok < 0 else (vol, cen, flip.view(bool), bool(ok))


def _fixed_measures(mesh: Mesh) -> tuple[np.ndarray, np.ndarray] | None:
    """_measures_and_centroids of a 3D mesh of FACE_TEMPLATES cells (mixed or not, no polyhedra) by
    the compiled models/mesh/_fastmesh.c (cells_validate's measures, in threads; the same values bit
    for bit: each cell's faces and triangles in the order of cell_faces + face_triangles); None where
    it does not apply or was not built."""
    if mesh.dim != 3:
        return None
    got = cells_validate(mesh, measures_only=True)
    return None if got is None else got[:2]


@dataclass
class Faces:
    """All faces of all cells (each interior face appears twice, once per cell).

    cell (F,): owning cell; offsets (F+1,) / nodes: CSR face -> point ids, ordered so that the
    normal points out of the owning cell (2D: edges, ordered counter-clockwise around the cell).
    """

    cell: np.ndarray
    offsets: np.ndarray
    nodes: np.ndarray

    @property
    def n(self) -> int:
        return int(self.cell.shape[0])

    def sizes(self) -> np.ndarray:
        return np.diff(self.offsets)

    def padded(self) -> np.ndarray:
        """(F, widest face) table of the nodes, short faces padded with the largest int64 (which
        sorts last and is never a face's smallest node)."""
        sizes = self.sizes()
        pad = np.full((self.n, int(sizes.max())), np.iinfo(np.int64).max, dtype=np.int64)
        col = np.arange(self.nodes.size) - np.repeat(self.offsets[:-1], sizes)
        pad[np.repeat(np.arange(self.n), sizes), col] = self.nodes
        return pad


def cell_index(offsets: np.ndarray) -> np.ndarray:
    """(nnz,) the row of every entry of a CSR array."""
    return np.repeat(np.arange(offsets.size - 1), np.diff(offsets))


def next_in_cycle(offsets: np.ndarray) -> np.ndarray:
    """(nnz,) index of the next entry of the same row, wrapping around (for node cycles)."""
    nnz = int(offsets[-1])
    nxt = np.arange(1, nnz + 1)
    ends = offsets[1:] - 1
    nxt[ends[np.diff(offsets) > 0]] = offsets[:-1][np.diff(offsets) > 0]
    return nxt


def cell_faces(mesh: Mesh) -> Faces:
    """Every face (3D) or edge (2D) of every cell, outward oriented."""
    if mesh.dim == 2:
        n, nnz = mesh.n_cells, mesh.connectivity.size
        k = nnz // n if n else 0
        if k and nnz == k * n and np.array_equal(mesh.offsets, np.arange(0, nnz + 1, k)):
            c = mesh.connectivity.reshape(n, k)  # one cell size: edges (c[j], c[j + 1]) by one copy each
            nodes = np.empty((n, k, 2), dtype=mesh.connectivity.dtype)
            nodes[:, :, 0] = c
            nodes[:, :-1, 1] = c[:, 1:]
            nodes[:, -1, 1] = c[:, 0]
            return Faces(
                cell=np.repeat(np.arange(n), k),
                offsets=np.arange(0, 2 * nnz + 1, 2, dtype=np.int64),
                nodes=nodes.reshape(-1),
            )
        nxt = next_in_cycle(mesh.offsets)
        nodes = np.column_stack([mesh.connectivity, mesh.connectivity[nxt]]).reshape(-1)
        cell = cell_index(mesh.offsets)
        return Faces(cell=cell, offsets=np.arange(0, nodes.size + 1, 2, dtype=np.int64), nodes=nodes)
    if _all_tetrahedra(mesh):  # one reshape, faces already grouped by cell
        n = mesh.n_cells
        # np.take with a flat index: several times the speed of c[:, (4, 3) table]
        nodes = np.take(
            mesh.connectivity.reshape(-1, 4), np.array(FACE_TEMPLATES[VTK_TETRA]).reshape(-1), axis=1
        ).reshape(-1)
        return Faces(
            cell=np.repeat(np.arange(n), 4),
            offsets=np.arange(0, 12 * n + 1, 3, dtype=np.int64),
            nodes=nodes.astype(np.int64, copy=False),
        )
    parts_cell, parts_size, parts_nodes = [], [], []
    one = _one_fixed_type(mesh)
    for t, faces in FACE_TEMPLATES.items():
        sel = (
            np.flatnonzero(mesh.cell_types == t)
            if one is None
            else np.arange(mesh.n_cells)
            if one == t
            else None
        )
        if sel is None or sel.size == 0:
            continue
        n = NODES[t]
        conn = (
            mesh.connectivity.reshape(-1, n)
            if one == t
            else mesh.connectivity[mesh.offsets[sel][:, None] + np.arange(n)[None, :]]
        )
        for size in (3, 4):
            tmpl = [f for f in faces if len(f) == size]
            if not tmpl:
                continue
            fn = conn[:, np.array(tmpl)]  # (ncells, nf, size)
            parts_cell.append(np.repeat(sel, len(tmpl)))
            parts_size.append(np.full(sel.size * len(tmpl), size, dtype=np.int64))
            parts_nodes.append(fn.reshape(-1))
    if mesh.poly_cells is not None:
        nf = np.diff(mesh.poly_cell_faces)
        parts_cell.append(np.repeat(mesh.poly_cells, nf))
        parts_size.append(np.diff(mesh.poly_face_offsets))
        parts_nodes.append(mesh.poly_face_nodes)
    cell = np.concatenate(parts_cell)
    sizes = np.concatenate(parts_size)
    nodes = np.concatenate(parts_nodes).astype(np.int64)
    offsets = np.zeros(sizes.size + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    if len(parts_cell) == 1:  # one part (e.g. hexahedra only): already grouped by cell
        return Faces(cell=cell, offsets=offsets, nodes=nodes)
    # order faces by cell (stable), so faces of a cell are contiguous
    order = np.argsort(cell, kind="stable")
    if not np.array_equal(order, np.arange(order.size)):
        cell, offsets, nodes = cell[order], *reorder_csr(offsets, nodes, order)
    return Faces(cell=cell, offsets=offsets, nodes=nodes)


def reorder_csr(offsets: np.ndarray, values: np.ndarray, order: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of a CSR array taken in `order` (vectorized gather)."""
    sizes = np.diff(offsets)[order]
    new_offsets = np.zeros(order.size + 1, dtype=np.int64)
    np.cumsum(sizes, out=new_offsets[1:])
    src = np.repeat(offsets[:-1][order] - new_offsets[:-1], sizes) + np.arange(new_offsets[-1])
    return new_offsets, values[src]


def fan_triangles(offsets: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fan-triangulate polygons given in CSR: returns (owner (T,), tri (T, 3) point ids)."""
    sizes = np.diff(offsets)
    ntri = np.maximum(sizes - 2, 0)
    owner = np.repeat(np.arange(sizes.size), ntri)
    first = np.zeros(ntri.size + 1, dtype=np.int64)
    np.cumsum(ntri, out=first[1:])
    k = np.arange(first[-1]) - first[:-1][owner] + 1  # 1..n-2
    base = offsets[:-1][owner]
    tri = np.column_stack([nodes[base], nodes[base + k], nodes[base + k + 1]])
    return owner, tri


def face_triangles(points: np.ndarray, offsets: np.ndarray, nodes: np.ndarray):
    """Faces cut into triangles the same way from both sides: (owner (T,), a, b, c (T, 3) corners).

    Triangles stay as they are; a face of 4+ nodes is fanned from the mean of its nodes, which
    does not depend on where its node cycle starts. Two cells sharing a non-planar (warped) face
    then bound the same surface, so their volumes add up exactly to their union's."""
    sizes = np.diff(offsets)
    if sizes.size and sizes.max() == 3 and sizes.min() == 3:
        t = nodes.reshape(-1, 3)
        return np.arange(sizes.size), points[t[:, 0]], points[t[:, 1]], points[t[:, 2]]
    tri = sizes == 3
    face = cell_index(offsets)
    nxt = next_in_cycle(offsets)
    big = ~tri[face]  # node entries of faces with 4+ nodes: one triangle each
    counts = np.maximum(sizes, 1).astype(np.float64)
    centre = (
        np.column_stack([np.bincount(face, weights=points[nodes, d], minlength=sizes.size) for d in range(3)])
        / counts[:, None]
    )
    t_ids = np.flatnonzero(tri)
    t0 = offsets[t_ids]
    e = np.flatnonzero(big)
    owner = np.concatenate([t_ids, face[e]])
    a = np.concatenate([points[nodes[t0]], centre[face[e]]])
    b = np.concatenate([points[nodes[t0 + 1]], points[nodes[e]]])
    c = np.concatenate([points[nodes[t0 + 2]], points[nodes[nxt[e]]]])
    return owner, a, b, c


def vertex_means(mesh: Mesh) -> np.ndarray:
    """(C, dim) mean of each cell's nodes."""
    cell = cell_index(mesh.offsets)
    counts = np.diff(mesh.offsets).astype(np.float64)
    return np.column_stack(
        [
            np.bincount(cell, weights=mesh.points[mesh.connectivity, d], minlength=mesh.n_cells) / counts
            for d in range(mesh.dim)
        ]
    )


def _polygon_measures(
    points: np.ndarray, offsets: np.ndarray, conn: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Signed area and centroid of node cycles, one reshape per distinct cycle length (the compiled
    twin: measure_polygon in models/mesh/_fastmesh.c, the same float operations in the same order)."""
    n = offsets.size - 1
    sizes = np.diff(offsets)
    area = np.empty(n)
    cen = np.empty((n, 2))
    for s in np.unique(sizes):  # a loop over the few distinct polygon sizes
        sel = None if sizes[0] == s and sizes[-1] == s and np.all(sizes == s) else np.flatnonzero(sizes == s)
        idx = conn.reshape(-1, s) if sel is None else conn[offsets[sel][:, None] + np.arange(s)[None, :]]
        if s == 3:  # triangles: closed form, no roll
            p0, p1, p2 = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
            u, v = p1 - p0, p2 - p0
            a = 0.5 * (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
            c = (p0 + p1 + p2) / 3.0
            if sel is None:
                return a, c
            area[sel] = a
            cen[sel] = c
            continue
        x = points[idx]  # (m, s, 2)
        o = x[:, :1, :]
        x = x - o
        xa, ya = x[:, :, 0], x[:, :, 1]
        xb, yb = np.roll(xa, -1, axis=1), np.roll(ya, -1, axis=1)
        cross = xa * yb - xb * ya
        # sums in cycle order from the first node (cumsum: a fixed order, the compiled twin's)
        a = 0.5 * np.cumsum(cross, axis=1)[:, -1]
        with np.errstate(divide="ignore", invalid="ignore"):
            c = np.column_stack(
                [np.cumsum((xa + xb) * cross, axis=1)[:, -1], np.cumsum((ya + yb) * cross, axis=1)[:, -1]]
            ) / (6 * a[:, None])
        c += o[:, 0, :]
        if sel is None:
            return a, c
        area[sel] = a
        cen[sel] = c
    return area, cen


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (n, 3) arrays (column by column: several times numpy.cross's speed)."""
    u0, u1, u2 = u[:, 0], u[:, 1], u[:, 2]
    v0, v1, v2 = v[:, 0], v[:, 1], v[:, 2]
    out = np.empty(u.shape, dtype=np.result_type(u, v))
    np.subtract(u1 * v2, u2 * v1, out=out[:, 0])
    np.subtract(u2 * v0, u0 * v2, out=out[:, 1])
    np.subtract(u0 * v1, u1 * v0, out=out[:, 2])
    return out


def _all_tetrahedra(mesh: Mesh) -> bool:
    n = mesh.n_cells
    return (
        mesh.dim == 3
        and n > 0
        and mesh.connectivity.size == 4 * n
        and mesh.poly_cells is None
        and bool(np.all(mesh.cell_types == VTK_TETRA))
    )


def _dot3(ax, ay, az, bx, by, bz) -> np.ndarray:
    """Row-wise dot product of 3-vectors given by components, summed as (x + z) + y: the order in
    which numpy's einsum("ij,ij->i") sums rows of three (what these functions used before they
    went column-wise), kept so that no measure changes by a bit."""
    out = ax * bx
    out += az * bz
    out += ay * by
    return out


def _cross3(ux, uy, uz, vx, vy, vz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u x v by components (the same products and differences as _cross)."""
    return uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx


def _tetra_measures(mesh: Mesh, face_areas: bool = False):
    """Signed volume and centroid of every cell of an all-tetrahedra mesh, in closed form: the same
    values as the face-based formula (a tetrahedron with outward faces (0,2,1), (0,1,3), (1,2,3),
    (0,3,2) has volume det(p1 - p0, p2 - p0, p3 - p0) / 6 and its vertex mean as centroid).

    face_areas: also return face areas from the same gathered corners, bit for bit what
    face_measures gives for these faces: ((C, 4) the faces of FACE_TEMPLATES[VTK_TETRA] in the
    current node order, (C,) face 2 as it is after the cell is mirrored); see tetra_face_areas.
    Coordinates are gathered per component (contiguous columns: every operation below is a plain
    elementwise pass over a chunk that stays in cache)."""
    t = mesh.connectivity.reshape(-1, 4)
    n = t.shape[0]
    vol, cen = np.empty(n), np.empty((n, 3))
    areas = np.empty((n, 4)) if face_areas else None  # already the layout of face ids 4 * cell + j
    mirrored = np.empty(n) if face_areas else None
    xyz = [np.ascontiguousarray(mesh.points[:, d]) for d in range(3)]
    chunk = 1 << 14  # temporaries stay in cache and are reused (elementwise: the same values)
    for s in range(0, n, chunk):
        tc = t[s : s + chunk]
        ids = [tc[:, j] for j in range(4)]
        p = [[np.take(x, i) for x in xyz] for i in ids]  # p[corner][component]
        a = [p[1][d] - p[0][d] for d in range(3)]
        b = [p[2][d] - p[0][d] for d in range(3)]
        c = [p[3][d] - p[0][d] for d in range(3)]
        v = _dot3(*a, *_cross3(*b, *c))
        v /= 6.0
        vol[s : s + chunk] = v
        for d in range(3):
            cen[s : s + chunk, d] = p[0][d] + (a[d] + b[d] + c[d]) / 4.0
        if face_areas:
            # face (i, j, k) has area |(pj - pi) x (pk - pi)| / 2, as _triangle_areas computes it
            e = [p[2][d] - p[1][d] for d in range(3)]
            crosses = (
                _cross3(*b, *a),  # (0, 2, 1)
                _cross3(*a, *c),  # (0, 1, 3)
                _cross3(*e, *[p[3][d] - p[1][d] for d in range(3)]),  # (1, 2, 3)
                _cross3(*c, *b),  # (0, 3, 2)
                # mirrored (2, 1, 3): (p1 - p2) x (p3 - p2) = -e x (p3 - p2), the same norm
                _cross3(*e, *[p[3][d] - p[2][d] for d in range(3)]),
            )
            for k, cr in enumerate(crosses):
                np.sqrt(_dot3(*cr, *cr), out=areas[s : s + chunk, k] if k < 4 else mirrored[s : s + chunk])
    if face_areas:
        areas *= 0.5
        mirrored *= 0.5
        return vol, cen, (areas, mirrored)
    return vol, cen


def tetra_face_areas(areas: tuple[np.ndarray, np.ndarray], flip: np.ndarray) -> np.ndarray:
    """(4 C,) the area of every face (face id 4 * cell + local face) of an all-tetrahedra mesh from
    _tetra_measures' areas, after the cells in `flip` were mirrored (nodes 1 and 2 swapped); made
    in the (C, 4) array of those areas (overwritten). A mirrored cell's faces (0,2,1), (0,1,3),
    (1,2,3), (0,3,2) are its old faces 0, 3, 2 and 1 with their nodes in another order: faces 0, 1
    and 3 keep their first node (the cross product only changes sign), face 2 starts at another
    node (the mirrored face 2's area)."""
    out, mirrored = areas
    if flip.any():
        old1 = out[:, 1].copy()
        np.copyto(out[:, 1], out[:, 3], where=flip)
        np.copyto(out[:, 3], old1, where=flip)
        np.copyto(out[:, 2], mirrored, where=flip)
    return out.reshape(-1)


def _measures_and_centroids(mesh: Mesh, faces: Faces | None = None) -> tuple[np.ndarray, np.ndarray]:
    n = mesh.n_cells
    if mesh.dim == 2:
        return _polygon_measures(mesh.points, mesh.offsets, mesh.connectivity)
    if _all_tetrahedra(mesh):
        return _tetra_measures(mesh)
    fixed = _fixed_measures(mesh)
    if fixed is not None:
        return fixed
    poly = _poly_measures(mesh)
    if poly is not None:
        return poly
    faces = faces or cell_faces(mesh)
    owner, a, b, c = face_triangles(mesh.points, faces.offsets, faces.nodes)
    cell = faces.cell[owner]
    o = vertex_means(mesh)
    a, b, c = a - o[cell], b - o[cell], c - o[cell]
    v = np.einsum("ij,ij->i", a, _cross(b, c))  # six times each triangle's volume: one division per cell
    vol6 = np.bincount(cell, weights=v, minlength=n)
    g = (a + b + c) / 4.0
    with np.errstate(divide="ignore", invalid="ignore"):
        cen = (
            np.column_stack([np.bincount(cell, weights=v * g[:, d], minlength=n) for d in range(3)])
            / vol6[:, None]
        )
    return vol6 / 6.0, cen + o


def _poly_measures(mesh: Mesh) -> tuple[np.ndarray, np.ndarray] | None:
    """_measures_and_centroids of a mesh of polyhedra only (their faces stored: VTK type 42, prisms
    of 5 and 6 sides), by poly_measures in models/mesh/_fastpoly.c (the same values bit for bit);
    None for other meshes or where it was not built."""
    from models.native import compiled

    n = mesh.n_cells
    if mesh.poly_cells is None or mesh.poly_cells.size != n or not n:
        return None
    if not np.array_equal(mesh.poly_cells, np.arange(n)):
        return None
    fast = compiled("mesh._fastmesh")
    if fast is None:
        return None
    vol, cen = np.empty(n), np.empty((n, 3))
    ok = fast.poly_measures(
        np.ascontiguousarray(mesh.points, dtype=np.float64),
        np.ascontiguousarray(mesh.offsets, dtype=np.int64),
        np.ascontiguousarray(mesh.connectivity, dtype=np.int64),
        np.ascontiguousarray(mesh.poly_cell_faces, dtype=np.int64),
        np.ascontiguousarray(mesh.poly_face_offsets, dtype=np.int64),
        np.ascontiguousarray(mesh.poly_face_nodes, dtype=np.int64),
        vol,
        cen,
    )
    return None if ok < 0 else (vol, cen)


def signed_measures(mesh: Mesh) -> np.ndarray:
    """(C,) signed area (2D) or volume (3D); positive for positively oriented cells."""
    return _measures_and_centroids(mesh)[0]


def cell_measures(mesh: Mesh) -> np.ndarray:
    """(C,) area or volume of each cell."""
    return np.abs(_measures_and_centroids(mesh)[0])


def cell_centroids(mesh: Mesh) -> np.ndarray:
    """(C, dim) barycentre of each cell (area/volume weighted, not the vertex mean)."""
    return _measures_and_centroids(mesh)[1]


def measures_and_centroids(mesh: Mesh, faces: Faces | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Both at once (one pass; reuses what reading the mesh already computed)."""
    if "measures" in mesh.meta and "centroids" in mesh.meta:
        return mesh.meta["measures"], mesh.meta["centroids"]
    m, c = _measures_and_centroids(mesh, faces)
    return np.abs(m), c


def cell_diameters(mesh: Mesh) -> np.ndarray:
    """(C,) largest distance between two nodes of each cell (loop over distinct cell sizes only)."""
    sizes = np.diff(mesh.offsets)
    out = np.zeros(mesh.n_cells)
    for s in np.unique(sizes):
        sel = np.flatnonzero(sizes == s)
        x = mesh.points[mesh.connectivity[mesh.offsets[sel][:, None] + np.arange(s)[None, :]]]
        best = np.zeros(sel.size)
        for i in range(s - 1):  # s is the number of nodes per cell (small)
            d = np.linalg.norm(x[:, i + 1 :, :] - x[:, i : i + 1, :], axis=2).max(axis=1)
            best = np.maximum(best, d)
        out[sel] = best
    return out


def face_measures(points: np.ndarray, faces: Faces, which: np.ndarray | None = None) -> np.ndarray:
    """Length of each edge (2D) or area of each face (3D); only faces `which` when given."""
    if points.shape[1] == 2:  # in chunks: the temporaries stay in cache (elementwise, the same values)
        e = faces.nodes.reshape(-1, 2)
        m = e.shape[0] if which is None else which.size
        out = np.empty(m)
        x, y = np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1])
        chunk = 1 << 16
        for s in range(0, m, chunk):
            ec = e[s : s + chunk] if which is None else e[which[s : s + chunk]]
            a, b = ec[:, 0], ec[:, 1]
            np.hypot(np.take(x, b) - np.take(x, a), np.take(y, b) - np.take(y, a), out=out[s : s + chunk])
        return out
    p = points
    if faces.nodes.size == 3 * faces.n:  # all triangles: no fan, no sum per face, rows by gathers
        return _triangle_areas(p, faces.nodes.reshape(-1, 3), which)
    offsets, nodes = (
        (faces.offsets, faces.nodes) if which is None else reorder_csr(faces.offsets, faces.nodes, which)
    )
    if nodes.size == 3 * (offsets.size - 1):
        return _triangle_areas(p, nodes.reshape(-1, 3), None)
    owner, tri = fan_triangles(offsets, nodes)
    cr = _cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]])
    return 0.5 * np.bincount(
        owner, weights=np.sqrt(np.einsum("ij,ij->i", cr, cr)), minlength=offsets.size - 1
    )


def _triangle_areas(
    p: np.ndarray, tri: np.ndarray, which: np.ndarray | None, chunk: int = 1 << 16
) -> np.ndarray:
    """Area of the triangles tri[which] (all rows when which is None), in chunks: the temporaries
    of a chunk stay in cache and their memory is reused (one pass over millions of faces otherwise
    spends most of its time faulting in fresh temporaries). Elementwise, so chunking changes no bit."""
    m = tri.shape[0] if which is None else which.size
    out = np.empty(m)
    xyz = [np.ascontiguousarray(p[:, d]) for d in range(3)]
    for s in range(0, m, chunk):
        t = tri[s : s + chunk] if which is None else tri[which[s : s + chunk]]
        q = [[np.take(x, t[:, j]) for x in xyz] for j in range(3)]  # q[corner][component]
        cr = _cross3(*[q[1][d] - q[0][d] for d in range(3)], *[q[2][d] - q[0][d] for d in range(3)])
        np.sqrt(_dot3(*cr, *cr), out=out[s : s + chunk])
    out *= 0.5
    return out


def mesh_diameter(points: np.ndarray) -> float:
    """Largest distance between two points (exact, via the convex hull)."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.asarray(points)
    if len(pts) <= 1:
        return 0.0
    try:
        hv = pts[ConvexHull(pts).vertices] if len(pts) > points.shape[1] else pts
    except (QhullError, ValueError):
        hv = pts
    if len(hv) > 4000:  # hull of a huge round domain: subsample pairs block by block
        best = 0.0
        for i in range(0, len(hv), 2000):
            d = np.linalg.norm(hv[i : i + 2000, None, :] - hv[None, :, :], axis=2)
            best = max(best, float(d.max()))
        return best
    return float(np.linalg.norm(hv[:, None, :] - hv[None, :, :], axis=2).max())

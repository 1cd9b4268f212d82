"""Every VTK cell type with an area or a volume, turned into the cells we agglomerate, on arrays.

A reader hands over its cells as VTK does (CSR offsets / connectivity, one VTK type id per cell,
polyhedron faces apart) and `normalize` returns our element and boundary CSR arrays:
- linear cells as they are; pixel (8) and voxel (11) reordered to quad / hexahedron node order;
  triangle strips (6) expanded into triangles; polygons of 3 or 4 nodes become triangles / quads;
- pentagonal (15) and hexagonal (16) prisms become polyhedra (their 7 / 8 faces);
- every quadratic, biquadratic, triquadratic (21-37), Lagrange (68-74) and Bezier (75-81) cell is
  kept on its corner nodes (VTK lists the corners first), with one line saying so;
- cells of the top dimension are the elements, those one dimension lower the boundary cells, the
  rest counted (reported, never silently dropped).
No Python loop over cells: lookup tables indexed by the type array, and CSR gathers.
"""

from __future__ import annotations

import numpy as np

from models.errors import MeshError, ParameterError
from models.mesh.container import (
    VTK_HEXAHEDRON,
    VTK_LINE,
    VTK_POLYGON,
    VTK_POLYHEDRON,
    VTK_PYRAMID,
    VTK_QUAD,
    VTK_TETRA,
    VTK_TRIANGLE,
    VTK_VERTEX,
    VTK_WEDGE,
)

TAG_NAMES = (
    "gmsh:physical",
    "CellEntityIds",
    "cell_tags",
    "facet_tags",  # dolfinx's XDMF: the tags of its facets (a grid of their own)
    "medit:ref",
    "physical",
    "material",
    "tag",
    "physical_group",
    "avsucd:material",
    "ObjectId",
    "material_id",
    "MaterialIds",
    "block",  # element block / zone of a composite VTK output (vtk_readers)
    "group",  # the groups read._named_groups makes of Abaqus sets, MED families, SU2 markers
    "nastran:ref",  # Nastran's property id of each element (PSOLID / PSHELL: its material)
)
BOUNDARY_TAG_NAME = "boundary_tag"  # boundary groups of lower-dimensional cells, as models.vtu writes them


def find_tag_key(cell_data: dict, physical_tag: str | None) -> str | None:
    """The cell-data name holding the physical groups: physical_tag (ParameterError where the mesh
    has none of that name), else the first of TAG_NAMES the mesh has, else None."""
    if physical_tag is not None:
        if physical_tag not in cell_data:
            raise ParameterError(
                f"physical tag {physical_tag!r} not found in the mesh cell data; available: {', '.join(sorted(cell_data)) or 'none'}"
            )
        return physical_tag
    return next((k for k in TAG_NAMES if k in cell_data), None)


VTK_POLY_VERTEX = 2
VTK_POLY_LINE = 4
VTK_TRIANGLE_STRIP = 6
VTK_PIXEL = 8
VTK_VOXEL = 11
VTK_PENTAGONAL_PRISM = 15
VTK_HEXAGONAL_PRISM = 16
VTK_QUADRATIC_POLYGON = 36

# type id -> (name, dimension, base linear type, corner nodes kept; 0: all, -2: the first half)
_INFO: dict[int, tuple[str, int, int, int]] = {
    1: ("vertex", 0, VTK_VERTEX, 1),
    2: ("poly-vertex", 0, VTK_VERTEX, 0),
    3: ("line", 1, VTK_LINE, 2),
    4: ("poly-line", 1, VTK_LINE, 0),
    5: ("triangle", 2, VTK_TRIANGLE, 3),
    6: ("triangle strip", 2, VTK_TRIANGLE, 0),
    7: ("polygon", 2, VTK_POLYGON, 0),
    8: ("pixel", 2, VTK_QUAD, 4),
    9: ("quad", 2, VTK_QUAD, 4),
    10: ("tetra", 3, VTK_TETRA, 4),
    11: ("voxel", 3, VTK_HEXAHEDRON, 8),
    12: ("hexahedron", 3, VTK_HEXAHEDRON, 8),
    13: ("wedge", 3, VTK_WEDGE, 6),
    14: ("pyramid", 3, VTK_PYRAMID, 5),
    15: ("pentagonal prism", 3, VTK_POLYHEDRON, 10),
    16: ("hexagonal prism", 3, VTK_POLYHEDRON, 12),
    21: ("quadratic edge", 1, VTK_LINE, 2),
    22: ("quadratic triangle", 2, VTK_TRIANGLE, 3),
    23: ("quadratic quad", 2, VTK_QUAD, 4),
    24: ("quadratic tetra", 3, VTK_TETRA, 4),
    25: ("quadratic hexahedron", 3, VTK_HEXAHEDRON, 8),
    26: ("quadratic wedge", 3, VTK_WEDGE, 6),
    27: ("quadratic pyramid", 3, VTK_PYRAMID, 5),
    28: ("biquadratic quad", 2, VTK_QUAD, 4),
    29: ("triquadratic hexahedron", 3, VTK_HEXAHEDRON, 8),
    30: ("quadratic linear quad", 2, VTK_QUAD, 4),
    31: ("quadratic linear wedge", 3, VTK_WEDGE, 6),
    32: ("biquadratic quadratic wedge", 3, VTK_WEDGE, 6),
    33: ("biquadratic quadratic hexahedron", 3, VTK_HEXAHEDRON, 8),
    34: ("biquadratic triangle", 2, VTK_TRIANGLE, 3),
    35: ("cubic line", 1, VTK_LINE, 2),
    36: ("quadratic polygon", 2, VTK_POLYGON, -2),
    37: ("triquadratic pyramid", 3, VTK_PYRAMID, 5),
    42: ("polyhedron", 3, VTK_POLYHEDRON, 0),
    68: ("Lagrange curve", 1, VTK_LINE, 2),
    69: ("Lagrange triangle", 2, VTK_TRIANGLE, 3),
    70: ("Lagrange quadrilateral", 2, VTK_QUAD, 4),
    71: ("Lagrange tetrahedron", 3, VTK_TETRA, 4),
    72: ("Lagrange hexahedron", 3, VTK_HEXAHEDRON, 8),
    73: ("Lagrange wedge", 3, VTK_WEDGE, 6),
    74: ("Lagrange pyramid", 3, VTK_PYRAMID, 5),
    75: ("Bezier curve", 1, VTK_LINE, 2),
    76: ("Bezier triangle", 2, VTK_TRIANGLE, 3),
    77: ("Bezier quadrilateral", 2, VTK_QUAD, 4),
    78: ("Bezier tetrahedron", 3, VTK_TETRA, 4),
    79: ("Bezier hexahedron", 3, VTK_HEXAHEDRON, 8),
    80: ("Bezier wedge", 3, VTK_WEDGE, 6),
    81: ("Bezier pyramid", 3, VTK_PYRAMID, 5),
}
_KNOWN_OTHER = {0: "empty cell", 41: "convex point set", 51: "parametric cell", 60: "higher-order cell"}
# VTK_EMPTY_CELL (no points): counted with the lower-dimensional cells, left out with a notice (VTK's
# writers leave one where a filter removed a cell); convex point sets come as polyhedra
# (models/mesh/convex_sets.py)
DIM = np.full(256, -1, np.int8)
BASE = np.zeros(256, np.uint8)
KEEP = np.zeros(256, np.int64)
for _t, (_n, _d, _b, _k) in _INFO.items():
    DIM[_t], BASE[_t], KEEP[_t] = _d, _b, _k
DIM[0] = 0
HIGHER = np.zeros(256, bool)
HIGHER[[t for t in _INFO if t >= 21 and t != 42]] = True
LINEAR_SIZE = {VTK_TRIANGLE: 3, VTK_QUAD: 4, VTK_TETRA: 4, VTK_HEXAHEDRON: 8, VTK_WEDGE: 6, VTK_PYRAMID: 5}
_REORDER = {VTK_PIXEL: np.array([0, 1, 3, 2]), VTK_VOXEL: np.array([0, 1, 3, 2, 4, 5, 7, 6])}


def type_name(t: int) -> str:
    t = int(t)
    return _INFO[t][0] if t in _INFO else _KNOWN_OTHER.get(t, f"VTK cell type {t}")


def ranges(starts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Concatenated aranges [starts[i], starts[i] + sizes[i]) (a CSR gather index, no loop)."""
    total = int(sizes.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    out = np.ones(total, np.int64)
    keep = sizes > 0
    st, sz = starts[keep].astype(np.int64), sizes[keep].astype(np.int64)
    first = np.zeros(st.size, np.int64)
    np.cumsum(sz[:-1], out=first[1:])
    out[first] = st
    out[first[1:]] -= st[:-1] + sz[:-1] - 1
    return np.cumsum(out)


def with_boundary_faces(offsets, conn, types, block, sizes, conn_b, types_b, tags_b):
    """A reader's elements with boundary faces it found beside them appended as cells of their own
    (offsets, conn, types) and the cell data that tells them apart: "block" (the elements' groups,
    or 0s where block is None; 0 for the faces) and BOUNDARY_TAG_NAME (0 for the elements, tags_b
    for the faces), as normalize takes them (CGNS boundary conditions, Gambit's)."""
    n = len(types)
    offsets = np.asarray(offsets, np.int64)
    zeros = np.zeros(len(sizes), np.int64)
    return (
        np.concatenate([offsets, offsets[-1] + np.cumsum(sizes)]),
        np.concatenate([np.asarray(conn, np.int64), np.asarray(conn_b, np.int64)]),
        np.concatenate([np.asarray(types, np.uint8), np.asarray(types_b, np.uint8)]),
        {
            "block": np.concatenate(
                [np.zeros(n, np.int64) if block is None else np.asarray(block, np.int64), zeros]
            ),
            BOUNDARY_TAG_NAME: np.concatenate([np.zeros(n, np.int64), np.asarray(tags_b, np.int64)]),
        },
    )


def _offsets(sizes: np.ndarray) -> np.ndarray:
    off = np.zeros(sizes.size + 1, np.int64)
    np.cumsum(sizes, out=off[1:])
    return off


def expand_strips(offsets, conn, sel):
    """Triangles of the triangle strips `sel` (cell ids): (n, 3) nodes, and the strip of each."""
    sizes = (offsets[sel + 1] - offsets[sel]).astype(np.int64)
    ntri = np.maximum(sizes - 2, 0)
    strip = np.repeat(sel, ntri)
    j = ranges(np.zeros(sel.size, np.int64), ntri)
    base = offsets[strip] + j
    odd = (j & 1).astype(bool)
    tri = np.stack([conn[base], conn[base + 1], conn[base + 2]], axis=1).astype(np.int64)
    tri[odd, 0], tri[odd, 1] = tri[odd, 1], tri[odd, 0].copy()
    return tri, strip


def prism_faces(nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Faces of n-gonal prisms (rows: bottom n-gon, then top), outward for a positive prism:
    (faces per cell, face sizes, face nodes)."""
    c, m = nodes.shape
    n = m // 2
    i = np.arange(n)
    bottom = nodes[:, i[::-1]]
    top = nodes[:, n + i]
    sides = np.stack([nodes[:, i], nodes[:, (i + 1) % n], nodes[:, n + (i + 1) % n], nodes[:, n + i]], axis=2)
    per = np.concatenate([bottom, top, sides.reshape(c, 4 * n)], axis=1)
    fsizes = np.tile(np.r_[n, n, np.full(n, 4)], c).astype(np.int64)
    return np.full(c, n + 2, np.int64), fsizes, per.reshape(-1).astype(np.int64)


def distinct_nodes(nfaces: np.ndarray, fsizes: np.ndarray, fnodes: np.ndarray):
    """Per polyhedron, its distinct nodes ascending: (sizes, nodes) (compiled: poly_distinct in
    models/mesh/_fastpoly.c, the same arrays)."""
    from models.native import compiled

    fast = compiled("mesh._fastmesh")
    if fast is not None and nfaces.size:
        cface = _offsets(np.asarray(nfaces, np.int64))
        foff = _offsets(np.asarray(fsizes, np.int64))
        nodes = np.ascontiguousarray(fnodes, dtype=np.int64)
        sizes, out = np.empty(nfaces.size, np.int64), np.empty(nodes.size, np.int64)
        n = fast.poly_distinct(cface, foff, nodes, sizes, out)
        if n >= 0:
            return sizes, out[:n].copy()
    owner = np.repeat(np.repeat(np.arange(nfaces.size), nfaces), fsizes)
    order = np.lexsort((fnodes, owner))
    so, sn = owner[order], fnodes[order]
    first = np.ones(sn.size, dtype=bool)
    first[1:] = (so[1:] != so[:-1]) | (sn[1:] != sn[:-1])
    return np.bincount(so[first], minlength=nfaces.size).astype(np.int64), sn[first]


class Normalized:
    """Our cells from a VTK cell set: elements (offsets, connectivity, types, tags), polyhedron faces
    [(cell ids, faces per cell, face sizes, face nodes)], boundary cells, lower cells counted, notes."""

    def __init__(self):
        self.dim = 0
        self.offsets = self.connectivity = self.types = self.tags = None
        self.poly_faces: list = []
        self.bnd = None  # (offsets, connectivity, types, tags or None)
        self.lower: dict[str, int] = {}
        self.notes: list[str] = []
        self.unused_higher = 0
        self.overlong = None  # linear cells listing more nodes than their kind has ({"count", "message"})


def _corner_csr(offsets, conn, types, sel):
    """CSR of the corner nodes of cells `sel` (all nodes where the type keeps all)."""
    t = types[sel]
    sizes = (offsets[sel + 1] - offsets[sel]).astype(np.int64)
    keep = KEEP[t]
    new = np.where(keep > 0, keep, np.where(keep == -2, sizes // 2, sizes))
    if np.any(sizes < 0):  # (offsets that go back: a corrupted number among them)
        bad = int(np.flatnonzero(sizes < 0)[0])
        raise MeshError(
            f"the cells' offsets go back at cell {int(sel[bad])}: its node list would end before it starts"
        )
    if np.any(new > sizes):
        bad = int(np.flatnonzero(new > sizes)[0])
        raise MeshError(
            f"a {type_name(t[bad])} cell (cell {int(sel[bad])}) has {int(sizes[bad])} nodes, fewer than its {int(new[bad])} corners"
        )
    if sel.size and np.array_equal(new, sizes) and _contiguous(offsets, sel):  # every node kept, in a row
        s, e = int(offsets[sel[0]]), int(offsets[sel[-1] + 1])
        c = np.asarray(conn[s:e], dtype=np.int64)
        if new.min() == new.max():
            w = int(new[0])
            return np.arange(0, sel.size * w + 1, w, dtype=np.int64), c
        return np.asarray(offsets[sel[0] : sel[-1] + 2], dtype=np.int64) - s, c
    rows = _rows(offsets, conn, sel, sizes, new)
    if rows is not None:  # higher-order cells of one kind: their first corners, one slice
        w = int(new[0])
        return np.arange(0, sel.size * w + 1, w, dtype=np.int64), rows[:, :w].astype(np.int64).reshape(-1)
    return _offsets(new), np.asarray(conn[ranges(offsets[sel], new)], dtype=np.int64)


def _contiguous(offsets, sel) -> bool:
    return bool(sel.size) and int(sel[-1]) - int(sel[0]) + 1 == sel.size


def _reorder(off, conn, types):
    for t, perm in _REORDER.items():
        sel = np.flatnonzero(types == t)
        if sel.size:
            rows = off[sel][:, None] + np.arange(perm.size)[None, :]
            conn[rows] = conn[rows[:, perm]]


def normalize(
    offsets, conn, types, tags=None, bnd_tags=None, poly=None, n_points: int | None = None
) -> Normalized:
    """VTK cells (offsets (C+1,), conn, types (C,) uint8, tags (C,) or None) -> `Normalized`.
    poly: VTK polyhedra faces (face offsets per polyhedron cell (Q+1,), face offsets (F+1,), face
    nodes), the polyhedra (type 42) in cell order; bnd_tags: tags for the boundary cells instead."""
    out = Normalized()
    types = np.asarray(types, dtype=np.uint8)
    offsets = np.asarray(offsets, dtype=np.int64)
    dims = DIM[types]
    if np.any(dims < 0):
        bad = types[dims < 0]
        found = ", ".join(sorted({type_name(t) for t in np.unique(bad)}))
        what = "a cell" if bad.size == 1 else f"{bad.size:,} cells"
        raise MeshError(f"the mesh has {what} of a kind without an area or a volume ({found})")
    if types.size == 0:
        raise MeshError("the mesh has no cells")
    dim = int(dims.max())
    out.dim = dim
    if dim < 2:
        kinds = ", ".join(sorted({type_name(t) for t in np.unique(types)}))
        what = "points alone" if dim == 0 else "1D meshes"  # (vertices only: no lines to speak of)
        raise MeshError(
            f"the file holds only {types.size:,} {kinds} cells (no area or volume): {what} are not "
            "supported; give a planar (2D) or a volume (3D) mesh"
        )
    # every lower-dimensional cell is reported (not agglomerated; faces of the elements become boundary groups)
    for t, cnt in zip(*np.unique(types[dims < dim], return_counts=True), strict=True):
        out.lower[type_name(t)] = out.lower.get(type_name(t), 0) + int(cnt)
    elem = np.flatnonzero(dims == dim)
    higher = HIGHER[types[elem]]
    if higher.any() and n_points is not None:
        out.unused_higher = _unused_higher(offsets, conn, types, elem, n_points)
        names = sorted({type_name(t) for t in np.unique(types[elem[higher]])})
        corners = "/".join(str(k) for k in sorted({int(KEEP[t]) for t in np.unique(types[elem[higher]])}))
        quadratic = all(t < 68 for t in np.unique(types[elem[higher]]))
        out.notes.append(higher_order_line(quadratic, names, corners, out.unused_higher))
    out.overlong = _overlong(offsets, types, elem)
    out.offsets, out.connectivity, out.types, out.tags = _elements(
        out, offsets, conn, types, elem, tags, poly
    )
    if dim >= 2:
        # a poly-line of two points is an edge (dolfinx's XDMF writes a 2D mesh's facets so)
        edge = (types == VTK_POLY_LINE) & (np.diff(offsets) == 2) if dim == 2 else None
        btypes = (
            types if edge is None or not edge.any() else np.where(edge, VTK_LINE, types).astype(types.dtype)
        )
        bsel = np.flatnonzero((dims == dim - 1) & (btypes != VTK_POLY_LINE) & (btypes != VTK_POLY_VERTEX))
        if bsel.size:
            bo, bc, bt, _ = _elements(None, offsets, conn, btypes, bsel, None, None)
            btags = None
            src = bnd_tags if bnd_tags is not None else tags
            if src is not None:
                btags = _strip_tags(types, offsets, bsel, np.asarray(src)[bsel])
            out.bnd = (bo, bc, bt, btags)
    return out


def _strip_tags(types, offsets, sel, tags):
    strips = types[sel] == VTK_TRIANGLE_STRIP
    if not strips.any():
        return tags
    sizes = offsets[sel + 1] - offsets[sel]
    rep = np.where(strips, np.maximum(sizes - 2, 0), 1)
    return np.concatenate([tags[~strips], np.repeat(tags[strips], rep[strips])])


def _elements(out, offsets, conn, types, sel, tags, poly):
    """Our CSR of cells `sel`: strips expanded (their triangles last), corners kept, prisms and
    polyhedra as polyhedra with their faces recorded in out.poly_faces."""
    t = types[sel]
    strips = t == VTK_TRIANGLE_STRIP
    tri = None
    if strips.any():
        tri, owner = expand_strips(offsets, conn, sel[strips])
        tri_tags = None if tags is None else np.asarray(tags)[owner]
        sel, t = sel[~strips], t[~strips]
    off, c = (
        _corner_csr(offsets, conn, types, sel) if sel.size else (np.zeros(1, np.int64), np.zeros(0, np.int64))
    )
    if c.base is not None and not c.flags.writeable:
        c = c.copy()
    _reorder(off, c, t)
    new_t = BASE[t]
    sizes = np.diff(off)
    poly_t = new_t == VTK_POLYGON
    if poly_t.any():
        new_t = np.where(
            poly_t & (sizes == 3), VTK_TRIANGLE, np.where(poly_t & (sizes == 4), VTK_QUAD, new_t)
        ).astype(np.uint8)
    cell_tags = None if tags is None else np.asarray(tags)[sel]
    polyh = new_t == VTK_POLYHEDRON
    if polyh.any():
        if out is None:
            raise MeshError("the mesh has polyhedra among its boundary cells")
        off, c = _polyhedra(out, off, c, t, polyh, types, sel, poly)
    if tri is not None:
        off = np.concatenate([off, off[-1] + np.arange(3, 3 * len(tri) + 1, 3)])
        c = np.concatenate([c, tri.reshape(-1)])
        new_t = np.concatenate([new_t, np.full(len(tri), VTK_TRIANGLE, np.uint8)])
        if cell_tags is not None:
            cell_tags = np.concatenate([cell_tags, tri_tags])
    return off, c, new_t.astype(np.uint8), cell_tags


def _polyhedra(out, off, c, t, polyh, types, sel, poly):
    """Faces of the prisms and VTK polyhedra among cells (our order), and their cells' distinct nodes."""
    ids = np.flatnonzero(polyh)
    sizes = np.diff(off)
    pieces = []  # per kind: (positions in ids, faces per cell, face sizes, face nodes, nodes per cell)
    for kind in (VTK_PENTAGONAL_PRISM, VTK_HEXAGONAL_PRISM, VTK_POLYHEDRON):
        k = np.flatnonzero(t[ids] == kind)
        if not k.size:
            continue
        cells = ids[k]
        if kind == VTK_POLYHEDRON:
            if poly is None:
                raise MeshError("the file has polyhedron cells without their faces")
            cell_face_off, face_off, face_nodes = (np.asarray(a, dtype=np.int64) for a in poly)
            rank = np.cumsum(types == VTK_POLYHEDRON) - 1  # rank of each type-42 cell of the file
            q = rank[sel[cells]]
            if q.size and cell_face_off.size < int(q.max()) + 2:
                raise MeshError("the file has fewer polyhedron face lists than polyhedron cells")
            fcount = cell_face_off[q + 1] - cell_face_off[q]
            fids = ranges(cell_face_off[q], fcount)
            if fids.size and int(fids.max()) + 1 >= face_off.size:
                raise MeshError("a polyhedron refers to a face that the file does not have")
            fsz = face_off[fids + 1] - face_off[fids]
            nodes = face_nodes[ranges(face_off[fids], fsz)]
        else:
            w = 10 if kind == VTK_PENTAGONAL_PRISM else 12
            rows = c[ranges(off[cells], np.full(cells.size, w))].reshape(-1, w)
            fcount, fsz, nodes = prism_faces(rows)
        if np.any(fcount < 4):
            raise MeshError("a polyhedron has fewer than 4 faces")
        pieces.append((k, fcount, fsz, nodes, np.add.reduceat(fsz, _offsets(fcount)[:-1])))
    # the faces in the order of `ids`
    pos = np.concatenate([p[0] for p in pieces])
    fcount = np.concatenate([p[1] for p in pieces])
    fsz_all = np.concatenate([p[2] for p in pieces])
    nodes_all = np.concatenate([p[3] for p in pieces])
    cell_nodes = np.concatenate([p[4] for p in pieces])
    order = np.argsort(pos, kind="stable")
    nfaces = fcount[order]
    face_sizes = fsz_all[ranges(_offsets(fcount)[:-1][order], nfaces)]
    face_nodes_all = nodes_all[ranges(_offsets(cell_nodes)[:-1][order], cell_nodes[order])]
    dsizes, dnodes = distinct_nodes(nfaces, face_sizes, face_nodes_all)
    # the element CSR again: polyhedra get their distinct nodes
    sizes = sizes.copy()
    sizes[ids] = dsizes
    new_off = _offsets(sizes)
    new_c = np.empty(int(new_off[-1]), np.int64)
    keep = np.flatnonzero(~polyh)
    new_c[ranges(new_off[keep], sizes[keep])] = c[ranges(off[keep], np.diff(off)[keep])]
    new_c[ranges(new_off[ids], dsizes)] = dnodes
    out.poly_faces.append((ids, nfaces, face_sizes, face_nodes_all))
    return new_off, new_c


def _overlong(offsets, types, elem) -> dict | None:
    """A line for linear cells that list more nodes than their kind has (a 9-node hexahedron, a file
    whose cell types and node counts disagree): VTK draws such a cell on its first nodes, and so do
    we: {"count", "message"}, or None when there are none."""
    t = types[elem]
    keep = KEEP[t]
    sizes = offsets[elem + 1] - offsets[elem]
    over = (keep > 0) & ~HIGHER[t] & (sizes > keep)
    if not over.any():
        return None
    i, n = int(np.flatnonzero(over)[0]), int(over.sum())
    return {
        "count": n,
        "message": f"{n:,} cell{'s' if n > 1 else ''} list{'' if n > 1 else 's'} more nodes than "
        f"{'their' if n > 1 else 'its'} kind has (cell {int(elem[i])}, a {type_name(t[i])}: "
        f"{int(sizes[i])} nodes): taken on the first {int(keep[i])}, as VTK draws it",
    }


def higher_order_line(quadratic: bool, names: list[str], corners: str, unused: int) -> str:
    """The one line a mesh of higher-order cells gets (every reader says it so)."""
    kind = "quadratic" if quadratic else "higher-order"
    return (
        f"{kind} cells ({', '.join(names)}): agglomerated on their {corners} corner nodes; "
        f"{unused:,} higher-order nodes unused"
    )


def _unused_higher(offsets, conn, types, elem, n_points: int) -> int:
    """Points used by the elements' higher-order (non-corner) nodes only."""
    t = types[elem]
    sizes = offsets[elem + 1] - offsets[elem]
    keep = KEEP[t]
    new = np.minimum(np.where(keep > 0, keep, np.where(keep == -2, sizes // 2, sizes)), sizes)
    used = np.zeros(n_points, bool)
    corner = np.zeros(n_points, bool)
    rows = _rows(offsets, conn, elem, sizes, new)
    if rows is not None:  # one cell size and corner count, the cells in a row (the usual file)
        used[rows] = True
        corner[rows[:, : int(new[0])]] = True
    else:
        used[np.asarray(conn[ranges(offsets[elem], sizes)], dtype=np.int64)] = True
        corner[np.asarray(conn[ranges(offsets[elem], new)], dtype=np.int64)] = True
    return int(np.count_nonzero(used & ~corner))


def _rows(offsets, conn, sel, sizes, new) -> np.ndarray | None:
    """The nodes of cells `sel` as rows (C, k) of `conn` (a view) when they all have k nodes and
    `new` corners, one after the other in `conn`; else None."""
    if not sel.size or sizes.min() != sizes.max() or new.min() != new.max() or not _contiguous(offsets, sel):
        return None
    k = int(sizes[0])
    s = int(offsets[sel[0]])
    return np.asarray(conn[s : s + k * sel.size]).reshape(sel.size, k)

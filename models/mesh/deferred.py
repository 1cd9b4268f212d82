"""A build left to the caller: the sandbox's reading child reads, the caller builds.

The reading child (models.mesh.sandbox) runs the part of a read that can crash or hang: VTK's C++
readers and our parsers, on the file's bytes. The Mesh itself is made by our builders
(build.mesh_from_cells, build.mesh_from_image), vectorized numpy and our own checks. So in the
child the builders do not build (DEFER): they hand back their arguments, a `Deferred`, and the
caller checks them and builds. The answer that crosses the memfd is then the reader's arrays, not
the Mesh with its orientation records, measures and centroids: about 30% fewer bytes for a
tetrahedral or hexahedral file, and for image data a few numbers instead of the whole lattice
(the caller makes its points and hexahedra from origin, spacing and extent); a whole structured
grid comes as its points and dimensions, its hexahedra made again by the caller (lattice.structured_cells).

The caller trusts nothing the child wrote (a child taken over by a reader exploit may lie):
`build.build_deferred` checks every invariant the builders rely on before any of them runs (dtypes and
shapes, CSR offsets from 0 to the end, each cell's node count against its type, polyhedra's faces,
boundary cells, plain metadata) and raises Inconsistent, which the caller words as a crashed
reader. The builders then check what they check for any reader, before anything indexes with an
id: point ids in range (refused in the words a bad file gets), then orientation, degenerate and
folded cells. So a lie that passes is a mesh our own checks accept.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from models.mesh.container import VTK_HEXAHEDRON, VTK_QUAD, VTK_TETRA, VTK_TRIANGLE
from models.mesh.invariants import csr_sizes, ids, in_range
from models.mesh.legacy import widen

# set in the reading child only (models.mesh.sandbox._read_in_child): builders return a Deferred
DEFER = False

_ALLOWED = {d: np.zeros(256, bool) for d in (2, 3)}  # element types by dimension
_ALLOWED[3][[10, 12, 13, 14, 15, 16, 42]] = True
_ALLOWED[2][[5, 7, 9]] = True
_POLYHEDRA = np.zeros(256, bool)
_POLYHEDRA[[15, 16, 42]] = True
# nodes per cell by type: exactly (> 0), or at least (< 0: -minimum)
_SIZE = np.zeros(256, np.int64)
for _t, _n in {5: 3, 9: 4, 7: -1, 10: 4, 12: 8, 13: 6, 14: 5, 15: 10, 16: 12, 42: -4}.items():
    _SIZE[_t] = _n
_BSIZE = np.zeros(256, np.int64)  # boundary cells: vertices, lines, triangles, quads, polygons
for _t, _n in {1: 1, 3: 2, 5: 3, 9: 4, 7: -3}.items():
    _BSIZE[_t] = _n
# bytes a built image Mesh takes per point and per cell (points; connectivity, offsets, types,
# measures, centroids, signed measures, flips): the caller refuses beyond the read's memory limit
_IMAGE_BYTES = (24, 8 * 8 + 8 + 1 + 8 + 24 + 8 + 1)


class Inconsistent(Exception):
    """The arguments the reading child handed back break an invariant the builders rely on."""


@dataclasses.dataclass
class Deferred:
    """A builder's arguments from the reading child. builder: "cells" (build.mesh_from_cells) or
    "image" (build.mesh_from_image); args: its positional arguments (for "cells" with a lattice
    hint, offsets, connectivity and types are None: the caller makes them); meta: what the reader
    adds to the Mesh's meta after the build (group names, the reader's name); dim: the Mesh's.
    build.build_deferred checks and builds it."""

    builder: str
    args: tuple
    meta: dict
    dim: int


def check(d: Deferred) -> None:
    """The shape of a Deferred from the child (its builder's arguments: cells_args, fixed_args,
    image_args)."""
    _need(type(d) is Deferred and type(d.builder) is str and type(d.args) is tuple and type(d.dim) is int)
    _need(d.builder in ("cells", "fixed", "image"))
    _plain(d.meta)


def cells(points, offsets, conn, cell_types, tags, tag_name, poly_faces, bnd, lower, dim, weld, meta, grid):
    """mesh_from_cells' arguments as a Deferred (in the reading child). A whole lattice whose
    hexahedra the builder takes from the grid hint goes without them (the caller makes them)."""
    if grid is not None and weld is None and not poly_faces:
        offsets = conn = cell_types = None
    args = (points, offsets, conn, cell_types, tags, tag_name, poly_faces, bnd, lower, dim, weld, meta, grid)
    return Deferred("cells", args, {}, int(dim))


FIXED_DIM = {VTK_TRIANGLE: 2, VTK_QUAD: 2, VTK_TETRA: 3, VTK_HEXAHEDRON: 3}  # fixed's types: their dimension


def fixed(points, cells, counted: bool, vtk_type: int, meta: dict):
    """A file of one cell type of fixed size (a FIXED_DIM type) as its reader found it
    (models/mesh/legacy.py's read_legacy_raw: the file's own arrays, big-endian ones included, no
    copy made here), as a Deferred: the caller checks them, widens them and builds (fixed_args)."""
    return Deferred("fixed", (points, cells, bool(counted), int(vtk_type)), dict(meta), FIXED_DIM[vtk_type])


def image(axes, tags, tag_name, meta):
    """mesh_from_image's arguments as a Deferred (in the reading child)."""
    return Deferred("image", (list(axes), tags, tag_name, meta), {}, 3)


# ---------------------------------------------------------------- the caller's checks


def _need(ok) -> None:
    if not ok:
        raise Inconsistent("inconsistent build arguments")


def _cells_fit(offsets, values, types: np.ndarray, table: np.ndarray) -> bool:
    """A CSR (offsets, values) of cells of `types`, each with the node count `table` gives its type.
    One type of fixed size (the common file): the offsets are 0, k, 2k, ... to len(values)."""
    _need(ids(offsets) and ids(values) and offsets.shape == (types.size + 1,))
    t = _one_type(types)
    if t is not None:
        k = int(table[t])
        if k > 0:
            return values.size == k * types.size and bool(
                (offsets == np.arange(0, k * types.size + 1, k, dtype=offsets.dtype)).all()
            )
    sizes = csr_sizes(offsets, values)
    _need(sizes is not None)
    return _sizes_fit(types, sizes, table)


def _one_type(types: np.ndarray) -> int | None:
    """The one type of every cell, or None (several types, or none)."""
    if types.size == 0:
        return None
    t = int(types[0])
    return t if bool((types == t).all()) else None


def _sizes_fit(types: np.ndarray, sizes: np.ndarray, table: np.ndarray) -> bool:
    want = table[types]
    if np.any(want == 0):
        return False
    return bool(np.all(np.where(want > 0, sizes == want, sizes >= -want)))


def _plain(x, depth: int = 0) -> None:
    """Metadata: str, numbers, bool, None, and dicts, lists and tuples of them (no arrays)."""
    _need(depth <= 8)
    if x is None or type(x) in (bool, int, float, str) or isinstance(x, (np.integer, np.floating, np.bool_)):
        return
    if type(x) is dict:
        for k, v in x.items():
            _need(k is None or type(k) in (bool, int, float, str))
            _plain(v, depth + 1)
        return
    _need(type(x) in (list, tuple))
    for v in x:
        _plain(v, depth + 1)


def cells_args(args: tuple, dim: int) -> tuple:
    """mesh_from_cells' arguments from the child, checked (Inconsistent); a lattice's hexahedra made here."""
    _need(len(args) == 13)
    points, offsets, conn, types, tags, tag_name, poly_faces, bnd, lower, d, weld, meta, grid = args
    _need(d == dim and dim in (2, 3))
    _need(isinstance(points, np.ndarray) and points.dtype == np.float64 and points.ndim == 2)
    _need(points.shape[1] in (1, 2, 3))
    n_points = points.shape[0]
    _need(
        weld is None
        or (isinstance(weld, (int, float, np.integer, np.floating)) and np.isfinite(weld) and weld >= 0)
    )
    _need(tag_name is None or type(tag_name) is str)
    _need(meta is None or type(meta) is dict)
    _plain(meta)
    _need(type(lower) is dict)
    _need(all(type(k) is str and isinstance(v, (int, np.integer)) and v >= 0 for k, v in lower.items()))
    if grid is not None:
        _need(type(grid) is dict and set(grid) == {"dims", "axes"} and dim == 3)
        dims = grid["dims"]
        _need(type(dims) is list and len(dims) == 3 and all(type(v) is int and v >= 2 for v in dims))
        _need(n_points == dims[0] * dims[1] * dims[2])
        axes = grid["axes"]
        if axes is not None:
            _need(type(axes) is list and len(axes) == 3)
            _need(
                all(
                    isinstance(a, np.ndarray) and a.dtype == np.float64 and a.shape == (v,)
                    for a, v in zip(axes, dims, strict=True)
                )
            )
        if weld is None and not poly_faces:  # the builder takes the hexahedra for the lattice's:
            # never the child's (deferred.cells leaves them out): made here
            _need(offsets is None and conn is None and types is None)
            from models.mesh.lattice import structured_cells

            offsets, conn, types = structured_cells(dims)  # (every axis live: hexahedra)
    _need(isinstance(types, np.ndarray) and types.dtype == np.uint8 and types.ndim == 1)
    n_cells = types.size
    _need(_cells_fit(offsets, conn, types, _SIZE))
    one = _one_type(types)  # (the common file: one pass instead of a lookup per cell, twice)
    _need(bool(_ALLOWED[dim][one]) if one is not None else bool(_ALLOWED[dim][types].all()))
    _need(tags is None or (ids(tags) and tags.shape == (n_cells,)))
    _need(type(poly_faces) is list)
    seen = []
    for piece in poly_faces:
        _need(type(piece) is tuple and len(piece) == 4)
        cells_of, nfaces, fsizes, fnodes = piece
        _need(ids(cells_of) and ids(nfaces) and ids(fsizes) and ids(fnodes))
        _need(in_range(cells_of, n_cells) and nfaces.shape == cells_of.shape)
        _need(nfaces.size == 0 or int(nfaces.min()) >= 4)
        _need(fsizes.size == int(nfaces.sum()) and (fsizes.size == 0 or int(fsizes.min()) >= 3))
        _need(fnodes.size == int(fsizes.sum()))  # (their point ids: the builder checks them)
        seen.append(cells_of)
    got = np.sort(np.concatenate(seen)) if seen else np.zeros(0, np.int64)
    if one is not None and not _POLYHEDRA[one]:
        _need(got.size == 0)  # no polyhedra: no polyhedron faces
    else:  # each polyhedron's faces once, only theirs
        _need(np.array_equal(got, np.flatnonzero(_POLYHEDRA[types])))
    if bnd is not None:
        _need(type(bnd) is tuple and len(bnd) == 4)
        b_off, b_conn, b_types, b_tags = bnd
        _need(isinstance(b_types, np.ndarray) and b_types.dtype == np.uint8 and b_types.ndim == 1)
        _need(_cells_fit(b_off, b_conn, b_types, _BSIZE))
        _need(b_tags is None or (ids(b_tags) and b_tags.shape == b_types.shape))
    return (points, offsets, conn, types, tags, tag_name, poly_faces, bnd, lower, dim, weld, meta, grid)


def fixed_args(args: tuple, dim: int) -> tuple:
    """mesh_from_cells' arguments for a Deferred "fixed" from the child, checked (Inconsistent):
    points (n, 3) floats, cells (C, k) integer ids or (C, k + 1) rows whose first column is k
    (counted), one type of k nodes of the Deferred's dimension; widened here to float64 and int64
    (as legacy.read_legacy_simple widens them in-process), the offsets and types made here."""
    _need(len(args) == 4)
    points, cells, counted, t = args
    _need(type(counted) is bool and type(t) is int and FIXED_DIM.get(t) == dim)
    k = int(_SIZE[t])
    _need(isinstance(points, np.ndarray) and points.dtype in (np.float32, np.float64))
    _need(points.ndim == 2 and points.shape[1] == 3)
    _need(ids(cells, 2) and cells.shape[1] == k + counted and cells.shape[0] >= 1)
    _need(not counted or bool((cells[:, 0] == k).all()))
    points, cells = widen(points, cells, counted)  # (as the reader does in-process)
    n = cells.shape[0]
    offsets = np.arange(0, n * k + 1, k, dtype=np.int64)
    types = np.full(n, t, np.uint8)
    return (points, offsets, cells.reshape(-1), types, None, None, [], None, {}, dim, None, None, None)


def image_bytes(n_points: int, n_cells: int) -> int:
    """The bytes a built image Mesh of n_points and n_cells takes (_IMAGE_BYTES)."""
    return n_points * _IMAGE_BYTES[0] + n_cells * _IMAGE_BYTES[1]


def image_args(args: tuple, memory_bytes: int | None) -> tuple:
    """mesh_from_image's arguments from the child, checked (Inconsistent); MemoryError for an image
    beyond memory_bytes."""
    _need(len(args) == 4)
    axes, tags, tag_name, meta = args
    _need(type(axes) is list and len(axes) == 3)
    _need(
        all(isinstance(a, np.ndarray) and a.dtype == np.float64 and a.ndim == 1 and a.size >= 2 for a in axes)
    )
    _need(all(np.isfinite(a).all() for a in axes))
    n_points = axes[0].size * axes[1].size * axes[2].size
    n_cells = (axes[0].size - 1) * (axes[1].size - 1) * (axes[2].size - 1)
    if memory_bytes is not None and image_bytes(n_points, n_cells) > memory_bytes:
        raise MemoryError
    _need(tags is None or (ids(tags) and tags.shape == (n_cells,)))
    _need(tag_name is None or type(tag_name) is str)
    _need(type(meta) is dict)
    _plain(meta)
    return axes, tags, tag_name, meta

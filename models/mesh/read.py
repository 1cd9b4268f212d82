"""Mesh input: any format meshio reads, turned into one `Mesh` of numpy arrays.

Format quirks stay here. Everything returned is validated: finite coordinates, cell indices in
range, no degenerate cells, cells oriented consistently with their neighbours and each connected
piece positively (2D counter-clockwise, 3D outward): see orientation.py. A folded cell (negative
signed measure once its neighbours agree) is kept and reported in mesh.meta["orientation"].
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings
from itertools import chain

import meshio
import numpy as np

from models.errors import MeshError, ParameterError
from models.mesh.container import (
    CELL_TYPE_NAMES,
    VTK_HEXAHEDRON,
    VTK_POLYGON,
    VTK_POLYHEDRON,
    VTK_PYRAMID,
    VTK_QUAD,
    VTK_TETRA,
    VTK_TRIANGLE,
    VTK_WEDGE,
    Mesh,
)

# meshio cell type name -> (VTK type, topological dimension, number of corner nodes kept)
_TYPES: dict[str, tuple[int, int, int]] = {
    "vertex": (1, 0, 1),
    "line": (3, 1, 2),
    "line3": (3, 1, 2),
    "triangle": (VTK_TRIANGLE, 2, 3),
    "triangle6": (VTK_TRIANGLE, 2, 3),
    "triangle7": (VTK_TRIANGLE, 2, 3),
    "quad": (VTK_QUAD, 2, 4),
    "quad8": (VTK_QUAD, 2, 4),
    "quad9": (VTK_QUAD, 2, 4),
    "polygon": (VTK_POLYGON, 2, 0),
    "tetra": (VTK_TETRA, 3, 4),
    "tetra10": (VTK_TETRA, 3, 4),
    "hexahedron": (VTK_HEXAHEDRON, 3, 8),
    "hexahedron20": (VTK_HEXAHEDRON, 3, 8),
    "hexahedron27": (VTK_HEXAHEDRON, 3, 8),
    "wedge": (VTK_WEDGE, 3, 6),
    "wedge15": (VTK_WEDGE, 3, 6),
    "wedge18": (VTK_WEDGE, 3, 6),
    "pyramid": (VTK_PYRAMID, 3, 5),
    "pyramid13": (VTK_PYRAMID, 3, 5),
    "pyramid14": (VTK_PYRAMID, 3, 5),
}
# Node permutation that mirrors a cell (turns a negatively oriented cell into a positive one).
MIRROR = {
    VTK_TETRA: np.array([0, 2, 1, 3]),
    VTK_HEXAHEDRON: np.array([0, 3, 2, 1, 4, 7, 6, 5]),
    VTK_WEDGE: np.array([0, 2, 1, 3, 5, 4]),
    VTK_PYRAMID: np.array([0, 3, 2, 1, 4]),
}
TAG_NAMES = (
    "gmsh:physical",
    "CellEntityIds",
    "cell_tags",
    "medit:ref",
    "physical",
    "material",
    "tag",
    "physical_group",
    "avsucd:material",
)
BOUNDARY_TAG_NAME = "boundary_tag"  # boundary groups of lower-dimensional cells, as models.vtu writes them
SUPPORTED_EXTENSIONS = (
    ".vtu",
    ".vtk",
    ".msh",
    ".xdmf",
    ".xmf",
    ".mesh",
    ".med",
    ".inp",
    ".ucd",
    ".obj",
    ".off",
    ".ply",
    ".stl",
    ".h5m",
    ".su2",
    ".nas",
    ".bdf",
    ".f3grid",
    ".avs",
    ".dat",
    ".tec",
    ".ugrid",
)


def read_mesh(
    path: str | os.PathLike,
    physical_tag: str | None = None,
    file_format: str | None = None,
    weld: float | None = None,
) -> Mesh:
    """Read a mesh file and return a validated, positively oriented `Mesh`.

    weld: merge points closer than this distance first (coincident duplicates that split a mesh)."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise MeshError(f"mesh file not found: {path}")
    if os.path.getsize(path) == 0:
        raise MeshError(f"mesh file is empty: {os.path.basename(path)}")
    ext = os.path.splitext(path)[1].lower()
    if file_format in ("ucd", "avsucd") or (file_format is None and ext in (".inp", ".ucd")):
        from models.mesh.ucd import is_ucd, read_ucd

        # .inp is Abaqus unless it looks like UCD
        if ext == ".ucd" or file_format is not None or is_ucd(path):
            return mesh_from_meshio(read_ucd(path), physical_tag=physical_tag, weld=weld, owned=True)
    if file_format is None and ext not in meshio.extension_to_filetypes:
        raise MeshError(
            f"unknown mesh format {ext or '(no extension)'!r}; use one of: " + ", ".join(SUPPORTED_EXTENSIONS)
        )
    if (file_format or ext.lstrip(".")) == "vtu":
        from models.mesh.vtu import read_vtu_simple

        simple = read_vtu_simple(path)  # the common layout without meshio's XML tree; else None
        if simple is not None:
            return mesh_from_meshio(simple, physical_tag=physical_tag, weld=weld, owned=True)
    try:
        with (
            warnings.catch_warnings(),
            contextlib.redirect_stdout(io.StringIO()),
            contextlib.redirect_stderr(io.StringIO()),
        ):
            warnings.simplefilter("ignore")
            m = meshio.read(path, file_format=file_format)
    except MeshError:
        raise
    except (Exception, SystemExit) as exc:  # meshio raises many kinds (even SystemExit) on broken input
        meshio_polyhedra_bug = "polyhedra with other cells" in str(exc) or "Incompatible cell data" in str(
            exc
        )
        if meshio_polyhedra_bug and (file_format or ext).lstrip(".") == "vtu":
            # e.g. our own 3D output with its boundary faces, or polyhedra not sorted by vertex count
            from models.mesh.vtu import read_vtu_mixed

            return mesh_from_meshio(read_vtu_mixed(path), physical_tag=physical_tag, weld=weld, owned=True)
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        if not any(ch.isalpha() for ch in msg):  # e.g. meshio's SystemExit(1) on a garbled file
            what = ext.lstrip(".") or file_format or "mesh"
            msg = f"not a valid {what} file ({' '.join([type(exc).__name__, msg]).strip()})"
        raise MeshError(f"cannot read {os.path.basename(path)} as a mesh: {msg}") from None
    return mesh_from_meshio(m, physical_tag=physical_tag, weld=weld, owned=True)


def mesh_from_meshio(
    m, physical_tag: str | None = None, weld: float | None = None, owned: bool = False
) -> Mesh:
    """Convert a meshio.Mesh (blocks of cells) into our CSR `Mesh`. owned: `m` is ours to consume
    (read here, dropped after): the mesh may keep and edit its arrays in place instead of a copy."""
    blocks = []
    for i, block in enumerate(m.cells):
        name = block.type
        if name.startswith("polyhedron"):
            blocks.append((i, name, VTK_POLYHEDRON, 3, block.data))
            continue
        if name not in _TYPES:
            raise MeshError(f"unsupported cell type {name!r} in the mesh")
        vtk, tdim, _ = _TYPES[name]
        blocks.append((i, name, vtk, tdim, block.data))
    tag_key = _find_tag_key(m.cell_data, physical_tag)
    top = max((b[3] for b in blocks if len(b[4])), default=0)
    bnd_key = BOUNDARY_TAG_NAME if BOUNDARY_TAG_NAME in m.cell_data else tag_key
    cells = []
    for i, name, _vtk, tdim, data in blocks:
        key = tag_key if tdim == top else bnd_key
        tags = None if key is None else np.asarray(m.cell_data[key][i]).reshape(-1)
        cells.append((name, data, tags, tdim))
    mesh = mesh_from_blocks(
        np.asarray(m.points, dtype=np.float64), cells, tag_name=tag_key, weld=weld, owned=owned
    )
    from models.mesh.boundary import group_names

    mesh.meta["group_names"], mesh.meta["boundary_names"] = group_names(
        getattr(m, "field_data", None), mesh.dim
    )
    return mesh


def mesh_from_arrays(points, cells, tags=None) -> Mesh:
    """Build a `Mesh` from points and [(meshio type name, array)] blocks; tags is None or one array per block."""
    blocks = []
    for j, (name, data) in enumerate(cells):
        if name.startswith("polyhedron"):
            tdim = 3
        elif name in _TYPES:
            tdim = _TYPES[name][1]
        else:
            raise MeshError(f"unsupported cell type {name!r}")
        blocks.append((name, data, None if tags is None else np.asarray(tags[j]).reshape(-1), tdim))
    return mesh_from_blocks(
        np.asarray(points, dtype=np.float64), blocks, tag_name=None if tags is None else "tags"
    )


def _find_tag_key(cell_data: dict, physical_tag: str | None) -> str | None:
    if physical_tag is not None:
        if physical_tag not in cell_data:
            raise ParameterError(
                f"physical tag {physical_tag!r} not found in the mesh cell data; available: {sorted(cell_data) or 'none'}"
            )
        return physical_tag
    for key in TAG_NAMES:
        if key in cell_data:
            return key
    return None


def _csr_from_blocks(blocks, owned: bool = False):
    """Concatenate blocks into CSR (a loop over blocks, not cells): fixed-width (n, w) arrays, or
    (sizes, nodes) pairs of variable-width cells (polyhedra). owned: the blocks are ours to keep, so
    one contiguous int64 (n, w) block becomes the connectivity as it is (no copy)."""
    if owned and len(blocks) == 1 and not isinstance(blocks[0], tuple):
        d = np.asarray(blocks[0], dtype=np.int64)
        if not d.flags.writeable:  # e.g. np.frombuffer of the file's bytes: orienting edits it in place
            d = d.copy()
        n, w = d.shape
        return np.arange(0, n * w + 1, w, dtype=np.int64) if w else np.zeros(n + 1, np.int64), d.reshape(-1)
    sizes = (
        np.concatenate(
            [d[0] if isinstance(d, tuple) else np.full(len(d), d.shape[1], dtype=np.int64) for d in blocks]
        )
        if blocks
        else np.zeros(0, np.int64)
    )
    conn = (
        np.concatenate(
            [d[1] if isinstance(d, tuple) else np.asarray(d, dtype=np.int64).reshape(-1) for d in blocks]
        )
        if blocks
        else np.zeros(0, np.int64)
    )
    offsets = np.zeros(len(sizes) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    return offsets, conn


def mesh_from_blocks(
    points: np.ndarray, blocks, tag_name: str | None = None, weld: float | None = None, owned: bool = False
) -> Mesh:
    """Core builder: split elements from boundary cells, check, orient, project 2D meshes.

    weld: merge points closer than this (see weld_points) before anything else is checked.
    owned: the blocks' arrays are the caller's to give away (see mesh_from_meshio)."""
    if points.ndim != 2 or len(points) == 0:
        raise MeshError("the mesh has no points")
    if points.shape[1] == 1:
        raise MeshError("1D meshes are not supported: the mesh has 1D coordinates")
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise MeshError(
            f"the mesh has {int(bad.sum())} points with NaN or infinite coordinates (first: point {int(np.flatnonzero(bad)[0])})"
        )
    nonempty = [b for b in blocks if len(b[1]) > 0]
    if not nonempty:
        raise MeshError("the mesh has no cells")
    dim = max(b[3] for b in nonempty)
    if dim < 2:
        raise MeshError(
            "1D meshes are not supported: the file holds only line/vertex cells, no 2D or 3D elements"
        )

    elem, bnd = [], []
    for name, data, tags, tdim in nonempty:
        (elem if tdim == dim else bnd if tdim == dim - 1 else []).append((name, data, tags))
    lower: dict[str, int] = {}  # not agglomerated: reported by describe(), never silently dropped
    for name, data, _tags, tdim in nonempty:
        if tdim < dim:
            lower[name] = lower.get(name, 0) + len(data)

    types_list, data_list, tag_list = [], [], []
    poly_faces = []  # per polyhedron block: (cell ids in elem order, faces per cell, face sizes, face nodes)
    n_so_far = 0
    for name, data, tags in elem:
        if name.startswith("polyhedron"):
            nfaces, fsizes, fnodes, sizes, nodes = _polyhedra(data)
            poly_faces.append((n_so_far + np.arange(len(data), dtype=np.int64), nfaces, fsizes, fnodes))
            data_list.append((sizes, nodes))
            types_list.append(np.full(len(data), VTK_POLYHEDRON, np.uint8))
            n_so_far += len(data)
        else:
            vtk, _, keep = _TYPES[name]
            arr = np.asarray(data, dtype=np.int64)
            if arr.ndim != 2:
                raise MeshError(f"malformed {name} block in the mesh")
            if keep:
                arr = arr[:, :keep]
            if vtk == VTK_POLYGON and arr.shape[1] == 3:
                vtk = VTK_TRIANGLE
            elif vtk == VTK_POLYGON and arr.shape[1] == 4:
                vtk = VTK_QUAD
            data_list.append(arr)
            types_list.append(np.full(len(arr), vtk, np.uint8))
            n_so_far += len(arr)
        if tags is not None:
            tag_list.append(tags)
    offsets, conn = _csr_from_blocks(data_list, owned=owned)
    cell_types = np.concatenate(types_list)
    tags = np.concatenate(tag_list).astype(np.int64) if tag_list and len(tag_list) == len(elem) else None
    if tags is not None and len(tags) != len(cell_types):
        raise MeshError("physical group data does not match the number of cells")

    if conn.size and (conn.min() < 0 or conn.max() >= len(points)):
        raise MeshError(
            f"cells refer to missing points: point ids must be in 0..{len(points) - 1}, found {int(conn.min())}..{int(conn.max())}"
        )

    mesh = Mesh(
        points=points,
        offsets=offsets,
        connectivity=conn,
        cell_types=cell_types,
        tags=tags,
        tag_name=tag_name if tags is not None else None,
    )
    welded = None
    if weld is not None:
        welded = weld_points(points, weld)
        mesh.connectivity = welded[conn]
        mesh.meta["welded"] = int(np.count_nonzero(welded != np.arange(len(points))))
    if dim == 2:
        _collapse_repeated_nodes(mesh)
    mesh.meta["lower_dim_cells"] = lower
    if poly_faces:
        _attach_polyhedra(mesh, poly_faces)
        pf = mesh.poly_face_nodes
        if pf.min() < 0 or pf.max() >= len(points):
            raise MeshError("polyhedron faces refer to missing points")
        if welded is not None:
            mesh.poly_face_nodes = welded[pf]

    if bnd:
        b_data = [
            np.asarray(d, dtype=np.int64)[:, : (_TYPES[n][2] or None)]
            for n, d, _ in bnd
            if not n.startswith("polyhedron")
        ]
        mesh.boundary_offsets, mesh.boundary_connectivity = _csr_from_blocks(b_data)
        mesh.boundary_types = np.concatenate([np.full(len(d), _TYPES[n][0], np.uint8) for n, d, _ in bnd])
        if all(t is not None for _, _, t in bnd):
            mesh.boundary_tags = np.concatenate([t for _, _, t in bnd]).astype(np.int64)
        if mesh.boundary_connectivity.size and mesh.boundary_connectivity.max() >= len(points):
            raise MeshError("boundary cells refer to missing points")
        if welded is not None:
            mesh.boundary_connectivity = welded[mesh.boundary_connectivity]

    if dim == 2:
        _project_to_plane(mesh)
    _orient_and_check(mesh)
    return mesh


def weld_points(points: np.ndarray, tol: float) -> np.ndarray:
    """(P,) the point each point is merged into: the smallest id of its group of points closer
    than `tol` (transitively). A k-d tree finds the pairs; groups are connected components."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    if not (isinstance(tol, int | float) and np.isfinite(tol) and tol >= 0):
        raise ParameterError(f"weld tolerance must be a finite number >= 0, got {tol!r}")
    n = len(points)
    pairs = (
        cKDTree(points).query_pairs(float(tol), output_type="ndarray")
        if tol > 0
        else np.zeros((0, 2), np.int64)
    )
    if pairs.size == 0:
        return np.arange(n)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, comp = connected_components(g, directed=False)
    first = np.full(comp.max() + 1, n, dtype=np.int64)
    np.minimum.at(first, comp, np.arange(n))
    return first[comp]


def _collapse_repeated_nodes(mesh: Mesh) -> None:
    """2D: drop a node equal to the next one in its cell's cycle (a quad with a repeated corner
    is a triangle). Cells left with fewer than 3 nodes stay, and are refused as degenerate."""
    from models.mesh.geometry import cell_index, next_in_cycle

    conn = mesh.connectivity
    sizes = np.diff(mesh.offsets)
    if sizes.size and sizes.min() == sizes.max():  # the usual case: one cell size, a cheap test first
        c = conn.reshape(-1, int(sizes[0]))
        if not np.any(c == np.roll(c, -1, axis=1)):
            return
    rep = conn == conn[next_in_cycle(mesh.offsets)]
    # keep at least one node per cell (a cell whose nodes are all equal keeps one)
    cell = cell_index(mesh.offsets)
    all_rep = np.bincount(cell, weights=rep, minlength=sizes.size) == sizes
    rep &= ~(all_rep[cell] & (np.arange(conn.size) == mesh.offsets[:-1][cell]))
    if not rep.any():
        return
    mesh.meta["collapsed"] = int(rep.sum())
    new_sizes = sizes - np.bincount(cell, weights=rep, minlength=sizes.size).astype(np.int64)
    mesh.connectivity = conn[~rep]
    mesh.offsets = np.concatenate([[0], np.cumsum(new_sizes)]).astype(np.int64)
    mesh.cell_types = np.where(
        new_sizes == 3, VTK_TRIANGLE, np.where(new_sizes == 4, VTK_QUAD, VTK_POLYGON)
    ).astype(np.uint8)


def _polyhedra(data) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """meshio's polyhedron cells (per cell a list of faces) as arrays, iterated at C level only:
    (faces per cell, face sizes, face nodes, distinct nodes per cell, those nodes ascending per cell)."""
    nfaces = np.fromiter(map(len, data), dtype=np.int64, count=len(data))
    faces = list(chain.from_iterable(data))
    fsizes = np.fromiter(map(len, faces), dtype=np.int64, count=len(faces))
    fnodes = np.concatenate(faces).astype(np.int64).reshape(-1) if faces else np.zeros(0, np.int64)
    owner = np.repeat(np.repeat(np.arange(len(data)), nfaces), fsizes)
    order = np.lexsort((fnodes, owner))
    so, sn = owner[order], fnodes[order]
    first = np.ones(sn.size, dtype=bool)
    first[1:] = (so[1:] != so[:-1]) | (sn[1:] != sn[:-1])
    return nfaces, fsizes, fnodes, np.bincount(so[first], minlength=len(data)).astype(np.int64), sn[first]


def _attach_polyhedra(mesh: Mesh, poly_faces) -> None:
    mesh.poly_cells = np.concatenate([c for c, _, _, _ in poly_faces])
    nfaces = np.concatenate([n for _, n, _, _ in poly_faces])
    fsizes = np.concatenate([f for _, _, f, _ in poly_faces])
    mesh.poly_cell_faces = np.concatenate([[0], np.cumsum(nfaces)])
    mesh.poly_face_offsets = np.concatenate([[0], np.cumsum(fsizes)])
    mesh.poly_face_nodes = np.concatenate([f for _, _, _, f in poly_faces])


def _project_to_plane(mesh: Mesh) -> None:
    """A 2D mesh stored with 3D points: find its plane and keep 2D coordinates plus the frame."""
    pts = mesh.points
    used = np.zeros(len(pts), dtype=bool)
    used[mesh.connectivity] = True
    p = pts[used]
    if np.all(p[:, 2] == p[0, 2]):
        frame = np.array([[0.0, 0.0, p[0, 2]], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        mesh.points = np.ascontiguousarray(pts[:, :2])
        mesh.frame = frame
        return
    origin = p.mean(axis=0)
    _, s, vt = np.linalg.svd(p - origin, full_matrices=False)
    extent = max(float(s[0]), 1e-300)
    if s[2] > 1e-8 * extent:
        raise MeshError(
            "2D cells lie on a curved (non-planar) surface; only planar 2D meshes are supported: "
            "project the surface onto a plane first, or give a 3D volume mesh"
        )
    e1, e2 = vt[0], vt[1]
    mesh.points = np.column_stack([(pts - origin) @ e1, (pts - origin) @ e2])
    mesh.frame = np.array([origin, e1, e2])


def _orient_and_check(mesh: Mesh) -> None:
    """Reject degenerate cells, orient cells by topology (see orientation.py), record what was fixed."""
    from models.mesh.geometry import (
        _all_tetrahedra,
        _measures_and_centroids,
        _tetra_measures,
        cell_faces,
        tetra_face_areas,
    )
    from models.mesh.orientation import orientation_flips

    tets = _all_tetrahedra(mesh)
    areas = None  # all tetrahedra: the face areas for the dual graph, from the same corners
    if tets:
        faces = None  # built once the cells are mirrored by their own sign (below)
        vol, cen, areas = _tetra_measures(mesh, face_areas=True)
    else:
        faces = cell_faces(mesh) if mesh.dim == 3 else None
        vol, cen = _measures_and_centroids(mesh, faces)
    mesh.meta["measures"] = np.abs(vol)  # orientation does not change measure or centroid
    mesh.meta["centroids"] = cen
    lo, hi = _bounds(mesh.points)
    bbox = hi - lo
    scale = float(np.linalg.norm(bbox)) ** mesh.dim
    if scale == 0:
        raise MeshError("the mesh is degenerate: all points coincide")
    degenerate = np.abs(vol) <= 1e-14 * scale
    if degenerate.any():
        ids = np.flatnonzero(degenerate)
        kind = "area" if mesh.dim == 2 else "volume"
        raise MeshError(
            f"the mesh has {ids.size} degenerate (zero-{kind}) cells, e.g. cell ids {ids[:5].tolist()}; "
            "remove them (or merge their coincident points with --weld) and retry"
        )
    pairing: dict = {}
    if tets:
        # Mirror every negative tetrahedron first (the usual answer), then build the faces and their
        # pairing once, on the mirrored cells: nothing to rebuild or renumber unless the orientation
        # flips more cells (folded ones). The same result as orienting the cells as they came: the
        # topology fixes each piece up to one global flip, chosen by the sign of its total volume.
        own = vol < 0
        if own.any():
            c = mesh.connectivity.reshape(-1, 4)
            sel = np.flatnonzero(own)
            c[sel, 1], c[sel, 2] = c[sel, 2], c[sel, 1]  # MIRROR[VTK_TETRA]
        faces = cell_faces(mesh)
        more = orientation_flips(mesh, np.abs(vol), faces, pairing)
        flip = own ^ more
    else:
        more = flip = orientation_flips(mesh, vol, faces, pairing)
    signed = np.where(flip, -vol, vol)
    if more.any():
        _flip_cells(mesh, more)
    if faces is not None:
        _keep_faces(mesh, more, faces, pairing, None if areas is None else tetra_face_areas(areas, flip))
    folded = np.flatnonzero(signed < 0)
    mesh.meta["signed_measures"] = signed
    mesh.meta["orientation"] = {
        "flipped": int(np.count_nonzero(flip)),
        "folded": int(folded.size),
        "folded_cells": folded[:20].tolist(),
    }


def _bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) per coordinate, one column at a time: the same values as points.min(axis=0) /
    max(axis=0), a reduction numpy does slowly over rows of 2 or 3 (~30x at a million points)."""
    cols = range(points.shape[1])
    return np.array([points[:, d].min() for d in cols]), np.array([points[:, d].max() for d in cols])


def _keep_faces(mesh: Mesh, flip: np.ndarray, faces, pairing: dict, areas=None) -> None:
    """Keep the faces and the face pairing the orientation sorted, for prepare / dual_graph (one
    sort and one gather of every face: the costliest steps of reading, not done twice).
    They were made before the flips: a flipped tetrahedron lists the same faces in another local
    order and direction, so its faces are rebuilt in place and face ids in the pairing renumbered
    (the keys, hence the pairs, do not change). Other meshes keep them only when nothing was flipped.
    areas: all tetrahedra, every face's area (face id 4 * cell + local face) after the flips."""
    from models.mesh.geometry import FACE_TEMPLATES, _all_tetrahedra

    order, pairs = pairing.get("order"), pairing.get("pairs")
    if flip.any():
        if not _all_tetrahedra(mesh):
            return
        tmpl = FACE_TEMPLATES[VTK_TETRA]
        sel = np.flatnonzero(flip)
        faces.nodes.reshape(-1, 12)[sel] = np.take(
            mesh.connectivity.reshape(-1, 4)[sel], np.array(tmpl).reshape(-1), axis=1
        )
        m = MIRROR[VTK_TETRA]
        # new local face k has the nodes of old local face m[tmpl[k]]: old j -> new k
        mirrored = [frozenset(m[list(f)].tolist()) for f in tmpl]
        new_of_old = np.array([mirrored.index(frozenset(f)) for f in tmpl])

        def renumber(ids: np.ndarray) -> np.ndarray:
            local = ids & 3  # face id = 4 * cell + local face
            return np.where(flip[ids >> 2], ids - local + new_of_old[local], ids)

        order = None if order is None else renumber(order)
        pairs = None if pairs is None else (renumber(pairs[0]), renumber(pairs[1]))
    mesh.meta["cell_faces"] = {
        "connectivity": mesh.connectivity,
        "faces": faces,
        "order": order,
        "same": pairing.get("same"),
        "pairs": pairs,
        "areas": areas,
    }


def _flip_cells(mesh: Mesh, flip: np.ndarray) -> None:
    """Reverse the orientation of the cells where `flip` is True (in place, vectorized)."""
    if mesh.dim == 2:
        mesh.connectivity = _reverse_rows(mesh.offsets, mesh.connectivity, flip)
        return
    for t, perm in MIRROR.items():
        sel = np.flatnonzero(flip & (mesh.cell_types == t))
        if sel.size:
            n = perm.size
            rows = mesh.offsets[sel][:, None] + np.arange(n)[None, :]
            mesh.connectivity[rows] = mesh.connectivity[rows[:, perm]]
    if mesh.poly_cells is not None and flip[mesh.poly_cells].any():
        # reverse every face of the flipped polyhedra
        face_flip = np.repeat(flip[mesh.poly_cells], np.diff(mesh.poly_cell_faces))
        mesh.poly_face_nodes = _reverse_rows(mesh.poly_face_offsets, mesh.poly_face_nodes, face_flip)


def _reverse_rows(offsets: np.ndarray, values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """CSR `values` with the rows where `mask` is True reversed (vectorized)."""
    sizes = np.diff(offsets)
    starts = offsets[:-1]
    idx = np.arange(values.size)
    row = np.repeat(np.arange(sizes.size), sizes)
    src = np.where(mask[row], 2 * starts[row] + sizes[row] - 1 - idx, idx)
    return values[src]


def describe(mesh: Mesh) -> dict:
    """Summary used by the CLI and the service: counts, dimension, types, groups, bounding box."""
    p = mesh.points3d()
    return {
        "cells": mesh.n_cells,
        "points": mesh.n_points,
        "dim": mesh.dim,
        "cell_types": mesh.cell_type_counts(),
        "lower_dim_cells": dict(mesh.meta.get("lower_dim_cells", {})),
        "physical_groups": mesh.physical_groups(),
        "bbox": [x.tolist() for x in _bounds(p)],
        **_boundary_summary(mesh),
    }


def _boundary_summary(mesh: Mesh) -> dict:
    from models.mesh.boundary import summary

    s = summary(mesh)
    return {"boundary_groups": [g["tag"] for g in s["groups"]], "boundary": s}


__all__ = [
    "read_mesh",
    "mesh_from_arrays",
    "mesh_from_meshio",
    "mesh_from_blocks",
    "describe",
    "CELL_TYPE_NAMES",
]

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
from models.mesh.build import MIRROR, _bounds, mesh_from_cells, weld_points  # noqa: F401 (MIRROR, weld_points: API)
from models.mesh.cells import distinct_nodes
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
    bnd_csr = None
    if bnd:
        b_data = [
            np.asarray(d, dtype=np.int64)[:, : (_TYPES[n][2] or None)]
            for n, d, _ in bnd
            if not n.startswith("polyhedron")
        ]
        b_off, b_conn = _csr_from_blocks(b_data)
        b_types = np.concatenate([np.full(len(d), _TYPES[n][0], np.uint8) for n, d, _ in bnd])
        b_tags = (
            np.concatenate([t for _, _, t in bnd]).astype(np.int64)
            if all(t is not None for _, _, t in bnd)
            else None
        )
        bnd_csr = (b_off, b_conn, b_types, b_tags)
    return mesh_from_cells(
        points, offsets, conn, cell_types, tags, tag_name, poly_faces, bnd_csr, lower, dim, weld=weld
    )


def _polyhedra(data) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """meshio's polyhedron cells (per cell a list of faces) as arrays, iterated at C level only:
    (faces per cell, face sizes, face nodes, distinct nodes per cell, those nodes ascending per cell)."""
    nfaces = np.fromiter(map(len, data), dtype=np.int64, count=len(data))
    faces = list(chain.from_iterable(data))
    fsizes = np.fromiter(map(len, faces), dtype=np.int64, count=len(faces))
    fnodes = np.concatenate(faces).astype(np.int64).reshape(-1) if faces else np.zeros(0, np.int64)
    return (nfaces, fsizes, fnodes, *distinct_nodes(nfaces, fsizes, fnodes))


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

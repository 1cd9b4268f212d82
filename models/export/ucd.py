"""deal.II / AVS UCD writer: the fine cells with the agglomerated element as material id."""

from __future__ import annotations

import os

import numpy as np

from models.errors import MeshError
from models.export import atomic
from models.mesh.ucd import _PYR_TO_UCD


def write_ucd(path: str | os.PathLike, mesh, material: np.ndarray | None = None, comment: str = "") -> None:
    """The fine mesh as UCD (points 1-based), each cell with `material` (default: its physical group
    or 0). Polygons and polyhedra have no UCD type: MeshError."""
    from models.mesh.container import (
        VTK_HEXAHEDRON,
        VTK_LINE,
        VTK_PYRAMID,
        VTK_QUAD,
        VTK_TETRA,
        VTK_TRIANGLE,
        VTK_WEDGE,
    )

    vtk_to_ucd = {
        VTK_TRIANGLE: "tri",
        VTK_QUAD: "quad",
        VTK_TETRA: "tet",
        VTK_PYRAMID: "pyr",
        VTK_WEDGE: "prism",
        VTK_HEXAHEDRON: "hex",
        VTK_LINE: "line",
    }
    types = np.asarray(mesh.cell_types)
    unknown = sorted(set(np.unique(types).tolist()) - set(vtk_to_ucd))
    if unknown:
        raise MeshError(
            f"UCD has no cell type for VTK type {unknown[0]} (polygons and polyhedra cannot be written as UCD)"
        )
    n = types.size
    mat = np.zeros(n, dtype=np.int64) if material is None else np.asarray(material, dtype=np.int64)
    if material is None and mesh.tags is not None:
        mat = np.asarray(mesh.tags, dtype=np.int64)
    offsets, connectivity = np.asarray(mesh.offsets, dtype=np.int64), np.asarray(mesh.connectivity)
    if mesh.boundary_types is not None and len(mesh.boundary_types):
        # the boundary groups go along as line (2D) / face (3D) cells with their tag as material id,
        # which is how deal.II reads boundary ids: a result read back keeps its boundary conditions
        btypes = np.asarray(mesh.boundary_types)
        bad = sorted(set(np.unique(btypes).tolist()) - set(vtk_to_ucd))
        if bad:
            raise MeshError(f"UCD has no cell type for the boundary cells of VTK type {bad[0]}")
        btags = np.asarray(mesh.boundary_tags, dtype=np.int64)
        boffsets = np.asarray(mesh.boundary_offsets, dtype=np.int64)
        types = np.concatenate([types, btypes])
        mat = np.concatenate([mat, btags])
        offsets = np.concatenate([offsets, offsets[-1] + boffsets[1:]])
        connectivity = np.concatenate([connectivity, np.asarray(mesh.boundary_connectivity)])
        n = types.size
    pts = np.asarray(mesh.points, dtype=np.float64)
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    lines = [f"# {c}" for c in comment.splitlines()] if comment else []
    lines.append(f"{len(pts)} {n} 0 0 0")
    out = ["\n".join(lines), "\n"]
    # text formatting: one %-format per row through map() (C-level iteration, no Python loop body)
    out.append(
        "".join(
            map("%d %.17g %.17g %.17g\n".__mod__, zip(range(1, len(pts) + 1), *pts.T.tolist(), strict=True))
        )
    )
    sizes = np.diff(offsets)
    conn = np.asarray(connectivity, dtype=np.int64) + 1
    cell_lines = np.empty(n, dtype=object)
    for t in np.unique(types):  # a loop over cell types, not cells
        rows = np.flatnonzero(types == t)
        k = int(sizes[rows[0]])
        v = conn[offsets[rows][:, None] + np.arange(k)]
        if t == VTK_PYRAMID:
            v = v[:, _PYR_TO_UCD]
        fmt = "%d %d " + vtk_to_ucd[int(t)] + " %d" * k + "\n"
        cell_lines[rows] = list(
            map(fmt.__mod__, map(tuple, np.column_stack([rows + 1, mat[rows], v]).tolist()))
        )
    out.append("".join(cell_lines.tolist()))
    atomic.write_lines(path, out)

"""Plain array containers: the fine input mesh and the agglomerated polytopal mesh.

A mesh is numpy arrays, never a Python object per cell. Cells are stored in CSR form
(`offsets`, `connectivity`) with one VTK cell type id per cell. After reading, every cell is
positively oriented: 2D cells are counter-clockwise, 3D cells have outward faces.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# VTK cell type ids (the same numbers VTK uses).
VTK_VERTEX = 1
VTK_LINE = 3
VTK_TRIANGLE = 5
VTK_POLYGON = 7
VTK_QUAD = 9
VTK_TETRA = 10
VTK_HEXAHEDRON = 12
VTK_WEDGE = 13
VTK_PYRAMID = 14
VTK_POLYHEDRON = 42

CELL_TYPE_NAMES = {
    VTK_TRIANGLE: "triangle",
    VTK_POLYGON: "polygon",
    VTK_QUAD: "quad",
    VTK_TETRA: "tetra",
    VTK_HEXAHEDRON: "hexahedron",
    VTK_WEDGE: "wedge",
    VTK_PYRAMID: "pyramid",
    VTK_POLYHEDRON: "polyhedron",
}
CELLS_2D = (VTK_TRIANGLE, VTK_POLYGON, VTK_QUAD)
CELLS_3D = (VTK_TETRA, VTK_HEXAHEDRON, VTK_WEDGE, VTK_PYRAMID, VTK_POLYHEDRON)


@dataclass
class Mesh:
    """A fine mesh of one dimension (2 or 3).

    points: (P, dim) float64. A 2D mesh stored with 3D points is projected onto its plane;
        `frame` (3, 3): rows origin, e1, e2 maps back: x3d = origin + x*e1 + y*e2.
    offsets (C+1,), connectivity (nnz,): CSR cell -> point ids (int64).
    cell_types (C,): VTK type id per cell (uint8).
    tags (C,) int64 or None: physical group per cell; `tag_name` is the cell-data name it came from.
    poly_*: faces of VTK polyhedra (3D only): poly_cells (Q,) cell ids; poly_cell_faces (Q+1,)
        offsets into faces; poly_face_offsets (F+1,) offsets into poly_face_nodes.
    boundary_*: lower-dimensional cells found in the file (boundary lines / faces), kept apart.
    """

    points: np.ndarray
    offsets: np.ndarray
    connectivity: np.ndarray
    cell_types: np.ndarray
    tags: np.ndarray | None = None
    tag_name: str | None = None
    frame: np.ndarray | None = None
    poly_cells: np.ndarray | None = None
    poly_cell_faces: np.ndarray | None = None
    poly_face_offsets: np.ndarray | None = None
    poly_face_nodes: np.ndarray | None = None
    boundary_offsets: np.ndarray | None = None
    boundary_connectivity: np.ndarray | None = None
    boundary_types: np.ndarray | None = None
    boundary_tags: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @property
    def dim(self) -> int:
        return int(self.points.shape[1])

    @property
    def n_cells(self) -> int:
        return int(self.cell_types.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def cell_sizes(self) -> np.ndarray:
        return np.diff(self.offsets)

    def points3d(self) -> np.ndarray:
        """Points in the original 3D space (for writing)."""
        if self.dim == 3:
            return self.points
        if self.frame is None:
            return np.column_stack([self.points, np.zeros(len(self.points))])
        o, e1, e2 = self.frame
        return o[None, :] + self.points[:, :1] * e1[None, :] + self.points[:, 1:2] * e2[None, :]

    def cell_type_counts(self) -> dict[str, int]:
        counts = np.bincount(self.cell_types)
        return {CELL_TYPE_NAMES.get(int(t), str(int(t))): int(counts[t]) for t in np.flatnonzero(counts)}

    def physical_groups(self) -> list[int]:
        if self.tags is None:
            return []
        s = np.sort(self.tags)
        return [int(t) for t in s[np.r_[True, s[1:] != s[:-1]]]]


@dataclass
class PolyMesh:
    """The agglomerated mesh: one polygon (2D) or polyhedron (3D) per element.

    points: (P, dim) the fine mesh points (same ids as the fine mesh; unused points allowed).
    2D: elem_offsets (E+1,) into loops; loop_offsets (L+1,) into loop_nodes. The first loop of an
        element is its outer boundary, counter-clockwise; further loops (holes) are clockwise.
        After the default hole policy every element has exactly one loop.
    3D: elem_offsets (E+1,) into faces; loop_offsets (F+1,) into loop_nodes: the element's boundary
        faces, each ordered so that its normal (right-hand rule) points out of the element.
    measure (E,): area / volume; n_fine (E,): number of fine cells; tags (E,) or None: physical
        group (majority of its fine cells); labels (C,): fine cell -> element id.
    facet_tags / facet_on_boundary: boundary group (models.mesh.boundary.NO_TAG if none) and "on the
        domain boundary" of every loop edge (2D) / face (3D), when the mesh has boundary groups.
    """

    points: np.ndarray
    elem_offsets: np.ndarray
    loop_offsets: np.ndarray
    loop_nodes: np.ndarray
    measure: np.ndarray
    n_fine: np.ndarray
    labels: np.ndarray
    tags: np.ndarray | None = None
    frame: np.ndarray | None = None
    facet_tags: np.ndarray | None = None
    facet_on_boundary: np.ndarray | None = None

    @property
    def dim(self) -> int:
        return int(self.points.shape[1])

    @property
    def n_elements(self) -> int:
        return int(self.elem_offsets.shape[0] - 1)

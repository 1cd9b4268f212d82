"""Closed triangulated surfaces for the fill tests, made with gmsh at test time, and the reference
volume they enclose (computed here, not by the library)."""

from __future__ import annotations

import numpy as np


def surface_of(build, h: float, curvature: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The boundary triangles of an OCC shape made by build(occ), meshed by gmsh at size h."""
    import gmsh

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.3 * h)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", curvature)
        build(gmsh.model.occ)
        gmsh.model.occ.synchronize()
        gmsh.model.mesh.generate(2)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
        index[tags.astype(np.int64)] = np.arange(len(tags))
        _, nodes = gmsh.model.mesh.getElementsByType(2)
        return coords.reshape(-1, 3).copy(), index[nodes.astype(np.int64)].reshape(-1, 3)
    finally:
        gmsh.finalize()


def enclosed_volume(points, tris) -> float:
    """Divergence theorem on the triangles (the reference, computed here, not by the library)."""
    p = points[tris]
    return abs(float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum()) / 6)

"""Structured meshes for the benchmarks: the unit square cut into n x n squares of two triangles each,
and the unit cube cut into n^3 cubes of six tetrahedra each (Kuhn: every tetrahedron holds the
cube's main diagonal, so neighbouring cubes' faces match). n=55 gives the 998,250-tetrahedra cube."""

from __future__ import annotations

from itertools import permutations

import numpy as np


def square(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(points (P, 2), triangles (2 n^2, 3))."""
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    p = np.column_stack([x.ravel(), y.ravel()])
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    v = lambda a, b: a * (n + 1) + b  # noqa: E731
    q = np.column_stack([v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)])
    return p, np.vstack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def cube(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(points (P, 3), tetrahedra (6 n^3, 4))."""
    g = np.linspace(0, 1, n + 1)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    p = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    i, j, k = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), np.arange(n), indexing="ij"))
    base = np.stack([i, j, k], axis=1)
    m = n + 1
    tets = []
    for perm in permutations(range(3)):
        corner = base.copy()
        ids = [corner @ [m * m, m, 1]]
        for axis in perm:  # walk from the cube's low corner to its high corner, one axis at a time
            corner = corner.copy()
            corner[:, axis] += 1
            ids.append(corner @ [m * m, m, 1])
        tets.append(np.stack(ids, axis=1))
    return p, np.vstack(tets).astype(np.int64)


def write(path: str, points: np.ndarray, cells: np.ndarray) -> None:
    """Write with meshio (binary VTU / gmsh by extension)."""
    import meshio

    kind = "triangle" if cells.shape[1] == 3 else "tetra"
    pts = points if points.shape[1] == 3 else np.column_stack([points, np.zeros(len(points))])
    meshio.write(path, meshio.Mesh(pts, [(kind, cells)]))

"""Small meshes of every cell type, made with numpy (no files outside the repo needed)."""

from __future__ import annotations

import numpy as np


def grid_points_2d(n: int, m: int | None = None) -> np.ndarray:
    m = m or n
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, m + 1), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel()])


def quads(n: int, m: int | None = None):
    m = m or n
    p = grid_points_2d(n, m)
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    i, j = i.ravel(), j.ravel()
    v = lambda a, b: a * (m + 1) + b  # noqa: E731
    q = np.column_stack([v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)])
    return p, q


def triangles(n: int, m: int | None = None):
    p, q = quads(n, m)
    t = np.vstack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    return p, t


def mixed_2d(n: int):
    """Left half quads, right half triangles, plus pentagons made by merging a triangle pair edge."""
    p, q = quads(n)
    cx = p[q].mean(axis=1)[:, 0]
    left = q[cx < 0.5]
    right = q[cx >= 0.5]
    tris = np.vstack([right[:, [0, 1, 2]], right[:, [0, 2, 3]]])
    return p, [("quad", left), ("triangle", tris)]


def cube_points(n: int) -> np.ndarray:
    x, y, z = np.meshgrid(*(np.linspace(0, 1, n + 1),) * 3, indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), z.ravel()])


def hexes(n: int):
    p = cube_points(n)
    i, j, k = (a.ravel() for a in np.meshgrid(*(np.arange(n),) * 3, indexing="ij"))
    v = lambda a, b, c: (a * (n + 1) + b) * (n + 1) + c  # noqa: E731
    h = np.column_stack(
        [
            v(i, j, k),
            v(i + 1, j, k),
            v(i + 1, j + 1, k),
            v(i, j + 1, k),
            v(i, j, k + 1),
            v(i + 1, j, k + 1),
            v(i + 1, j + 1, k + 1),
            v(i, j + 1, k + 1),
        ]
    )
    return p, h


def tets(n: int):
    """Kuhn subdivision of each cube into 6 tetrahedra (conforming)."""
    p, h = hexes(n)
    t = np.vstack(
        [
            h[:, [0, 1, 2, 6]],
            h[:, [0, 1, 5, 6]],
            h[:, [0, 3, 2, 6]],
            h[:, [0, 3, 7, 6]],
            h[:, [0, 4, 5, 6]],
            h[:, [0, 4, 7, 6]],
        ]
    )
    return p, t


def wedges(n: int):
    p, h = hexes(n)
    w = np.vstack([h[:, [0, 1, 2, 4, 5, 6]], h[:, [0, 2, 3, 4, 6, 7]]])
    return p, w


def mixed_3d(n: int):
    """Hexahedra (x < 1/2), cubes split into 6 pyramids (x > 1/2), and the pyramids whose base
    lies on the boundary x = 1 split into 2 tetrahedra: a conforming hex + pyramid + tet mesh."""
    p, h = hexes(n)
    cen = p[h].mean(axis=1)
    keep = h[cen[:, 0] < 0.5]
    split = h[cen[:, 0] >= 0.5]
    centers = p[split].mean(axis=1)
    cid = len(p) + np.arange(len(split))
    pts = np.vstack([p, centers])
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    pyr, tet = [], []
    for f in faces:
        base = split[:, list(f)]
        # pyramid base must be ordered so its normal points to the apex: reverse the outward face
        base = base[:, ::-1]
        on_x1 = np.all(np.isclose(pts[base][:, :, 0], 1.0), axis=1)
        pyr.append(np.column_stack([base[~on_x1], cid[~on_x1]]))
        b, c = base[on_x1], cid[on_x1]
        tet.append(np.column_stack([b[:, 0], b[:, 1], b[:, 2], c]))
        tet.append(np.column_stack([b[:, 0], b[:, 2], b[:, 3], c]))
    return pts, [("hexahedron", keep), ("pyramid", np.vstack(pyr)), ("tetra", np.vstack(tet))]

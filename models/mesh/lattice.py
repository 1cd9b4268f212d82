"""The read stage's validation for a whole 3D structured grid (image data, rectilinear and
structured grids as vtk_readers._structured turns them into hexahedra).

Its hexahedra are consistently oriented by construction: every cell is the same node template on
the point lattice, so two neighbours always meet on a shared face in opposite directions. The
general machinery (a face per cell side, keyed and compared; build._orient_and_check) can only
find that again. What remains to check is the geometry: each cell's signed volume (the sign of its
Jacobian), degenerate cells, and the one global flip the topology allows (the lattice is one
connected piece: flip every cell when the total volume is negative, as orientation_flips does per
piece). Folded cells (negative after that flip) are counted as there.

Measures and centroids: an axis-aligned grid (image data without rotation, rectilinear grids) in
closed form, dx * dy * dz and the box's centre (equal to the general path's to rounding, not bit
for bit); other structured grids by the general fixed-size path (geometry._fixed_measures).

And the lattice's arrays, for both readers of structured files (vtk_readers, on VTK's dataset;
xml_grid, on the file's bytes): its cells (structured_cells: hexahedra, quads or lines), its points
(grid_points, image_points), image data's axes (image_axes).
"""

from __future__ import annotations

import math

import numpy as np

from models.errors import MeshError
from models.mesh.container import Mesh


def _box_measures(axes) -> tuple[np.ndarray, np.ndarray]:
    """Signed volumes (C,) and centroids (C, 3) of the boxes of a tensor grid, x fastest."""
    x, y, z = (np.asarray(a, np.float64) for a in axes)
    dx, dy, dz = np.diff(x), np.diff(y), np.diff(z)
    vol = ((dz[:, None] * dy[None, :])[:, :, None] * dx[None, None, :]).reshape(-1)
    mx, my, mz = (x[:-1] + x[1:]) / 2, (y[:-1] + y[1:]) / 2, (z[:-1] + z[1:]) / 2
    cen = np.empty((mz.size, my.size, mx.size, 3))
    cen[..., 0] = mx[None, None, :]
    cen[..., 1] = my[None, :, None]
    cen[..., 2] = mz[:, None, None]
    return vol, cen.reshape(-1, 3)


def lattice_measures(mesh: Mesh, grid: dict) -> tuple[np.ndarray, np.ndarray]:
    """Signed volumes and centroids of a whole structured grid's hexahedra (see the module's note)."""
    from models.mesh.geometry import _measures_and_centroids

    if grid.get("axes") is not None:
        return _box_measures(grid["axes"])
    return _measures_and_centroids(mesh, None)


def lattice_flips(vol: np.ndarray) -> np.ndarray:
    """(C,) bool: the one global flip of a connected lattice (every cell when the total is negative)."""
    return np.full(vol.size, bool(vol.sum() < 0))


def check_image_geometry(origin, spacing, live) -> None:
    """MeshError (one sentence) when image data's origin, or its spacing along a live axis, is not a
    finite number or the spacing is zero: the lattice would have no volume or no place."""
    o, h = np.asarray(origin, np.float64), np.asarray(spacing, np.float64)
    if not np.isfinite(o).all():
        raise MeshError(f"the image data's origin must be finite numbers, found {_triple(o)}")
    hl = h[list(live)]
    if not np.isfinite(hl).all() or np.any(hl == 0):
        raise MeshError(f"the image data's spacing must be finite and nonzero, found {_triple(h)}")


def _triple(v) -> str:
    return "(" + ", ".join(f"{float(x):g}" for x in v) + ")"


def image_axes(origin, spacing, extent) -> list[np.ndarray]:
    """x, y, z point coordinates of axis-aligned image data: origin + index * spacing, indices from
    the extent (they need not start at 0)."""
    return [
        origin[a] + (extent[2 * a] + np.arange(extent[2 * a + 1] - extent[2 * a] + 1)) * spacing[a]
        for a in range(3)
    ]


def lower_corners(live, cdims, stride) -> np.ndarray:
    """Point id of each cell's lower corner, cells numbered with the first live axis fastest."""
    parts = [np.arange(n, dtype=np.int64) * stride[a] for a, n in zip(live, cdims, strict=True)]
    total = parts[-1]
    for p in parts[-2::-1]:  # outer axes first: idx[k, j, i] = k*sz + j*sy + i
        total = (total[:, None] + p[None, :]).reshape(-1)
    return total


def hex_corners(stride) -> np.ndarray:
    """A hexahedron's eight point-id offsets from its lower corner on a lattice (VTK's node order)."""
    sx, sy, sz = stride
    return np.array([0, sx, sx + sy, sy, sz, sz + sx, sz + sx + sy, sz + sy])


def structured_cells(dims) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(offsets, connectivity, types) of a lattice of dims points (image data, structured and
    rectilinear grids): hexahedra (3 axes of 2 points or more), quads (2) or lines (1), VTK's cell
    numbering (the first live axis fastest) and node order; no cell where no axis is live."""
    live = [a for a in range(3) if dims[a] > 1]
    if not live:
        return np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8)
    stride = [1, dims[0], dims[0] * dims[1]]
    cdims = [dims[a] - 1 for a in live]
    if len(live) == 3:
        corner, vtk = hex_corners(stride), 12
    elif len(live) == 2:
        sa, sb = stride[live[0]], stride[live[1]]
        corner, vtk = np.array([0, sa, sa + sb, sb]), 9
    else:
        corner, vtk = np.array([0, stride[live[0]]]), 3
    conn = cell_nodes(live, cdims, stride, corner)
    w, n = corner.size, math.prod(cdims)
    return np.arange(0, n * w + 1, w, dtype=np.int64), conn, np.full(n, vtk, np.uint8)


def cell_nodes(live, cdims, stride, corner) -> np.ndarray:
    """The connectivity of a lattice's cells: each cell's lower corner (cells numbered with the first
    live axis fastest) plus the node template `corner`, int64. One layer of cells (the last live
    axis's) first, then every layer as that one plus its offset: one contiguous pass (~3.5x a sum
    of broadcast columns at 13,824 hexahedra)."""
    inner = lower_corners(live[:-1], cdims[:-1], stride) if len(live) > 1 else np.zeros(1, np.int64)
    layer = inner[:, None] + np.asarray(corner, np.int64)[None, :]
    out = np.empty((cdims[-1], inner.size, layer.shape[1]), np.int64)
    np.add(layer[None], (np.arange(cdims[-1], dtype=np.int64) * stride[live[-1]])[:, None, None], out=out)
    return out.reshape(-1)


def grid_points(axes) -> np.ndarray:
    """Points of a tensor grid, x fastest."""
    x, y, z = axes
    pts = np.empty((z.size, y.size, x.size, 3))
    pts[..., 0] = x[None, None, :]
    pts[..., 1] = y[None, :, None]
    pts[..., 2] = z[:, None, None]
    return pts.reshape(-1, 3)


def image_points(origin, spacing, extent, direction=None) -> np.ndarray:
    """Points of image data, x fastest: index * spacing along each axis (indices from the extent),
    turned by the direction matrix (3, 3) unless it is None or the identity, plus the origin."""
    axes = [
        (extent[2 * a] + np.arange(int(extent[2 * a + 1] - extent[2 * a] + 1))) * spacing[a] for a in range(3)
    ]
    pts = grid_points(axes)
    if direction is not None and not np.array_equal(direction, np.eye(3)):
        pts = pts @ np.asarray(direction).T
    return pts + np.asarray(origin)

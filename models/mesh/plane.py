"""A 2D mesh stored with 3D points (models.mesh.build): its plane found, its points in 2D
coordinates of that plane and the frame kept; a surface that is not planar refused in one sentence
(fill a closed one: FILL_HINT). Tolerances: a millionth of the mesh's width, the rounding of float32
coordinates, or of decimals written with 5-8 significant digits (said: meta["rounded_plane"]; refused
where that rounding is above a hundredth of the small cells' size)."""

from __future__ import annotations

import numpy as np

from models.errors import MeshError
from models.mesh.container import Mesh

# the curved surface's refusal names this command (the CLI puts the file's name for SURFACE); the
# readers' callers know that refusal by it (models.mesh.fill.open_surface_refusal, models.api)
FILL_HINT = "agglomerate SURFACE --fill"


def _plane_tolerance(p: np.ndarray) -> float:
    """How far off their plane the points of a planar mesh may lie: a millionth of the mesh's width
    (projecting moves areas by a trillionth), or the rounding of single-precision coordinates where
    every coordinate is a float32 (PLY, binary STL and most VTK sources store them so: a tilted
    plane's points then lie up to about 2^-24 of their size off it)."""
    width = float(np.linalg.norm(np.ptp(p, axis=0)))
    tol = 1e-6 * width
    if np.array_equal(p.astype(np.float32).astype(np.float64), p):
        tol = max(tol, 4 * 2.0**-24 * float(np.abs(p).max()))
    return tol


def project_to_plane(mesh: Mesh) -> None:
    """A 2D mesh stored with 3D points: find its plane and keep 2D coordinates plus the frame."""
    pts = mesh.points
    z = pts[:, 2]
    flat = len(pts) and bool(np.all(z == z[0]))  # every point at one z (the usual file): no gather
    if not flat:
        used = np.zeros(len(pts), dtype=bool)
        used[mesh.connectivity] = True
        p = pts[used]
    if flat or np.all(p[:, 2] == p[0, 2]):
        frame = np.array([[0.0, 0.0, z[0] if flat else p[0, 2]], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        mesh.points = np.ascontiguousarray(pts[:, :2])
        mesh.frame = frame
        return
    origin = p.mean(axis=0)
    _, s, vt = np.linalg.svd(p - origin, full_matrices=False)
    off = float(np.abs((p - origin) @ vt[2]).max())  # the farthest point from the best plane
    digits = None
    if off > _plane_tolerance(p):  # (unless the file wrote its coordinates rounded to a few digits)
        digits = written_digits(p)
        if digits is None or off > 4 * 10.0 ** (1 - digits) * float(np.abs(p).max()):
            digits = None
    if digits is not None:  # rounded: projecting moves a cell's area by about (off / its size)^2
        h = _small_edge(mesh)
        if off > 1e-2 * h:
            raise MeshError(
                f"its points lie up to {off:.2g} off their plane, the rounding of coordinates written with "
                f"{digits} significant digits this far from the origin (up to {float(np.abs(p).max()):.3g}): "
                f"{off / h:.0%} of its small cells' size ({h:.2g}), too coarse to read their shapes; move the mesh "
                "near the origin, or write it with more digits, and retry"
            )
    if off > _plane_tolerance(p) and digits is None:
        from models.mesh.container import CELL_TYPE_NAMES

        counts = np.bincount(mesh.cell_types)
        held = " and ".join(
            f"{int(counts[t]):,} {CELL_TYPE_NAMES.get(int(t), 'cell')}s" for t in np.flatnonzero(counts)
        )
        raise MeshError(
            f"a non-planar surface of {held} (its cells are not in one plane: curved, faceted or on "
            f"several planes; a point lies {off:.3g} off the best plane, across a mesh "
            f"{float(np.linalg.norm(np.ptp(p, axis=0))):.3g} wide): only planar 2D meshes and volume meshes are "
            "agglomerated; give a volume mesh, or fill a closed surface (.stl, .obj, .ply, .off) with tetrahedra: "
            f"magnet {FILL_HINT} ... (or magnet generate stl --stl SURFACE -o volume.vtu)"
        )
    e1, e2 = vt[0], vt[1]
    mesh.points = np.column_stack([(pts - origin) @ e1, (pts - origin) @ e2])
    mesh.frame = np.array([origin, e1, e2])
    if digits is not None:
        mesh.meta["rounded_plane"] = {
            "count": 1,
            "message": f"the points lie up to {off:.2g} off their plane, the rounding of coordinates written "
            f"with {digits} significant digits: projected onto it",
        }


def _small_edge(mesh: Mesh) -> float:
    """A small cell's size: the 1st percentile of the cells' first edges (node 0 to node 1)."""
    first = mesh.offsets[:-1][np.diff(mesh.offsets) > 1]
    if first.size == 0:
        return float("inf")
    a, b = mesh.points[mesh.connectivity[first]], mesh.points[mesh.connectivity[first + 1]]
    return float(np.percentile(np.linalg.norm(a - b, axis=1), 1))


def written_digits(p: np.ndarray, fewest: int = 5, most: int = 8) -> int | None:
    """The fewest significant decimal digits (fewest..most) that give every coordinate of p back
    (to a few ulps: the double nearest each decimal), as from a text file written with that many
    (a Nastran field of 8 characters, C's %g); None where none does."""
    x = np.unique(p.ravel())
    x = x[x != 0]
    if not x.size:
        return None
    mag = np.floor(np.log10(np.abs(x)))
    for d in range(fewest, most + 1):
        scale = 10.0 ** (d - 1 - mag)
        back = np.round(x * scale) / scale
        if np.all(np.abs(back - x) <= 8 * np.finfo(float).eps * np.abs(x)):
            return d
    return None

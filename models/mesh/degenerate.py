"""What a refusal of degenerate cells says about them (on a refusal's path: loops over a few cells)."""

from __future__ import annotations

import numpy as np

from models.mesh.container import Mesh


def sized(mesh: Mesh, vol: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Of the cells `ids` (tiny beside the domain), those whose measure is above 1e-6 of their own
    box's diagonal to the dimension: small cells of a graded mesh, not flat ones (13 of 123,479
    tetrahedra of a cube graded 1000:1 were left out as degenerate before)."""
    from models.mesh.cells import ranges

    sizes = mesh.offsets[ids + 1] - mesh.offsets[ids]
    ids, sizes = ids[sizes > 0], sizes[sizes > 0]
    if ids.size == 0:
        return ids
    pts = mesh.points[mesh.connectivity[ranges(mesh.offsets[ids], sizes)]]
    start = np.r_[0, np.cumsum(sizes)[:-1]]
    ext = np.maximum.reduceat(pts, start, axis=0) - np.minimum.reduceat(pts, start, axis=0)
    return ids[np.abs(vol[ids]) > 1e-6 * np.linalg.norm(ext, axis=1) ** mesh.dim]


def point_text(p: np.ndarray) -> str:
    """A point's coordinates as a sentence shows them: (x, y, z), 6 digits."""
    return "(" + ", ".join(f"{float(v):.6g}" for v in p) + ")"


def far_point(mesh: Mesh) -> str | None:
    """A sentence naming the point(s) lying a million times farther from the points' median than
    99% of the points do (a corrupted coordinate: the bounding box it makes turns every cell
    degenerate beside it), or None. On a refusal's path."""
    used = np.unique(mesh.connectivity)
    if used.size < 8:
        return None
    p = mesh.points[used]
    dev = np.abs(p - np.median(p, axis=0)).max(axis=1)
    scale = float(np.percentile(dev, 99))
    far = used[dev > 1e6 * max(scale, 1e-300)]
    if far.size == 0 or far.size * 100 > used.size:
        return None
    return (
        f"{'a point lies' if far.size == 1 else f'{far.size:,} points lie'} far from all the others "
        f"(point {int(far[0])} at {point_text(mesh.points3d()[far[0]] if mesh.dim == 2 else mesh.points[far[0]])}; "
        f"99% of the points lie within {scale:.3g} of their median): a corrupted coordinate? fix it and retry"
    )


def corners(mesh: Mesh, ids: np.ndarray) -> str:
    """What these degenerate cells (a few, on a refusal's path) have: "coincident" (two node ids at
    the same coordinates), "repeated" (a node id twice, or fewer nodes than a cell of the dimension
    needs: collapsed on reading), else "distinct"."""
    found = "distinct"
    for c in ids.tolist():
        nodes = mesh.connectivity[mesh.offsets[c] : mesh.offsets[c + 1]]
        if np.unique(mesh.points[nodes], axis=0).shape[0] < np.unique(nodes).size:
            return "coincident"
        if np.unique(nodes).size < max(nodes.size, mesh.dim + 1):
            found = "repeated"
    return found


def welded_too_far(mesh: Mesh, ids: np.ndarray, kind: str) -> str | None:
    """Where the weld asked for (--weld) merged points, the degenerate cells `ids` are its doing:
    the sentence that says its tolerance is larger than those cells; else None."""
    if not mesh.meta.get("welded"):
        return None
    return (
        f"merging points closer than the weld tolerance (--weld) left {ids.size:,} of the "
        f"{mesh.n_cells:,} cells degenerate (zero-{kind}), e.g. cell ids {ids[:5].tolist()}: the "
        "tolerance is larger than these cells; give a smaller one"
    )

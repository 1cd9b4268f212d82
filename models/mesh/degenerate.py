"""What a refusal of degenerate cells says about them (on a refusal's path: loops over a few cells)."""

from __future__ import annotations

import numpy as np

from models.errors import id_list
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
        f"{mesh.n_cells:,} cells degenerate (zero-{kind}), e.g. cells {id_list(ids)}: the "
        "tolerance is larger than these cells; give a smaller one"
    )


_AXES = "xyz"


def flat_cause(mesh: Mesh) -> str | None:
    """Why most of a mesh's cells are flat, where the points say it (on a refusal's path), or None:
    a coordinate the same for every point, or taking a few values only, far from the origin for the
    mesh's size (rounded: 8-character Nastran fields keep 3 significant digits at 1e6), or all the
    points on one line (a writer that kept two coordinates of a plane in XZ or YZ)."""
    used = np.unique(mesh.connectivity)
    if used.size < 8:
        return None
    p = mesh.points if mesh.dim == 3 or mesh.frame is None else mesh.points3d()
    p = np.asarray(p[used], dtype=np.float64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    ext = hi - lo
    size = float(ext.max())
    if size == 0:
        return None
    far = np.maximum(np.abs(lo), np.abs(hi)) >= 1e3 * size  # coordinates far from the origin
    same = ext <= 1e-9 * size
    n_values = [np.unique(p[:, a]).size for a in range(p.shape[1])]
    few = np.array([not same[a] and n_values[a] * 64 <= p.shape[0] for a in range(p.shape[1])])
    facts = [
        f"{_AXES[a]} is {0.0 if abs(lo[a]) <= 1e-9 * size else lo[a]:.6g} for every point"
        for a in np.flatnonzero(same)
    ] + [f"{_AXES[a]} takes only {n_values[a]} values" for a in np.flatnonzero(few & far)]
    c = p - p.mean(axis=0)
    sv = np.linalg.svd(c[:: max(1, c.shape[0] // 20000)], compute_uv=False)
    line = sv.size > 1 and sv[1] <= 1e-9 * sv[0]
    if ((same | few) & far).any():
        advice = (
            "the file keeps too few digits of coordinates this far from the origin (8-character fields "
            "keep 3 significant digits at 1e6): move the mesh near the origin, or write it with more "
            "digits (large-field Nastran, or another format)"
        )
    elif line and same.any():
        advice = (
            "the writer kept two coordinates of a plane that is not XY and dropped the third: write the "
            "plane in XY, or in a format that keeps three coordinates"
        )
    elif line:
        advice = "fix the file's coordinates and retry"
    else:
        return None
    said = f" ({', '.join(facts)})" if facts else ""
    return f"{'all of its points lie on one line' if line else 'its coordinates are rounded'}{said}: {advice}"

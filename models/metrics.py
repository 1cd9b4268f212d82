"""Quality metrics of an agglomerated mesh (MISSION.md section 6), all in [0, 1] per element.

Everything works on whole arrays. The only Python loops run over agglomerated elements (one convex
hull per element) or over refinement levels / pivot steps; never over fine cells or boundary facets.

Boundary of an element: 2D, its segments (outer loop CCW, holes CW: the element is on the left of
every segment); 3D, its faces fan-triangulated (outward normals). The largest inscribed ball is exact
(linear program) for convex elements and certified to `rel_tol * diameter` otherwise; see
`largest_inscribed_ball`. The 3D search and geometry, the enclosing balls and the partition
statistics run in the compiled models/_fastmetrics.c where it was built; their numpy versions here
are the fallback (MAGNET_NO_COMPILED=1) and the reference of the tests.
"""

from __future__ import annotations

import itertools
import math
import os
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from models.errors import ParameterError
from models.mesh import PolyMesh
from models.summary import summarize  # callers import it from here too

DEFAULT_REL_TOL = 1e-3
_PAIR_CHUNK = 1 << 21  # point/primitive pairs evaluated per numpy batch
_INTERIOR_MARGIN = 1e-9  # closest point this far (in barycentric units) from a facet's rim is "interior"
_CONVEX_TOL = 1e-10  # element is convex when measure >= (1 - tol) * hull measure


# --------------------------------------------------------------------------------------------------
# geometry shared by all metrics


@dataclass
class _Geometry:
    dim: int
    n: int
    prim: np.ndarray  # (S, dim, dim): segment endpoints (2D) / triangle corners (3D)
    prim_elem: np.ndarray  # (S,) element of each primitive, sorted
    prim_ptr: np.ndarray  # (E+1,) CSR element -> primitives
    boundary_size: np.ndarray  # (E,) perimeter (2D, holes included) / surface area (3D)
    signed_measure: np.ndarray  # (E,) area / volume from the boundary (sign = orientation)
    n_loops: np.ndarray  # (E,) loops (2D) / faces (3D) per element
    bbox_lo: np.ndarray  # (E, dim)
    bbox_hi: np.ndarray  # (E, dim)
    hull_pts: list  # per element: (h, dim) convex hull vertices
    hull_eq: list  # per element: (f, dim+1) facet equations n.x + b <= 0 inside, |n| = 1 (or None)
    hull_measure: np.ndarray  # (E,)
    diameter: np.ndarray  # (E,) largest distance between boundary vertices
    prim_next: np.ndarray | None = None  # 2D: next segment of the same loop
    prim_prev: np.ndarray | None = None  # 2D: previous segment of the same loop
    start_unsafe: np.ndarray | None = None  # 2D: start vertex repeated in the element or degenerate
    tri_adj: np.ndarray | None = None  # 3D: neighbouring triangle across each edge (see _triangle_neighbours)
    table_: np.ndarray | None = None  # per-primitive constants (see _prim_table); see .table
    cen: np.ndarray | None = None  # (S, dim) primitive centroid
    rad_: np.ndarray | None = None  # (S,) primitive within ball(cen, rad); see .rad
    hull_cat: np.ndarray | None = None  # 3D compiled path: hull_pts concatenated ...
    hull_ptr: np.ndarray | None = None  # ... and their offsets per element

    # the compiled 3D search builds its per-element tables itself: the numpy paths (and the
    # fallbacks) get them on first use
    @property
    def table(self) -> np.ndarray:
        if self.table_ is None:
            self._tables()
        return self.table_

    @property
    def rad(self) -> np.ndarray:
        if self.rad_ is None:
            self._tables()
        return self.rad_

    def _tables(self) -> None:
        ext = _compiled() if self.dim == 3 and self.prim.shape[0] else None
        if ext is None:
            self.table_ = _prim_table(self.prim)
        else:
            self.table_ = np.empty((self.prim.shape[0], 16))
            ext.tri_table(np.ascontiguousarray(self.prim), self.table_)
        self.rad_ = (
            np.linalg.norm(self.prim - self.cen[:, None], axis=2).max(1) if self.prim.size else np.zeros(0)
        )

    @property
    def convex(self) -> np.ndarray:
        """Elements equal to their convex hull (one loop in 2D, measure == hull measure)."""
        ok = np.abs(self.signed_measure) >= (1.0 - _CONVEX_TOL) * self.hull_measure
        ok &= self.hull_measure > 0
        ok &= np.array([eq is not None for eq in self.hull_eq], dtype=bool)
        if self.dim == 2:
            ok &= self.n_loops == 1
        return ok


def _ragged_arange(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row, position-in-row) for a ragged array with `counts` entries per row."""
    counts = np.asarray(counts, dtype=np.int64)
    row = np.repeat(np.arange(counts.size), counts)
    start = np.cumsum(counts) - counts
    return row, np.arange(row.size) - start[row]


def _unique(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sorted distinct values, inverse and counts, by sorting (np.unique can be far slower)."""
    order = np.argsort(x, kind="stable")
    s = x[order]
    first = np.ones(s.size, dtype=bool)
    first[1:] = s[1:] != s[:-1]
    grp = np.cumsum(first) - 1
    inv = np.empty(s.size, dtype=np.int64)
    inv[order] = grp
    return s[first], inv, np.diff(np.r_[np.flatnonzero(first), s.size])


def _triangle_neighbours(tri: np.ndarray, elem: np.ndarray, n_points: int) -> np.ndarray:
    """(S, 3): the triangle of the same element across edge k (k = 0: corners 0-1, 1: 0-2, 2: 1-2),
    or -1 when that edge is not shared by exactly two consistently oriented triangles."""
    S = tri.shape[0]
    adj = np.full((S, 3), -1, dtype=np.int64)
    if S == 0:
        return adj
    u = tri[:, [0, 0, 1]].ravel()
    v = tri[:, [1, 2, 2]].ravel()
    fwd = np.array([1, -1, 1] * S)  # edge direction along the triangle's orientation (0->1, 2->0, 1->2)
    fwd = np.where(u < v, fwd, -fwd)
    key = np.minimum(u, v) * np.int64(n_points) + np.maximum(u, v)
    el = np.repeat(elem, 3)
    if (int(elem.max()) + 1) * float(n_points) ** 2 < 2.0**62:  # one int64 key: one sort
        ks = el * np.int64(n_points) ** 2 + key
        order = np.argsort(ks)
        ks = ks[order]
        first = np.ones(order.size, dtype=bool)
        first[1:] = ks[1:] != ks[:-1]
    else:
        order = np.lexsort((key, el))
        ks, es = key[order], el[order]
        first = np.ones(order.size, dtype=bool)
        first[1:] = (ks[1:] != ks[:-1]) | (es[1:] != es[:-1])
    start = np.flatnonzero(first)
    cnt = np.diff(np.r_[start, order.size])
    pair = start[cnt == 2]
    i, j = order[pair], order[pair + 1]
    ok = fwd[i] != fwd[j]
    i, j = i[ok], j[ok]
    adj.ravel()[i] = j // 3
    adj.ravel()[j] = i // 3
    return adj


def _farthest_first(p: np.ndarray) -> tuple[np.ndarray, float]:
    """p reordered with its farthest pair first (the enclosing-ball pivoting starts from their ball),
    and the distance between them (the diameter)."""
    h = p.shape[0]
    if h < 2:
        return p, 0.0
    best, i, j = -1.0, 0, 0
    for r0 in range(0, h, 256):  # blocks of rows: memory stays O(256 h) for a huge hull
        dp = p[r0 : r0 + 256, None, :] - p[None, :, :]
        d2 = np.einsum("ijk,ijk->ij", dp, dp)
        k = int(d2.argmax())
        if d2.flat[k] > best:
            best = float(d2.flat[k])
            i, j = r0 + k // h, k % h
    rest = np.ones(h, dtype=bool)
    rest[[i, j]] = False
    return np.concatenate([p[[i, j]], p[rest]]), float(np.linalg.norm(p[i] - p[j]))


def _hulls_qhull(vpts: np.ndarray, v_ptr: np.ndarray, dim: int):
    """Convex hull (vertices, facet equations, measure) and diameter of each element: one qhull call
    per element."""
    from scipy.spatial import ConvexHull  # here, not at import: the hierarchy writer imports this module

    n = v_ptr.size - 1
    hull_pts, hull_eq = [], []
    hull_measure = np.zeros(n)
    diameter = np.zeros(n)
    for e in range(n):
        p = vpts[v_ptr[e] : v_ptr[e + 1]]
        eq = None
        if p.shape[0] > dim:
            try:
                h = ConvexHull(p)
                p, eq = p[h.vertices], h.equations
                hull_measure[e] = h.volume
            except Exception:  # flat / degenerate element: keep all its points, no hull
                pass
        p, diameter[e] = _farthest_first(p)
        hull_pts.append(p)
        hull_eq.append(eq)
    return hull_pts, hull_eq, hull_measure, diameter


def _farthest_pairs(ext, vpts: np.ndarray, v_ptr: np.ndarray):
    """3D without hulls: every element's boundary vertices with its farthest pair first (the
    enclosing-ball pivoting starts from it) and the diameter, the pair found by the compiled
    brute force (the same pair and distance as over the hull's vertices)."""
    n = v_ptr.size - 1
    i = np.zeros(n, dtype=np.int64)
    j = np.zeros(n, dtype=np.int64)
    diameter = np.zeros(n)
    ext.farthest_pairs(
        np.ascontiguousarray(vpts, dtype=np.float64), np.ascontiguousarray(v_ptr), i, j, diameter
    )
    # the pair to positions 0 and 1 of each set: two swaps of a permutation (sets are disjoint)
    perm = np.arange(vpts.shape[0])
    two = np.flatnonzero(np.diff(v_ptr) >= 2)
    s0 = v_ptr[two]
    a, b = s0 + i[two], s0 + j[two]
    tmp = perm[s0].copy()
    perm[s0] = perm[a]
    perm[a] = tmp
    b = np.where(b == s0, a, b)  # the second point moved if it sat in position 0
    tmp = perm[s0 + 1].copy()
    perm[s0 + 1] = perm[b]
    perm[b] = tmp
    p = vpts[perm]
    pts = [p[v_ptr[e] : v_ptr[e + 1]] for e in range(n)]
    return pts, diameter, p


def _convex_3d(ext, prim_ptr, prim, adj, signed, v_ptr, diameter):
    """Convex 3D elements without hulls: a closed, consistently oriented triangulated surface (every
    edge shared by two triangles) of a sphere's topology (V - E + F = 2) whose every edge is
    convex (the neighbour's corners on the inner side of each triangle's plane, to 1e-10 x the
    diameter; compiled) bounds a convex body. Returns hull_eq (the element's own triangle planes,
    outward, for the Chebyshev-centre LP; None where not convex) and hull_measure (|volume| where
    convex, 0 elsewhere), as _hulls_qhull gives them for _Geometry.convex."""
    n = prim_ptr.size - 1
    out_sign = np.where(signed >= 0, 1.0, -1.0)
    local = np.zeros(n, dtype=np.uint8)
    ext.locally_convex(prim, np.ascontiguousarray(adj), prim_ptr, out_sign, 1e-10 * diameter, local)
    F = np.diff(prim_ptr)
    V = np.diff(v_ptr)
    convex = (local == 1) & (2 * V - F == 4) & (signed != 0)
    hull_measure = np.where(convex, np.abs(signed), 0.0)
    hull_eq = [None] * n
    for e in np.flatnonzero(convex):  # convex 3D elements are rare (a Python loop over those only)
        rows = _prim_table(prim[prim_ptr[e] : prim_ptr[e + 1]])
        nrm = out_sign[e] * rows[:, 9:12]
        eq = np.column_stack([nrm, -np.einsum("ij,ij->i", nrm, rows[:, 0:3])])
        hull_eq[e] = eq[np.linalg.norm(nrm, axis=1) > 0.5]  # degenerate triangles have no plane
    return hull_eq, hull_measure


def _chains_2d(pts: np.ndarray, grp: np.ndarray) -> np.ndarray:
    """Indices (into pts) of the lower convex chain of every group, in order. pts are sorted by
    group, then lexicographically (x, y). A point on or above the segment joining its two current
    chain neighbours (within rounding) is no hull vertex, so all such points go at once, pass after
    pass (Andrew's monotone chain without its stack)."""
    # coincident points once only (two copies of a hull vertex would each look removable)
    dup = np.zeros(pts.shape[0], dtype=bool)
    dup[1:] = (grp[1:] == grp[:-1]) & np.all(pts[1:] == pts[:-1], axis=1)
    idx = np.flatnonzero(~dup)
    while idx.size > 2:
        q, gr = pts[idx], grp[idx]
        mid = np.flatnonzero((gr[1:-1] == gr[:-2]) & (gr[1:-1] == gr[2:])) + 1
        a, b, c = q[mid - 1], q[mid], q[mid + 1]
        cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - b[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - b[:, 0])
        ab, bc = np.hypot(*(b - a).T), np.hypot(*(c - b).T)
        drop = mid[cross <= 1e-12 * ab * bc]  # collinear within rounding counts as "not a vertex"
        if drop.size == 0:
            break
        keep = np.ones(idx.size, dtype=bool)
        keep[drop] = False
        idx = idx[keep]
    return idx


def _hulls_2d(vpts: np.ndarray, v_ptr: np.ndarray):
    """_hulls_qhull for 2D, vectorized over the elements: counter-clockwise hull vertices, edge
    equations n.x + b <= 0 inside (|n| = 1), area and diameter (rotating-free: all hull pairs)."""
    n = v_ptr.size - 1
    elem = np.repeat(np.arange(n), np.diff(v_ptr))
    up = np.lexsort((vpts[:, 1], vpts[:, 0], elem))
    down = np.lexsort((-vpts[:, 1], -vpts[:, 0], elem))
    lower = up[_chains_2d(vpts[up], elem[up])]
    upper = down[_chains_2d(vpts[down], elem[down])]
    # lower chain left to right, then the upper one right to left without its two ends
    le, ue = elem[lower], elem[upper]
    inner = np.ones(upper.size, dtype=bool)
    inner[_row_starts(ue)] = False
    inner[np.r_[_row_starts(ue)[1:], ue.size] - 1] = False
    hv = np.concatenate([lower, upper[inner]])
    he = np.concatenate([le, ue[inner]])
    rank = np.concatenate([np.arange(le.size), le.size + np.arange(int(inner.sum()))])
    order = np.lexsort((rank, he))
    hv, he = hv[order], he[order]
    hp = vpts[hv]
    cnt = np.bincount(he, minlength=n)
    hptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(cnt, out=hptr[1:])
    nxt = np.arange(hv.size) + 1
    nxt[hptr[1:][cnt > 0] - 1] = hptr[:-1][cnt > 0]
    a, b = hp, hp[nxt]
    area = 0.5 * np.bincount(he, a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], minlength=n)
    d = b - a
    ln = np.linalg.norm(d, axis=1)
    nrm = np.column_stack([d[:, 1], -d[:, 0]]) / np.where(ln > 0, ln, 1.0)[:, None]
    eq = np.column_stack([nrm, -np.einsum("ij,ij->i", nrm, a)])
    # diameter: farthest pair among each element's hull vertices (all pairs, in one ragged batch;
    # hulls of more than 256 vertices go block by block in _farthest_first below)
    small = cnt[he] <= 256
    pr, pos = _ragged_arange(np.where(small, cnt[he], 0))
    i = np.repeat(np.arange(hv.size), np.where(small, cnt[he], 0))
    j = hptr[he][pr] + pos
    dd = ((hp[i] - hp[j]) ** 2).sum(1)
    best = _group_argmax(he[i], dd)
    diameter = np.zeros(n)
    diameter[he[i[best]]] = np.sqrt(dd[best])
    # farthest pair first in each element's vertex list (see _farthest_first): one permutation
    rank = np.arange(hv.size, dtype=np.float64)
    rank[i[best]], rank[j[best]] = -2.0, -1.0
    perm = np.lexsort((rank, he))
    pts_split = np.split(hp[perm], hptr[1:-1])
    eq_split = np.split(eq, hptr[1:-1])
    hull_measure = np.where(cnt >= 3, area, 0.0)
    hull_pts = [p if c >= 3 else None for p, c in zip(pts_split, cnt, strict=True)]
    hull_eq = [q if c >= 3 else None for q, c in zip(eq_split, cnt, strict=True)]
    for e in np.flatnonzero(
        cnt < 3
    ):  # collinear / single point: no hull, all its points (as qhull's failure)
        hull_pts[e], diameter[e] = _farthest_first(vpts[v_ptr[e] : v_ptr[e + 1]])
    for e in np.flatnonzero(cnt > 256):
        hull_pts[e], diameter[e] = _farthest_first(hull_pts[e])
    return hull_pts, hull_eq, hull_measure, diameter


def _prepare_3d_compiled(ext, pts, eo, lo, nodes) -> _Geometry:
    """_prepare in 3D with the compiled module: the same geometry (triangles in the same Morton
    order, the same neighbours, vertices, boxes and diameters), without hulls (see _farthest_pairs
    and _convex_3d) and with the triangle table left to first use."""
    n = eo.size - 1
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    S = int(np.maximum(np.diff(lo) - 2, 0).sum())
    prim = np.empty((S, 3, 3))
    cen = np.empty((S, 3))
    prim_ptr = np.zeros(n + 1, dtype=np.int64)
    adj = np.empty((S, 3), dtype=np.int64)
    size = np.zeros(n)
    signed = np.zeros(n)
    vpts = np.empty((nodes.size, 3))
    v_ptr = np.zeros(n + 1, dtype=np.int64)
    bbox_lo = np.full((n, 3), np.nan)
    bbox_hi = np.full((n, 3), np.nan)
    nv = ext.fan3d(
        pts,
        eo,
        lo,
        np.ascontiguousarray(nodes),
        prim,
        cen,
        prim_ptr,
        adj,
        size,
        signed,
        vpts,
        v_ptr,
        bbox_lo,
        bbox_hi,
    )
    vpts = vpts[:nv]
    hull_pts, diameter, hull_cat = _farthest_pairs(ext, vpts, v_ptr)
    hull_eq, hull_measure = _convex_3d(ext, prim_ptr, prim, adj, signed, v_ptr, diameter)
    return _Geometry(
        3,
        n,
        prim,
        np.repeat(np.arange(n), np.diff(prim_ptr)),
        prim_ptr,
        size,
        signed,
        np.diff(eo),
        bbox_lo,
        bbox_hi,
        hull_pts,
        hull_eq,
        hull_measure,
        diameter,
        tri_adj=adj,
        cen=cen,
        hull_cat=hull_cat,
        hull_ptr=v_ptr,
    )


def _prepare(poly: PolyMesh) -> _Geometry:
    pts = np.asarray(poly.points, dtype=np.float64)
    dim = pts.shape[1]
    if dim not in (2, 3):
        raise ParameterError(f"metrics need 2D or 3D points, got dimension {dim}")
    eo = np.asarray(poly.elem_offsets, dtype=np.int64)
    lo = np.asarray(poly.loop_offsets, dtype=np.int64)
    nodes = np.asarray(poly.loop_nodes, dtype=np.int64)
    n = eo.size - 1
    loop_elem = np.repeat(np.arange(n), np.diff(eo))
    loop_len = np.diff(lo)
    node_elem = np.repeat(loop_elem, loop_len)

    if dim == 2:
        nxt = np.arange(nodes.size) + 1
        nonempty = loop_len > 0
        nxt[lo[1:][nonempty] - 1] = lo[:-1][nonempty]
        prv = np.empty_like(nxt)
        prv[nxt] = np.arange(nxt.size)
        p = pts[nodes]
        a, b = p, p[nxt]
        seg_len = np.linalg.norm(b - a, axis=1)
        size = np.bincount(node_elem, seg_len, minlength=n)
        signed = 0.5 * np.bincount(node_elem, a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], minlength=n)
        _, inv, cnt = _unique(node_elem * np.int64(pts.shape[0]) + nodes)
        pinch = cnt[inv] > 1
        # drop vertices in the middle of a straight run (staircase boundaries of structured meshes):
        # the boundary, hence every distance and inside test, is unchanged
        din, dout = p - p[prv], b - p
        cross = din[:, 0] * dout[:, 1] - din[:, 1] * dout[:, 0]
        straight = (np.abs(cross) <= 1e-14 * seg_len[prv] * seg_len) & (np.einsum("ij,ij->i", din, dout) > 0)
        loop_id = np.repeat(np.arange(loop_len.size), loop_len)
        straight &= ~pinch
        straight &= (np.bincount(loop_id, ~straight, minlength=loop_len.size) >= 3)[loop_id]
        kept = np.flatnonzero(~straight)
        kl = loop_id[kept]
        first = np.ones(kept.size, dtype=bool)
        first[1:] = kl[1:] != kl[:-1]
        start = np.flatnonzero(first)
        last = np.r_[start[1:], kept.size] - 1
        knext = np.arange(kept.size) + 1
        knext[last] = start
        kprev = np.empty_like(knext)
        kprev[knext] = np.arange(knext.size)
        prim = np.stack([p[kept], p[kept][knext]], axis=1)  # (S, 2, 2)
        prim_elem = node_elem[kept]
        klen = np.linalg.norm(prim[:, 1] - prim[:, 0], axis=1)
        unsafe = pinch[kept] | (klen == 0) | (klen[kprev] == 0)
        extra = {"prim_next": knext, "prim_prev": kprev, "start_unsafe": unsafe}
    else:
        ext = _compiled()
        if ext is not None:
            return _prepare_3d_compiled(ext, pts, eo, lo, nodes)
        ntri = np.maximum(loop_len - 2, 0)
        face, j = _ragged_arange(ntri)
        base = lo[:-1][face]
        prim = np.stack([pts[nodes[base]], pts[nodes[base + j + 1]], pts[nodes[base + j + 2]]], axis=1)
        prim_elem = loop_elem[face]
        a, b, c = prim[:, 0], prim[:, 1], prim[:, 2]
        cr = np.cross(b - a, c - a)
        size = np.bincount(prim_elem, 0.5 * np.linalg.norm(cr, axis=1), minlength=n)
        signed = np.bincount(prim_elem, np.einsum("ij,ij->i", a, np.cross(b, c)), minlength=n) / 6.0
        extra = {"tri_nodes": np.column_stack([nodes[base], nodes[base + j + 1], nodes[base + j + 2]])}
    prim_ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(prim_elem, minlength=n), out=prim_ptr[1:])

    # distinct boundary vertices per element, grouped by element
    key = _unique(node_elem * np.int64(pts.shape[0]) + nodes)[0]
    v_elem, v_node = np.divmod(key, np.int64(pts.shape[0]))
    v_ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(v_elem, minlength=n), out=v_ptr[1:])
    vpts = pts[v_node]
    bbox_lo = np.full((n, dim), np.nan)
    bbox_hi = np.full((n, dim), np.nan)
    has = v_ptr[1:] > v_ptr[:-1]
    if vpts.size:
        bbox_lo[has] = np.minimum.reduceat(vpts, v_ptr[:-1][has], axis=0)
        bbox_hi[has] = np.maximum.reduceat(vpts, v_ptr[:-1][has], axis=0)

    if dim == 2:
        hull_pts, hull_eq, hull_measure, diameter = _hulls_2d(vpts, v_ptr)
    else:
        hull_pts, hull_eq, hull_measure, diameter = _hulls_qhull(vpts, v_ptr, dim)
    cen = prim.mean(axis=1)
    # order the primitives of each element along a Morton curve (spatially coherent runs for the
    # bounding-ball hierarchy used by the inscribed-ball search)
    if prim.shape[0]:
        span = np.maximum(bbox_hi - bbox_lo, 1e-300)[prim_elem]
        bits = 16 if dim == 2 else 10
        ic = np.clip(
            ((cen - bbox_lo[prim_elem]) / span * ((1 << bits) - 1)).astype(np.int64), 0, (1 << bits) - 1
        )
        # interleave the bits with one table lookup per axis (bit b of axis k -> bit b * dim + k)
        v = np.arange(1 << bits, dtype=np.int64)
        spread = np.zeros(1 << bits, dtype=np.int64)
        for b in range(bits):
            spread |= ((v >> b) & 1) << (b * dim)
        code = prim_elem.astype(np.int64) << (bits * dim)  # elements first (fits: bits * dim <= 32)
        for k in range(dim):
            code |= spread[ic[:, k]] << k
        perm = np.argsort(code, kind="stable")
        inv = np.empty_like(perm)
        inv[perm] = np.arange(perm.size)
        prim, prim_elem, cen = prim[perm], prim_elem[perm], cen[perm]
        if dim == 2:
            extra = {
                "prim_next": inv[extra["prim_next"][perm]],
                "prim_prev": inv[extra["prim_prev"][perm]],
                "start_unsafe": extra["start_unsafe"][perm],
            }
        else:
            extra = {"tri_adj": _triangle_neighbours(extra["tri_nodes"][perm], prim_elem, pts.shape[0])}
    elif dim == 3:
        extra = {"tri_adj": np.zeros((0, 3), dtype=np.int64)}
    rad = np.linalg.norm(prim - cen[:, None], axis=2).max(1) if prim.size else np.zeros(0)
    table = _prim_table(prim)
    return _Geometry(
        dim,
        n,
        prim,
        prim_elem,
        prim_ptr,
        size,
        signed,
        np.diff(eo),
        bbox_lo,
        bbox_hi,
        hull_pts,
        hull_eq,
        hull_measure,
        diameter,
        table_=table,
        cen=cen,
        rad_=rad,
        **extra,
    )


# --------------------------------------------------------------------------------------------------
# smallest enclosing ball (exact)


def _circumballs(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest ball through all k+1 points of each set q (m, k+1, d), centre in their affine hull.

    Returns centres (m, d) and squared radii (m,), +inf where the points are affinely dependent.
    """
    m, kp1, d = q.shape
    if kp1 == 1:
        return q[:, 0].copy(), np.zeros(m)
    A = q[:, 1:] - q[:, :1]  # (m, k, d)
    G = np.einsum("mid,mjd->mij", A, A)
    rhs = 0.5 * np.einsum("mii->mi", G)
    det = np.linalg.det(G)
    scale = np.prod(np.einsum("mii->mi", G), axis=1)
    ok = np.abs(det) > 1e-12 * scale
    G[~ok] = np.eye(kp1 - 1)
    lam = np.linalg.solve(G, rhs[..., None])[..., 0]
    off = np.einsum("mi,mid->md", lam, A)
    r2 = np.where(ok, np.einsum("md,md->m", off, off), np.inf)
    return q[:, 0] + off, r2


def _miniball_small(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact smallest enclosing ball of each small set T (m, d+2, d) by enumerating supports.

    Returns centre (m, d), squared radius (m,), support (m, d+1, d) (points repeated to fill).
    """
    m, npt, d = T.shape
    best_c = np.zeros((m, d))
    best_r2 = np.full(m, np.inf)
    best_s = np.repeat(T[:, :1], d + 1, axis=1)
    for k in range(1, d + 2):
        for sub in itertools.combinations(range(npt), k):
            c, r2 = _circumballs(T[:, sub])
            dist2 = ((T - c[:, None]) ** 2).sum(-1).max(1)
            valid = dist2 <= r2 * (1 + 1e-12) + 1e-300
            better = valid & (r2 < best_r2)
            if better.any():
                best_c[better], best_r2[better] = c[better], r2[better]
                fill = list(sub) + [sub[0]] * (d + 1 - k)
                best_s[better] = T[better][:, fill]
    return best_c, best_r2, best_s


def _enclosing_balls(sets: list[np.ndarray], dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact smallest enclosing balls of many point sets at once (pivoting, Gaertner 1999).

    Start from one point; repeatedly take the farthest point outside the current ball and replace
    the ball by the smallest ball of {its support (<= d+1 points)} + {that point}. The radius grows
    strictly, so this ends on the exact ball (the move-to-front/pivoting variant of Welzl).
    """
    m = len(sets)
    centre = np.zeros((m, dim))
    r2 = np.zeros(m)
    sizes = np.array([s.shape[0] for s in sets], dtype=np.int64)
    live = np.flatnonzero(sizes > 0)
    if live.size == 0:
        return centre, np.sqrt(r2)
    H = int(sizes.max())
    P = np.empty((live.size, H, dim))
    for i, e in enumerate(live):  # pad with the first point (harmless duplicates)
        P[i, : sizes[e]] = sets[e]
        P[i, sizes[e] :] = sets[e][0]
    # start from the smallest ball of the first two points (the element's farthest pair, see
    # _prepare: usually close to the answer); any set's smallest ball is a valid start
    c = 0.5 * (P[:, 0] + P[:, 1]) if H > 1 else P[:, 0].copy()
    rr = ((P[:, 0] - c) ** 2).sum(-1)
    support = (
        np.concatenate([P[:, :2], np.repeat(P[:, 1:2], dim - 1, axis=1)], axis=1)
        if H > 1
        else np.repeat(P[:, :1], dim + 1, axis=1)
    )
    active = np.arange(live.size)
    for _ in range(1000):
        d2 = ((P[active] - c[active, None]) ** 2).sum(-1)
        j = d2.argmax(1)
        far = d2[np.arange(active.size), j]
        out = far > rr[active] * (1 + 1e-10) + 1e-300
        active, j = active[out], j[out]
        if active.size == 0:
            break
        T = np.concatenate([support[active], P[active, j][:, None]], axis=1)
        cn, rn, sn = _miniball_small(T)
        c[active], rr[active], support[active] = cn, rn, sn
    # radius as the actual farthest distance: the ball always encloses every point
    rr = ((P - c[:, None]) ** 2).sum(-1).max(1)
    centre[live], r2[live] = c, rr
    return centre, np.sqrt(r2)


def smallest_enclosing_ball(pts: np.ndarray) -> tuple[np.ndarray, float]:
    """Exact smallest ball enclosing `pts` (n, d), d = 2 or 3; computed on the convex hull vertices."""
    pts = np.asarray(pts, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[0] == 0:
        raise ParameterError("smallest_enclosing_ball needs a non-empty (n, d) array")
    dim = pts.shape[1]
    if pts.shape[0] > dim + 1:
        from scipy.spatial import ConvexHull

        try:
            pts = pts[ConvexHull(pts).vertices]
        except Exception:  # degenerate (collinear / coplanar): use every point
            pass
    c, r = _enclosing_balls([pts], dim)
    return c[0], float(r[0])


# --------------------------------------------------------------------------------------------------
# distances from points to element boundaries


_LOC_INTERIOR, _LOC_START, _LOC_END, _LOC_RIM = 0, 1, 2, 3


def _prim_table(prim: np.ndarray) -> np.ndarray:
    """Per-primitive constants for _prim_distance, one row each (gathered with a single np.take).

    2D: ax, ay, abx, aby, 1/|ab|^2 (0 when degenerate).
    3D: a (3), e0 = b - a (3), e1 = c - a (3), unit normal (3), e0.e0, e0.e1, e1.e1, 1/det (0 when
    degenerate).
    """
    if prim.shape[1] == 2:
        a = prim[:, 0]
        ab = prim[:, 1] - a
        L2 = np.einsum("ij,ij->i", ab, ab)
        inv = np.divide(1.0, L2, out=np.zeros_like(L2), where=L2 > 0)
        return np.column_stack([a, ab, inv])
    a = prim[:, 0]
    e0 = prim[:, 1] - a
    e1 = prim[:, 2] - a
    nrm = np.cross(e0, e1)
    nn = np.linalg.norm(nrm, axis=1)
    nrm = nrm / np.where(nn > 0, nn, 1.0)[:, None]
    d00 = np.einsum("ij,ij->i", e0, e0)
    d01 = np.einsum("ij,ij->i", e0, e1)
    d11 = np.einsum("ij,ij->i", e1, e1)
    det = d00 * d11 - d01 * d01
    inv = np.divide(1.0, det, out=np.zeros_like(det), where=det > 1e-14 * d00 * d11)
    return np.column_stack([a, e0, e1, nrm, d00, d01, d11, inv])


def _segment_offset(T: np.ndarray, q: np.ndarray):
    """2D, rows T of _prim_table: unclipped parameter t of the projection of q on each segment, and
    (dx, dy) = q - its closest point on the segment."""
    abx, aby = T[:, 2], T[:, 3]
    dx = q[:, 0] - T[:, 0]
    dy = q[:, 1] - T[:, 1]
    t = (dx * abx + dy * aby) * T[:, 4]
    tc = np.clip(t, 0.0, 1.0)
    dx -= tc * abx
    dy -= tc * aby
    return t, dx, dy


def _triangle_projection(T: np.ndarray, q: np.ndarray):
    """3D, rows T of _prim_table: v = q - a, barycentric coordinates (bv, bw) of q's projection on
    the triangle's plane, its signed height h along the unit normal, and whether the projection
    falls inside the (non-degenerate) triangle."""
    v = q - T[:, 0:3]
    d00, d01, d11, inv = T[:, 12], T[:, 13], T[:, 14], T[:, 15]
    d20 = np.einsum("ij,ij->i", v, T[:, 3:6])
    d21 = np.einsum("ij,ij->i", v, T[:, 6:9])
    bv = (d11 * d20 - d01 * d21) * inv
    bw = (d00 * d21 - d01 * d20) * inv
    h = np.einsum("ij,ij->i", v, T[:, 9:12])
    inside = (inv > 0) & (bv >= 0) & (bw >= 0) & (bv + bw <= 1)
    return bv, bw, h, inside


def _rim_closest(T: np.ndarray, q: np.ndarray, what: int = 3):
    """3D: closest point of each triangle's rim (its three edges) to q. Returns the squared
    distance, q minus that point, and the edge (0: corners 0-1, 1: 0-2, 2: 1-2) when the point
    lies strictly inside it (-1 at a corner); the first edge wins ties. what = 1: the squared
    distance only; 2: and the vector; 3: all three."""
    a, e0, e1 = T[:, 0:3], T[:, 3:6], T[:, 6:9]
    m = _INTERIOR_MARGIN
    best = vec = edge = None
    for k, (s0, t) in enumerate(((a, e0), (a, e1), (a + e0, e1 - e0))):
        w = q - s0
        tt = np.einsum("ij,ij->i", w, t) / np.maximum(np.einsum("ij,ij->i", t, t), 1e-300)
        w -= np.clip(tt, 0, 1)[:, None] * t  # w: q minus the closest point of edge k
        dd = np.einsum("ij,ij->i", w, w)
        if k == 0:
            best = dd
            vec = w if what >= 2 else None
            if what >= 3:
                edge = np.where((tt > m) & (tt < 1 - m), 0, -1)
            continue
        better = dd < best
        best = np.where(better, dd, best)
        if what >= 2:
            vec = np.where(better[:, None], w, vec)
        if what >= 3:
            edge = np.where(better, np.where((tt > m) & (tt < 1 - m), k, -1), edge)
    return best, vec, edge


def _prim_distance(g: _Geometry, q: np.ndarray, p: np.ndarray, T: np.ndarray | None = None):
    """Squared distance from points q (n, d) to primitives p (n,), where the closest point lies, side.

    loc: _LOC_INTERIOR (inside the segment / triangle, off its rim), _LOC_START / _LOC_END (2D: a
    segment end), _LOC_RIM (3D: a triangle edge or corner). side: q is on the inner side of the
    primitive's oriented line / plane (meaningful for loc == _LOC_INTERIOR).
    """
    m = _INTERIOR_MARGIN
    if T is None:
        T = np.take(g.table, p, axis=0)
    if g.dim == 2:
        t, dx, dy = _segment_offset(T, q)
        loc = (t <= m).astype(np.int8)  # _LOC_START (also for a degenerate segment: t = 0)
        loc[t >= 1 - m] = _LOC_END
        side = T[:, 2] * (q[:, 1] - T[:, 1]) - T[:, 3] * (q[:, 0] - T[:, 0]) > 0
        return dx * dx + dy * dy, loc, side
    bv, bw, h, proj_in = _triangle_projection(T, q)
    d2 = h * h
    rim = np.flatnonzero(~proj_in)
    if rim.size:
        d2[rim] = _rim_closest(T[rim], q[rim], 1)[0]
    bu = 1.0 - bv - bw
    interior = proj_in & (bu > m) & (bv > m) & (bw > m)
    loc = np.where(interior, _LOC_INTERIOR, _LOC_RIM).astype(np.int8)
    return d2, loc, h < 0


def _segment_distance2(g: _Geometry, q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """2D: squared distance from points q (n, 2) to segments p (n,) (_prim_distance without flags)."""
    _, dx, dy = _segment_offset(np.take(g.table, p, axis=0), q)
    return dx * dx + dy * dy


def _offset_to_closest(g: _Geometry, q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """q - y, y the point of primitive p closest to q (rows of q (n, d), p (n,))."""
    T = np.take(g.table, p, axis=0)
    if g.dim == 2:
        _, dx, dy = _segment_offset(T, q)
        return np.column_stack([dx, dy])
    _, _, h, inside = _triangle_projection(T, q)
    out = T[:, 9:12] * h[:, None]
    rim = np.flatnonzero(~inside)
    if rim.size:
        out[rim] = _rim_closest(T[rim], q[rim], 2)[1]
    return out


def _edge_inside(g: _Geometry, q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """3D, closest point of triangle p on its rim: +1 inside / -1 outside when it lies inside an
    edge shared with one other triangle (side of the edge pseudo-normal n1 + n2, exact for a
    closed surface), 0 when undecided (a corner, a non-manifold edge)."""
    T = np.take(g.table, p, axis=0)
    best, vec, edge = _rim_closest(T, q)
    out = np.zeros(p.size, dtype=np.int8)
    on = np.flatnonzero(edge >= 0)
    other = g.tri_adj[p[on], edge[on]]
    ok = other >= 0
    on, other = on[ok], other[ok]
    ns = T[on, 9:12] + g.table[other, 9:12]
    s = np.einsum("ij,ij->i", vec[on], ns)
    sure = np.abs(s) > 1e-9 * np.sqrt(best[on]) * np.linalg.norm(ns, axis=1)
    out[on[sure]] = np.where(s[sure] < 0, 1, -1)
    return out


def _cell_bounds(g: _Geometry, fc: np.ndarray, half: np.ndarray, rows: np.ndarray, prims: np.ndarray):
    """Upper bounds of max over the cell of the distance to the boundary, from several boundary points.

    Cells: centre fc[r], half side half[r]; (rows, prims), sorted by row: a few primitives close
    to each cell. With y_i the closest point of primitive i, D_i = |c - y_i|, u_i = (c - y_i) / D_i,
    for x = c + delta in the cell, d(x) <= |x - y_i| <= D_i + u_i.delta + |delta|^2 / (2 D_i).
    Any convex combination of these bounds the minimum, so max over the cell is at most
    sum l_i D_i + half * |sum l_i u_i|_1 + rho^2 sum l_i / (2 D_i). Single points use the exact
    farthest corner instead; pairs of points take the best l on their segment (a breakpoint of
    the 1-norm). Balanced contacts (a ridge between two walls) give a second-order bound.
    """
    n = fc.shape[0]
    out = np.full(n, np.inf)
    if rows.size == 0:
        return out
    v = _offset_to_closest(g, np.take(fc, rows, axis=0), prims)
    D = np.sqrt(np.einsum("ij,ij->i", v, v))
    # keep _BOUND_POINTS distinct closest points per row (a vertex or an edge shared by several
    # triangles shows up once per triangle, next to each other in distance order)
    dup = np.zeros(rows.size, dtype=bool)
    dup[1:] = (rows[1:] == rows[:-1]) & (np.linalg.norm(v[1:] - v[:-1], axis=1) <= 1e-9 * (D[1:] + D[:-1]))
    k = np.flatnonzero(~dup)
    rows, v, D = rows[k], v[k], D[k]
    st = _row_starts(rows)
    k = np.flatnonzero(
        np.arange(rows.size) - np.repeat(st, np.diff(np.r_[st, rows.size])) < _BOUND_POINTS_FW[g.dim]
    )
    rows, v, D = rows[k], v[k], D[k]
    h = np.take(half, rows)
    single = np.sqrt(((np.abs(v) + h[:, None]) ** 2).sum(1))
    st = _row_starts(rows)
    out[rows[st]] = np.minimum.reduceat(single, st)
    ok = D > 0
    u = v / np.where(ok, D, 1.0)[:, None]
    # pairs within each row (one value per row and pair: plain assignment)
    cnt = np.diff(np.r_[st, rows.size])
    kmax = min(int(cnt.max()), _BOUND_POINTS)
    for i in range(kmax):
        for j in range(i + 1, kmax):
            has = np.flatnonzero(cnt > j)
            a_, b_ = st[has] + i, st[has] + j
            good = ok[a_] & ok[b_]
            a_, b_, r_ = a_[good], b_[good], rows[a_[good]]
            if a_.size == 0:
                continue
            ua, ub_ = u[a_], u[b_]
            den = ub_ - ua
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = np.where(den != 0, ub_ / den, 0.0)
            lam = np.clip(np.column_stack([np.zeros(a_.size), np.ones(a_.size), lam]), 0.0, 1.0)
            rho2 = (h[a_] ** 2) * g.dim
            w = lam[:, :, None] * ua[:, None, :] + (1 - lam[:, :, None]) * ub_[:, None, :]
            val = (
                lam * D[a_, None]
                + (1 - lam) * D[b_, None]
                + h[a_, None] * np.abs(w).sum(2)
                + rho2[:, None] * (lam / (2 * D[a_, None]) + (1 - lam) / (2 * D[b_, None]))
            )
            out[r_] = np.minimum(out[r_], val.min(1))
    # all points of a row: Frank-Wolfe on F(l) = sum l_i D_i + half sqrt(d) |sum l_i u_i|_2 (a
    # smooth stand-in for the bound), line search on a grid; any l in the simplex gives a valid
    # bound, balanced contacts around the cell a sharp one
    big = np.flatnonzero(cnt >= 3)
    if big.size and _FW_STEPS[g.dim]:
        m = int(cnt[big].max())
        idx = st[big][:, None] + np.minimum(np.arange(m)[None, :], cnt[big][:, None] - 1)  # pad: repeat
        U, Dp, okp = u[idx], D[idx], ok[idx].all(1)
        hb = h[st[big]]
        w = hb * math.sqrt(g.dim)
        lam = np.zeros((big.size, m))
        lam[:, 0] = 1.0
        x = U[:, 0].copy()
        ld = Dp[:, 0].copy()
        ar = np.arange(big.size)
        gam = np.linspace(0.0, 1.0, 17)
        for _ in range(_FW_STEPS[g.dim]):
            nx = np.linalg.norm(x, axis=1)
            grad = Dp + (w / np.where(nx > 0, nx, 1.0))[:, None] * np.einsum("rmd,rd->rm", U, x)
            j = grad.argmin(1)
            step = U[ar, j] - x
            dd = Dp[ar, j] - ld
            trial = (
                ld[:, None]
                + gam[None, :] * dd[:, None]
                + w[:, None] * np.linalg.norm(x[:, None, :] + gam[None, :, None] * step[:, None, :], axis=2)
            )
            gb = gam[trial.argmin(1)]
            x += gb[:, None] * step
            ld += gb * dd
            lam *= (1.0 - gb)[:, None]
            lam[ar, j] += gb
        with np.errstate(divide="ignore", invalid="ignore"):
            val = (
                (lam * Dp).sum(1)
                + hb * np.abs(x).sum(1)
                + (hb**2) * g.dim * (lam / (2.0 * np.where(Dp > 0, Dp, 1.0))).sum(1)
            )
        r_ = rows[st[big]][okp]
        out[r_] = np.minimum(out[r_], val[okp])
    return out


def _wedge_inside(g: _Geometry, q: np.ndarray, s: np.ndarray, at_end: np.ndarray) -> np.ndarray:
    """2D: is q inside, given that its closest boundary point is the start (or end) vertex of s.

    The open segment from q to that vertex v misses the boundary, so q is inside iff q - v points
    into the interior angle at v, swept counter-clockwise from the outgoing to the reversed incoming
    edge (the interior is on the left of every edge, holes included).
    """
    s_in = np.where(at_end, s, g.prim_prev[s])
    s_out = np.where(at_end, g.prim_next[s], s)
    v = g.prim[s_out, 0]
    d_out = g.prim[s_out, 1] - v
    d_back = g.prim[s_in, 0] - v
    u = q - v

    def angle(w):
        return np.mod(
            np.arctan2(d_out[:, 0] * w[:, 1] - d_out[:, 1] * w[:, 0], np.einsum("ij,ij->i", d_out, w)),
            2 * np.pi,
        )

    return angle(u) < angle(d_back)


def _inside_bruteforce(g: _Geometry, q: np.ndarray, elem: np.ndarray) -> np.ndarray:
    """Exact point-in-element test against every boundary primitive of the element.

    2D: even-odd crossing number (holes included). 3D: winding number from triangle solid angles.
    """
    counts = g.prim_ptr[elem + 1] - g.prim_ptr[elem]
    out = np.zeros(q.shape[0], dtype=bool)
    ptr = np.zeros(q.shape[0] + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    i0 = 0
    while i0 < q.shape[0]:
        i1 = max(int(np.searchsorted(ptr, ptr[i0] + _PAIR_CHUNK, side="right")) - 1, i0 + 1)
        row, pos = _ragged_arange(counts[i0:i1])
        p = g.prim_ptr[elem[i0:i1]][row] + pos
        x = np.take(q[i0:i1], row, axis=0)
        P = np.take(g.prim, p, axis=0)
        if g.dim == 2:
            a, b = P[:, 0], P[:, 1]
            straddle = (a[:, 1] > x[:, 1]) != (b[:, 1] > x[:, 1])
            dy = np.where(straddle, b[:, 1] - a[:, 1], 1.0)
            xint = a[:, 0] + (x[:, 1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / dy
            val = (straddle & (x[:, 0] < xint)).astype(np.float64)
            s = np.bincount(row, val, minlength=i1 - i0)
            out[i0:i1] = (s.astype(np.int64) % 2) == 1
        else:
            A, B, C = (P[:, k] - x for k in range(3))
            la, lb, lc = (np.linalg.norm(V, axis=1) for V in (A, B, C))
            num = np.einsum("ij,ij->i", A, np.cross(B, C))
            den = (
                la * lb * lc
                + np.einsum("ij,ij->i", A, B) * lc
                + np.einsum("ij,ij->i", A, C) * lb
                + np.einsum("ij,ij->i", B, C) * la
            )
            w = np.bincount(row, 2.0 * np.arctan2(num, den), minlength=i1 - i0)
            out[i0:i1] = np.abs(w) > 2.0 * np.pi
        i0 = i1
    return out


def _classify(
    g: _Geometry,
    q: np.ndarray,
    elem: np.ndarray,
    near: np.ndarray,
    loc: np.ndarray,
    side: np.ndarray,
    orient: np.ndarray,
) -> np.ndarray:
    """+1 inside / -1 outside for points q whose closest boundary primitive is `near` (with the
    loc / side flags of _prim_distance). The open segment from q to its closest boundary point
    misses the boundary, so the local geometry there decides: the primitive's side when the point
    is inside it, the vertex wedge (2D) or edge pseudo-normal (3D) on a rim; anything else (pinched
    vertex, non-manifold edge, 3D corner) falls back to the crossing / winding number."""
    st = np.zeros(q.shape[0], dtype=np.int8)
    m = loc == _LOC_INTERIOR
    st[m] = np.where(side[m] == orient[elem[m]], 1, -1)
    if g.dim == 2:
        m = ((loc == _LOC_START) & ~g.start_unsafe[near]) | (
            (loc == _LOC_END) & ~g.start_unsafe[g.prim_next[near]]
        )
        m = np.flatnonzero(m & (st == 0))
        if m.size:
            w = _wedge_inside(g, q[m], near[m], loc[m] == _LOC_END)
            st[m] = np.where(w == orient[elem[m]], 1, -1)
    else:
        m = np.flatnonzero(st == 0)
        if m.size:
            e = _edge_inside(g, q[m], near[m])
            st[m] = np.where(orient[elem[m]], e, -e)
    rest = np.flatnonzero(st == 0)
    if rest.size:
        st[rest] = np.where(_inside_bruteforce(g, q[rest], elem[rest]), 1, -1)
    return st


def _group_argmax(groups: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """Index of the largest value in each group (one index per distinct group; the first one on
    ties), in group order."""
    if groups.size == 0:
        return np.zeros(0, dtype=np.int64)
    if np.all(groups[1:] >= groups[:-1]):  # sorted groups (the usual case): no sort needed
        st = _row_starts(groups)
        mx = np.fmax.reduceat(vals, st)
        hit = np.flatnonzero(vals == np.repeat(mx, np.diff(np.r_[st, groups.size])))
        hit = hit[_row_starts(groups[hit])]
        if hit.size == st.size:  # else a group of NaNs only: the sort below handles it
            return hit
    order = np.lexsort((-vals, groups))
    g = groups[order]
    first = np.ones(g.size, dtype=bool)
    first[1:] = g[1:] != g[:-1]
    return order[first]


_FANOUT = 8
_FW_STEPS = {2: 0, 3: 4}  # Frank-Wolfe steps for the balanced combination in _cell_bounds
_LIST_WHOLE = 1.5  # a straddling node goes to the children's list whole when radius <= this * rho
_BOUND_POINTS = 6  # nearby boundary points combined pairwise in the second-order cell bound
_BOUND_POINTS_FW = {2: 6, 3: 8}  # ... and all together (Frank-Wolfe), per dimension
# second-order cell bounds apply where rho < this * distance; off in 2D, where the plain 1-Lipschitz
# bound with more (cheap) cells is twice as fast on every 2D bench mesh (brain, structured,
# Delaunay, Voronoi, holes) and finds radii at least as good
_BOUND_RHO = {2: 0.0, 3: 1.0}
_CHILD_EXACT = True
_BNB_BATCH_PRIMS = 100_000  # boundary primitives per batch of elements in the branch and bound
_DIVE = {2: False, 3: True}  # greedy dive first: pays off in 3D only (2D: 10-20% slower on the bench meshes)
_CHILD_PRUNE = {2: False, 3: True}  # bound children before evaluating them (pays off in 3D)
_CHILD_POINTS = 8  # parent's nearest primitives used to bound its children before evaluating them


@dataclass
class _BallTree:
    """Bounding-ball hierarchy over each element's primitives (nodes < S are the primitives).

    Internal nodes group _FANOUT consecutive (Morton-ordered) nodes of one element; each node's
    ball contains all its primitives. root[e] is the top node of element e.
    """

    centre: np.ndarray  # (N, d)
    radius: np.ndarray  # (N,)
    rep: np.ndarray  # (N, d) a boundary point in the node (distance to it bounds d from above)
    child_start: np.ndarray  # (N,) first child (internal nodes), children are contiguous
    child_count: np.ndarray  # (N,) 0 for primitives
    root: np.ndarray  # (E,) -1 for elements without primitives
    n_prims: int
    pack: np.ndarray | None = None  # (N, 2d+1): centre, rep, radius side by side (one gather)
    leaf3: np.ndarray | None = None  # 3D triangles: centre, radius, rep, unit normal, n.a

    def __post_init__(self):
        self.pack = np.column_stack([self.centre, self.rep, self.radius])


def _build_ball_tree(g: _Geometry) -> _BallTree:
    S = g.prim.shape[0]
    centre, radius, rep = [g.cen], [g.rad], [g.prim[:, 0]]
    cstart, ccount = [np.zeros(S, np.int64)], [np.zeros(S, np.int64)]
    root = np.full(g.n, -1, dtype=np.int64)
    ids = np.arange(S)
    elem = g.prim_elem
    base = S
    while ids.size:
        cnt = np.bincount(elem, minlength=g.n)
        single = cnt == 1
        last = np.flatnonzero(single[elem])
        root[elem[last]] = ids[last]
        multi = ~single[elem]
        ids, elem = ids[multi], elem[multi]
        if ids.size == 0:
            break
        first = np.ones(ids.size, dtype=bool)
        first[1:] = elem[1:] != elem[:-1]
        start = np.flatnonzero(first)
        rank = np.arange(ids.size) - np.repeat(start, np.diff(np.r_[start, ids.size]))
        newgrp = first | (rank % _FANOUT == 0)
        gstart = np.flatnonzero(newgrp)
        gcount = np.diff(np.r_[gstart, ids.size])
        cc = np.concatenate(centre)
        rr = np.concatenate(radius)
        m = np.add.reduceat(cc[ids], gstart, axis=0) / gcount[:, None]
        grp = np.repeat(np.arange(gstart.size), gcount)
        r = np.maximum.reduceat(np.linalg.norm(cc[ids] - m[grp], axis=1) + rr[ids], gstart)
        rp = np.concatenate(rep)[ids]
        dr = np.linalg.norm(rp - m[grp], axis=1)
        closest = np.minimum.reduceat(dr, gstart)
        hit = np.flatnonzero(dr == closest[grp])
        hit = hit[_row_starts(grp[hit])]
        centre.append(m)
        radius.append(r)
        rep.append(rp[hit])
        cstart.append(ids[gstart])
        ccount.append(gcount)
        elem = elem[gstart]
        ids = base + np.arange(gstart.size)
        base += gstart.size
    bt = _BallTree(
        np.concatenate(centre),
        np.concatenate(radius),
        np.concatenate(rep),
        np.concatenate(cstart),
        np.concatenate(ccount),
        root,
        S,
    )
    if g.dim == 3:
        nrm = g.table[:, 9:12]
        bt.leaf3 = np.column_stack(
            [g.cen, g.rad, g.prim[:, 0], nrm, np.einsum("ij,ij->i", nrm, g.prim[:, 0])]
        )
    return bt


def _group_argmin_sorted(rows: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """Index of the smallest value of each run of equal (sorted) rows."""
    st = _row_starts(rows)
    mn = np.minimum.reduceat(vals, st)
    hit = np.flatnonzero(vals == np.repeat(mn, np.diff(np.r_[st, rows.size])))
    return hit[_row_starts(rows[hit])]


def _row_starts(rows: np.ndarray) -> np.ndarray:
    first = np.ones(rows.size, dtype=bool)
    first[1:] = rows[1:] != rows[:-1]
    return np.flatnonzero(first)


def _evaluate(
    g: _Geometry, bt: _BallTree, fc: np.ndarray, rho: np.ndarray, rows: np.ndarray, nodes: np.ndarray
):
    """Exact distance from each cell centre fc[i] to its element boundary.

    (rows, nodes), sorted by row, is each cell's candidate list: ball-tree nodes covering every
    primitive within distance d + 2 rho of the parent cell. Nodes are opened top-down while they
    may hold a primitive within reach; every primitive reached gets its exact distance (3D
    triangles after a bounding-ball / plane screen). Returns distance, closest primitive, its loc
    code, the side flag, the children's candidate lists (rows, nodes), sorted by row: nodes
    covering every primitive within d_i + 2 rho_i of the centre, which (triangle inequality)
    holds everything a child, rho_i / 2 away with half-diagonal rho_i / 2, needs; and the exact
    leaf distances computed (rows, prims, distances; unsorted).
    """
    n = fc.shape[0]
    dim = g.dim
    S = bt.n_prims
    upper = np.full(n, np.inf)
    dist = np.full(n, np.inf)
    near = np.zeros(n, dtype=np.int64)
    loc = np.zeros(n, dtype=np.int8)
    side = np.zeros(n, dtype=bool)
    listed = np.zeros(rows.size, dtype=bool)
    keep_r, keep_n, leaf = [], [], []

    def row_min(rows, vals, target):
        st = _row_starts(rows)
        ur = rows[st]
        target[ur] = np.minimum(target[ur], np.minimum.reduceat(vals, st))

    def exact(lr, ln, q, ll):
        """Exact distances of leaves (rows sorted); fold them into dist/near/loc/side."""
        if lr.size == 0:
            return
        if dim == 2:  # distances of every pair, the flags of the nearest one only
            dl = np.sqrt(_segment_distance2(g, q, ln))
        else:
            d2, lc, sd = _prim_distance(g, q, ln)
            dl = np.sqrt(d2)
        leaf.append((lr, ln, dl, ll))
        k = _group_argmin_sorted(lr, dl)
        r = lr[k]
        better = np.flatnonzero(dl[k] < dist[r])
        r, k = r[better], k[better]
        if dim == 2:
            _, lk, sk = _prim_distance(g, np.take(q, k, axis=0), ln[k])
        else:
            lk, sk = lc[k], sd[k]
        dist[r], near[r], loc[r], side[r] = dl[k], ln[k], lk, sk
        np.minimum(upper, dist, out=upper)

    while rows.size:
        li = np.flatnonzero(nodes < S)
        if li.size:
            lr, ln, ll = rows[li], nodes[li], listed[li]
            q = np.take(fc, lr, axis=0)
            if dim == 3:
                # exact triangle distances are dear: first the most promising leaf of each row
                # (smallest lower bound) to tighten the upper bound, then only the leaves that
                # may still be nearer; the others within reach are listed as they are
                L = np.take(bt.leaf3, ln, axis=0)  # centre, radius, rep, unit normal, offset
                diff = q - L[:, 0:3]
                cd = np.sqrt(np.einsum("ij,ij->i", diff, diff))
                lb = np.maximum(cd - L[:, 3], np.abs(np.einsum("ij,ij->i", q, L[:, 7:10]) - L[:, 10]))
                lb -= 1e-12 * (cd + L[:, 3])
                diff = q - L[:, 4:7]
                row_min(lr, np.sqrt(np.einsum("ij,ij->i", diff, diff)), upper)
                first = _group_argmin_sorted(lr, lb)
                exact(lr[first], ln[first], np.take(q, first, axis=0), ll[first])
                u = upper[lr]
                ex = lb <= u
                ex[first] = False
                later = ~ex & ~ll & (lb <= u + 2.0 * rho[lr])
                later[first] = False
                later = np.flatnonzero(later)
                keep_r.append(lr[later])
                keep_n.append(ln[later])
                ok = np.flatnonzero(ex)
                lr, ln, ll, q = lr[ok], ln[ok], ll[ok], np.take(q, ok, axis=0)
            exact(lr, ln, q, ll)
            ii = np.flatnonzero(nodes >= S)
            rows, nodes, listed = rows[ii], nodes[ii], listed[ii]
            if rows.size == 0:
                break
        q = np.take(fc, rows, axis=0)
        nd = np.take(bt.pack, nodes, axis=0)
        diff = q - nd[:, :dim]
        cd = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        rr = nd[:, -1]
        lb = cd - rr - 1e-12 * (cd + rr)
        diff = q - nd[:, dim : 2 * dim]
        row_min(rows, np.sqrt(np.einsum("ij,ij->i", diff, diff)), upper)
        u = upper[rows]
        rh = rho[rows]
        lim = u + 2.0 * rh
        alive = lb <= lim
        # list a whole node when it lies inside the reach, or is small against the cell
        add = alive & ~listed & ((cd + rr <= lim) | (rr <= _LIST_WHOLE * rh))
        ai = np.flatnonzero(add)
        keep_r.append(rows[ai])
        keep_n.append(nodes[ai])
        listed |= add
        m = np.flatnonzero(alive & ~(listed & (lb > u)))  # open: may hold the nearest, or unlisted
        parent = nodes[m]
        row2, pos = _ragged_arange(bt.child_count[parent])
        rows = rows[m][row2]
        listed = listed[m][row2]
        nodes = bt.child_start[parent][row2] + pos
    # leaves within d + 2 rho (and not under a listed node) go to the children's lists
    for lr, ln, dl, ll in leaf:
        m = np.flatnonzero(~ll & (dl <= dist[lr] * (1 + 1e-12) + 2.0 * rho[lr]))
        keep_r.append(lr[m])
        keep_n.append(ln[m])
    kr, kn = np.concatenate(keep_r), np.concatenate(keep_n)
    order = np.argsort(kr, kind="stable")
    leaves = tuple(np.concatenate([x[k] for x in leaf]) for k in range(3))
    return dist, near, loc, side, kr[order], kn[order], leaves


def _dense_bound(V: np.ndarray, valid: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Upper bound of max over each cell of the distance to the boundary, from fixed boundary points.

    V (n, k, d): c - y_i for boundary points y_i (valid where `valid`), cell centre c, half side
    h: the exact distance from the cell's farthest corner to the nearest y_i (any boundary point's
    distance bounds the distance to the boundary from above).
    """
    out = np.sqrt(((np.abs(V) + h[:, None, None]) ** 2).sum(2))
    out[~valid] = np.inf
    return out.min(1)


def _child_prune(
    g: _Geometry,
    leaves,
    keep: np.ndarray,
    n_cells: int,
    pfc: np.ndarray,
    cfc: np.ndarray,
    cside: np.ndarray,
    nc: int,
    floor: np.ndarray,
) -> np.ndarray:
    """Children (indices into cfc, child i of kept cell keep[i // nc]) whose upper bound from their
    parent's nearest boundary points (closest points of its nearest exactly evaluated primitives,
    see _dense_bound) exceeds `floor`."""
    lr, ln, dl = leaves
    kpos = np.full(n_cells, -1, dtype=np.int64)
    kpos[keep] = np.arange(keep.size)
    m = np.flatnonzero(kpos[lr] >= 0)
    if m.size == 0 or keep.size == 0:
        return np.arange(cfc.shape[0])
    pr, pn, pd = kpos[lr[m]], ln[m], dl[m]
    order = np.lexsort((pd, pr))
    pr, pn = pr[order], pn[order]
    st = _row_starts(pr)
    rank = np.arange(pr.size) - np.repeat(st, np.diff(np.r_[st, pr.size]))
    m = rank < 3 * _CHILD_POINTS
    pr, pn = pr[m], pn[m]
    pr_all, pn_all = pr, pn
    v = _offset_to_closest(g, np.take(pfc, pr, axis=0), pn)
    y = np.take(pfc, pr, axis=0) - v
    # distinct points (a vertex / edge shared by several triangles shows up next to itself)
    dup = np.zeros(pr.size, dtype=bool)
    dup[1:] = (pr[1:] == pr[:-1]) & (np.abs(y[1:] - y[:-1]).max(1) <= 1e-12 * (np.abs(v[1:]).max(1) + 1e-300))
    k = np.flatnonzero(~dup)
    pr, pn, y = pr[k], pn[k], y[k]
    st = _row_starts(pr)
    rank = np.arange(pr.size) - np.repeat(st, np.diff(np.r_[st, pr.size]))
    k = rank < _CHILD_POINTS
    pr, pn, y, rank = pr[k], pn[k], y[k], rank[k]
    pr_all, pn_all = pr, pn
    d = cfc.shape[1]
    Y = np.zeros((keep.size, _CHILD_POINTS, d))
    valid = np.zeros((keep.size, _CHILD_POINTS), dtype=bool)
    Y[pr, rank] = y
    valid[pr, rank] = True
    out = np.empty(cfc.shape[0], dtype=bool)
    step = max(1, _PAIR_CHUNK // (64 * _CHILD_POINTS))
    for i0 in range(0, cfc.shape[0], step):
        i1 = min(i0 + step, cfc.shape[0])
        par = np.arange(i0, i1) // nc
        V = cfc[i0:i1, None, :] - Y[par]
        out[i0:i1] = _dense_bound(V, valid[par], 0.5 * cside[i0:i1]) > floor[i0:i1]
    ch = np.flatnonzero(out)
    if ch.size and _CHILD_EXACT:
        # survivors: the same bounds from the closest points of those primitives to the child's
        # own centre (sharper: the contact points slide with the centre)
        pcount = np.bincount(pr_all, minlength=keep.size)
        pstart = np.cumsum(pcount) - pcount
        par = ch // nc
        rows, pos = _ragged_arange(pcount[par])
        prims = pn_all[pstart[par][rows] + pos]
        V = np.zeros((ch.size, _CHILD_POINTS, d))
        valid = np.zeros((ch.size, _CHILD_POINTS), dtype=bool)
        V[rows, pos] = _offset_to_closest(g, np.take(cfc[ch], rows, axis=0), prims)
        valid[rows, pos] = True
        b2 = _dense_bound(V, valid, 0.5 * cside[ch])
        ch = ch[b2 > floor[ch]]
    return ch


def _inscribed_bnb(g: _Geometry, elems: np.ndarray, rel_tol: float, bt: _BallTree | None = None):
    """Branch and bound over a quadtree/octree for the largest inscribed balls of `elems`.

    Breadth first, all elements at once. Every cell centre gets its exact distance to the element
    boundary and a known inside/outside status when it matters; a cell is dropped when
    (+-distance) + rho <= best + eps (the distance to the boundary is 1-Lipschitz).
    """
    d = g.dim
    orient = g.signed_measure >= 0  # tolerate reversed elements
    # best certified radius so far; 0 is a valid lower bound of the true radius even before an
    # interior point is found, and keeps slivers thinner than eps from being refined forever
    best = np.zeros(g.n)
    best_pt = np.full((g.n, d), np.nan)
    eps = rel_tol * g.diameter
    elems = np.asarray(elems, dtype=np.int64)
    elems = elems[(g.diameter[elems] > 0) & (g.prim_ptr[elems + 1] > g.prim_ptr[elems])]
    bt = _build_ball_tree(g) if bt is None else bt
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=d)))
    sq = math.sqrt(d)
    big = 4.0 * float(g.diameter.max()) + 1.0

    def search(dive: bool) -> None:
        fe = elems
        fc = 0.5 * (g.bbox_lo[fe] + g.bbox_hi[fe])
        side_len = (g.bbox_hi[fe] - g.bbox_lo[fe]).max(1) * (1 + 1e-9)
        status = np.zeros(fe.size, dtype=np.int8)  # +1 inside, -1 outside, 0 unknown
        rows, nodes = np.arange(fe.size), bt.root[fe]  # root candidate lists: the element's tree root

        for _level in range(200):
            if fe.size == 0:
                break
            rho = 0.5 * sq * side_len
            dist, near, loc, side, lrows, lnodes, leaves = _evaluate(g, bt, fc, rho, rows, nodes)
            # status of the cells that could matter (kept, or better than the best so far)
            todo = np.flatnonzero((status == 0) & ((dist + rho > best[fe] + eps[fe]) | (dist > best[fe])))
            if todo.size:
                st = _classify(g, fc[todo], fe[todo], near[todo], loc[todo], side[todo], orient)
                status[todo] = st
            inside = np.flatnonzero(status == 1)
            if inside.size:
                k = inside[_group_argmax(fe[inside], dist[inside])]
                k = k[dist[k] > best[fe[k]]]
                best[fe[k]] = dist[k]
                best_pt[fe[k]] = fc[k]
            bound = np.where(status == -1, -dist, dist) + rho  # 1-Lipschitz bound of the max over the cell
            # sharper bound from several nearby boundary points, where its second-order term is small
            cand = (status != -1) & (bound > best[fe] + eps[fe]) & (rho < _BOUND_RHO[d] * dist)
            if cand.any():
                lr, ln, dl = leaves
                m = cand[lr]
                lr, ln, dl = lr[m], ln[m], dl[m]
                order = np.argsort(lr + dl / (2.0 * dl.max() + 1e-300))  # by row, then by distance
                lr, ln = lr[order], ln[order]
                st = _row_starts(lr)
                rank = np.arange(lr.size) - np.repeat(st, np.diff(np.r_[st, lr.size]))
                m = rank < 3 * _BOUND_POINTS_FW[d]
                bound = np.minimum(bound, _cell_bounds(g, fc, 0.5 * side_len, lr[m], ln[m]))
            keep = np.flatnonzero(bound > best[fe] + eps[fe])
            if dive and keep.size:  # greedy descent: follow one promising cell per element
                score = np.where(status[keep] == 1, dist[keep] + big, bound[keep])
                keep = keep[_group_argmax(fe[keep], score)]
            # children: a child centre is rho/2 from its parent's, so it inherits a known status
            # whenever the parent is farther than that from the boundary
            nc = corners.shape[0]
            child_side = 0.5 * side_len[keep]
            inherit = np.where(dist[keep] > 0.5 * rho[keep], status[keep], 0).astype(np.int8)
            cfc = (fc[keep][:, None, :] + 0.5 * child_side[:, None, None] * corners[None]).reshape(-1, d)
            cfe = np.repeat(fe[keep], nc)
            cside = np.repeat(child_side, nc)
            # cheap bound first: the parent's nearest boundary primitives bound the distance over
            # each child (any boundary point does), so most children are dropped before their
            # (dear) exact evaluation
            if _CHILD_PRUNE[d]:
                ch = _child_prune(g, leaves, keep, dist.size, fc, cfc, cside, nc, best[cfe] + eps[cfe])
            else:
                ch = np.arange(cfc.shape[0])
            par = keep[ch // nc]
            fc, fe, side_len = cfc[ch], cfe[ch], cside[ch]
            status = inherit[ch // nc]
            # children share their parent's candidate list
            lcount = np.bincount(lrows, minlength=dist.size)
            lstart = np.cumsum(lcount) - lcount
            rows, pos = _ragged_arange(lcount[par])
            nodes = lnodes[lstart[par][rows] + pos]
        else:  # pragma: no cover - the cell size halves every level, so this cannot happen
            raise RuntimeError("inscribed-ball branch and bound did not converge")

    # a greedy dive first gives a good lower bound, so the full search prunes from the start;
    # a few local ascent steps from the dive's point then bring it close to the optimum
    if _DIVE[d]:
        search(dive=True)
    if _POLISH_STEPS[d]:
        _polish(g, elems, best, best_pt, orient)
    search(dive=False)
    return best_pt, best


_POLISH_STEPS = {2: 0, 3: 3}  # sequential-LP ascent steps after the dive (3D)
_POLISH_REACH = 0.3  # primitives within (1 + this) * best of the point enter the local model (a step
# moves at most sqrt(3) * trust * best, so every primitive left out stays farther than best)
_POLISH_TRUST = 0.15  # the step stays within this * best of the point (each coordinate)


def _polish(
    g: _Geometry, elems: np.ndarray, best: np.ndarray, best_pt: np.ndarray, orient: np.ndarray
) -> None:
    """Raise the lower bound of each element: sequential linear programming on the distance to the
    boundary, from its best interior point so far (updates best / best_pt in place).

    Around x0, every primitive i near x0 (closest point y_i, unit direction u_i = (x0 - y_i) / D_i)
    gives dist(x, prim i) >= u_i.(x - y_i) (the distance to a convex set is convex), so the local
    model max r s.t. u_i.(x - y_i) >= r, |x - x0|_inf <= trust, one block-diagonal LP for all
    elements, proposes a point; it is kept only when it is certified inside (as in the search)
    and its exact distance to all of the element's primitives beats the best so far. It only ever
    raises best to an exact distance at a certified interior point, so the guarantee is the
    search's; for planar contacts the model is exact and the step lands on the local optimum.
    """
    from scipy.optimize import linprog  # lazy: scipy.optimize takes most of a second to import

    e = elems[np.isfinite(best_pt[elems, 0]) & (best[elems] > 0)]
    for _ in range(_POLISH_STEPS[g.dim]):
        if e.size == 0:
            return
        x0, s = best_pt[e], best[e]
        cnt = g.prim_ptr[e + 1] - g.prim_ptr[e]
        row, pos = _ragged_arange(cnt)
        p = g.prim_ptr[e][row] + pos
        v = _offset_to_closest(g, np.take(x0, row, axis=0), p)
        D = np.sqrt(np.einsum("ij,ij->i", v, v))
        m = np.flatnonzero((D <= (1.0 + _POLISH_REACH) * s[row]) & (D > 0))
        r_, u, Dn = row[m], v[m] / D[m, None], D[m] / s[row[m]]
        # variables per element: z = (x - x0) / s (3), r / s; r/s - u.z <= D / s; maximise sum r / s
        nv = e.size * 4
        cols = np.column_stack([4 * r_ + k for k in range(4)]).ravel()
        vals = np.column_stack([-u, np.ones(r_.size)]).ravel()
        A = sparse.csr_matrix((vals, (np.repeat(np.arange(r_.size), 4), cols)), shape=(r_.size, nv))
        c = np.zeros(nv)
        c[3::4] = -1.0
        bounds = [(-_POLISH_TRUST, _POLISH_TRUST)] * 3 + [(0, None)]
        res = linprog(c, A_ub=A, b_ub=Dn, bounds=bounds * e.size, method="highs")
        if res.status != 0 or res.x is None:  # pragma: no cover - bounded and feasible (z = 0)
            return
        x = x0 + s[:, None] * res.x.reshape(e.size, 4)[:, :3]
        # exact distance to every primitive of the element, and the inside test of the search
        d2, loc, side = _prim_distance(g, np.take(x, row, axis=0), p)
        k = _group_argmin_sorted(row, d2)
        dist = np.sqrt(d2[k])
        ok = np.flatnonzero(dist > best[e])
        if ok.size:
            st = _classify(g, x[ok], e[ok], p[k][ok], loc[k][ok], side[k][ok], orient)
            ok = ok[st == 1]
        best[e[ok]] = dist[ok]
        best_pt[e[ok]] = x[ok]
        e = e[ok]


def _inscribed_lp(g: _Geometry, elems: np.ndarray):
    """Chebyshev centres of convex elements: one block-diagonal LP (max sum of radii) with HiGHS."""
    d = g.dim
    centres = np.full((g.n, d), np.nan)
    radius = np.zeros(g.n)
    elems = np.asarray(elems, dtype=np.int64)
    if elems.size == 0:
        return centres, radius
    rows, cols, vals, rhs = [], [], [], []
    shift = np.empty((elems.size, d))
    scale = np.empty(elems.size)
    r0 = 0
    for i, e in enumerate(elems):
        eq = g.hull_eq[e]
        m = g.hull_pts[e].mean(0)
        s = g.diameter[e]
        shift[i], scale[i] = m, s
        nrm = eq[:, :d]
        b = (eq[:, d] + nrm @ m) / s  # n.x' + b' <= 0 in the shifted/scaled frame
        f = eq.shape[0]
        rr = np.repeat(np.arange(r0, r0 + f), d + 1)
        cc = np.tile(np.arange(i * (d + 1), (i + 1) * (d + 1)), f)
        vv = np.column_stack([nrm, np.ones(f)]).ravel()
        rows.append(rr)
        cols.append(cc)
        vals.append(vv)
        rhs.append(-b)
        r0 += f
    nv = elems.size * (d + 1)
    A = sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, nv)
    )
    c = np.zeros(nv)
    c[d :: d + 1] = -1.0
    bounds = [(None, None)] * d + [(0, None)]
    from scipy.optimize import linprog  # lazy: scipy.optimize takes most of a second to import

    res = linprog(c, A_ub=A, b_ub=np.concatenate(rhs), bounds=bounds * elems.size, method="highs")
    if res.status != 0 or res.x is None:  # pragma: no cover - bounded and feasible by construction
        raise RuntimeError(f"Chebyshev-centre LP failed: {res.message}")
    x = res.x.reshape(elems.size, d + 1)
    for i, e in enumerate(elems):  # radius = actual distance from the centre to the facet planes
        cen = shift[i] + scale[i] * x[i, :d]
        eq = g.hull_eq[e]
        centres[e] = cen
        radius[e] = max(0.0, float(-(eq[:, :d] @ cen + eq[:, d]).max()))
    return centres, radius


def _check_tol(rel_tol: float) -> float:
    rel_tol = float(rel_tol)
    if not (0.0 < rel_tol < 1.0):
        raise ParameterError(f"rel_tol must be in (0, 1), got {rel_tol}")
    return rel_tol


_INSCRIBED_METHODS = ("auto", "bnb", "bnb-numpy")
_EXT_MAX_CELLS = 1_000_000  # cells per element before the compiled search hands it to numpy (~100 needed)


def _compiled():
    """The compiled helpers (models/_fastmetrics.c), or None where they were not built (or
    MAGNET_NO_COMPILED=1)."""
    from .native import compiled

    return compiled("_fastmetrics")


def _threads() -> int:
    """Threads for the compiled search: MAGNET_THREADS, else the cores this process may use."""
    env = os.environ.get("MAGNET_THREADS", "")
    if env.strip():
        try:
            return max(1, int(env))
        except ValueError:
            raise ParameterError(f"MAGNET_THREADS must be a whole number, got {env!r}") from None
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _inscribed_compiled(ext, g: _Geometry, elems: np.ndarray, rel_tol: float):
    """Compiled best-first search over `elems` (3D), in threads (the module releases the GIL;
    each element is searched by one thread, so the result does not depend on their number).
    Returns centres, radii and the elements it gave up on (cell budget spent; none on any mesh
    measured)."""
    centres = np.full((g.n, 3), np.nan)
    radius = np.zeros(g.n)
    evals = np.zeros(g.n, dtype=np.int64)
    elems = np.ascontiguousarray(elems, dtype=np.int64)
    args = (
        np.ascontiguousarray(g.prim, dtype=np.float64),
        np.ascontiguousarray(g.tri_adj, dtype=np.int64),
        np.ascontiguousarray(g.prim_ptr, dtype=np.int64),
    )
    rest = (
        np.ascontiguousarray(g.diameter, dtype=np.float64),
        np.ascontiguousarray(g.bbox_lo, dtype=np.float64),
        np.ascontiguousarray(g.bbox_hi, dtype=np.float64),
        (g.signed_measure >= 0).astype(np.uint8),
        float(rel_tol),
        _EXT_MAX_CELLS,
        centres,
        radius,
        evals,
    )
    nt = min(_threads(), max(1, elems.size // 16))
    if nt == 1:
        ext.inscribed(*args, elems, *rest)
    else:  # interleaved shares (neighbouring elements cost alike); outputs are disjoint rows
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(nt) as pool:
            list(pool.map(lambda k: ext.inscribed(*args, elems[k::nt].copy(), *rest), range(nt)))
    return centres, radius, elems[evals[elems] < 0]


def _inscribed(g: _Geometry, rel_tol: float, method: str = "auto"):
    if method not in _INSCRIBED_METHODS:
        raise ParameterError(f"unknown inscribed-ball method {method!r} ({', '.join(_INSCRIBED_METHODS)})")
    convex = g.convex if method == "auto" else np.zeros(g.n, dtype=bool)
    centres, radius = _inscribed_lp(g, np.flatnonzero(convex))
    # an element of zero measure (faces back to back) has no interior: radius 0, no centre
    flat = np.abs(g.signed_measure) <= 1e-12 * np.maximum(g.diameter, 1e-300) ** g.dim
    rest = np.flatnonzero(~convex & ~flat)
    ext = _compiled() if g.dim == 3 and method != "bnb-numpy" else None
    if rest.size and ext is not None:
        done = rest
        c2, r2, rest = _inscribed_compiled(ext, g, rest, rel_tol)
        centres[done], radius[done] = c2[done], r2[done]
    if rest.size:
        # elements in batches of about _BNB_BATCH_PRIMS boundary primitives: the search's per-level
        # arrays (cells x candidate nodes) stay bounded, so memory does not grow with the mesh; the
        # elements are independent, so the result is the same as one search over all of them
        bt = _build_ball_tree(g)
        nprim = (g.prim_ptr[rest + 1] - g.prim_ptr[rest]).astype(np.int64)
        batch = np.cumsum(nprim) // _BNB_BATCH_PRIMS
        for b in np.unique(batch):
            part = rest[batch == b]
            c2, r2 = _inscribed_bnb(g, part, rel_tol, bt)
            centres[part], radius[part] = c2[part], r2[part]
    return centres, radius


def largest_inscribed_ball(
    poly: PolyMesh, rel_tol: float = DEFAULT_REL_TOL, method: str = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """Centres (E, d) and radii (E,) of the largest balls inside each element.

    Convex elements (measure equal to the hull measure, one loop in 2D): exact Chebyshev centre
    from a linear program over the element's facet half-spaces (scipy linprog / HiGHS); the radius
    is re-measured from the returned centre, so it never exceeds the true one beyond rounding.

    Other elements (or all, with method="bnb"): in 3D, the compiled best-first search of
    models/_fastmetrics.c (same certificate, octree cells, bounds from the closest triangles and
    a small LP over each cell's corners; see that file); method="bnb-numpy", 2D, or where the
    module was not built (MAGNET_NO_COMPILED=1 switches it off): branch and bound on a quadtree
    (2D) / octree (3D) over the element's bounding cube, all elements at once, with exact point-to-segment /
    point-to-triangle distances (bounding-ball tree, candidate lists passed from parent to child
    cells) and exact inside tests (side of the closest facet, vertex wedge / edge pseudo-normal,
    else crossing number (2D) / winding number (3D)). best is the largest exact distance found at
    a certified interior point (0 before one is found; a greedy dive seeds it). A cell of
    half-diagonal rho is discarded when an upper bound U of the distance over the cell satisfies
    U <= best + eps: U = f + rho (f the signed centre distance; the distance is 1-Lipschitz), or a
    second-order bound from several nearby boundary points (see _cell_bounds). Every discarded
    cell holds no interior point farther than best + eps from the boundary, and the cells always
    cover the element, hence the guarantee, with eps = rel_tol * diameter (largest distance
    between the element's boundary vertices):

        r_true - eps <= r <= r_true

    (r is the exact distance from a certified interior point to the boundary). Elements with zero
    diameter, and slivers where no interior point was needed (then r_true <= eps), get radius 0
    and a NaN centre.
    """
    rel_tol = _check_tol(rel_tol)
    return _inscribed(_prepare(poly), rel_tol, method)


# --------------------------------------------------------------------------------------------------
# per-element metrics


def _enclosing_radius(g: _Geometry) -> np.ndarray:
    ext = _compiled() if g.hull_cat is not None else None
    if ext is None:
        return _enclosing_balls(g.hull_pts, g.dim)[1]
    centre = np.zeros((g.n, 3))
    radius = np.zeros(g.n)
    ext.enclosing_balls(np.ascontiguousarray(g.hull_cat), np.ascontiguousarray(g.hull_ptr), centre, radius)
    return radius


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return np.clip(out, 0.0, 1.0)


def _circle_ratio(g: _Geometry, rel_tol: float) -> np.ndarray:
    return _ratio(_inscribed(g, rel_tol)[1], _enclosing_radius(g))


def circle_ratio(poly: PolyMesh, rel_tol: float = DEFAULT_REL_TOL) -> np.ndarray:
    """Inscribed / enclosing ball radius per element (exact for convex elements, else within
    rel_tol * diameter / R_enclosing below the true value; see largest_inscribed_ball)."""
    return _circle_ratio(_prepare(poly), _check_tol(rel_tol))


def _apr(g: _Geometry, measure: np.ndarray) -> np.ndarray:
    return _ratio(4.0 * np.pi * np.abs(measure), g.boundary_size**2)


def area_perimeter_ratio(poly: PolyMesh) -> np.ndarray:
    """2D: 4 pi A / P^2 per element, P the total length of all loops (holes included)."""
    g = _prepare(poly)
    if g.dim != 2:
        raise ParameterError("area_perimeter_ratio is a 2D metric (use sphericity in 3D)")
    return _apr(g, np.asarray(poly.measure, dtype=np.float64))


def _sphericity(g: _Geometry, measure: np.ndarray) -> np.ndarray:
    return _ratio(np.cbrt(36.0 * np.pi * measure**2), g.boundary_size)


def sphericity(poly: PolyMesh) -> np.ndarray:
    """3D: (36 pi V^2)^(1/3) / S per element, S the total area of its boundary faces."""
    g = _prepare(poly)
    if g.dim != 3:
        raise ParameterError("sphericity is a 3D metric (use area_perimeter_ratio in 2D)")
    return _sphericity(g, np.asarray(poly.measure, dtype=np.float64))


def element_diameters(poly: PolyMesh) -> np.ndarray:
    """Largest distance between two boundary vertices of each element (over convex hull vertices)."""
    return _prepare(poly).diameter


def _uniformity(diam: np.ndarray) -> np.ndarray:
    top = diam.max() if diam.size else 0.0
    return _ratio(diam, np.full_like(diam, top))


def uniformity_factor(poly: PolyMesh) -> np.ndarray:
    """diam(P) / max over elements of diam."""
    return _uniformity(_prepare(poly).diameter)


def volume_difference(measure: np.ndarray) -> np.ndarray:
    """1 / (1 + |V - V_mean| / V_mean) per element."""
    v = np.abs(np.asarray(measure, dtype=np.float64))
    mean = v.mean() if v.size else 0.0
    if mean <= 0:
        return np.ones_like(v)
    return 1.0 / (1.0 + np.abs(v - mean) / mean)


def _compact(values: np.ndarray) -> tuple[np.ndarray, int]:
    """Group index 0..k-1 of each value (in sorted value order) and k; O(n) for small integers."""
    v = np.asarray(values).ravel()
    if v.size == 0:
        return np.zeros(0, dtype=np.int64), 0
    if np.issubdtype(v.dtype, np.integer):
        lo, hi = int(v.min()), int(v.max())
        if hi - lo <= 4 * v.size + 1024:
            present = np.bincount(v - lo) > 0
            code = np.cumsum(present) - 1
            return code[v - lo], int(present.sum())
    u, inv, _ = _unique(v)
    return inv, int(u.size)


def heterogeneity_preservation(
    labels: np.ndarray, fine_tags: np.ndarray, n_elements: int | None = None
) -> np.ndarray:
    """Fraction of each element's fine cells that belong to its majority tag group.

    With two groups (tags mapped to 0/1) this is max(p, 1 - p), p the mean tag; with more groups it
    is the majority-group fraction. Elements without fine cells get NaN.
    """
    labels = np.asarray(labels, dtype=np.int64)
    tags = np.asarray(fine_tags)
    if tags.shape != labels.shape:
        raise ParameterError(f"fine_tags has shape {tags.shape}, labels {labels.shape}")
    n = int(labels.max()) + 1 if n_elements is None and labels.size else int(n_elements or 0)
    grp, ng = _compact(tags)
    ng = max(ng, 1)
    counts = np.bincount(labels * ng + grp, minlength=n * ng).reshape(n, ng)
    total = counts.sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, counts.max(1) / np.maximum(total, 1), np.nan)


# --------------------------------------------------------------------------------------------------
# partition statistics on the fine dual graph


def _equals_transpose(indptr: np.ndarray, indices: np.ndarray) -> bool:
    """Whether a CSR pattern equals its transpose array for array (scipy's O(nnz) counting
    transpose has rows in increasing order, so then the rows are sorted and the pattern symmetric)."""
    if indices.size == 0:
        return True
    n = indptr.size - 1
    t = sparse.csr_matrix((np.ones(indices.size, dtype=bool), indices, indptr), shape=(n, n)).T.tocsr()
    return np.array_equal(t.indptr, indptr) and np.array_equal(t.indices, indices)


def partition_statistics(indptr: np.ndarray, indices: np.ndarray, labels: np.ndarray) -> dict:
    """Cut, normalized cut, volume imbalance, part count and connectivity of a partition.

    The CSR graph is symmetrised; each undirected edge counts once, self loops are ignored.
    normalized_cut = sum_i cut(S_i) / vol(S_i), vol = sum of degrees; volume_imbalance = largest
    part / mean part size (cells); connected: every part induces a connected subgraph.
    """
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    labels = np.asarray(labels, dtype=np.int64)
    nc = labels.size
    if indptr.size != nc + 1:
        raise ParameterError(f"indptr has {indptr.size} entries for {nc} labels")
    if indices.size and (indices.min() < 0 or indices.max() >= nc):
        raise ParameterError("graph indices out of range")
    part, parts = _compact(labels)
    sizes = np.bincount(part, minlength=parts)
    ext = _compiled()
    symmetric = _equals_transpose(indptr, indices)  # and every row sorted (maybe with duplicates)
    if ext is not None and symmetric:
        # one compiled pass (union-find for the components) where the pattern is symmetric with
        # strictly increasing rows, the usual dual graph; None if a row is not strictly increasing
        vol = np.zeros(parts)
        cut_i = np.zeros(parts)
        r = ext.partition_stats(indptr, np.ascontiguousarray(indices), np.ascontiguousarray(part), vol, cut_i)
        if r is not None:
            return _partition_summary(r[0], cut_i, vol, sizes, parts, r[1])
    u = np.repeat(np.arange(nc, dtype=np.int64), np.diff(indptr))
    if symmetric and np.all((indices[1:] > indices[:-1]) | (u[1:] != u[:-1])):  # no duplicates
        # the usual dual graph: every undirected edge twice, once per direction, no duplicates;
        # no COO -> CSR sort needed
        off = u != indices
        deg = np.bincount(u[off], minlength=nc)
        cross = off & (part[u] != part[indices])
        cut = int(cross.sum()) // 2
        cut_i = np.bincount(part[u[cross]], minlength=parts)
        keep = off & ~cross
        kept_ptr = np.zeros(nc + 1, dtype=np.int64)
        np.cumsum(np.bincount(u[keep], minlength=nc), out=kept_ptr[1:])
        # float64 data and int32 indices, as csgraph wants them (no conversion copies); the
        # pattern is symmetric, so weak components of the directed graph are the components
        idx = indices[keep].astype(np.int32) if nc < 2**31 else indices[keep]
        ptr = kept_ptr.astype(np.int32) if kept_ptr[-1] < 2**31 and nc < 2**31 else kept_ptr
        g = sparse.csr_matrix((np.ones(int(kept_ptr[-1])), idx, ptr), shape=(nc, nc))
        directed = True
    else:
        lo, hi = np.minimum(u, indices), np.maximum(u, indices)
        off = lo != hi
        # upper-triangular pattern; the COO -> CSR conversion merges duplicate (and mirrored) entries
        up = sparse.csr_matrix((np.ones(int(off.sum()), dtype=bool), (lo[off], hi[off])), shape=(nc, nc))
        a = np.repeat(np.arange(nc, dtype=np.int64), np.diff(up.indptr))
        b = up.indices.astype(np.int64)
        deg = np.bincount(a, minlength=nc) + np.bincount(b, minlength=nc)
        cut_mask = part[a] != part[b]
        cut = int(cut_mask.sum())
        cut_i = np.bincount(part[a][cut_mask], minlength=parts) + np.bincount(
            part[b][cut_mask], minlength=parts
        )
        inner = ~cut_mask
        g = sparse.csr_matrix((np.ones(int(inner.sum()), dtype=bool), (a[inner], b[inner])), shape=(nc, nc))
        directed = False
    vol = np.bincount(part, weights=deg, minlength=parts)
    ncomp = connected_components(g, directed=directed, connection="weak")[0] if nc else 0
    return _partition_summary(cut, cut_i, vol, sizes, parts, ncomp)


def _partition_summary(cut, cut_i, vol, sizes, parts, ncomp) -> dict:
    with np.errstate(divide="ignore", invalid="ignore"):
        ncut = float(np.where(vol > 0, cut_i / np.where(vol > 0, vol, 1), 0.0).sum())
    return {
        "cut": cut,
        "normalized_cut": ncut,
        "volume_imbalance": float(sizes.max() / sizes.mean()) if parts else 0.0,
        "parts": parts,
        "connected": bool(ncomp == parts),
    }


# --------------------------------------------------------------------------------------------------
# report


def _box_measure(g: _Geometry) -> np.ndarray:
    side = np.nan_to_num(g.bbox_hi - g.bbox_lo, nan=0.0)
    return np.prod(side, axis=1)


def box_ratio(poly: PolyMesh) -> np.ndarray:
    """|K| / |B_K| per element, B_K its axis-aligned bounding box (1 for a box; R3MG's BR)."""
    return _ratio(np.abs(np.asarray(poly.measure, dtype=np.float64)), _box_measure(_prepare(poly)))


def coverage(box_measures: np.ndarray, measures: np.ndarray) -> float:
    """sum |B_K| / |Omega|: how much the elements' bounding boxes cover (1 = no overlap, no waste).
    Polynomial spaces on bounding boxes pay for it in conditioning (R3MG's coverage)."""
    total = float(np.abs(np.asarray(measures, dtype=np.float64)).sum())
    return float(np.sum(box_measures) / total) if total > 0 else float("nan")


def box_measures(
    points: np.ndarray,
    offsets: np.ndarray,
    connectivity: np.ndarray,
    labels: np.ndarray,
    measures: np.ndarray,
) -> dict:
    """Box ratio per element and coverage straight from the fine mesh (no merged polytopes):
    {"box_ratio": (E,), "coverage": float, "box": (E,) box measures}. Vectorized."""
    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1
    vl = np.repeat(labels, np.diff(offsets))
    p = np.asarray(points, dtype=np.float64)[connectivity]
    order = np.argsort(vl, kind="stable")
    v = vl[order]
    starts = np.flatnonzero(np.r_[True, v[1:] != v[:-1]])
    lo = np.minimum.reduceat(p[order], starts, axis=0)
    hi = np.maximum.reduceat(p[order], starts, axis=0)
    box = np.zeros(k)
    box[v[starts]] = np.prod(hi - lo, axis=1)
    m = np.bincount(labels, weights=np.abs(measures), minlength=k)
    return {"box_ratio": _ratio(m, box), "coverage": coverage(box, m), "box": box}


def _plain(values: np.ndarray) -> list:
    return [float(x) if np.isfinite(x) else None for x in np.asarray(values, dtype=np.float64)]


def metrics_report(
    poly: PolyMesh,
    indptr: np.ndarray,
    indices: np.ndarray,
    fine_tags: np.ndarray | None = None,
    rel_tol: float = DEFAULT_REL_TOL,
) -> dict:
    """All MISSION.md section 6 metrics of an agglomerated mesh as a JSON-serialisable dict."""
    g = _prepare(poly)
    rel_tol = _check_tol(rel_tol)
    measure = np.asarray(poly.measure, dtype=np.float64)
    inscribed = _inscribed(g, rel_tol)[1]
    per: dict[str, np.ndarray] = {"circle_ratio": _ratio(inscribed, _enclosing_radius(g))}
    if g.dim == 2:
        per["area_perimeter_ratio"] = _apr(g, measure)
    else:
        per["sphericity"] = _sphericity(g, measure)
    per["uniformity_factor"] = _uniformity(g.diameter)
    per["volume_difference"] = volume_difference(measure)
    box = _box_measure(g)
    per["box_ratio"] = _ratio(np.abs(measure), box)
    per["box_circle_ratio"] = _ratio(inscribed, 0.5 * np.linalg.norm(g.bbox_hi - g.bbox_lo, axis=1))
    if fine_tags is not None:
        per["heterogeneity_preservation"] = heterogeneity_preservation(poly.labels, fine_tags, g.n)
    return {
        "elements": int(g.n),
        "dim": int(g.dim),
        "coverage": coverage(box, measure),
        "summary": {k: summarize(v) for k, v in per.items()},
        "per_element": {k: _plain(v) for k, v in per.items()},
        "partition": partition_statistics(indptr, indices, poly.labels),
    }

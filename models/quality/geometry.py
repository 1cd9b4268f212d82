"""Quality metrics of an agglomerated mesh (MISSION.md section 6), all in [0, 1] per element.

Everything works on whole arrays. The only Python loops run over agglomerated elements (one convex
hull per element) or over refinement levels / pivot steps; never over fine cells or boundary facets.

Boundary of an element: 2D, its segments (outer loop CCW, holes CW: the element is on the left of
every segment); 3D, its faces fan-triangulated (outward normals). The largest inscribed ball is exact
(linear program) for convex elements and certified to `rel_tol * diameter` otherwise; see
`largest_inscribed_ball`. The 3D search and geometry, the enclosing balls and the partition
statistics run in the compiled models/quality/_fastmetrics.c where it was built; their numpy versions here
are the fallback (MAGNET_NO_COMPILED=1) and the reference of the tests.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from models.errors import ParameterError
from models.mesh.container import PolyMesh

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


def _compiled():
    """The compiled helpers (models/quality/_fastmetrics.c), or None where they were not built (or
    MAGNET_NO_COMPILED=1)."""
    from models.native import compiled

    return compiled("quality._fastmetrics")


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


def _row_starts(rows: np.ndarray) -> np.ndarray:
    first = np.ones(rows.size, dtype=bool)
    first[1:] = rows[1:] != rows[:-1]
    return np.flatnonzero(first)

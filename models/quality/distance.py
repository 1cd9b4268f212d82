"""Distances from points to the boundary primitives of agglomerates, the ball tree over them
and the cell bounds of the inscribed-ball branch and bound (the numpy reference of models/quality/_fastmetrics.c)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from models.quality.geometry import (
    _INTERIOR_MARGIN,
    _LOC_END,
    _LOC_INTERIOR,
    _LOC_RIM,
    _LOC_START,
    _PAIR_CHUNK,
    _Geometry,
    _group_argmax,
    _ragged_arange,
    _row_starts,
)


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

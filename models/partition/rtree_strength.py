"""Strength-aware cut axes for rtree hierarchies (issue 24, round four).

rtree cuts each part across the longest extent of its box. For multigrid the cut should rather cross
the operator's weak couplings: this module chooses, per part and halving step, among the 2 or 3 axes
the one whose quantile plane is crossed by the least TPFA transmissibility (face measure / centroid
distance, times d^T K d / |d|^2 for a diffusion tensor K) per unit of cut measure; near-ties (within
a factor 1 + tol) keep the longest extent, so isotropic uniform meshes keep their shapes. The crossing
weight of a plane is a segment sum over the edge list (edges inside the part whose endpoints rank on
either side of the quantile along the axis). Inside the slack window the cut's position is the one the
least transmissibility crosses (instead of the least box overlap). Numpy only: rtree_levels(axes=
"strength", "strength-mincut" or "strength-position") runs split_counts' numpy halving step with
this rule (the compiled cuts keep the longest extent).
"""

from __future__ import annotations

import numpy as np

from models.partition.rtree_split import _count_split

PER_UNIT = True  # score: crossing weight per unit of cut measure (False: the crossing weight alone)
POSITION = True  # the cut's position inside the slack window: the least crossing coupling
TOL = 0.5  # the longest extent wins unless another axis' crossing weight per unit of cut is 1.5x smaller


def tpfa_coupling(
    indptr: np.ndarray, indices: np.ndarray, face: np.ndarray, x: np.ndarray, kappa: np.ndarray | None = None
) -> np.ndarray:
    """(nnz,) TPFA transmissibility of every CSR entry: |f| d^T K d / |d|^3 (K = diag(kappa), or I),
    d the centroid-to-centroid vector (as models.hierarchy.multigrid.tpfa_poisson makes them)."""
    rows = np.repeat(np.arange(indptr.size - 1), np.diff(indptr))
    d = x[indices] - x[rows]
    d2 = np.einsum("ij,ij->i", d, d)
    kd = d2 if kappa is None else np.einsum("ij,ij->i", d * np.asarray(kappa, dtype=np.float64), d)
    return np.asarray(face, dtype=np.float64) * kd / np.maximum(d2, 1e-300) ** 1.5


def _directional(v: np.ndarray, kappa: np.ndarray | None) -> np.ndarray:
    """v_hat^T K v_hat for the rows v (K = diag(kappa)); 1 without kappa."""
    if kappa is None:
        return np.ones(v.shape[0])
    sq = v * v
    return (sq @ np.asarray(kappa, dtype=np.float64)) / np.maximum(sq.sum(axis=1), 1e-300)


def tpfa_boundary(mesh, data, kappa: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(owner cell, transmissibility) of every boundary face of the TPFA operator with u = 0 there:
    |f| k_d / |d|, d from the cell's centroid to the face centre (k_d = d^T K d / |d|^2)."""
    from models.mesh.geometry import face_measures

    g = data.graph
    c = data.centroids
    f = g.faces
    fb = np.flatnonzero(g.partner < 0)
    pts = np.asarray(mesh.points, dtype=np.float64)[:, : c.shape[1]]
    size = np.diff(f.offsets)[fb]
    first = np.zeros(fb.size + 1, dtype=np.int64)
    np.cumsum(size, out=first[1:])
    idx = np.repeat(f.offsets[fb] - first[:-1], size) + np.arange(first[-1])
    fsum = np.add.reduceat(pts[f.nodes[idx]], first[:-1], axis=0) if fb.size else np.zeros((0, c.shape[1]))
    fcen = fsum / np.maximum(size, 1)[:, None]
    owner = f.cell[fb]
    bv = c[owner] - fcen
    tb = face_measures(pts, f, fb) * _directional(bv, kappa) / np.maximum(np.linalg.norm(bv, axis=1), 1e-300)
    return owner, tb


def _cross_at_cuts(n: int, cells: np.ndarray, eu, ev, et) -> np.ndarray:
    """cross[j]: the weight of the edges (eu, ev, et) crossing the cut before position j of `cells`
    (the active parts' cells, each part's sorted along an axis): an edge at positions a < b crosses
    the cuts a+1..b, a difference array summed once."""
    tot = cells.size
    idx = np.empty(n, dtype=np.int64)
    idx[cells] = np.arange(tot)
    a, b = idx[eu], idx[ev]
    lo, hi = np.minimum(a, b) + 1, np.maximum(a, b) + 1
    return np.cumsum(
        np.bincount(lo, weights=et, minlength=tot + 2) - np.bincount(hi, weights=et, minlength=tot + 2)
    )


def _least_in_window(cross, mid, target, window, s0, e1, cut):
    """Per part (positions s0..e1), among the cuts whose middle measure lies within `window` of the
    quantile `target`, the one the least weight crosses (ties: nearest the quantile): (weight, cut
    as cells before it); the quantile's `cut` where the window is empty."""
    cost = cross[s0 + np.clip(cut, 0, e1 - s0 + 1)].copy()
    out = cut.copy()
    wl = np.maximum(np.searchsorted(mid, target - window, side="left"), s0)
    wh = np.minimum(np.searchsorted(mid, target + window, side="right"), e1)  # the cut after e1 is no cut
    wlen = np.maximum(wh - wl, 0)
    if int(wlen.sum()) == 0:
        return cost, out
    na = s0.size
    gw = np.repeat(np.arange(na), wlen)
    w_off = np.zeros(na + 1, dtype=np.int64)
    np.cumsum(wlen, out=w_off[1:])
    wpos = np.repeat(wl - w_off[:-1], wlen) + np.arange(gw.size)  # cut after wpos
    scale = max(float(np.abs(cross).max()), 1e-300)
    dev = np.abs(mid[wpos] - target[gw]) / np.maximum(window[gw], 1e-300)
    c = np.maximum(cross[wpos + 1], 0.0)
    key = c / scale + 1e-9 * dev
    has = np.flatnonzero(wlen > 0)
    kmin = np.minimum.reduceat(key, w_off[:-1][has])
    hit = np.flatnonzero(key == np.repeat(kmin, wlen[has]))
    best = hit[np.r_[True, gw[hit][1:] != gw[hit][:-1]]]
    g = gw[best]
    cost[g], out[g] = c[best], wpos[best] - s0[g] + 1
    return cost, out


class StrengthAxes:
    """The cut-axis rule of _halving_step: called with (P, w, a_start, a_size, m, ext), returns each
    active part's axis; then cut(...) places the cut on it. indptr/indices/coupling: the cells' graph
    and its transmissibilities; cell_ext (N, dim): the cells' box sizes (the cut measure of a part
    uses its extent plus one cell); per_unit: score = crossing weight / cut measure (else the
    crossing weight alone: a min cut); axis: False keeps the longest extent; position: the cut inside
    the slack window by the least crossing weight (the axis scored at its best cut there; False: at
    the quantile, and the cut by the least box overlap); slack: rtree's, the window in final parts."""

    def __init__(
        self,
        indptr,
        indices,
        coupling,
        cell_ext,
        tol=TOL,
        per_unit=True,
        axis=True,
        position=POSITION,
        slack=0.3,
    ):
        n = indptr.size - 1
        rows = np.repeat(np.arange(n), np.diff(indptr))
        keep = rows < indices  # each edge once
        self.u, self.v = rows[keep], np.asarray(indices)[keep]
        self.t = np.asarray(coupling, dtype=np.float64)[keep]
        self.cell_ext = np.asarray(cell_ext, dtype=np.float64)
        self.tol, self.per_unit = float(tol), bool(per_unit)
        self.axis, self.position, self.slack = bool(axis), bool(position), float(slack)
        self._e = None  # the edges inside the active parts of the current step (set by __call__)

    def __call__(self, P, w, a_start, a_size, m, ext):
        dim, n = P.shape
        na = a_start.size
        a_off = np.zeros(na + 1, dtype=np.int64)
        np.cumsum(a_size, out=a_off[1:])
        tot = int(a_off[-1])
        s0, e1 = a_off[:-1], a_off[1:] - 1
        pos = np.repeat(a_start - s0, a_size) + np.arange(tot)
        owner = np.repeat(np.arange(na), a_size)
        pid = np.full(n, -1, dtype=np.int64)
        pid[P[0, pos]] = owner
        pu = pid[self.u]
        e = np.flatnonzero((pu >= 0) & (pu == pid[self.v]))  # edges inside an active part
        eu, ev, et = self.u[e], self.v[e], self.t[e]
        self._e = (eu, ev, et)
        longest = np.argmax(ext, axis=1)
        if not self.axis:
            return longest
        cross = np.empty((na, dim))
        h = np.empty((na, dim))
        for d in range(dim):  # a loop over the axes
            cells = P[d, pos]
            ws = w[cells]
            cum = np.cumsum(ws)
            base = cum[s0] - ws[s0]
            vol = cum[e1] - base
            m1, target = _count_split(m, base, vol, ext[:, d], dim)
            mid = cum - 0.5 * ws
            cut = np.clip(np.searchsorted(mid, target) - s0, m1, a_size - (m - m1))
            window = vol / np.maximum(m, 1) * (self.slack if self.position else 0.0)
            cross[:, d] = _least_in_window(
                _cross_at_cuts(n, cells, eu, ev, et), mid, target, window, s0, e1, cut
            )[0]
            h[:, d] = np.bincount(owner, weights=self.cell_ext[cells, d], minlength=na) / np.maximum(
                a_size, 1
            )
        score = cross
        if self.per_unit:
            L = np.maximum(ext + h, 1e-300)
            score = cross / (np.prod(L, axis=1)[:, None] / L)  # per unit of the plane's measure in the part
        best = np.argmin(score, axis=1)
        r = np.arange(na)
        return np.where(score[r, longest] <= (1.0 + self.tol) * score[r, best], longest, best)

    def cut(self, chosen, s0, e1, mid, target, window, cut):
        """Per active part (positions s0..e1 of `chosen`, its cells sorted along the chosen axis), the
        cut (cells before it go to side 0) whose middle measure lies within `window` of the quantile
        `target` and that the least transmissibility crosses (ties: nearest the quantile); `cut`
        where the window is empty."""
        eu, ev, et = self._e
        n = int(max(chosen.max(), eu.max() if eu.size else 0, ev.max() if ev.size else 0)) + 1
        return _least_in_window(_cross_at_cuts(n, chosen, eu, ev, et), mid, target, window, s0, e1, cut)[1]


def strength_rule(batch, coupling, lo, hi, axes: str = "strength", slack: float = 0.3) -> StrengthAxes:
    """The rule for the cells of `batch` (TPFA couplings of its centroids when `coupling` is None).
    axes: "strength" (axis by crossing weight per unit of cut, position by crossing weight),
    "strength-mincut" (axis by the crossing weight alone), "strength-position" (the longest extent,
    position by crossing weight)."""
    if coupling is None:
        coupling = tpfa_coupling(batch.indptr, batch.indices, batch.weights, batch.centroids)
    ext = hi - lo if lo is not None else np.zeros_like(batch.centroids)
    return StrengthAxes(
        batch.indptr,
        batch.indices,
        coupling,
        ext,
        per_unit=axes == "strength",
        axis=axes != "strength-position",
    )

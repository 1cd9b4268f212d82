"""`rtree`: nested geometric agglomeration with exact counts (the R-tree idea of R3MG, made exact).

A group that must become m parts is cut in two along the longest extent of its centroids' box, at
the measure-weighted quantile m1/m, the two sides getting m1 and m - m1 parts; m1 is chosen so the
pieces come out as close to cubes as the count allows (m1 = m x floor(c/2)/c for c, the number
of cube-sized pieces along that extent). All groups of a level are cut at once: the cells are
sorted once per axis, and a halving step partitions every part's range of those orders stably (no
sort, no loop over groups or cells; the per-cell work in models/graph/_fastgraph.c where it is built, the
same operations as the numpy twins here, which tests/test_fastgraph.py holds bit for bit equal).
Afterwards every part is made connected: each part keeps its largest connected piece and the other
pieces join the neighbouring part of the same parent with which they share the longest interface,
so counts stay exact and levels stay nested.

Levels of a hierarchy go top-down: the coarsest level is cut from the whole domain (one group per
connected component of the mesh, or per physical group), then every element of level l is cut
into its share of level l+1's count (proportional to its measure, at least 1). The elements of a
hierarchy's levels are numbered along the domain's principal axis, for Gauss-Seidel smoothers.
"""

from __future__ import annotations

import numpy as np

from models.errors import ParameterError
from models.graph.batch import GraphBatch
from models.graph.csr import kept_pointers, row_pointers, run_starts
from models.native import compiled
from models.partition.base import Partitioner
from models.partition.rtree_principal import split_principal
from models.partition.rtree_split import _count_split
from models.partition.rtree_strength import strength_rule

SLACK = 0.3  # cut moves up to 0.3 x one final part's measure for tighter boxes (BR .881 at 364 on the refined quads; VD .94 -> .83)


def _compiled():
    """The compiled halving steps and piece labelling (models/graph/_fastgraph.c), or None where they
    were not built (or MAGNET_NO_COMPILED=1): then their numpy twins here run, with the same results."""
    return compiled("graph._fastgraph")


def _group_boxes(x: np.ndarray, grp: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(k, dim) lower and upper corners of the points of each group."""
    order = np.argsort(grp, kind="stable")
    g = grp[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    lo = np.full((k, x.shape[1]), np.inf)
    hi = np.full((k, x.shape[1]), -np.inf)
    if order.size:
        xs = x[order]
        lo[g[starts]] = np.minimum.reduceat(xs, starts, axis=0)
        hi[g[starts]] = np.maximum.reduceat(xs, starts, axis=0)
    return lo, hi


def apportion(weights: np.ndarray, total: int, caps: np.ndarray) -> np.ndarray:
    """Integers m_g >= 1, m_g <= caps_g, summing to `total` (when feasible), proportional to the
    weights (largest remainders). Infeasible totals give the nearest feasible sum."""
    w = np.maximum(np.asarray(weights, dtype=np.float64), 0)
    caps = np.asarray(caps, dtype=np.int64)
    g = w.size
    total = int(np.clip(total, g, caps.sum()))
    q = w / w.sum() * total if w.sum() > 0 else np.full(g, total / g)
    m = np.clip(np.floor(q).astype(np.int64), 1, caps)
    for _ in range(64):  # a handful of rounds (caps and the minimum of 1 push counts around)
        diff = total - int(m.sum())
        if diff == 0:
            break
        r = q - m
        if diff > 0:
            cand = np.flatnonzero(m < caps)
            pick = cand[np.argsort(-r[cand], kind="stable")[:diff]]
            m[pick] += 1
        else:
            cand = np.flatnonzero(m > 1)
            pick = cand[np.argsort(r[cand], kind="stable")[:-diff]]
            m[pick] -= 1
    return m


def _small_int(a: np.ndarray, k: int) -> np.ndarray:
    """a as the smallest unsigned type holding 0..k-1 (numpy's stable sort is a radix sort up to 16 bits)."""
    return a.astype(np.uint16) if k <= 65536 else a.astype(np.uint32) if k <= 2**32 else a


def _stable_by(keys: np.ndarray, k: int, order: np.ndarray) -> np.ndarray:
    """order, stably re-sorted by keys[order] (integers in 0..k-1)."""
    return order[np.argsort(_small_int(keys[order], k), kind="stable")]


def _stable_argsort(v: np.ndarray) -> np.ndarray:
    """np.argsort(v, kind="stable"): without ties (and NaNs) that is the quicksort's order, which is
    4x faster on floats; with ties, the stable sort (straight away when a sample of ~2000 values
    already has ties, as structured meshes' coordinates do)."""
    sample = v[:: max(1, v.size // 2048)]
    if np.unique(sample).size < sample.size:  # ties among a sample of the values: no quicksort first
        return np.argsort(v, kind="stable")
    o = np.argsort(v)
    vs = v[o]
    if vs.size and (bool((vs[1:] == vs[:-1]).any()) or np.isnan(vs[-1])):
        return np.argsort(v, kind="stable")
    return o


class _Segments:
    """Cells kept, for every axis, in the order (part, coordinate along the axis, cell index): each part
    is the same contiguous range [start, start + size) of all `dim` orders. Splitting a part is a
    stable partition of its range (no sort), so a whole hierarchy is cut after one sort per axis."""

    def __init__(self, x: np.ndarray, grp: np.ndarray, k: int, axis_orders: list[np.ndarray] | None = None):
        n, dim = x.shape
        if axis_orders is None:
            axis_orders = [_stable_argsort(x[:, d]) for d in range(dim)]
        self.axis_orders = axis_orders
        # int64, not int32: the cell ids are used as indices, and numpy converts int32 index arrays
        # on every gather and scatter (the cuts of the 1M cube 0.9x the CPU with int64)
        self.P = np.empty((dim, n), dtype=np.int64)
        for d in range(dim):
            self.P[d] = _stable_by(grp, k, axis_orders[d])
        self.size = np.bincount(grp, minlength=k).astype(np.int64)
        self.start = np.zeros(k, dtype=np.int64)
        np.cumsum(self.size[:-1], out=self.start[1:])
        self._bounds = None

    def bounds(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """The cells' boxes (N, dim) as one (dim * N,) complex array, axis by axis (cell c's bounds
        along axis d at d * N + c: lower bound real, upper imaginary), so that one gather fetches both
        (made once per pair of arrays)."""
        if self._bounds is None or self._bounds[0] is not lo or self._bounds[1] is not hi:
            n, dim = lo.shape
            lh = np.empty((dim, n), dtype=np.complex128)
            lh.real = lo.T
            lh.imag = hi.T
            self._bounds = (lo, hi, lh.reshape(-1))
        return self._bounds[2]


def split_counts(
    grp: np.ndarray,
    need: np.ndarray,
    x: np.ndarray,
    w: np.ndarray,
    cell_lo: np.ndarray | None = None,
    cell_hi: np.ndarray | None = None,
    slack: float = SLACK,
    segments: _Segments | None = None,
    rule=None,
) -> np.ndarray:
    """Cut every group g (labels `grp` in 0..G-1) into need[g] parts by recursive weighted cuts.

    cell_lo/cell_hi (N, dim): the cells' own boxes; when given, each cut moves within `slack` x
    the measure of one final part from the quantile to where the two sides' boxes overlap least (tighter
    boxes: higher box ratio, lower coverage; counts stay exact).
    segments: the cells' per-axis orders for these groups (rtree_levels passes them from level to level).
    rule: None (longest extent) or a callable choosing each part's cut axis (rtree_strength; numpy only).
    Returns (N,) labels in 0..need.sum()-1, the parts of group g numbered need[:g].sum() onwards."""
    n, dim = x.shape
    grp = np.asarray(grp, dtype=np.int64)
    need = np.asarray(need, dtype=np.int64).copy()
    k0 = need.size
    seg = segments if segments is not None else _Segments(x, grp, k0)
    P, start, size = seg.P, seg.start, seg.size
    Pf = P.reshape(-1)
    root = np.arange(k0)
    need = np.minimum(need, np.maximum(size, 1))
    tight = cell_lo is not None and slack > 0
    if tight:  # the boxes' bounds axis by axis: (dim * N,), axis d at d * N
        lh_t = seg.bounds(cell_lo, cell_hi)
    fc = _compiled() if 0 < n and dim <= 3 and rule is None else None
    if fc is not None:  # the per-cell work of every halving step in C (same operations, same results)
        xc = np.ascontiguousarray(x, dtype=np.float64)
        wc = np.ascontiguousarray(w, dtype=np.float64)
        chosen_buf, mid_buf = np.empty(n, dtype=np.int64), np.empty(n)
        lh_f = lh_t.view(np.float64) if tight else np.empty(0)
        # scratch made once (fresh memory costs page faults at every step): side flags, int64, float64
        scratch = (np.zeros(n, dtype=np.uint8), np.empty(n, dtype=np.int64), np.empty(3 * n if tight else 0))
    else:
        side = np.zeros(n, dtype=bool)
    while True:
        act = np.flatnonzero(need > 1)
        if act.size == 0:
            break
        a_start, a_size = start[act], size[act]
        na = act.size
        m = need[act]
        if fc is not None:
            axis, length = np.empty(na, dtype=np.int64), np.empty(na)
            base, vol = np.empty(na), np.empty(na)
            fc.cut_prepare(Pf, xc, wc, a_start, a_size, axis, length, chosen_buf, mid_buf, base, vol)
            m1, target = _count_split(m, base, vol, length, dim)
            window = vol / np.maximum(m, 1) * slack if tight else np.empty(0)
            n0 = np.empty(na, dtype=np.int64)
            args = (Pf, lh_f, chosen_buf, mid_buf, a_start, a_size, axis, target, window, m1, m, slack, n0)
            fc.cut_apply(*args, *scratch)
        else:
            n0, m1 = _halving_step(P, x, w, a_start, a_size, m, side, lh_t if tight else None, slack, rule)
        start = np.concatenate([start, a_start + n0])
        size = np.concatenate([size, a_size - n0])
        size[act] = n0
        need = np.concatenate([need, m - m1])
        need[act] = m1
        root = np.concatenate([root, root[act]])
    # number the parts group by group
    part_order = np.lexsort((np.arange(need.size), root))
    rank = np.empty(need.size, dtype=np.int64)
    rank[part_order] = np.arange(need.size)
    by_pos = np.argsort(start, kind="stable")
    labels = np.empty(n, dtype=np.int64)
    labels[P[0]] = np.repeat(rank[by_pos], size[by_pos])
    seg.start, seg.size = start[part_order], size[part_order]  # ranges of the parts, in their new numbering
    return labels


def _halving_step(P, x, w, a_start, a_size, m, side, lh_t, slack, rule=None):
    """One halving step of split_counts in numpy (the twin of _fastgraph.cut_prepare + cut_apply;
    a change here needs the same change there, tests/test_fastgraph.py compares them bit for bit):
    every active part (range a_start, a_size of the axis orders P, m parts to make) cut in two, P's
    ranges partitioned stably (side 0 first). Returns (n0, m1): the cells and parts of each part's side 0."""
    dim, n = P.shape
    Pf = P.reshape(-1)
    na = a_start.size
    a_off = np.zeros(na + 1, dtype=np.int64)
    np.cumsum(a_size, out=a_off[1:])
    tot = int(a_off[-1])
    s0, e1 = a_off[:-1], a_off[1:] - 1
    first, last = a_start, a_start + a_size - 1
    ext = np.column_stack([x[P[d, last], d] - x[P[d, first], d] for d in range(dim)])
    axis = np.argmax(ext, axis=1) if rule is None else rule(P, w, a_start, a_size, m, ext)
    length = ext[np.arange(na), axis]
    ar = np.arange(tot)
    pos = np.repeat(a_start - s0, a_size)  # position in the orders of each cell of the active parts
    pos += ar
    ax_n = np.repeat(axis * n, a_size)
    chosen = Pf[ax_n + pos]  # cells of the active parts, sorted along their part's axis
    ws = w[chosen]
    cum = np.cumsum(ws)
    base = cum[s0] - ws[s0]  # measure before each part
    vol = cum[e1] - base
    mid = cum - 0.5 * ws  # measure before each cell's middle (increasing)
    m1, target = _count_split(m, base, vol, length, dim)
    cut = np.searchsorted(mid, target) - s0  # cells whose middle lies below the quantile
    if getattr(rule, "position", False):  # the least crossing coupling inside the slack window
        cut = rule.cut(chosen, s0, e1, mid, target, vol / np.maximum(m, 1) * slack, cut)
    elif lh_t is not None:
        ax_n += chosen
        cut = _tight_cut(ax_n, lh_t, mid, target, vol / np.maximum(m, 1) * slack, s0, e1, cut, slack)
    n0 = np.clip(cut, m1, a_size - (m - m1))  # both sides keep at least as many cells as parts
    mask1 = ar >= np.repeat(s0 + n0, a_size)  # side 1: ranks n0 onwards along the part's axis
    side[chosen[mask1]] = True
    pos0, pos1 = pos[~mask1], pos[mask1]
    # stable partition of every axis order inside each active range: side 0 first, then side 1
    for d in range(dim):  # a loop over the axes
        V = P[d, pos]
        S = side[V]
        P[d, pos1] = V[S]
        np.logical_not(S, out=S)
        P[d, pos0] = V[S]
    side.fill(False)
    return n0, m1


def _tight_cut(idx, lh_t, mid, target, window, s0, e1, cut, slack):
    """Per part (positions s0..e1 of the active cells, sorted along the part's cut axis), the cut
    (cells before it go to side 0) whose middle measure lies within `window` of the quantile `target`,
    minimising the overlap of the two sides' extents along the axis (first of the smallest; `cut`
    where none). idx: each active cell's bounds in lh_t (axis * N + cell; lower bound real, upper
    imaginary). Only the window's
    positions are looked at one by one; the rest of a part by one reduceat each side."""
    na = s0.size
    wl = np.maximum(np.searchsorted(mid, target - window, side="left"), s0)
    wh = np.minimum(np.searchsorted(mid, target + window, side="right"), e1)  # the cut after e1 is no cut
    wlen = np.maximum(wh - wl, 0)
    W = int(wlen.sum())
    if W == 0:
        return cut
    # the cells' extents along their part's axis, each padded with one empty bound for the reduceats
    hi_pad = np.empty(idx.size + 1)
    lo_pad = np.empty(idx.size + 1)
    both = np.take(lh_t, idx)  # one gather of both bounds (16 bytes), then two contiguous copies
    hi_pad[:-1] = both.imag
    lo_pad[:-1] = both.real
    hi_pad[-1], lo_pad[-1] = -np.inf, np.inf
    vhi, vlo = hi_pad[:-1], lo_pad[:-1]
    span = float(max(vhi.max() - vlo.min(), 1e-300))
    big = 4.0 * span + 1.0
    vmin = float(vlo.min())
    # max hi of [s0, wl) and min lo of (wh, e1]: reduceat over interleaved bounds (empty -> +-inf)
    b = np.column_stack([s0, wl]).reshape(-1)
    pre = np.maximum.reduceat(hi_pad, b)[::2]
    pre[wl <= s0] = -np.inf
    b = np.column_stack([wh + 1, e1 + 1]).reshape(-1)
    post = np.minimum.reduceat(lo_pad, b)[::2]
    post[wh + 1 > e1] = np.inf
    gw = np.repeat(np.arange(na), wlen)
    w_off = np.zeros(na + 1, dtype=np.int64)
    np.cumsum(wlen, out=w_off[1:])
    wpos = np.repeat(wl - w_off[:-1], wlen) + np.arange(W)  # cut after wpos
    off = gw * big
    pmax = np.maximum.accumulate(vhi[wpos] - vmin + off) - off + vmin
    pmax = np.maximum(pmax, pre[gw])
    smin = np.minimum.accumulate((vlo[wpos + 1] - vmin + off)[::-1])[::-1] - off + vmin
    smin = np.minimum(smin, post[gw])
    dev = np.abs(mid[wpos] - target[gw]) / np.maximum(window[gw] / slack, 1e-300)  # in final parts' measures
    cost = np.maximum(pmax - smin, 0.0) + 1e-9 * span * dev
    ws0 = w_off[:-1][wlen > 0]
    cmin = np.minimum.reduceat(cost, ws0)
    has = np.flatnonzero(wlen > 0)
    hit = np.flatnonzero(cost == np.repeat(cmin, wlen[has]))
    best = hit[np.r_[True, gw[hit][1:] != gw[hit][:-1]]]
    out = cut.copy()
    out[gw[best]] = wpos[best] - s0[gw[best]] + 1
    return out


def _grow_from_mains(
    indptr: np.ndarray, cols: np.ndarray, labels: np.ndarray, frag: np.ndarray, par: np.ndarray
) -> np.ndarray:
    """Labels where every fragment cell takes the label of the nearest main-piece cell (hops through
    fragment cells of the same parent; the shortest-path tree keeps each region connected to its
    main piece). Fragment cells no main piece reaches keep their label."""
    import scipy.sparse as sp  # scipy here only: ~0.2 s of start-up for the runs that never come here
    from scipy.sparse.csgraph import dijkstra

    n = labels.size
    e = np.flatnonzero(frag[cols])  # into fragment cells only (few), inside one parent
    a, b = _edge_rows(indptr, e), cols[e]
    keep = par[a] == par[b]
    a, b = a[keep], b[keep]
    src = np.unique(a[~frag[a]])
    if src.size == 0:
        return labels
    g = sp.csr_matrix((np.ones(a.size), (a, b)), shape=(n, n))
    _, _, source = dijkstra(
        g, directed=True, indices=src, unweighted=True, min_only=True, return_predecessors=True
    )
    out = labels.copy()
    hit = frag & (source >= 0)
    out[hit] = labels[source[hit]]
    return out


def _rows_of(indptr: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(row, entry) of every CSR entry of the rows `cells`, row by row in that order (CSR order when
    increasing), and the row pointers of those rows alone: no (nnz,) pass."""
    dg = indptr[cells + 1] - indptr[cells]
    ptr = row_pointers(dg)
    return np.repeat(cells, dg), np.repeat(indptr[cells] - ptr[:-1], dg) + np.arange(ptr[-1]), ptr


def _edge_rows(indptr: np.ndarray, e: np.ndarray) -> np.ndarray:
    """The row of each entry `e` of a CSR (a search per entry: no (nnz,) array of rows)."""
    return np.searchsorted(indptr, e, side="right") - 1


def _small_labels(labels: np.ndarray) -> np.ndarray:
    """labels as int32 when they fit (half the memory traffic of the (nnz,) arrays made from them)."""
    return labels.astype(np.int32) if labels.size and labels.max() < 2**31 else labels


def _label_pieces(
    indptr: np.ndarray, indices: np.ndarray, labels: np.ndarray, cells: np.ndarray | None = None
) -> tuple[int, np.ndarray]:
    """Connected pieces of the parts `labels` (edges inside a part only) over all cells, or over
    `cells` (increasing ids, whole parts only): (number, piece of each cell). Pieces are numbered
    in the order of their first cell (scipy's numbering: one scan over the nodes)."""
    fc = _compiled()
    if fc is not None and indptr.dtype == np.int64 and indices.dtype == np.int64:  # union-find in C
        lab = np.ascontiguousarray(labels, dtype=np.int64)
        sub = np.empty(0, dtype=np.int64) if cells is None else np.ascontiguousarray(cells, dtype=np.int64)
        comp = np.empty(labels.size if cells is None else sub.size, dtype=np.int32)
        if comp.size:
            return fc.pieces(
                np.ascontiguousarray(indptr), np.ascontiguousarray(indices), lab, sub, comp
            ), comp
    if cells is None:
        ptr, nb = indptr, indices
        lab = _small_labels(labels)
        same = np.repeat(lab, np.diff(indptr)) == lab[indices]
        m = labels.size
    else:  # the rows of `cells` only, renumbered 0..len(cells)-1
        rows, e, ptr = _rows_of(indptr, cells)
        nb = indices[e]
        same = labels[rows] == labels[nb]
        m = cells.size
    ptr = kept_pointers(same, ptr)
    nb = nb[same]
    if cells is not None:
        loc = np.empty(labels.size, dtype=np.int64)
        loc[cells] = np.arange(m)
        nb = loc[nb]
    import scipy.sparse as sp  # the fallback only (no compiled module)
    from scipy.sparse.csgraph import connected_components

    g = sp.csr_matrix((np.ones(nb.size, dtype=np.int8), nb, ptr), shape=(m, m))
    return connected_components(g, directed=False)


def _update_pieces(indptr, indices, labels, before, comp, clab, first_cell):
    """The pieces after `before` became `labels`: those of parts that gained or lost cells found
    again, the others kept; all numbered by their first cell as one pass over all cells would
    (_label_pieces). Returns (number, piece of each cell, first cell of each piece)."""
    changed = before != labels
    if not changed.any():
        return first_cell.size, comp, first_cell
    dirty = np.zeros(int(max(before.max(), labels.max())) + 1, dtype=bool)
    dirty[before[changed]] = True
    dirty[labels[changed]] = True
    cells = np.flatnonzero(dirty[labels])
    nd, cd = _label_pieces(indptr, indices, labels, cells)
    keep = np.flatnonzero(~dirty[clab])  # pieces of untouched parts, unchanged
    firsts = np.concatenate([first_cell[keep], cells[np.flatnonzero(run_starts(np.maximum.accumulate(cd)))]])
    order = np.argsort(firsts, kind="stable")  # two sorted runs of distinct cells: one merge
    rank = np.empty(order.size, dtype=np.int64)
    rank[order] = np.arange(order.size)
    renum = np.full(clab.size, -1, dtype=np.int64)
    renum[keep] = rank[: keep.size]
    out = renum[comp]
    out[cells] = rank[keep.size + cd]
    return order.size, out, firsts[order]


def make_connected(
    indptr: np.ndarray,
    indices: np.ndarray,
    weights: np.ndarray,
    labels: np.ndarray,
    parent: np.ndarray | None = None,
    measures: np.ndarray | None = None,
    max_rounds: int = 100,
    within: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Every part keeps its largest connected piece; other pieces join the neighbouring part (of
    the same parent) that touches them along the longest interface, preferring parts' main pieces.
    Pieces with no neighbour in their parent (possible when the parent is itself disconnected) then
    join any neighbouring part, or with `within` (a label per node: physical groups) any
    neighbouring part of their own `within`, never another's. Returns (labels, pieces moved).
    Parts stay non-empty."""
    n = labels.size
    labels = np.asarray(labels, dtype=np.int64).copy()
    mes = np.ones(n) if measures is None else np.asarray(measures, dtype=np.float64)
    par = np.zeros(n, dtype=np.int64) if parent is None else np.asarray(parent, dtype=np.int64)
    # the last resort's parent: none, or the node's `within` (its part may not leave it)
    last = np.zeros(n, dtype=np.int64) if within is None else np.asarray(within, dtype=np.int64)
    if parent is None and within is not None:
        par = last
    moved_total = 0
    free = parent is None
    rnd = 0
    comp = clab = first_cell = None  # the last round's pieces (numbered by their first cell), their labels
    before = labels  # the labels those pieces were found for
    while rnd < max_rounds:  # in practice 1 to 3 rounds
        if comp is None:
            nc, comp = _label_pieces(indptr, indices, labels)
            first_cell = np.flatnonzero(run_starts(np.maximum.accumulate(comp)))
        elif before is not labels:  # only parts that gained or lost cells have new pieces
            nc, comp, first_cell = _update_pieces(indptr, indices, labels, before, comp, clab, first_cell)
        before = labels
        k = int(labels.max()) + 1
        if nc == k:
            break
        cm = np.bincount(comp, weights=mes, minlength=nc)
        clab = np.empty(nc, dtype=np.int64)
        clab[comp] = labels
        # main piece of each part: largest measure (ties: lowest piece id); parts of one piece: it
        main = np.bincount(clab, minlength=k)[clab] == 1
        multi = np.flatnonzero(~main)
        cl, cmm = clab[multi], cm[multi]
        top = np.full(k, -np.inf)
        np.maximum.at(top, cl, cmm)
        cand = multi[cmm == top[cl]]  # the largest pieces of their parts, increasing ids
        win = np.full(k, nc, dtype=np.int64)
        np.minimum.at(win, clab[cand], cand)  # ties: the lowest piece id
        main[win[win < nc]] = True
        frag_cell = ~main[comp]
        # edges leaving fragment cells into another part of the same parent (as indices: fragments are few)
        a, e, _ = _rows_of(indptr, np.flatnonzero(frag_cell))
        b = indices[e]
        keep = (labels[a] != labels[b]) & (par[a] == par[b])
        e, a, b = e[keep], a[keep], b[keep]  # the edges' rows and columns
        if e.size == 0:
            if free:
                break
            free, par, rnd = True, last, 0  # last resort: any neighbour
            continue
        if rnd >= 1:
            # what is left after one round: every fragment cell joins the main piece it reaches first
            # through fragment cells of its parent (one multi-source BFS), so one pass connects all
            new = _grow_from_mains(indptr, indices, labels, frag_cell, par)
            if np.array_equal(new, labels):
                if free:
                    break
                free, par, rnd = True, last, 0
                continue
            moved_total += int(np.count_nonzero(new != labels))
            labels = new
            rnd += 1
            continue
        # interface weight per (fragment piece, neighbour label); main pieces of neighbours count double
        to_main = main[comp[b]]
        bonus = np.where(to_main, 2.0, 1.0)
        key_p, key_l = comp[a], labels[b]
        import scipy.sparse as sp  # a fragment to move: scipy's COO sum

        m = sp.coo_matrix((weights[e] * bonus + 1e-12, (key_p, key_l)), shape=(nc, k)).tocsr()
        m.sum_duplicates()
        # per row the largest interface, ties: the lowest label (rows sorted by column); no sort
        rows_nz = np.flatnonzero(np.diff(m.indptr))
        target = np.full(nc, -1, dtype=np.int64)
        if rows_nz.size:
            r = np.repeat(np.arange(nc), np.diff(m.indptr))
            top = np.maximum.reduceat(m.data, m.indptr[rows_nz])
            hit = np.flatnonzero(m.data == np.repeat(top, np.diff(m.indptr)[rows_nz]))
            best = hit[run_starts(r[hit])]
            target[r[best]] = m.indices[best]
        # only pieces touching a main piece move this round (they then join a connected part)
        touches_main = np.zeros(nc, dtype=bool)
        touches_main[comp[a[to_main]]] = True
        go = (target >= 0) & ~main & (touches_main | ~touches_main.any())
        if not go.any():
            if free:
                break
            free, par, rnd = True, last, 0
            continue
        mv = go[comp]
        labels = labels.copy()
        labels[mv] = target[comp[mv]]
        moved_total += int(go.sum())
        rnd += 1
    return labels, moved_total


def cut_and_connect(
    batch: GraphBatch,
    grp: np.ndarray,
    need: np.ndarray,
    balance: str = "measure",
    boxes: tuple | None = None,
    slack: float = SLACK,
) -> np.ndarray:
    """split_counts + make_connected inside each group: (N,) labels, exact counts where possible."""
    w = batch.measures if balance == "measure" else np.ones(batch.n_nodes)
    lo, hi = boxes if boxes is not None else (None, None)
    lab = split_counts(
        grp, need, batch.centroids, np.maximum(np.asarray(w, dtype=np.float64), 1e-300), lo, hi, slack
    )
    lab, _ = make_connected(batch.indptr, batch.indices, batch.weights, lab, parent=grp, measures=w)
    return lab


def _quotient(indptr: np.ndarray, indices: np.ndarray, weights: np.ndarray, labels: np.ndarray, k: int):
    """CSR (indptr, indices, summed weights) of the graph of the parts `labels` (0..k-1)."""
    import scipy.sparse as sp

    fc = _compiled()
    if (
        fc is not None
        and k < 2**31
        and indptr.dtype == indices.dtype == np.int64
        and weights.dtype == np.float64
    ):
        m = indices.size  # the same entries, in the same order, in one pass
        rows, cols, w = np.empty(m, dtype=np.int32), np.empty(m, dtype=np.int32), np.empty(m)
        lab = np.ascontiguousarray(labels, dtype=np.int64)
        c = fc.cross_edges(
            np.ascontiguousarray(indptr), np.ascontiguousarray(indices), weights, lab, rows, cols, w
        )
        q = sp.csr_matrix((w[:c], (rows[:c], cols[:c])), shape=(k, k))
    else:
        lab = _small_labels(labels)
        rows = np.repeat(lab, np.diff(indptr))
        cols = lab[indices]
        off = rows != cols
        q = sp.csr_matrix((weights[off], (rows[off], cols[off])), shape=(k, k))
    q.sum_duplicates()
    return q.indptr.astype(np.int64), q.indices.astype(np.int64), q.data


def components(batch: GraphBatch, within: np.ndarray | None = None) -> np.ndarray:
    """Connected components of the batch graph (only edges inside equal `within` labels)."""
    n = batch.n_nodes
    indptr, indices = batch.indptr, batch.indices
    if n and _compiled() is not None:  # one union-find pass in C (the same numbering)
        lab = np.zeros(n, dtype=np.int64) if within is None else within
        return _label_pieces(indptr, indices, lab)[1].astype(np.int64)
    if within is not None:  # keep the CSR rows: the filtered graph without a COO conversion
        keep = np.repeat(within, np.diff(indptr)) == within[indices]
        indptr = kept_pointers(keep, indptr)
        indices = indices[keep]
    import scipy.sparse as sp  # the fallback only (no compiled module)
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    g = sp.csr_matrix((np.ones(indices.size), indices, indptr), shape=(n, n))
    if n == 0 or breadth_first_order(g, 0, directed=True, return_predecessors=False).size == n:
        return np.zeros(n, dtype=np.int64)  # cell 0 reaches every cell: one component (no transpose)
    return connected_components(g, directed=False)[1].astype(np.int64)


def cell_boxes(
    points: np.ndarray, offsets: np.ndarray, connectivity: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(C, dim) lower and upper corners of every cell's vertices (vectorized reduceat). One cell type:
    made axis by axis, so the arrays are column-major ((dim, C) contiguous, as the cuts read them)."""
    pts = np.asarray(points, dtype=np.float64)
    sizes = np.diff(offsets)
    if (
        sizes.size and sizes.min() == sizes.max() and offsets[0] == 0 and connectivity.size == offsets[-1]
    ):  # one cell type: the vertices' coordinates one axis at a time, no reduceat
        nv = int(sizes[0])
        dim = pts.shape[1]
        lo = np.empty((dim, sizes.size))
        hi = np.empty((dim, sizes.size))
        for d in range(dim):  # a loop over the axes
            col = np.ascontiguousarray(pts[:, d])
            np.take(col, connectivity[0::nv], out=lo[d])
            hi[d] = lo[d]
            for j in range(1, nv):  # a loop over the cell's vertices
                q = col[connectivity[j::nv]]
                np.minimum(lo[d], q, out=lo[d])
                np.maximum(hi[d], q, out=hi[d])
        return lo.T, hi.T
    p = pts[connectivity]
    starts = np.asarray(offsets[:-1], dtype=np.int64)
    return np.minimum.reduceat(p, starts, axis=0), np.maximum.reduceat(p, starts, axis=0)


def rtree_levels(
    batch: GraphBatch,
    counts: list[int],
    groups: np.ndarray | None = None,
    balance: str = "measure",
    boxes: tuple | None = None,
    slack: float = SLACK,
    graphs: list | None = None,
    axes: str = "box",
    coupling: np.ndarray | None = None,
) -> list[np.ndarray]:
    """Nested labels for the element counts `counts` (coarsest first), each level connected.

    The cuts of all levels are made first, top-down (each level's parts split into the next level's
    share, from one sort of the cells per axis). Then the levels are made connected bottom-up: the
    finest on the mesh's graph (pieces join a part of the same parent), every coarser one on the
    graph of the finer level's (connected) elements, which is ratio times smaller, so the elements
    of each level are unions of the finer level's: exactly nested, every element connected. With
    more than one level, every level's elements are numbered along the domain's principal axis
    (_sweep_key); a single level keeps the cuts' tree order.
    groups: optional (N,) labels (e.g. physical groups) no element may cross.
    graphs: a list that receives the CSR (indptr, indices) of the graph of each level's elements in
    the numbering of the returned labels (finest first, all levels but the coarsest; no repeats, no
    self loops; rows sorted where no sweep renumbered them).
    axes: "box" (the cuts across the longest extent of each part's box, compiled where built) or
    "principal" (split_principal: across each part's own principal axis; numpy only, no tight cuts) or
    "strength" / "strength-mincut" / "strength-position" (rtree_strength: axis and position by the least
    `coupling` (nnz,) of the batch graph, TPFA when None, per unit of cut / in all / position only)."""
    if axes not in ("box", "principal", "strength", "strength-mincut", "strength-position"):
        raise ParameterError(f"axes must be box, principal or strength[-mincut|-position], got {axes!r}")
    w = batch.measures if balance == "measure" else np.ones(batch.n_nodes)
    w = np.asarray(w, dtype=np.float64)
    wp = np.maximum(w, 1e-300)
    lo, hi = boxes if boxes is not None else (None, None)
    root = components(batch, groups)
    n_root = int(root.max()) + 1 if root.size else 0
    principal = axes == "principal"
    seg = None if principal else _Segments(batch.centroids, root, n_root)
    rule = strength_rule(batch, coupling, lo, hi, axes, slack) if axes[:8] == "strength" else None
    parent = root
    raw = []
    for c in counts:
        size = np.bincount(parent) if principal else seg.size
        need = apportion(np.bincount(parent, weights=w, minlength=size.size), int(c), size)
        if principal:
            parent = split_principal(parent, need, batch.centroids, wp)
        else:
            parent = split_counts(parent, need, batch.centroids, wp, lo, hi, slack, seg, rule)
        raw.append(parent)
    # element ids stay the raw part ids, so raw parent maps give each element's parents
    up = []  # up[L]: raw part of level L -> its raw part at level L-1 (root group for L = 0)
    for L, lab in enumerate(raw):
        pm = np.zeros(int(lab.max()) + 1 if lab.size else 0, dtype=np.int64)
        pm[lab] = raw[L - 1] if L > 0 else root
        up.append(pm)
    roots = None  # with groups: each raw part's root (a connected piece of one group), per level:
    if groups is not None:  # no repair moves a piece out of it
        roots = [up[0]]
        for L in range(1, len(raw)):
            roots.append(roots[L - 1][up[L]])
    # finest level: pieces of a part join a neighbouring part of the same (raw) parent
    fine, _ = make_connected(
        batch.indptr,
        batch.indices,
        batch.weights,
        raw[-1],
        parent=up[-1][raw[-1]],
        measures=w,
        within=None if roots is None else root,
    )
    sweep = len(raw) > 1  # a hierarchy: every level's elements numbered along one sweep (_sweep_key)
    node_lab, node_w = fine, w  # nodes of the graph at hand: cells, then elements of the finer level
    node_s = w * _sweep_key(batch.centroids, w) if sweep else None
    qp, qi, qw = batch.indptr, batch.indices, batch.weights
    maps = [None] * len(raw)  # maps[L]: raw element of level L+1 -> its raw element of level L
    rank = [None] * len(raw)  # rank[L]: raw element of level L -> its number along the sweep
    for L in range(len(raw) - 2, -1, -1):
        k_f = up[L + 1].size
        qp, qi, qw = _quotient(qp, qi, qw, node_lab, k_f)  # graph of level L+1's elements
        node_w = np.bincount(node_lab, weights=node_w, minlength=k_f)
        init = up[L + 1]  # raw level-L part of each level-(L+1) element
        lab, _ = make_connected(
            qp,
            qi,
            qw,
            init,
            parent=up[L][init],
            measures=node_w,
            within=None if roots is None else roots[L + 1],
        )
        if sweep:
            node_s = np.bincount(node_lab, weights=node_s, minlength=k_f)
            rank[L + 1] = _sweep_rank(node_s / np.maximum(node_w, 1e-300))
        if graphs is not None:  # in the numbering of the returned labels
            graphs.append((qp, qi) if not sweep else _renamed(qp, qi, rank[L + 1]))
        maps[L] = lab
        node_lab = lab
    if sweep:
        k0 = int(node_lab.max()) + 1
        rank[0] = _sweep_rank(
            np.bincount(node_lab, weights=node_s, minlength=k0)
            / np.maximum(np.bincount(node_lab, weights=node_w, minlength=k0), 1e-300)
        )
    out = [None] * len(raw)
    out[-1] = fine if not sweep else rank[-1][fine]
    for L in range(len(raw) - 2, -1, -1):
        m = maps[L]
        if sweep:  # numbered element of level L+1 -> numbered element of level L
            m = np.empty_like(maps[L])
            m[rank[L + 1]] = rank[L][maps[L]]
        out[L] = m[out[L + 1]]
    return out


def _renamed(indptr: np.ndarray, indices: np.ndarray, rank: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The CSR graph with node i renamed rank[i]: rows moved, columns renamed (each row's entries
    keep their order, so rows are not sorted)."""
    inv = np.empty_like(rank)
    inv[rank] = np.arange(rank.size)
    _, src, ptr = _rows_of(indptr, inv)
    return ptr, rank[indices[src]]


def _sweep_key(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N,) position of every cell along the principal axis of the whole domain (measure-weighted).

    A hierarchy's elements are numbered in this order, level by level: a Gauss-Seidel smoother then
    sweeps every level across the domain once, as a lexicographic sweep does, instead of zig-zagging
    through the tree order of the cuts (PCG iterations with pyamg's V-cycle at ratio 8, averaged over
    twelve rotations of the brain: 34.0 -> 33.3; six of the refined quads: 63.7 -> 62.3)."""
    # no BLAS: a threaded BLAS sums in an order that depends on the thread count (the 1M cube's
    # numbering differed between 1 and 2 threads) and leaves woken threads spinning for ~0.1 s of CPU
    W = max(float(w.sum()), 1e-300)
    xw = x * w[:, None]
    mean = xw.sum(axis=0) / W
    dim = x.shape[1]
    cov = np.empty((dim, dim))
    for i in range(dim):  # a loop over pairs of axes
        for j in range(i, dim):
            cov[i, j] = cov[j, i] = (xw[:, i] * x[:, j]).sum()
    cov = cov / W - np.outer(mean, mean)
    v = np.linalg.eigh(cov)[1][:, -1]
    v = v if v[np.argmax(np.abs(v))] > 0 else -v  # a fixed sign: the same numbering everywhere
    key = x[:, 0] * v[0]
    for d in range(1, dim):  # a loop over the axes
        key += x[:, d] * v[d]
    return key


def _sweep_rank(key: np.ndarray) -> np.ndarray:
    """rank[e]: the number of element e when the elements are sorted by key (ties: lower id first)."""
    rank = np.empty(key.size, dtype=np.int64)
    rank[np.argsort(key, kind="stable")] = np.arange(key.size)
    return rank


# how far the repeated steps of a hierarchy may be stretched or shrunk (a fraction of the requested
# ratio) so that they are even and the coarsest level lands near --coarsest (issue 24: the old plan's
# last step was whatever was left, e.g. 14 -> 1 elements, and one element cannot hold a holed domain)
STRETCH = 0.15


def level_counts(
    n: int, ratio, coarsest: int = 1, stretch: float = STRETCH, given: int | None = None, least: int = 1
) -> list[int]:
    """Element counts of a hierarchy, coarsest first, down to at most `coarsest` elements (at least 1).

    ratio: one number (every step), or a schedule (finest step first, the last one repeated), e.g.
    (5, 12): the finest level n / 5 elements, every coarser one about 12 times fewer. The head of the
    schedule (of one number: the finest step) is taken as given; the repeated steps are planned
    from the coarse end (_even_steps): all of one size, at least ratio * (1 - stretch) and within
    RATIO_SLACK of the ratio, so that the coarsest level is near `coarsest` instead of whatever the
    last division leaves (14 -> 1 elements, say). stretch = 0: no step below the ratio. given: how
    many leading steps are taken as given (default: the schedule's head, or 1 for one number; 0: every
    step planned). least: the fewest elements the coarsest level may have (a domain with a hole: 2;
    a level that would then not coarsen is left out)."""
    steps = [float(r) for r in np.atleast_1d(np.asarray(ratio, dtype=np.float64))]
    if not steps or not all(r >= 2 for r in steps):
        raise ParameterError(f"ratio must be >= 2, got {ratio!r}")
    if coarsest < 1:
        raise ParameterError(f"coarsest must be >= 1, got {coarsest!r}")
    counts = []
    c = n
    if given is None:
        head = steps[:-1] or steps
    else:
        head = [steps[min(j, len(steps) - 1)] for j in range(given)]
    for r in head:  # the schedule's head (one number: the finest step), as given
        if c <= coarsest:
            break
        c = max(1, int(np.ceil(c / r - 1e-9)))
        counts.append(c)
    if c > coarsest:
        counts += _even_steps(c, steps[-1], coarsest, stretch, least)
    _hold(counts, least)
    return counts[::-1]


def _hold(counts: list[int], least: int) -> None:
    """Counts (finest first) held to `least` at the coarse end, in place: last counts below it
    dropped while the one before is no more than it, else the last raised to it."""
    while counts and counts[-1] < least:
        if len(counts) > 1 and counts[-2] <= least:
            counts.pop()
        else:
            counts[-1] = int(least)


def _even_steps(c: int, r: float, coarsest: int, stretch: float, least: int = 1) -> list[int]:
    """Counts below c (finest first) in even steps near r down to at most `coarsest`: for each number
    of steps s near log_r(c / coarsest), the step x^(1/s) (x = c / coarsest) raised to r * (1 - stretch)
    where smaller (the coarsest level then below `coarsest`); the s whose whole-number counts keep
    every step nearest r (the largest |step / r - 1| least; a step above r * (1 + RATIO_SLACK) never).
    Where the best of those still leaves a step more than RATIO_SLACK off r (the last count rounded:
    a hexahedral plate of 86,265 finest aggregates got 34 > 3, 11.3 against 16), the steps that end
    exactly on a coarsest count e (least <= e <= coarsest, within the slack) are tried too (14.4
    ends on 2)."""
    x = c / coarsest
    s0 = max(1, int(np.ceil(np.log(x) / np.log(r) - 1e-12)))
    lo, hi = r * (1.0 - stretch), r * (1.0 + RATIO_SLACK)
    tries = [(s, max(x ** (1.0 / s), lo)) for s in range(max(1, s0 - 1), s0 + 2)]
    best, best_dev = _best_steps(c, r, coarsest, s0, tries, least)
    if best_dev > RATIO_SLACK:
        ends = [
            (s, (c / e) ** (1.0 / s))
            for s in range(max(1, s0 - 1), s0 + 2)
            for e in range(max(1, int(least)), int(coarsest) + 1)
        ]
        # (down to the slack's floor here, not the stretch's: with --groups a torus inclusion's box
        # plans at least 4 coarsest of 7,683 aggregates, 480 > 30 > 4 (a last step of 7.5) where
        # 12.4 ends on 4)
        floor = r * (1.0 - RATIO_SLACK)
        more, more_dev = _best_steps(
            c, r, coarsest, s0, [(s, st) for s, st in ends if floor <= st <= hi], least
        )
        if more is not None and more_dev < best_dev - 1e-12:
            best = more
    return best


def _best_steps(
    c: int, r: float, coarsest: int, s0: int, tries, least: int = 1
) -> tuple[list[int] | None, float]:
    """Of the (steps, step size) tries, the whole-number counts whose largest |step / r - 1| is least
    (_even_steps), each judged as level_counts will hold it to `least` (a last count below it raised,
    or dropped where the one before is no more): (counts finest first, that deviation); (None, inf)
    for no try."""
    best, best_dev = None, np.inf
    for s, step in tries:
        if step > r * (1.0 + RATIO_SLACK) and s < s0 + 1:
            continue
        out, prev = [], c
        for j in range(1, s + 1):
            prev = min(max(1, int(np.floor(c / step**j + 0.5))), max(prev - 1, 1))  # nearest
            out.append(prev)
        if out[-1] > coarsest:  # whole numbers rounded up past it: one step more
            out.append(max(1, min(coarsest, int(np.ceil(out[-1] / r - 1e-9)))))
        _hold(out, least)  # (as level_counts will)
        ratios = np.array([c, *out[:-1]], dtype=np.float64) / np.array(out, dtype=np.float64)
        dev = float(np.max(np.abs(ratios / r - 1.0)))
        if dev < best_dev - 1e-12:
            best, best_dev = out, dev
    return best, best_dev


RATIO_SLACK = 0.25  # issue 24: every level within 25% of the requested ratio


class RTreePartitioner(Partitioner):
    """Recursive measure-weighted box cuts with exact counts and connected parts (see module doc)."""

    name = "rtree"
    supports_kway = True
    description = (
        "Nested geometric agglomeration: box cuts along the longest extent at measure-weighted "
        "quantiles (exact counts), connected parts; fast, vectorized, any ratio per level."
    )

    wants_cell_boxes = True  # agglomerate() fills GraphBatch.cell_boxes for the tight cuts

    def __init__(self, seed: int = 0, balance: str = "measure", slack: float = SLACK):
        if balance not in ("measure", "cells"):
            raise ParameterError(f"balance must be 'measure' or 'cells', got {balance!r}")
        if not 0 <= slack <= 1:
            raise ParameterError(f"slack must be in [0, 1], got {slack!r}")
        self.slack = float(slack)
        self.seed = int(seed)  # deterministic: kept for the common constructor signature
        self.balance = balance

    def kway(self, batch: GraphBatch, k: int) -> np.ndarray:
        n = batch.n_nodes
        if k <= 1 or n == 0:
            return np.zeros(n, dtype=np.int64)
        return rtree_levels(batch, [int(k)], balance=self.balance, boxes=batch.cell_boxes, slack=self.slack)[
            0
        ]

    def bisect_batch(self, batch: GraphBatch) -> np.ndarray:
        gi = batch.graph_index()
        sizes = np.diff(batch.graph_ptr)
        need = np.where(sizes >= 2, 2, 1)
        lab = cut_and_connect(batch, gi, need, self.balance, batch.cell_boxes, self.slack)
        first = np.cumsum(np.r_[0, need[:-1]])  # the first part of each graph -> side 0
        return (lab != first[gi]).astype(np.int64)

"""Refiners: improve a partition given on a `GraphBatch` (scikit-learn style like partitioners).

`refine(batch, labels)` takes a bisection of every graph of the batch (labels in {0, 1}) and
returns a better one; `refine_kway(batch, labels)` takes any partition of the batch and moves
boundary nodes between parts. The cut and the volumes use the batch's edge counts and degree
volumes, so on a coarsened graph they are the fine graph's.

`fm` (Fiduccia-Mattheyses style, vectorized over the batch):
- bisection: on the band of nodes within `hops` of the cut, each step moves, in every graph at
  once, the unlocked node whose move lowers the normalized cut most (possibly a negative gain, to
  climb out of local minima) within the balance tolerance; a moved node is locked. After at most
  budget_factor x (cut + 1) steps each graph rolls back to the best prefix of its moves. Passes
  repeat while they gain. Then stray islands go to the other side (both sides connected); `tries`
  runs (default 3 on batches up to 20k nodes, else 1; the later ones break ties between equal
  gains at random) and a graph keeps its old
  bisection unless a refined one has a strictly lower normalized cut (the best one). After a
  whole recursive bisection, `polish` refines pairs of adjacent final parts for their share of
  the k-way normalized cut: flow refinement (below) first, then pairwise FM.
- k-way: first flow refinement (models.partition.flow: for pairs of adjacent parts, a minimum cut inside a
  band around their boundary whose size keeps a balanced cut possible, pairs by a matching of the
  quotient graph per round, parts kept connected and within the cap), then rounds of simultaneous
  positive-gain moves of boundary nodes to the neighbouring part
  they share most edges with, on an independent set (no two moved nodes adjacent, so every gain
  is exact), within the balance tolerance; a move that would disconnect its part is undone.
"""

from __future__ import annotations

import importlib

import numpy as np
import scipy.sparse as sp

from models.errors import ParameterError, listed
from models.graph.batch import GraphBatch
from models.partition.flow import part_components

REFINERS: dict[str, str] = {
    "fm": "models.partition.refine:FMRefiner",
    "rl-refiner": "models.partition.rl:RLRefiner",
}


class Refiner:
    """Base class: subclasses set `name` and implement `refine` (and `refine_kway` if they can).

    Physical groups: a refiner only sees the batch's edge counts and volumes. To keep materials
    apart (agglomerate(keep_groups=...), on for sage-hetero) the caller hands it a batch whose
    edges between two groups count 1% (models.partition.groups.group_weighted: cuts drift to material
    interfaces) and keeps a refined result only where it mixes no more cells (keep_purer)."""

    name: str = "base"
    description: str = ""
    supports_kway: bool = False

    def refine(self, batch: GraphBatch, labels: np.ndarray) -> np.ndarray:
        """Better bisection of every graph of the batch: (N,) labels in {0, 1}."""
        raise NotImplementedError

    def refine_kway(self, batch: GraphBatch, labels: np.ndarray) -> np.ndarray:
        raise ParameterError(f"refiner {self.name!r} has no k-way mode")


def get_refiner(name: str, **options) -> Refiner:
    """Instantiate the refiner called `name` (ParameterError if unknown)."""
    if name not in REFINERS:
        raise ParameterError(f"unknown refiner {name!r}; choose one of {listed(sorted(REFINERS))}")
    module, factory = REFINERS[name].split(":")
    return getattr(importlib.import_module(module), factory)(**options)


def bisection_state(batch: GraphBatch, side: np.ndarray):
    """Per-node external/internal edge counts and per-graph cut, degree volumes and measures."""
    n = batch.n_nodes
    rows = np.repeat(np.arange(n), np.diff(batch.indptr))
    ec = batch.edge_counts()
    diff = side[rows] != side[batch.indices]
    ext = np.bincount(rows, weights=ec * diff, minlength=n)
    tot = np.bincount(rows, weights=ec, minlength=n)
    gi = batch.graph_index()
    B = batch.n_graphs
    cut = np.bincount(gi, weights=ext, minlength=B) / 2
    vol = np.bincount(gi * 2 + side, weights=batch.volumes(), minlength=2 * B).reshape(B, 2)
    meas = np.bincount(gi * 2 + side, weights=batch.measures, minlength=2 * B).reshape(B, 2)
    return rows, ec, ext, tot - ext, gi, cut, vol, meas


def _ncut(cut: np.ndarray, vol: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        v0 = np.where(vol[:, 0] > 0, 1 / vol[:, 0], np.inf)
        v1 = np.where(vol[:, 1] > 0, 1 / vol[:, 1], np.inf)
        return np.where(cut > 0, cut * (v0 + v1), 0.0)


def bisection_ncut(batch: GraphBatch, side: np.ndarray) -> np.ndarray:
    """(B,) normalized cut of each graph's bisection (inf when a side is empty and the cut is not)."""
    _, _, _, _, _, cut, vol, _ = bisection_state(batch, side)
    nc = _ncut(cut, vol)
    empty = (vol[:, 0] == 0) | (vol[:, 1] == 0)
    return np.where(empty & (np.diff(batch.graph_ptr) >= 2), np.inf, nc)


def cut_band(batch: GraphBatch, side: np.ndarray, hops: int) -> np.ndarray:
    """(N,) bool: nodes at most `hops`-1 edges away from a node on the cut (hops >= 1)."""
    n = batch.n_nodes
    rows = np.repeat(np.arange(n), np.diff(batch.indptr))
    band = np.bincount(rows, weights=side[rows] != side[batch.indices], minlength=n) > 0
    for _ in range(max(hops, 1) - 1):
        band = band | (np.bincount(rows, weights=band[batch.indices], minlength=n) > 0)
    return band


def _segment_first_argmax(score: np.ndarray, seg: np.ndarray, n_seg: int) -> np.ndarray:
    """Index (into score) of the first maximum of each segment (segments contiguous, sorted);
    -1 where a segment is empty or all -inf."""
    out = np.full(n_seg, -1, dtype=np.int64)
    if score.size == 0:
        return out
    starts = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
    mx = np.maximum.reduceat(score, starts)
    gmx = np.full(n_seg, -np.inf)
    gmx[seg[starts]] = mx
    hit = np.flatnonzero((score == gmx[seg]) & np.isfinite(score))
    if hit.size:
        s = seg[hit]
        first = hit[np.r_[True, s[1:] != s[:-1]]]
        out[seg[first]] = first
    return out


class CutState:
    """A bisection of every graph of a batch with what a move needs, updated move by move:
    per-node external/internal edge counts, per-graph cut, degree volumes and measures."""

    def __init__(
        self,
        batch: GraphBatch,
        side: np.ndarray,
        tolerance: float = 0.05,
        cap: np.ndarray | None = None,
        third: np.ndarray | None = None,
    ):
        """cap (B,): the largest measure a side may have (k-way pairs: (1 + tol) x mean part);
        with it the objective is the edge cut, else the normalized cut with the tolerance.
        third (N,): edges of each node to nodes outside the batch (two parts of a k-way partition:
        their cut to the other parts), counted in each side's cut: the objective is then those two
        parts' share of the k-way normalized cut."""
        self.cap = None if cap is None else np.asarray(cap, dtype=np.float64)
        self.batch = batch
        self.side = np.asarray(side, dtype=np.int64).copy()
        _, self.ec, self.ext, self.inn, self.gi, self.cut, self.vol, self.meas = bisection_state(
            batch, self.side
        )
        self.d = batch.volumes()
        self.m = batch.measures
        self.total_m = self.meas.sum(axis=1)
        self.tol = float(tolerance)
        B = batch.n_graphs
        self.third = np.zeros(batch.n_nodes) if third is None else np.asarray(third, dtype=np.float64)
        self.X = np.bincount(self.gi * 2 + self.side, weights=self.third, minlength=2 * B).reshape(B, 2)

    def ncut(self) -> np.ndarray:
        if not self.X.any():
            return _ncut(self.cut, self.vol)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.vol[:, 0] > 0, (self.cut + self.X[:, 0]) / self.vol[:, 0], 0.0) + np.where(
                self.vol[:, 1] > 0, (self.cut + self.X[:, 1]) / self.vol[:, 1], 0.0
            )

    def objective(self) -> np.ndarray:
        """(B,) what the moves minimize: the normalized cut, or the edge cut when capped."""
        return self.ncut() if self.cap is None else self.cut.astype(np.float64).copy()

    def imbalance(self) -> np.ndarray:
        """(B,) |measure(side 0) - measure(side 1)| / measure(graph)."""
        return np.abs(self.meas[:, 0] - self.meas[:, 1]) / np.where(self.total_m > 0, self.total_m, 1.0)

    def evaluate(self, cand: np.ndarray):
        """For moving each node of `cand`: (normalized cut after, allowed) where allowed = the side
        it leaves stays non-empty and the imbalance stays within the tolerance or decreases."""
        cg = self.gi[cand]
        v_side = self.side[cand]
        d, m = self.d[cand], self.m[cand]
        with np.errstate(divide="ignore", invalid="ignore"):
            cut_new = self.cut[cg] - self.ext[cand] + self.inn[cand]
            vs = self.vol[cg, v_side] - d
            vt = self.vol[cg, 1 - v_side] + d
            t = self.third[cand]
            nc_new = (cut_new + self.X[cg, v_side] - t) / vs + (cut_new + self.X[cg, 1 - v_side] + t) / vt
            tm = np.where(self.total_m[cg] > 0, self.total_m[cg], 1.0)
            imb_new = np.abs(self.meas[cg, v_side] - m - self.meas[cg, 1 - v_side] - m) / tm
            imb_cur = np.abs(self.meas[cg, 0] - self.meas[cg, 1]) / tm
        if self.cap is not None:
            mt = self.meas[cg, 1 - v_side] + m
            ok = (vs > 0) & ((mt <= self.cap[cg]) | (mt <= self.meas[cg, v_side] - m))
            return cut_new.astype(np.float64), ok
        ok = (vs > 0) & ((imb_new <= self.tol) | (imb_new < imb_cur))
        return nc_new, ok

    def move(self, v: np.ndarray) -> None:
        """Move the nodes `v` (at most one per graph, so never two adjacent) to the other side."""
        batch = self.batch
        g = self.gi[v]
        old = self.side[v]
        new = 1 - old
        ext, inn = self.ext, self.inn
        self.cut[g] += inn[v] - ext[v]
        self.vol[g, old] -= self.d[v]
        self.vol[g, new] += self.d[v]
        self.meas[g, old] -= self.m[v]
        self.meas[g, new] += self.m[v]
        self.X[g, old] -= self.third[v]
        self.X[g, new] += self.third[v]
        self.side[v] = new
        # neighbours: an edge to a node now on the neighbour's side becomes internal, and vice versa
        indptr = batch.indptr
        cnt = indptr[v + 1] - indptr[v]
        src = np.repeat(np.arange(v.size), cnt)
        eidx = np.repeat(indptr[v] - np.r_[0, np.cumsum(cnt)[:-1]], cnt) + np.arange(int(cnt.sum()))
        u = batch.indices[eidx]
        w = self.ec[eidx]
        same_now = self.side[u] == new[src]
        np.add.at(ext, u, np.where(same_now, -w, w))
        np.add.at(inn, u, np.where(same_now, w, -w))
        ext[v], inn[v] = inn[v], ext[v]


def fm_pass(
    batch: GraphBatch,
    side: np.ndarray,
    tolerance: float,
    hops: int,
    budget: np.ndarray | None = None,
    score_fn=None,
    cap: np.ndarray | None = None,
    third: np.ndarray | None = None,
):
    """One FM pass over every graph of the batch with rollback to the best prefix.

    Returns (new side, per-graph normalized cut before, after). `score_fn(state, cand, gain)`
    -> (n_cand,) may replace the gain as the move priority (the RL refiner's policy); the
    rollback always uses the true normalized cut."""
    st = CutState(batch, side, tolerance, cap, third)
    B = batch.n_graphs
    band = cut_band(batch, st.side, hops)
    cand = np.flatnonzero(band)
    cg = st.gi[cand]
    if budget is None:
        budget = np.minimum(st.cut + 1, np.bincount(cg, minlength=B)).astype(np.int64)
    nc0 = st.objective()
    locked = np.zeros(cand.size, dtype=bool)
    n_steps = int(budget.max()) if budget.size else 0
    moves = np.full((n_steps, B), -1, dtype=np.int64)
    hist = np.full((n_steps, B), np.inf)
    for s in range(n_steps):
        nc_new, ok = st.evaluate(cand)
        ok &= (~locked) & (budget > s)[cg]
        if not ok.any():
            break
        nc_cur = st.objective()
        gain = nc_cur[cg] - nc_new
        score = gain if score_fn is None else score_fn(st, cand, gain)
        pick = _segment_first_argmax(np.where(ok, score, -np.inf), cg, B)
        got = pick >= 0
        if not got.any():
            break
        p = pick[got]
        g = np.flatnonzero(got)
        locked[p] = True
        st.move(cand[p])
        moves[s, g] = cand[p]
        hist[s, g] = st.objective()[g]
    side = st.side
    # rollback to the best prefix (strictly better than the start, else no move)
    if n_steps:
        best_step = np.argmin(hist, axis=0)
        best_val = hist[best_step, np.arange(B)]
        keep_upto = np.where(best_val < nc0 - 1e-12, best_step, -1)
        undo = (np.arange(n_steps)[:, None] > keep_upto[None, :]) & (moves >= 0)
        side[moves[undo]] ^= 1
        nc_after = np.where(keep_upto >= 0, best_val, nc0)
    else:
        nc_after = nc0
    return side, nc0, nc_after


class FMRefiner(Refiner):
    """Fiduccia-Mattheyses-style boundary refinement (see the module docstring)."""

    name = "fm"
    supports_kway = True
    description = (
        "FM: boundary gain moves (normalized cut for bisections, edge cut k-way) within a balance "
        "tolerance, rollback to the best prefix, parts kept connected; vectorized over the batch"
    )

    def __init__(
        self,
        tolerance: float = 0.05,
        hops: int = 4,
        passes: int = 8,
        kway_rounds: int = 30,
        kway_tolerance: float = 0.03,
        pair_rounds: int = 2,
        objective: str = "ncut",
        polish_rounds: int = 4,
        budget_factor: float = 2.0,
        tries: int | None = None,
        seed: int | None = 0,
        flow_rounds: int = 40,
        fm_max_nodes: int = 1_000,
        flow_hops: int | None = None,
        kway_flow_rounds: int | None = 12,
    ):
        if not 0 <= tolerance < 1:
            raise ParameterError(f"fm tolerance must be in [0, 1), got {tolerance}")
        self.tolerance = float(tolerance)
        self.hops = int(hops)
        self.passes = int(passes)
        self.kway_rounds = int(kway_rounds)
        self.kway_tolerance = float(kway_tolerance)
        self.pair_rounds = int(pair_rounds)
        if objective not in ("ncut", "cut"):
            raise ParameterError(f"fm objective must be 'ncut' or 'cut', got {objective!r}")
        self.objective = objective
        self.polish_rounds = int(polish_rounds)
        self.budget_factor = float(budget_factor)
        self.tries = tries  # None: 3 on batches up to 20k nodes, 1 above (each try is a full FM run)
        self.seed = seed
        self.flow_rounds = int(
            flow_rounds
        )  # flow refinement rounds of pairs of parts (models.partition.flow); 0 = off
        self.fm_max_nodes = int(fm_max_nodes)  # with flows: larger batches skip the move-by-move FM passes
        # k-way flows: bands at most flow_hops - 1 hops from the boundary; None: a quarter of a
        # mean part's width, sqrt(nodes per part) / 4, within [3, 12] (the band is also bounded by
        # measure). 12 rounds, METIS k-way start, cut vs METIS, 4 seeds, this rule vs a third of
        # the width within [4, 12]: brain k 128 -4.27% vs -4.21% (3 vs 4 hops, 12% less time),
        # brain k 32 -8.41% vs -7.93%, MeshEmilia k 64 -2.13 vs -2.16, 200^2 square k 64 -6.38 vs
        # -6.49 (9 vs 12 hops, 15% less time), k 512 -2.97 vs -3.11, gmsh cubes 20k k 128 -2.14
        # vs -2.18 and 99k k 256 -3.60 vs -3.60. Rounds = kway_flow_rounds, or flow_rounds when
        # None; 12 by default: on the brain at k 128 that keeps the k-way refinement within METIS
        # k-way's own time (40 rounds: -4.8% at ~2.3x)
        self.flow_hops = None if flow_hops is None else int(flow_hops)
        self.kway_flow_rounds = None if kway_flow_rounds is None else int(kway_flow_rounds)

    def refine(self, batch: GraphBatch, labels: np.ndarray) -> np.ndarray:
        labels = np.asarray(labels, dtype=np.int64)
        if batch.n_nodes == 0:
            return labels.copy()
        cap = None
        if self.objective == "cut":  # edge cut under a measure cap per side, judged by the normalized cut
            cap = (0.5 + self.tolerance / 2) * np.bincount(
                batch.graph_index(), weights=batch.measures, minlength=batch.n_graphs
            )
        best = labels
        if self.flow_rounds > 0:
            # flows first (min cuts in balance-bounded bands, every graph at once), FM from there
            from models.partition.flow import flow_bisections

            flowed = flow_bisections(batch, labels, self.tolerance, min(self.flow_rounds, 20), self.seed or 0)
            best = keep_better(batch, labels, connected_sides(batch, flowed))
            if batch.n_nodes > self.fm_max_nodes:  # FM's move-by-move rounds would take minutes here
                return best
        start = best
        tries = self.tries if self.tries is not None else (3 if batch.n_nodes <= 20_000 else 1)
        for t in range(max(int(tries), 1)):
            # later tries break ties between equal gains at random (seeded): another local optimum
            score_fn = None
            if t > 0:
                jitter = np.random.default_rng([self.seed or 0, t]).random(batch.n_nodes)

                def score_fn(st, cand, gain, jitter=jitter):
                    return gain + 1e-9 * jitter[cand] * np.abs(gain).max(initial=0)

            side = self._passes(batch, start, cap, score_fn)
            best = keep_better(batch, best, connected_sides(batch, side))
        return best

    def _passes(self, batch, labels, cap, score_fn):
        side = labels.copy()
        for _ in range(self.passes):
            budget = None
            if self.budget_factor != 1:
                st = CutState(batch, side)
                n_band = np.bincount(st.gi[cut_band(batch, side, self.hops)], minlength=batch.n_graphs)
                budget = np.minimum(np.ceil(self.budget_factor * (st.cut + 1)), n_band).astype(np.int64)
            side, before, after = fm_pass(
                batch, side, self.tolerance, self.hops, budget=budget, cap=cap, score_fn=score_fn
            )
            if not np.any(after < before - 1e-12):
                break
        return side

    def polish(self, batch: GraphBatch, labels: np.ndarray) -> np.ndarray:
        """After a recursive bisection: pairs of adjacent final parts refined for their share of
        the k-way normalized cut, by minimum cuts in bands around their boundary (models.partition.flow,
        parts within (1 + tolerance) x the mean part or no heavier than before) and then by
        pairwise FM; parts kept connected, no pair's share ever goes up."""
        labels = np.asarray(labels, dtype=np.int64)
        if self.flow_rounds > 0 and labels.size:
            from models.partition.flow import flow_kway

            labels = flow_kway(
                batch,
                labels,
                self.tolerance,
                self.flow_rounds,
                alpha=8.0,
                max_alpha=16.0,
                seed=self.seed or 0,
                objective="ncut",
                schedule="matching",
            )
        if self.polish_rounds <= 0:
            return labels
        return pairwise_fm(
            batch, labels, self.tolerance, self.polish_rounds, self.hops, self.seed or 0, "ncut"
        )

    def refine_kway(self, batch: GraphBatch, labels: np.ndarray) -> np.ndarray:
        if self.flow_rounds > 0:
            from models.partition.flow import flow_kway

            rounds = self.flow_rounds if self.kway_flow_rounds is None else self.kway_flow_rounds
            hops = self.flow_hops
            if hops is None:
                k = int(np.max(labels)) + 1 if labels.size else 1
                hops = int(np.clip(round(np.sqrt(labels.size / k) / 4), 3, 12))
            labels = flow_kway(
                batch,
                labels,
                self.kway_tolerance,
                rounds,
                alpha=8.0,
                max_alpha=16.0,
                max_hops=hops,
                seed=self.seed or 0,
                schedule="matching",
            )
            return kway_refine(batch, labels, self.kway_tolerance, self.kway_rounds)
        labels = kway_refine(batch, labels, self.kway_tolerance, self.kway_rounds)
        if self.pair_rounds > 0:
            labels = pairwise_fm(
                batch, labels, self.kway_tolerance, self.pair_rounds, self.hops, self.seed or 0
            )
            labels = kway_refine(batch, labels, self.kway_tolerance, self.kway_rounds)
        return labels


def connected_sides(batch: GraphBatch, side: np.ndarray) -> np.ndarray:
    """Stray islands of a side go to the other side (both sides of each connected graph connected)."""
    from models.partition.sage import contiguous_sides

    return contiguous_sides(batch, side, None)


def keep_better(batch: GraphBatch, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """`after` in the graphs where its normalized cut is strictly lower, else `before`."""
    nb = bisection_ncut(batch, before)
    na = bisection_ncut(batch, after)
    better = na < nb - 1e-12
    return np.where(better[batch.graph_index()], after, before)


def kway_refine(
    batch: GraphBatch, labels: np.ndarray, tolerance: float = 0.03, rounds: int = 30
) -> np.ndarray:
    """Greedy k-way boundary refinement of the edge cut (see the module docstring)."""
    labels = np.asarray(labels, dtype=np.int64).copy()
    n = batch.n_nodes
    if n == 0:
        return labels
    k = int(labels.max()) + 1
    rows = np.repeat(np.arange(n), np.diff(batch.indptr))
    cols = batch.indices
    ec = batch.edge_counts()
    m = batch.measures
    w_part = np.bincount(labels, weights=m, minlength=k)
    cap = (1 + tolerance) * w_part.sum() / k
    start_labels = labels.copy()
    comps0 = np.full(k, -1, dtype=np.int64)  # components per part at the start: read as parts lose nodes
    prio_jitter = None
    for _ in range(rounds):
        lr, lc = labels[rows], labels[cols]
        ext = lr != lc
        inn = np.bincount(rows, weights=ec * ~ext, minlength=n)
        if not ext.any():
            break
        # connection of each boundary node to each neighbouring part
        key = rows[ext] * k + lc[ext]
        uk, inv = np.unique(key, return_inverse=True)
        conn = np.bincount(inv, weights=ec[ext])
        node = uk // k
        part = uk % k
        # best target part per node: max conn (uk sorted by node)
        order = np.lexsort((-conn, node))
        firsts = order[np.r_[True, node[order][1:] != node[order][:-1]]]
        v, q, c = node[firsts], part[firsts], conn[firsts]
        gain = c - inn[v]
        fits = w_part[q] + m[v] <= cap
        ok = (gain > 0) & fits & (w_part[labels[v]] - m[v] > 0)
        v, q, gain = v[ok], q[ok], gain[ok]
        if v.size == 0:
            break
        # independent set: a candidate moves only if no adjacent candidate has a higher priority
        if prio_jitter is None:
            prio_jitter = np.random.default_rng(0).random(n) * 1e-3
        prio = np.full(n, -np.inf)
        prio[v] = gain + prio_jitter[v]
        nb_max = np.full(n, -np.inf)
        np.maximum.at(nb_max, rows, prio[cols])
        win = prio[v] > nb_max[v]
        v, q, gain = v[win], q[win], gain[win]
        # capacity per target part: best gains first
        o = np.lexsort((-gain, q))
        v, q = v[o], q[o]
        cum = np.cumsum(m[v])
        start = np.r_[True, q[1:] != q[:-1]]
        base = np.maximum.accumulate(np.where(start, cum - m[v], 0))
        fit = w_part[q] + (cum - base) <= cap
        v, q = v[fit], q[fit]
        if v.size == 0:
            break
        src = labels[v]
        lost = np.zeros(k, dtype=bool)
        lost[src] = True
        need = lost & (comps0 < 0)
        if need.any():
            comps0[need] = part_components(rows, cols, start_labels, k, need, batch.indptr)[need]
        labels[v] = q
        # undo the moves out of parts that lost their connectivity (only those parts are read)
        for _ in range(5):
            lost = np.zeros(k, dtype=bool)
            lost[src] = True
            broken = lost & (part_components(rows, cols, labels, k, lost, batch.indptr) > comps0)
            bad = broken[src]
            if not bad.any():
                break
            labels[v[bad]] = src[bad]
            v, q, src = v[~bad], q[~bad], src[~bad]
        if v.size == 0:
            break
        w_part = np.bincount(labels, weights=m, minlength=k)
    return labels


def pairwise_fm(
    batch: GraphBatch,
    labels: np.ndarray,
    tolerance: float = 0.03,
    rounds: int = 6,
    hops: int = 3,
    seed: int = 0,
    objective: str = "cut",
) -> np.ndarray:
    """k-way FM by pairs of parts: each round matches adjacent parts (heavy-edge matching on the
    quotient graph, weighted by their shared cut, randomized per round), runs one edge-cut FM pass
    with rollback on every pair at once (a batch of two-part graphs), moves stray islands back so
    both parts stay connected, and keeps a pair's new split only if its cut went down and neither
    part grew past (1 + tolerance) x the mean part measure (or past its own earlier measure).
    objective "ncut": the pair's share of the k-way normalized cut (its cut to the other parts
    included, degree volumes of the whole graph) under the bisection tolerance instead."""
    from models.mesh.dual import subgraph_by_labels
    from models.partition.coarsen import heavy_edge_matching

    labels = np.asarray(labels, dtype=np.int64).copy()
    n = batch.n_nodes
    if n == 0:
        return labels
    k = int(labels.max()) + 1
    rows = np.repeat(np.arange(n), np.diff(batch.indptr))
    cols = batch.indices
    ec = batch.edge_counts()
    # degree volumes (degrees on a fine graph); edge counts and volumes as given (models.partition.groups)
    full_deg = batch.volumes()
    cap = (1 + tolerance) * float(batch.measures.sum()) / k
    rng = np.random.default_rng(seed)
    for _ in range(rounds):
        lr, lc = labels[rows], labels[cols]
        x = lr != lc
        q = sp.csr_matrix((ec[x], (lr[x], lc[x])), shape=(k, k))
        q.sum_duplicates()
        q.sort_indices()
        qb = GraphBatch(
            indptr=q.indptr.astype(np.int64),
            indices=q.indices.astype(np.int64),
            weights=q.data,
            graph_ptr=np.array([0, k]),
            centroids=np.zeros((k, 1)),
            measures=np.ones(k),
            tags=None,
            node_ids=np.arange(k),
            edge_count=q.data.astype(np.float64),
            volume=1 + rng.random(k),
        )
        mate = heavy_edge_matching(qb, seed=int(rng.integers(2**31)))
        a = np.flatnonzero((mate >= 0) & (np.arange(k) < mate))
        if a.size == 0:
            break
        b = mate[a]
        pid = np.full(k, -1, dtype=np.int64)
        pid[a] = np.arange(a.size)
        pid[b] = np.arange(a.size)
        nodes = np.flatnonzero(pid[labels] >= 0)
        order, ptr, ip, ix, eid = subgraph_by_labels(
            batch.indptr, batch.indices, np.arange(cols.size), pid[labels[nodes]], nodes
        )
        pb = GraphBatch(
            indptr=ip,
            indices=ix,
            weights=batch.weights[eid],
            graph_ptr=ptr,
            centroids=batch.centroids[order],
            measures=batch.measures[order],
            tags=None,
            node_ids=order,
            edge_count=None if batch.edge_count is None else ec[eid],
            volume=full_deg[order],
        )
        side = (labels[order] == b[pid[labels[order]]]).astype(np.int64)
        if objective == "ncut":
            third = full_deg[order] - np.bincount(
                np.repeat(np.arange(order.size), np.diff(ip)), weights=ec[eid], minlength=order.size
            )
            new, _, _ = fm_pass(pb, side, tolerance, hops, third=third)
            new = connected_sides(pb, new)
            before, after = (
                CutState(pb, side, tolerance, third=third),
                CutState(pb, new, tolerance, third=third),
            )
            worse_balance = after.imbalance() > np.maximum(tolerance, before.imbalance()) + 1e-12
            ok = (after.ncut() < before.ncut() - 1e-12) & ~worse_balance & (after.meas.min(axis=1) > 0)
        else:
            caps = np.full(a.size, cap)
            new, _, _ = fm_pass(pb, side, tolerance, hops, cap=caps)
            new = connected_sides(pb, new)
            before, after = CutState(pb, side, cap=caps), CutState(pb, new, cap=caps)
            grew = np.any(after.meas > np.maximum(cap, before.meas) + 1e-12 * cap, axis=1)
            ok = (after.cut < before.cut) & ~grew & (after.meas.min(axis=1) > 0)
        take = ok[pb.graph_index()]
        gi = pid[labels[order]]
        labels[order[take]] = np.where(new[take] == 1, b[gi[take]], a[gi[take]])
    return labels

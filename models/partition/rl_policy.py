"""Reinforcement-learning bisection (MISSION.md section 4): the A2C networks, their environments
and their training (`magnet train rl-partitioner|rl-refiner`).

Both agents act on a whole batch of graphs at once (one action per graph per step, vectorized).
- RL refiner: starts from a (projected) bisection; on the band of nodes within `hops` of the cut
  it moves one node per step, either way (a moved node is locked, as in FM); reward = decrease of
  the normalized cut minus b x the increase of the squared relative imbalance, scaled by the
  graph's starting cut; episode = cut + 1 steps. Features: side (2), band-edge flag (masked),
  side volumes / total volume (2), fraction of the node's edges that are cut. Network: 2 shared
  SAGE layers, actor = SAGE + linear (a logit per node), critic = SAGE + linear + mean pool.
- RL partitioner: all nodes on side 0 but a minimum-degree seed; each step moves one side-0 node
  adjacent to side 1 to side 1 (the others are masked), so side 1 grows connected; reward =
  decrease of the normalized cut; |V|/2 steps. Features: side, principal-axis coordinates,
  fraction of cut edges. Network: 4 SAGE + 1 dense shared, actor 2 dense, critic attentional
  pooling + 2 dense.
Training is n-step A2C with a real critic: the value loss trains the critic (its value is not
detached from the value loss, only from the advantage in the policy loss), gamma 0.9, value-loss
weight 0.1, an entropy bonus, Adam 1e-3, updates every `n_step` steps.
"""

from __future__ import annotations

import numpy as np
import torch

from models.graph.batch import GraphBatch
from models.graph.csr import run_starts
from models.nets.rl import ActorCritic, _actor_logits, _actor_weights, _mean_csr, mean_adjacency
from models.partition.refine import CutState, _segment_first_argmax, cut_band

# ----------------------------------------------------------------------------- environments


def _sub_batch(batch: GraphBatch, nodes: np.ndarray):
    """CSR of the subgraph induced by sorted `nodes` (local numbering) and its graph index."""
    n = batch.n_nodes
    new = np.full(n, -1, dtype=np.int64)
    new[nodes] = np.arange(nodes.size)
    rows = np.repeat(np.arange(n), np.diff(batch.indptr))
    keep = (new[rows] >= 0) & (new[batch.indices] >= 0)
    r, c = new[rows[keep]], new[batch.indices[keep]]
    indptr = np.zeros(nodes.size + 1, dtype=np.int64)
    np.cumsum(np.bincount(r, minlength=nodes.size), out=indptr[1:])
    return indptr, c, keep


class RefinerEnv:
    """The refiner's environment on a batch: band, features, moves, rewards."""

    def __init__(
        self,
        batch: GraphBatch,
        side: np.ndarray,
        hops: int = 3,
        tolerance: float = 0.05,
        imbalance_weight: float = 0.35,
    ):
        self.batch = batch
        self.st = CutState(batch, side, tolerance)
        band = cut_band(batch, self.st.side, hops)
        self.nodes = np.flatnonzero(band)
        self.gi_np = self.st.gi[self.nodes]
        self.B = batch.n_graphs
        ip, ix, _ = _sub_batch(batch, self.nodes)
        self.adj = mean_adjacency(ip, ix, self.nodes.size)
        # band-edge nodes: a neighbour outside the band (their view is cut off: masked out)
        n = batch.n_nodes
        rows = np.repeat(np.arange(n), np.diff(batch.indptr))
        outside = np.bincount(rows, weights=~band[batch.indices], minlength=n) > 0
        self.edge_flag = outside[self.nodes]
        self.tot = np.bincount(rows, weights=self.st.ec, minlength=n)[self.nodes]
        self.locked = np.zeros(self.nodes.size, dtype=bool)
        self.gi = torch.from_numpy(self.gi_np)
        self.start_cut = np.maximum(self.st.cut.copy(), 1.0)
        self.start_nc = np.maximum(self.st.ncut(), 1e-12)
        self.b = imbalance_weight
        self.budget = self.st.cut + 1

    def features(self, as_numpy: bool = False):
        st, v = self.st, self.nodes
        s = st.side[v]
        vt = np.maximum(st.vol.sum(axis=1), 1e-12)
        f = np.column_stack(
            [
                s == 0,
                s == 1,
                self.edge_flag,
                st.vol[self.gi_np, 0] / vt[self.gi_np],
                st.vol[self.gi_np, 1] / vt[self.gi_np],
                st.ext[v] / np.maximum(self.tot, 1e-12),
            ]
        )
        f = f.astype(np.float32)
        return f if as_numpy else torch.from_numpy(f)

    def mask(self, step: int) -> np.ndarray:
        _, ok = self.st.evaluate(self.nodes)
        return ok & ~self.locked & ~self.edge_flag & (self.budget > step)[self.gi_np]

    def potential(self) -> np.ndarray:
        return self.st.ncut() / self.start_nc + self.b * self.st.imbalance() ** 2

    def step(self, pick: np.ndarray) -> np.ndarray:
        """Apply one move per graph (pick: band index or -1); reward per graph."""
        before = self.potential()
        got = pick >= 0
        if got.any():
            self.locked[pick[got]] = True
            self.st.move(self.nodes[pick[got]])
        return np.where(got, before - self.potential(), 0.0)


class PartitionerEnv:
    """The partitioner's environment: grow side 1 from a minimum-degree seed to half the measure."""

    def __init__(self, batch: GraphBatch):
        self.batch = batch
        n = batch.n_nodes
        gi = batch.graph_index()
        deg = batch.degrees()
        side = np.zeros(n, dtype=np.int64)
        # seed: the first node of minimum degree in each non-empty graph
        key = deg.astype(np.float64) + np.arange(n) / (n + 1.0)
        sizes = np.diff(batch.graph_ptr)
        ne = sizes > 0
        mn = np.minimum.reduceat(key, batch.graph_ptr[:-1][ne])
        seed = np.flatnonzero(np.isin(key, mn))
        side[seed] = 1
        self.st = CutState(batch, side, 1.0)
        self.gi_np = gi
        self.gi = torch.from_numpy(gi)
        self.B = batch.n_graphs
        self.adj = mean_adjacency(batch.indptr, batch.indices, n)
        self.tot = np.maximum(
            np.bincount(np.repeat(np.arange(n), deg), weights=self.st.ec, minlength=n), 1e-12
        )
        self.coords = _principal_coords(batch)
        self.n_steps = np.maximum(sizes // 2 - 1, 0)  # the seed is one node already

    def features(self) -> torch.Tensor:
        st = self.st
        f = np.column_stack([st.side, self.coords, st.ext / self.tot])
        return torch.from_numpy(f.astype(np.float32))

    def mask(self, step: int) -> np.ndarray:
        """Side-0 nodes next to side 1; in a graph where there is none (side 1 filled its connected
        piece of a disconnected graph) any side-0 node."""
        live = (self.st.side == 0) & (self.n_steps > step)[self.gi_np]
        m = live & (self.st.ext > 0)
        has = np.bincount(self.gi_np, weights=m, minlength=self.B) > 0
        return m | (live & ~has[self.gi_np])

    def potential(self) -> np.ndarray:
        return np.minimum(self.st.ncut(), 4.0)

    def step(self, pick: np.ndarray) -> np.ndarray:
        before = self.potential()
        got = pick >= 0
        if got.any():
            self.st.move(pick[got])
        return np.where(got, before - self.potential(), 0.0)


def _principal_coords(batch: GraphBatch) -> np.ndarray:
    """Coordinates centred, on principal axes, unit variance, per graph (as SAGE-Base's features)."""
    from models.nets.gnn import normalize_features

    x = torch.from_numpy(np.column_stack([batch.centroids, batch.measures]).astype(np.float32))
    gi = torch.from_numpy(batch.graph_index())
    return normalize_features(x, gi, batch.n_graphs, batch.dim)[:, : batch.dim].numpy()


# -------------------------------------------------------------------------------- inference


def _band_csr(env: RefinerEnv):
    """CSR of the band's induced subgraph (band numbering), cached on the environment."""
    if getattr(env, "_csr", None) is None:
        ip, ix, _ = _sub_batch(env.batch, env.nodes)
        env._csr = (ip, ix)
    return env._csr


def _induced(ip: np.ndarray, ix: np.ndarray, keep: np.ndarray):
    """CSR induced by the sorted band indices `keep` (whole graphs: no edge leaves them)."""
    new = np.full(ip.size - 1, -1, dtype=np.int64)
    new[keep] = np.arange(keep.size)
    deg = ip[keep + 1] - ip[keep]
    src = np.repeat(ip[keep] - np.r_[0, np.cumsum(deg)[:-1]], deg) + np.arange(int(deg.sum()))
    c = new[ix[src]]
    out = np.zeros(keep.size + 1, dtype=np.int64)
    np.cumsum(deg, out=out[1:])
    return out, c


def _policy_pass(model: ActorCritic, env: RefinerEnv, steps: int, per_pass: int, slack: int = 8):
    """One greedy episode of the policy on `env` (the moves and the normalized cut after each).

    Same decisions as taking, at every step, the argmax logit over the whole masked band of each
    graph (first index on ties), the logits refreshed every `per_pass` steps, but cheaper:
    - the forward pass runs only on the band of the graphs whose move budget is not spent (the
      graphs are disjoint, so their logits are unchanged);
    - after a forward pass each graph keeps its `per_pass + slack` best unlocked movable nodes in
      logit order, and a step evaluates only those (the mask of the whole band only for a graph
      whose short list has no allowed node left);
    - no reward bookkeeping (inference)."""
    st, B = env.st, env.B
    weights = _actor_weights(model)
    moves = np.full((steps, B), -1, dtype=np.int64)
    hist = np.full((steps, B), np.inf)
    ip, ix = _band_csr(env)
    gi = env.gi_np
    movable = ~env.edge_flag
    fwd_nodes = None  # band indices of the last forward's subgraph
    s = 0
    while s < steps:
        live_g = env.budget > s
        live = live_g[gi]
        if fwd_nodes is None or live.sum() < 0.7 * fwd_nodes.size:
            fwd_nodes = np.flatnonzero(live)
            if fwd_nodes.size == 0:
                break
            sip, six = (ip, ix) if fwd_nodes.size == gi.size else _induced(ip, ix, fwd_nodes)
            adj = _mean_csr(sip, six)
        x = env.features(as_numpy=True)
        logits = _actor_logits(weights, x if fwd_nodes.size == gi.size else x[fwd_nodes], adj)
        # the short lists: unlocked movable nodes of live graphs, by graph then logit (desc) then index
        ok0 = movable[fwd_nodes] & ~env.locked[fwd_nodes] & live[fwd_nodes]
        c = fwd_nodes[ok0]
        if c.size == 0:
            break
        order = np.lexsort((c, -logits[ok0], gi[c]))
        c = c[order]
        cg = gi[c]
        start = np.flatnonzero(np.r_[True, cg[1:] != cg[:-1]])
        rank = np.arange(c.size) - np.repeat(start, np.diff(np.r_[start, c.size]))
        keep = rank < per_pass + slack
        cand, cand_g = c[keep], cg[keep]
        truncated = np.zeros(B, dtype=bool)
        truncated[cg[~keep]] = True
        full_order = c  # the whole sorted list, for the rare fallback
        taken = np.zeros(cand.size, dtype=bool)
        # what CutState.evaluate's mask needs, fixed for the window (an unmoved node keeps its side)
        cn = env.nodes[cand]
        csd = st.side[cn]
        k_s, k_o = cand_g * 2 + csd, cand_g * 2 + 1 - csd
        cd, cm = st.d[cn], st.m[cn]
        tm = np.where(st.total_m > 0, st.total_m, 1.0)
        ctm = tm[cand_g]
        any_move = False
        for _ in range(per_pass):
            if s >= steps:
                break
            vol, meas = st.vol.reshape(-1), st.meas.reshape(-1)
            imb_cur = (np.abs(st.meas[:, 0] - st.meas[:, 1]) / tm)[cand_g]
            imb_new = np.abs(meas[k_s] - meas[k_o] - 2 * cm) / ctm
            ok = (vol[k_s] - cd > 0) & ((imb_new <= st.tol) | (imb_new < imb_cur))
            ok &= ~taken & (env.budget > s)[cand_g]
            pick = np.full(B, -1, dtype=np.int64)
            hit = np.flatnonzero(ok)
            if hit.size:
                hg = cand_g[hit]
                first = hit[run_starts(hg)]
                pick[cand_g[first]] = cand[first]
                taken[first] = True
            need = truncated & (pick < 0) & (env.budget > s)
            if need.any():  # a short list ran dry: the rest of that graph's sorted list
                sel = need[gi[full_order]] & ~env.locked[full_order]
                fo = full_order[sel]
                _, ok2 = st.evaluate(env.nodes[fo])
                h2 = np.flatnonzero(ok2)
                if h2.size:
                    g2 = gi[fo[h2]]
                    f2 = h2[run_starts(g2)]
                    pick[gi[fo[f2]]] = fo[f2]
            got = pick >= 0
            if not got.any():
                break
            any_move = True
            p = pick[got]
            env.locked[p] = True
            st.move(env.nodes[p])
            moves[s, got] = env.nodes[p]
            hist[s, got] = st.ncut()[got]
            s += 1
        if not any_move:
            break
    return moves, hist


def refine_with_policy(
    model: ActorCritic,
    batch: GraphBatch,
    side: np.ndarray,
    hops: int = 3,
    tolerance: float = 0.05,
    passes: int = 2,
    actions_per_pass: int = 1,
    max_forwards: int | None = None,
) -> np.ndarray:
    """Greedy policy moves (argmax logit) for at most cut + 1 steps, rollback to the best prefix.
    actions_per_pass > 1: that many moves per graph per forward pass (the logits of one pass, the
    mask refreshed after every move); max_forwards: at most that many forward passes per pass
    (more moves per pass on graphs with a long cut). See `_policy_pass` for what makes it fast."""
    from models.partition.refine import connected_sides, keep_better

    side0 = np.asarray(side, dtype=np.int64)
    cur = side0.copy()
    for _ in range(passes):
        env = RefinerEnv(batch, cur, hops, tolerance)
        nc0 = env.st.ncut()
        steps = int(env.budget.max()) if env.budget.size else 0
        per_pass = max(actions_per_pass, 1)
        if max_forwards:
            per_pass = max(per_pass, -(-steps // max_forwards))
        with torch.inference_mode():
            moves, hist = _policy_pass(model, env, steps, per_pass)
        new = env.st.side
        if steps:
            best = np.argmin(hist, axis=0)
            val = hist[best, np.arange(env.B)]
            upto = np.where(val < nc0 - 1e-12, best, -1)
            undo = (np.arange(steps)[:, None] > upto[None, :]) & (moves >= 0)
            new[moves[undo]] ^= 1
            if not np.any(val < nc0 - 1e-12):
                cur = new
                break
        cur = new
    return keep_better(batch, side0, connected_sides(batch, cur))


def partition_with_policy(
    model: ActorCritic, batch: GraphBatch, actions_per_pass: int = 4, window: float = 0.01
) -> np.ndarray:
    """Greedy growth of side 1, several moves per forward pass (the top logits of each graph, not
    adjacent... taken one after the other with the mask refreshed); keeps the least normalized cut
    inside +-window of half the measure (else the state nearest half)."""
    env = PartitionerEnv(batch)
    B = env.B
    best_nc = np.full(B, np.inf)
    best_side = env.st.side.copy()
    steps = int(env.n_steps.max()) if B else 0
    steps = steps + int(np.ceil(window * np.diff(batch.graph_ptr).max())) if B else 0
    env.n_steps = env.n_steps + np.ceil(window * np.diff(batch.graph_ptr)).astype(np.int64)
    s = 0
    with torch.inference_mode():
        while s < steps:
            m = env.mask(s)
            if not m.any():
                break
            logits, _ = model(env.features(), env.adj, env.gi, B)
            logits = logits.numpy().astype(np.float64)
            for _ in range(actions_per_pass):
                m = env.mask(s)
                if not m.any() or s >= steps:
                    break
                cand = np.flatnonzero(m)
                pick = _segment_first_argmax(logits[cand], env.gi_np[cand], B)
                got = pick >= 0
                env.st.move(cand[pick[got]])
                s += 1
                frac = env.st.meas[:, 1] / np.maximum(env.st.total_m, 1e-300)
                nc = env.st.ncut()
                inside = np.abs(frac - 0.5) <= window
                better = inside & (nc < best_nc)
                if better.any():
                    best_nc[better] = nc[better]
                    sel = better[env.gi_np]
                    best_side[sel] = env.st.side[sel]
    none = ~np.isfinite(best_nc)
    if none.any():  # never inside the window: the final state
        sel = none[env.gi_np]
        best_side[sel] = env.st.side[sel]
    return best_side

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

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .csr import run_starts
from .partitioners.base import GraphBatch
from .refine import CutState, _segment_first_argmax, bisection_ncut, cut_band

# --------------------------------------------------------------------------------- layers


def mean_adjacency(indptr: np.ndarray, indices: np.ndarray, n: int) -> torch.Tensor:
    """Row-normalized sparse adjacency (mean over neighbours; empty rows give 0)."""
    deg = np.diff(indptr)
    rows = np.repeat(np.arange(n), deg)
    w = 1.0 / np.maximum(deg[rows], 1)
    i = torch.from_numpy(np.stack([rows, indices]).astype(np.int64))
    return torch.sparse_coo_tensor(
        i, torch.from_numpy(w.astype(np.float32)), (n, n), check_invariants=False
    ).coalesce()


class Sage(nn.Module):
    """GraphSAGE layer with mean aggregation: W_l mean(x_nbr) + W_r x."""

    def __init__(self, a: int, b: int):
        super().__init__()
        self.lin_l = nn.Linear(a, b)
        self.lin_r = nn.Linear(a, b, bias=False)

    def forward(self, x: torch.Tensor, adj: torch.Tensor) -> torch.Tensor:
        return self.lin_l(torch.sparse.mm(adj, x)) + self.lin_r(x)


def _seg_sum(v: torch.Tensor, gi: torch.Tensor, n: int) -> torch.Tensor:
    return torch.zeros((n,) + v.shape[1:], dtype=v.dtype).index_add_(0, gi, v)


def masked_log_softmax(logits: torch.Tensor, mask: torch.Tensor, gi: torch.Tensor, n: int):
    """Per-graph log-softmax over the allowed nodes: (log-probs (N,), per-graph any-allowed (B,))."""
    neg = torch.finfo(logits.dtype).min
    z = torch.where(mask, logits, torch.full_like(logits, neg))
    mx = torch.full((n,), neg, dtype=z.dtype).scatter_reduce(0, gi, z, "amax", include_self=True)
    e = torch.where(mask, torch.exp(z - mx[gi]), torch.zeros_like(z))
    s = _seg_sum(e, gi, n)
    logp = z - mx[gi] - torch.log(s.clamp_min(1e-30))[gi]
    return torch.where(mask, logp, torch.full_like(logp, neg)), s > 0


def sample_per_graph(logp: torch.Tensor, mask: torch.Tensor, gi: torch.Tensor, n: int, gen, greedy: bool):
    """One node per graph: argmax of log-prob (+ Gumbel noise when sampling); -1 where none allowed."""
    score = logp.detach().clone()
    if not greedy:
        u = torch.rand(score.shape, generator=gen).clamp(1e-9, 1 - 1e-9)
        score = score - torch.log(-torch.log(u))
    neg = torch.finfo(score.dtype).min
    score = torch.where(mask, score, torch.full_like(score, neg))
    mx = torch.full((n,), neg, dtype=score.dtype).scatter_reduce(0, gi, score, "amax", include_self=True)
    hit = torch.nonzero(mask & (score == mx[gi])).flatten()
    pick = torch.full((n,), -1, dtype=torch.int64)
    pick.scatter_reduce_(0, gi[hit], hit, "amax", include_self=True)
    return pick


@dataclass(frozen=True)
class RLConfig:
    kind: str  # "refiner" or "partitioner"
    in_features: int
    sage_units: int
    dense_units: int
    n_shared_sage: int

    def to_dict(self) -> dict:
        return asdict(self)


class ActorCritic(nn.Module):
    """Shared SAGE trunk; actor -> one logit per node; critic -> one value per graph."""

    def __init__(self, cfg: RLConfig):
        super().__init__()
        self.cfg = cfg
        h, dnn = cfg.sage_units, cfg.dense_units
        widths = [cfg.in_features] + [h] * cfg.n_shared_sage
        self.trunk = nn.ModuleList(Sage(a, b) for a, b in zip(widths[:-1], widths[1:], strict=True))
        if cfg.kind == "refiner":
            self.actor_sage, self.critic_sage = Sage(h, h), Sage(h, h)
            self.actor_out, self.critic_out = nn.Linear(h, 1), nn.Linear(h, 1)
        else:
            self.shared_dense = nn.Linear(h, dnn)
            self.actor = nn.Sequential(nn.Linear(dnn, dnn), nn.Tanh(), nn.Linear(dnn, 1))
            self.gate = nn.Linear(dnn, 1)
            self.critic = nn.Sequential(nn.Linear(dnn, dnn), nn.Tanh(), nn.Linear(dnn, 1))

    def forward(self, x, adj, gi, n_graphs: int):
        for layer in self.trunk:
            x = torch.tanh(layer(x, adj))
        if self.cfg.kind == "refiner":
            logits = self.actor_out(torch.tanh(self.actor_sage(x, adj))).squeeze(1)
            hv = torch.tanh(self.critic_sage(x, adj))
            cnt = _seg_sum(torch.ones(len(x), 1), gi, n_graphs).clamp_min(1)
            value = self.critic_out(_seg_sum(hv, gi, n_graphs) / cnt).squeeze(1)
            return logits, value
        x = torch.tanh(self.shared_dense(x))
        logits = self.actor(x).squeeze(1)
        g = self.gate(x).squeeze(1)  # attentional aggregation: softmax gate per graph
        gmax = torch.full((n_graphs,), -1e30).scatter_reduce(0, gi, g, "amax", include_self=True)
        e = torch.exp(g - gmax[gi])
        a = e / _seg_sum(e, gi, n_graphs).clamp_min(1e-30)[gi]
        value = self.critic(_seg_sum(a.unsqueeze(1) * x, gi, n_graphs)).squeeze(1)
        return logits, value


def refiner_config() -> RLConfig:
    return RLConfig("refiner", 6, 16, 16, 2)


def partitioner_config(dim: int) -> RLConfig:
    return RLConfig("partitioner", dim + 2, 64, 32, 4)


def save(model: ActorCritic, path, meta: dict | None = None) -> None:
    state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
    torch.save({"config": model.cfg.to_dict(), "state_dict": state, "meta": meta or {}}, path)


def load(path) -> tuple[ActorCritic, dict]:
    blob = torch.load(path, map_location="cpu", weights_only=True)
    model = ActorCritic(RLConfig(**blob["config"]))
    model.load_state_dict(blob["state_dict"])
    model.eval()
    return model, blob.get("meta", {})


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
    from .gnn import normalize_features

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


def _actor_weights(model: ActorCritic) -> list:
    """The refiner's actor path as float32 numpy arrays (cached on the model): per SAGE layer
    (W_l^T, b_l, W_r^T) for the trunk and the actor's layer, then the output layer (w^T, b)."""
    cached = getattr(model, "_np_actor", None)
    if cached is None:

        def arr(t):
            return t.detach().cpu().numpy().astype(np.float32)

        layers = [
            (arr(m.lin_l.weight).T.copy(), arr(m.lin_l.bias), arr(m.lin_r.weight).T.copy())
            for m in list(model.trunk) + [model.actor_sage]
        ]
        cached = (layers, (arr(model.actor_out.weight).T.copy(), arr(model.actor_out.bias)))
        model._np_actor = cached
    return cached


def _mean_csr(indptr: np.ndarray, indices: np.ndarray):
    """mean_adjacency as a float32 scipy CSR matrix."""
    import scipy.sparse as sp

    n = indptr.size - 1
    deg = np.diff(indptr)
    w = np.repeat(1.0 / np.maximum(deg, 1), deg).astype(np.float32)
    return sp.csr_matrix((w, indices, indptr), shape=(n, n))


def _actor_logits(weights, x: np.ndarray, adj) -> np.ndarray:
    """ActorCritic.forward's logits (refiner) in numpy: the critic is not needed at inference."""
    layers, (wo, bo) = weights
    h = np.ascontiguousarray(x, dtype=np.float32)
    for wl, bl, wr in layers:
        out = (adj @ h) @ wl
        out += h @ wr
        out += bl
        h = np.tanh(out, out=out)
    return (h @ wo + bo)[:, 0].astype(np.float64)


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
    from .refine import connected_sides, keep_better

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


# --------------------------------------------------------------------------------- training


@dataclass
class RLTrainConfig:
    agent: str  # "rl-refiner" or "rl-partitioner"
    out: str
    workdir: str
    dim: int = 2
    n_meshes: int = 60
    episodes: int = 400
    graphs_per_episode: int = 8
    lr: float = 1e-3
    gamma: float = 0.9
    value_weight: float = 0.1
    entropy_weight: float = 0.01
    n_step: int = 8
    max_steps: int = 200
    seed: int = 0
    threshold: int = 200
    max_minutes: float | None = None
    resume: bool = False
    eval_every: int = 25


def training_graphs(cfg: RLTrainConfig, log=print) -> list[tuple[GraphBatch, np.ndarray | None]]:
    """The data: generated meshes (seeded). For the partitioner: their graphs coarsened to the
    threshold (what it bisects in multilevel mode). For the refiner: every level of that coarsening
    with the SAGE-Base bisection of the coarsest graph projected onto it (unrefined), as in the paper."""
    from .agglomerate import make_batch
    from .coarsen import coarsen
    from .generate import generate
    from .partitioners import get_partitioner
    from .pipeline import prepare

    rng = np.random.default_rng(cfg.seed)
    # 3D: the unit cube and random boxes (some with a corner cut away: an L-shaped solid), so that
    # the agent does not only see cubes
    kinds = ["square-tri", "delaunay", "square-quad", "voronoi"] if cfg.dim == 2 else ["cube", "cube-portion"]
    sage = get_partitioner("sage-base") if cfg.agent == "rl-refiner" else None
    out = []
    t0 = time.perf_counter()
    for i in range(cfg.n_meshes):
        kind = kinds[i % len(kinds)]
        ms = int(rng.integers(2**31))
        if kind in ("square-tri", "square-quad"):
            gen = generate(kind, ms, size=1.0 / int(rng.integers(20, 60)))
        elif kind in ("delaunay", "voronoi"):
            gen = generate(kind, ms, n=int(rng.integers(400, 3000)))
        else:  # 3D: 1k-25k tetrahedra (coarsened several levels, as in multilevel mode)
            gen = generate(kind, ms, size=float(rng.uniform(0.06, 0.12)))
        mesh = gen.to_mesh()
        _, data = prepare(mesh)
        b = make_batch(data, np.zeros(mesh.n_cells, dtype=np.int64))
        levels = coarsen(b, threshold=cfg.threshold, seed=ms)
        coarse = levels[-1].batch if levels else b
        if sage is None:
            out.append((coarse, None))
        else:
            cur = sage.bisect_batch(coarse)
            for j in range(len(levels) - 1, -1, -1):
                cur = cur[levels[j].cmap]
                out.append((levels[j - 1].batch if j > 0 else b, cur.copy()))
        if (i + 1) % 10 == 0:
            log(
                f"  data: {i + 1}/{cfg.n_meshes} meshes, {len(out)} graphs ({time.perf_counter() - t0:.0f} s)"
            )
    return out


def concat_batches(items: list[GraphBatch]) -> GraphBatch:
    """Disjoint union of single-graph batches."""
    off = np.cumsum([0] + [b.n_nodes for b in items])
    eoff = np.cumsum([0] + [b.indices.size for b in items])
    return GraphBatch(
        indptr=np.concatenate([b.indptr[:-1] + eoff[i] for i, b in enumerate(items)] + [[eoff[-1]]]).astype(
            np.int64
        ),
        indices=np.concatenate([b.indices + off[i] for i, b in enumerate(items)]),
        weights=np.concatenate([b.weights for b in items]),
        graph_ptr=off.astype(np.int64),
        centroids=np.concatenate([b.centroids for b in items]),
        measures=np.concatenate([b.measures for b in items]),
        tags=None,
        node_ids=np.concatenate([b.node_ids for b in items]),
        edge_count=np.concatenate([b.edge_counts() for b in items]),
        volume=np.concatenate([b.volumes() for b in items]),
    )


def run_episode(model, env, gen, max_steps: int, n_step: int, gamma: float, vw: float, ew: float, opt=None):
    """One batched episode; n-step A2C updates when `opt` is given. Returns (total reward per graph,
    mean policy loss, mean value loss)."""
    B = env.B
    total = np.zeros(B)
    buf = []
    pl, vl, nupd = 0.0, 0.0, 0
    step = 0

    def update(bootstrap: torch.Tensor | None):
        nonlocal pl, vl, nupd
        ret = bootstrap if bootstrap is not None else torch.zeros(B)
        p_loss = torch.zeros(())
        v_loss = torch.zeros(())
        ent = torch.zeros(())
        for logp_a, value, reward, alive, entropy in reversed(buf):
            ret = reward + gamma * ret
            adv = (ret - value).detach()
            p_loss = p_loss - (logp_a * adv * alive).sum()
            v_loss = v_loss + (((ret - value) ** 2) * alive).sum()
            ent = ent + (entropy * alive).sum()
        loss = (p_loss + vw * v_loss - ew * ent) / max(B, 1)
        opt.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        pl += float(p_loss.detach()) / B
        vl += float(v_loss.detach()) / B
        nupd += 1
        buf.clear()

    while step < max_steps:
        m = env.mask(step)
        if not m.any():
            break
        mt = torch.from_numpy(m)
        with torch.set_grad_enabled(opt is not None):
            logits, value = model(env.features(), env.adj, env.gi, B)
            logp, alive = masked_log_softmax(logits, mt, env.gi, B)
            pick = sample_per_graph(logp, mt, env.gi, B, gen, greedy=False)
            safe = pick.clamp_min(0)
            logp_a = torch.where(alive, logp[safe], torch.zeros(B))
            p = torch.where(mt, torch.exp(logp), torch.zeros_like(logp))
            entropy = -_seg_sum(torch.where(mt, p * logp, torch.zeros_like(p)), env.gi, B)
        r = env.step(pick.numpy())
        total += r
        step += 1
        if opt is not None:
            buf.append((logp_a, value, torch.from_numpy(r.astype(np.float32)), alive.float(), entropy))
            if len(buf) >= n_step:
                with torch.no_grad():
                    m2 = env.mask(step)
                    _, boot = model(env.features(), env.adj, env.gi, B)
                    alive_next = torch.from_numpy(np.bincount(env.gi_np, weights=m2, minlength=B) > 0).float()
                update(boot * alive_next)
    if opt is not None and buf:
        update(None)
    return total, pl / max(nupd, 1), vl / max(nupd, 1)


def evaluate_agent(model, cfg: RLTrainConfig, graphs) -> dict:
    """Mean normalized cut of the greedy agent on held-out graphs, and of the fm baseline on the
    same graphs with the same budget and rollback (refiner) or of METIS bisection (partitioner)."""
    from .partitioners import get_partitioner
    from .refine import FMRefiner

    batch = concat_batches([g for g, _ in graphs])
    if cfg.agent == "rl-refiner":
        start = np.concatenate([s for _, s in graphs])
        ours = refine_with_policy(model, batch, start)
        base = FMRefiner(hops=3, passes=2).refine(batch, start)
        ref = start
        names = ("rl", "fm", "start")
    else:
        ours = partition_with_policy(model, batch)
        base = get_partitioner("metis").bisect_batch(batch)
        ref = None
        names = ("rl", "metis", None)
    out = {
        names[0]: float(np.mean(bisection_ncut(batch, ours))),
        names[1]: float(np.mean(bisection_ncut(batch, base))),
    }
    if ref is not None:
        out[names[2]] = float(np.mean(bisection_ncut(batch, ref)))
    return out


def train(cfg: RLTrainConfig, log=print) -> dict:
    """Train (or resume) an agent; writes the weights, a checkpoint, a JSON-lines log and a plot."""
    torch.manual_seed(cfg.seed)
    work = Path(cfg.workdir)
    work.mkdir(parents=True, exist_ok=True)
    ckpt = work / "checkpoint.pt"
    data_cache = work / "graphs.pt"
    t_start = time.perf_counter()
    if data_cache.is_file():
        graphs = _load_graphs(data_cache)
        log(f"data: {len(graphs)} graphs from {data_cache}")
    else:
        graphs = training_graphs(cfg, log)
        _save_graphs(graphs, data_cache)
    rng = np.random.default_rng(cfg.seed)
    order = rng.permutation(len(graphs))
    n_val = max(4, len(graphs) // 10)
    val = [graphs[i] for i in order[:n_val]]
    train_set = [graphs[i] for i in order[n_val:]]
    model = ActorCritic(refiner_config() if cfg.agent == "rl-refiner" else partitioner_config(cfg.dim))
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    gen = torch.Generator().manual_seed(cfg.seed)
    history: list[dict] = []
    episode = 0
    best = np.inf
    elapsed0 = 0.0
    if cfg.resume and ckpt.is_file():
        state = torch.load(ckpt, weights_only=False)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        gen.set_state(state["gen"])
        rng = state["rng"]
        history, episode, best, elapsed0 = state["history"], state["episode"], state["best"], state["elapsed"]
        log(f"resumed at episode {episode}")
    else:
        rng = np.random.default_rng(cfg.seed + 1)
    logf = open(work / "log.jsonl", "a", encoding="utf-8")
    t0 = time.perf_counter()
    while episode < cfg.episodes:
        ids = rng.choice(len(train_set), size=min(cfg.graphs_per_episode, len(train_set)), replace=False)
        items = [train_set[i] for i in ids]
        batch = concat_batches([g for g, _ in items])
        if cfg.agent == "rl-refiner":
            env = RefinerEnv(batch, np.concatenate([s for _, s in items]))
        else:
            env = PartitionerEnv(batch)
        model.train()
        total, pl, vl = run_episode(
            model, env, gen, cfg.max_steps, cfg.n_step, cfg.gamma, cfg.value_weight, cfg.entropy_weight, opt
        )
        episode += 1
        rec = {
            "episode": episode,
            "reward": float(total.mean()),
            "policy_loss": pl,
            "value_loss": vl,
            "seconds": round(elapsed0 + time.perf_counter() - t0, 1),
        }
        if episode % cfg.eval_every == 0 or episode == cfg.episodes:
            model.eval()
            ev = evaluate_agent(model, cfg, val)
            rec.update({f"val_{k}": v for k, v in ev.items()})
            if ev["rl"] < best:
                best = ev["rl"]
                save(model, cfg.out, meta={"episode": episode, "val": ev, "config": asdict(cfg)})
            log(json.dumps(rec))
            torch.save(
                {
                    "model": model.state_dict(),
                    "opt": opt.state_dict(),
                    "gen": gen.get_state(),
                    "rng": rng,
                    "history": history + [rec],
                    "episode": episode,
                    "best": best,
                    "elapsed": elapsed0 + time.perf_counter() - t0,
                },
                ckpt,
            )
        history.append(rec)
        logf.write(json.dumps(rec) + "\n")
        logf.flush()
        if cfg.max_minutes is not None and (elapsed0 + time.perf_counter() - t0) / 60 > cfg.max_minutes:
            log(f"stopping after {cfg.max_minutes} minutes at episode {episode}")
            if episode % cfg.eval_every:
                model.eval()
                ev = evaluate_agent(model, cfg, val)
                if ev["rl"] < best:
                    best = ev["rl"]
                    save(model, cfg.out, meta={"episode": episode, "val": ev, "config": asdict(cfg)})
                torch.save(
                    {
                        "model": model.state_dict(),
                        "opt": opt.state_dict(),
                        "gen": gen.get_state(),
                        "rng": rng,
                        "history": history,
                        "episode": episode,
                        "best": best,
                        "elapsed": elapsed0 + time.perf_counter() - t0,
                    },
                    ckpt,
                )
            break
    logf.close()
    _plot(history, work / "loss.png", cfg.agent)
    return {
        "episodes": episode,
        "best_val": best,
        "seconds": time.perf_counter() - t_start,
        "history": history,
    }


def _save_graphs(graphs, path):
    blob = []
    for b, s in graphs:
        blob.append(
            {k: torch.from_numpy(np.asarray(v)) for k, v in asdict(b).items() if v is not None}
            | ({"side": torch.from_numpy(s)} if s is not None else {})
        )
    torch.save(blob, path)


def _load_graphs(path):
    out = []
    for d in torch.load(path, weights_only=True):
        side = d.pop("side", None)
        kw = {k: v.numpy() for k, v in d.items()}
        kw.setdefault("tags", None)
        out.append((GraphBatch(**kw), None if side is None else side.numpy()))
    return out


def _plot(history, path, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not history:
        return
    ep = [h["episode"] for h in history]
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.5))
    ax[0].plot(ep, [h["reward"] for h in history], lw=0.7)
    ax[0].set_title("episode reward")
    ax[1].plot(ep, [h["policy_loss"] for h in history], lw=0.7, label="policy")
    ax[1].plot(ep, [h["value_loss"] for h in history], lw=0.7, label="value")
    ax[1].legend()
    ax[1].set_title("losses")
    ev = [h for h in history if "val_rl" in h]
    if ev:
        for k in [k for k in ev[-1] if k.startswith("val_")]:
            ax[2].plot([h["episode"] for h in ev], [h.get(k) for h in ev], marker="o", label=k[4:])
        ax[2].legend()
        ax[2].set_title("validation normalized cut")
    for a in ax:
        a.set_xlabel("episode")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)

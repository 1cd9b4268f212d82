"""The reinforcement-learning networks (A2C actor-critic on graphs, GraphSAGE layers) and their numpy
twin for the actor's forward pass; no environment, no training."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

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

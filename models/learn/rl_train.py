"""Training of the A2C partitioner and refiner (models/partition/rl_policy.py holds the environments)."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from models.graph.batch import GraphBatch
from models.nets.rl import (
    ActorCritic,
    _seg_sum,
    masked_log_softmax,
    partitioner_config,
    refiner_config,
    sample_per_graph,
    save,
)
from models.partition.refine import bisection_ncut
from models.partition.rl_policy import PartitionerEnv, RefinerEnv, partition_with_policy, refine_with_policy

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
    from models.learn.generate import generate
    from models.partition import get_partitioner
    from models.partition.agglomerate import make_batch
    from models.partition.coarsen import coarsen
    from models.pipeline import prepare

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
    from models.partition import get_partitioner
    from models.partition.refine import FMRefiner

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

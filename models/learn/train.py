"""Training of the SAGE bisection networks (`magnet train`): unsupervised, expected normalized cut
(+ heterogeneity penalty for SAGE-Heterogeneous), Adam, random rotations as augmentation, a held-out
validation set, a log file and a loss-history plot, a checkpoint every epoch (resumable), the best
validation model written as the weights file. Same seed, same data, same weights (CPU).
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from models.errors import ParameterError, listed

try:  # torch is only needed to train; the argument parser must import without it
    import torch
except ImportError:  # pragma: no cover
    torch = None


# The paper's recipes (MISSION.md sections 2-3): epochs, learning rate, weight decay, batch size.
PAPER = {
    "sage-base-2d": dict(epochs=300, lr=1e-5, weight_decay=1e-5, batch_size=4),
    "sage-base-3d": dict(epochs=400, lr=1e-4, weight_decay=1e-5, batch_size=4),
    "sage-hetero-2d": dict(epochs=200, lr=1e-5, weight_decay=1e-5, batch_size=4),
    "sage-hetero-3d": dict(epochs=150, lr=1e-4, weight_decay=1e-5, batch_size=4),
}


@dataclass
class TrainConfig:
    recipe: str
    out: str
    workdir: str
    data: str | None = None
    n_meshes: int | None = None
    pieces: float | None = None
    epochs: int | None = None
    lr: float | None = None
    weight_decay: float | None = None
    batch_size: int | None = None
    lr_schedule: str = "constant"
    hetero_weight: float = 1.0
    val_fraction: float = 0.1
    seed: int = 0
    threads: int | None = None
    device: str | None = None
    max_minutes: float | None = None
    resume: bool = False
    select: str = "val"  # best model by validation loss, "rb": by the recursive-bisection check, or "last"
    kinds: str | None = None  # "kind:weight,..." replaces the recipe's mix of mesh kinds
    init: str | None = None  # start from these weights (fine-tuning) instead of a seeded random init
    stop_epoch: int | None = None  # stop after this epoch (the lr schedule still spans `epochs`)

    def resolved(self) -> TrainConfig:
        """Fill the unset hyper-parameters from the paper's recipe."""
        if self.recipe not in PAPER:
            raise ParameterError(f"unknown recipe {self.recipe!r}; choose one of {listed(sorted(PAPER))}")
        cfg = TrainConfig(**asdict(self))
        for k, v in PAPER[self.recipe].items():
            if getattr(cfg, k) is None:
                setattr(cfg, k, v)
        if cfg.select not in ("val", "rb", "last"):
            raise ParameterError("select must be 'val', 'rb' or 'last'")
        if cfg.lr_schedule not in ("constant", "cosine"):
            raise ParameterError("lr_schedule must be 'constant' or 'cosine'")
        if not 0 < cfg.val_fraction < 1:
            raise ParameterError("val_fraction must be in (0, 1)")
        return cfg


def _hardware(device) -> str:
    import torch

    if str(device).startswith("cuda"):
        return torch.cuda.get_device_name(0)
    return f"CPU {platform.processor() or platform.machine()}, {torch.get_num_threads()} thread(s)"


def initial_state(path: str, model) -> dict:
    """Weights to start from: the same network, or the SAGE-Base network of the same dimension for a
    SAGE-Heterogeneous one (the extra input p gets zero weights, so training starts from a network
    that already bisects; a random start under the heterogeneity penalty tends to collapse onto
    "side = group", which leaves single-group graphs unsplit)."""
    from dataclasses import replace

    from models.nets.gnn import load_model

    start, _ = load_model(path)
    state = start.state_dict()
    if start.config == model.config:
        return state
    if replace(start.config, hetero=True) != model.config:
        raise ParameterError(f"--init {path}: network {start.config} does not match {model.config}")
    state = {k: v.clone() for k, v in state.items()}
    for name in ("convs.0.lin_l.weight", "convs.0.lin_r.weight"):
        w = state[name]
        state[name] = torch.cat([w, torch.zeros(w.shape[0], 1, dtype=w.dtype)], dim=1)
    return state


def batch_losses(model, batch, dim: int, hetero: bool, hetero_weight: float, hard: bool = False):
    """(normalized cut, penalty) per graph of a torch-geometric batch; hard=True uses argmax labels."""
    import torch

    from models.nets.gnn import expected_normalized_cut, heterogeneity_penalty, normalize_features

    n_graphs = int(batch.num_graphs)
    x = normalize_features(batch.x, batch.batch, n_graphs, dim)
    y = model(x, batch.edge_index)
    if hard:
        y = torch.nn.functional.one_hot(y.argmax(dim=1), 2).to(y.dtype)
    nc = expected_normalized_cut(y, batch.edge_index, batch.batch, n_graphs, batch.degree)
    pen = torch.zeros_like(nc)
    if hetero:
        pen = heterogeneity_penalty(y, batch.x[:, dim + 1], batch.batch, n_graphs, hetero_weight)
    return nc, pen


def evaluate(model, ds, cfg: TrainConfig, device) -> dict:
    """Mean loss, mean hard normalized cut and mean hard penalty over a data set."""
    import torch

    sums = np.zeros(3)
    model.eval()
    with torch.inference_mode():
        for batch in ds.batches(32):
            batch = batch.to(device)
            nc, pen = batch_losses(model, batch, ds.dim, ds.hetero, cfg.hetero_weight)
            hnc, hpen = batch_losses(model, batch, ds.dim, ds.hetero, cfg.hetero_weight, hard=True)
            sums += [float((nc + pen).sum()), float(hnc.sum()), float(hpen.sum())]
    model.train()
    return dict(zip(("loss", "hard_ncut", "hard_penalty"), (sums / len(ds)).tolist(), strict=False))


def bisection_check_meshes(dim: int) -> list:
    """Held-out generated meshes (seeds outside any data set) for the recursive-bisection check."""
    from models.learn.generate import generate

    if dim == 2:
        specs = [("holes", dict(n=4, size=0.015)), ("voronoi", dict(n=4000)), ("split", dict(size=0.015))]
    else:
        specs = [("cube-portion", dict(size=0.05)), ("cube", dict(size=0.06))]
    return [generate(kind, seed=10**9 + i, **kw).to_mesh() for i, (kind, kw) in enumerate(specs)]


class BisectionCheck:
    """Recursive bisection (nref levels) of held-out meshes with the model being trained: normalized
    cut relative to METIS on the same meshes, and extra fragments of the raw argmax partition. This
    tracks what the model is for better than the loss on single bisections of training shapes."""

    def __init__(self, dim: int, nref: int):
        from models.partition import get_partitioner
        from models.partition.agglomerate import recursive_bisection
        from models.pipeline import prepare

        self.nref, self._rb = nref, recursive_bisection
        self.data = [prepare(mesh)[1] for mesh in bisection_check_meshes(dim)]
        metis = get_partitioner("metis")
        self.ref = [self._ncut(d, self._labels(d, metis)) for d in self.data]

    def _labels(self, d, part):
        n = d.graph.n
        return self._rb(d, part, np.arange(n), np.zeros(n, dtype=np.int64), levels=self.nref)

    @staticmethod
    def _ncut(d, labels) -> float:
        g = d.graph
        rows = np.repeat(np.arange(g.n), np.diff(g.indptr))
        k = int(labels.max()) + 1
        cut = np.bincount(labels[rows], weights=(labels[rows] != labels[g.indices]), minlength=k)
        vol = np.bincount(labels, weights=np.diff(g.indptr).astype(float), minlength=k)
        return float(np.sum(cut / np.maximum(vol, 1)))

    def __call__(self, model) -> dict:
        from models.partition.agglomerate import connected_parts
        from models.partition.sage import SageBasePartitioner

        model.eval()
        ratios, frags = [], []
        for d, ref in zip(self.data, self.ref, strict=False):
            clean = self._labels(d, SageBasePartitioner(model=model, device="cpu"))
            raw = self._labels(d, SageBasePartitioner(model=model, device="cpu", contiguous=False, smooth=0))
            split, _ = connected_parts(d, raw, np.arange(d.graph.n))
            ratios.append(self._ncut(d, clean) / ref)
            frags.append((int(split.max()) + 1) / (int(raw.max()) + 1) - 1)
        model.train()
        return {"rb_ncut_ratio": float(np.mean(ratios)), "rb_raw_fragments": float(np.mean(frags))}


def plot_history(history: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = [h["epoch"] for h in history]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(ep, [h["train_loss"] for h in history], label="train loss (expected)")
    ax.plot(ep, [h["val_loss"] for h in history], label="validation loss (expected)")
    ax.plot(ep, [h["val_hard_ncut"] for h in history], "--", label="validation normalized cut (argmax)")
    ax.set_xlabel("epoch")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def train(cfg: TrainConfig, log=print) -> dict:
    """Train one model as configured; returns a summary (also stored in the weights file's meta)."""
    import torch

    from models.learn.dataset import GraphDataset, build_dataset, get_recipe
    from models.nets.gnn import BisectionGNN, GNNConfig, load_model, save_model

    cfg = cfg.resolved()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    device = torch.device(cfg.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    work = Path(cfg.workdir)
    work.mkdir(parents=True, exist_ok=True)
    logfile = open(work / "train.log", "a")

    def say(msg: str) -> None:
        line = f"[{time.strftime('%H:%M:%S')}] {msg}"
        logfile.write(line + "\n")
        logfile.flush()
        if log:
            log(line)

    # Data: the recipe's data set, built once (seeded) and cached.
    data_path = Path(cfg.data) if cfg.data else work / f"{cfg.recipe}-seed{cfg.seed}.npz"
    kinds = None
    if cfg.kinds:
        try:
            kinds = {k: float(w) for k, w in (item.split(":") for item in cfg.kinds.split(","))}
        except ValueError as exc:
            raise ParameterError("kinds must look like 'delaunay:1,holes:0.5'") from exc
    recipe = get_recipe(cfg.recipe, n_meshes=cfg.n_meshes, pieces=cfg.pieces, kinds=kinds)
    if data_path.exists():
        ds = GraphDataset.load(data_path)
        say(f"data set {data_path}: {len(ds)} graphs, {ds.n_nodes} nodes")
    else:
        say(
            f"building data set {recipe.name} ({recipe.n_meshes} graphs, pieces {recipe.pieces}) -> {data_path}"
        )
        ds = build_dataset(recipe, data_path, seed=cfg.seed, log=say)
    rng = np.random.default_rng(cfg.seed)
    perm = rng.permutation(len(ds))
    n_val = max(1, int(round(cfg.val_fraction * len(ds))))
    val, tr = ds.subset(np.sort(perm[:n_val])), ds.subset(np.sort(perm[n_val:]))

    torch.manual_seed(cfg.seed)
    model = BisectionGNN(GNNConfig.paper(ds.dim, ds.hetero)).to(device)
    if cfg.init:
        model.load_state_dict(initial_state(cfg.init, model))
        say(f"starting from the weights in {cfg.init}")
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    gen = torch.Generator().manual_seed(cfg.seed)
    history: list[dict] = []
    start, best, train_seconds = 0, float("inf"), 0.0
    ckpt = work / "checkpoint.pt"
    if cfg.resume and ckpt.exists():
        state = torch.load(ckpt, map_location=device, weights_only=True)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        gen.set_state(state["generator"])
        history = json.loads(state["history"])
        start, best, train_seconds = int(state["epoch"]), float(state["best"]), float(state["seconds"])
        say(f"resumed from {ckpt} at epoch {start}")
    say(
        f"training {cfg.recipe} on {device} ({_hardware(device)}): {len(tr)} train / {len(val)} val graphs, "
        f"epochs {cfg.epochs}, lr {cfg.lr} ({cfg.lr_schedule}), weight decay {cfg.weight_decay}, batch {cfg.batch_size}"
    )

    def lr_at(epoch: int) -> float:
        if cfg.lr_schedule == "cosine":
            return cfg.lr * (0.05 + 0.95 * 0.5 * (1 + np.cos(np.pi * epoch / cfg.epochs)))
        return cfg.lr

    if cfg.select == "rb" and ds.hetero:
        raise ParameterError("--select rb is for the SAGE-Base recipes (homogeneous meshes)")
    check = BisectionCheck(ds.dim, nref=6 if ds.dim == 2 else 5) if cfg.select == "rb" else None
    t_start = time.perf_counter() - train_seconds
    for epoch in range(start, cfg.epochs):
        for group in opt.param_groups:
            group["lr"] = lr_at(epoch)
        total, count = 0.0, 0
        for batch in tr.batches(cfg.batch_size, shuffle=True, generator=gen, rotate=True):
            batch = batch.to(device)
            nc, pen = batch_losses(model, batch, ds.dim, ds.hetero, cfg.hetero_weight)
            loss = (nc + pen).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * int(batch.num_graphs)
            count += int(batch.num_graphs)
        ev = evaluate(model, val, cfg, device)
        rb = check(model.cpu()) if check else {}
        model.to(device)
        seconds = time.perf_counter() - t_start
        history.append(
            {
                "epoch": epoch + 1,
                "train_loss": total / count,
                "val_loss": ev["loss"],
                "val_hard_ncut": ev["hard_ncut"],
                "val_hard_penalty": ev["hard_penalty"],
                "lr": lr_at(epoch),
                "seconds": round(seconds, 1),
                **rb,
            }
        )
        rb_txt = (
            f"  rb ncut/metis {rb['rb_ncut_ratio']:.4f} raw fragments {rb['rb_raw_fragments']:.4f}"
            if rb
            else ""
        )
        say(
            f"epoch {epoch + 1}/{cfg.epochs}: train {total / count:.5f}  val {ev['loss']:.5f}  "
            f"val ncut(argmax) {ev['hard_ncut']:.5f}  penalty {ev['hard_penalty']:.5f}{rb_txt}  {seconds:.0f} s"
        )
        score = rb["rb_ncut_ratio"] + rb["rb_raw_fragments"] if rb else ev["loss"]
        if cfg.select == "last":
            score = -float(epoch)
        if score < best:
            best = score
            save_model(model, work / "best.pt", meta={"epoch": epoch + 1})
        torch.save(
            {
                "model": model.state_dict(),
                "optimizer": opt.state_dict(),
                "generator": gen.get_state(),
                "history": json.dumps(history),
                "epoch": epoch + 1,
                "best": best,
                "seconds": seconds,
            },
            ckpt,
        )
        plot_history(history, work / "loss_history.png", cfg.recipe)
        if cfg.stop_epoch and epoch + 1 >= cfg.stop_epoch:
            say(f"stopping after epoch {epoch + 1} as asked")
            break
        if cfg.max_minutes and seconds > 60 * cfg.max_minutes:
            say(f"time budget of {cfg.max_minutes} min reached after epoch {epoch + 1}")
            break

    best_model, best_meta = load_model(work / "best.pt", device="cpu")
    final = evaluate(best_model.to(device), val, cfg, device)
    summary = {
        "recipe": cfg.recipe,
        "data_recipe": ds.meta.get("recipe", recipe.to_dict()),
        "data_seed": ds.meta.get("seed"),
        "n_train": len(tr),
        "n_val": len(val),
        "train_nodes": int(tr.n_nodes),
        "epochs_run": len(history),
        "best_epoch": best_meta.get("epoch"),
        "final_train_loss": history[-1]["train_loss"] if history else None,
        "best_val_loss": final["loss"],
        "best_val_hard_ncut": final["hard_ncut"],
        "best_val_hard_penalty": final["hard_penalty"],
        "select": cfg.select,
        "best_epoch_check": next((h for h in history if h["epoch"] == best_meta.get("epoch")), None),
        "train_seconds": round(history[-1]["seconds"], 1) if history else 0.0,
        "hardware": _hardware(device),
        "config": asdict(cfg),
        "torch": torch.__version__,
    }
    Path(cfg.out).parent.mkdir(parents=True, exist_ok=True)
    save_model(best_model, cfg.out, meta={"summary": json.dumps(summary)})
    (work / "summary.json").write_text(json.dumps(summary, indent=1))
    say(
        f"wrote {cfg.out}: best epoch {summary['best_epoch']}, val loss {final['loss']:.5f}, "
        f"val ncut {final['hard_ncut']:.5f}"
    )
    logfile.close()
    return summary

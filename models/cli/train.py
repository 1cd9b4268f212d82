"""`magnet train`: the command-line face of models/learn/train.py and models/learn/rl_train.py."""

from __future__ import annotations

import argparse
from pathlib import Path

from models.learn.train import PAPER, TrainConfig, train

try:  # torch is only needed to train; the argument parser must import without it
    import torch
except ImportError:  # pragma: no cover
    torch = None


def add_train_args(parser: argparse.ArgumentParser) -> None:
    """Arguments of `magnet train` (unset hyper-parameters take the paper's values for the recipe)."""
    parser.add_argument(
        "recipe",
        choices=sorted(PAPER) + ["rl-partitioner", "rl-refiner"],
        help="which model and data set recipe (rl-*: the A2C agents, models/partition/rl_policy.py)",
    )
    parser.add_argument("-o", "--out", required=True, help="weights file to write (.pt)")
    parser.add_argument(
        "--workdir", default=None, help="checkpoint, log, plot, cached data (default: OUT.stem + '_run')"
    )
    parser.add_argument("--data", default=None, help="a data set .npz (from `magnet generate dataset`)")
    parser.add_argument("--meshes", type=int, default=None, help="number of training graphs (recipe default)")
    parser.add_argument(
        "--pieces", type=float, default=None, help="fraction of graphs that are random mesh pieces"
    )
    parser.add_argument("--epochs", type=int, default=None)
    parser.add_argument("--lr", type=float, default=None)
    parser.add_argument("--weight-decay", type=float, default=None)
    parser.add_argument("--batch-size", type=int, default=None)
    parser.add_argument("--lr-schedule", choices=("constant", "cosine"), default="constant")
    parser.add_argument("--hetero-weight", type=float, default=1.0, help="heterogeneity penalty a (> 0.5)")
    parser.add_argument("--val-fraction", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--device", default=None, help="cpu or cuda (default: cuda when available)")
    parser.add_argument(
        "--max-minutes", type=float, default=None, help="stop after the epoch that passes this"
    )
    parser.add_argument("--resume", action="store_true", help="continue from the workdir's checkpoint")
    parser.add_argument(
        "--select",
        choices=("val", "rb", "last"),
        default="val",
        help="keep the epoch with the best validation loss, or the best recursive-bisection "
        "check on held-out meshes (normalized cut / METIS + raw fragment rate), or the last",
    )
    parser.add_argument("--kinds", default=None, help="mesh kinds and weights, e.g. 'delaunay:1,holes:1'")
    parser.add_argument("--init", default=None, help="start from these weights (fine-tuning stage)")
    parser.add_argument("--episodes", type=int, default=None, help="rl-*: training episodes (default 400)")
    parser.add_argument(
        "--graphs-per-episode", type=int, default=None, help="rl-*: graphs acting in parallel (8)"
    )
    parser.add_argument("--max-steps", type=int, default=None, help="rl-*: step cap per episode (200)")
    parser.add_argument(
        "--dim", type=int, default=2, choices=(2, 3), help="rl-*: mesh dimension of the data (2)"
    )
    parser.add_argument(
        "--stop-epoch",
        type=int,
        default=None,
        help="stop after this epoch; the lr schedule still spans --epochs (replays a run "
        "that --max-minutes cut short, exactly)",
    )


def train_main(args: argparse.Namespace) -> int:
    """Run `magnet train`; returns the process exit code."""
    out = Path(args.out)
    if args.recipe.startswith("rl-"):
        from models.learn import rl_train as rl

        if args.threads and torch is not None:
            torch.set_num_threads(args.threads)
        given = {
            "n_meshes": args.meshes,
            "episodes": args.episodes,
            "graphs_per_episode": args.graphs_per_episode,
            "max_steps": args.max_steps,
            "lr": args.lr,
        }
        rcfg = rl.RLTrainConfig(
            agent=args.recipe,
            out=str(out),
            workdir=args.workdir or str(out.with_name(out.stem + "_run")),
            dim=args.dim,
            seed=args.seed,
            max_minutes=args.max_minutes,
            resume=args.resume,
            **{k: v for k, v in given.items() if v is not None},
        )
        res = rl.train(rcfg)
        print(
            f"wrote {out}: {res['episodes']} episodes, best validation normalized cut {res['best_val']:.5f}"
        )
        return 0
    cfg = TrainConfig(
        recipe=args.recipe,
        out=str(out),
        workdir=args.workdir or str(out.with_name(out.stem + "_run")),
        data=args.data,
        n_meshes=args.meshes,
        pieces=args.pieces,
        epochs=args.epochs,
        lr=args.lr,
        weight_decay=args.weight_decay,
        batch_size=args.batch_size,
        lr_schedule=args.lr_schedule,
        hetero_weight=args.hetero_weight,
        val_fraction=args.val_fraction,
        seed=args.seed,
        threads=args.threads,
        device=args.device,
        max_minutes=args.max_minutes,
        resume=args.resume,
        select=args.select,
        kinds=args.kinds,
        init=args.init,
        stop_epoch=args.stop_epoch,
    )
    train(cfg)
    return 0


if __name__ == "__main__":
    p = argparse.ArgumentParser(prog="magnet train")
    add_train_args(p)
    raise SystemExit(train_main(p.parse_args()))

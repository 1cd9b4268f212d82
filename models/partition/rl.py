"""The A2C agents of models/partition/rl_policy.py as a Partitioner (`rl-partitioner`) and a Refiner (`rl-refiner`).

Weights ship in models/weights/ (rl-partitioner-2d.pt and rl-partitioner-3d.pt, picked by the
mesh's dimension as SAGE-Base's; rl-refiner.pt for both), trained by
`magnet train rl-partitioner|rl-refiner [--dim 3]`. torch is imported only when a graph is processed.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from models.errors import ModelError
from models.graph.batch import GraphBatch
from models.partition.base import Partitioner
from models.partition.refine import Refiner

WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
_CACHE: dict[str, object] = {}
_LOCK = threading.Lock()


def _load(path: Path):
    with _LOCK:
        if str(path) not in _CACHE:
            if not path.is_file():
                stem = path.stem.rsplit("-", 1)[0] if path.stem.endswith(("-2d", "-3d")) else path.stem
                dim = " --dim 3" if path.stem.endswith("-3d") else ""
                raise ModelError(
                    f"weights file {path} is missing: train it with `magnet train {stem}{dim} -o {path}`"
                )
            from models.nets.rl import load

            try:
                _CACHE[str(path)] = load(path)[0]
            except Exception as exc:
                raise ModelError(f"cannot load weights {path}: {exc}") from exc
        return _CACHE[str(path)]


class RLPartitioner(Partitioner):
    """A2C partitioner: grows side 1 from a minimum-degree seed to half the graph (models/partition/rl_policy.py)."""

    name = "rl-partitioner"
    dims = (2, 3)
    description = (
        "RL partitioner (A2C): grows one side from a minimum-degree seed, one node per action, "
        "keeps the least normalized cut within +-1% of half; for the coarsest graphs of mode multilevel"
    )

    def __init__(
        self,
        weights_dir: str | Path | None = None,
        actions_per_pass: int = 4,
        seed: int | None = None,
        contiguous: bool = True,
    ):
        self.weights_dir = weights_dir
        self.actions_per_pass = int(actions_per_pass)
        self.seed = seed
        self.contiguous = contiguous

    def bisect_batch(self, batch: GraphBatch) -> np.ndarray:
        from models.partition.rl_policy import partition_with_policy

        if batch.dim not in self.dims:
            raise ModelError(f"{self.name} handles 2D and 3D meshes, not {batch.dim}D")
        if batch.n_nodes == 0:
            return np.zeros(0, dtype=np.int64)
        model = _load(Path(self.weights_dir or WEIGHTS_DIR) / f"rl-partitioner-{batch.dim}d.pt")
        if model.cfg.in_features != batch.dim + 2:
            raise ModelError(
                f"weights of {self.name} for {batch.dim}D meshes have {model.cfg.in_features} input "
                f"features, not {batch.dim + 2}: a file of the wrong dimension?"
            )
        side = partition_with_policy(model, batch, self.actions_per_pass)
        if self.contiguous:
            from models.partition.sage import contiguous_sides

            side = contiguous_sides(batch, side)
        return side


class RLRefiner(Refiner):
    """A2C refiner: greedy policy moves on the band around the cut, rollback to the best prefix."""

    name = "rl-refiner"
    description = (
        "RL refiner (A2C): moves nodes either way on the 3-hop band around the cut, greedy policy for "
        "at most cut + 1 steps, rollback to the best prefix; sides kept connected, never worse than its input"
    )

    def __init__(
        self,
        weights_dir: str | Path | None = None,
        hops: int = 3,
        tolerance: float = 0.05,
        passes: int = 2,
        actions_per_pass: int = 1,
        max_forwards: int | None = 128,
        seed: int | None = None,
    ):
        self.weights_dir = weights_dir
        self.actions_per_pass = int(actions_per_pass)
        self.max_forwards = max_forwards
        self.hops = int(hops)
        self.tolerance = float(tolerance)
        self.passes = int(passes)
        self.seed = seed

    def refine(self, batch: GraphBatch, labels: np.ndarray) -> np.ndarray:
        from models.partition.rl_policy import refine_with_policy

        labels = np.asarray(labels, dtype=np.int64)
        if batch.n_nodes == 0:
            return labels.copy()
        model = _load(Path(self.weights_dir or WEIGHTS_DIR) / "rl-refiner.pt")
        return refine_with_policy(
            model,
            batch,
            labels,
            self.hops,
            self.tolerance,
            self.passes,
            self.actions_per_pass,
            self.max_forwards,
        )

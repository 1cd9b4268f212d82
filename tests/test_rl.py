"""The A2C agents: masked per-graph softmax, the shipped refiner/partitioner on real graphs, and
`magnet train rl-*` reproducible and resumable (tiny runs)."""

import json

import numpy as np
import pytest
import torch
from conftest import BRAIN

from models.agglomerate import make_batch
from models.coarsen import coarsen
from models.io import read_mesh
from models.partitioners import get_partitioner
from models.pipeline import prepare
from models.refine import bisection_ncut, get_refiner
from models.rl import RLTrainConfig, load, masked_log_softmax, train


@pytest.fixture(scope="module")
def brain_batch():
    m = read_mesh(BRAIN)
    _, d = prepare(m)
    lab = (d.centroids[:, 0] > np.median(d.centroids[:, 0])).astype(np.int64)
    return make_batch(d, lab)


def test_masked_softmax_is_a_distribution_per_graph():
    gi = torch.tensor([0, 0, 0, 1, 1, 2])
    logits = torch.tensor([1.0, 2.0, 3.0, 0.5, -1.0, 4.0])
    mask = torch.tensor([True, False, True, True, True, False])
    logp, alive = masked_log_softmax(logits, mask, gi, 3)
    p = torch.where(mask, logp.exp(), torch.zeros(6))
    assert torch.allclose(torch.zeros(3).index_add_(0, gi, p)[:2], torch.ones(2))
    assert alive.tolist() == [True, True, False]
    assert p[1] == 0


def test_rl_refiner_never_worse_and_sides_connected(brain_batch):
    b = brain_batch
    start = get_partitioner("kmeans").bisect_batch(b)
    out = get_refiner("rl-refiner").refine(b, start)
    before, after = bisection_ncut(b, start), bisection_ncut(b, out)
    assert np.all(after <= before + 1e-12) and np.any(after < before)


def test_rl_partitioner_bisects_coarse_graphs(brain_batch):
    levels = coarsen(brain_batch, threshold=200)
    c = levels[-1].batch
    side = get_partitioner("rl-partitioner").bisect_batch(c)
    gi = c.graph_index()
    frac = np.bincount(gi, weights=c.measures * side) / np.bincount(gi, weights=c.measures)
    assert np.all((frac > 0.3) & (frac < 0.7))
    assert np.all(np.isfinite(bisection_ncut(c, side)))


def test_train_is_reproducible_and_resumable(tmp_path):
    def cfg(name, episodes, resume=False):
        return RLTrainConfig(agent="rl-partitioner", out=str(tmp_path / f"{name}.pt"), workdir=str(tmp_path / name),
                             n_meshes=5, episodes=episodes, graphs_per_episode=2, max_steps=12, eval_every=2,
                             resume=resume, seed=3)

    train(cfg("a", 2))
    train(cfg("b", 2))
    wa, wb = load(tmp_path / "a.pt")[0].state_dict(), load(tmp_path / "b.pt")[0].state_dict()
    assert all(torch.equal(wa[k], wb[k]) for k in wa)  # same seed, same weights
    for f in ("log.jsonl", "loss.png", "checkpoint.pt"):
        assert (tmp_path / "a" / f).is_file()
    res = train(cfg("a", 4, resume=True))
    assert res["episodes"] == 4
    eps = [json.loads(line)["episode"] for line in open(tmp_path / "a" / "log.jsonl")]
    assert eps == [1, 2, 3, 4]

"""Training (CI-sized): the loss falls, a saved model reloads to identical outputs, a run is
reproducible from its seed and resumable from its checkpoint."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torch_geometric")
pytest.importorskip("gmsh")

from models.cli.train import add_train_args, train_main  # noqa: E402
from models.errors import ParameterError  # noqa: E402
from models.learn.dataset import build_dataset, get_recipe  # noqa: E402
from models.learn.train import TrainConfig, train  # noqa: E402
from models.nets.gnn import load_model, normalize_features  # noqa: E402


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """Two tiny data sets (2D base, 2D hetero) of small generated meshes."""
    d = tmp_path_factory.mktemp("data")
    small = dict(size_range=(0.1, 0.14), points_range=(80, 160), div_range=(6, 10))
    base = get_recipe("sage-base-2d", n_meshes=10, pieces=0.3, **small)
    hetero = get_recipe("sage-hetero-2d", n_meshes=8, pieces=0.0, **small)
    build_dataset(base, d / "base.npz", seed=0, log=None)
    build_dataset(hetero, d / "hetero.npz", seed=0, log=None)
    return d


def _cfg(tmp_path, data, name="run", recipe="sage-base-2d", **kw) -> TrainConfig:
    opts = dict(epochs=4, lr=5e-3, batch_size=2, threads=1, device="cpu", val_fraction=0.2)
    opts.update(kw)
    return TrainConfig(
        recipe=recipe, out=str(tmp_path / f"{name}.pt"), workdir=str(tmp_path / name), data=str(data), **opts
    )


def _outputs(path, ds_path):
    from models.learn.dataset import GraphDataset

    model, _ = load_model(path)
    batch = next(GraphDataset.load(ds_path).batches(4))
    with torch.inference_mode():
        x = normalize_features(batch.x, batch.batch, int(batch.num_graphs), 2)
        return model(x, batch.edge_index)


def test_loss_falls_log_plot_and_reload(tmp_path, tiny):
    summary = train(_cfg(tmp_path, tiny / "base.npz"), log=None)
    work = tmp_path / "run"
    lines = (work / "train.log").read_text().splitlines()
    losses = [float(line.split("train ")[1].split()[0]) for line in lines if "] epoch " in line]
    assert len(losses) == 4 and losses[-1] < losses[0]
    assert (work / "loss_history.png").stat().st_size > 1000
    assert summary["epochs_run"] == 4 and summary["best_val_loss"] > 0
    # the shipped file and the best checkpoint give identical outputs
    assert torch.equal(
        _outputs(tmp_path / "run.pt", tiny / "base.npz"), _outputs(work / "best.pt", tiny / "base.npz")
    )


def test_reproducible_and_resumable(tmp_path, tiny):
    train(_cfg(tmp_path, tiny / "base.npz", name="a", epochs=3), log=None)
    train(_cfg(tmp_path, tiny / "base.npz", name="b", epochs=3), log=None)
    a, _ = load_model(tmp_path / "a.pt")
    b, _ = load_model(tmp_path / "b.pt")
    for (k, va), vb in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(va, vb), k
    # 2 epochs, then resume for the 3rd: same weights as 3 epochs in one go
    train(_cfg(tmp_path, tiny / "base.npz", name="c", epochs=2), log=None)
    train(_cfg(tmp_path, tiny / "base.npz", name="c", epochs=3, resume=True), log=None)
    ckpt_c = torch.load(tmp_path / "c" / "checkpoint.pt", weights_only=True)
    ckpt_a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=True)
    assert ckpt_c["epoch"] == 3
    for k, v in ckpt_a["model"].items():
        assert torch.equal(v, ckpt_c["model"][k]), k


def test_hetero_training_step(tmp_path, tiny):
    summary = train(
        _cfg(tmp_path, tiny / "hetero.npz", recipe="sage-hetero-2d", epochs=2, hetero_weight=1.0), log=None
    )
    model, _ = load_model(tmp_path / "run.pt")
    assert model.config.hetero and model.config.in_features == 4
    assert np.isfinite(summary["best_val_hard_penalty"])


def test_cli_hooks_and_bad_parameters(tmp_path, tiny):
    parser = argparse.ArgumentParser()
    add_train_args(parser)
    args = parser.parse_args(
        [
            "sage-base-2d",
            "-o",
            str(tmp_path / "cli.pt"),
            "--data",
            str(tiny / "base.npz"),
            "--epochs",
            "1",
            "--threads",
            "1",
            "--device",
            "cpu",
            "--batch-size",
            "4",
        ]
    )
    assert train_main(args) == 0 and (tmp_path / "cli.pt").exists()
    with pytest.raises(ParameterError):
        train(_cfg(tmp_path, tiny / "base.npz", recipe="sage-giant"), log=None)
    with pytest.raises(ParameterError):
        train(_cfg(tmp_path, tiny / "base.npz", lr_schedule="wavy"), log=None)


def test_fine_tuning_from_weights(tmp_path, tiny):
    train(_cfg(tmp_path, tiny / "base.npz", name="first", epochs=1), log=None)
    summary = train(
        _cfg(tmp_path, tiny / "base.npz", name="second", epochs=1, lr=1e-4, init=str(tmp_path / "first.pt")),
        log=None,
    )
    assert summary["epochs_run"] == 1
    # SAGE-Heterogeneous may start from SAGE-Base: same network, zero weights for the group input p
    train(
        _cfg(
            tmp_path,
            tiny / "hetero.npz",
            name="third",
            recipe="sage-hetero-2d",
            epochs=1,
            lr=1e-12,
            init=str(tmp_path / "first.pt"),
        ),
        log=None,
    )
    base, _ = load_model(tmp_path / "first.pt")
    het, _ = load_model(tmp_path / "third.pt")
    w = het.convs[0].lin_l.weight.detach()
    assert torch.allclose(w[:, :3], base.convs[0].lin_l.weight.detach(), atol=1e-6)
    assert torch.all(w[:, 3].abs() < 1e-6)
    with pytest.raises(ParameterError, match="does not match"):  # but not the other way round
        train(
            _cfg(tmp_path, tiny / "base.npz", name="fourth", epochs=1, init=str(tmp_path / "third.pt")),
            log=None,
        )

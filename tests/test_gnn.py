"""The SAGE networks: feature normalization, losses, the partitioners' contract, shipped weights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torch_geometric")

from models.errors import ModelError  # noqa: E402
from models.graph.batch import GraphBatch  # noqa: E402
from models.nets.gnn import (  # noqa: E402
    BisectionGNN,
    GNNConfig,
    expected_normalized_cut,
    heterogeneity_penalty,
    load_model,
    normalize_features,
    random_rotation,
    save_model,
)
from models.partition import get_partitioner  # noqa: E402
from models.partition.sage import WEIGHTS_DIR, SageBasePartitioner, SageHeteroPartitioner  # noqa: E402


def grid_graph(nx: int, ny: int, nz: int = 1, x0=(0.0, 0.0, 0.0)):
    """Structured grid of nx*ny(*nz) square/cube cells: centroids, measures, CSR adjacency."""
    dim = 2 if nz == 1 else 3
    idx = np.arange(nx * ny * nz).reshape(nz, ny, nx)
    pairs = [
        np.stack([idx[:, :, :-1].ravel(), idx[:, :, 1:].ravel()], 1),
        np.stack([idx[:, :-1, :].ravel(), idx[:, 1:, :].ravel()], 1),
    ]
    if dim == 3:
        pairs.append(np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1))
    e = np.concatenate(pairs)
    e = np.concatenate([e, e[:, ::-1]])
    e = e[np.lexsort((e[:, 1], e[:, 0]))]
    n = nx * ny * nz
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(e[:, 0], minlength=n), out=indptr[1:])
    z, y, x = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    cen = np.column_stack([x.ravel(), y.ravel(), z.ravel()])[:, :dim] + 0.5 + np.asarray(x0)[:dim]
    return cen.astype(float), np.ones(n), indptr, e[:, 1].astype(np.int64)


def make_batch(graphs, tags=None) -> GraphBatch:
    """Disjoint union of (centroids, measures, indptr, indices) graphs as a GraphBatch."""
    ptr, ips, ixs, off, eoff = [0], [np.zeros(1, np.int64)], [], 0, 0
    for c, _m, ip, ix in graphs:
        ips.append(ip[1:] + eoff)
        ixs.append(ix + off)
        off += len(c)
        eoff += len(ix)
        ptr.append(off)
    indices = np.concatenate(ixs)
    return GraphBatch(
        indptr=np.concatenate(ips),
        indices=indices,
        weights=np.ones(len(indices)),
        graph_ptr=np.array(ptr),
        centroids=np.concatenate([g[0] for g in graphs]),
        measures=np.concatenate([g[1] for g in graphs]),
        tags=tags,
        node_ids=np.arange(off),
    )


@pytest.fixture(scope="module")
def weights_dir(tmp_path_factory) -> Path:
    """Randomly initialized (seeded) networks saved like the shipped ones: tests do not depend on them."""
    d = tmp_path_factory.mktemp("weights")
    for dim in (2, 3):
        for hetero, stem in ((False, "sage-base"), (True, "sage-hetero")):
            torch.manual_seed(dim)
            save_model(BisectionGNN(GNNConfig.paper(dim, hetero)), d / f"{stem}-{dim}d.pt")
    return d


def _features(n_graphs=3, dim=2, seed=0):
    rng = np.random.default_rng(seed)
    xs, sizes = [], rng.integers(20, 60, size=n_graphs)
    for s in sizes:
        coords = rng.normal(size=(s, dim)) * rng.uniform(0.1, 5, size=dim) + rng.normal(size=dim) * 10
        xs.append(np.column_stack([coords, rng.uniform(1, 2, size=s)]))
    x = torch.tensor(np.concatenate(xs), dtype=torch.float64)
    batch = torch.repeat_interleave(torch.arange(n_graphs), torch.tensor(sizes))
    return x, batch, sizes


@pytest.mark.parametrize("dim", [2, 3])
def test_normalization_is_per_graph_zero_mean_unit_variance_widest_first(dim):
    x, batch, sizes = _features(4, dim)
    z = normalize_features(x, batch, 4, dim)
    for b in range(4):
        zb = z[batch == b].numpy()
        assert np.allclose(zb[:, :dim].mean(0), 0, atol=1e-9)
        assert np.allclose(zb[:, :dim].var(0), 1, atol=1e-6)
        cov = np.cov(zb[:, :dim].T, bias=True)
        assert np.allclose(cov, np.eye(dim), atol=1e-6)  # decorrelated: principal axes
        assert abs(zb[:, dim].mean()) < 1e-9 and abs(zb[:, dim].std() - 1) < 1e-6
        # one graph alone gives the same result as inside the batch (vectorized correctly)
        alone = normalize_features(x[batch == b], torch.zeros(int(sizes[b]), dtype=torch.long), 1, dim)
        assert torch.allclose(alone, z[batch == b], atol=1e-9)


def test_normalization_undoes_rotation_translation_and_scale():
    x, batch, _ = _features(2, 2)
    q = random_rotation(2, torch.Generator().manual_seed(3))
    y = x.clone()
    y[:, :2] = 7.0 * (x[:, :2] @ q.T) + torch.tensor([3.0, -1.0], dtype=x.dtype)
    a, b = normalize_features(x, batch, 2, 2), normalize_features(y, batch, 2, 2)
    assert torch.allclose(a, b, atol=1e-6)


def test_uniform_measure_normalizes_to_zero():
    x, batch, _ = _features(2, 2)
    x[:, 2] = 0.25
    assert torch.all(normalize_features(x, batch, 2, 2)[:, 2] == 0)


def test_expected_ncut_equals_normalized_cut_for_hard_labels():
    cen, m, ip, ix = grid_graph(6, 4)
    rows = np.repeat(np.arange(len(cen)), np.diff(ip))
    labels = (cen[:, 0] > 2).astype(int)
    y = torch.nn.functional.one_hot(torch.tensor(labels), 2).double()
    ei = torch.tensor(np.stack([rows, ix]))
    deg = torch.tensor(np.diff(ip), dtype=torch.float64)
    got = expected_normalized_cut(y, ei, torch.zeros(len(cen), dtype=torch.long), 1, deg)
    cut = 4  # a vertical cut through a 6 x 4 grid
    vol = [np.diff(ip)[labels == k].sum() for k in (0, 1)]
    assert got.item() == pytest.approx(cut / vol[0] + cut / vol[1])


def test_heterogeneity_penalty():
    y = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5], [0.5, 0.5]])
    p = torch.tensor([0.0, 1.0, 0.0, 0.0])
    batch = torch.tensor([0, 0, 1, 1])
    pen = heterogeneity_penalty(y, p, batch, 2, weight=2.0)
    assert pen[0].item() == 0.0  # groups already separated: no penalty
    assert pen[1].item() == 0.0  # one group only: the penalty does not apply
    y2 = torch.tensor([[0.0, 1.0], [1.0, 0.0], [0.5, 0.5], [0.5, 0.5]])
    assert heterogeneity_penalty(y2, p, batch, 2, weight=2.0)[0].item() == pytest.approx(2.0)


def test_save_load_roundtrip_identical_outputs(tmp_path):
    torch.manual_seed(0)
    model = BisectionGNN(GNNConfig.paper(2)).eval()
    save_model(model, tmp_path / "m.pt", meta={"note": "x"})
    again, meta = load_model(tmp_path / "m.pt")
    x, batch, _ = _features(2, 2)
    x = x.float()
    ei = torch.tensor([[0, 1, 1, 2], [1, 0, 2, 1]])
    with torch.inference_mode():
        assert torch.equal(model(x, ei), again(x, ei))
    assert meta == {"note": "x"}


def test_sparse_adjacency_matches_edge_index():
    from models.nets.gnn import csr_adjacency

    cen, m, ip, ix = grid_graph(7, 5)
    torch.manual_seed(1)
    model = BisectionGNN(GNNConfig.paper(2)).eval()
    x = torch.tensor(np.column_stack([cen, m]), dtype=torch.float32)
    rows = np.repeat(np.arange(len(cen)), np.diff(ip))
    with torch.inference_mode():
        a = model(x, torch.tensor(np.stack([ix, rows])))
        b = model(x, csr_adjacency(ip, ix, len(cen)))
    assert torch.allclose(a, b, atol=1e-5)


def test_fused_inference_matches_forward():
    """BisectionGNN.infer (the CPU inference path) is the same function as forward(), 2D and 3D,
    isolated nodes included."""
    from models.nets.gnn import neighbour_lists

    for dim, shape in ((2, (7, 5)), (3, (4, 3, 3))):
        cen, m, ip, ix = grid_graph(*shape)
        # an isolated extra node (no neighbours: its mean aggregation is 0 in both paths)
        cen = np.vstack([cen, cen[:1] + 5.0])
        m = np.r_[m, m[0]]
        ip = np.r_[ip, ip[-1]]
        torch.manual_seed(dim)
        model = BisectionGNN(GNNConfig.paper(dim)).eval()
        x = torch.tensor(np.column_stack([cen, m]), dtype=torch.float32)
        rows = np.repeat(np.arange(len(cen)), np.diff(ip))
        with torch.inference_mode():
            a = model(x, torch.tensor(np.stack([ix, rows])))
            b = model.infer(x, neighbour_lists(ip, ix))
        assert b.shape == (len(cen), 2)
        assert torch.allclose(a, b, atol=1e-5), float((a - b).abs().max())


@pytest.mark.parametrize("cls", [SageBasePartitioner, SageHeteroPartitioner])
@pytest.mark.parametrize("dim", [2, 3])
def test_bisect_batch_contract(weights_dir, cls, dim):
    shape = (6, 5) if dim == 2 else (4, 3, 3)
    graphs = [grid_graph(*shape, x0=(10.0 * i, 0, 0)) for i in range(3)] + [
        grid_graph(*(s * 2 for s in shape))
    ]
    tags = None
    if cls is SageHeteroPartitioner:
        tags = np.concatenate([(g[0][:, 0] % 10 > 3).astype(int) + 5 for g in graphs])
    batch = make_batch(graphs, tags)
    part = cls(weights_dir=weights_dir, device="cpu")
    labels = part.bisect_batch(batch)
    assert labels.shape == (batch.n_nodes,) and set(np.unique(labels)) <= {0, 1}
    for b in range(batch.n_graphs):
        lo, hi = batch.graph_ptr[b], batch.graph_ptr[b + 1]
        assert 0 < labels[lo:hi].sum() < hi - lo  # both sides non-empty
        sub = batch.subgraph(b)
        assert np.array_equal(part.bisect_batch(sub), labels[lo:hi])  # batched == one graph at a time
        _assert_sides_connected(sub, labels[lo:hi])
    assert np.array_equal(part.bisect_batch(batch), labels)  # deterministic


def _assert_sides_connected(g: GraphBatch, labels):
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    rows = np.repeat(np.arange(g.n_nodes), np.diff(g.indptr))
    for side in (0, 1):
        keep = (labels[rows] == side) & (labels[g.indices] == side)
        m = sp.csr_matrix((np.ones(keep.sum()), (rows[keep], g.indices[keep])), shape=(g.n_nodes,) * 2)
        _, comp = connected_components(m, directed=False)
        assert np.unique(comp[labels == side]).size == 1


def test_contiguous_sides_removes_islands():
    from models.partition.sage import contiguous_sides

    cen, m, ip, ix = grid_graph(8, 8)
    batch = make_batch([(cen, m, ip, ix)])
    labels = (cen[:, 0] > 4).astype(np.int64)
    labels[9] = 1  # an island of side 1 inside side 0
    labels[62] = 0  # and one of side 0 inside side 1
    fixed = contiguous_sides(batch, labels)
    assert np.array_equal(fixed, (cen[:, 0] > 4).astype(np.int64))


def test_missing_weights_raise_model_error(tmp_path):
    part = SageBasePartitioner(weights_dir=tmp_path, device="cpu")
    with pytest.raises(ModelError, match="missing"):
        part.bisect_batch(make_batch([grid_graph(4, 4)]))


def test_hetero_refuses_three_groups(weights_dir):
    g = grid_graph(6, 6)
    tags = (g[0][:, 0] // 2).astype(int)  # three groups
    with pytest.raises(ModelError, match="two physical groups"):
        SageHeteroPartitioner(weights_dir=weights_dir, device="cpu").bisect_batch(make_batch([g], tags))


def test_registry_names():
    for name, cls in (("sage-base", SageBasePartitioner), ("sage-hetero", SageHeteroPartitioner)):
        p = get_partitioner(name, seed=0)
        assert isinstance(p, cls) and p.name == name and p.dims == (2, 3) and not p.supports_kway
        assert p.description


@pytest.mark.parametrize("stem", ["sage-base-2d", "sage-base-3d", "sage-hetero-2d", "sage-hetero-3d"])
def test_shipped_weights(stem):
    path = WEIGHTS_DIR / f"{stem}.pt"
    if not path.exists():
        pytest.skip(f"{path.name} not trained yet")
    assert path.stat().st_size < 2_000_000
    model, meta = load_model(path)  # weights_only=True inside
    cfg = model.config
    assert cfg.dim == int(stem[-2]) and cfg.hetero == ("hetero" in stem)
    assert (cfg.sage_units, cfg.dense_units) == ((64, 32) if cfg.dim == 2 else (128, 64))
    assert "summary" in meta
    assert (WEIGHTS_DIR / f"{stem}.md").exists()  # model card


@pytest.mark.parametrize("model", ["sage-base", "sage-hetero"])
@pytest.mark.parametrize(
    "mode,kw",
    [
        ("nref", dict(nref=4)),
        ("target-size", dict(target_size=0.3)),
        ("mult-factor", dict(mult_factor=0.25)),
        ("segregated", dict(mult_factor=0.3)),
        ("coarsen", dict(nref=3, subset=np.arange(0, 300))),
    ],
)
def test_every_mode_runs_with_sage(weights_dir, model, mode, kw):
    from models.learn.generate import generate
    from models.partition.agglomerate import agglomerate
    from models.pipeline import prepare

    mesh = generate("split", seed=1, size=0.06).to_mesh()
    _, data = prepare(mesh)
    res = agglomerate(mesh, data, model=model, mode=mode, model_options={"weights_dir": weights_dir}, **kw)
    assert res.labels.shape == (mesh.n_cells,) and res.n_elements > 1
    if mode == "nref":
        assert res.requested == 16 and 1 < res.parts_before_split <= 16
    if mode == "segregated":  # no element mixes the two groups
        mixed = [np.unique(mesh.tags[res.labels == e]).size for e in range(res.n_elements)]
        assert max(mixed) == 1
    with pytest.raises(Exception, match="k-way"):
        agglomerate(mesh, data, model=model, mode="kway", k=4, model_options={"weights_dir": weights_dir})


def test_contiguous_sides_keeps_disconnected_inclusions_with_their_group():
    from models.partition.sage import contiguous_sides

    cen, m, ip, ix = grid_graph(9, 9)
    batch = make_batch([(cen, m, ip, ix)])
    p = np.zeros(len(cen))
    incl = [10, 16, 64, 70]  # four one-cell inclusions, apart from each other
    p[incl] = 1
    labels = p.astype(np.int64).copy()
    labels[40] = 1  # a matrix cell wrongly on the inclusions' side
    fixed = contiguous_sides(batch, labels, p)
    assert np.array_equal(fixed, p.astype(np.int64))
    assert contiguous_sides(batch, labels).sum() == 1  # without groups: one side-1 island is kept


def test_smooth_cut_straightens_a_jagged_boundary_but_not_group_interfaces():
    from models.partition.sage import smooth_cut

    cen, m, ip, ix = grid_graph(8, 8)
    batch = make_batch([(cen, m, ip, ix)])
    straight = (cen[:, 0] > 4).astype(np.int64)
    jagged = straight.copy()
    jagged[[3 + 8 * 2, 3 + 8 * 5]] = 1  # two bumps across the cut
    assert np.array_equal(smooth_cut(batch, jagged, 2), straight)
    p = np.zeros(len(cen))
    p[[3 + 8 * 2]] = 1  # a one-cell inclusion: its own side, it must not move
    assert smooth_cut(batch, jagged, 2, p)[3 + 8 * 2] == 1


def test_group_feature_is_signed_in_mixed_graphs_and_zero_in_single_group_graphs():
    x, batch, sizes = _features(2, 2)
    p = torch.zeros(len(x), 1, dtype=x.dtype)
    first = batch == 0
    p[first.nonzero()[:5, 0]] = 1.0  # graph 0 holds both groups, graph 1 only group 0
    z = normalize_features(torch.cat([x, p], 1), batch, 2, 2)
    assert torch.equal(z[first, 3], 2 * p[first, 0] - 1)
    assert torch.all(z[~first, 3] == 0)


def test_sage_layer_matches_torch_geometric():
    """Our plain-torch SageConv is torch-geometric's SAGEConv(aggr="mean"): same parameter names, same
    outputs (edge list and sparse CSR adjacency, isolated node included), same gradients."""
    from torch_geometric.nn import SAGEConv

    from models.nets.gnn import SageConv, csr_adjacency

    cen, m, ip, ix = grid_graph(5, 4)
    ip = np.r_[ip, ip[-1]]  # an isolated extra node
    x = torch.tensor(np.column_stack([np.vstack([cen, cen[:1] + 3.0]), np.r_[m, m[0]]]), dtype=torch.float32)
    rows = np.repeat(np.arange(len(x)), np.diff(ip))
    ei = torch.tensor(np.stack([ix, rows]))
    torch.manual_seed(3)
    ours = SageConv(3, 8)
    torch.manual_seed(3)
    ref = SAGEConv(3, 8, aggr="mean")
    assert sorted(ours.state_dict()) == sorted(ref.state_dict())
    for name, value in ref.state_dict().items():  # seeded initialization: the same weights
        assert torch.allclose(ours.state_dict()[name], value, atol=1e-7), name
    ref.load_state_dict(ours.state_dict())
    xa, xb = x.clone().requires_grad_(), x.clone().requires_grad_()
    a, b = ours(xa, ei), ref(xb, ei)
    assert torch.allclose(a, b, atol=1e-6)
    a.square().sum().backward()
    b.square().sum().backward()
    assert torch.allclose(xa.grad, xb.grad, atol=1e-5)
    with torch.inference_mode():
        assert torch.allclose(ours(x, csr_adjacency(ip, ix, len(x))), b.detach(), atol=1e-5)


def test_inference_does_not_import_torch_geometric(weights_dir):
    """Loading weights and bisecting on the CPU leaves torch-geometric (and torch._dynamo, which it
    loads) unimported: together they cost about 2 s of a command's start-up."""
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    code = (
        "import sys\n"
        "from models.mesh.read import read_mesh\n"
        "from models import pipeline\n"
        f"opts = dict(device='cpu', weights_dir={str(weights_dir)!r})\n"
        "res = pipeline.run(read_mesh('tests/data/BrainCoronalNoHoles.vtu'), model='sage-base', mode='nref', nref=2,\n"
        "                   model_options=opts, compute_metrics=False)\n"
        "assert res.summary()['elements'] == 4, res.summary()\n"
        "print(sorted(m for m in sys.modules if m.startswith(('torch_geometric', 'torch._dynamo'))))\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=root, env=env
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


@pytest.mark.parametrize("dim,hetero", [(2, False), (3, False), (2, True), (3, True)])
def test_numpy_inference_matches_torch(weights_dir, dim, hetero):
    """gnn_numpy (the CPU path, no torch) reads the weight files and computes the same probabilities as
    the torch network, normalization included, on a batch of graphs with an isolated node; with the
    shipped weights as well."""
    from models.nets import gnn_numpy
    from models.nets.gnn import neighbour_lists
    from models.partition.sage import batch_features

    shape = (6, 5) if dim == 2 else (4, 3, 3)
    graphs = [grid_graph(*shape, x0=(10.0 * i, 0, 0)) for i in range(2)] + [
        grid_graph(*(s * 2 for s in shape))
    ]
    cen, m, ip, ix = graphs[-1]
    graphs[-1] = (np.vstack([cen, cen[:1] + 0.3]), np.r_[m, m[0] * 1.5], np.r_[ip, ip[-1]], ix)
    # distinct principal axes (a square grid's are not unique: any two solvers may pick different ones)
    rng = np.random.default_rng(dim)
    graphs = [
        (
            c * [1.0, 1.37, 0.71][:dim] + rng.normal(0, 0.05, c.shape),
            mm * rng.uniform(0.5, 1.5, len(mm)),
            p,
            q,
        )
        for c, mm, p, q in graphs
    ]
    tags = np.concatenate([(g[0][:, 0] % 10 > 3).astype(int) for g in graphs]) if hetero else None
    batch = make_batch(graphs, tags)
    stem = "sage-hetero" if hetero else "sage-base"
    for path in (weights_dir / f"{stem}-{dim}d.pt", WEIGHTS_DIR / f"{stem}-{dim}d.pt"):
        model, _ = load_model(path)
        weights = gnn_numpy.read_weights(path)
        assert weights["config"] == model.config.to_dict()
        for name, value in model.state_dict().items():
            assert np.array_equal(weights["state_dict"][name], value.numpy()), name
        raw = batch_features(batch, hetero)
        gi = batch.graph_index()
        x_np = gnn_numpy.normalize_features(raw, gi, batch.n_graphs, dim)
        x_t = normalize_features(torch.from_numpy(raw), torch.from_numpy(gi), batch.n_graphs, dim)
        assert np.allclose(x_np, x_t.numpy(), atol=1e-4), np.abs(x_np - x_t.numpy()).max()
        a = model.infer(x_t, neighbour_lists(batch.indptr, batch.indices)).numpy()
        b = gnn_numpy.probabilities(weights, x_np, batch.indptr, batch.indices)
        assert b.shape == (batch.n_nodes, 2) and b.dtype == np.float32
        assert np.allclose(a, b, atol=1e-4), np.abs(a - b).max()


def test_numpy_weights_reader_refuses_foreign_pickles(tmp_path):
    """A weight file that pickles anything but tensors and plain types is refused, not run."""
    from models.nets import gnn_numpy

    path = tmp_path / "evil.pt"
    torch.save({"config": {}, "state_dict": {}, "meta": {"x": Path("x")}}, path)
    with pytest.raises(Exception, match="unexpected object"):
        gnn_numpy.read_weights(path)

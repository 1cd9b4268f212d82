"""Training data sets: many generated meshes with their dual graphs precomputed, in one .npz file.

A data set stores, for every graph, the raw node features (centroid, cell measure, physical group p
in {0, 1}), the undirected edges (local ids, i < j) and the node degrees, all concatenated with
pointer arrays; `GraphDataset` reads it back and yields torch-geometric `Data` / `Batch` objects.

Recipes name the mix of mesh kinds. Besides whole meshes, a recipe may ask for "pieces": connected
parts of a mesh cut out by a few random plane cuts, so that the network also sees the irregular
subgraphs that recursive bisection hands it after the first level.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from models.errors import ParameterError, listed

FORMAT_VERSION = 1


@dataclass(frozen=True)
class Recipe:
    """What a data set is made of: kinds with weights, size ranges, fraction of random pieces."""

    name: str
    dim: int
    hetero: bool
    n_meshes: int
    kinds: dict[str, float]
    size_range: tuple[float, float]  # mesh size h for gmsh kinds
    points_range: tuple[int, int] = (150, 1200)  # delaunay / voronoi point counts
    div_range: tuple[int, int] = (10, 40)  # structured divisions per side
    pieces: float = 0.0  # fraction of graphs that are random pieces of a mesh
    piece_depth: tuple[int, int] = (1, 4)  # number of random cuts for a piece
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)


# The paper's data sets (MISSION.md sections 2-3). Kind weights are the fractions of meshes.
RECIPES: dict[str, Recipe] = {
    "sage-base-2d": Recipe(
        "sage-base-2d",
        2,
        False,
        800,
        {"square-quad": 1, "square-tri": 1, "delaunay": 1, "voronoi": 1},
        (0.025, 0.06),
    ),
    "sage-base-3d": Recipe(
        "sage-base-3d",
        3,
        False,
        400,
        {"cube": 1, "cube-portion": 3},
        (0.09, 0.18),
    ),
    "sage-hetero-2d": Recipe(
        "sage-hetero-2d",
        2,
        True,
        600,
        {"homogeneous": 1, "split": 1, "inclusions": 1},
        (0.025, 0.06),
        extra={"inclusions": (6, 12)},
    ),
    "sage-hetero-3d": Recipe(
        "sage-hetero-3d",
        3,
        True,
        400,
        {"cube-hetero": 1},
        (0.09, 0.18),
    ),
}
_HOMOGENEOUS_2D = ("square-quad", "square-tri", "delaunay", "voronoi")


def get_recipe(name: str, **overrides) -> Recipe:
    """A named recipe, with fields replaced by the non-None overrides."""
    if name not in RECIPES:
        raise ParameterError(f"unknown recipe {name!r}; choose one of {listed(sorted(RECIPES))}")
    base = RECIPES[name].to_dict()
    base.update({k: v for k, v in overrides.items() if v is not None})
    return Recipe(**base)


# ------------------------------------------------------------------------------ graph extraction


@dataclass
class GraphArrays:
    """One graph: raw features (N, F) float32, undirected edges (E, 2) int32 (i < j), degrees (N,)."""

    x: np.ndarray
    edges: np.ndarray
    degree: np.ndarray
    kind: str
    seed: int


def mesh_graph(mesh, hetero: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(features, CSR indptr, indices, p) of a library Mesh: centroid and measure (+ p if hetero)."""
    from models.mesh.dual import dual_graph
    from models.mesh.geometry import measures_and_centroids

    g = dual_graph(mesh)
    measures, centroids = measures_and_centroids(mesh)
    p = group_indicator(mesh.tags, len(measures))
    cols = [centroids, measures[:, None]] + ([p[:, None]] if hetero else [])
    return np.column_stack(cols).astype(np.float64), g.indptr, g.indices, p


def group_indicator(tags: np.ndarray | None, n: int) -> np.ndarray:
    """p in {0, 1}: 0 for the smallest tag, 1 for the others (two groups at most make sense)."""
    if tags is None:
        return np.zeros(n)
    return (np.asarray(tags) != np.min(tags)).astype(np.float64)


def _csr_edges(indptr: np.ndarray, indices: np.ndarray) -> np.ndarray:
    rows = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    keep = rows < indices
    return np.column_stack([rows[keep], indices[keep]]).astype(np.int32)


def _sub_csr(indptr, indices, nodes):
    """Induced subgraph on `nodes` (sorted ids), CSR with local ids."""
    local = np.full(len(indptr) - 1, -1, dtype=np.int64)
    local[nodes] = np.arange(len(nodes))
    rows = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    keep = (local[rows] >= 0) & (local[indices] >= 0)
    r, c = local[rows[keep]], local[indices[keep]]
    sub_ptr = np.zeros(len(nodes) + 1, dtype=np.int64)
    np.cumsum(np.bincount(r, minlength=len(nodes)), out=sub_ptr[1:])
    return sub_ptr, c


def random_piece(
    x: np.ndarray, indptr, indices, dim: int, rng: np.random.Generator, depth: int
) -> np.ndarray:
    """Nodes of a random connected piece: `depth` random plane cuts at random quantiles, keeping one
    side each time, then the largest connected component."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    nodes = np.arange(len(x))
    for _ in range(depth):
        if len(nodes) < 64:
            break
        d = rng.normal(size=dim)
        proj = x[nodes, :dim] @ d
        cut = np.quantile(proj, rng.uniform(0.3, 0.7))
        nodes = nodes[proj <= cut] if rng.random() < 0.5 else nodes[proj > cut]
    sub_ptr, sub_idx = _sub_csr(indptr, indices, nodes)
    a = csr_matrix((np.ones(len(sub_idx)), sub_idx, sub_ptr), shape=(len(nodes), len(nodes)))
    _, comp = connected_components(a, directed=False)
    return nodes[comp == np.argmax(np.bincount(comp))]


def graph_from_nodes(x, indptr, indices, nodes, kind, seed) -> GraphArrays:
    sub_ptr, sub_idx = _sub_csr(indptr, indices, nodes)
    return GraphArrays(
        x=x[nodes].astype(np.float32),
        edges=_csr_edges(sub_ptr, sub_idx),
        degree=np.diff(sub_ptr).astype(np.int32),
        kind=kind,
        seed=seed,
    )


def _draw_kind(recipe: Recipe, rng: np.random.Generator) -> str:
    kinds = list(recipe.kinds)
    w = np.array([recipe.kinds[k] for k in kinds], dtype=float)
    kind = kinds[rng.choice(len(kinds), p=w / w.sum())]
    if kind == "homogeneous":
        kind = _HOMOGENEOUS_2D[rng.integers(len(_HOMOGENEOUS_2D))]
    return kind


def recipe_graph(recipe: Recipe, index: int, seed: int) -> GraphArrays:
    """Graph number `index` of the recipe's data set (independent of the others: own seed)."""
    from models.learn.generate import generate

    rng = np.random.default_rng([seed, index])
    kind = _draw_kind(recipe, rng)
    mesh_seed = int(rng.integers(2**31))
    piece = rng.random() < recipe.pieces
    grow = 2.0 if piece else 1.0  # pieces come from finer meshes so they keep a useful size
    size, n = None, None
    if kind in ("square-tri", "square-quad"):
        size = 1.0 / (rng.integers(*recipe.div_range) * np.sqrt(grow))
    elif kind in ("delaunay", "voronoi"):
        n = int(rng.integers(*recipe.points_range) * grow)
    elif kind != "stl":
        lo, hi = recipe.size_range
        size = float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) / grow ** (1 / recipe.dim)
    if kind == "inclusions" and "inclusions" in recipe.extra:
        n = int(rng.integers(recipe.extra["inclusions"][0], recipe.extra["inclusions"][1] + 1))
    gen = generate(kind, mesh_seed, size=size, n=n)
    x, indptr, indices, _ = mesh_graph(gen.to_mesh(), recipe.hetero)
    nodes = np.arange(len(x))
    if piece:
        nodes = random_piece(
            x, indptr, indices, recipe.dim, rng, int(rng.integers(*recipe.piece_depth, endpoint=True))
        )
    return graph_from_nodes(x, indptr, indices, nodes, kind + ("-piece" if piece else ""), mesh_seed)


# ------------------------------------------------------------------------------------ storage


class GraphDataset:
    """Graphs stored concatenated: x (N, F), edges (E, 2) local ids, degree (N,), with node_ptr and
    edge_ptr (G+1,) marking where graph g starts."""

    def __init__(self, x, edges, degree, node_ptr, edge_ptr, kinds, meta: dict):
        self.x, self.edges, self.degree = x, edges, degree
        self.node_ptr, self.edge_ptr = node_ptr, edge_ptr
        self.kinds = kinds
        self.meta = meta

    def __len__(self) -> int:
        return int(len(self.node_ptr) - 1)

    @property
    def n_nodes(self) -> int:
        return int(self.node_ptr[-1])

    @property
    def dim(self) -> int:
        return int(self.meta["dim"])

    @property
    def hetero(self) -> bool:
        return bool(self.meta["hetero"])

    @classmethod
    def from_graphs(cls, graphs: list[GraphArrays], meta: dict) -> GraphDataset:
        node_ptr = np.zeros(len(graphs) + 1, dtype=np.int64)
        edge_ptr = np.zeros(len(graphs) + 1, dtype=np.int64)
        np.cumsum([len(g.x) for g in graphs], out=node_ptr[1:])
        np.cumsum([len(g.edges) for g in graphs], out=edge_ptr[1:])
        return cls(
            np.concatenate([g.x for g in graphs]),
            np.concatenate([g.edges for g in graphs]),
            np.concatenate([g.degree for g in graphs]),
            node_ptr,
            edge_ptr,
            np.array([g.kind for g in graphs]),
            meta,
        )

    def save(self, path: str | Path) -> None:
        np.savez_compressed(
            path,
            x=self.x,
            edges=self.edges,
            degree=self.degree.astype(np.int16),
            node_ptr=self.node_ptr,
            edge_ptr=self.edge_ptr,
            kinds=self.kinds,
            meta=np.array(json.dumps(self.meta)),
        )

    @classmethod
    def load(cls, path: str | Path) -> GraphDataset:
        with np.load(path, allow_pickle=False) as f:
            meta = json.loads(str(f["meta"]))
            if meta.get("format") != FORMAT_VERSION:
                raise ParameterError(f"{path}: data set format {meta.get('format')} != {FORMAT_VERSION}")
            return cls(
                f["x"],
                f["edges"],
                f["degree"].astype(np.int64),
                f["node_ptr"],
                f["edge_ptr"],
                f["kinds"],
                meta,
            )

    def subset(self, ids) -> GraphDataset:
        graphs = [self.arrays(int(i)) for i in ids]
        return GraphDataset.from_graphs(graphs, dict(self.meta))

    def arrays(self, i: int) -> GraphArrays:
        a, b = self.node_ptr[i], self.node_ptr[i + 1]
        c, d = self.edge_ptr[i], self.edge_ptr[i + 1]
        return GraphArrays(self.x[a:b], self.edges[c:d], self.degree[a:b], str(self.kinds[i]), 0)

    def data(self, i: int, rotation: np.ndarray | None = None):
        """Graph i as a torch-geometric Data: x (raw features, coordinates rotated if asked),
        edge_index (both directions), degree."""
        import torch
        from torch_geometric.data import Data

        g = self.arrays(i)
        x = torch.from_numpy(np.ascontiguousarray(g.x))
        if rotation is not None:
            x = x.clone()
            x[:, : self.dim] = x[:, : self.dim] @ torch.as_tensor(rotation, dtype=x.dtype).T
        e = torch.from_numpy(g.edges.astype(np.int64)).T
        edge_index = torch.cat([e, e.flip(0)], dim=1)
        return Data(x=x, edge_index=edge_index, degree=torch.from_numpy(g.degree).float(), num_nodes=len(g.x))

    def batches(self, batch_size: int, shuffle: bool = False, generator=None, rotate: bool = False):
        """Yield torch-geometric Batch objects of `batch_size` graphs (random rotations if asked)."""
        import torch
        from torch_geometric.data import Batch

        from models.nets.gnn import random_rotation

        order = torch.randperm(len(self), generator=generator) if shuffle else torch.arange(len(self))
        for s in range(0, len(self), batch_size):
            ids = order[s : s + batch_size].tolist()
            rots = [random_rotation(self.dim, generator).numpy() if rotate else None for _ in ids]
            yield Batch.from_data_list([self.data(i, r) for i, r in zip(ids, rots, strict=False)])


def build_dataset(
    recipe: str | Recipe,
    path: str | Path | None = None,
    seed: int = 0,
    n_meshes: int | None = None,
    log=print,
) -> GraphDataset:
    """Generate the recipe's meshes (seeded), extract their graphs, save to `path` if given."""
    recipe = get_recipe(recipe, n_meshes=n_meshes) if isinstance(recipe, str) else recipe
    t0 = time.perf_counter()
    graphs = []
    for i in range(recipe.n_meshes):
        graphs.append(recipe_graph(recipe, i, seed))
        if log and (i + 1) % max(1, recipe.n_meshes // 10) == 0:
            log(
                f"  data set {recipe.name}: {i + 1}/{recipe.n_meshes} graphs ({time.perf_counter() - t0:.0f} s)"
            )
    meta = {
        "format": FORMAT_VERSION,
        "dim": recipe.dim,
        "hetero": recipe.hetero,
        "seed": seed,
        "recipe": recipe.to_dict(),
        "build_seconds": round(time.perf_counter() - t0, 1),
    }
    ds = GraphDataset.from_graphs(graphs, meta)
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        ds.save(path)
    return ds

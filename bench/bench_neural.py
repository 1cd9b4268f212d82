"""Neural agglomeration benchmark (issue 4): SAGE-Base / SAGE-Heterogeneous vs METIS and k-means
recursive bisection, in one run on one machine.

1. Brain coronal slice, nref 7: normalized cut (ratio to METIS), extra elements from disconnected
   fragments before any absorption, connectivity after the split, CPU time per 10k cells.
2. The same SAGE-Base run batched level by level vs one forward pass per subgraph: speed-up, same labels.
3. Unit cube with ~100k tetrahedra, nref 8: same table as 1.
4. Unit square with 16 circular inclusions (regular grid), nref 6: heterogeneity preservation.
5. Unit cube cut into 4 heterogeneous parts (~25k tetrahedra), nref 5: heterogeneity preservation.

Run: python bench/bench_neural.py [--quick] [--weights-dir DIR] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from models.graph.batch import GraphBatch  # noqa: E402
from models.partition import get_partitioner  # noqa: E402
from models.partition.agglomerate import CellData, connected_parts, recursive_bisection  # noqa: E402
from models.partition.base import Partitioner  # noqa: E402


def cell_data(mesh) -> CellData:
    from models.pipeline import prepare

    return prepare(mesh)[1]


def normalized_cut(indptr: np.ndarray, indices: np.ndarray, labels: np.ndarray) -> float:
    """sum over parts of cut(S) / vol(S), vol = sum of degrees (MISSION.md section 1)."""
    rows = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    k = int(labels.max()) + 1
    cut = np.bincount(labels[rows], weights=(labels[rows] != labels[indices]).astype(float), minlength=k)
    vol = np.bincount(labels, weights=np.diff(indptr).astype(float), minlength=k)
    return float(np.sum(cut[vol > 0] / vol[vol > 0]))


def heterogeneity_preservation(labels: np.ndarray, tags: np.ndarray) -> np.ndarray:
    """HP per element = max(p_mean, 1 - p_mean), p = 1 for the larger tag (MISSION.md section 6)."""
    p = (tags != tags.min()).astype(float)
    k = int(labels.max()) + 1
    mean = np.bincount(labels, weights=p, minlength=k) / np.maximum(np.bincount(labels, minlength=k), 1)
    return np.maximum(mean, 1 - mean)


def all_connected(data: CellData, labels: np.ndarray) -> bool:
    g = data.graph
    rows = np.repeat(np.arange(g.n), np.diff(g.indptr))
    keep = labels[rows] == labels[g.indices]
    m = sp.csr_matrix((np.ones(int(keep.sum())), (rows[keep], g.indices[keep])), shape=(g.n, g.n))
    return connected_components(m, directed=False)[0] == int(labels.max()) + 1


class Timed(Partitioner):
    """Wraps a partitioner and adds up the CPU time spent inside bisect_batch (the inference)."""

    def __init__(self, inner: Partitioner, per_graph: bool = False):
        self.inner, self.per_graph, self.dims = inner, per_graph, inner.dims
        self.name = inner.name + ("-per-graph" if per_graph else "")
        self.cpu = self.wall = 0.0
        self.calls = 0

    def bisect_batch(self, batch: GraphBatch) -> np.ndarray:
        c, w = time.process_time(), time.perf_counter()
        if self.per_graph:  # the unbatched way: one forward pass per subgraph
            out = np.concatenate([self.inner.bisect_batch(batch.subgraph(b)) for b in range(batch.n_graphs)])
            self.calls += batch.n_graphs
        else:
            out = self.inner.bisect_batch(batch)
            self.calls += 1
        self.cpu += time.process_time() - c
        self.wall += time.perf_counter() - w
        return out


def run(data: CellData, part: Partitioner, nref: int) -> dict:
    nodes = np.arange(data.graph.n)
    t0 = time.process_time()
    w0 = time.perf_counter()
    raw = recursive_bisection(data, part, nodes, np.zeros(data.graph.n, dtype=np.int64), levels=nref)
    cpu, wall = time.process_time() - t0, time.perf_counter() - w0
    split, _ = connected_parts(data, raw, nodes)
    n_parts = int(np.unique(raw).size)
    n_split = int(split.max()) + 1
    return {
        "labels": raw,
        "split": split,
        "ncut": normalized_cut(data.graph.indptr, data.graph.indices, raw),
        "parts": n_parts,
        "elements_after_split": n_split,
        "extra_fragments_pct": 100.0 * (n_split - n_parts) / n_parts,
        "connected_after": bool(all_connected(data, split)),
        "cpu_s": cpu,
        "wall_s": wall,
        "cpu_per_10k_s": cpu / data.graph.n * 1e4,
    }


def table(title: str, rows: dict, ref: str = "metis") -> None:
    print(f"\n## {title}")
    print(
        "| method | parts | normalized cut | ratio to METIS | extra fragments % | connected after split | "
        "CPU s | CPU s / 10k cells |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        print(
            f"| {name} | {r['parts']} | {r['ncut']:.4f} | {r['ncut'] / rows[ref]['ncut']:.3f} | "
            f"{r['extra_fragments_pct']:.2f} | {r['connected_after']} | {r['cpu_s']:.2f} | {r['cpu_per_10k_s']:.3f} |"
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--brain", default=str(ROOT / "tests/data/BrainCoronalNoHoles.vtu"))
    ap.add_argument(
        "--weights-dir", default=None, help="use weights from this folder instead of models/weights"
    )
    ap.add_argument(
        "--cube-size", type=float, default=0.036, help="gmsh size h of the cube (0.036: ~100k tets)"
    )
    ap.add_argument("--quick", action="store_true", help="skip the 100k cube")
    ap.add_argument(
        "--skip", default="", help="comma list of sections to skip: brain,batch,cube,hetero,hetero3d"
    )
    ap.add_argument("--json", default=None, help="also write the numbers as JSON")
    ap.add_argument(
        "--threads", type=int, default=1, help="torch CPU threads (default 1: CPU time is what is compared)"
    )
    args = ap.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))

    import torch

    from models.learn.generate import generate
    from models.mesh.read import read_mesh

    torch.set_num_threads(args.threads)
    opts = {} if args.weights_dir is None else {"weights_dir": args.weights_dir}
    methods = {
        "metis": get_partitioner("metis"),
        "kmeans": get_partitioner("kmeans"),
        "sage-base": get_partitioner("sage-base", **opts),
        "sage-base (raw argmax)": get_partitioner("sage-base", contiguous=False, smooth=0, **opts),
    }
    device = f"GPU {torch.cuda.get_device_name(0)}" if torch.cuda.is_available() else "CPU"
    out: dict = {
        "machine": f"{torch.get_num_threads()} torch thread(s), {device}",
        "torch": torch.__version__,
    }
    print(f"# bench_neural ({out['machine']}, torch {torch.__version__})")

    if "brain" not in skip or "batch" not in skip:
        brain = read_mesh(args.brain)
        data = cell_data(brain)
        print(f"brain: {brain.n_cells} cells")
        methods["sage-base"].bisect_batch(make_warmup(data))  # load weights / warm up once
    if "brain" not in skip:
        rows = {name: run(data, p, 7) for name, p in methods.items()}
        table(f"Brain coronal slice ({brain.n_cells} triangles), nref 7", rows)
        out["brain"] = {
            k: {kk: vv for kk, vv in v.items() if kk not in ("labels", "split")} for k, v in rows.items()
        }
    if "batch" not in skip:
        tb, ts = Timed(methods["sage-base"]), Timed(methods["sage-base"], per_graph=True)
        batched, single = run(data, tb, 7), run(data, ts, 7)
        same = bool(np.array_equal(batched["labels"], single["labels"]))
        print("\n## Batched level-by-level inference vs one forward pass per subgraph (brain, nref 7)")
        print("| inference | forward calls | inference CPU s | inference wall s | whole bisection CPU s |")
        print("|---|---|---|---|---|")
        for label, t, r in (
            ("batched (one pass per level)", tb, batched),
            ("one pass per subgraph", ts, single),
        ):
            print(f"| {label} | {t.calls} | {t.cpu:.3f} | {t.wall:.3f} | {r['cpu_s']:.3f} |")
        speed_cpu, speed_wall = ts.cpu / tb.cpu, ts.wall / tb.wall
        print(
            f"inference speed-up {speed_cpu:.1f}x CPU time, {speed_wall:.1f}x wall; whole recursive bisection "
            f"{single['cpu_s'] / batched['cpu_s']:.1f}x; identical labels: {same}"
        )
        out["batching"] = {
            "batched_cpu_s": tb.cpu,
            "per_graph_cpu_s": ts.cpu,
            "batched_wall_s": tb.wall,
            "per_graph_wall_s": ts.wall,
            "speedup_cpu": speed_cpu,
            "speedup_wall": speed_wall,
            "calls": [tb.calls, ts.calls],
            "identical": same,
        }
    if not args.quick and "cube" not in skip:
        t = time.perf_counter()
        cube = generate("cube", seed=0, size=args.cube_size).to_mesh()
        data3 = cell_data(cube)
        print(f"\ncube: {cube.n_cells} tetrahedra (generated + graph in {time.perf_counter() - t:.1f} s)")
        methods["sage-base"].bisect_batch(make_warmup(data3))
        rows = {name: run(data3, p, 8) for name, p in methods.items()}
        table(f"Unit cube ({cube.n_cells} tetrahedra), nref 8", rows)
        out["cube"] = {
            k: {kk: vv for kk, vv in v.items() if kk not in ("labels", "split")} for k, v in rows.items()
        }
    if "hetero" not in skip:
        sq = generate("inclusions", seed=0, n=16, regular=True, size=0.01).to_mesh()
        datah = cell_data(sq)
        hm = dict(methods)
        hm["sage-hetero"] = get_partitioner("sage-hetero", **opts)
        print(
            f"\n## Unit square with 16 inclusions ({sq.n_cells} triangles), nref 6: heterogeneity preservation"
        )
        print("| method | elements | HP mean | HP min | normalized cut | CPU s |\n|---|---|---|---|---|---|")
        out["hetero"] = {}
        for name, p in hm.items():
            if name.startswith("sage"):
                p.bisect_batch(make_warmup(datah))  # weights loaded outside the timing
            r = run(datah, p, 6)
            hp = heterogeneity_preservation(r["split"], sq.tags)
            print(
                f"| {name} | {r['elements_after_split']} | {hp.mean():.4f} | {hp.min():.3f} | {r['ncut']:.4f} | "
                f"{r['cpu_s']:.2f} |"
            )
            out["hetero"][name] = {
                "hp_mean": float(hp.mean()),
                "hp_min": float(hp.min()),
                "ncut": r["ncut"],
                "elements": r["elements_after_split"],
                "cpu_s": r["cpu_s"],
            }
    if "hetero3d" not in skip:
        cube_h = generate("cube-hetero", seed=1, parts=4, size=0.06).to_mesh()
        datah3 = cell_data(cube_h)
        hm = dict(methods)
        hm["sage-hetero"] = get_partitioner("sage-hetero", **opts)
        print(
            f"\n## Unit cube in 4 heterogeneous parts ({cube_h.n_cells} tetrahedra), nref 5: heterogeneity "
            "preservation"
        )
        print("| method | elements | HP mean | HP min | normalized cut | CPU s |\n|---|---|---|---|---|---|")
        out["hetero3d"] = {}
        for name, p in hm.items():
            if name.startswith("sage"):
                p.bisect_batch(make_warmup(datah3))
            r = run(datah3, p, 5)
            hp = heterogeneity_preservation(r["split"], cube_h.tags)
            print(
                f"| {name} | {r['elements_after_split']} | {hp.mean():.4f} | {hp.min():.3f} | {r['ncut']:.4f} | "
                f"{r['cpu_s']:.2f} |"
            )
            out["hetero3d"][name] = {
                "hp_mean": float(hp.mean()),
                "hp_min": float(hp.min()),
                "ncut": r["ncut"],
                "elements": r["elements_after_split"],
                "cpu_s": r["cpu_s"],
            }
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


def make_warmup(data: CellData) -> GraphBatch:
    """A one-graph batch of the whole mesh (first call loads the weights, outside the timings)."""
    from models.partition.agglomerate import make_batch

    return make_batch(data, np.zeros(data.graph.n, dtype=np.int64))


if __name__ == "__main__":
    raise SystemExit(main())

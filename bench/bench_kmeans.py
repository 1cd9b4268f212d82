"""k-means partitioner at scale: our partition stage (k-way k-means, then connected parts) against
scikit-learn's KMeans on the same centroids with the same seed, in the same run. Prints a table:
seconds and inertia (sum of squared distances of the centroids to their cluster's mean) of both, and
the recursive-bisection mode for scale. Nothing is asserted.

  python bench/bench_kmeans.py                 # 2,097,152-triangle square, k=128
  python bench/bench_kmeans.py --n 256 --k 64  # a quick one (131,072 triangles)
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def square_mesh(n: int):
    """The unit square cut into n x n squares, each into two triangles (2 n^2 triangles)."""
    from models.mesh.read import mesh_from_arrays

    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    p = np.column_stack([x.ravel(), y.ravel()])
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    v = lambda a, b: a * (n + 1) + b  # noqa: E731
    q = np.column_stack([v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)])
    return mesh_from_arrays(p, [("triangle", np.vstack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))])


def inertia(x: np.ndarray, labels: np.ndarray) -> float:
    """Sum over clusters of the squared distances of the points to the cluster mean."""
    k = int(labels.max()) + 1
    counts = np.bincount(labels, minlength=k).astype(np.float64)
    total = 0.0
    for d in range(x.shape[1]):
        s = np.bincount(labels, weights=x[:, d], minlength=k)
        total += float(np.sum(x[:, d] ** 2) - np.sum(s[counts > 0] ** 2 / counts[counts > 0]))
    return total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1024, help="squares per side (2 n^2 triangles)")
    ap.add_argument("--k", type=int, default=128)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-sklearn", action="store_true", help="skip the scikit-learn baseline")
    args = ap.parse_args()

    from models.partition.agglomerate import agglomerate
    from models.partition.kmeans import KMeansPartitioner
    from models.pipeline import prepare

    mesh = square_mesh(args.n)
    graph, data = prepare(mesh)
    x = data.centroids
    print(f"# k-means: {mesh.n_cells:,} triangles, k={args.k}, seed {args.seed}")
    print("| run | seconds | inertia | inertia / scikit-learn's |")
    print("|---|---|---|---|")
    ref = None
    if not args.no_sklearn:
        from sklearn.cluster import KMeans

        t = time.perf_counter()
        km = KMeans(n_clusters=args.k, n_init=1, random_state=args.seed, algorithm="lloyd").fit(x)
        t_ref = time.perf_counter() - t
        ref = inertia(x, km.labels_.astype(np.int64))
        print(f"| scikit-learn KMeans fit (k-means++, Lloyd) | {t_ref:.2f} | {ref:.6g} | 1 |")

    t = time.perf_counter()
    raw = KMeansPartitioner(seed=args.seed).kway_labels(x, args.k)
    t_fit = time.perf_counter() - t
    ours = inertia(x, raw)
    rel = f"{ours / ref:.4f}" if ref else "-"
    print(f"| ours: k-means fit | {t_fit:.2f} | {ours:.6g} | {rel} |")

    for mode, kw in (("kway", {"k": args.k}), ("nref", {"nref": int(round(np.log2(args.k)))})):
        t = time.perf_counter()
        agg = agglomerate(mesh, data, model="kmeans", mode=mode, seed=args.seed, **kw)
        dt = time.perf_counter() - t
        print(
            f"| ours: partition stage, {mode} ({agg.labels.max() + 1} parts) | {dt:.2f} | "
            f"{inertia(x, agg.labels):.6g} | - |"
        )


if __name__ == "__main__":
    main()

"""What boundary groups cost: the same mesh agglomerated with its tagged boundary cells and with
them stripped (the baseline), in the same run. Prints a table of seconds and ratios; asserts nothing.

  python bench/bench_boundary.py             # 2D square with 4 tagged sides (~500k triangles), 3D cube (~100k tets)
  python bench/bench_boundary.py --quick     # ~50k triangles only
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)
import structured  # noqa: E402


def grid_square(n: int):
    """n x n squares cut in two triangles, sides tagged 2 (y=0), 3 (x=1), 4 (y=1), 5 (x=0)."""
    from models.mesh.read import mesh_from_arrays

    p, t = structured.square(n)
    v = lambda a, b: a * (n + 1) + b  # noqa: E731
    k = np.arange(n)
    lines = np.vstack(
        [
            np.column_stack([v(k, 0), v(k + 1, 0)]),
            np.column_stack([v(n, k), v(n, k + 1)]),
            np.column_stack([v(k, n), v(k + 1, n)]),
            np.column_stack([v(0, k), v(0, k + 1)]),
        ]
    )
    tags = np.repeat([2, 3, 4, 5], n)
    return (
        mesh_from_arrays(p, [("triangle", t), ("line", lines)], tags=[np.ones(len(t)), tags]),
        mesh_from_arrays(p, [("triangle", t)]),
    )


def grid_cube(n: int):
    """Kuhn tetrahedra of an n^3 grid, the six faces tagged 11..16."""
    from models.mesh.geometry import cell_faces
    from models.mesh.read import mesh_from_arrays

    p, t = structured.cube(n)
    bare = mesh_from_arrays(p, [("tetra", t)])
    f = cell_faces(bare)
    key = np.sort(f.nodes.reshape(-1, 3), axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    tri = f.nodes.reshape(-1, 3)[cnt[inv.reshape(-1)] == 1]
    c = p[tri].mean(axis=1)
    axis = np.argmax(np.minimum(c, 1 - c) < 1e-9, axis=1)
    side = (c[np.arange(len(c)), axis] > 0.5).astype(int)
    tags = 11 + 2 * axis + side
    return mesh_from_arrays(p, [("tetra", t), ("triangle", tri)], tags=[np.ones(len(t)), tags]), bare


def timed(fn, repeat: int = 2) -> float:
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    from models import pipeline
    from models.mesh.read import describe

    cases = [("square", grid_square(160 if args.quick else 500), 64)]
    if not args.quick:
        cases.append(("cube", grid_cube(26), 64))
    print(f"{'mesh':8s} {'cells':>8s} {'step':22s} {'groups s':>9s} {'none s':>9s} {'ratio':>6s}")
    for name, (tagged, bare), k in cases:
        rows = [
            ("describe", lambda m: describe(m)),
            (
                "run (metis kway)",
                lambda m, k=k: pipeline.run(m, model="metis", mode="kway", k=k, compute_metrics=False),
            ),
        ]
        for step, fn in rows:
            a = timed(lambda fn=fn, m=tagged: fn(m))
            b = timed(lambda fn=fn, m=bare: fn(m))
            print(f"{name:8s} {tagged.n_cells:8d} {step:22s} {a:9.3f} {b:9.3f} {a / b:6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

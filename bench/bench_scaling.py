"""How every stage scales with the mesh: structured 2D squares (triangles) and 3D cubes (six
tetrahedra per cube) of growing size, each run in its own process through read, graph, partition
(METIS k-way and k-means k-way), merge, metrics and write, with about 1000 cells per element.

Prints tables per dimension (CPU and wall seconds per stage, peak memory per size) and the
log-log slope of each stage's time against the cell count (1 = linear), and draws
docs/scaling.png (CPU seconds by default: on a shared, loaded machine wall times swing with the
load of the moment; --clock wall for wall seconds).

  python bench/bench_scaling.py            # 2D 10k..525k triangles, 3D 10k..160k tetrahedra (a few minutes)
  python bench/bench_scaling.py --full     # 2D up to 2.1M triangles, 3D up to 1M tetrahedra
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path[:0] = [ROOT, HERE]

STAGES = ("read", "graph", "partition metis", "partition kmeans", "merge", "metrics", "write")
CELLS_PER_ELEMENT = 1000
SIZES = {  # squares / cubes per side
    2: [71, 141, 283, 512],  # 10k, 40k, 160k, 524k triangles
    3: [12, 19, 30],  # 10k, 41k, 162k tetrahedra
}
FULL = {2: [71, 141, 283, 512, 1024], 3: [12, 19, 30, 41, 55]}  # ... 2.1M triangles; ... 998k tetrahedra


def one(dim: int, n: int) -> dict:
    """Every stage once on one mesh (run in a fresh process: peak memory is this mesh's)."""
    import structured

    from models.mesh.read import read_mesh
    from models.partition.agglomerate import agglomerate
    from models.pipeline import Result, prepare, split_holes, write_outputs
    from models.quality.report import metrics_report

    t, cpu = {}, {}

    class stage:  # noqa: N801  (with stage("name"): ... records wall and CPU seconds)
        def __init__(self, name):
            self.name = name

        def __enter__(self):
            self.w, self.c = time.perf_counter(), time.process_time()

        def __exit__(self, *exc):
            t[self.name] = time.perf_counter() - self.w
            cpu[self.name] = time.process_time() - self.c

    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "in.vtu")
        p, c = structured.square(n) if dim == 2 else structured.cube(n)
        structured.write(src, p, c)
        del p, c
        with stage("read"):
            mesh = read_mesh(src)
        with stage("graph"):
            graph, data = prepare(mesh)
        k = max(2, mesh.n_cells // CELLS_PER_ELEMENT)
        with stage("partition metis"):
            agg = agglomerate(mesh, data, model="metis", mode="kway", k=k)
        with stage("partition kmeans"):
            agglomerate(mesh, data, model="kmeans", mode="kway", k=k)
        with stage("merge"):
            poly, labels, n_split = split_holes(mesh, graph, data, agg.labels, "split")
        with stage("metrics"):
            report = metrics_report(poly, graph.indptr, graph.indices, mesh.tags)
        res = Result(mesh, graph, data, agg, poly, n_split, metrics=report)
        with stage("write"):
            write_outputs(res, vtu=os.path.join(tmp, "out.vtu"), metrics=os.path.join(tmp, "out.json"))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB
    return {"dim": dim, "n": n, "cells": int(mesh.n_cells), "k": k, "times": t, "cpu": cpu, "peak_mib": peak}


def run_one(dim: int, n: int) -> dict:
    """one() in a child process (its peak resident memory is this mesh's)."""
    out = subprocess.run(
        [sys.executable, __file__, "--one", str(dim), str(n)],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")])},
    )
    if out.returncode != 0:
        raise RuntimeError(f"{dim}D n={n} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def slopes(rows: list[dict], clock: str = "cpu") -> dict[str, float]:
    """Least-squares slope of log(time) against log(cells), per stage; clock "cpu" (process CPU
    seconds: steadier on a shared machine) or "times" (wall seconds)."""
    cells = np.log([r["cells"] for r in rows])
    return {s: float(np.polyfit(cells, np.log([max(r[clock][s], 1e-6) for r in rows]), 1)[0]) for s in STAGES}


def plot(results: dict[int, list[dict]], path: str, clock: str = "cpu") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 5.2))
    for ax, dim in zip(axes[:2], (2, 3), strict=True):
        rows = results[dim]
        if not rows:
            continue
        x = np.array([r["cells"] for r in rows])
        sl = slopes(rows, clock)
        for s in STAGES:
            ax.loglog(x, [r[clock][s] for r in rows], "o-", label=f"{s} (slope {sl[s]:.2f})")
        ax.set_title(
            f"{dim}D: "
            + ("triangles" if dim == 2 else "tetrahedra")
            + f", ~{CELLS_PER_ELEMENT} cells per element"
        )
        ax.set_xlabel("cells")
        ax.set_ylabel("CPU seconds" if clock == "cpu" else "wall seconds")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    ax = axes[2]
    for dim in (2, 3):
        rows = results[dim]
        if rows:
            ax.loglog([r["cells"] for r in rows], [r["peak_mib"] for r in rows], "o-", label=f"{dim}D")
    ax.set_title("peak memory of the whole run")
    ax.set_xlabel("cells")
    ax.set_ylabel("MiB")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="up to 2.1M triangles and 1M tetrahedra")
    ap.add_argument("--dims", default="2,3")
    ap.add_argument("--png", default=os.path.join(ROOT, "docs", "scaling.png"))
    ap.add_argument("--json", help="also write every row here")
    ap.add_argument(
        "--clock",
        default="cpu",
        choices=["cpu", "wall"],
        help="what the slopes and the picture use: process CPU seconds (default; steadier on a shared machine) or wall",
    )
    ap.add_argument("--one", nargs=2, type=int, metavar=("DIM", "N"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(*args.one)))
        return
    sizes = FULL if args.full else SIZES
    results: dict[int, list[dict]] = {2: [], 3: []}
    for dim in (int(d) for d in args.dims.split(",")):
        for n in sizes[dim]:
            row = run_one(dim, n)
            results[dim].append(row)
            print(
                f"{dim}D {row['cells']:>9,} cells k={row['k']:>5}: "
                + " ".join(f"{s} {row['times'][s]:.2f}/{row['cpu'][s]:.2f}" for s in STAGES)
                + f" (wall/CPU s) | peak {row['peak_mib']:.0f} MiB",
                flush=True,
            )
    clock = "cpu" if args.clock == "cpu" else "times"
    for dim in (2, 3):
        rows = results[dim]
        if len(rows) < 2:
            continue
        for key, what in (("cpu", "CPU seconds"), ("times", "wall seconds")):
            print(f"\n## {dim}D ({'triangles' if dim == 2 else 'tetrahedra'}), {what} per stage")
            print("| cells | k | " + " | ".join(STAGES) + " | peak MiB |")
            print("|---" * (len(STAGES) + 3) + "|")
            for r in rows:
                print(
                    f"| {r['cells']:,} | {r['k']} | "
                    + " | ".join(f"{r[key][s]:.2f}" for s in STAGES)
                    + f" | {r['peak_mib']:.0f} |"
                )
            sl = slopes(rows, key)
            print("| log-log slope | | " + " | ".join(f"{sl[s]:.2f}" for s in STAGES) + " | |")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(results, fh, indent=1)
    os.makedirs(os.path.dirname(args.png), exist_ok=True)
    plot(results, args.png, clock)
    print(f"\nwrote {args.png}")


if __name__ == "__main__":
    main()

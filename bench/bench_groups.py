"""Refiners on meshes with physical groups: sage-hetero multilevel + fm / rl-refiner with the
groups kept (keep_groups on, the default for sage-hetero: models.partition.groups) against the group-blind
refiners (keep_groups off) and against no refiner, all in the same run.

Per row: mean heterogeneity preservation over the elements (models.metrics, the fraction of an
element's cells in its majority group; 1 = every element in one material), elements that mix two
materials, the normalized cut of the final partition (dual graph, unit edges), the number of
elements and the partition time. Meshes: tests/data/square_inclusion.msh, cube_inclusion.msh
(a matrix and an inclusion) and two generated ones (`inclusions` 2D, `cube-hetero` 3D, seed 0).

  python bench/bench_groups.py            # all four meshes, nref 4 and 6
  python bench/bench_groups.py --quick    # the two test meshes, nref 4
"""

from __future__ import annotations

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)
DATA = os.path.join(ROOT, "tests", "data")


def meshes(quick: bool):
    from models.mesh.read import read_mesh

    yield "square_inclusion", read_mesh(os.path.join(DATA, "square_inclusion.msh")), 4
    yield "cube_inclusion", read_mesh(os.path.join(DATA, "cube_inclusion.msh")), 4
    if quick:
        return
    from models.learn.generate import generate

    yield "inclusions h=0.02", generate("inclusions", seed=0, size=0.02).to_mesh(), 6
    yield "cube-hetero h=0.08", generate("cube-hetero", seed=0, size=0.08, parts=2).to_mesh(), 6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--modes", default="multilevel,nref")
    args = ap.parse_args()

    import numpy as np

    from models.partition.agglomerate import agglomerate
    from models.pipeline import prepare
    from models.quality.partition_stats import partition_statistics
    from models.quality.shape import heterogeneity_preservation

    print(
        f"{'mesh':20s} {'mode':10s} {'refiner':10s} {'groups':6s} {'hetero':>7s} {'mixed':>5s} "
        f"{'ncut':>7s} {'elems':>5s} {'time':>6s}"
    )
    for name, mesh, nref in meshes(args.quick):
        g, d = prepare(mesh)
        for mode in args.modes.split(","):
            for ref, keep in (
                (None, None),
                ("fm", False),
                ("fm", True),
                ("rl-refiner", False),
                ("rl-refiner", True),
            ):
                t = time.perf_counter()
                a = agglomerate(
                    mesh, d, model="sage-hetero", mode=mode, nref=nref, refiner=ref, keep_groups=keep
                )
                t = time.perf_counter() - t
                h = heterogeneity_preservation(a.labels, mesh.tags)
                nc = partition_statistics(g.indptr, g.indices, a.labels)["normalized_cut"]
                tag = "-" if ref is None else ("kept" if keep else "blind")
                print(
                    f"{name:20s} {mode:10s} {ref or 'none':10s} {tag:6s} {np.nanmean(h):7.4f} "
                    f"{int((h < 1).sum()):5d} {nc:7.3f} {a.n_elements:5d} {t:6.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()

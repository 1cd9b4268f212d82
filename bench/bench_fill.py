"""Filling a closed surface: models.mesh.fill.fill_surface against plain gmsh, in the same run.

The shell: a CAD-like part about 130 units across (a plate with two bores, a dome and a ring fused
by gmsh's OCC kernel), surface-meshed and written as a binary STL (~9,000 triangles at --h 4).

The baseline: what a gmsh user types, gmsh.merge(path), geo.addSurfaceLoop(all surfaces), addVolume,
synchronize, mesh.generate(3), then the tetrahedra out as numpy arrays. Ours does more, all kept:
reading with meshio, merging points, the closed/manifold check, the volume and the cell estimate,
the surface handed to gmsh as arrays, and the filled volume computed. Alternating runs; the median
and the best of --repeat (best-of-N is the steadier figure on a loaded machine).

  python bench/bench_fill.py              # ~9k triangles
  python bench/bench_fill.py --h 2.5      # ~19k triangles
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def make_shell(path: str, h: float) -> int:
    import gmsh
    import meshio

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.3 * h)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 12)
        occ = gmsh.model.occ
        plate = occ.addBox(-65, -40, -20, 130, 80, 40)
        bores = [
            (3, occ.addCylinder(-30, 0, -30, 0, 0, 60, 15)),
            (3, occ.addCylinder(30, 0, -30, 0, 0, 60, 12)),
        ]
        cut, _ = occ.cut([(3, plate)], bores)
        occ.fuse(cut, [(3, occ.addSphere(0, 0, 20, 25)), (3, occ.addTorus(0, 0, -20, 40, 6))])
        occ.synchronize()
        gmsh.model.mesh.generate(2)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
        index[tags.astype(np.int64)] = np.arange(len(tags))
        _, nodes = gmsh.model.mesh.getElementsByType(2)
        tris = index[nodes.astype(np.int64)].reshape(-1, 3)
        points = coords.reshape(-1, 3)
    finally:
        gmsh.finalize()
    meshio.write(path, meshio.Mesh(points, [("triangle", tris)]), binary=True)
    return len(tris)


def plain_gmsh(path: str) -> tuple[float, float, int]:
    import gmsh

    c = time.process_time()
    t = time.perf_counter()
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.merge(path)
        loop = gmsh.model.geo.addSurfaceLoop([e for _, e in gmsh.model.getEntities(2)])
        gmsh.model.geo.addVolume([loop])
        gmsh.model.geo.synchronize()
        gmsh.model.mesh.generate(3)
        _, nodes = gmsh.model.mesh.getElementsByType(4)
        gmsh.model.mesh.getNodes()
        n = len(nodes) // 4
    finally:
        gmsh.finalize()
    return time.perf_counter() - t, time.process_time() - c, n


def ours(path: str) -> tuple[float, float, int, dict]:
    from models.mesh.fill import fill_surface

    c = time.process_time()
    t = time.perf_counter()
    f = fill_surface(path, max_cells=None)
    return time.perf_counter() - t, time.process_time() - c, len(f.tets), f.info


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--h", type=float, default=4.0, help="surface mesh size of the shell (default 4)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "shell.stl")
        n_tri = make_shell(path, args.h)
        base, mine, base_cpu, mine_cpu = [], [], [], []
        ours(path)  # warm-up: imports (meshio, scipy) are paid once per process, not per fill
        for _ in range(args.repeat):
            tb, cb, nb = plain_gmsh(path)
            to, co, no, info = ours(path)
            base.append(tb)
            mine.append(to)
            base_cpu.append(cb)
            mine_cpu.append(co)
        ratio_med = statistics.median(mine) / statistics.median(base)
        ratio_best = min(mine) / min(base)
        ratio_cpu = min(mine_cpu) / min(base_cpu)
        rel = abs(info["volume"] - info["enclosed_volume"]) / info["enclosed_volume"]
        out = {
            "triangles": n_tri,
            "tets_plain_gmsh": nb,
            "tets_ours": no,
            "estimated": info["estimated_cells"],
            "plain_gmsh_s": {"median": statistics.median(base), "best": min(base)},
            "ours_s": {"median": statistics.median(mine), "best": min(mine)},
            "plain_gmsh_cpu_s": min(base_cpu),
            "ours_cpu_s": min(mine_cpu),
            "ours_stages_s": info["timings"],
            "ratio": {"median": ratio_med, "best": ratio_best, "cpu_best": ratio_cpu},
            "volume_rel_error": rel,
        }
        print(json.dumps(out, indent=1))
        print(
            f"{n_tri:,} triangles -> {no:,} tetrahedra (plain gmsh {nb:,}; estimated {info['estimated_cells']:,}): "
            f"ours {min(mine):.2f} s vs plain gmsh {min(base):.2f} s (best of {args.repeat}): "
            f"{ratio_best:.2f}x (median {ratio_med:.2f}x, CPU {ratio_cpu:.2f}x); volume error {rel:.1e}"
        )


if __name__ == "__main__":
    main()

"""Start-up of `magnet agglomerate --model metis --k 128` as a whole process, against a floor: a
fresh Python that imports numpy, scipy, meshio and pymetis, reads the mesh, builds the dual graph
and calls pymetis (issue 25, section 5). Goal: at most 1.2x the floor.

Meshes: the 14k-cell brain (tests/data) and a square of about 131k triangles generated with gmsh
here. The two commands run in turn (A B A B ...), each whole process timed from outside; the
ratio is taken pair by pair and its median printed, with min and max.

    python bench/bench_startup.py [--runs 7]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BRAIN = os.path.join(ROOT, "tests", "data", "BrainCoronalNoHoles.vtu")

FLOOR = r"""
import sys
import meshio, numpy as np, scipy.sparse as sp, pymetis
m = meshio.read(sys.argv[1])
tri = np.vstack([c.data for c in m.cells if c.type == "triangle"])
n = len(tri)
e = np.sort(np.vstack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
key = e[:, 0] * (len(m.points) + 1) + e[:, 1]
cell = np.tile(np.arange(n), 3)
order = np.argsort(key, kind="stable")
k, c = key[order], cell[order]
same = np.flatnonzero(k[1:] == k[:-1])
a, b = c[same], c[same + 1]
g = sp.csr_matrix((np.ones(2 * a.size), (np.r_[a, b], np.r_[b, a])), shape=(n, n))
_, parts = pymetis.part_graph(128, xadj=g.indptr, adjncy=g.indices)
print(len(set(parts)))
"""


def square_mesh(path: str, h: float = 0.0042) -> str:
    import gmsh

    gmsh.initialize(["", "-v", "0"])
    try:
        gmsh.model.add("square")
        gmsh.model.occ.addRectangle(0, 0, 0, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.model.mesh.generate(2)
        gmsh.write(path)
    finally:
        gmsh.finalize()
    import meshio

    m = meshio.read(path)  # the triangles alone, as the service would get them
    tri = [c for c in m.cells if c.type == "triangle"]
    out = path.replace(".msh", ".vtu")
    meshio.write(out, meshio.Mesh(m.points[:, :2], tri))
    return out


def whole_process(cmd: list[str], env: dict) -> float:
    t = time.perf_counter()
    r = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    dt = time.perf_counter() - t
    if r.returncode != 0:
        raise SystemExit(f"{cmd[:4]} failed: {r.stderr.strip()[-400:]}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=ROOT, OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    # Both sides import compiled bytecode, as an installed package does (pip writes it at install):
    # with PYTHONDONTWRITEBYTECODE set (Dockerfile, some shells) models/ would be compiled from
    # source in every run (~0.1 s) while numpy, scipy and meshio come compiled from site-packages.
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    subprocess.run([sys.executable, "-m", "compileall", "-q", os.path.join(ROOT, "models")], check=True)
    with tempfile.TemporaryDirectory() as tmp:
        meshes = {"brain 14k": BRAIN, "square 131k": square_mesh(os.path.join(tmp, "square.msh"))}
        floor = os.path.join(tmp, "floor.py")
        open(floor, "w").write(FLOOR)
        for name, mesh in meshes.items():
            ours = [sys.executable, "-m", "models.cli", "agglomerate", mesh, "-o", os.path.join(tmp, "o.vtu")]
            ours += ["--model", "metis", "--k", "128"]
            base = [sys.executable, floor, mesh]
            whole_process(ours, env), whole_process(base, env)  # warm-up (file cache)
            a, b = [], []
            for _ in range(args.runs):
                a.append(whole_process(ours, env))
                b.append(whole_process(base, env))
            ratios = [x / y for x, y in zip(a, b, strict=True)]
            print(
                f"{name}: magnet {statistics.median(a):.3f}s, floor {statistics.median(b):.3f}s, "
                f"ratio median {statistics.median(ratios):.2f} (min {min(ratios):.2f}, max {max(ratios):.2f})"
            )


if __name__ == "__main__":
    main()

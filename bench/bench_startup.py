"""Start-up of `magnet agglomerate --model metis --k 128` as a whole process, against a floor: a
fresh Python that imports numpy, scipy, meshio and pymetis, reads the mesh, builds the dual graph
and calls pymetis (issue 25, section 5). Goal: at most 1.2x the floor.

Meshes: the 14k-cell brain (tests/data) and a square of about 131k triangles generated with gmsh
here. The two commands run in turn (A B A B ...), each whole process timed from outside; the
ratio is taken pair by pair and its median printed, with min and max.

    python bench/bench_startup.py [--runs 7] [--baseline OTHER_CHECKOUT]

--baseline times the same command from another checkout of the repository too (its compiled
modules built), in the same interleaved run: the before / after table of docs/benchmarks.md.
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


def whole_process(cmd: list[str], env: dict, cwd: str) -> float:
    """Wall time of one whole process. cwd: away from any checkout (`python -m` looks there first)."""
    t = time.perf_counter()
    r = subprocess.run(cmd, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    dt = time.perf_counter() - t
    if r.returncode != 0:
        raise SystemExit(f"{cmd[:4]} failed: {r.stderr.strip()[-400:]}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--baseline", help="another checkout of the repository, timed alongside")
    args = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=ROOT, OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    # Both sides import compiled bytecode, as an installed package does (pip writes it at install):
    # with PYTHONDONTWRITEBYTECODE set (Dockerfile, some shells) models/ would be compiled from
    # source in every run (~0.1 s) while numpy, scipy and meshio come compiled from site-packages.
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    roots = [ROOT] + ([os.path.abspath(args.baseline)] if args.baseline else [])
    for root in roots:
        subprocess.run([sys.executable, "-m", "compileall", "-q", os.path.join(root, "models")], check=True)
    with tempfile.TemporaryDirectory() as tmp:
        meshes = {"brain 14k": BRAIN, "square 131k": square_mesh(os.path.join(tmp, "square.msh"))}
        floor = os.path.join(tmp, "floor.py")
        open(floor, "w").write(FLOOR)
        for name, mesh in meshes.items():
            out = os.path.join(tmp, "o.vtu")
            ours = [sys.executable, "-m", "models.cli", "agglomerate", mesh, "-o", out, "--model", "metis"]
            cmds = {"floor": ([sys.executable, floor, mesh], env)}
            for label, root in zip(("magnet", "baseline"), roots, strict=False):
                cmds[label] = (ours + ["--k", "128"], dict(env, PYTHONPATH=root))
            for cmd, e in cmds.values():
                whole_process(cmd, e, tmp)  # warm-up (file cache)
            times: dict[str, list[float]] = {label: [] for label in cmds}
            for _ in range(args.runs):
                for label, (cmd, e) in cmds.items():
                    times[label].append(whole_process(cmd, e, tmp))
            line = [f"{name}: floor {statistics.median(times['floor']):.3f}s"]
            for label in list(cmds)[1:]:
                line.append(
                    f"{label} {statistics.median(times[label]):.3f}s x{_ratio(times[label], times['floor'])}"
                )
            if "baseline" in times:
                line.append(f"magnet / baseline x{_ratio(times['magnet'], times['baseline'])}")
            print("; ".join(line), flush=True)


def _ratio(a: list[float], b: list[float]) -> str:
    """The median of the pairwise ratios a[i] / b[i] (runs of the same round), with min and max."""
    r = [x / y for x, y in zip(a, b, strict=True)]
    return f"{statistics.median(r):.2f} (min {min(r):.2f}, max {max(r):.2f})"


if __name__ == "__main__":
    main()

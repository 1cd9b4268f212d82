"""Library speed: ours against the floor (meshio read + a raw pymetis call on the same graph),
measured in the same run on the same machine. Prints a table; nothing is asserted.

  python bench/bench_library.py            # brain, 2M-triangle square, 100k-tet cube
  python bench/bench_library.py --quick    # brain only
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)
BRAIN = os.path.join(ROOT, "tests", "data", "BrainCoronalNoHoles.vtu")


def make_square(path: str, n: int = 1024) -> None:
    import meshio

    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    p = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    v = lambda a, b: a * (n + 1) + b  # noqa: E731
    q = np.column_stack([v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)])
    t = np.vstack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    meshio.write(path, meshio.Mesh(p, [("triangle", t)]), binary=True)


def make_cube(path: str, target: int = 100_000) -> None:
    import gmsh

    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("cube")
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        h = 0.0362 * (100_000 / target) ** (1 / 3)  # measured: about `target` tetrahedra
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.model.mesh.generate(3)
        gmsh.write(path)
    finally:
        gmsh.finalize()


def floor(path: str, k: int, repeat: int = 1) -> dict:
    """meshio read + our graph (given to METIS as it needs) + raw pymetis.part_graph; each timing is
    the median of `repeat` runs."""
    import meshio
    import pymetis

    from models.mesh.read import read_mesh
    from models.pipeline import prepare

    reads, parts = [], []
    g, _ = prepare(read_mesh(path))
    dt = pymetis.zero_copy_dtype()
    adj = pymetis.CSRAdjacency(g.indptr.astype(dt), g.indices.astype(dt))
    for _ in range(repeat):
        t = time.perf_counter()
        meshio.read(path)
        reads.append(time.perf_counter() - t)
        t = time.perf_counter()
        pymetis.part_graph(k, adj)
        parts.append(time.perf_counter() - t)
    t_read, t_metis = float(np.median(reads)), float(np.median(parts))
    return {"meshio_read": t_read, "pymetis": t_metis, "floor": t_read + t_metis}


def ours(path: str, k: int, out: str, repeat: int = 1) -> dict:
    """Everything end to end, `repeat` times in one fresh process (for its peak memory); the run
    with the median total is reported."""
    code = f"""
import json, resource, time, sys
sys.path.insert(0, {ROOT!r})
# import everything first: the floor's timings exclude importing meshio and pymetis too
from models.mesh.read import read_mesh
from models import pipeline, metrics, vtu
from models.partition import metis
import pymetis
runs = []
for _ in range({repeat}):
    t = time.perf_counter(); m = read_mesh({path!r}); tr = time.perf_counter() - t
    res = pipeline.run(m, model="metis", mode="kway", k={k})
    res.timings = {{"read": tr, **res.timings}}
    pipeline.write_outputs(res, vtu={out!r} + ".vtu", metrics={out!r} + ".json", labels={out!r} + ".labels.json")
    runs.append({{"total": time.perf_counter() - t, "stages": res.timings, "elements": res.poly.n_elements}})
    del res
runs.sort(key=lambda r: r["total"])
best = runs[len(runs) // 2]
best.update(cells=m.n_cells, totals=[r["total"] for r in runs],
            peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
print(json.dumps(best))
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def row(name, k, path, tmp, repeat=1):
    f = floor(path, k, repeat)
    o = ours(path, k, os.path.join(tmp, name), repeat)
    st = " ".join(f"{a}={b:.3f}" for a, b in o["stages"].items())
    spread = (
        f" (runs {min(o['totals']) / f['floor']:.2f}-{max(o['totals']) / f['floor']:.2f}x)"
        if len(o["totals"]) > 1
        else ""
    )
    print(
        f"{name:<28} {o['cells']:>9} {k:>5} {o['elements']:>6} | floor {f['floor']:6.2f}s (read {f['meshio_read']:.2f} + metis {f['pymetis']:.2f}) "
        f"| ours {o['total']:6.2f}s ratio {o['total'] / f['floor']:5.2f}x{spread} | peak {o['peak_mb']:.0f} MB | {st}"
    )
    return {"name": name, "floor": f, "ours": o, "ratio": o["total"] / f["floor"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json")
    args = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        # small case: median of 7 runs each (a single 0.1 s run swings by +-40% on a shared machine)
        results.append(row("brain k=128", 128, BRAIN, tmp, repeat=7))
        if not args.quick:
            sq = os.path.join(tmp, "square2M.vtu")
            make_square(sq)
            results.append(row("square 2,097,152 tri k=1024", 1024, sq, tmp))
            cube = os.path.join(tmp, "cube100k.msh")
            make_cube(cube)
            results.append(row("cube ~100k tet k=256", 256, cube, tmp))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()

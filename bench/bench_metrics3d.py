"""The 3D quality metrics stage against a baseline version of models/quality/, same run.

Meshes (issue 11): the structured 1M-tet cube (bench/structured.py, 55^3 cubes x 6 tetrahedra) at
METIS k-way k=1024, and a ~110k-tet gmsh unit cube (mesh size 0.035) at k=256. Each mesh is read,
partitioned and merged once (cached under --cache); then metrics_report of every version runs in
its own process (CPU and wall seconds of the stage, peak resident memory above the loaded input),
alternating versions --repeat times. The radii of both versions are compared against the
certified tolerance (rel_tol x diameter).

  python bench/bench_metrics3d.py --baseline REV          # REV: a git revision of models/quality/
  python bench/bench_metrics3d.py --baseline REV --small  # the gmsh cube only
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import resource
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path[:0] = [ROOT, HERE]


def gmsh_cube(path: str, h: float) -> int:
    import gmsh
    import structured

    gmsh.initialize(["-nt", "1"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        _, nt = gmsh.model.mesh.getElementsByType(4)
    finally:
        gmsh.finalize()
    idx = np.zeros(int(tags.max()) + 1, dtype=np.int64)
    idx[tags.astype(np.int64)] = np.arange(tags.size)
    tets = idx[nt.astype(np.int64)].reshape(-1, 4)
    structured.write(path, coords.reshape(-1, 3), tets)
    return tets.shape[0]


def build(case: str, cache: str) -> str:
    out = os.path.join(cache, f"{case}.pkl")
    if os.path.exists(out):
        return out
    import structured

    from models.mesh.read import read_mesh
    from models.partition.agglomerate import agglomerate
    from models.pipeline import prepare, split_holes

    src = os.path.join(cache, f"{case}.vtu")
    if case == "cube1m":
        p, c = structured.cube(55)
        structured.write(src, p, c)
        k = 1024
    else:
        gmsh_cube(src, 0.035)
        k = 256
    mesh = read_mesh(src)
    graph, data = prepare(mesh)
    agg = agglomerate(mesh, data, model="metis", mode="kway", k=k)
    poly, _, _ = split_holes(mesh, graph, data, agg.labels, "split")
    with open(out, "wb") as f:
        pickle.dump(
            {
                "poly": poly,
                "indptr": graph.indptr,
                "indices": graph.indices,
                "tags": mesh.tags,
                "cells": int(mesh.n_cells),
                "k": k,
            },
            f,
        )
    return out


def one(module_path: str, data_path: str, radii_out: str) -> dict:
    """metrics_report of the module at module_path on the cached mesh (run in a fresh process)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("metrics_under_test", module_path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["metrics_under_test"] = mod
    spec.loader.exec_module(mod)
    from scipy.optimize import linprog  # noqa: F401  (its import is not the stage's time)

    with open(data_path, "rb") as f:
        d = pickle.load(f)
    with open("/proc/self/status") as f:
        rss0 = next(int(x.split()[1]) for x in f if x.startswith("VmRSS")) / 1024.0
    w, c = time.perf_counter(), time.process_time()
    rep = mod.metrics_report(d["poly"], d["indptr"], d["indices"], d["tags"])
    w, c = time.perf_counter() - w, time.process_time() - c
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    del rep
    g = mod._prepare(d["poly"])  # the radii themselves, for the comparison (not timed)
    np.save(radii_out, np.column_stack([mod._inscribed(g, mod.DEFAULT_REL_TOL)[1], g.diameter]))
    return {"cpu": c, "wall": w, "peak_mib": peak - rss0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", required=True, help="git revision of models/quality/ to compare with")
    ap.add_argument("--cache", default="/tmp/bench_metrics3d")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--small", action="store_true", help="the 110k gmsh cube only")
    ap.add_argument("--one", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(*a.one)))
        return
    os.makedirs(a.cache, exist_ok=True)
    base = os.path.join(a.cache, "metrics_baseline.py")
    with open(base, "w") as f:
        f.write(
            subprocess.run(
                ["git", "-C", ROOT, "show", f"{a.baseline}:models/quality/"],
                check=True,
                capture_output=True,
                text=True,
            ).stdout
        )
    versions = {"baseline": base, "current": os.path.join(ROOT, "models", "metrics.py")}
    env = {**os.environ, "PYTHONPATH": ROOT, "OMP_NUM_THREADS": "1"}
    for case in ["gmsh"] if a.small else ["gmsh", "cube1m"]:
        data = build(case, a.cache)
        res = {v: [] for v in versions}
        for _ in range(a.repeat):
            for v, path in versions.items():
                out = subprocess.run(
                    [
                        sys.executable,
                        __file__,
                        "--baseline",
                        a.baseline,
                        "--one",
                        path,
                        data,
                        os.path.join(a.cache, f"radii_{case}_{v}.npy"),
                    ],
                    capture_output=True,
                    text=True,
                    env=env,
                    check=True,
                )
                res[v].append(json.loads(out.stdout.strip().splitlines()[-1]))
        rb = np.load(os.path.join(a.cache, f"radii_{case}_baseline.npy"))
        rc = np.load(os.path.join(a.cache, f"radii_{case}_current.npy"))
        eps = 1e-3 * rb[:, 1]
        dr = (rc[:, 0] - rb[:, 0]) / np.where(eps > 0, eps, 1.0)
        best = {v: min(r["cpu"] for r in rs) for v, rs in res.items()}
        print(
            f"{case}: metrics stage CPU s (best of {a.repeat}) baseline {best['baseline']:.2f} current "
            f"{best['current']:.2f} -> {best['baseline'] / best['current']:.2f}x; wall "
            + " / ".join(f"{v} {min(r['wall'] for r in rs):.2f}" for v, rs in res.items())
            + "; peak MiB above input "
            + " / ".join(f"{v} {max(r['peak_mib'] for r in rs):.0f}" for v, rs in res.items())
            + f"; radius change / eps: min {dr.min():.3f} max {dr.max():.3f}",
            flush=True,
        )


if __name__ == "__main__":
    main()

"""Reading at scale: our read and graph stages against the floor, in the same run.

Reports the median and the best of --repeat alternating runs (best-of-N is the steadier figure on
a loaded machine).

The floor: meshio.read of the same file, plus pairing the tetrahedra's faces with one numpy argsort
(sort every face's nodes, one int64 key per face, argsort, equal neighbours are the shared faces).
Ours does more (orientation by topology, checks, measures, centroids, face areas), all kept.

  python bench/bench_read.py            # 998,250 tetrahedra (55^3 cubes x 6)
  python bench/bench_read.py --n 30     # 162,000 tetrahedra
  python bench/bench_read.py --fresh    # every run in a new process, as a `magnet` run reads
  python bench/bench_read.py --shuffle  # cells and points renumbered at random (keys not nearly sorted)

--fresh: in one process the later runs reuse memory the earlier ones touched; a new process pays
for every page it touches (in this VM ~0.5-3 s/GB), so the peak memory of each side counts too.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)


def floor(path: str) -> tuple[float, float, float]:
    import meshio

    c = time.process_time()
    t = time.perf_counter()
    m = meshio.read(path)
    t_read = time.perf_counter() - t
    t = time.perf_counter()
    tets = m.cells_dict["tetra"].astype(np.int64)
    f = np.sort(tets[:, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]].reshape(-1, 3), axis=1)
    bits = int(len(m.points)).bit_length()
    key = (f[:, 0] << (2 * bits)) | (f[:, 1] << bits) | f[:, 2]
    order = np.argsort(key)
    sk = key[order]
    same = np.flatnonzero(sk[1:] == sk[:-1])
    _pairs = np.stack([order[same] // 4, order[same + 1] // 4])
    return t_read, time.perf_counter() - t, time.process_time() - c


def ours(path: str) -> tuple[float, float, float]:
    from models.mesh.read import read_mesh
    from models.pipeline import prepare

    c = time.process_time()
    t = time.perf_counter()
    mesh = read_mesh(path)
    t_read = time.perf_counter() - t
    t = time.perf_counter()
    prepare(mesh)
    return t_read, time.perf_counter() - t, time.process_time() - c


def sandboxed(path: str) -> tuple[float, float, float]:
    """ours(), the read in a forked child under limits (models.mesh.sandbox, as the CLI, the API and
    the worker read); CPU counts the child's too."""
    import resource

    from models.mesh.sandbox import read_mesh_safe
    from models.pipeline import prepare

    def cpu() -> float:
        ch = resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.process_time() + ch.ru_utime + ch.ru_stime

    c = cpu()
    t = time.perf_counter()
    mesh = read_mesh_safe(path)
    t_read = time.perf_counter() - t
    t = time.perf_counter()
    prepare(mesh)
    return t_read, time.perf_counter() - t, cpu() - c


def in_child(which: str, path: str) -> tuple[float, float, float]:
    """floor() or ours() in a new process (the modules imported before the clock starts)."""
    code = (
        "import json, sys; sys.path[:0] = [sys.argv[1], sys.argv[2]]; import bench_read, meshio, "
        "models.mesh.read, models.mesh.sandbox, models.pipeline, models.mesh.vtu; "
        "print(json.dumps(getattr(bench_read, sys.argv[3])(sys.argv[4])))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, HERE, os.path.dirname(HERE), which, path],
        capture_output=True,
        text=True,
        check=True,
    )
    return tuple(json.loads(out.stdout.strip().splitlines()[-1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=55, help="cubes per side (6 n^3 tetrahedra)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--format", default="vtu", choices=["vtu", "msh"])
    ap.add_argument("--fresh", action="store_true", help="every run in a new process")
    ap.add_argument("--shuffle", action="store_true", help="renumber cells and points at random (seed 1)")
    args = ap.parse_args()
    run_floor, run_ours, run_safe = (
        (
            (lambda p: in_child("floor", p)),
            (lambda p: in_child("ours", p)),
            (lambda p: in_child("sandboxed", p)),
        )
        if args.fresh
        else (floor, ours, sandboxed)
    )
    import structured

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, f"cube.{args.format}")
        p, t = structured.cube(args.n)
        if args.shuffle:  # an unstructured numbering: the face keys come in no particular order
            rng = np.random.default_rng(1)
            perm = rng.permutation(len(p))
            p, t = p[perm], np.argsort(perm)[t[rng.permutation(len(t))]]
        structured.write(path, p, t)
        rf, rg, of, og, cf, co, sf, sg, cs = [], [], [], [], [], [], [], [], []
        for _ in range(args.repeat):  # alternate, so that drifting load hits both alike
            a, b, c = run_floor(path)
            rf.append(a)
            rg.append(b)
            cf.append(c)
            a, b, c = run_ours(path)
            of.append(a)
            og.append(b)
            co.append(c)
            a, b, c = run_safe(path)
            sf.append(a)
            sg.append(b)
            cs.append(c)
    med = statistics.median
    where = "each in a new process" if args.fresh else "in this process"
    what = "renumbered " if args.shuffle else ""
    print(
        f"# read + graph, {len(t):,} {what}tetrahedra ({args.format}), {args.repeat} alternating runs {where}"
    )
    print("| | read s | graph / pairing s | total s (median) | total s (best) |")
    print("|---|---|---|---|---|")
    tf = [a + b for a, b in zip(rf, rg, strict=True)]
    to = [a + b for a, b in zip(of, og, strict=True)]
    print(
        f"| floor: meshio.read + one argsort pairing | {med(rf):.2f} | {med(rg):.2f} | {med(tf):.2f} | {min(tf):.2f} |"
    )
    print(f"| ours: read_mesh + prepare | {med(of):.2f} | {med(og):.2f} | {med(to):.2f} | {min(to):.2f} |")
    ts = [a + b for a, b in zip(sf, sg, strict=True)]
    print(
        f"| ours sandboxed: read_mesh_safe (forked child) + prepare | {med(sf):.2f} | {med(sg):.2f} | "
        f"{med(ts):.2f} | {min(ts):.2f} |"
    )
    print(f"| ratio ours / floor | | | {med(to) / med(tf):.2f} | {min(to) / min(tf):.2f} |")
    print(f"| ratio sandboxed / floor | | | {med(ts) / med(tf):.2f} | {min(ts) / min(tf):.2f} |")
    print(
        f"| ratio sandboxed / ours (the child's cost) | {med(sf) / med(of):.2f} | | {med(ts) / med(to):.2f} | {min(ts) / min(to):.2f} |"
    )
    print(
        f"\nprocess CPU s, best of {args.repeat}: floor {min(cf):.2f}, ours {min(co):.2f}, "
        f"ratio {min(co) / min(cf):.2f} (median ratio {med(co) / med(cf):.2f}); sandboxed (parent + child) "
        f"{min(cs):.2f}, ratio to ours {min(cs) / min(co):.2f}"
    )


if __name__ == "__main__":
    main()

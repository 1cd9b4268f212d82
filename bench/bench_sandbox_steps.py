"""Where a sandboxed read's time goes, step by step (issue 23; round four (b) and round six in
docs/benchmarks.md), for the code under --root (this tree by default: run it once with --root of a
base checkout and once without, alternating, to compare).

Per file (13,824 or --n**3 hexahedra: legacy VTK binary and VTI, written here by VTK's writers):
  dump      the child's answer written into a memfd (a Mesh read in this process), ms
  load      the caller's side of it: the memfd mapped and the Mesh rebuilt, ms
  trip      a child of the zygote returning a value to the caller: from the child's clock reading
            (time.monotonic, system-wide) to the value in the caller's hands: the child's tiny
            answer, its byte(s) and the caller's wake-up, ms
  safe      read_mesh_safe through the zygote, ms;  in-process  read_mesh, ms (the same run)
Best / median of --repeat, --settle s between sandboxed calls (outside the clocks).

  python bench/bench_sandbox_steps.py [--root /path/to/base] [--n 24] [--repeat 15]
"""

from __future__ import annotations

import argparse
import importlib
import os
import statistics
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", default=os.path.dirname(HERE))
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--settle", type=float, default=0.2)
    ap.add_argument("--trips", type=int, default=60, help="samples of the trip")
    a = ap.parse_args()
    sys.path[:0] = [os.path.abspath(a.root), HERE]
    os.chdir(a.root)

    from models.mesh import sandbox, zygote  # from --root (imported before the bench adds its own root)
    from models.mesh.read import read_mesh

    saved = list(sys.path)
    corpus = importlib.import_module("bench_read_formats").corpus  # the same files as the formats bench
    sys.path[:] = [
        *saved,
        os.path.join(HERE, "..", "tests"),
    ]  # (it put this tree first: the zygote must get --root)

    if hasattr(zygote, "_dump"):  # the base: a pickle
        dump = zygote._dump
    else:
        from models.mesh.answer import dump
    assert zygote.wait_ready(120)
    folder = tempfile.mkdtemp(prefix="magnet-steps-")
    want = {label: path for label, path, _ in corpus(folder, a.n) if "binary" in label or "VTI" in label}

    def stats(xs):
        return f"{min(xs) * 1e3:.2f} / {statistics.median(xs) * 1e3:.2f}"

    kw = {"path": "x", "timeout_s": 60, "memory_bytes": 1 << 32}
    trips = []
    for _ in range(a.trips):
        t0 = sandbox.call_in_child(time.monotonic, **kw)
        trips.append(time.monotonic() - t0)
        time.sleep(a.settle)
    print(f"root {a.root}  n {a.n}  ({sandbox.__file__})")
    print(f"trip (child's return -> caller) ms best / median: {stats(trips)}")
    for name, path in want.items():
        mesh = read_mesh(path)
        dumps, loads, safe, local = [], [], [], []
        for _ in range(a.repeat):
            fd = os.memfd_create("steps", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
            t = time.perf_counter()
            dump(("ok", mesh), fd)
            dumps.append(time.perf_counter() - t)
            t = time.perf_counter()
            got = sandbox._load(fd)
            loads.append(time.perf_counter() - t)
            assert got[0] == "ok"
            os.close(fd)
            del got
            t = time.perf_counter()
            read_mesh(path)
            local.append(time.perf_counter() - t)
            t = time.perf_counter()
            sandbox.read_mesh_safe(path)
            safe.append(time.perf_counter() - t)
            time.sleep(a.settle)
        print(f"{name}: {mesh.n_cells:,} cells")
        print(f"  dump ms {stats(dumps)}   load ms {stats(loads)}")
        print(f"  read_mesh_safe ms {stats(safe)}   in-process ms {stats(local)}")
    zygote.shutdown()


if __name__ == "__main__":
    main()

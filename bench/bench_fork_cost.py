"""The cost of the reading child: forked by the reading process itself, or by the reader zygote.

For each kind of reading process (its modules imported as it has them when it reads: the CLI after
an in-process read, the service's FastAPI app, the Celery worker's tasks with torch), in a process
of its own: its resident memory, then best-of-N of models.mesh.sandbox.call_in_child of a no-op
(os.getpid): the fork, the child's limits, its answer through the memfd, its end; by this process
("direct") and by its zygote ("zygote"), alternating in the same run; the ratio direct / zygote.
Then the same for a read of a 10^4-cell binary legacy VTK file (read_mesh_safe).

  python bench/bench_fork_cost.py [--repeat 15]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

ROLES = {
    "CLI (magnet, after an in-process read)": "import models.cli.main, models.mesh.read, models.mesh.vtk_readers, vtk",
    "service (uvicorn + FastAPI app)": (
        "import uvicorn; from jobqueue.settings import Settings; from service.app import create_app; "
        "create_app(Settings(data_dir=tempfile.mkdtemp()))"
    ),
    "worker (Celery tasks + torch)": "import torch, worker.tasks, models.api, models.mesh.read",
}


def _rss(pid: int | None = None) -> float:
    with open(f"/proc/{pid or 'self'}/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def measure(setup: str, repeat: int, path: str) -> dict:
    import tempfile  # noqa: F401  (the setups use it)

    exec(setup)
    from models.mesh import zygote
    from models.mesh.read import read_mesh
    from models.mesh.sandbox import call_in_child, read_mesh_safe

    read_mesh(path)  # everything a read imports, imported here too (as in a process that has read)
    kw = {"path": path, "timeout_s": 60, "memory_bytes": 4 << 30}
    if not zygote.wait_ready():
        raise SystemExit("the zygote did not start")
    out = {"rss_mb": _rss(), "zygote_rss_mb": _rss(zygote.pid())}
    for name, fn in (
        ("noop", lambda z: call_in_child(os.getpid, zygote=z, **kw)),
        ("read", lambda z: read_mesh_safe(path, zygote=z)),
    ):
        d, g = [], []
        for _ in range(repeat):
            t = time.perf_counter()
            fn(False)
            d.append(time.perf_counter() - t)
            t = time.perf_counter()
            fn(True)
            g.append(time.perf_counter() - t)
        out[name] = (min(d), min(g))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--role", help=argparse.SUPPRESS)
    ap.add_argument("--file", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.role:
        sys.path[:0] = [ROOT]
        print(json.dumps(measure(ROLES[args.role], args.repeat, args.file)))
        return
    sys.path[:0] = [ROOT, os.path.join(ROOT, "tests")]
    import vtk_corpus as vc

    with tempfile.TemporaryDirectory() as tmp:
        p, h = vc.grid(24, 24, 24)
        path = vc.write_legacy(os.path.join(tmp, "hex.vtk"), vc.unstructured(p, [(12, h)]), 42, True)
        print(
            f"# the reading child's cost, best of {args.repeat} alternating runs ({len(h):,}-hexahedron read)"
        )
        print(
            "| reading process | its RSS MB | zygote RSS MB | no-op child: direct ms | zygote ms | "
            "direct / zygote | read: direct ms | zygote ms | direct / zygote |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        env = {**os.environ, "PYTHONPATH": ROOT, "MAGNET_READ_ZYGOTE": "1"}
        for role in ROLES:
            r = subprocess.run(
                [sys.executable, __file__, "--role", role, "--file", path, "--repeat", str(args.repeat)],
                capture_output=True,
                text=True,
                env=env,
                cwd=ROOT,
            )
            if r.returncode:
                print(f"| {role} | failed: {r.stderr.strip().splitlines()[-1:]} |")
                continue
            m = json.loads(r.stdout.strip().splitlines()[-1])
            (nd, nz), (rd, rz) = m["noop"], m["read"]
            print(
                f"| {role} | {m['rss_mb']:.0f} | {m['zygote_rss_mb']:.0f} | {nd * 1e3:.1f} | {nz * 1e3:.1f} | "
                f"{nd / nz:.2f} | {rd * 1e3:.1f} | {rz * 1e3:.1f} | {rd / rz:.2f} |"
            )


if __name__ == "__main__":
    main()

"""`magnet check` speed against the floor: meshio.read of the same file, same run, same machine.
Prints a table (best of --repeat runs each); nothing is asserted.

  python bench/bench_check.py            # brain and a 2M-triangle square
  python bench/bench_check.py --quick    # brain only
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import tempfile
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)
sys.path.insert(0, HERE)
BRAIN = os.path.join(ROOT, "tests", "data", "BrainCoronalNoHoles.vtu")


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    import meshio
    from bench_library import make_square

    from models.mesh.check import check_file
    from models.mesh.read import read_mesh

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    cases = [("brain (14k triangles)", BRAIN)]
    tmp = tempfile.mkdtemp(prefix="bench_check_")
    if not args.quick:
        sq = os.path.join(tmp, "square2m.vtu")
        make_square(sq, n=1000)  # 2,000,000 triangles
        cases.append(("square (2M triangles)", sq))

    def quiet_meshio(path):
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            meshio.read(path)

    print(
        f"{'mesh':24s} {'meshio.read':>12s} {'read_mesh':>12s} {'check':>12s} {'read/meshio':>12s} {'check/meshio':>13s}"
    )
    for name, path in cases:
        t_meshio = best(lambda p=path: quiet_meshio(p), args.repeat)
        t_read = best(lambda p=path: read_mesh(p), args.repeat)
        t_check = best(lambda p=path: check_file(p), args.repeat)
        print(
            f"{name:24s} {t_meshio:11.3f}s {t_read:11.3f}s {t_check:11.3f}s {t_read / t_meshio:11.1f}x {t_check / t_meshio:12.1f}x"
        )


if __name__ == "__main__":
    main()

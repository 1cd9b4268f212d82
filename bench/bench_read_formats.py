"""Read stage against VTK's own reader, per format, in the same run (issue 23: at most 2x).

Ours: models.mesh.read.read_mesh (the one reader pick_reader chooses, the conversion and the
validation: point checks, degeneracy, orientation by topology, measures, face pairing).
VTK: the same format's VTK reader, Update(), then vtk_to_numpy of points, offsets, connectivity and
types (the arrays of an unstructured grid; structured datasets: their points only, the cells being
implicit there). Each side runs --repeat times alternating in this process; the table gives the
best of each and their ratio. Files of 10,000 cells or more, written here by VTK's writers.
"sandboxed" is read_mesh_safe (a forked child, the Mesh back through a memfd), the way the
service and the worker read every upload: the child forked by this process, or by its reader zygote.
The zygote column counts the request's way to the zygote and on to its spare child (forked ahead
of the request, as in the service), the child's read and validation, and the Mesh's way back; the
spare's own fork and warm-up run between reads, outside the clocks, and after each sandboxed read
the bench waits --settle seconds (outside the clocks) so that they, and the exiting child, do not
overlap the next timed read of any column (a service meets reads seconds apart, not back to back).
VTK, in-process and zygote alternate; the direct-fork column runs after them, per file: forking
this process write-protects every page of it, and each page written afterwards faults once, which
slowed whichever column came next by up to 2x (VTK's or ours) and is not what a service meets (its
reading children are the zygote's, never its own forks).

--cold: each sample is the first read of the file in a fresh process (after the imports and a read of
a tiny file of the same kind, so that neither side counts its first-call set-up), VTK's and ours
alternating: what one `magnet` command or one job pays, memory fresh from the system (on the virtual
machines we run on a fresh page costs ~2 us, so an 11 MB file copied costs ~6 ms whoever copies it).
--all adds the uncompressed (raw) layouts, planar, mixed and polyhedral files of the 2026-12 sweep.

  python bench/bench_read_formats.py            # ~13,824-98,304 cells per file
  python bench/bench_read_formats.py --n 30     # larger
  python bench/bench_read_formats.py --in-process   # VTK and ours in-process only
  python bench/bench_read_formats.py --n 48 --all --in-process   # every kind, 10^5 cells, warm
  python bench/bench_read_formats.py --n 48 --all --cold         # the same, fresh processes
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.dirname(HERE), os.path.join(os.path.dirname(HERE), "tests")]


def vtk_side(path: str) -> float:
    import vtk
    from vtkmodules.util.numpy_support import vtk_to_numpy

    t = time.perf_counter()
    ext = os.path.splitext(path)[1]
    r = {
        ".vtk": vtk.vtkDataSetReader,
        ".vtu": vtk.vtkXMLUnstructuredGridReader,
        ".vts": vtk.vtkXMLStructuredGridReader,
        ".vti": vtk.vtkXMLImageDataReader,
        ".vtr": vtk.vtkXMLRectilinearGridReader,
        ".exo": vtk.vtkExodusIIReader,
    }[ext]()
    r.SetFileName(path)
    r.Update()
    ds = r.GetOutputDataObject(0)
    if ds.IsA("vtkCompositeDataSet"):
        it = ds.NewIterator()
        it.InitTraversal()
        ds = it.GetCurrentDataObject()
    if ds.IsA("vtkUnstructuredGrid"):
        c = ds.GetCells()
        _ = (
            vtk_to_numpy(ds.GetPoints().GetData()),
            vtk_to_numpy(c.GetOffsetsArray()),
            vtk_to_numpy(c.GetConnectivityArray()),
            vtk_to_numpy(ds.GetCellTypes()),
        )
    elif ds.GetPoints() is not None:
        _ = vtk_to_numpy(ds.GetPoints().GetData())
    return time.perf_counter() - t


def ours(path: str) -> float:
    """In-process: read_mesh as it is (MAGNET_READ_SANDBOX=0 and the CLI's pure-Python readers)."""
    from models.mesh.read import read_mesh

    t = time.perf_counter()
    read_mesh(path)
    return time.perf_counter() - t


def sandboxed(path: str, zygote: bool = True) -> float:
    """In a forked child (read_mesh_safe: the service, the worker, the CLI on native readers), the
    fork, the child's read and the Mesh's way back through the memfd all counted; the child forked
    by the reader zygote (zygote=True), or by this process."""
    from models.mesh.sandbox import read_mesh_safe

    t = time.perf_counter()
    read_mesh_safe(path, zygote=zygote)
    return time.perf_counter() - t


def _exodus(path: str, points, hexes) -> str | None:
    """Exodus II written by meshio (it needs netCDF4; vtkExodusIIWriter crashes in the vtk 9.7
    wheel), or None where netCDF4 is missing."""
    try:
        import meshio
        import netCDF4  # noqa: F401
    except ImportError:
        print("# Exodus II left out: meshio's Exodus writer needs netCDF4 (pip install netCDF4)")
        return None
    meshio.write(path, meshio.Mesh(points, [("hexahedron", hexes)]), file_format="exodus")
    return path


def corpus(tmp: str, n: int, every: bool = False) -> list[tuple[str, str, int]]:
    os.makedirs(tmp, exist_ok=True)
    import vtk
    import vtk_corpus as vc

    out = []
    p, h = vc.grid(n, n, n)
    hexes = vc.unstructured(p, [(12, h)])
    out.append(
        (
            "hexahedra, legacy 4.2 binary",
            vc.write_legacy(os.path.join(tmp, "hex.vtk"), hexes, 42, True),
            len(h),
        )
    )
    kuhn = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]
    m = max(n * 2 // 3, 12)
    p2, h2 = vc.grid(m, m, m)
    tets = np.concatenate([h2[:, k] for k in kuhn])
    out.append(
        (
            "tetrahedra, VTU appended",
            vc.write_xml(os.path.join(tmp, "tet.vtu"), vc.unstructured(p2, [(10, tets)])),
            len(tets),
        )
    )
    out.append(  # the same, appended raw (not base64): VTK's read is a copy of the file's bytes
        (
            "tetrahedra, VTU appended raw",
            vc.write_xml(os.path.join(tmp, "tet_raw.vtu"), vc.unstructured(p2, [(10, tets)]), encode=False),
            len(tets),
        )
    )
    out.append(
        (
            "tetrahedra, legacy 5.1 ascii",
            vc.write_legacy(os.path.join(tmp, "tet.vtk"), vc.unstructured(p2, [(10, tets)]), 51),
            len(tets),
        )
    )
    # quadratic tetrahedra: mid-edge nodes per cell (straight-sided)
    pc = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [1, 3], [2, 3]])
    mids = p2[tets[:, pc]].mean(axis=2).reshape(-1, 3)
    q = np.concatenate([tets, len(p2) + np.arange(len(mids)).reshape(-1, 6)], axis=1)
    out.append(
        (
            "quadratic tetrahedra (24), VTU",
            vc.write_xml(os.path.join(tmp, "q.vtu"), vc.unstructured(np.concatenate([p2, mids]), [(24, q)])),
            len(q),
        )
    )
    exo = _exodus(os.path.join(tmp, "hex.exo"), p, h)
    if exo:
        out.append(("hexahedra, Exodus II (meshio + netCDF4)", exo, len(h)))
    out.append(
        (
            "structured grid, VTS",
            vc.write_xml(os.path.join(tmp, "sg.vts"), vc.structured_grid((n + 1,) * 3), "appended"),
            n**3,
        )
    )
    im = vc.image((n + 1,) * 3)
    out.append(("image data, VTI", vc.write_xml(os.path.join(tmp, "im.vti"), im, "appended"), n**3))
    if every:
        out += _uncompressed(tmp, n, p, h, p2, tets)
    del vtk
    return out


def _uncompressed(tmp: str, n: int, p, h, p2, tets) -> list[tuple[str, str, int]]:
    """The kinds where VTK's read is a copy of the file's bytes (uncompressed binary), planar,
    mixed and polyhedral files: the 2026-12 sweep's rows (docs/benchmarks.md)."""
    import vtk_corpus as vc

    w = lambda name, ds, **kw: vc.write_xml(os.path.join(tmp, name), ds, "appended", encode=False, **kw)  # noqa: E731
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(p2))
    inv = np.argsort(perm)
    m = int(round((len(h) / 2) ** 0.5))  # planar meshes of about as many cells
    q, quads = vc.quad_grid(m, m)
    half = len(h) // 2
    kuhn = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]
    t2 = np.concatenate([h[half:, k] for k in kuhn])
    pp, ph = vc.grid(n // 2, n // 2, n // 2)
    return [
        ("hexahedra, VTU appended raw", w("hex_raw.vtu", vc.unstructured(p, [(12, h)])), len(h)),
        (
            "hexahedra, legacy 5.1 binary",
            vc.write_legacy(os.path.join(tmp, "hex51.vtk"), vc.unstructured(p, [(12, h)]), 51, True),
            len(h),
        ),
        (
            "tetrahedra, VTU raw, shuffled numbering",
            w("tet_shuf.vtu", vc.unstructured(p2[perm], [(10, inv[tets])])),
            len(tets),
        ),
        ("quads, VTU raw", w("quad_raw.vtu", vc.unstructured(q, [(9, quads)])), len(quads)),
        (
            "triangles, VTU raw",
            w(
                "tri_raw.vtu",
                vc.unstructured(q, [(5, np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]))]),
            ),
            2 * len(quads),
        ),
        (
            "hexahedra + tetrahedra, VTU raw",
            w("mixed_raw.vtu", vc.unstructured(p, [(12, h[:half]), (10, t2)])),
            half + len(t2),
        ),
        ("polyhedra (hexahedra), VTU raw", w("poly_raw.vtu", vc.polyhedra(pp, ph)), len(ph)),
        ("structured grid, VTS raw", w("sg_raw.vts", vc.structured_grid((n + 1,) * 3)), n**3),
        ("rectilinear grid, VTR raw", w("rg_raw.vtr", vc.rectilinear((n + 1,) * 3)), n**3),
        ("image data, VTI raw", w("im_raw.vti", vc.image((n + 1,) * 3)), n**3),
    ]


def _keep_heap() -> None:
    """The process's heap kept between reads, as every read of ours keeps it (the CLI's and the
    API's in-process reads, the sandbox's parent: models.mesh.heap); VTK's side shares the malloc
    (MAGNET_READ_HEAP=0: both without)."""
    from models.mesh import heap

    heap.keep()


def _cold_one(which: str, path: str, small: str) -> None:
    """(--one) In this fresh process: imports, a read of the tiny `small` file, then the timed first
    read of `path` by `which` (vtk or ours); prints its seconds."""
    import vtk  # noqa: F401

    import models.mesh.read  # noqa: F401
    import models.mesh.vtk_readers  # noqa: F401

    _keep_heap()

    os.environ["MAGNET_READ_SANDBOX"] = "0"
    side = vtk_side if which == "vtk" else ours
    side(small)
    print(side(path))


def _cold(files: list, tmp: str, repeat: int) -> None:
    import subprocess

    small = {name: path for name, path, _ in corpus(os.path.join(tmp, "small"), 3, every=True)}
    print(
        f"# first read in a fresh process (after a tiny file of the same kind), median of {repeat} alternating"
    )
    print("| file | cells | VTK s | ours s | ours / VTK |")
    print("|---|---|---|---|---|")
    for name, path, cells in files:
        got = {"vtk": [], "ours": []}
        for _ in range(repeat):
            for which in ("vtk", "ours"):
                out = subprocess.run(
                    [sys.executable, __file__, "--one", which, path, small[name]],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                got[which].append(float(out.stdout.split()[-1]))
        a, b = float(np.median(got["vtk"])), float(np.median(got["ours"]))
        print(f"| {name} | {cells:,} | {a:.4f} | {b:.4f} | {b / a:.2f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=24, help="cells per side of the hexahedral grids")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument(
        "--in-process", action="store_true", help="VTK and ours in-process only (no sandboxed columns)"
    )
    ap.add_argument("--settle", type=float, default=0.2, help="pause after each sandboxed read, s")
    ap.add_argument(
        "--all", action="store_true", help="also the uncompressed, planar, mixed, polyhedral rows"
    )
    ap.add_argument("--cold", action="store_true", help="first reads in fresh processes (median of --repeat)")
    ap.add_argument("--one", nargs=3, metavar=("SIDE", "FILE", "SMALL"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        return _cold_one(*args.one)
    import vtk  # noqa: F401  (imported before the clocks: both sides use it loaded)

    import models.mesh.read  # noqa: F401
    import models.mesh.vtk_readers  # noqa: F401

    _keep_heap()

    with tempfile.TemporaryDirectory() as tmp:
        files = corpus(tmp, args.n, every=args.all)
        if args.cold:
            return _cold(files, tmp, args.repeat)
        if args.in_process:
            print(f"# read stage vs VTK reader + vtk_to_numpy, best of {args.repeat} alternating runs")
            print("| file | cells | VTK s | ours in-process s | in-process / VTK |")
            print("|---|---|---|---|---|")
            for name, path, cells in files:
                a, b = [], []
                for _ in range(args.repeat):
                    a.append(vtk_side(path))
                    b.append(ours(path))
                print(f"| {name} | {cells:,} | {min(a):.4f} | {min(b):.4f} | {min(b) / min(a):.2f} |")
            return
        print(
            f"# read stage vs VTK reader + vtk_to_numpy, best of {args.repeat} alternating runs, "
            f"{args.settle:g} s pause after each sandboxed read"
        )
        from models.mesh import zygote

        if not zygote.wait_ready():
            print("# the reader zygote did not start: its column is a direct fork")
        print(
            "| file | cells | VTK s | ours in-process s | sandboxed, direct fork s | sandboxed, zygote s | "
            "in-process / VTK | direct fork / VTK | zygote / VTK |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        for name, path, cells in files:
            a, b, c, d = [], [], [], []
            for _ in range(args.repeat):
                a.append(vtk_side(path))
                b.append(ours(path))
                d.append(sandboxed(path))
                time.sleep(args.settle)
            for _ in range(args.repeat):  # after the others: a fork of this process write-protects
                c.append(sandboxed(path, zygote=False))  # its pages, and every page written after
                time.sleep(args.settle)  # it faults once, VTK's and ours alike (see the docstring)
            va, vb, vc_, vd = min(a), min(b), min(c), min(d)
            print(
                f"| {name} | {cells:,} | {va:.4f} | {vb:.4f} | {vc_:.4f} | {vd:.4f} | {vb / va:.2f} | "
                f"{vc_ / va:.2f} | {vd / va:.2f} |"
            )


if __name__ == "__main__":
    main()

"""Multilevel agglomeration and refiners against METIS, measured in the same run (issue 8's bars).

Brain (tests/data/BrainCoronalNoHoles.vtu, nref 7 = 128 elements) and a ~100k-tetrahedra unit
cube (nref 8 = 256 elements). Every row: normalized cut of the final (connected) partition, its
ratio to METIS recursive bisection of the same run, parts split into pieces by the contiguity
clean-up (extra fragments), wall time of the partition stage and of its parts (coarsen, bisect,
refine) and the ratio of the time to METIS's. k-way rows: edge cut vs METIS k-way. The numbers are
printed as a table, the bars as PASS / MISS lines with the margin; nothing is asserted.

  python bench/bench_multilevel.py              # brain + cube
  python bench/bench_multilevel.py --quick      # brain only
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)
sys.path.insert(0, HERE)
BRAIN = os.path.join(ROOT, "tests", "data", "BrainCoronalNoHoles.vtu")


def run_row(mesh, g, data, model, mode, refiner=None, **kw):
    from models.partition.agglomerate import agglomerate
    from models.quality.partition_stats import partition_statistics

    t = time.perf_counter()
    a = agglomerate(mesh, data, model=model, mode=mode, refiner=refiner, **kw)
    wall = time.perf_counter() - t
    st = partition_statistics(g.indptr, g.indices, a.labels)
    return {
        "method": f"{model} {mode}" + (f" + {refiner}" if refiner else ""),
        "normalized_cut": st["normalized_cut"],
        "cut": int(st["cut"]),
        "connected": bool(st["connected"]),
        "elements": int(a.n_elements),
        "parts_split": int(a.parts_split),
        "time": wall,
        "stages": {
            k: round(float(v), 3) for k, v in a.timings.items() if k in ("coarsen", "bisect", "refine")
        },
    }


def kahip_row(g, data, k: int):
    """KaHIP (kaffpa, strong preset, 3% imbalance, the cell measures as node weights as METIS gets
    them) when the optional `kahip` package imports, else None. Not a dependency of the project."""
    try:
        import kahip
    except ImportError:
        return None
    import numpy as np

    from models.partition.metis import integer_weights
    from models.quality.partition_stats import partition_statistics

    vw = integer_weights(data.measures).tolist()
    t = time.perf_counter()
    _, blocks = kahip.kaffpa(
        vw, g.indptr.tolist(), [1] * int(g.indices.size), g.indices.tolist(), k, 0.03, True, 0, kahip.STRONG
    )
    wall = time.perf_counter() - t
    lab = np.asarray(blocks, dtype=np.int64)
    st = partition_statistics(g.indptr, g.indices, lab)
    name = "kahip strong" + ("" if st["connected"] else " (parts NOT connected)")
    return {
        "method": name,
        "normalized_cut": st["normalized_cut"],
        "cut": int(st["cut"]),
        "connected": bool(st["connected"]),
        "elements": int(st["parts"]),
        "parts_split": 0,
        "time": wall,
        "stages": {},
    }


def kway_times(mesh, data, k: int, repeats: int = 9) -> dict:
    """Median CPU and wall seconds of METIS k-way with and without `fm`, the two run alternately
    `repeats` times each (one run of ~0.05 s swings by 2x on a loaded machine)."""
    from models.partition.agglomerate import agglomerate

    out = {"metis kway": ([], []), "metis kway + fm": ([], [])}
    for _ in range(repeats):
        for key, refiner in (("metis kway", None), ("metis kway + fm", "fm")):
            c, w = time.process_time(), time.perf_counter()
            agglomerate(mesh, data, model="metis", mode="kway", refiner=refiner, k=k)
            out[key][0].append(time.process_time() - c)
            out[key][1].append(time.perf_counter() - w)
    med = lambda v: sorted(v)[len(v) // 2]  # noqa: E731
    return {key: {"cpu": med(c), "wall": med(w)} for key, (c, w) in out.items()}


def warm_up(mesh, data):
    """Load the neural weights once (not part of any timing)."""
    from models.partition.agglomerate import agglomerate
    from models.partition.rl import WEIGHTS_DIR, _load

    _load(WEIGHTS_DIR / "rl-refiner.pt")
    for model in ("sage-base", "rl-partitioner"):
        agglomerate(mesh, data, model=model, mode="multilevel", nref=1)


def table(rows, base, base_key="normalized_cut"):
    head = f"{'method':42s} {'ncut':>9s} {'x METIS':>8s} {'cut':>7s} {'elem':>5s} {'split':>5s} {'time s':>8s} {'x METIS':>8s}  stages"
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r['method']:42s} {r['normalized_cut']:9.4f} {r['normalized_cut'] / base['normalized_cut']:8.3f} "
            f"{r['cut']:7d} {r['elements']:5d} {r['parts_split']:5d} {r['time']:8.2f} {r['time'] / base['time']:8.2f}  "
            + " ".join(f"{k} {v:.2f}" for k, v in r["stages"].items())
        )
    return "\n".join(lines)


def bar(results, name, ok, detail):
    results.append({"bar": name, "met": bool(ok), "detail": detail})
    print(f"{'PASS' if ok else 'MISS'}  {name}: {detail}")


def brain(bars):
    from models.mesh.read import read_mesh
    from models.pipeline import prepare

    mesh = read_mesh(BRAIN)
    g, data = prepare(mesh)
    warm_up(mesh, data)
    nref = 7
    rows = {}
    specs = [
        ("metis nref", dict(model="metis", mode="nref", nref=nref)),
        ("sage-base nref", dict(model="sage-base", mode="nref", nref=nref)),
        (
            "sage-base ml + rl-refiner",
            dict(model="sage-base", mode="multilevel", nref=nref, refiner="rl-refiner"),
        ),
        (
            "rl-partitioner ml + rl-refiner",
            dict(model="rl-partitioner", mode="multilevel", nref=nref, refiner="rl-refiner"),
        ),
        ("sage-base ml + fm", dict(model="sage-base", mode="multilevel", nref=nref, refiner="fm")),
        ("metis nref + fm", dict(model="metis", mode="nref", nref=nref, refiner="fm")),
        ("metis ml + fm", dict(model="metis", mode="multilevel", nref=nref, refiner="fm")),
        ("metis nref + rl-refiner", dict(model="metis", mode="nref", nref=nref, refiner="rl-refiner")),
    ]
    for key, kw in specs:
        rows[key] = run_row(mesh, g, data, **kw)
        print(f"  brain {key}: {rows[key]['normalized_cut']:.4f} in {rows[key]['time']:.2f} s", flush=True)
    kway = {
        "metis kway": run_row(mesh, g, data, "metis", "kway", k=2**nref),
        "metis kway + fm": run_row(mesh, g, data, "metis", "kway", refiner="fm", k=2**nref),
    }
    times = kway_times(mesh, data, 2**nref)
    for key, t in times.items():
        kway[key]["time"] = t["wall"]
        kway[key]["cpu"] = t["cpu"]
    kahip = kahip_row(g, data, 2**nref)
    if kahip is not None:
        kway["kahip strong"] = kahip
    base = rows["metis nref"]
    print("\nBrain, 14,372 triangles, nref 7 (128 elements); baseline METIS recursive bisection\n")
    print(table(list(rows.values()), base))
    print("\nk-way 128; baseline METIS k-way; times: medians of 9 alternating runs\n")
    print(table(list(kway.values()), kway["metis kway"]))
    print()
    r = lambda k: rows[k]["normalized_cut"] / base["normalized_cut"]  # noqa: E731
    s = rows["sage-base ml + rl-refiner"]
    bar(
        bars,
        "brain: sage-base ml + rl-refiner <= plain sage-base",
        s["normalized_cut"] <= rows["sage-base nref"]["normalized_cut"],
        f"{s['normalized_cut']:.4f} vs {rows['sage-base nref']['normalized_cut']:.4f}",
    )
    bar(
        bars,
        "brain: sage-base ml + rl-refiner <= 1.03x METIS",
        r("sage-base ml + rl-refiner") <= 1.03,
        f"{r('sage-base ml + rl-refiner'):.3f}x",
    )
    bar(
        bars,
        "brain: sage-base ml + rl-refiner 0 extra fragments",
        s["parts_split"] == 0 and s["elements"] == 128,
        f"{s['parts_split']} parts split, {s['elements']} elements",
    )
    bar(
        bars,
        "brain: rl-partitioner ml + rl-refiner <= 1.15x METIS",
        r("rl-partitioner ml + rl-refiner") <= 1.15,
        f"{r('rl-partitioner ml + rl-refiner'):.3f}x",
    )
    bar(
        bars,
        "brain: sage-base ml + fm <= 0.97x METIS",
        r("sage-base ml + fm") <= 0.97,
        f"{r('sage-base ml + fm'):.3f}x",
    )
    bar(
        bars,
        "brain: metis nref + fm <= 0.97x METIS",
        r("metis nref + fm") <= 0.97,
        f"{r('metis nref + fm'):.3f}x",
    )
    kw0, kw1 = kway["metis kway"], kway["metis kway + fm"]
    bar(
        bars,
        "brain: metis kway + fm edge cut >= 4% below METIS k-way",
        kw1["cut"] <= 0.96 * kw0["cut"],
        f"{kw1['cut']} vs {kw0['cut']} ({100 * (1 - kw1['cut'] / kw0['cut']):.1f}% lower)",
    )
    bar(
        bars,
        "brain: metis kway + fm every part connected",
        kw1["connected"] and kw1["parts_split"] == 0,
        f"connected {kw1['connected']}, {kw1['parts_split']} split",
    )
    bar(
        bars,
        "brain: metis kway + fm at most 2x METIS k-way time",
        kw1["cpu"] <= 2 * kw0["cpu"],
        f"CPU {kw1['cpu']:.3f} s vs {kw0['cpu']:.3f} s ({kw1['cpu'] / kw0['cpu']:.2f}x; wall "
        f"{kw1['time'] / kw0['time']:.2f}x)",
    )
    return {"brain": rows, "brain_kway": kway}


def cube(bars, cells: int):
    from bench_library import make_cube

    from models.mesh.read import read_mesh
    from models.pipeline import prepare

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "cube.msh")
        make_cube(path, cells)
        mesh = read_mesh(path)
    g, data = prepare(mesh)
    warm_up(mesh, data)
    nref = 8
    rows = {}
    for key, kw in [
        ("metis nref", dict(model="metis", mode="nref", nref=nref)),
        ("sage-base nref", dict(model="sage-base", mode="nref", nref=nref)),
        (
            "sage-base ml + rl-refiner",
            dict(model="sage-base", mode="multilevel", nref=nref, refiner="rl-refiner"),
        ),
        ("sage-base ml + fm", dict(model="sage-base", mode="multilevel", nref=nref, refiner="fm")),
        (
            "rl-partitioner ml + rl-refiner",
            dict(model="rl-partitioner", mode="multilevel", nref=nref, refiner="rl-refiner"),
        ),
    ]:
        rows[key] = run_row(mesh, g, data, **kw)
        print(f"  cube {key}: {rows[key]['normalized_cut']:.4f} in {rows[key]['time']:.2f} s", flush=True)
    base = rows["metis nref"]
    print(f"\nCube, {mesh.n_cells:,} tetrahedra, nref 8 (256 elements); baseline METIS recursive bisection\n")
    print(table(list(rows.values()), base))
    print()
    s = rows["sage-base ml + rl-refiner"]
    ratio = s["normalized_cut"] / base["normalized_cut"]
    bar(bars, "cube: sage-base ml + rl-refiner <= 1.1x METIS", ratio <= 1.1, f"{ratio:.3f}x")
    extra = (s["elements"] - 256) / 256
    bar(
        bars,
        "cube: sage-base ml + rl-refiner <= 1% extra fragments",
        extra <= 0.01,
        f"{s['elements']} elements for 256 ({100 * extra:.1f}% extra, {s['parts_split']} parts split)",
    )
    rl = rows["rl-partitioner ml + rl-refiner"]["normalized_cut"] / base["normalized_cut"]
    bar(
        bars,
        "cube: rl-partitioner ml + rl-refiner <= 1.15x METIS (as on the brain)",
        rl <= 1.15,
        f"{rl:.3f}x",
    )
    return {"cube": rows, "cube_cells": int(mesh.n_cells)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="brain only")
    ap.add_argument("--cube-only", action="store_true", help="cube only")
    ap.add_argument("--cube-cells", type=int, default=100_000)
    ap.add_argument("--json", help="write every number here")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    bars: list[dict] = []
    out = {} if args.cube_only else brain(bars)
    if not args.quick:
        out.update(cube(bars, args.cube_cells))
    out["bars"] = bars
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=1)
    print(f"\n{sum(b['met'] for b in bars)} of {len(bars)} bars met")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""`magnet hierarchy` (nested levels for multigrid, any model) and `magnet mgcheck` (judge them with
a multigrid solve). Loaded only when one of them is asked for (pyamg stays out of other commands)."""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from models.errors import MeshError, ParameterError


def add_hierarchy_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("mesh")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="DIR",
        help="folder for level_L.vtu, level_L.labels.json, level_L.parent.json, level_L.metrics.json, "
        "level_L.agg.npz/.mtx (aggregation operators) and hierarchy.json",
    )
    p.add_argument(
        "--model",
        default="rtree",
        help="rtree (native, default) | metis | kmeans (agglomerates agglomerated) | "
        "sage-base ... (recursive bisection)",
    )
    p.add_argument(
        "--ratio",
        type=float,
        default=None,
        help="coarsening ratio of every level, >= 2, rtree cuts at every level (default: rtree's finest "
        "level a standard aggregation of the cells' graph, then 8 per level in 2D, 16 in 3D)",
    )
    p.add_argument(
        "--coarsest",
        type=int,
        default=10,
        help="the coarsest level has at most this many elements (default 10)",
    )
    p.add_argument(
        "--finest",
        metavar="{aggregation,cuts,quality,nested}",
        help="how the finest level is made (rtree; default: aggregation with the default schedule and no "
        "--kappa, else cuts). aggregation: pyamg's standard aggregation of the cells, cuts above: ties or "
        "beats pyamg's iterations, ragged coarse boxes. cuts: rtree cuts of the cells at every level: "
        "box-shaped elements (R3MG's box measures), up to 1.14x pyamg's iterations; the one with --ratio "
        "or --kappa. quality: pairwise quality-controlled aggregates: fewer iterations (0.92x in 2D) at a "
        "higher operator complexity (1.3-1.4x pyamg's on the family, 1.6x on recombined quads, 2x on hexahedra with pyramids). nested: pyamg's aggregation inside the cells' cuts: the "
        "cuts' boxes on the coarser levels, up to 1.12x pyamg's iterations on the family (1.2x on an outside 3D mesh)",
    )
    p.add_argument(
        "--boxfit",
        action="store_true",
        help="then move boundary units (cells, or the finer level's elements) between elements towards "
        "tighter boxes: better box ratio and coverage, counts exact, levels still nested; any model",
    )
    p.add_argument(
        "--keep-rings",
        action="store_true",
        help="3D: keep elements with a handle (rings around a tunnel or a neighbour) instead of cutting "
        "them (faster; a note counts them); refused for a 2D mesh",
    )
    p.add_argument(
        "--groups", action="store_true", help="no element crosses a physical group (rtree, metis, kmeans)"
    )
    p.add_argument(
        "--metrics",
        action="store_true",
        help="shape metrics of every element of every level (slower); "
        "without: partition statistics, box ratio and coverage per level",
    )
    p.add_argument("--lymph", action="store_true", help="also the lymph structs of every level (2D)")
    p.add_argument(
        "--mgcheck",
        action="store_true",
        help="judge the levels with a multigrid solve (see magnet mgcheck); "
        "numbers in hierarchy.json under 'multigrid'",
    )
    p.add_argument(
        "--kappa",
        metavar="KX,KY[,KZ]",
        help="anisotropic diffusion tensor diag(kx, ky[, kz]) the levels are for: rtree cuts in the "
        "metric of its couplings (elements sqrt(kx/ky) times longer along x than y); also the tensor "
        "of --mgcheck (default: identity); with another model, only --mgcheck's (add it)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--physical-tag")
    p.set_defaults(func=hierarchy_main)


def add_mgcheck_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("mesh")
    p.add_argument(
        "hierarchy",
        metavar="DIR",
        help="a folder written by `magnet hierarchy` or `magnet agglomerate --hierarchy`",
    )
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument(
        "--kappa",
        metavar="KX,KY[,KZ]",
        help="anisotropic diffusion tensor diag(kx, ky[, kz]) in the TPFA operator (default: identity)",
    )
    p.add_argument("--physical-tag")
    p.set_defaults(func=mgcheck_main)


def hierarchy_main(args) -> int:
    from models.agglomeration import build_hierarchy

    out = args.output
    kappa = None
    if args.kappa is not None:
        from models.hierarchy.multigrid import parse_kappa

        kappa = parse_kappa(args.kappa)  # bad values refused before any work
        if args.model != "rtree" and not args.mgcheck:  # (else given and ignored without a word)
            raise ParameterError(
                f"--kappa cuts the levels for a diffusion tensor with --model rtree only; with --model "
                f"{args.model} it is the tensor of --mgcheck's solve: add --mgcheck, or use --model rtree"
            )
    parent = os.path.dirname(os.path.abspath(out))
    if not os.path.isdir(parent):
        raise ParameterError(f"cannot write the hierarchy to {out!r}: folder {parent!r} does not exist")
    t0 = time.perf_counter()
    h = build_hierarchy(
        args.mesh,
        model=args.model,
        ratio=args.ratio,
        coarsest=args.coarsest,
        seed=args.seed,
        groups=args.groups,
        physical_tag=args.physical_tag,
        # the levels cut for the operator (rtree; the other models: kappa goes to --mgcheck only)
        kappa=args.kappa if kappa is not None and args.model == "rtree" else None,
        finest=args.finest,
        boxfit=args.boxfit,
        keep_rings=args.keep_rings,
    )
    mesh, data, info = h.mesh, h.data, h.info
    t_read = time.perf_counter() - t0 - info["build_time"]
    t = time.perf_counter()
    index = h.write(out, metrics=args.metrics, lymph=args.lymph)
    t_write = time.perf_counter() - t
    mg = ""
    if args.mgcheck:
        from models.hierarchy.multigrid import format_report, mgcheck, parse_kappa
        from models.mesh.dropped import read_labels

        written = [
            read_labels(
                mesh.meta,
                np.asarray(
                    json.load(open(os.path.join(out, lv["labels"]), encoding="utf-8")), dtype=np.int64
                ),
            )
            for lv in index["levels"]
        ]
        rep = mgcheck(mesh, data, written, kappa=parse_kappa(args.kappa, mesh.dim))
        index["multigrid"] = rep
        from models.hierarchy.nested import _write_json

        _write_json(os.path.join(out, "hierarchy.json"), index)
        mg = "\n" + format_report(rep)
    sizes = " > ".join(str(lv["elements"]) for lv in index["levels"])
    print(format_levels(info["report"]))
    for note in info.get("notes", []):
        print(f"note: {note}")
    from models.mesh.dropped import dropped_sentence

    left_out = dropped_sentence(mesh.meta)
    if left_out:
        print(f"warning: {left_out} (labels: -1 for them)")
    from models.hierarchy.stale import removed_sentence

    if h.removed:
        print(f"note: {removed_sentence(h.removed, out)}")
    print(
        f"{len(index['levels'])} nested levels ({sizes} elements) from {mesh.n_cells} cells with {args.model} "
        f"| read {t_read:.2f}s build {info['build_time']:.2f}s write {t_write:.2f}s | total {time.perf_counter() - t0:.2f}s"
        f" -> {out}{mg}"
    )
    return 0


def format_levels(report: list[dict]) -> str:
    """The per-level report: elements (planned: the count the plan gave the level, which the domain
    may have raised), ratio to the finer level (planned, and asked: the --ratio or schedule step, "-"
    for a finest level no ratio was asked of; off: achieved against asked, "!" past 25%), holed
    elements found, holes opened by moving a path to a neighbour (threaded), ring cuts, elements split
    into their children, pairs merged back, pairs merged with the holes between them threaded
    through every level (models.hierarchy.rethread), and in 3D the elements left that are not balls."""
    from models.partition.rtree import RATIO_SLACK

    balls = any("not_balls" in r for r in report)  # (3D: elements whose cells' characteristic is not 1)
    lines = [
        f"{'level':>5}{'elements':>10}{'planned':>9}{'ratio':>7}{'planned':>8}{'asked':>7}{'off':>6}"
        f"{'holed':>7}{'threaded':>9}{'ring cuts':>10}{'splits':>8}{'merged':>8}{'merged+threads':>16}"
        + (f"{'not balls':>11}" if balls else "")
    ]
    for r in report:
        req = f"{r['requested']}" if "requested" in r else "-"
        want = _ratio(r["requested_ratio"]) if "requested_ratio" in r else "-"
        asked = _ratio(r["asked_ratio"]) if "asked_ratio" in r else "-"
        off = "-"
        if "asked_ratio" in r:
            raw = r["ratio"] / r["asked_ratio"] - 1.0
            d = round(raw, 2) + 0.0  # (+ 0.0: no "-0%")
            off = (f"{d:+.0%}" if d < 9.99 else ">999%") + ("!" if abs(raw) > RATIO_SLACK else "")
        lines.append(
            f"{r['level']:>5}{r['elements']:>10}{req:>9}{_ratio(r['ratio']):>7}{want:>8}{asked:>7}{off:>6}"
            f"{r['holed_elements']:>7}{r.get('holes_threaded', 0):>9}{r['ring_cuts']:>10}"
            f"{r['split_into_children']:>8}{r['merged_pairs']:>8}{r.get('threaded_merges', 0):>16}"
            + (f"{r.get('not_balls', 0):>11}" if balls else "")
        )
    return "\n".join(lines)


def _ratio(x: float) -> str:
    """A ratio in at most 6 characters (a column of the table: 8.00, 13.5, 1.1e+05)."""
    return f"{x:.2f}" if abs(x) < 1000 else f"{x:.2g}"


def read_levels(folder: str) -> list[np.ndarray]:
    """The labels of every level of a hierarchy folder (hierarchy.json order: coarsest first)."""
    path = os.path.join(folder, "hierarchy.json")
    try:
        index = json.load(open(path, encoding="utf-8"))
        files = [lv["labels"] for lv in index["levels"]]
    except FileNotFoundError:
        raise ParameterError(
            f"{folder} holds no hierarchy.json (write one with `magnet hierarchy`)"
        ) from None
    except (OSError, ValueError, KeyError, TypeError):
        raise ParameterError(
            f"cannot read {path}: it is not the index `magnet hierarchy` writes (damaged or truncated?); "
            "write the hierarchy again"
        ) from None
    levels = []
    for f in files:
        name = os.path.basename(str(f))
        try:
            lv = np.asarray(json.load(open(os.path.join(folder, name), encoding="utf-8")), dtype=np.int64)
        except FileNotFoundError:
            raise ParameterError(f"the hierarchy in {folder} lists {name}, which is missing") from None
        except (OSError, ValueError, TypeError, OverflowError):
            raise ParameterError(
                f"cannot read {name} of the hierarchy in {folder}: it is not a list of element ids "
                "(damaged or truncated?); write the hierarchy again"
            ) from None
        levels.append(lv)
    return levels


def mgcheck_main(args) -> int:
    from models.hierarchy.multigrid import format_report, mgcheck, parse_kappa
    from models.mesh.sandbox import read_mesh_cli as read_mesh
    from models.pipeline import prepare

    kappa = parse_kappa(args.kappa)
    levels = read_levels(args.hierarchy)
    mesh = read_mesh(args.mesh, physical_tag=args.physical_tag)
    from models.mesh.dropped import read_labels

    levels = [read_labels(mesh.meta, lv) for lv in levels]  # (the file's cells: those read)
    for L, lv in enumerate(levels):
        if lv.ndim != 1 or lv.size != mesh.n_cells:
            raise MeshError(
                f"the hierarchy in {args.hierarchy} is not of this mesh: its level {L} labels "
                f"{lv.size:,} cells, the mesh has {mesh.n_cells:,} (another mesh's hierarchy, or a damaged file)"
            )
    _, data = prepare(mesh)
    kappa = parse_kappa(args.kappa, mesh.dim)
    rep = mgcheck(mesh, data, levels, kappa=kappa)
    print(json.dumps(rep, indent=1) if args.json else format_report(rep))
    return 0

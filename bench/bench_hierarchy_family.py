"""Hierarchies on a family of meshes (issue 24): 2D plates with 1, 4 and 16 holes, an L-shape, a slit,
a mesh graded 100:1 towards a corner, a 50:1 boundary layer, two materials, quads, triangles and
quads; 3D a torus, a genus-two slab, a block with a spherical cavity, a block with two tunnels, a
thin-walled cup, hexahedra, hexahedra and prisms. All built with gmsh here (bench/family_meshes.py).

For each mesh and model (the default ratio schedule by dimension, or --ratio R at every level; coarsest 10): the level counts and the worst level ratio against
the requested one, elements that enclose a hole (should be 0), disconnected elements (should be 0),
PCG iterations and operator complexity against pyamg's standard aggregation (TPFA Poisson as
`magnet mgcheck`; on the boundary layer also with the matching tensor kappa = diag(50, 1)), box
ratio / coverage of the finest and middle level, CR of the finest, and the build time against one
METIS k-way call at the finest level's count, measured in the same run. Worst case first.

    python bench/bench_hierarchy_family.py [--large] [--models rtree,metis,kmeans] [--meshes a,b]
        [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path[:0] = [ROOT, HERE]

from bench_hierarchy import circle_ratio, pieces  # noqa: E402
from family_meshes import FAMILY  # noqa: E402

from models.hierarchy.multigrid import mgcheck  # noqa: E402
from models.hierarchy.nested import build_hierarchy, default_ratio  # noqa: E402
from models.hierarchy.topology import handle_elements  # noqa: E402
from models.mesh.read import mesh_from_arrays  # noqa: E402
from models.partition.rtree import level_counts  # noqa: E402
from models.pipeline import prepare  # noqa: E402
from models.quality.report import box_measures  # noqa: E402

RATIO = None  # the default per-level schedule by dimension (models.hierarchy.nested.default_ratio); --ratio R: every level R
COARSEST = 10
# 2D members with holes (box ratio / coverage at 91 and 364 are judged on the others)
HOLED = {
    "plate-1hole": True,
    "plate-4holes": True,
    "plate-16holes": True,
    "plate-36holes": True,
    "pinholes-100": True,
    "quads": True,
    "tri+quad": True,
}
# model name in the table -> (build_hierarchy model, model_options)
MODELS = {
    "rtree": ("rtree", None),
    "rtree-cuts": (
        "rtree",
        {"finest": "cuts"},
    ),  # rtree cuts at the finest level too (the default before round six)
    # the finest level a standard aggregation (round six: pyamg's compiled pass, the rest joined by
    # strength), rtree cuts above; -pyamg: pyamg's own join (first neighbour); -luby: round five's rounds
    "rtree-agg": ("rtree", {"finest": "aggregation"}),
    # round eight: cuts of the cells at every coarser level, the finest level pyamg's aggregation
    # inside each element of the level above
    "rtree-nested": ("rtree", {"finest": "nested"}),
    "rtree-nested-plain": ("rtree", {"finest": "nested", "merge": False}),  # no merge of the clipped
    "rtree-pyamg": ("rtree", {"finest": "pyamg"}),
    "rtree-luby": ("rtree", {"finest": "luby"}),
    # round seven: Notay's quality-controlled pairwise aggregation (2 matchings in 2D, 3 in 3D, mu < 8)
    "rtree-quality": ("rtree", {"finest": "quality"}),
    "rtree-quality-m6": ("rtree", {"finest": "quality", "passes": 3, "maxsize": 6}),
    "rtree-measure": ("rtree", {"balance": "measure"}),  # measure-weighted cuts (the default before issue 24)
    "rtree-principal": ("rtree", {"axes": "principal"}),  # cuts across each part's principal axis (numpy)
    "rtree-strength": ("rtree", {"axes": "strength"}),  # cut axis across the weakest TPFA couplings (numpy)
    "rtree-box": (
        "rtree",
        {"axes": "box"},
    ),  # longest extent, least box overlap (the default before round four)
    "rtree-s-total": ("rtree", {"axes": "strength-mincut"}),  # the same, least crossing weight
    "rtree-keep-rings": (
        "rtree",
        {"rings": False},
    ),  # 3D rings (elements with a handle) kept (cut by default since round fifteen)
    "rtree-faces": ("rtree", None),  # finest step 1 + the cells' mean face count (tri 4, quad/tet 5, hex 7)
    "rtree-s-pos": ("rtree", {"axes": "strength-position"}),  # longest extent, cut position by couplings
    "rtree-r8": ("rtree", None),  # ratio 8 at every level (the default before round three)
    "rtree-kappa": ("rtree", None),  # cut in the metric of the member's tensor kappa (where it has one)
    "rtree-boxfit": ("rtree", {"boxfit": True}),  # + models.hierarchy.boxfit (units moved to tighter boxes)
    "rtree-box-boxfit": ("rtree", {"axes": "box", "boxfit": True}),  # least-overlap cuts + boxfit
    "metis": ("metis", None),
    "kmeans": ("kmeans", None),
    "sage-base": ("sage-base", None),
}

# the models whose levels at exactly 91 and 364 elements are measured (box_at: their axes and boxfit)
BOX_AT = (
    "rtree",
    "rtree-cuts",
    "rtree-nested",
    "rtree-nested-plain",
    "rtree-box",
    "rtree-boxfit",
    "rtree-box-boxfit",
)
AGGREGATED = ("aggregation", "pyamg", "luby")  # finest modes whose coarser levels cut the aggregates


def face_ratio(mesh) -> tuple[float, float]:
    """(1 + the cells' mean number of faces, 16): pyamg's aggregate of a cell and its face neighbours
    (VTK ids: triangle 3 faces, quad 4, tetra 4, hexahedron 6, wedge 5, pyramid 5; others 4)."""
    faces = np.full(256, 4.0)
    faces[[5, 9, 10, 12, 13, 14]] = [3, 4, 4, 6, 5, 5]
    return (1.0 + float(faces[mesh.cell_types].mean()), 16.0)


def holed(mesh, graph, data, labels) -> int:
    """Elements of one level that enclose a hole or cavity (merging decides)."""
    from models.polytope.merge import merge

    _, holes = merge(mesh, graph, labels, data.measures)
    return int(np.unique(holes.elements).size)


def metis_time(data, k: int) -> float:
    from models.partition import get_partitioner
    from models.partition.agglomerate import make_batch

    batch = make_batch(data, np.zeros(data.graph.n, dtype=np.int64))
    t = time.perf_counter()
    get_partitioner("metis").kway(batch, int(k))
    return time.perf_counter() - t


def box_at(mesh, data, counts=(91, 364), axes="strength-mincut", boxfit=False, aggregated=False) -> dict:
    """Box ratio and coverage of rtree hierarchy levels of exactly `counts` elements (R3MG's measures
    at 91 and 364 elements; 2D members without holes). aggregated=False: rtree_levels' count-weighted
    cuts of the cells (as build_hierarchy makes levels with finest="cuts"); aggregated=True: as the
    default rtree hierarchy makes them (round six: the finest level pyamg's standard aggregation, the
    levels of 91 and 364 elements cuts of the finest aggregates' graph). boxfit: then
    models.hierarchy.boxfit's pass on them (nested, as build_hierarchy does)."""
    from models.graph.batch import GraphBatch
    from models.partition.rtree import cell_boxes, rtree_levels
    from models.partition.rtree_strength import tpfa_coupling

    n, G = mesh.n_cells, data.graph
    boxes = cell_boxes(data.points, data.offsets, data.connectivity)
    if aggregated:
        from models.hierarchy.finest import aggregated_levels

        opts = {"boxes": boxes, "balance": "cells", "axes": axes}
        if axes.startswith("strength"):
            opts["coupling"] = tpfa_coupling(G.indptr, G.indices, G.weights, data.centroids)
        levels, _, _, _ = aggregated_levels(mesh, data, None, 16.0, COARSEST, opts, counts=list(counts))
    else:
        batch = GraphBatch(
            indptr=G.indptr,
            indices=G.indices,
            weights=G.weights,
            graph_ptr=np.array([0, n], dtype=np.int64),
            centroids=data.centroids,
            measures=data.measures,
            tags=data.tags,
            node_ids=np.arange(n),
        )
        levels = rtree_levels(batch, list(counts), balance="cells", boxes=boxes, axes=axes)
    if boxfit:
        from models.hierarchy.boxfit import boxfit_levels

        levels = boxfit_levels(levels, boxes[0], boxes[1], data.measures, G.indptr, G.indices)
    out = {}
    for c, lv in zip(counts, levels, strict=False):
        assert int(lv.max()) + 1 == c, (c, int(lv.max()) + 1)
        bm = box_measures(mesh.points, mesh.offsets, mesh.connectivity, lv, data.measures)
        out[str(c)] = [float(bm["box_ratio"].mean()), float(bm["coverage"])]
    return out


def row(name, mesh, graph, data, model, kappa, t_metis) -> dict:
    base, opts = MODELS[model]
    ratio = 8.0 if model == "rtree-r8" else face_ratio(mesh) if model == "rtree-faces" else RATIO
    cut_k = None if model != "rtree-kappa" or kappa is None else np.asarray(kappa, dtype=np.float64)
    t = time.perf_counter()
    try:
        levels, info = build_hierarchy(
            mesh, data, model=base, ratio=ratio, coarsest=COARSEST, model_options=opts, kappa=cut_k
        )
    except Exception as exc:  # a model that cannot run here (e.g. no weights): say so, go on
        return {"mesh": name, "model": model, "error": str(exc).splitlines()[0]}
    t_build = time.perf_counter() - t
    sizes = [int(lv.max()) + 1 for lv in levels]
    ratios = [b / a for a, b in zip(sizes, sizes[1:] + [mesh.n_cells], strict=True)]
    # against the ratio asked (the schedule: finest step first, the last repeated), every level, finest
    # up; and against the planned counts (level_counts evens the repeated steps within STRETCH)
    # (the default rtree's finest step is the aggregation's own: build_hierarchy records it in info["ratio"])
    sched = [
        float(v)
        for v in np.atleast_1d(info.get("ratio", ratio if ratio is not None else default_ratio(mesh.dim)))
    ]
    asked = [sched[min(j, len(sched) - 1)] for j in range(len(ratios))]
    worst = max(abs(r / w - 1.0) for r, w in zip(ratios[::-1], asked, strict=True))
    req = [int(c) for c in info["requested"]] + [mesh.n_cells]
    want = [b / a for a, b in zip(req, req[1:], strict=False)]
    worst_plan = max(abs(r / w - 1.0) for r, w in zip(ratios[::-1], want[::-1], strict=False))
    if len(sizes) != len(req) - 1 or sizes[0] > COARSEST:  # a level missing, or the coarse end stalled
        worst = max(worst, abs(sizes[0] / req[0] - 1.0))
        worst_plan = max(worst_plan, abs(sizes[0] / req[0] - 1.0))
    bm = [box_measures(mesh.points, mesh.offsets, mesh.connectivity, lv, data.measures) for lv in levels]
    mid = len(levels) // 2
    rep = mgcheck(mesh, data, levels)
    out = {
        "mesh": name,
        "dim": mesh.dim,
        "cells": int(mesh.n_cells),
        "model": model,
        "levels": sizes,
        "level_ratios": ratios,
        "worst_ratio_deviation": worst,
        "worst_vs_plan": worst_plan,
        "coarsest_ok": sizes[0] <= COARSEST,
        "holed": sum(holed(mesh, graph, data, lv) for lv in levels),
        # 3D elements with a handle (a ring around a tunnel or around a neighbour, or touching
        # themselves along an edge), summed over the levels; not fixed by default (rings: opt-in)
        "handles": sum(handle_elements(mesh, graph, lv).size for lv in levels) if mesh.dim == 3 else 0,
        "extra_pieces": sum(pieces(graph, lv) - s for lv, s in zip(levels, sizes, strict=True)),
        "it_S": rep["smoothed"]["iterations"],
        "it_S_pyamg": rep["pyamg_sa"]["iterations"],
        "it_S_ratio": rep["ratios"]["smoothed_iterations_vs_pyamg"],
        "oc_S_ratio": rep["ratios"]["smoothed_complexity_vs_pyamg"],
        "it_U_ratio": rep["ratios"]["unsmoothed_iterations_vs_pyamg"],
        "oc_U_ratio": rep["ratios"]["unsmoothed_complexity_vs_pyamg"],
        "box_ratio_fine_mid": [float(bm[-1]["box_ratio"].mean()), float(bm[mid]["box_ratio"].mean())],
        "coverage_fine_mid": [bm[-1]["coverage"], bm[mid]["coverage"]],
        "cr_fine": circle_ratio(mesh, graph, data, levels[-1]),
        "build_time": t_build,
        "metis_time": t_metis,
        "report": info.get("report"),
        "finest": info.get("finest"),
    }
    if kappa is not None:
        ra = mgcheck(mesh, data, levels, kappa=np.asarray(kappa))
        out["kappa"] = list(kappa)
        out["it_S_ratio_kappa"] = ra["ratios"]["smoothed_iterations_vs_pyamg"]
        out["it_U_ratio_kappa"] = ra["ratios"]["unsmoothed_iterations_vs_pyamg"]
        out["oc_S_ratio_kappa"] = ra["ratios"]["smoothed_complexity_vs_pyamg"]
    return out


HEAD = (
    f"{'mesh':<14}{'model':<12}{'cells':>7} {'levels (coarse > fine)':<28}{'worst r':>8}{'holed':>6}{'hdl':>5}{'pcs+':>5}"
    f"{'itS/pa':>8}{'ocS/pa':>7}{'itU/pa':>7}{'ocU/pa':>7}{'aniso S':>8}{'BR f/m':>11}{'cov f/m':>11}{'CR f':>6}"
    f"{'build/metis':>12}"
)


def fmt(r: dict) -> str:
    if "error" in r:
        return f"{r['mesh']:<14}{r['model']:<12}unavailable: {r['error']}"
    lv = ">".join(map(str, r["levels"]))
    an = f"{r['it_S_ratio_kappa']:.2f}" if "it_S_ratio_kappa" in r else "-"
    br, cv = r["box_ratio_fine_mid"], r["coverage_fine_mid"]
    return (
        f"{r['mesh']:<14}{r['model']:<12}{r['cells']:>7} {lv:<28}{r['worst_ratio_deviation']:>8.2f}{r['holed']:>6}"
        f"{r['handles'] if r['dim'] == 3 else '-':>5}{r['extra_pieces']:>5}{r['it_S_ratio']:>8.2f}{r['oc_S_ratio']:>7.2f}{r['it_U_ratio']:>7.2f}"
        f"{r['oc_U_ratio']:>7.2f}{an:>8}{br[0]:>6.2f}/{br[1]:.2f}{cv[0]:>6.2f}/{cv[1]:.2f}{r['cr_fine']:>6.2f}"
        f"{r['build_time'] / max(r['metis_time'], 1e-9):>12.2f}"
    )


def worst_cases(rows: list[dict]) -> list[str]:
    """Per model: the worst value over the family of each column, and on which mesh."""
    out = []
    ok = [r for r in rows if "error" not in r]
    for model in dict.fromkeys(r["model"] for r in ok):
        rs = [r for r in ok if r["model"] == model]

        def arg(key, pick=max, rs=rs, dim=None):
            c = [r for r in rs if dim is None or r["dim"] == dim]
            if not c:
                return "-"
            b = pick(c, key=lambda r: r[key] if not isinstance(r[key], list) else r[key][0])
            v = b[key][0] if isinstance(b[key], list) else b[key]
            return f"{v:.2f} ({b['mesh']})" if isinstance(v, float) else f"{v} ({b['mesh']})"

        out.append(
            f"{model}: worst level ratio deviation {arg('worst_ratio_deviation')}; holed elements "
            f"{arg('holed')}; 3D elements with a handle {arg('handles', dim=3)}; extra pieces {arg('extra_pieces')}; smoothed iterations / pyamg 2D "
            f"{arg('it_S_ratio', dim=2)}, 3D {arg('it_S_ratio', dim=3)}; op. complexity / pyamg "
            f"{arg('oc_S_ratio')}; unsmoothed iterations / pyamg 2D {arg('it_U_ratio', dim=2)}, 3D "
            f"{arg('it_U_ratio', dim=3)}; finest BR {arg('box_ratio_fine_mid', min)}; finest coverage "
            f"{arg('coverage_fine_mid')}; build / METIS {max(r['build_time'] / max(r['metis_time'], 1e-9) for r in rs):.2f}"
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true", help="about 10^6 cells per mesh instead of 10^4")
    ap.add_argument(
        "--scale", type=float, default=None, help="size factor (1: ~10^4 cells; --large: 10^2 cells x)"
    )
    ap.add_argument("--models", default="rtree,metis,kmeans", help=f"comma list of {', '.join(MODELS)}")
    ap.add_argument("--meshes", default=",".join(FAMILY), help="comma list (default: the whole family)")
    ap.add_argument("--json", help="write every number here")
    ap.add_argument(
        "--ratio",
        type=float,
        default=RATIO,
        help="requested ratio of every level (default: the schedule by dimension)",
    )
    a = ap.parse_args()
    globals()["RATIO"] = a.ratio
    models = a.models.split(",")
    rows = []
    for name in a.meshes.split(","):
        make, kappa = FAMILY[name]
        t = time.perf_counter()
        p, blocks, tags = make(1.0)
        dim = p.shape[1]
        s = a.scale if a.scale is not None else (100.0 ** (1.0 / dim) if a.large else 1.0)
        if s != 1.0:
            p, blocks, tags = make(s)
        mesh = mesh_from_arrays(p, blocks, tags)
        graph, data = prepare(mesh)
        k = level_counts(mesh.n_cells, RATIO if RATIO is not None else default_ratio(mesh.dim), COARSEST)[-1]
        t_metis = min(metis_time(data, k) for _ in range(2))
        print(
            f"\n{name}: {mesh.n_cells} cells ({mesh.dim}D), made in {time.perf_counter() - t:.1f}s; "
            f"METIS k-way {k}: {t_metis:.3f}s",
            flush=True,
        )
        print(HEAD, flush=True)
        for model in models:
            if model == "rtree-kappa" and kappa is None:
                continue  # the same levels as rtree
            r = row(name, mesh, graph, data, model, kappa, t_metis)
            if model in BOX_AT and mesh.dim == 2 and "error" not in r and not HOLED.get(name, False):
                o = MODELS[model][1] or {}
                ax, bf = o.get("axes", "strength-mincut"), bool(o.get("boxfit"))
                # levels made as build_hierarchy makes this model's (the default: cuts of the finest
                # aggregates' graph); the default rtree also as rtree_levels' cuts of the cells
                agg = r.get("finest") in AGGREGATED
                r["box_at"] = box_at(mesh, data, axes=ax, boxfit=bf, aggregated=agg)
                r["box_at_how"] = "aggregates" if agg else "cells"
                if agg and model == "rtree":
                    r["box_at_cells"] = box_at(mesh, data, axes=ax, boxfit=bf)
            rows.append(r)
            print(fmt(r), flush=True)
    ok = [r for r in rows if "error" not in r]
    ok.sort(key=lambda r: -r["worst_ratio_deviation"] - r["holed"] - max(r["it_S_ratio"] - 1, 0))
    print(
        "\nthe family, worst case first (worst r: max |level ratio / requested ratio - 1|, all levels; the"
        " requested ratio the schedule's, --ratio's)"
    )
    print(HEAD)
    for r in ok:
        print(fmt(r))
    at = [r for r in ok if "box_at" in r]
    if at:
        print(
            "\nrtree box ratio / coverage at 91 and 364 elements (2D members without holes; goal >= 0.85 / <= 1.15)"
        )
        for r in at:
            for key, how in (("box_at", r.get("box_at_how", "cells")), ("box_at_cells", "cells")):
                if key not in r:
                    continue
                b = r[key]
                print(
                    f"  {r['mesh']:<14}{r['model']:<17}{how:<11} 91: {b['91'][0]:.2f} / {b['91'][1]:.2f}   "
                    f"364: {b['364'][0]:.2f} / {b['364'][1]:.2f}"
                )
        for model in dict.fromkeys(r["model"] for r in at):
            rs = [r for r in at if r["model"] == model]
            print(
                f"  worst {model}: BR {min(min(r['box_at']['91'][0], r['box_at']['364'][0]) for r in rs):.2f}, "
                f"coverage {max(max(r['box_at']['91'][1], r['box_at']['364'][1]) for r in rs):.2f}"
            )
    print("\nworst over the family:")
    for line in worst_cases(rows):
        print("  " + line)
    if a.json:
        with open(a.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1, default=float)


if __name__ == "__main__":
    main()

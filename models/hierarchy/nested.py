"""Nested agglomeration hierarchies (what multigrid users need): every level of a recursive mode,
each coarse element exactly a union of elements of the next finer level.

nested_levels() turns the labels a recursive bisection recorded after each level into exactly
nested partitions ending at the final agglomeration (whose elements may have been split into
connected pieces, merged fragments or cut holes): going from the finest level up, each finer
element joins the coarse part that holds most of its cells, then coarse parts are split into
connected pieces. A coarse element that would enclose a hole is replaced by its children.

write_hierarchy() writes one directory: level_L.vtu, level_L.labels.json (fine cell -> element),
level_L.parent.json (element of level L -> its element at level L-1, 0-based, L >= 1),
level_L.metrics.json, optionally level_L.lymph.json and .mat (2D), and hierarchy.json indexing them; level 0
is the coarsest, the last level the final result (same element numbering as the job's outputs).
"""

from __future__ import annotations

import json
import os

import numpy as np

from models.export import atomic
from models.hierarchy.coarse import coarse_graph, kway_apart  # noqa: F401  (coarse_graph re-exported)
from models.hierarchy.holes import (  # noqa: F401  (re-exported: tests and callers import them from here)
    _element_graph,
    _has_voids,
    _with_outside,
    _without_holes,
    cavity_elements,
    fix_holes,
)
from models.hierarchy.plan import (
    at_least,
    count_weighted,
    domain_plan,
    group_pieces,
    said_off_plan,
    with_asked,
    with_requested,
    without_stalled_top,
)
from models.hierarchy.rethread import coarse_end
from models.mesh.celldata import CellData, compact_labels
from models.mesh.container import Mesh


def _majority(child: np.ndarray, rec: np.ndarray) -> np.ndarray:
    """For each child id, the rec label holding most of its cells (ties: the smallest label)."""
    k = int(child.max()) + 1
    key = child.astype(np.int64) * (int(rec.max()) + 1) + rec
    uk, cnt = np.unique(key, return_counts=True)
    c = uk // (int(rec.max()) + 1)
    r = uk % (int(rec.max()) + 1)
    order = np.lexsort((r, -cnt, c))
    first = order[np.r_[True, c[order][1:] != c[order][:-1]]]
    out = np.zeros(k, dtype=np.int64)
    out[c[first]] = r[first]
    return out


def nested_levels(
    data: CellData, final: np.ndarray, recorded: list[np.ndarray], nodes: np.ndarray, mesh: Mesh | None = None
) -> list[np.ndarray]:
    """Exactly nested labels over all cells, coarsest first, the last one = `final`.

    recorded: labels over `nodes` after each recursion level (Agglomeration.levels, coarsest
    first); cells outside `nodes` (coarsen mode) are their own element on every level. With
    `mesh`, coarse elements that would enclose a hole are replaced by their children."""
    from models.partition.agglomerate import connected_parts

    n = final.size
    all_nodes = np.arange(n)
    levels = [compact_labels(np.asarray(final, dtype=np.int64))]
    outside = np.ones(n, dtype=bool)
    outside[nodes] = False
    for rec in reversed(recorded[:-1] if len(recorded) > 1 else []):
        finer = levels[0]
        full = np.empty(n, dtype=np.int64)
        full[nodes] = rec
        base = int(rec.max()) + 1 if rec.size else 0
        full[outside] = base + np.arange(int(outside.sum()))
        coarse = _majority(finer, full)[finer]
        coarse, _ = connected_parts(data, coarse, all_nodes)
        coarse = compact_labels(coarse)
        if mesh is not None:
            coarse = _without_holes(mesh, data, coarse, finer)
        if int(coarse.max()) + 1 == int(finer.max()) + 1:
            continue  # nothing merged on this level
        levels.insert(0, coarse)
    return levels


def parent_maps(levels: list[np.ndarray]) -> list[np.ndarray]:
    """For each level L >= 1: (elements of L,) -> its element at level L-1."""
    out = []
    for coarse, fine in zip(levels[:-1], levels[1:], strict=True):
        p = np.empty(int(fine.max()) + 1, dtype=np.int64)
        p[fine] = coarse
        out.append(p)
    return out


def is_nested(levels: list[np.ndarray]) -> bool:
    """True when every element of each level lies inside one element of the level above."""
    for coarse, fine in zip(levels[:-1], levels[1:], strict=True):
        p = np.full(int(fine.max()) + 1, -1, dtype=np.int64)
        p[fine] = coarse
        if not np.array_equal(p[fine], coarse):
            return False
    return True


def write_hierarchy(
    out_dir: str | os.PathLike,
    mesh: Mesh,
    data: CellData,
    levels: list[np.ndarray],
    metrics: bool = True,
    extra: dict | None = None,
    lymph: bool = False,
    boundary=None,
    boundary_tag: int = 1,
    operators: bool = True,
    merged: list | None = None,
    written: dict | None = None,
) -> dict:
    """Write every level (see the module docstring); returns the hierarchy.json index.
    lymph: also level_L.lymph.json (2D) with the lymph region/neighbor structs of each level;
    boundary: the fine mesh's boundary groups (models.mesh.boundary.fine_boundary), kept on every level;
    operators: also the aggregation operator into each level (write_operators). metrics=False still
    gives the partition statistics and the box measures (box ratio, coverage) of each level.
    merged: the polytopes models.polytope.merge.merge already made of each level (build_hierarchy's), not
    merged again. written: a dict given is filled with the levels as written ("levels": 3D elements
    are numbered by their vertex count, the order meshio reads back), their polytopes ("merged") and
    the level files of an earlier hierarchy in the folder that were removed ("removed":
    models.hierarchy.stale)."""
    from models.export.vtu import group_names_of, points_xml, write_vtu
    from models.mesh.boundary import output_cells
    from models.mesh.dropped import file_labels
    from models.polytope.merge import merge, sort_by_vertex_count

    names = group_names_of(mesh)
    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    g = data.graph
    polys = []
    if merged is not None and len(merged) != len(levels):
        merged = None
    for L, labels in enumerate(levels):
        poly = (
            merged[L]
            if merged is not None and merged[L] is not None
            else merge(mesh, g, labels, data.measures)[0]
        )
        poly = sort_by_vertex_count(poly)  # 3D: the element order meshio reads back; labels follow
        if boundary is not None:
            from models.mesh.boundary import annotate

            annotate(poly, boundary)
        polys.append(poly)
    levels = [np.asarray(p.labels, dtype=np.int64) for p in polys]
    if written is not None:
        written.update(levels=levels, merged=polys)
    parents = parent_maps(levels)
    nested = is_nested(levels)
    index = {
        "levels": [],
        "nested": nested,
        "cells": int(mesh.n_cells),
        "dim": int(mesh.dim),
        # a few bad cells the read left out (models.mesh.dropped.few_bad): each level's labels.json
        # has one entry per cell of the file, -1 for those (agglomerate's labels.json alike)
        **({"cells_left_out": mesh.meta["dropped_cells"]} if mesh.meta.get("dropped_cells") else {}),
        **(extra or {}),
    }
    if not metrics and nested:
        stats = level_statistics(mesh, g, levels, data.measures)  # all levels at once
    pts_xml = [None] * len(polys)  # the Points array, encoded once for the levels that share it
    for L, poly in enumerate(polys):
        same = next((j for j in range(L) if _same_points(polys[j], poly)), None)
        pts_xml[L] = points_xml(poly) if same is None else pts_xml[same]
    for L, (labels, poly) in enumerate(zip(levels, polys, strict=True)):
        entry = {
            "level": L,
            "elements": int(poly.n_elements),
            "mesh": f"level_{L}.vtu",
            "labels": f"level_{L}.labels.json",
        }
        cell_data = {}
        if metrics:
            from models.quality.report import metrics_report

            rep = metrics_report(poly, g.indptr, g.indices, fine_tags=mesh.tags)
            for name, vals in rep["per_element"].items():
                cell_data[name] = np.asarray(vals, dtype=np.float64)
            rep = {k: v for k, v in rep.items() if k != "per_element"}
        elif nested:
            rep = stats[L]
        else:
            from models.quality.partition_stats import partition_statistics
            from models.quality.report import box_measures
            from models.quality.summary import summarize

            bm = box_measures(mesh.points, mesh.offsets, mesh.connectivity, labels, data.measures)
            rep = {
                "elements": int(poly.n_elements),
                "dim": int(mesh.dim),
                "coverage": bm["coverage"],
                "summary": {"box_ratio": summarize(bm["box_ratio"])},
                "partition": partition_statistics(g.indptr, g.indices, labels),
            }
        _write_json(os.path.join(out_dir, f"level_{L}.metrics.json"), rep)
        entry["metrics"] = f"level_{L}.metrics.json"
        entry["normalized_cut"] = rep["partition"]["normalized_cut"]
        write_vtu(  # (with the fine mesh's boundary groups and the groups' names, as agglomerate's)
            os.path.join(out_dir, entry["mesh"]),
            poly,
            cell_data,
            boundary=None if boundary is None else output_cells(poly),
            group_names=names,
            points_xml=pts_xml[L],
        )
        _write_json(os.path.join(out_dir, entry["labels"]), file_labels(mesh.meta, labels))
        if L > 0:
            entry["parent"] = f"level_{L}.parent.json"
            _write_json(os.path.join(out_dir, entry["parent"]), parents[L - 1])
        if lymph and mesh.dim == 2:
            from models.export.lymph import lymph_structs, write_lymph_json, write_lymph_mat

            region, neighbor = lymph_structs(poly, boundary_tag=boundary_tag)
            entry["lymph"] = f"level_{L}.lymph.json"
            entry["lymph_mat"] = f"level_{L}.lymph.mat"
            write_lymph_json(os.path.join(out_dir, entry["lymph"]), region, neighbor)
            write_lymph_mat(os.path.join(out_dir, entry["lymph_mat"]), region, neighbor)
        index["levels"].append(entry)
    if operators:
        for entry, op in zip(index["levels"], write_operators(out_dir, levels, mesh.n_cells), strict=True):
            entry["aggregation"] = op
    _write_json(os.path.join(out_dir, "hierarchy.json"), index)
    from models.hierarchy.stale import remove_stale, written_names

    removed = remove_stale(out_dir, written_names(index["levels"]))  # (an earlier run's level files)
    if written is not None:
        written["removed"] = removed
    return index


def _same_points(a, b) -> bool:
    """Do two polytope meshes write the same Points array (the same points, the same 2D frame)?"""
    if a.dim != b.dim or not (a.points is b.points or np.array_equal(a.points, b.points)):
        return False
    if a.dim != 2 or (a.frame is None and b.frame is None):
        return True
    return a.frame is not None and b.frame is not None and np.array_equal(a.frame, b.frame)


def _components_count(indptr: np.ndarray, indices: np.ndarray, labels: np.ndarray) -> int:
    """Connected pieces of the parts `labels` of a symmetric CSR graph (edges inside a part only)."""
    from models.partition.rtree import _label_pieces  # compiled union-find where built, else scipy

    return int(_label_pieces(indptr, indices, np.asarray(labels, dtype=np.int64))[0]) if labels.size else 0


def level_statistics(mesh: Mesh, graph, levels: list[np.ndarray], measures: np.ndarray) -> list[dict]:
    """Per level of exactly nested `levels` (coarsest first), what write_hierarchy writes without
    --metrics: elements, coverage, box-ratio summary and the partition statistics, the same numbers
    as models.metrics.box_measures / partition_statistics level by level, batched: the boxes of a
    level are the union of its children's boxes, the undirected edge list is built once, and a
    level's connectedness is decided on the graph of the finer level's elements."""
    import scipy.sparse as sp

    from models.partition.rtree import _small_int, cell_boxes
    from models.quality.summary import summarize

    indptr, indices = np.asarray(graph.indptr, dtype=np.int64), np.asarray(graph.indices, dtype=np.int64)
    n = indptr.size - 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    # each undirected edge once (duplicates and self loops merged away, as partition_statistics does)
    upper = rows < indices
    later = np.r_[False, (indices[1:] > indices[:-1]) | (rows[1:] != rows[:-1])]  # sorted, no repeats
    if 2 * int(upper.sum()) == indices.size and bool(later[1:][rows[1:] == rows[:-1]].all()):
        a, b = rows[upper], indices[upper]  # a canonical symmetric CSR (the dual graph's): as it is
    else:
        off = rows != indices
        up = sp.csr_matrix(
            (
                np.ones(int(off.sum()), dtype=bool),
                (np.minimum(rows, indices)[off], np.maximum(rows, indices)[off]),
            ),
            shape=(n, n),
        )
        a = np.repeat(np.arange(n), np.diff(up.indptr))
        b = up.indices.astype(np.int64)
    deg = (np.bincount(a, minlength=n) + np.bincount(b, minlength=n)).astype(np.float64)
    absm = np.abs(np.asarray(measures, dtype=np.float64))
    lo, hi = cell_boxes(mesh.points, mesh.offsets, mesh.connectivity)
    out: list[dict] = [None] * len(levels)
    q_ptr, q_ind = indptr, indices  # graph of the finer nodes: cells, then the finer level's elements
    ea, eb, ec = a, b, None  # its undirected edges, each once, with their number of fine edges (None: 1)
    node_vol, node_n = deg, np.ones(n)  # fine degrees and cells summed over each finer node
    connected_below = True
    for L in range(len(levels) - 1, -1, -1):
        lab = np.asarray(levels[L], dtype=np.int64)
        k = int(lab.max()) + 1
        if L < len(levels) - 1:  # element of this level of each element of the finer level
            node_to = np.zeros(int(levels[L + 1].max()) + 1, dtype=np.int64)
            node_to[levels[L + 1]] = lab
        else:
            node_to = lab
        order = np.argsort(_small_int(node_to, k), kind="stable")  # a radix sort up to 16 bits
        starts = np.flatnonzero(np.r_[True, node_to[order][1:] != node_to[order][:-1]])
        lo = np.minimum.reduceat(lo[order], starts, axis=0)
        hi = np.maximum.reduceat(hi[order], starts, axis=0)
        box = np.prod(hi - lo, axis=1)
        m = np.bincount(lab, weights=absm, minlength=k)
        with np.errstate(divide="ignore", invalid="ignore"):
            br = np.clip(np.where(box > 0, m / np.where(box > 0, box, 1.0), 0.0), 0.0, 1.0)
        total = float(m.sum())
        cov = float(box.sum() / total) if total > 0 else float("nan")
        # partition statistics: the fine edges cut by this level are the finer nodes' edges it cuts
        ua, ub = node_to[ea], node_to[eb]
        cut_mask = ua != ub
        ua, ub = ua[cut_mask], ub[cut_mask]
        c = None if ec is None else ec[cut_mask]
        cut_i = np.bincount(ua, weights=c, minlength=k) + np.bincount(ub, weights=c, minlength=k)
        n_cut = int(cut_mask.sum()) if c is None else int(c.sum())
        node_vol = np.bincount(node_to, weights=node_vol, minlength=k)  # sums of integers: exact
        node_n = np.bincount(node_to, weights=node_n, minlength=k)
        with np.errstate(divide="ignore", invalid="ignore"):
            ncut = float(np.where(node_vol > 0, cut_i / np.where(node_vol > 0, node_vol, 1), 0.0).sum())
        # connected: every element's finer nodes connected through the finer level's element graph
        if connected_below:  # the finer level's elements are connected: their graph decides
            connected_below = _components_count(q_ptr, q_ind, node_to) == k
            connected = connected_below
        else:
            connected = _components_count(indptr, indices, lab) == k
        out[L] = {
            "elements": k,
            "dim": int(mesh.dim),
            "coverage": cov,
            "summary": {"box_ratio": summarize(br)},
            "partition": {
                "cut": n_cut,
                "normalized_cut": ncut,
                "volume_imbalance": float(node_n.max() / node_n.mean()) if k else 0.0,
                "parts": k,
                "connected": bool(connected),
            },
        }
        if L == 0:
            break
        # the undirected edges of this level's elements (with multiplicities), for the next (coarser) level
        key = np.minimum(ua, ub) * np.int64(k) + np.maximum(ua, ub)
        uniq, inv = np.unique(key, return_inverse=True)
        ec = np.bincount(inv, weights=c, minlength=uniq.size).astype(np.int64)
        ea, eb = uniq // k, uniq % k
        qm = sp.csr_matrix(
            (np.ones(2 * uniq.size, dtype=np.int8), (np.r_[ea, eb], np.r_[eb, ea])), shape=(k, k)
        )
        q_ptr, q_ind = qm.indptr.astype(np.int64), qm.indices.astype(np.int64)
    return out


def aggregation_operators(levels: list[np.ndarray], n_cells: int | None = None) -> list:
    """The aggregation operator into each level, coarsest first: P_L (rows x elements of level L), a
    single 1 per row, rows = the elements of level L+1, or the fine cells for the finest level.
    In multigrid order (fine to coarse) they are reversed(...): what pyamg's predefined
    aggregation takes (`AggOp`)."""
    import scipy.sparse as sp

    ops = []
    for L, labels in enumerate(levels):
        if L + 1 < len(levels):
            p = parent_maps(levels[L : L + 2])[0]  # elements of L+1 -> element of L
        else:
            p = np.asarray(labels, dtype=np.int64)
        k = int(labels.max()) + 1
        ops.append(sp.csr_matrix((np.ones(p.size), (np.arange(p.size), p)), shape=(p.size, k)))
    return ops


def write_operators(out_dir: str, levels: list[np.ndarray], n_cells: int) -> list[dict]:
    """level_L.agg.npz (scipy.sparse.save_npz) and level_L.agg.mtx (MatrixMarket, for Matlab's
    mmread) per level; returns their hierarchy.json entries."""
    import scipy.sparse as sp

    out = []
    for L, P in enumerate(aggregation_operators(levels, n_cells)):
        npz, mtx = f"level_{L}.agg.npz", f"level_{L}.agg.mtx"
        sp.save_npz(os.path.join(out_dir, npz), P, compressed=False)  # zlib took 0.1 s of 5 levels of 92k
        rows = "fine cells" if L + 1 == len(levels) else f"elements of level {L + 1}"
        _write_mtx(
            os.path.join(out_dir, mtx), P.indices, P.shape[1], f" aggregation into level {L}: rows = {rows}"
        )
        out.append(
            {
                "npz": npz,
                "mtx": mtx,
                "rows": "cells" if L + 1 == len(levels) else f"level_{L + 1}",
                "shape": [int(P.shape[0]), int(P.shape[1])],
            }
        )
    return out


# The default per-level ratios (finest step first, the last repeated) by the mesh's dimension: the
# finest step near the size of pyamg's finest aggregates, the coarser steps larger, as pyamg's are
# (issue 24, round three: measured on the whole family, docs/hierarchy.md); 2D coarser steps of 8
# since round nine (under the finest aggregation: smoothed iterations against pyamg's, worst 2D
# member 1.00 -> 0.91, at complexity 1.00 -> 1.07; in 3D 8 gains no iteration, costs 1.08-1.15)
SCHEDULE = {2: (5.0, 8.0), 3: (8.0, 16.0)}


# the finest levels that are aggregates of the cells (model_options["finest"]; "cuts" is the other)
AGGREGATED = ("aggregation", "pyamg", "luby", "quality", "nested")


def default_ratio(dim: int) -> tuple[float, ...]:
    """The per-level ratio schedule `magnet hierarchy` uses without --ratio (finest step first)."""
    return SCHEDULE[3 if int(dim) >= 3 else 2]


def build_hierarchy(
    mesh: Mesh,
    data: CellData,
    model: str = "rtree",
    ratio=None,
    coarsest: int = 10,
    seed: int = 0,
    groups: bool = False,
    model_options: dict | None = None,
    finest: np.ndarray | None = None,
    kappa: np.ndarray | None = None,
) -> tuple[list[np.ndarray], dict]:
    """Exactly nested levels (coarsest first) with about `ratio` times fewer elements per level, from
    n_cells / ratio down to at most `coarsest` elements; every element connected.
    ratio: a number (every level), a schedule (finest step first, the last repeated: (5, 8) makes
    n / 5 elements, then 8 times fewer per level), or None: default_ratio(mesh.dim).

    rtree: natively (models.partition.rtree.rtree_levels). Models with a k-way mode (metis,
    kmeans): the agglomerates are agglomerated (k-way on each level's coarse dual graph, pieces
    then joined to a neighbour so counts stay exact). Bisection-only models (sage-base, ...): one
    recursive bisection, recorded, and the levels nearest the wanted counts.
    groups: no element crosses a physical group (rtree and the k-way models).
    kappa: the diagonal of the diffusion tensor K the levels are for (rtree only): the cuts are made in
    the metric of the operator's couplings, x -> K^(-1/2) x, where the TPFA transmissibilities
    |f| d^T K d / |d|^3 are isotropic: parts are cut across weak couplings and stretched along strong
    ones (sqrt(kx / ky) times longer along x than along y). Returns (levels, info); info["merged"]
    holds each level's polytopes (pass them to write_hierarchy as `merged`).
    finest: (cells,) labels of an agglomeration already made (a job's k elements): it is the finest
    level, and the coarser ones agglomerate its elements by `ratio` (k-way on each level's coarse
    dual graph; metis for models without a k-way mode)."""
    import time

    from models.errors import ParameterError
    from models.partition import get_partitioner
    from models.partition.rtree import cell_boxes, level_counts, make_connected, rtree_levels

    t0 = time.perf_counter()
    n = mesh.n_cells
    default = ratio is None
    model_options = dict(model_options or {})
    boxfit = bool(model_options.pop("boxfit", False))  # models.hierarchy.boxfit after the levels
    rings = bool(model_options.pop("rings", True))  # 3D: rings around a tunnel or a neighbour cut
    if not rings and mesh.dim == 2:
        raise ParameterError(
            "keeping rings (--keep-rings) is for 3D meshes, whose elements may go around a tunnel; a 2D "
            "element never encloses a hole"
        )
    if ratio is None:
        ratio = default_ratio(mesh.dim)
    asked_ratio = ratio  # (the aggregated finest levels give back the ratios they made)
    if finest is not None:
        return _hierarchy_above(
            data, np.asarray(finest, dtype=np.int64), mesh, model, ratio, coarsest, seed, t0
        )
    opts_in = dict(model_options or {})
    finest_mode = opts_in.pop("finest", None)
    if finest_mode is not None and finest_mode not in ("cuts", *AGGREGATED):
        raise ParameterError(
            f"finest must be aggregation, nested, pyamg, luby, quality or cuts, got {finest_mode!r}"
        )
    # finest="aggregation" (the default for rtree with the default schedule and no kappa; issue 24,
    # rounds five and six): the finest level a standard aggregation of the cells' graph by pyamg's
    # compiled pass, rtree cuts above (worst it 1.00 / 1.00 at complexity 1.04, build under one METIS
    # call); "cuts": rtree cuts at every level (the default before, and with --ratio or kappa, where
    # the finest step is not the aggregation's own); "pyamg": pyamg's own join; "luby": round five;
    # "nested" (round eight): cuts of the cells above, the finest level pyamg's aggregation inside
    # each element of the level above it
    if finest_mode is None:
        finest_mode = "aggregation" if model == "rtree" and default and kappa is None else "cuts"
    agg_mode = finest_mode in AGGREGATED
    if agg_mode and (not default or kappa is not None):
        raise ParameterError("an aggregated finest level goes with the default ratio schedule and no kappa")
    if agg_mode and model != "rtree":
        raise ParameterError("an aggregated finest level: model rtree only")
    hole_pairs, least, why, stretch = domain_plan(mesh, data)
    notes: list[str] = []
    counts = level_counts(n, ratio, coarsest, stretch=stretch)
    if not counts:
        raise ParameterError(
            f"the mesh has {n:,} cell{'s' if n != 1 else ''}: nothing to coarsen with coarsest = {coarsest}"
        )
    if groups and mesh.tags is None:
        raise ParameterError("respecting physical groups needs a mesh with physical groups")
    if groups and model != "rtree" and not get_partitioner(model, seed=seed).supports_kway:
        raise ParameterError(
            f"physical groups in a hierarchy: model {model} cuts by bisection only; use rtree, metis or kmeans"
        )
    # each cell's physical group where no element may cross one (--groups), compact
    group_of = np.unique(mesh.tags, return_inverse=True)[1].reshape(-1).astype(np.int64) if groups else None
    if groups:
        least, why = group_pieces(data, group_of, least, why, mesh)
    asked = counts[0] if len(counts) else 1
    # planned down to the fewest elements the domain allows where --coarsest asks for fewer (3 rings
    # apart, 6 at least, --coarsest 1: 6 > 8 > 51 planned, a step of 1.33x; planned to 6: 6 > 43 > 310)
    floor = max(int(coarsest), int(least))
    if least > 1 and (model != "rtree" or least > coarsest):  # (rtree's aggregated paths: below)
        # planned with the fewest coarsest elements the domain needs (a hole: 2), not raised to them
        # afterwards (METIS on a gear: 2 > 18 > 249 > 3391, a last step 44% off; planned: 10 > 184 > 3391)
        counts = level_counts(n, ratio, floor, stretch=stretch, least=least) or counts
    counts = at_least(counts, least)
    if kappa is not None:
        kappa = np.asarray(kappa, dtype=np.float64).ravel()
        if model != "rtree":
            raise ParameterError("levels cut for a diffusion tensor (kappa): model rtree only")
        if kappa.size != data.centroids.shape[1] or not np.all(np.isfinite(kappa)) or not np.all(kappa > 0):
            raise ParameterError(
                f"kappa must be {data.centroids.shape[1]} positive numbers, one per axis of the mesh"
            )
    if model == "rtree":
        from models.graph.batch import GraphBatch

        G = data.graph  # the whole mesh as one graph: make_batch's batch of one label, without its sort
        cen = data.centroids
        boxes = cell_boxes(data.points, data.offsets, data.connectivity)
        if kappa is not None:  # the operator's metric: K^(-1/2) x (a positive scaling: same orders)
            s = 1.0 / np.sqrt(kappa)
            cen = cen * s
            boxes = (boxes[0] * s, boxes[1] * s)
        batch = GraphBatch(
            indptr=G.indptr,
            indices=G.indices,
            weights=G.weights,
            graph_ptr=np.array([0, n], dtype=np.int64),
            centroids=cen,
            measures=data.measures,
            tags=data.tags,
            node_ids=np.arange(n),
        )
        batch.cell_boxes = boxes
        tags = group_of
        # count-weighted cuts: an element's size follows the local cell size, so elements hold
        # comparable numbers of cells as algebraic aggregates do (issue 24: on the family, smoothed
        # PCG iterations vs pyamg worst case 4.20x (graded 100:1) with measure-weighted cuts, 1.26x
        # with count-weighted; the same levels on uniform meshes); model_options may ask "measure"
        opts = {
            "boxes": batch.cell_boxes,
            "balance": "cells",
            # cut axis and position by the least crossing TPFA transmissibility (issue 24 round four:
            # layer-50 21 -> 17 iterations vs pyamg's 19, the 2D worst case 1.11 -> 1.09; numpy path);
            # with kappa the box cuts in the K metric (a 16:1 grid: 18 iterations, min cut 26)
            "axes": "strength-mincut" if kappa is None else "box",
            **opts_in,
        }  # the tight cuts, as the flat modes make them
        if (
            str(opts.get("axes", "")).startswith("strength") and opts.get("coupling") is None
        ):  # TPFA with K, true coordinates
            from models.partition.rtree_strength import tpfa_coupling

            opts["coupling"] = tpfa_coupling(G.indptr, G.indices, G.weights, data.centroids, kappa)
        graphs = []  # the graphs of the levels' elements, for the cavity check
        from models.hierarchy.finest import aggregated_levels, aggregation_in_cuts

        if finest_mode == "nested":
            levels, counts, level_graphs, ratio = aggregation_in_cuts(
                mesh,
                data,
                batch,
                tags,
                ratio[-1] if np.ndim(ratio) else ratio,
                floor,
                opts,
                least=least,
                stretch=stretch,
            )
            how = "native: rtree cuts of the cells, the finest level by standard aggregation inside them"
        elif agg_mode:
            levels, counts, level_graphs, ratio = aggregated_levels(
                mesh,
                data,
                tags,
                ratio[-1] if np.ndim(ratio) else ratio,
                floor,
                opts,
                finest_mode,
                least=least,
                stretch=stretch,
            )
            how = "native: finest level by standard aggregation of the cells' graph, rtree cuts above"
        else:
            levels = rtree_levels(batch, counts, groups=tags, graphs=graphs, **opts)
            level_graphs = {len(levels) - 1 - j: q for j, q in enumerate(graphs)}
            how = "native"
    else:
        from models.partition.agglomerate import agglomerate

        part = get_partitioner(model, seed=seed, **count_weighted(model, opts_in))  # (finest: ours)
        if part.supports_kway and group_of is not None:  # each piece of a group its share, apart
            levels = [np.arange(n)]
            for c in reversed(counts):
                cg = coarse_graph(data, levels[0])
                at = np.zeros(cg.n_nodes, dtype=np.int64)
                at[levels[0]] = group_of
                levels.insert(0, kway_apart(part, cg, int(c), at)[levels[0]])
            levels.pop()
            how = "agglomerates agglomerated (k-way on each coarse dual graph), each piece of a group apart"
        elif part.supports_kway:
            fine = agglomerate(mesh, data, model=part, mode="kway", k=counts[-1], seed=seed).labels
            levels = [fine]
            for c in reversed(counts[:-1]):
                cg = coarse_graph(data, levels[0])
                raw = np.asarray(part.kway(cg, int(c)), dtype=np.int64)
                raw, _ = make_connected(
                    cg.indptr, cg.indices, cg.weights, compact_labels(raw), measures=cg.measures
                )
                levels.insert(0, compact_labels(raw)[levels[0]])
            how = "agglomerates agglomerated (k-way on each coarse dual graph)"
        else:
            depth = max(1, int(round(np.log2(max(counts[-1], 2)))))
            agg = agglomerate(
                mesh,
                data,
                model=part,
                mode="nref",
                nref=min(depth, int(np.log2(n))),
                seed=seed,
                record_levels=True,
            )
            cand = nested_levels(data, agg.labels, agg.levels, agg.nodes)
            sizes = np.array([int(c.max()) + 1 for c in cand])
            pick = sorted({int(np.argmin(np.abs(np.log(sizes) - np.log(c)))) for c in counts})
            levels = [cand[i] for i in pick]
            how = "top-down recursive bisection, recorded"
    levels = [np.asarray(lv, dtype=np.int64) for lv in levels]
    if boxfit:  # boundary units moved towards tighter boxes; the elements' graphs change
        from models.hierarchy.boxfit import boxfit_levels

        lo, hi = cell_boxes(data.points, data.offsets, data.connectivity)
        levels = boxfit_levels(levels, lo, hi, data.measures, data.graph.indptr, data.graph.indices)
    known = level_graphs if model == "rtree" and not boxfit else None
    # 3D rings (elements with a handle) cut on every model and domain unless rings=false: 2.6-3.7% of
    # the elements of levels 1-2 at 10^5 cells without (docs/hierarchy.md, round fifteen)
    levels, polys, report = fix_holes(
        mesh,
        data,
        levels,
        known,
        hole_pairs=hole_pairs,
        rings=rings,
        groups=group_of,
    )
    levels, polys, report = coarse_end(mesh, data, levels, polys, report, hole_pairs, counts, group_of)
    levels, polys, report, counts = without_stalled_top(levels, polys, report, list(counts), notes)
    report = with_asked(with_requested(report, counts, n), asked_ratio, not agg_mode, not agg_mode)
    step = ratio[-1] if np.ndim(ratio) else ratio
    said_off_plan(levels, report, coarsest, notes, (mesh, data.graph, rings), least, why, asked, step)
    info = {
        "model": model,
        "finest": finest_mode,
        "boxfit": boxfit,
        "ratio": float(ratio) if np.ndim(ratio) == 0 else [float(r) for r in ratio],
        "coarsest": int(coarsest),
        "stretch": float(stretch),
        "kappa": None if kappa is None else [float(v) for v in kappa],
        "requested": counts,
        "method": how,
        "build_time": time.perf_counter() - t0,
        "merged": polys,
        "report": report,
        "notes": notes,
    }
    return levels, info


def _hierarchy_above(data, finest, mesh, model, ratio, coarsest, seed, t0):
    """build_hierarchy(..., finest=labels): the given agglomeration and coarser levels above it."""
    import time

    from models.partition import get_partitioner
    from models.partition.rtree import level_counts, make_connected

    hole_pairs, least, why, stretch = domain_plan(mesh, data)
    notes: list[str] = []
    counts = level_counts(int(finest.max()) + 1, ratio, coarsest, stretch=stretch)
    asked = counts[0] if len(counts) else 1
    if least > coarsest:  # (planned down to the fewest the domain allows, as build_hierarchy does)
        counts = level_counts(int(finest.max()) + 1, ratio, least, stretch=stretch, least=least) or counts
    counts = at_least(counts, least)
    part = get_partitioner(model, seed=seed, **count_weighted(model, None))
    if not part.supports_kway:
        part = get_partitioner("metis", seed=seed, **count_weighted("metis", None))
    levels = [finest]
    for c in reversed(counts):
        cg = coarse_graph(data, levels[0])
        raw = np.asarray(part.kway(cg, int(c)), dtype=np.int64)
        raw, _ = make_connected(cg.indptr, cg.indices, cg.weights, compact_labels(raw), measures=cg.measures)
        levels.insert(0, compact_labels(raw)[levels[0]])
    levels, polys, report = fix_holes(mesh, data, levels, None, hole_pairs=hole_pairs, rings=True)
    plan = [*counts, int(finest.max()) + 1]
    levels, polys, report = coarse_end(mesh, data, levels, polys, report, hole_pairs, plan, None)
    levels, polys, report, plan = without_stalled_top(levels, polys, report, plan, notes)
    report = with_asked(with_requested(report, plan, finest.size), ratio, finest=False)
    step = ratio[-1] if np.ndim(ratio) else ratio
    said_off_plan(levels, report, coarsest, notes, (mesh, data.graph, True), least, why, asked, step)
    info = {
        "model": part.name,
        "ratio": float(ratio) if np.ndim(ratio) == 0 else [float(r) for r in ratio],
        "coarsest": int(coarsest),
        "stretch": float(stretch),
        "kappa": None,
        "requested": plan,
        "method": "the job's agglomeration as the finest level, its elements agglomerated (k-way on each coarse dual graph)",
        "build_time": time.perf_counter() - t0,
        "merged": polys,
        "report": report,
        "notes": notes,
    }
    return levels, info


_TRIPLES = None  # (3000,) three-character codes: 0..999 blank-led ("  0" for 0), zero-padded, blank-led ("   " for 0)


def _digits(v: np.ndarray, width: int) -> np.ndarray:
    """(N, width) ASCII codes of the non-negative integers v, right-aligned with blanks: three digits
    at a time from a table, the block holding a number's leading digit (and blocks above it) from the
    table with leading blanks, the blocks below it zero-padded (no pass to blank leading zeros)."""
    global _TRIPLES
    if _TRIPLES is None:
        text = "".join(f"{i:3d}" for i in range(1000)) + "".join(f"{i:03d}" for i in range(1000))
        text += "   " + "".join(f"{i:3d}" for i in range(1, 1000))
        _TRIPLES = np.frombuffer(text.encode("ascii"), np.uint8).view("V3")
    v = np.asarray(v, dtype=np.int64)
    nb = -(-width // 3)
    chars = np.empty((v.size, nb), dtype="V3")
    rest = v
    for j in range(nb - 1, -1, -1):  # a loop over blocks of three digits, lowest first
        rest, blk = np.divmod(rest, 1000)
        # digits above this block: zero-padded; none: blank-led (the lowest block writes 0 as "  0")
        blk += np.where(rest > 0, 1000, 0 if j == nb - 1 else 2000)
        chars[:, j] = _TRIPLES[blk]
    return chars.view(np.uint8).reshape(v.size, 3 * nb)[:, 3 * nb - width :]


def _int_list_json(values: np.ndarray) -> str:
    """A JSON list of non-negative integers, written vectorized: every number right-aligned in a
    fixed width (JSON allows the blanks), so json.loads gives the same list as json.dumps'."""
    v = np.asarray(values, dtype=np.int64).ravel()
    if v.size == 0 or v.min() < 0:
        return json.dumps(v.tolist())
    chars = np.concatenate(
        [_digits(v, len(str(int(v.max())))), np.full((v.size, 1), ord(","), np.uint8)], axis=1
    )
    chars[-1, -1] = ord("]")
    return "[" + chars.tobytes().decode("ascii")


def _write_mtx(path: str, cols: np.ndarray, k: int, comment: str) -> None:
    """MatrixMarket coordinate integer file of the (rows x k) matrix with a single 1 in row i at
    column cols[i] (an aggregation operator), written vectorized (scipy's and Matlab's mmread read it)."""
    cols = np.asarray(cols, dtype=np.int64)
    n = cols.size
    head = f"%%MatrixMarket matrix coordinate integer general\n%{comment}\n{n} {k} {n}\n"
    if n:
        i = _digits(np.arange(1, n + 1), len(str(n)))
        j = _digits(cols + 1, len(str(int(cols.max()) + 1)))
        sep = np.full((n, 1), ord(" "), np.uint8)
        body = np.concatenate(
            [i, sep, j, sep, np.full((n, 1), ord("1"), np.uint8), np.full((n, 1), ord("\n"), np.uint8)],
            axis=1,
        ).tobytes()
    else:
        body = b""
    atomic.write_bytes(path, head.encode("ascii") + body)


def _write_json(path: str, obj) -> None:
    if isinstance(obj, np.ndarray):
        text = _int_list_json(obj)
    else:
        text = json.dumps(
            obj, indent=None if isinstance(obj, list) else 1
        )  # dumps: the C encoder (dump is pure Python)
    atomic.write_text(path, text)

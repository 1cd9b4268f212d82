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

from .agglomerate import CellData, compact_labels, connected_parts
from .mesh import Mesh


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


def nested_levels(data: CellData, final: np.ndarray, recorded: list[np.ndarray], nodes: np.ndarray,
                  mesh: Mesh | None = None) -> list[np.ndarray]:
    """Exactly nested labels over all cells, coarsest first, the last one = `final`.

    recorded: labels over `nodes` after each recursion level (Agglomeration.levels, coarsest
    first); cells outside `nodes` (coarsen mode) are their own element on every level. With
    `mesh`, coarse elements that would enclose a hole are replaced by their children."""
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


def _without_holes(mesh: Mesh, data: CellData, coarse: np.ndarray, finer: np.ndarray) -> np.ndarray:
    """Replace every coarse element that encloses a hole (or a cavity) by its children."""
    from .merge import merge

    for _ in range(int(coarse.max()) + 2):
        _, holes = merge(mesh, data.graph, coarse, data.measures)
        bad = np.unique(holes.elements)
        if bad.size == 0:
            return coarse
        is_bad = np.zeros(int(coarse.max()) + 1, dtype=bool)
        is_bad[bad] = True
        sel = is_bad[coarse]
        coarse = coarse.copy()
        coarse[sel] = int(coarse.max()) + 1 + finer[sel]
        coarse = compact_labels(coarse)
    return coarse


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


def write_hierarchy(out_dir: str | os.PathLike, mesh: Mesh, data: CellData, levels: list[np.ndarray],
                    metrics: bool = True, extra: dict | None = None, lymph: bool = False, boundary=None,
                    boundary_tag: int = 1) -> dict:
    """Write every level (see the module docstring); returns the hierarchy.json index.
    lymph: also level_L.lymph.json (2D) with the lymph region/neighbor structs of each level;
    boundary: the fine mesh's boundary groups (models.boundary.fine_boundary), kept on every level."""
    from .merge import merge, sort_by_vertex_count
    from .metrics import metrics_report, partition_statistics
    from .vtu import write_vtu

    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    g = data.graph
    polys = []
    for labels in levels:
        poly, _ = merge(mesh, g, labels, data.measures)
        poly = sort_by_vertex_count(poly)  # 3D: the element order meshio reads back; labels follow
        if boundary is not None:
            from .boundary import annotate

            annotate(poly, boundary)
        polys.append(poly)
    levels = [np.asarray(p.labels, dtype=np.int64) for p in polys]
    parents = parent_maps(levels)
    index = {"levels": [], "nested": is_nested(levels), "cells": int(mesh.n_cells), "dim": int(mesh.dim),
             **(extra or {})}
    for L, (labels, poly) in enumerate(zip(levels, polys, strict=True)):
        entry = {"level": L, "elements": int(poly.n_elements), "mesh": f"level_{L}.vtu",
                 "labels": f"level_{L}.labels.json"}
        cell_data = {}
        if metrics:
            rep = metrics_report(poly, g.indptr, g.indices, fine_tags=mesh.tags)
            for name, vals in rep["per_element"].items():
                cell_data[name] = np.asarray(vals, dtype=np.float64)
            rep = {k: v for k, v in rep.items() if k != "per_element"}
        else:
            rep = {"partition": partition_statistics(g.indptr, g.indices, labels)}
        _write_json(os.path.join(out_dir, f"level_{L}.metrics.json"), rep)
        entry["metrics"] = f"level_{L}.metrics.json"
        entry["normalized_cut"] = rep["partition"]["normalized_cut"]
        write_vtu(os.path.join(out_dir, entry["mesh"]), poly, cell_data)
        _write_json(os.path.join(out_dir, entry["labels"]), labels.tolist())
        if L > 0:
            entry["parent"] = f"level_{L}.parent.json"
            _write_json(os.path.join(out_dir, entry["parent"]), parents[L - 1].tolist())
        if lymph and mesh.dim == 2:
            from .lymph import lymph_structs, write_lymph_json, write_lymph_mat

            region, neighbor = lymph_structs(poly, boundary_tag=boundary_tag)
            entry["lymph"] = f"level_{L}.lymph.json"
            entry["lymph_mat"] = f"level_{L}.lymph.mat"
            write_lymph_json(os.path.join(out_dir, entry["lymph"]), region, neighbor)
            write_lymph_mat(os.path.join(out_dir, entry["lymph_mat"]), region, neighbor)
        index["levels"].append(entry)
    _write_json(os.path.join(out_dir, "hierarchy.json"), index)
    return index


def _write_json(path: str, obj) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=None if isinstance(obj, list) else 1)
    os.replace(tmp, path)

"""`magnet check`: what a mesh holds and what is wrong with it, with a verdict.

The report is a plain dict (JSON as it is): cells by type, dimension, connected pieces, boundary
loops (2D) or shells (3D) and holes, the orientation fixes the reader made, folded cells,
duplicate and unused points, pinch vertices, non-conforming (hanging) nodes, lower-dimensional
cells that are no facet of any cell, physical and boundary groups. Each finding is an `issue`
{kind, severity, count, ids, message}; severity "warning" means the mesh agglomerates but the user
should know, "error" that it cannot be agglomerated as it is. The verdict is "ok", "warnings" or
"error". Everything is vectorized over cells; only the findings are Python lists.
"""

from __future__ import annotations

import os
import re
from itertools import chain, islice

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from models.errors import MagnetError, MeshError, id_list
from models.mesh.container import Mesh

N_IDS = 10  # ids listed per finding


def check_file(path: str | os.PathLike, physical_tag: str | None = None, weld: float | None = None) -> dict:
    """Read `path` and report on it; a mesh that cannot be read gets the reader's message and verdict 'error'."""
    from models.mesh.sandbox import read_mesh_safe

    try:
        mesh = read_mesh_safe(path, physical_tag=physical_tag, weld=weld)
    except MagnetError as exc:
        from models.mesh.fill import open_surface_refusal

        return {
            "file": os.path.basename(os.fspath(path)),
            "verdict": "error",
            "issues": [_issue("unreadable", "error", 1, [], str(open_surface_refusal(path, exc)))],
        }
    report = named(mesh_report(mesh), path)
    report["file"] = os.path.basename(os.fspath(path))
    return report


def named(report: dict, path) -> dict:
    """The report's errors found after reading (not a manifold, a cell with a face twice) worded as
    every refusal is: naming the file and the format (sandbox.wording), in place."""
    from models.mesh.sandbox import wording

    name = os.path.basename(os.fspath(path))
    for issue in report.get("issues", []):
        if issue["severity"] == "error" and name not in issue["message"]:
            issue["message"] = wording(issue["message"], path)
    return report


def _issue(kind: str, severity: str, count: int, ids, message: str) -> dict:
    return {
        "kind": kind,
        "severity": severity,
        "count": int(count),
        "ids": [int(i) for i in islice(ids, N_IDS)],  # not list(ids): that boxes every id first
        "message": message,
    }


def mesh_report(mesh: Mesh, graph=None) -> dict:
    """The report of a mesh the reader accepted (`graph`: its dual graph, when already built)."""
    from models.mesh.dual import dual_graph

    issues: list[dict] = []
    o = mesh.meta.get("orientation", {})
    rep: dict = {
        "dim": mesh.dim,
        "cells": mesh.n_cells,
        "cell_types": mesh.cell_type_counts(),
        "points": mesh.n_points,
        "physical_groups": mesh.physical_groups(),
        "group_names": {int(k): str(v) for k, v in (mesh.meta.get("group_names") or {}).items()},
        "orientation": {"flipped": int(o.get("flipped", 0)), "folded": int(o.get("folded", 0))},
    }
    if mesh.meta.get("welded"):
        rep["welded_points"] = int(mesh.meta["welded"])
    if mesh.meta.get("collapsed"):
        rep["collapsed_repeated_vertices"] = int(mesh.meta["collapsed"])
    if o.get("folded"):
        issues.append(
            _issue(
                "folded",
                "warning",
                o["folded"],
                o.get("folded_cells", []),
                f"{o['folded']} cells are folded over (negative {'area' if mesh.dim == 2 else 'volume'} "
                "once oriented like their neighbours); they are kept, their elements stay closed",
            )
        )
    if graph is None:
        try:
            graph = dual_graph(mesh, measures=False)  # the topology is all the report needs
        except MeshError as exc:
            issues.append(_issue("non-manifold", "error", 1, [], str(exc)))
            return _finish(rep, issues)
    used = np.zeros(mesh.n_points, dtype=bool)
    used[mesh.connectivity] = True
    unused = np.flatnonzero(~used)
    rep["unused_points"] = int(unused.size)
    from models.mesh.dropped import dropped_sentence

    left_out = dropped_sentence(mesh.meta)
    if left_out:  # a few bad cells among many: left out, the rest read (non-negotiable 3)
        ids = mesh.meta["dropped_cells"]["ids_all"]
        issues.append(_issue("cells-left-out", "warning", len(ids), [], left_out))
    collapsed = mesh.meta.get("collapsed_hexahedra") or {}
    if collapsed:  # bricks with repeated nodes, read as the cells they are
        n = sum(collapsed.values())
        kinds = ", ".join(f"{v:,} {k}" for k, v in sorted(collapsed.items()))
        issues.append(
            _issue(
                "collapsed-hexahedra",
                "info",
                n,
                [],
                f"{n:,} hexahedra with repeated nodes read as the cells they are ({kinds})",
            )
        )
    if mesh.meta.get("overlong_cells"):  # cell types and node counts disagree: said, read as VTK draws them
        long = mesh.meta["overlong_cells"]
        issues.append(_issue("overlong-cells", "warning", int(long["count"]), [], str(long["message"])))
    from models.mesh.dropped import ignored_lower_sentence

    ignored = ignored_lower_sentence(mesh.meta, mesh.dim)
    if ignored:  # lines and points of a volume mesh: read, counted, said, not used
        heads = re.findall(r"(?:^|; )([\d,]+) (?:empty cell|cells of lower)", ignored)
        count = sum(int(x.replace(",", "")) for x in heads)
        issues.append(_issue("ignored-lower-cells", "info", count, [], ignored))
    if mesh.meta.get("overlapping_groups"):  # gmsh cells in two physical groups: one each
        issues.append(_issue("overlapping-groups", "info", 1, [], str(mesh.meta["overlapping_groups"])))
    if mesh.meta.get("open_polyhedra"):  # a face missing from a polyhedron's list
        op = mesh.meta["open_polyhedra"]
        issues.append(_issue("open-polyhedra", "warning", int(op["count"]), [], str(op["message"])))
    if mesh.meta.get("reversed_faces"):  # polyhedra of a format that stores each face once
        rev = mesh.meta["reversed_faces"]
        issues.append(_issue("reversed-faces", "info", int(rev["count"]), [], str(rev["message"])))
    if mesh.meta.get("reordered_cells"):  # a Gambit file's bricks, pyramids: in Gambit's node order
        moved = mesh.meta["reordered_cells"]
        issues.append(_issue("reordered-cells", "info", int(moved["count"]), [], str(moved["message"])))
    if mesh.meta.get("openfoam_order"):  # an OpenFOAM case's faces out of upper-triangular order
        issues.append(_issue("openfoam-order", "warning", 1, [], str(mesh.meta["openfoam_order"]["message"])))
    if mesh.meta.get("fluent_faces"):  # a Fluent face's node or cell ids out of range (VTK read on)
        issues.append(_issue("fluent-faces", "warning", 1, [], str(mesh.meta["fluent_faces"]["message"])))
    if mesh.meta.get("lost_data"):  # data arrays the reader could not read (the mesh whole)
        issues.append(_issue("lost-data", "warning", 1, [], str(mesh.meta["lost_data"]["message"])))
    if mesh.meta.get("rounded_plane"):  # a tilted plane's coordinates rounded in the file: projected
        issues.append(_issue("rounded-plane", "info", 1, [], str(mesh.meta["rounded_plane"]["message"])))
    if mesh.meta.get("trailing_bytes"):  # a legacy file going on after its mesh: ignored, as VTK does
        issues.append(_issue("trailing-bytes", "warning", 1, [], str(mesh.meta["trailing_bytes"]["message"])))
    if mesh.meta.get("repeated_pieces"):  # a parallel file's pieces, each the whole mesh: read once
        rep_p = mesh.meta["repeated_pieces"]
        issues.append(_issue("repeated-pieces", "info", int(rep_p["count"]), [], str(rep_p["message"])))
    if mesh.meta.get("ghost_cells"):  # a parallel writer's piece read alone: its ghost layer left out
        ghosts = mesh.meta["ghost_cells"]
        issues.append(_issue("ghost-cells", "info", int(ghosts["count"]), [], str(ghosts["message"])))
    if mesh.meta.get("gambit_groups"):  # a Gambit file's element groups: overlaps, gaps, or not used
        issues.append(_issue("element-groups", "info", 1, [], str(mesh.meta["gambit_groups"]["message"])))
    if mesh.meta.get("nonfinite_points"):  # NaN or infinite points no cell uses: left out on reading
        nf = mesh.meta["nonfinite_points"]
        issues.append(_issue("nonfinite-points", "info", int(nf["count"]), [], str(nf["message"])))
    if mesh.meta.get("merged_points"):  # a cell soup (deal.II's DataOut): its copies merged on reading
        merged = mesh.meta["merged_points"]
        issues.append(_issue("merged-points", "info", int(merged["count"]), [], str(merged["message"])))
    higher = int(mesh.meta.get("higher_order_unused_points", 0) or 0) if mesh.meta.get("higher_order") else 0
    if higher:  # a higher-order mesh: its other nodes said so, in one line (not as stray points)
        issues.append(_issue("higher-order", "info", higher, [], str(mesh.meta["higher_order"])))
    stray = int(unused.size) - min(higher, int(unused.size))
    if stray:
        issues.append(
            _issue(
                "unused-points",
                "info",
                stray,
                unused if not higher else [],
                f"{stray:,} points belong to no cell (ignored)",
            )
        )

    # connected pieces of the dual graph
    n_pieces, piece = connected_components(graph.matrix(), directed=False)
    rep["components"] = int(n_pieces)
    if n_pieces > 1:
        sizes = np.bincount(piece)
        issues.append(
            _issue(
                "disconnected",
                "warning",
                n_pieces,
                [],
                f"the mesh has {n_pieces} disconnected pieces "
                f"(smallest: {int(sizes.min())} cells); each is agglomerated on its own",
            )
        )

    # boundary facets, loops / shells, holes
    f = graph.faces
    bnd = np.flatnonzero(graph.partner < 0)
    rep["boundary_facets"] = int(bnd.size)
    loops, pinch = _boundary_topology(mesh, f, bnd)
    key = "boundary_loops" if mesh.dim == 2 else "boundary_shells"
    rep[key] = loops
    rep["holes"] = max(loops - int(n_pieces), 0)
    if pinch.size:
        what = "vertices" if mesh.dim == 2 else "edges or vertices (vertex ids)"
        issues.append(
            _issue(
                "pinch",
                "warning",
                pinch.size,
                pinch,
                f"{pinch.size} boundary {what} where cells touch only at a point/edge (pinch); "
                "elements never cross them",
            )
        )

    # coincident points among the used ones; on the boundary they split the mesh along a seam
    dup_groups, dup_pts, seam = _duplicates(mesh, used, f, bnd)
    rep["duplicate_points"] = int(dup_pts)
    if dup_pts:
        issues.append(
            _issue(
                "duplicate-points",
                "warning",
                dup_pts,
                seam if seam.size else [],
                f"{dup_pts} points coincide with another point ({dup_groups} places)"
                + (
                    "; on the boundary they split the mesh along a seam (cells on both sides are not "
                    "neighbours; ids of the boundary copies listed)"
                    if seam.size
                    else ""
                )
                + "; merge them with --weld TOL (e.g. --weld 1e-9)",
            )
        )

    hanging = _hanging_nodes(mesh, f, bnd)
    rep["hanging_nodes"] = int(hanging.size)
    if hanging.size:
        issues.append(
            _issue(
                "non-conforming",
                "warning",
                hanging.size,
                hanging,
                f"{hanging.size} vertices lie inside another cell's {'edge' if mesh.dim == 2 else 'face edge'} "
                "(hanging nodes / T-junctions, point ids listed): the cells there are not neighbours, "
                "elements are not joined across that line (an element holding both sides, joined elsewhere, "
                "closes over the node)",
            )
        )

    stray = _stray_lower_dim(mesh, f)
    if mesh.boundary_types is not None:
        rep["lower_dim_cells"] = int(mesh.boundary_types.size)
    if stray.size:
        issues.append(
            _issue(
                "mixed-dimension",
                "warning",
                stray.size,
                stray,
                f"{stray.size} {mesh.dim - 1}D cells are no {'edge' if mesh.dim == 2 else 'face'} of any "
                f"{mesh.dim}D cell (ignored: only the {mesh.dim}D cells are agglomerated)",
            )
        )
    try:
        from models.mesh.boundary import check_issues, check_lines, summary

        rep["boundary"] = summary(mesh, f, graph.partner)  # the graph's faces, not a second cell_faces
        rep["boundary_notes"] = check_lines(rep["boundary"])
        issues.extend(check_issues(rep["boundary"]))
    except Exception:  # noqa: BLE001 - the boundary summary is an extra, never a reason to fail the check
        pass
    return _finish(rep, issues)


def _finish(rep: dict, issues: list[dict]) -> dict:
    sev = {i["severity"] for i in issues}
    rep["verdict"] = "error" if "error" in sev else "warnings" if "warning" in sev else "ok"
    rep["issues"] = issues
    return rep


def _boundary_topology(mesh: Mesh, f, bnd: np.ndarray) -> tuple[int, np.ndarray]:
    """(number of boundary loops / shells, pinch vertex ids) from the boundary facets."""
    from models.mesh.geometry import cell_index, next_in_cycle

    if bnd.size == 0:
        return 0, np.zeros(0, np.int64)
    n = mesh.n_points
    if mesh.dim == 2:
        a, b = f.nodes[2 * bnd], f.nodes[2 * bnd + 1]
        g = sp.csr_matrix((np.ones(a.size), (a, b)), shape=(n, n))
        n_comp, comp = connected_components(g, directed=False)
        touched = np.zeros(n, dtype=bool)
        touched[a] = touched[b] = True
        loops = int(np.unique(comp[touched]).size)
        deg = np.bincount(a, minlength=n) + np.bincount(b, minlength=n)
        return loops, np.flatnonzero(deg > 2)
    # 3D: faces linked by shared edges; an edge on more than two boundary faces is a pinch
    from models.mesh.geometry import reorder_csr

    fo, nodes = reorder_csr(f.offsets, f.nodes, bnd)
    owner = cell_index(fo)
    u, v = nodes, nodes[next_in_cycle(fo)]
    ek = np.minimum(u, v) * np.int64(n) + np.maximum(u, v)
    order = np.argsort(ek, kind="stable")
    se = ek[order]
    same = se[1:] == se[:-1]
    i = np.flatnonzero(same)
    g = sp.csr_matrix((np.ones(i.size), (owner[order[i]], owner[order[i + 1]])), shape=(bnd.size, bnd.size))
    loops, shell = connected_components(g, directed=False)
    _, cnt = np.unique(se, return_counts=True)
    first = np.r_[True, ~same]
    pinch_keys = se[first][cnt > 2]
    # a vertex on two shells: the domain touches itself there at a point (two cubes at a corner)
    vs = np.unique(nodes * np.int64(loops) + shell[owner])
    at_point = np.flatnonzero(np.bincount(vs // loops, minlength=n) > 1)
    return int(loops), np.union1d(np.unique(pinch_keys // n), at_point)


def _duplicates(mesh: Mesh, used: np.ndarray, f, bnd: np.ndarray) -> tuple[int, int, np.ndarray]:
    """(groups of coincident used points, points in them beyond the first, the ones on the boundary)."""
    from scipy.spatial import cKDTree

    ids = np.flatnonzero(used)
    p = mesh.points[ids]
    span = float(np.linalg.norm(p.max(axis=0) - p.min(axis=0))) if ids.size else 0.0
    if ids.size < 2 or span == 0:
        return 0, 0, np.zeros(0, np.int64)
    pairs = cKDTree(p).query_pairs(1e-12 * span, output_type="ndarray")
    if pairs.size == 0:
        return 0, 0, np.zeros(0, np.int64)
    g = sp.csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(ids.size, ids.size))
    _, comp = connected_components(g, directed=False)
    members = np.unique(pairs.ravel())
    n_groups = int(np.unique(comp[members]).size)
    from models.mesh.geometry import reorder_csr

    on_bnd = np.zeros(mesh.n_points, dtype=bool)
    _, bn = reorder_csr(f.offsets, f.nodes, bnd)
    on_bnd[bn] = True
    dup_ids = ids[members]
    return n_groups, int(members.size - n_groups), dup_ids[on_bnd[dup_ids]]


def _hanging_nodes(mesh: Mesh, f, bnd: np.ndarray) -> np.ndarray:
    """Boundary vertices lying strictly inside a boundary edge (2D) / boundary-face edge (3D)."""
    from scipy.spatial import cKDTree

    from models.mesh.geometry import next_in_cycle, reorder_csr

    if bnd.size == 0:
        return np.zeros(0, np.int64)
    fo, nodes = reorder_csr(f.offsets, f.nodes, bnd)
    u, v = nodes, nodes[next_in_cycle(fo)]
    if mesh.dim == 2:
        u, v = u[0::2], u[1::2]
    p = mesh.points
    verts = np.unique(nodes)
    tree = cKDTree(p[verts])
    mid = 0.5 * (p[u] + p[v])
    half = 0.5 * np.linalg.norm(p[v] - p[u], axis=1)
    hits = tree.query_ball_point(mid, half * (1 + 1e-9))
    counts = np.fromiter(map(len, hits), dtype=np.int64, count=len(hits))  # C-level iteration
    if counts.sum() == 0:
        return np.zeros(0, np.int64)
    edge = np.repeat(np.arange(u.size), counts)
    cand = verts[np.fromiter(chain.from_iterable(hits), dtype=np.int64, count=int(counts.sum()))]
    keep = (cand != u[edge]) & (cand != v[edge])
    edge, cand = edge[keep], cand[keep]
    d = p[v[edge]] - p[u[edge]]
    w = p[cand] - p[u[edge]]
    L2 = np.einsum("ij,ij->i", d, d)
    t = np.einsum("ij,ij->i", w, d) / L2
    off = w - t[:, None] * d
    dist2 = np.einsum("ij,ij->i", off, off)
    on = (t > 1e-9) & (t < 1 - 1e-9) & (dist2 <= (1e-9**2) * L2)
    return np.unique(cand[on])


def _stray_lower_dim(mesh: Mesh, ef) -> np.ndarray:
    """Ids (among the lower-dimensional cells) of those that are no facet of any cell (`ef`: the
    cells' faces)."""
    if mesh.boundary_types is None or mesh.boundary_offsets is None:
        return np.zeros(0, np.int64)
    from models.mesh.dual import face_keys
    from models.mesh.geometry import Faces

    nb = mesh.boundary_types.size
    bf = Faces(cell=np.arange(nb), offsets=mesh.boundary_offsets, nodes=mesh.boundary_connectivity)
    sizes = bf.sizes()
    if mesh.dim == 2:
        bf_ok = sizes == 2
    else:
        bf_ok = sizes >= 3
    if not bf_ok.any():
        return np.flatnonzero(~bf_ok)
    kb = face_keys(bf, mesh.n_points) if bf_ok.all() else None
    ke = face_keys(ef, mesh.n_points)
    if kb is None or kb.ndim != ke.ndim or kb.ndim != 1:
        return np.zeros(0, np.int64)  # mixed widths: not checked
    return np.flatnonzero(~np.isin(kb, ke))


def format_report(rep: dict) -> str:
    """The report as text for a terminal."""
    lines = []
    if "cells" in rep:
        types = ", ".join(f"{n} {t}" for t, n in rep["cell_types"].items())
        lines.append(
            f"{rep.get('file', 'mesh')}: {rep['dim']}D, {rep['cells']} cell{'s' if rep['cells'] != 1 else ''} "
            f"({types}), {rep['points']} point{'s' if rep['points'] != 1 else ''}"
        )
        if "components" in rep:
            loops = rep.get("boundary_loops", rep.get("boundary_shells"))
            kind = "loops" if rep["dim"] == 2 else "shells"
            lines.append(
                f"pieces: {rep['components']}, boundary {kind}: {loops}, holes: {rep['holes']}, "
                f"boundary {'edges' if rep['dim'] == 2 else 'faces'}: {rep['boundary_facets']}"
            )
        o = rep["orientation"]
        lines.append(
            f"orientation: {o['flipped']} cells re-oriented to match their neighbours, {o['folded']} folded"
        )
        if rep.get("welded_points"):
            lines.append(f"welded: {rep['welded_points']} points merged into coincident ones")
        names = rep.get("group_names") or {}
        groups = [f"{g} {names[g]!r}" if g in names else str(g) for g in rep["physical_groups"]]
        lines.append(f"physical groups: {', '.join(groups) or 'none'}")
        lines.extend(rep.get("boundary_notes", []))
    else:
        lines.append(f"{rep.get('file', 'mesh')}: cannot be used")
    for i in rep["issues"]:
        more = ", ..." if i["count"] > len(i["ids"]) else ""
        ids = f" (ids {id_list(i['ids'], len(i['ids']))}{more})" if i["ids"] else ""
        lines.append(f"{i['severity']}: {i['message']}{ids}")
    lines.append(f"verdict: {rep['verdict']}")
    return "\n".join(lines)

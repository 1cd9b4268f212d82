"""One agglomeration run from a Mesh to files: graph -> partition -> connected parts -> merge ->
hole handling -> metrics -> outputs, with a timing per stage.

Hole policy (see merge.py): "split" (default) cuts an element that encloses a hole or a cavity in
two, along the line/plane through the hole's centre perpendicular to the element's widest
direction; each half is then split into connected components. This repeats (at most 8 rounds)
until no element has a hole, so every written polygon has exactly one boundary loop. "error"
refuses the job instead, naming the elements.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from models.errors import HoleError, MeshError, ParameterError
from models.export import atomic
from models.mesh.boundary import FineBoundary, annotate, fine_boundary, has_groups
from models.mesh.celldata import CellData, compact_labels
from models.mesh.container import Mesh, PolyMesh
from models.mesh.dual import DualGraph, cached_faces, dual_graph
from models.mesh.geometry import cell_faces, measures_and_centroids
from models.polytope.euler import pinched
from models.polytope.merge import merge, sort_by_vertex_count

if TYPE_CHECKING:  # models.partition.agglomerate is imported where partitioning runs (not by prepare alone)
    from models.partition.agglomerate import Agglomeration

HOLE_POLICIES = ("split", "error")


@dataclass
class Result:
    mesh: Mesh
    graph: DualGraph
    data: CellData
    agglomeration: Agglomeration
    poly: PolyMesh
    holes_split: int
    timings: dict = field(default_factory=dict)
    metrics: dict | None = None
    boundary: FineBoundary | None = None  # the fine mesh's boundary groups, when it has any

    def summary(self) -> dict:
        s = self.agglomeration.summary()
        s["elements"] = int(self.poly.n_elements)
        s["holes_split"] = int(self.holes_split)
        s["cells"] = int(self.mesh.n_cells)
        s["dim"] = int(self.mesh.dim)
        s["timings"] = {k: round(float(v), 4) for k, v in self.timings.items()}
        left_out = self.mesh.meta.get("dropped_cells")
        if left_out:  # a few bad cells the read left out (models.mesh.dropped.few_bad): said with the result
            from models.mesh.dropped import dropped_sentence

            s["cells_left_out"] = {"ids": list(left_out["ids_all"]), "note": dropped_sentence(self.mesh.meta)}
        return s


def input_labels(mesh: Mesh, labels: np.ndarray) -> np.ndarray:
    """One label per cell of the file (or of cells= as given): -1 for the few bad cells the read
    left out (mesh.meta["dropped_cells"]); `labels` (one per cell read) where none was."""
    from models.mesh.dropped import file_labels

    return file_labels(mesh.meta, labels)


def prepare(mesh: Mesh) -> tuple[DualGraph, CellData]:
    """Dual graph and cell geometry (the features every partitioner uses)."""
    c = cached_faces(mesh)  # kept by reading (with the face pairing), else built here
    faces = c["faces"] if c is not None else cell_faces(mesh)
    graph = dual_graph(mesh, faces)
    measures, centroids = measures_and_centroids(mesh, faces if mesh.dim == 3 else None)
    data = CellData(graph, measures, centroids, mesh.points, mesh.offsets, mesh.connectivity, mesh.tags)
    return graph, data


def split_holes(
    mesh: Mesh,
    graph: DualGraph,
    data: CellData,
    labels: np.ndarray,
    policy: str = "split",
    max_rounds: int = 12,
    rings: bool = True,
    cavities=None,
):
    """Merge, and split elements that enclose holes until none does. Returns (poly, labels, n_split).
    cavities: 3D, domain_holes' (cavity, cell) pairs: an element alone around one is cut through it
    too (a handle pinched at an edge can hide the cavity from the element's shells)."""
    if policy not in HOLE_POLICIES:
        raise ParameterError(f"hole_policy must be one of {', '.join(HOLE_POLICIES)}, got {policy!r}")
    from models.hierarchy.topology import alone_around
    from models.partition.agglomerate import connected_parts

    n_split = 0
    all_nodes = np.arange(mesh.n_cells)
    for _ in range(max_rounds + 1):
        poly, holes = merge(mesh, graph, labels, data.measures)
        normals = None
        own, own_c = alone_around(cavities, labels, data.centroids)
        new = ~np.isin(own, holes.elements)
        if new.any():
            holes = type(holes)(
                elements=np.r_[holes.elements, own[new]],
                centers=np.vstack([holes.centers.reshape(-1, own_c.shape[1]), own_c[new]]),
                odd_surface=holes.odd_surface,
            )
        if holes.elements.size == 0:
            elems, centers, normals = _rings(mesh, graph, data, labels, rings, holes.odd_surface)
            if elems.size == 0:
                return poly, labels, n_split
        else:
            elems, first = np.unique(holes.elements, return_index=True)
            centers = holes.centers[first]
        if policy == "error":
            ids = ", ".join(str(int(e)) for e in elems[:10]) + (", ..." if elems.size > 10 else "")
            one = elems.size == 1
            raise HoleError(
                f"{elems.size} agglomerated element{' encloses' if one else 's enclose'} a hole (element"
                f"{'' if one else 's'} {ids}) and the hole policy 'error' refuses {'it' if one else 'them'}: "
                f"use the hole policy 'split' (--hole-policy split) to cut {'it' if one else 'them'}"
            )
        if _ == max_rounds:
            break
        new_label = labels.copy()
        nxt = int(labels.max()) + 1
        by_el, lo, hi = _cells_of(labels, elems)
        for i, (e, c) in enumerate(zip(elems, centers, strict=True)):  # a loop over the (few) holed elements
            cells = by_el[lo[i] : hi[i]]
            x = data.centroids[cells]
            if normals is not None and np.any(normals[i]):
                side = (x - c) @ normals[i] > 0
                new_label[cells[side]] = nxt
                nxt += 1
                continue
            xc = x - x.mean(axis=0)
            _, _, vt = np.linalg.svd(xc, full_matrices=False)
            hc = holes.centers[holes.elements == e]
            if len(hc) > 2:  # several holes: through the middle one along the axis, halving them
                c = hc[np.argsort(hc @ vt[0])[len(hc) // 2]]
            side = (x - c) @ vt[0] > 0
            if side.all() or not side.any():
                side = (x - c) @ vt[1] > 0
            new_label[cells[side]] = nxt
            nxt += 1
        labels, _s = connected_parts(data, new_label, all_nodes)
        labels = compact_labels(labels)
        n_split += elems.size
    raise HoleError(
        f"{elems.size} element{'s' if elems.size > 1 else ''} still enclose{'' if elems.size > 1 else 's'} a hole after {max_rounds} rounds of cutting them: the "
        "domain has too many holes for so few elements; ask for more elements"
    )


def run(
    mesh: Mesh,
    model: str = "metis",
    mode: str = "kway",
    k: int | None = None,
    nref: int | None = None,
    target_size: float | None = None,
    mult_factor: float | None = None,
    subset=None,
    absorb_fraction: float = 0.0,
    hole_policy: str = "split",
    seed: int = 0,
    model_options: dict | None = None,
    compute_metrics: bool = True,
    progress: Callable[[float, str], None] | None = None,
    size_measure: str = "centroids",
    refiner: str | None = None,
    threshold: int = 200,
    record_levels: bool = False,
    keep_groups: bool | None = None,
    allow_extra: bool = False,
) -> Result:
    """Agglomerate `mesh`; progress(fraction, stage) is called between stages. refiner, threshold,
    record_levels, keep_groups: see models.partition.agglomerate.agglomerate (multilevel mode, nested
    hierarchy, refiners that keep physical groups apart)."""

    def report(frac: float, stage: str) -> None:
        if progress is not None:
            progress(frac, stage)

    timings: dict[str, float] = {}
    t = time.perf_counter()
    report(0.02, "graph")
    graph, data = prepare(mesh)
    timings["graph"] = time.perf_counter() - t

    t = time.perf_counter()
    report(0.1, "partition")

    def part_progress(frac: float, stage: str) -> None:
        report(0.1 + 0.6 * frac, stage)

    from models.partition.agglomerate import agglomerate

    agg = agglomerate(
        mesh,
        data,
        model=model,
        mode=mode,
        k=k,
        nref=nref,
        target_size=target_size,
        mult_factor=mult_factor,
        subset=subset,
        absorb_fraction=absorb_fraction,
        seed=seed,
        progress=part_progress,
        model_options=model_options,
        size_measure=size_measure,
        refiner=refiner,
        threshold=threshold,
        record_levels=record_levels,
        keep_groups=keep_groups,
        allow_extra=allow_extra,
    )
    timings["partition"] = time.perf_counter() - t
    for stage in ("coarsen", "bisect", "refine"):  # parts of "partition" (multilevel mode, refiners)
        if stage in agg.timings:
            timings[f"partition.{stage}"] = agg.timings[stage]

    t = time.perf_counter()
    report(0.72, "merge")
    before = dict(agg.recount)
    try:
        poly, labels, n_split = _hole_free(mesh, graph, data, agg, hole_policy, rings=True)
    except (ParameterError, MeshError):  # k, or the cuts, cannot do without rings (3D): keep them, say so
        if mesh.dim != 3:
            raise
        agg.recount = before
        poly, labels, n_split = _hole_free(mesh, graph, data, agg, hole_policy, rings=False)
        from models.hierarchy.topology import handle_elements

        agg.recount["rings_kept"] = int(handle_elements(mesh, graph, labels).size)
    poly = sort_by_vertex_count(poly)  # 3D: the element order meshio can read back
    labels = poly.labels
    agg.labels = labels
    agg.n_elements = poly.n_elements

    fb = fine_boundary(mesh, graph.faces, graph.partner) if has_groups(mesh) else None
    if fb is not None:
        annotate(poly, fb)  # every element facet keeps the group of its fine facet
    timings["merge"] = time.perf_counter() - t

    res = Result(
        mesh=mesh,
        graph=graph,
        data=data,
        agglomeration=agg,
        poly=poly,
        holes_split=n_split,
        timings=timings,
        boundary=fb,
    )
    if compute_metrics:
        t = time.perf_counter()
        report(0.8, "metrics")
        res.metrics = element_metrics(res)
        timings["metrics"] = time.perf_counter() - t
    report(0.9, "write")
    return res


def _cells_of(labels: np.ndarray, elems: np.ndarray):
    """The cells of each element of `elems`: by_el[lo[i] : hi[i]] (one sort, no pass per element)."""
    by_el = np.argsort(labels, kind="stable")
    lo = np.searchsorted(labels[by_el], elems)
    hi = np.searchsorted(labels[by_el], elems, side="right")
    return by_el, lo, hi


def _hole_free(mesh, graph, data, agg, hole_policy: str, rings: bool):
    """split_holes on the partition, then, where k is asked for exactly, _recount_after_holes:
    (poly, labels, elements split)."""
    try:
        poly, labels, n_split = split_holes(mesh, graph, data, agg.labels, hole_policy, rings=rings)
    except MeshError:
        if not agg.exact or hole_policy != "split":
            raise
        poly = labels = None  # too many holes for the cuts: _recount_after_holes threads them
        n_split = 0
    if agg.exact and (poly is None or poly.n_elements != agg.n_elements):
        poly, labels = _recount_after_holes(mesh, graph, data, agg, poly, labels, hole_policy, rings=rings)
    if mesh.dim == 3 and labels is not None and hole_policy == "split":
        from models.hierarchy.topology import alone_around, domain_holes

        cav = domain_holes(mesh, data)
        if alone_around(cav, labels)[0].size:  # alone around a cavity, which its
            # shells did not show (a handle pinched at an edge): cut, and counted again with them
            poly, labels, more = split_holes(
                mesh, graph, data, labels, hole_policy, rings=rings, cavities=cav
            )
            n_split += more
            if agg.exact and poly.n_elements != agg.n_elements:
                poly, labels = _recount_after_holes(
                    mesh, graph, data, agg, poly, labels, hole_policy, rings=rings, cavities=cav
                )
    return poly, labels, n_split


def _rings(mesh: Mesh, graph: DualGraph, data: CellData, labels: np.ndarray, handles: bool = True, odd=None):
    """Elements that go around something without an inner boundary loop or shell, and the cut that
    opens each: (elements, a point of each cut, its normal). 2D: an element touching itself at a
    vertex, cut through that vertex between its cells there. 3D (models.hierarchy.topology.
    handle_elements), on a domain with a tunnel or a cavity: an element around a cavity whose inner
    surface touches its outer one along an edge, cut through its centroid across its principal axis;
    with `handles`, a ring around a tunnel of the domain or around a neighbour, cut through its
    centroid normal to its second principal axis (a plane holding the first: a slice of a pipe and a
    sleeve along it are both opened). odd: the merge's elements whose boundary surface is not a set
    of spheres (Holes.odd_surface), the only ones looked at: then on every domain (a band of a thin
    wall around a cup's bottom is a ring around a neighbour); without it, only on a domain with a
    tunnel or a cavity (looking at every element costs up to a third of a run at 20,000 elements)."""
    if mesh.dim == 2:
        elems, vertex = pinched(mesh, graph, labels)
        return elems, mesh.points[vertex], _fan_normals(data, labels, elems, vertex)
    from models.hierarchy.topology import domain_genus, handle_elements

    none = np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3))
    if odd is None:
        genus, shells = domain_genus(mesh, graph, with_shells=True)
        if genus == 0 and shells <= 1:  # no tunnel, no cavity: nothing to go around but neighbours
            return none
    elif odd.size == 0:
        return none
    rings, cavities = handle_elements(mesh, graph, labels, only=odd, cavities=True)
    if not handles:
        rings = rings[:0]
    one = np.bincount(labels)[np.r_[rings, cavities]] < 2  # (a single cell, a polyhedron read back: not cut)
    rings, cavities = rings[~one[: rings.size]], cavities[~one[rings.size :]]
    elems = np.r_[rings, cavities].astype(np.int64)
    axis = np.r_[np.ones(rings.size, dtype=np.int64), np.zeros(cavities.size, dtype=np.int64)]
    centers = np.zeros((elems.size, 3))
    normals = np.zeros((elems.size, 3))
    by_el, lo, hi = _cells_of(labels, elems)
    for i in range(elems.size):  # a loop over the (few) elements found
        x = data.centroids[by_el[lo[i] : hi[i]]]
        centers[i] = x.mean(axis=0)
        if x.shape[0] > 2:
            normals[i] = np.linalg.svd(x - centers[i], full_matrices=False)[2][axis[i]]
    return elems, centers, normals


def _fan_normals(data: CellData, labels: np.ndarray, elems: np.ndarray, vertex: np.ndarray) -> np.ndarray:
    """For each element touching itself at `vertex`: the direction from one group of its cells at that
    vertex (cells joined by a side) to another, the normal of a cut through the vertex that parts
    them; zero where the cells there form one group."""
    normals = np.zeros((elems.size, data.centroids.shape[1]))
    if elems.size == 0:  # (the usual case: no scipy import)
        return normals
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    g = data.graph
    entry = np.flatnonzero(np.isin(data.connectivity, vertex))
    cell = np.searchsorted(data.offsets, entry, side="right") - 1
    for i, (e, v) in enumerate(zip(elems, vertex, strict=True)):  # a loop over the (few) pinched elements
        cells = np.unique(cell[(data.connectivity[entry] == v) & (labels[cell] == e)])
        if cells.size < 2:
            continue
        nb = [g.indices[g.indptr[c] : g.indptr[c + 1]] for c in cells]
        rows = np.repeat(np.arange(cells.size), [len(x) for x in nb])
        cols = np.searchsorted(cells, np.concatenate(nb))
        ok = (cols < cells.size) & (cells[np.minimum(cols, cells.size - 1)] == np.concatenate(nb))
        adj = csr_matrix((np.ones(int(ok.sum())), (rows[ok], cols[ok])), shape=(cells.size, cells.size))
        n, comp = connected_components(adj, directed=False)
        if n < 2:
            continue
        x = data.centroids[cells]
        normals[i] = x[comp == 0].mean(axis=0) - x[comp == 1].mean(axis=0)
    return normals


def _recount_after_holes(
    mesh, graph, data, agg, poly, labels, hole_policy, rounds: int = 4, rings: bool = True, cavities=None
):
    """Elements cut because they enclosed a hole raised the count above the k asked for (poly and
    labels: split_holes' answer, None where it gave up). In turn, until one gives k elements:
    - the cut elements merged back into a neighbour where the union encloses nothing (its Euler
      characteristic is 1: models.polytope.euler);
    - from the partition again, each element around a hole first gives a path of its cells from the
      hole to a neighbour (models.hierarchy.holes.thread_holes: the hole then lies between two
      elements and the count stays), what is left cut and merged back as above; on a plate with 100
      holes about a cell wide this meets k = 2 to 16, which the cuts alone cannot;
    - the smallest merged back (models.partition.connect), the holes that makes threaded, and holes
      checked again, a few rounds."""
    from models.partition.connect import exact_count
    from models.polytope.euler import merge_safely

    target = agg.n_elements
    nodes = np.arange(mesh.n_cells)
    whole = target == agg.requested  # not with a subset: the rest stays as is
    # with a subset, the cells outside it stay elements of their own: each its own group, which no
    # merge crosses, so the cut elements are merged back among the subset's (the count asked of it)
    outside = None if whole else agg.labels >= agg.requested
    keep = None if whole else np.where(outside, np.cumsum(outside), 0)
    sizes = np.abs(data.measures)
    for how in ("cut", "threaded") if whole else ("cut",):
        start = labels
        if how == "threaded":
            start, opened = _threaded(mesh, data, agg.labels)
            if opened == 0:
                continue
            try:
                _p, start, _n = split_holes(
                    mesh, graph, data, start, hole_policy, rings=rings, cavities=cavities
                )
            except MeshError:
                continue
        if start is None:
            continue
        got, merged = merge_safely(mesh, graph, start, target, sizes=sizes, keep=keep)
        try:
            p2, got, _n = split_holes(mesh, graph, data, got, hole_policy, rings=rings, cavities=cavities)
        except MeshError:
            continue
        if p2.n_elements == target:
            agg.recount["merged"] = agg.recount.get("merged", 0) + merged
            if how == "threaded":
                agg.recount["threaded"] = opened
            return p2, got
        if how == "cut":
            poly, labels = p2, got
    for _ in range(rounds if whole and labels is not None else 0):
        labels, merged, resplit = exact_count(data, labels, nodes, target, agg.asked)
        agg.recount["merged"] = agg.recount.get("merged", 0) + merged
        agg.recount["split"] = agg.recount.get("split", 0) + resplit
        labels, opened = _threaded(mesh, data, labels)  # the holes those merges made, opened
        if opened:
            agg.recount["threaded"] = agg.recount.get("threaded", 0) + opened
        poly, labels, _n = split_holes(mesh, graph, data, labels, hole_policy, rings=rings, cavities=cavities)
        if poly.n_elements == target:
            return poly, labels
    got = "" if poly is None else f" ({poly.n_elements - (0 if whole else int(outside.sum()))} elements)"
    raise ParameterError(
        f"{agg.asked} = {agg.requested} cannot be met: elements that enclose a hole must be cut and merging "
        f"them back makes new holes{got}; allow extra elements (options.allow_extra)"
    )


def _threaded(mesh: Mesh, data: CellData, labels: np.ndarray, rounds: int = 8):
    """Each element that alone goes around a hole of the domain gives the shortest path of its cells
    from the hole to a neighbouring element (thread_holes with cells as the units), rounds while
    holes open. Returns (labels, holes opened)."""
    from models.hierarchy.holes import thread_holes
    from models.hierarchy.topology import domain_holes

    hole_id, hole_cell = domain_holes(mesh, data)
    n = mesh.n_cells
    cells, parent = np.arange(n), np.zeros(n, dtype=np.int64)
    total = 0
    for _ in range(rounds if hole_id.size else 0):  # a loop over rounds (each one path per hole)
        labels, opened = thread_holes(data, labels, cells, parent, hole_id, hole_cell)
        total += opened
        if opened == 0:
            break
    return labels, total


def element_metrics(res: Result) -> dict:
    """The metrics report (models.metrics) for a result."""
    from models.quality.report import metrics_report

    g = res.graph
    return metrics_report(res.poly, g.indptr, g.indices, fine_tags=res.mesh.tags)


def write_outputs(
    res: Result,
    vtu: str | None = None,
    metrics: str | None = None,
    labels: str | None = None,
    lymph: str | list[str] | None = None,
    plot: str | None = None,
    extra: dict | None = None,
    boundary_tag: int = 1,
) -> dict:
    """Write the requested outputs; returns {kind: path}. lymph: path(s), '.mat' or '.json' by extension.
    boundary_tag: lymph bc_tag of boundary edges without a boundary group."""
    out: dict[str, str] = {}
    t = time.perf_counter()
    if vtu:
        from models.export.vtu import group_names_of, write_vtu

        cell_data = {}
        if res.metrics is not None:
            for name, vals in res.metrics["per_element"].items():
                cell_data[name] = np.asarray(vals, dtype=np.float64)
        from models.mesh.boundary import output_cells

        write_vtu(
            vtu, res.poly, cell_data, boundary=output_cells(res.poly), group_names=group_names_of(res.mesh)
        )
        out["mesh"] = vtu
    if labels:
        lab = input_labels(res.mesh, res.agglomeration.labels)
        atomic.write_text(labels, json.dumps(lab.tolist()))
        out["labels"] = labels
    if lymph:
        if res.mesh.dim != 2:
            raise ParameterError("lymph output exists for 2D meshes only")
        from models.export.lymph import lymph_structs, write_lymph_json, write_lymph_mat

        region, neighbor = lymph_structs(res.poly, boundary_tag=boundary_tag)
        for i, path in enumerate([lymph] if isinstance(lymph, str) else lymph):
            (write_lymph_json if path.endswith(".json") else write_lymph_mat)(path, region, neighbor)
            out["lymph" if i == 0 else f"lymph{i}"] = path
    if plot:
        from models.quality.plot import plot_agglomeration

        plot_agglomeration(res.poly, plot, fine_mesh=res.mesh if res.mesh.n_cells <= 200_000 else None)
        out["preview"] = plot
    res.timings["write"] = time.perf_counter() - t
    if metrics:
        if res.metrics is None:
            res.metrics = element_metrics(res)
        report = dict(res.metrics)
        if res.boundary is not None:
            from models.mesh.boundary import measure_report

            report["boundary"] = measure_report(res.boundary, res.poly)
        report["run"] = {**res.summary(), **(extra or {})}
        from models.mesh.check import mesh_report

        report["mesh_report"] = mesh_report(res.mesh, res.graph)  # what `magnet check` says of the input
        atomic.write_text(metrics, json.dumps(report, indent=1))
        out["metrics"] = metrics
    return out


def write_hierarchy(
    res: Result,
    out_dir: str,
    metrics: bool = True,
    extra: dict | None = None,
    lymph: bool = False,
    boundary_tag: int = 1,
    written: dict | None = None,
) -> dict:
    """The nested hierarchy of a recursive run (pipeline.run(..., record_levels=True)) written to
    out_dir (models.hierarchy.nested); returns the hierarchy.json index (written: filled as
    models.hierarchy.nested.write_hierarchy fills it, e.g. the earlier level files it removed)."""
    from models.hierarchy.nested import nested_levels
    from models.hierarchy.nested import write_hierarchy as _write

    agg = res.agglomeration
    if not agg.levels:
        raise ParameterError(
            "a hierarchy needs a recursive mode (nref, target-size, mult-factor, segregated, "
            "multilevel, or coarsen with one of them) run with record_levels=True"
        )
    levels = nested_levels(res.data, agg.labels, agg.levels, agg.nodes, res.mesh)
    return _write(
        out_dir,
        res.mesh,
        res.data,
        levels,
        metrics=metrics,
        extra=extra,
        lymph=lymph,
        boundary=res.boundary,
        boundary_tag=boundary_tag,
        written=written,
    )

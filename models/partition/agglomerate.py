"""Agglomeration = partition the dual graph, then make every part connected.

Modes: direct k-way, number of refinements (2^n parts), target size (bisect until every part's
diameter < h), multiplicative factor (h = f x mesh diameter), segregated (physical groups first,
then the same h = f x mesh diameter inside each group), coarsen (only a subset of cells; the rest stays).
Recursive bisection runs level by level: all parts of a level go to the partitioner as one
`GraphBatch` (one forward pass for the neural models).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from models.errors import ParameterError, id_list, listed
from models.graph.batch import GraphBatch
from models.mesh.celldata import CellData, compact_labels  # here too: models.agglomerate.CellData
from models.mesh.container import Mesh
from models.mesh.dual import sorted_unique, subgraph_by_labels
from models.partition import Partitioner, get_partitioner
from models.partition.connect import connected_parts  # noqa: F401  (here too: callers import it from here)

MODES = ("kway", "nref", "target-size", "mult-factor", "segregated", "coarsen", "multilevel")
MAX_NREF = 30
MAX_LEVELS = 64


@dataclass
class Agglomeration:
    """Result of partitioning: `labels` (C,) fine cell -> element id 0..n_elements-1."""

    labels: np.ndarray
    n_elements: int
    requested: int | None
    parts_before_split: int
    parts_split: int
    fragments_absorbed: int
    timings: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    levels: list | None = None  # labels over `nodes` after each recursion level (record_levels)
    nodes: np.ndarray | None = None
    exact: bool = False  # the count `requested` is enforced (k or nref asked for, allow_extra off)
    asked: str = "k"  # how the count was asked for, in messages: "k" or "2^nref"
    recount: dict = field(default_factory=dict)  # {"merged", "split", "threaded", "rings_kept": n} to meet it

    def summary(self) -> dict:
        return {
            "elements": int(self.n_elements),
            "requested": self.requested,
            "asked": self.asked,  # "k" or "2^nref": how the count was asked for
            "parts_before_split": int(self.parts_before_split),
            "parts_split": int(self.parts_split),
            "fragments_absorbed": int(self.fragments_absorbed),
            "recount": {
                "merged": int(self.recount.get("merged", 0)),
                "split": int(self.recount.get("split", 0)),
                "threaded": int(self.recount.get("threaded", 0)),  # holes opened by a path of cells
                "rings_kept": int(self.recount.get("rings_kept", 0)),  # 3D rings around a tunnel
            },
        }


def make_batch(data: CellData, labels: np.ndarray, nodes: np.ndarray | None = None) -> GraphBatch:
    """The disjoint union of the subgraphs induced by `labels` (over `nodes`, or all cells)."""
    g = data.graph
    order, ptr, ip, ix, w = subgraph_by_labels(g.indptr, g.indices, g.weights, labels, nodes)
    return GraphBatch(
        indptr=ip,
        indices=ix,
        weights=w,
        graph_ptr=ptr,
        centroids=data.centroids[order],
        measures=data.measures[order],
        tags=None if data.tags is None else data.tags[order],
        node_ids=order,
    )


def absorb_fragments(
    data: CellData, labels: np.ndarray, nodes: np.ndarray, fraction: float, n_parts: int | None = None
) -> tuple[np.ndarray, int]:
    """Merge parts smaller than `fraction` x mean part measure into the neighbour part with which
    they share the longest interface (repeated until none is left or none can move).

    The mean is total measure / `n_parts` (the number of parts the partitioner made, before the
    split into connected components), so many fragments do not drag the threshold down."""
    if fraction <= 0 or nodes.size == 0:
        return labels, 0
    total = float(data.measures[nodes].sum())
    g = data.graph
    n = g.n
    lab_full = np.full(n, -1, dtype=np.int64)
    absorbed = 0
    rows = np.repeat(np.arange(n), np.diff(g.indptr))
    for _ in range(50):
        lab_full[nodes] = labels
        k = int(labels.max()) + 1
        size = np.bincount(labels, weights=data.measures[nodes], minlength=k)
        present = size > 0
        mean = total / n_parts if n_parts else size[present].mean()
        small = present & (size < fraction * mean)
        if not small.any() or present.sum() <= 1:
            break
        a, b = lab_full[rows], lab_full[g.indices]
        e = (a >= 0) & (b >= 0) & (a != b) & small[np.maximum(a, 0)]
        if not e.any():
            break
        import scipy.sparse as sp  # here only: ~0.2 s of start-up for the runs that never absorb

        inter = sp.csr_matrix((g.weights[e], (a[e], b[e])), shape=(k, k)).tocsr()
        inter.sum_duplicates()
        frag = np.flatnonzero(small & (np.diff(inter.indptr) > 0))
        # target = neighbour with the longest shared interface (vectorized row argmax)
        best = np.zeros(k, dtype=np.int64) - 1
        r = np.repeat(np.arange(k), np.diff(inter.indptr))
        order = np.lexsort((-inter.data, r))
        firsts = order[np.r_[True, r[order][1:] != r[order][:-1]]]
        best[r[firsts]] = inter.indices[firsts]
        # avoid chains: a fragment merges into a non-fragment, or into a larger fragment
        tgt = best[frag]
        ok = (~small[tgt]) | (size[tgt] > size[frag]) | ((size[tgt] == size[frag]) & (tgt < frag))
        frag, tgt = frag[ok], tgt[ok]
        if frag.size == 0:
            break
        # resolve merges into parts that themselves move in this round: follow to a fixed target
        mapping = np.arange(k)
        mapping[frag] = tgt
        for _ in range(32):
            nxt = mapping[mapping]
            if np.array_equal(nxt, mapping):
                break
            mapping = nxt
        labels = mapping[labels]
        absorbed += int(frag.size)
    return compact_labels(labels).astype(np.int64), absorbed


SIZE_MEASURES = ("centroids", "vertices")


def _size_points(
    data: CellData, labels: np.ndarray, nodes: np.ndarray, size_measure: str
) -> tuple[np.ndarray, np.ndarray]:
    """The points whose spread is a part's size, and the part of each: the centroids of its cells
    (the paper's measure, the default) or the vertices of its cells (every element below h)."""
    if size_measure == "centroids":
        return data.centroids[nodes], labels
    cell_of = np.repeat(np.arange(data.offsets.size - 1), np.diff(data.offsets))
    lab_full = np.full(data.offsets.size - 1, -1, dtype=np.int64)
    lab_full[nodes] = labels
    vlab = lab_full[cell_of]
    keep = vlab >= 0
    return data.points[data.connectivity[keep]], vlab[keep]


def _part_extent(
    data: CellData,
    labels: np.ndarray,
    nodes: np.ndarray,
    parts: np.ndarray,
    h: float,
    size_measure: str = "centroids",
) -> np.ndarray:
    """For each part in `parts`, True when its size (largest distance between its cell centroids,
    or between its vertices: `size_measure`) is >= h.

    Bounding boxes decide most parts at once: diagonal < h -> smaller; longest side >= h ->
    larger. Only the ambiguous ones get an exact convex-hull diameter (a loop over those parts).
    """
    from scipy.spatial import ConvexHull, QhullError

    k = int(labels.max()) + 1
    pts, vlab = _size_points(data, labels, nodes, size_measure)
    dim = pts.shape[1]
    lo = np.full((k, dim), np.inf)
    hi = np.full((k, dim), -np.inf)
    for d in range(dim):
        np.minimum.at(lo[:, d], vlab, pts[:, d])
        np.maximum.at(hi[:, d], vlab, pts[:, d])
    side = (hi - lo)[parts]
    diag = np.linalg.norm(side, axis=1)
    big = side.max(axis=1) >= h
    unsure = np.flatnonzero(~big & (diag >= h))
    if unsure.size:
        order = np.argsort(vlab, kind="stable")
        ptr = np.searchsorted(vlab[order], np.arange(k + 1))
        for i in unsure:
            p = parts[i]
            q = pts[order[ptr[p] : ptr[p + 1]]]
            try:
                q = q[ConvexHull(q).vertices]
            except (QhullError, ValueError):
                pass
            dmax = max(float(np.linalg.norm(q[j + 1 :] - q[j], axis=1).max(initial=0)) for j in range(len(q)))
            big[i] = dmax >= h
    return big


def _force_split(batch: GraphBatch, split: np.ndarray) -> np.ndarray:
    """Make sure every graph of the batch got two non-empty sides (median cut on the widest axis)."""
    gi = batch.graph_index()
    ones = np.bincount(gi, weights=split, minlength=batch.n_graphs)
    sizes = np.diff(batch.graph_ptr)
    bad = np.flatnonzero(((ones == 0) | (ones == sizes)) & (sizes >= 2))
    for b in bad:  # rare: a partitioner that returned one side only
        lo, hi = int(batch.graph_ptr[b]), int(batch.graph_ptr[b + 1])
        x = batch.centroids[lo:hi]
        axis = int(np.argmax(np.ptp(x, axis=0)))
        o = np.argsort(x[:, axis], kind="stable")
        s = np.zeros(hi - lo, dtype=np.int64)
        s[o[(hi - lo) // 2 :]] = 1
        split[lo:hi] = s
    return split


def make_bisector(
    partitioner: Partitioner,
    refiner=None,
    multilevel: bool = False,
    threshold: int = 200,
    seed: int = 0,
    timings: dict | None = None,
    group_weight: float | None = None,
) -> Callable[[GraphBatch], np.ndarray]:
    """batch -> (N,) sides: the partitioner's bisection, optionally multilevel (coarsen every graph
    to `threshold` nodes by heavy-edge matching, bisect the coarsest graphs, project back level by
    level) and refined (at every level when multilevel, else once on the batch). Stage times add
    up in `timings` (coarsen, bisect, refine). group_weight (keep groups, models.partition.groups): the
    refiner sees edges between physical groups at this weight, and a graph keeps its refined
    bisection only if no more fine cells end up outside their side's majority group."""
    from models.partition.coarsen import coarsen
    from models.partition.groups import group_weighted, keep_purer

    tm = timings if timings is not None else {}

    def clock(stage: str, t: float) -> None:
        tm[stage] = tm.get(stage, 0.0) + time.perf_counter() - t

    def refine(b: GraphBatch, split: np.ndarray, counts: np.ndarray | None = None) -> np.ndarray:
        if refiner is None:
            return split
        t = time.perf_counter()
        if group_weight is None:
            out = _force_split(b, np.asarray(refiner.refine(b, split), dtype=np.int64))
        else:
            out = _force_split(
                b, np.asarray(refiner.refine(group_weighted(b, group_weight), split), dtype=np.int64)
            )
            out = keep_purer(b, split, out, counts)
        clock("refine", t)
        return out

    def bisect(batch: GraphBatch) -> np.ndarray:
        levels = []
        if multilevel:
            t = time.perf_counter()
            levels = coarsen(batch, threshold=threshold, seed=seed)
            clock("coarsen", t)
        coarse = levels[-1].batch if levels else batch
        t = time.perf_counter()
        split = _force_split(coarse, np.asarray(partitioner.bisect_batch(coarse), dtype=np.int64))
        clock("bisect", t)
        counts: list = [None] * (len(levels) + 1)  # fine cells per node of each level (the groups' guard)
        if group_weight is not None and batch.tags is not None:
            c = np.ones(batch.n_nodes)
            for i, lv in enumerate(levels, 1):
                counts[i] = c = np.bincount(lv.cmap, weights=c, minlength=lv.batch.n_nodes)
        for i in range(len(levels), 0, -1):
            lv = levels[i - 1]
            split = refine(lv.batch, split, counts[i])[lv.cmap]
        return refine(batch, split)

    return bisect


def recursive_bisection(
    data: CellData,
    partitioner: Partitioner | Callable[[GraphBatch], np.ndarray],
    nodes: np.ndarray,
    labels: np.ndarray,
    levels: int | None = None,
    h: float | np.ndarray | None = None,
    progress: Callable[[float, str], None] | None = None,
    record: list | None = None,
    size_measure: str = "centroids",
) -> np.ndarray:
    """Bisect parts level by level: `levels` times (nref), or while a part's size >= h
    (size: see _part_extent).

    h may be one value or one value per initial part (segregated mode: per physical group).
    `partitioner` is a Partitioner or a bisect(batch) -> sides function (make_bisector).
    """
    bisect = partitioner.bisect_batch if isinstance(partitioner, Partitioner) else partitioner
    labels = labels.copy()
    h_part = (
        None
        if h is None
        else np.broadcast_to(np.asarray(h, dtype=np.float64), (int(labels.max()) + 1,)).copy()
    )
    n_levels = levels if levels is not None else MAX_LEVELS
    if record is not None:
        record.append(labels.copy())
    for level in range(n_levels):
        k = int(labels.max()) + 1
        sizes = np.bincount(labels, minlength=k)
        cand = np.flatnonzero(sizes >= 2)
        if h_part is not None and cand.size:
            cand = cand[_needs_split(data, labels, nodes, cand, h_part, size_measure)]
        if cand.size == 0:
            break
        sel = np.isin(labels, cand)
        sub_lab = np.full(labels.size, -1, dtype=np.int64)
        remap = np.full(k, -1, dtype=np.int64)
        remap[cand] = np.arange(cand.size)
        sub_lab[sel] = remap[labels[sel]]
        batch = make_batch(data, sub_lab[sel], nodes[sel])
        split = np.asarray(bisect(batch), dtype=np.int64)
        split = _force_split(batch, split)
        # nodes whose side is 1 get a new part id: k + index of their part among the candidates
        pos = np.empty(data.graph.n, dtype=np.int64)
        pos[nodes] = np.arange(nodes.size)
        moved = batch.node_ids[split == 1]
        old = labels[pos[moved]]
        labels[pos[moved]] = k + remap[old]
        if h_part is not None:
            h_part = np.concatenate([h_part, h_part[cand]])
        if record is not None:
            record.append(labels.copy())
        if progress is not None:
            frac = (level + 1) / n_levels if levels is not None else min(0.95, 1 - 0.5 ** (level + 1))
            progress(frac, f"bisection level {level + 1}")
    return labels


def _needs_split(data, labels, nodes, cand, h_part, size_measure="centroids"):
    hp = h_part[cand]
    out = np.zeros(cand.size, dtype=bool)
    for hv in np.unique(hp):  # a few distinct h values at most (one per physical group)
        m = hp == hv
        out[m] = _part_extent(data, labels, nodes, cand[m], float(hv), size_measure)
    return out


def _check_k(k, n):
    if k is None:
        raise ParameterError("k is required for mode 'kway' (number of elements)")
    if not isinstance(k, int | np.integer) or isinstance(k, bool):
        raise ParameterError(f"k must be an integer, got {k!r}")
    if k < 1:
        raise ParameterError(f"k must be >= 1, got {k}")
    if k > n:
        raise ParameterError(f"k = {k} is larger than the number of cells to agglomerate ({n})")


def agglomerate(
    mesh: Mesh,
    data: CellData,
    model: str | Partitioner = "metis",
    mode: str = "kway",
    k: int | None = None,
    nref: int | None = None,
    target_size: float | None = None,
    mult_factor: float | None = None,
    subset: np.ndarray | None = None,
    absorb_fraction: float = 0.0,
    seed: int = 0,
    progress: Callable[[float, str], None] | None = None,
    model_options: dict | None = None,
    refiner=None,
    threshold: int = 200,
    record_levels: bool = False,
    size_measure: str = "centroids",
    keep_groups: bool | None = None,
    group_weight: float | None = None,
    allow_extra: bool = False,
) -> Agglomeration:
    """Partition the cells and return connected parts (see the module docstring for the modes).

    refiner: None, a name (models.partition.refine.REFINERS) or a Refiner: refines every bisection (every
    level of the coarsening in mode 'multilevel') or, in mode 'kway', the k-way partition.
    Mode 'multilevel' stops like nref, target-size or mult-factor, whichever value is given;
    `threshold` is the coarsest graph size. record_levels: keep the labels after each recursion
    level in `Agglomeration.levels` (the nested hierarchy, models.hierarchy.nested). size_measure: what
    target-size / mult-factor / segregated compare with h: "centroids" (largest distance between
    the centroids of a part's cells, and the mesh diameter the same way: the paper's measure) or
    "vertices" (largest distance between its vertices: every element is then below h).
    keep_groups (None = on for heterogeneity-aware models, sage-hetero): on a mesh with physical
    groups, the refiner sees edges between groups at `group_weight` (default 0.01) so its cuts
    prefer material interfaces, and a refined bisection (k-way partition, polished partition) is
    kept only if no more cells end up outside the majority group of their part (models.partition.groups).
    k asked for (mode kway, or coarsen with k) gives exactly k elements (models.partition.connect:
    fragments merged, the largest parts split again; ParameterError when it cannot be met) unless
    allow_extra, which keeps every connected fragment as an element of its own."""
    t0 = time.perf_counter()
    n = mesh.n_cells
    if mode not in MODES:
        raise ParameterError(f"unknown mode {mode!r}; choose one of {listed(MODES)}")
    if size_measure not in SIZE_MEASURES:
        raise ParameterError(f"size_measure must be one of {', '.join(SIZE_MEASURES)}, got {size_measure!r}")
    part = (
        model
        if isinstance(model, Partitioner)
        else get_partitioner(model, seed=seed, **(model_options or {}))
    )
    if isinstance(refiner, str):
        from models.partition.refine import get_refiner

        refiner = None if refiner == "none" else get_refiner(refiner, seed=seed)
    if isinstance(threshold, bool) or not isinstance(threshold, int | np.integer) or threshold < 2:
        raise ParameterError(f"threshold must be an integer >= 2, got {threshold!r}")
    if keep_groups is None:
        keep_groups = bool(getattr(part, "hetero", False))
    if group_weight is None:
        from models.partition.groups import DEFAULT_GROUP_WEIGHT

        group_weight = DEFAULT_GROUP_WEIGHT
    if (
        isinstance(group_weight, bool)
        or not isinstance(group_weight, int | float | np.floating)
        or not 0 < group_weight <= 1
    ):
        raise ParameterError(f"group_weight must be a number in (0, 1], got {group_weight!r}")
    gw = float(group_weight) if keep_groups and data.tags is not None and refiner is not None else None
    stage_times: dict[str, float] = {}
    bisector = make_bisector(part, refiner, mode == "multilevel", int(threshold), seed, stage_times, gw)
    if refiner is None and mode != "multilevel":
        bisector = part
    level_labels: list[np.ndarray] | None = [] if record_levels else None
    if mesh.dim not in part.dims:
        raise ParameterError(f"model {part.name!r} does not handle {mesh.dim}D meshes")
    if absorb_fraction is None or not (0 <= absorb_fraction < 1):
        raise ParameterError(f"absorb_fraction must be in [0, 1), got {absorb_fraction}")

    if subset is not None:
        subset = np.asarray(subset)
        if subset.size == 0:
            raise ParameterError("subset is empty: give the ids of the cells to agglomerate")
        if not np.issubdtype(subset.dtype, np.integer):
            raise ParameterError("subset must contain integer cell ids")
        bad = subset[(subset < 0) | (subset >= n)]
        if bad.size:
            raise ParameterError(
                f"subset has {bad.size} unknown cell ids (valid: 0..{n - 1}), e.g. {id_list(bad)}"
            )
        nodes = sorted_unique(subset).astype(np.int64)
    elif mode == "coarsen":
        raise ParameterError("mode 'coarsen' needs a subset of cell ids")
    else:
        nodes = np.arange(n, dtype=np.int64)

    sub_mode = mode
    if mode == "multilevel":
        sub_mode = (
            "nref"
            if nref is not None
            else "target-size"
            if target_size is not None
            else "mult-factor"
            if mult_factor is not None
            else None
        )
        if sub_mode is None:
            raise ParameterError("mode 'multilevel' needs one of nref, target_size or mult_factor")
    if mode == "coarsen":
        sub_mode = (
            "kway"
            if k is not None
            else "nref"
            if nref is not None
            else "target-size"
            if target_size is not None
            else "mult-factor"
            if mult_factor is not None
            else None
        )
        if sub_mode is None:
            raise ParameterError("mode 'coarsen' needs one of k, nref, target_size or mult_factor")

    requested = None
    labels = np.zeros(nodes.size, dtype=np.int64)
    if sub_mode == "kway":
        _check_k(k, nodes.size)
        if not part.supports_kway:
            raise ParameterError(
                f"model {part.name!r} has no direct k-way mode; use nref, target-size or mult-factor"
            )
        requested = int(k)
        batch = make_batch(data, labels, nodes)
        if getattr(part, "wants_cell_boxes", False):
            from models.partition.rtree import cell_boxes

            lo_hi = cell_boxes(data.points, data.offsets, data.connectivity)
            batch.cell_boxes = (lo_hi[0][batch.node_ids], lo_hi[1][batch.node_ids])
        raw = np.asarray(part.kway(batch, int(k)), dtype=np.int64)
        labels = np.empty(nodes.size, dtype=np.int64)
        pos = np.empty(n, dtype=np.int64)
        pos[nodes] = np.arange(nodes.size)
        labels[pos[batch.node_ids]] = raw
        labels = compact_labels(labels)
        if refiner is not None:
            t = time.perf_counter()
            start = labels[pos[batch.node_ids]]
            refined = np.asarray(refiner.refine_kway(_weighted(batch, gw), start), dtype=np.int64)
            labels[pos[batch.node_ids]] = _purer(batch, gw, start, refined)
            labels = compact_labels(labels)
            stage_times["refine"] = time.perf_counter() - t
    elif sub_mode == "nref":
        if nref is None:
            raise ParameterError("nref is required for mode 'nref' (number of refinements)")
        if not isinstance(nref, int | np.integer) or isinstance(nref, bool) or nref < 0:
            raise ParameterError(f"nref must be an integer >= 0, got {nref!r}")
        if nref > MAX_NREF or 2**nref > nodes.size:
            raise ParameterError(
                f"nref = {nref} asks for 2^{nref} elements, more than the {nodes.size} cells to agglomerate"
            )
        requested = 2 ** int(nref)
        labels = recursive_bisection(
            data, bisector, nodes, labels, levels=int(nref), progress=progress, record=level_labels
        )
    elif sub_mode in ("target-size", "mult-factor", "segregated"):
        if sub_mode == "target-size":
            if target_size is None:
                raise ParameterError("target_size is required for mode 'target-size'")
            h = _positive(target_size, "target_size")
        else:
            if mult_factor is None:
                raise ParameterError(f"mult_factor is required for mode {sub_mode!r}")
            f = _positive(mult_factor, "mult_factor")
            if f > 1:
                raise ParameterError(f"mult_factor must be in (0, 1], got {f}")
        if sub_mode == "segregated":
            if data.tags is None:
                raise ParameterError(
                    "mode 'segregated' needs physical groups (cell data such as gmsh:physical or CellEntityIds)"
                )
            groups, labels = sorted_unique(data.tags[nodes], return_inverse=True)
            labels = labels.astype(np.int64)
            labels, _ = connected_parts(data, labels, nodes)
        if sub_mode in ("mult-factor", "segregated"):
            # h = f x the diameter of the whole mesh (or subset), in every group alike: elements of
            # one size across materials. (With each group's own diameter, a small inclusion gets
            # an h below its cells' size and stays unagglomerated: MeshEmilia at f = 0.04 gave
            # 1068 elements, 433 of them single cells of the three small layers; now 693.)
            from models.mesh.geometry import mesh_diameter

            if size_measure == "centroids":
                h = f * mesh_diameter(data.centroids[nodes])
            else:
                h = f * mesh_diameter(data.points[_used_points(data, nodes)])
        labels = recursive_bisection(
            data,
            bisector,
            nodes,
            labels,
            h=h,
            progress=progress,
            record=level_labels,
            size_measure=size_measure,
        )
    if (
        refiner is not None
        and hasattr(refiner, "polish")
        and sub_mode not in ("kway", "segregated")
        and labels.size
    ):
        # the recursion optimized each bisection alone; polish pairs of final parts for the k-way cut
        t = time.perf_counter()
        batch = make_batch(data, np.zeros(nodes.size, dtype=np.int64), nodes)
        pos = np.empty(n, dtype=np.int64)
        pos[nodes] = np.arange(nodes.size)
        start = compact_labels(labels)[pos[batch.node_ids]]
        polished = _purer(
            batch, gw, start, np.asarray(refiner.polish(_weighted(batch, gw), start), dtype=np.int64)
        )
        labels = labels.copy()
        labels[pos[batch.node_ids]] = polished
        stage_times["refine"] = stage_times.get("refine", 0.0) + time.perf_counter() - t
    t_part = time.perf_counter() - t0

    parts_before = int(np.count_nonzero(np.bincount(labels)))
    labels, parts_split = connected_parts(data, labels, nodes)
    labels, absorbed = absorb_fragments(data, labels, nodes, absorb_fraction, parts_before)
    labels = compact_labels(labels)
    # the count asked for, exactly: k, or 2^nref (nref and multilevel modes) unless the bisection
    # levels are recorded (a nested hierarchy: its last level must stay the last bisection's)
    exact = (sub_mode == "kway" or (sub_mode == "nref" and level_labels is None)) and not allow_extra
    asked = "2^nref" if sub_mode == "nref" else "k"
    recount = {}
    if exact:
        from models.partition.connect import exact_count

        labels, merged, resplit = exact_count(data, labels, nodes, int(requested), asked)
        recount = {"merged": merged, "split": resplit}
    n_agg = int(labels.max()) + 1 if labels.size else 0
    full = np.empty(n, dtype=np.int64)
    full[nodes] = labels
    rest = np.setdiff1d(np.arange(n), nodes, assume_unique=True)
    full[rest] = n_agg + np.arange(rest.size)  # cells outside the subset stay as they are
    t_conn = time.perf_counter() - t0 - t_part
    return Agglomeration(
        labels=full,
        n_elements=n_agg + rest.size,
        requested=requested,
        parts_before_split=parts_before,
        parts_split=parts_split,
        fragments_absorbed=absorbed,
        timings={"partition": t_part, "connect": t_conn, **stage_times},
        levels=level_labels,
        nodes=nodes if record_levels else None,
        exact=exact,
        recount=recount,
        asked=asked,
    )


def _weighted(batch: GraphBatch, group_weight: float | None) -> GraphBatch:
    """The batch a k-way refiner sees: edges between groups at group_weight (None: as it is)."""
    if group_weight is None:
        return batch
    from models.partition.groups import group_weighted

    return group_weighted(batch, group_weight)


def _purer(
    batch: GraphBatch, group_weight: float | None, before: np.ndarray, after: np.ndarray
) -> np.ndarray:
    """A refined k-way partition, unless (keeping groups) more cells are outside their part's
    majority group than before, or a part was emptied (flow refinement can swallow the small parts
    that following the groups leaves: sage-hetero nref 6 + fm on a generated `inclusions` mesh
    went to 29 of 64 elements, multilevel): then the partition before."""
    if group_weight is None or batch.tags is None:
        return after
    from models.partition.groups import kway_impurity

    lost = np.count_nonzero(np.bincount(after)) < np.count_nonzero(np.bincount(before))
    return (
        before
        if lost or kway_impurity(batch.tags, after) > kway_impurity(batch.tags, before) + 1e-9
        else after
    )


def _cells_nodes(data: CellData, cells: np.ndarray) -> np.ndarray:
    """Indices into `connectivity` of the nodes of `cells` (vectorized CSR gather)."""
    starts = data.offsets[cells]
    sizes = data.offsets[cells + 1] - starts
    first = np.zeros(cells.size + 1, dtype=np.int64)
    np.cumsum(sizes, out=first[1:])
    return np.repeat(starts - first[:-1], sizes) + np.arange(first[-1])


def _used_points(data: CellData, cells: np.ndarray) -> np.ndarray:
    """Boolean mask of the points used by `cells`."""
    used = np.zeros(data.points.shape[0], dtype=bool)
    used[data.connectivity[_cells_nodes(data, cells)]] = True
    return used


def _positive(v, name):
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a number, got {v!r}") from None
    if not np.isfinite(x) or x <= 0:
        raise ParameterError(f"{name} must be a positive number, got {v!r}")
    return x

"""The finest level of a hierarchy as aggregates of the cells (model_options["finest"] of
models.hierarchy.nested.build_hierarchy; issue 24, rounds five to eight): pyamg's standard aggregation
(or the quality-controlled pairs) of the cells' graph with rtree cuts of the aggregates' graph above
(`aggregated_levels`), or pyamg's aggregation inside the cuts of the cells (`aggregation_in_cuts`).
Imported by models.hierarchy.nested only; it imports nothing of it."""

from __future__ import annotations

import numpy as np

from models.mesh.celldata import CellData
from models.mesh.container import Mesh

# the default aggregation's strength threshold (issue 24, round nine): couplings weaker than 5% of
# the strongest at either end are left out of the finest aggregation (a 50:1 boundary layer: 19 ->
# 16 iterations against pyamg's 19; every other member of the family unchanged: no coupling that weak)
THETA = 0.05


def aggregated_levels(
    mesh: Mesh,
    data: CellData,
    tags,
    step: float,
    coarsest: int,
    opts: dict,
    how: str = "aggregation",
    counts: list | None = None,
    least: int = 1,
    stretch: float | None = None,
):
    """The default rtree hierarchy (issue 24, round five): the finest level a standard aggregation of
    the cells' graph (models.partition.rtree_aggregate), every coarser level rtree's cuts of the
    graph of the finest elements, `step` times fewer elements per level (count-weighted: a node
    weighs its cells; boxes the union of its cells'; the couplings summed over the cells'), no
    element across a physical group (tags). Returns (levels coarsest first, counts, the graphs of
    the levels' elements by level, the achieved (finest step, step)). counts: the coarser levels'
    element counts (coarsest first, each below the finest's), instead of `step` times fewer per level
    (bench_hierarchy_family's box measures at exactly 91 and 364 elements)."""
    from models.graph.batch import GraphBatch
    from models.partition.rtree import (
        STRETCH,
        _quotient,
        _renamed,
        _sweep_key,
        _sweep_rank,
        level_counts,
        rtree_levels,
    )
    from models.partition.rtree_aggregate import normalized_coupling, pyamg_aggregates, standard_aggregates
    from models.partition.rtree_strength import tpfa_boundary, tpfa_coupling

    G = data.graph
    n = G.n
    indptr, indices = np.asarray(G.indptr, dtype=np.int64), np.asarray(G.indices, dtype=np.int64)
    coupling = opts.get("coupling")
    if coupling is None:
        coupling = tpfa_coupling(indptr, indices, G.weights, data.centroids)
    coupling = np.asarray(coupling, dtype=np.float64)
    ip, ii, cw = indptr, indices, coupling
    if tags is not None:  # no element across a group: the graph without the edges between groups
        rows = np.repeat(np.arange(n), np.diff(indptr))
        keep = tags[rows] == tags[indices]
        ip = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(rows[keep], minlength=n), out=ip[1:])
        ii, cw = indices[keep], coupling[keep]
    # pyamg's symmetric strength |a_ij| / sqrt(a_ii a_jj) of the TPFA operator (Dirichlet boundary,
    # as models.hierarchy.multigrid.tpfa_poisson assembles it): the diagonal is the couplings' row sums
    # plus the boundary faces' transmissibilities
    owner, tb = tpfa_boundary(mesh, data)
    rows_all = np.repeat(np.arange(n), np.diff(indptr))
    diag = np.bincount(rows_all, weights=coupling, minlength=n) + np.bincount(owner, weights=tb, minlength=n)
    strength = normalized_coupling(ip, ii, cw, diag)
    if how == "luby":  # round five: vectorized Luby rounds (as many as the numbering's chains)
        agg = standard_aggregates(ip, ii, strength)
    elif how == "quality":  # round seven: Notay's quality-controlled pairwise aggregation
        from models.partition.rtree_aggregate import quality_aggregates

        passes = int(opts.get("passes", 2 if mesh.dim == 2 else 3))
        agg = quality_aggregates(
            ip,
            ii,
            cw,
            diag,
            passes=passes,
            bound=float(opts.get("bound", 8.0)),
            join_singletons=bool(opts.get("join", True)),
            maxsize=opts.get("maxsize"),
        )
    else:  # pyamg's compiled pass; "aggregation": the cells off the stars join by strength
        agg = pyamg_aggregates(ip, ii, strength if how == "aggregation" else None)
        theta = float(opts.get("theta", THETA))
        if how == "aggregation" and theta > 0:  # the weak couplings left out (anisotropic cells):
            # aggregates of the strong graph, the smallest merged until the count is the whole graph's
            from models.partition.rtree_aggregate import merge_smallest, strong_couplings

            sp_, si_, sw_ = strong_couplings(ip, ii, strength, theta)
            if si_.size < ii.size:
                agg = merge_smallest(ip, ii, strength, pyamg_aggregates(sp_, si_, sw_), int(agg.max()) + 1)
    k = int(agg.max()) + 1
    cnt = np.bincount(agg, minlength=k).astype(np.float64)
    qp, qi, qw = _quotient(indptr, indices, np.asarray(G.weights, dtype=np.float64), agg, k)
    _, _, qc = _quotient(indptr, indices, coupling, agg, k)
    mes = np.abs(np.asarray(data.measures, dtype=np.float64))
    msum = np.maximum(np.bincount(agg, weights=mes, minlength=k), 1e-300)
    cen = (
        np.column_stack(
            [
                np.bincount(agg, weights=mes * data.centroids[:, d], minlength=k)
                for d in range(data.centroids.shape[1])
            ]
        )
        / msum[:, None]
    )
    # the finest elements numbered along the domain's principal axis (as rtree numbers its levels)
    rank = _sweep_rank(_sweep_key(cen, msum))
    lo, hi = opts["boxes"]
    order = np.argsort(agg, kind="stable")
    starts = np.flatnonzero(np.r_[True, agg[order][1:] != agg[order][:-1]])
    boxes = (np.minimum.reduceat(lo[order], starts, axis=0), np.maximum.reduceat(hi[order], starts, axis=0))
    q = GraphBatch(
        indptr=qp,
        indices=qi,
        weights=qw,
        graph_ptr=np.array([0, k], dtype=np.int64),
        centroids=cen,
        measures=cnt,
        tags=None,
        node_ids=np.arange(k),
    )
    upper_counts = (
        level_counts(k, step, coarsest, given=0, least=least, stretch=STRETCH if stretch is None else stretch)
        if counts is None
        else [int(c) for c in counts if c < k]
    )
    graphs: list = []
    level_graphs = {}
    levels = [agg]
    if upper_counts:
        qtags = None
        if tags is not None:
            qtags = np.zeros(k, dtype=np.int64)
            qtags[agg] = tags
        up_opts = {
            key_: v
            for key_, v in opts.items()
            if key_ not in ("boxes", "balance", "coupling", "passes", "bound", "join", "maxsize", "theta")
        }
        if str(up_opts.get("axes", "")).startswith("strength"):
            up_opts["coupling"] = qc
        upper = rtree_levels(
            q, upper_counts, groups=qtags, balance="measure", boxes=boxes, graphs=graphs, **up_opts
        )
        levels = [u[agg] for u in upper] + [agg]
        level_graphs = {len(upper) - 1 - j: g for j, g in enumerate(graphs)}
    levels[-1] = rank[agg]
    level_graphs[len(levels) - 1] = _renamed(qp, qi, rank)
    return levels, [*upper_counts, k], level_graphs, (n / k, float(step))


def aggregation_strength(mesh: Mesh, data: CellData, coupling: np.ndarray, keep_label=None):
    """(indptr, indices, strength) of the cells' graph for pyamg's aggregation: pyamg's symmetric
    strength |a_ij| / sqrt(a_ii a_jj) of the TPFA operator (Dirichlet boundary, as
    models.hierarchy.multigrid.tpfa_poisson assembles it: the diagonal the couplings' row sums plus
    the boundary faces' transmissibilities). keep_label: (cells,) labels; only the edges inside one
    label are kept (no aggregate crosses a label; the diagonal stays the whole operator's)."""
    from models.partition.rtree_aggregate import normalized_coupling
    from models.partition.rtree_strength import tpfa_boundary

    G = data.graph
    n = G.n
    indptr, indices = np.asarray(G.indptr, dtype=np.int64), np.asarray(G.indices, dtype=np.int64)
    rows = np.repeat(np.arange(n), np.diff(indptr))
    owner, tb = tpfa_boundary(mesh, data)
    diag = np.bincount(rows, weights=coupling, minlength=n) + np.bincount(owner, weights=tb, minlength=n)
    ip, ii, cw = indptr, indices, coupling
    if keep_label is not None:
        keep = keep_label[rows] == keep_label[indices]
        ip = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(rows[keep], minlength=n), out=ip[1:])
        ii, cw = indices[keep], coupling[keep]
    return ip, ii, normalized_coupling(ip, ii, cw, diag)


def aggregation_in_cuts(
    mesh: Mesh,
    data: CellData,
    batch,
    tags,
    step: float,
    coarsest: int,
    opts: dict,
    counts=None,
    least: int = 1,
    stretch: float | None = None,
):
    """finest="nested" (issue 24, round eight): the coarser levels rtree's cuts of the CELLS (as
    finest="cuts" makes them, so they keep the cut boxes), their counts `step` times fewer per level
    from the count k0 of pyamg's standard aggregation of the whole cells' graph (k0 / step, ...);
    the finest level pyamg's standard aggregation (the cells off the stars joined by strength) of the
    cells' graph without the edges that cross an element of the level above, so every aggregate
    lies inside one element of it; then (model_options merge, default true) the smallest aggregates
    (those the cut sides clipped) join the neighbouring aggregate inside the same element they couple
    to most, until the count is k0 (merge_smallest) where the graph allows. Returns (levels coarsest first, the requested counts (the coarser
    levels', then k0: the finest level's count is measured against the unrestricted aggregation's),
    the graphs of the levels' elements by level, the achieved (finest step, step)).
    counts: the coarser levels' element counts (coarsest first) instead of k0 / step, ..."""
    from models.partition.rtree import STRETCH, _quotient, level_counts, rtree_levels
    from models.partition.rtree_aggregate import merge_smallest, pyamg_aggregates

    G = data.graph
    n = G.n
    indptr, indices = np.asarray(G.indptr, dtype=np.int64), np.asarray(G.indices, dtype=np.int64)
    opts = dict(opts)
    merge = bool(opts.pop("merge", True))
    coupling = opts.get("coupling")
    if coupling is None:
        from models.partition.rtree_strength import tpfa_coupling

        coupling = tpfa_coupling(indptr, indices, G.weights, data.centroids)
    coupling = np.asarray(coupling, dtype=np.float64)
    k0 = int(pyamg_aggregates(*aggregation_strength(mesh, data, coupling, tags)).max()) + 1
    upper = (
        level_counts(
            k0, step, coarsest, given=0, least=least, stretch=STRETCH if stretch is None else stretch
        )
        if counts is None
        else [int(c) for c in counts if c < k0]
    )
    graphs: list = []
    level_graphs = {}
    up_levels = []
    if upper:
        up_levels = [
            np.asarray(u, dtype=np.int64)
            for u in rtree_levels(batch, upper, groups=tags, graphs=graphs, **{**opts, "coupling": coupling})
        ]
        level_graphs = {len(up_levels) - 1 - j: g for j, g in enumerate(graphs)}
    within = up_levels[-1] if up_levels else tags
    ip, ii, strength = aggregation_strength(mesh, data, coupling, within)
    agg = pyamg_aggregates(ip, ii, strength)
    if merge:  # the aggregates the cut sides clipped: the smallest join a neighbour inside the parent
        agg = merge_smallest(ip, ii, strength, agg, k0)
    k = int(agg.max()) + 1
    qp, qi, _ = _quotient(indptr, indices, np.ones(indices.size), agg, k)
    level_graphs[len(up_levels)] = (qp, qi)
    return [*up_levels, agg], [*upper, k0], level_graphs, (n / k, float(step))

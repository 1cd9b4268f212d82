"""A hierarchy's plan as the domain allows it (issue 24, round ten): the domain's holes, the fewest
elements a level may have, level_counts' stretch, the planned counts held to the fewest, the notes
where levels leave the plan, and the partitioners' options that balance cells."""

from __future__ import annotations

import numpy as np

from models.hierarchy.topology import domain_holes, fewest_elements, piece_genus
from models.mesh.celldata import CellData
from models.mesh.container import Mesh


def domain_plan(mesh: Mesh, data: CellData):
    """What the domain asks of a hierarchy's plan: (domain_holes' pairs, the fewest elements a level
    may have and why, level_counts' stretch). A domain with holes or tunnels gets steps down to 15%
    shorter, so that the coarsest level is near --coarsest (its elements then surround fewer holes);
    elsewhere no step shorter than asked (round ten: on the 2D family at 10^5 the shorter steps cost
    1.08 -> 1.11 operator complexity)."""
    from models.graph.csr import connected_components
    from models.partition.rtree import STRETCH

    hole_pairs = domain_holes(mesh, data)
    pieces, body = connected_components(data.graph.indptr, data.graph.indices)
    genus = piece_genus(mesh, data.graph, body, pieces) if mesh.dim == 3 else None  # (a piece with a
    tunnels = genus is not None and bool(genus.any())  # tunnel needs two elements)
    least, why = fewest_elements(data, hole_pairs, genus, (pieces, body))
    stretch = STRETCH if (hole_pairs[0].size or tunnels) else 0.0
    return hole_pairs, least, why, stretch


STALL = 2.0  # a coarsest level coarsening less than this (pairwise aggregation's step) is dropped


def without_stalled_top(levels, polys, report: list[dict], counts: list[int], notes: list[str]):
    """A coarsest level left above its count that coarsens the level below less than STALL times
    (merges that stalled: 27 cavities at 6.5 10^5 cells, 19 elements from 29 for 2 planned; METIS 31
    from 33) is no level for multigrid: dropped, so the hierarchy ends one level finer, said in a
    note. (levels, polys, report, counts), coarsest first; report: fix_holes', before
    _with_requested."""
    if len(levels) < 2 or len(counts) != len(levels):
        return levels, polys, report, counts
    k0, k1 = int(levels[0].max()) + 1, int(levels[1].max()) + 1
    if k0 <= counts[0] or k1 >= STALL * k0:
        return levels, polys, report, counts
    notes.append(
        f"the coarsest level planned ({counts[0]:,} elements) stalled at {k0:,}, {k1 / k0:.1f}x fewer than "
        f"the level below, where {k1 / counts[0]:.1f}x were asked: elements that would enclose a hole or "
        f"a cavity or be a ring could not be merged further, so the hierarchy ends one level finer, at "
        f"{k1:,} elements"
    )
    return levels[1:], polys[1:], report[1:], counts[1:]


def said_off_plan(
    levels,
    report: list[dict],
    coarsest: int,
    notes: list[str],
    balls=None,
    least: int = 1,
    why: str = "",
    asked: int = 1,
    step: float | None = None,
) -> None:
    """A note where the levels left the plan (elements around holes cut, not merged back): the
    coarsest level above --coarsest or above the schedule's count `asked` (why: where the domain
    asks for `least` elements at least, domain_plan's or group_pieces'), levels more than 25% off their planned ratio (`report`:
    _with_requested's); balls: (mesh, graph, rings) for said_not_balls; step: the ratio asked of the
    levels above the finest, where the plan itself could not keep a level within 25% of it."""
    if balls is not None:
        said_not_balls(balls[0], balls[1], levels, report, notes, balls[2])
    from models.partition.rtree import RATIO_SLACK

    k0 = int(levels[0].max()) + 1
    top = report[0] if report else {}
    planned = top.get("requested", coarsest)
    if why and asked < k0 <= least:  # (the domain or the groups ask for them)
        than = f"more than --coarsest {coarsest}" if k0 > coarsest else f"not {asked:,}"
        notes.append(f"the coarsest level has {k0:,} elements, {than}: {why}")
    elif k0 > planned and (top.get("ring_cuts") or top.get("split_into_children")):
        # (above the plan but within --coarsest too: a block with 6 cavities, METIS, 4 for 3)
        what = (
            "surround a hole"
            if balls is None or balls[0].dim == 2
            else "not be balls (rings around a tunnel or a neighbour, or around a cavity)"
        )
        than = f"more than --coarsest {coarsest}" if k0 > coarsest else f"not the {planned:,} planned"
        notes.append(
            f"the coarsest level has {k0:,} elements, {than}: elements that would "
            f"{what} were cut and could not all be merged back"
        )
    elif k0 > planned:  # (where the plan asked for more: said above, or the drop's note)
        than = (
            f"more than --coarsest {coarsest} and than planned"
            if k0 > coarsest
            else f"not the {planned:,} planned"
        )
        notes.append(f"the coarsest level has {k0:,} elements, {than}")
    far = [r for r in report if "asked_ratio" in r and abs(r["ratio"] / r["asked_ratio"] - 1.0) > RATIO_SLACK]
    if far:
        notes.append(said_off_asked(far, report, coarsest, least, why))
    elif step and not any("asked_ratio" in r for r in report):  # (a report without the ratios asked)
        said_plan_off(report, float(step), coarsest, least, why, notes)
    off = [
        f"level {r['level']} {r['ratio']:.1f}x (planned {r['requested_ratio']:.1f}x)"
        for r in report
        if "requested_ratio" in r
        and abs(r["ratio"] / r["requested_ratio"] - 1.0) > RATIO_SLACK
        and not any(r is f for f in far)  # (said with the ratio asked)
    ]
    if off:
        notes.append("coarsened off the plan by more than 25%: " + ", ".join(off))


def with_requested(report: list[dict], counts: list[int], n: int) -> list[dict]:
    """fix_holes' per-level report with the requested count and step ratio of each level (where the
    levels are the requested ones) and the achieved ratio against the requested one."""
    out = []
    same = len(counts) == len(report)
    for L, r in enumerate(report):
        r = {"level": L, **r}
        if same:
            below = n if L + 1 == len(counts) else counts[L + 1]
            r["requested"] = int(counts[L])
            r["requested_ratio"] = below / counts[L]
            r["ratio_vs_requested"] = r["ratio"] / r["requested_ratio"]
        out.append(r)
    return out


def with_asked(report: list[dict], ratio, finest: bool = True, head: bool = True) -> list[dict]:
    """The report's levels (coarsest first) with the ratio asked of each (`asked_ratio`, the step from
    the level below it: the schedule's steps from the finest level up, the last repeated) and the
    ratio achieved against it (`ratio_vs_asked`). finest False: the finest level's count was asked of
    no ratio (pyamg's aggregation of the cells, a job's own elements), the steps start above it; head
    False: every step the schedule's last (the cuts above an aggregated finest level)."""
    sched = [float(r) for r in np.atleast_1d(np.asarray(ratio, dtype=np.float64))]
    sched = sched if head else sched[-1:]
    m = len(report) - (0 if finest else 1)
    steps = [sched[min(j, len(sched) - 1)] for j in range(max(m, 0))]
    for r, a in zip(report[::-1][(0 if finest else 1) :], steps, strict=True):
        r["asked_ratio"] = a
        r["ratio_vs_asked"] = r["ratio"] / a
    return report


def said_off_asked(far: list[dict], report: list[dict], coarsest: int, least: int, why: str) -> str:
    """One sentence for the levels (`far`, with_asked's) that coarsen more than 25% off the ratio asked
    (not only off their plan, which the domain may have moved: 8 inclusions, --groups, level 0 10.8x
    for 16x asked, 13x planned, went without a word): each level's ratio achieved, asked and planned,
    and where the plan itself is that far off, why (said_plan_off's reason)."""
    from models.partition.rtree import RATIO_SLACK

    def one(r):
        planned = r.get("requested_ratio")
        shown = planned is not None and abs(planned / r["asked_ratio"] - 1.0) > 0.01
        return f"level {r['level']} {r['ratio']:.1f}x where {r['asked_ratio']:g}x was asked" + (
            f" ({planned:.1f}x planned)" if shown else ""
        )

    text = (
        f"{'a level coarsens' if len(far) == 1 else f'{len(far)} levels coarsen'} more than 25% off the "
        f"ratio asked: {', '.join(one(r) for r in far)}"
    )
    planned_off = [
        r
        for r in far
        if "requested_ratio" in r and abs(r["requested_ratio"] / r["asked_ratio"] - 1.0) > RATIO_SLACK
    ]
    if planned_off and report:
        text += f" (no plan came closer: {_no_counts(report, coarsest, least, why)})"
    return text


def _no_counts(report: list[dict], coarsest: int, least: int, why: str) -> str:
    """Why no plan keeps every level within 25% of the ratio asked (said_plan_off's reason)."""
    kf, k0 = int(report[-1]["elements"]), int(report[0].get("requested", report[0]["elements"]))
    end = (
        f"the {least:,} elements the coarsest level needs ({why})"
        if least > 1 and k0 <= least
        else f"at most --coarsest {coarsest}"
    )
    return (
        f"no whole counts in steps within 25% of it run from the finest level's {kf:,} elements down to {end}"
    )


def said_plan_off(
    report: list[dict], step: float, coarsest: int, least: int, why: str, notes: list[str]
) -> None:
    """A note where the plan itself keeps a level above the finest more than 25% off the ratio asked:
    no whole counts in steps within 25% of it run from the finest level's count to a coarsest count
    the domain allows (8 ball inclusions, --groups: at least 10 coarsest elements, 8,294 finest
    aggregates, 10 > 32 > 518 planned)."""
    from models.partition.rtree import RATIO_SLACK

    off = [
        f"level {r['level']} {r['requested_ratio']:.1f}x"
        for r in report[:-1]
        if "requested_ratio" in r and abs(r["requested_ratio"] / step - 1.0) > RATIO_SLACK
    ]
    if not off or not report:
        return
    notes.append(
        f"planned off the ratio {step:g}x by more than 25% ({', '.join(off)}): "
        + _no_counts(report, coarsest, least, why)
    )


def count_weighted(model: str, options: dict | None) -> dict:
    """The model's options for a hierarchy: METIS and k-means balance cell counts, not measures or
    space (balance="cells"), as rtree's cuts do, so that an element's size follows the local cell
    size (issue 24: measure-weighted METIS parts hold thousands of cells where the mesh is fine and a
    handful where it is coarse; on a 1000:1 graded mesh 101 smoothed iterations against pyamg's 17,
    cell-weighted 11; elongated holes 28 -> 12 against 15; 60 random holes 22 -> 11 against 14.
    METIS with unit node weights gave the same iterations but on the coarse graphs 91 of 121 elements
    of a genus-4 plate wrapped around a neighbour, cell counts 16)."""
    out = dict(options or {})
    if model in ("metis", "kmeans"):
        out.setdefault("balance", "cells")
    return out


def at_least(counts: list[int], least: int) -> list[int]:
    """The planned counts (coarsest first) with the coarsest level at least `least` elements (a level
    that would then coarsen the next less than STALL times is dropped). Why is said once the levels are made (said_off_plan):
    the finest aggregation plans the levels above it again."""
    counts = list(counts)
    while counts and counts[0] < least:  # (a loop over the levels dropped: few)
        counts = counts[1:] if len(counts) > 1 and counts[1] < STALL * least else [least, *counts[1:]]
    return counts


def group_pieces(data: CellData, groups, least: int, why: str, mesh: Mesh | None = None) -> tuple[int, str]:
    """With --groups a level has at least one element per connected piece of a physical group (no
    element crosses a group), two for a piece around a hole, a tunnel or another piece (one element
    would enclose it or be a ring; mesh: where it is given): (the fewest elements, why), the domain's
    own where it asks for more; ParameterError where the groups leave nothing to coarsen (every
    piece one cell). groups: each cell's group (compact labels)."""
    from models.errors import ParameterError
    from models.graph.csr import connected_components

    n = int(groups.size)
    pieces, body = connected_components(data.graph.indptr, data.graph.indices, groups)
    if pieces >= n:
        raise ParameterError(
            f"the physical groups leave nothing to coarsen: each of the {n:,} cells is a piece of its "
            "group on its own, and no element crosses a group (--groups); drop --groups"
        )
    holed = 0
    if mesh is not None:
        genus, shells = piece_genus(mesh, data.graph, body.astype(np.int64), pieces, True, across=True)
        holed = int(np.count_nonzero((genus > 0) | (shells > 1)))
    if pieces + holed <= least:
        return least, why
    return pieces + holed, (
        f"no element crosses a physical group (--groups), and the groups form {pieces:,} separate pieces"
        + (f", {holed:,} of them around a hole, a tunnel or another piece" if holed else "")
    )


def said_not_balls(mesh, graph, levels, report: list[dict], notes: list[str], rings: bool) -> None:
    """3D: each level's elements that are not balls (Euler characteristic of their cells other than 1:
    rings around a tunnel or a neighbour, elements around a cavity) in the report (`not_balls`), and
    a note where there are any (models.polytope.euler.level_euler: one incidence pass)."""
    if mesh.dim != 3:
        return
    from models.polytope.euler import level_euler

    chis = level_euler(mesh, graph, levels)
    bad = [int(np.count_nonzero(c != 1)) for c in chis]
    for r, b in zip(report, bad, strict=True):
        r["not_balls"] = b
    if sum(bad):
        where = ", ".join(f"{b} on level {L}" for L, b in enumerate(bad) if b)
        ring = sum(int(np.count_nonzero(c < 1)) for c in chis)
        hollow = sum(int(np.count_nonzero(c > 1)) for c in chis)
        kinds = [f"{ring:,} ring{'s' if ring > 1 else ''} around a tunnel or a neighbour"] if ring else []
        kinds += [f"{hollow:,} around a cavity (an enclosed void)"] if hollow else []
        notes.append(
            f"{sum(bad):,} element{'s are' if sum(bad) > 1 else ' is'} not balls ({where}): {' and '.join(kinds)}"
            + (", kept as asked (--keep-rings)" if not rings else " that cutting could not remove")
        )

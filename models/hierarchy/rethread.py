"""The coarse end of a 2D hierarchy on a domain with many holes, merged down to its planned count
with holes threaded through every level (issue 24).

Where fix_holes leaves the coarsest level above its count (elements that would surround a hole
were cut, and no pair of neighbours merges without surrounding one), two neighbouring coarsest
elements are merged anyway, and each hole their union surrounds is threaded: the shortest path of
the FINEST level's elements from the hole to another coarsest element moves, at every level above
the finest, into the element of the unit it reaches (so the levels stay exactly nested). A thread of
units of a few cells opens a hole where a thread of the level below (fix_holes' threading) is too
thick to fit. A merge is kept only if every element it changed, at every level, stays connected and
has Euler characteristic 1 (encloses nothing, touches itself nowhere); otherwise it is undone and
that pair is not tried again. On 60 random holes (21,583 triangles) the coarsest level went from 15
elements (5.0x, planned 7.5x) to the plan.
"""

from __future__ import annotations

import numpy as np

from models.mesh.celldata import CellData, compact_labels
from models.mesh.container import Mesh


def _sound(mesh, graph, finest, unit_to, levels_changed, qp, qi) -> bool:
    """Every element of the given (level, elements) pairs connected over the units' graph and with
    Euler characteristic 1."""
    from models.graph.csr import connected_components
    from models.polytope.euler import element_euler

    for L, els in levels_changed:
        lab = unit_to[L]
        k = int(lab.max()) + 1
        mine = np.zeros(k, dtype=bool)
        mine[els] = True
        units = np.flatnonzero(mine[lab])
        if units.size == 0:
            continue
        comp = connected_components(qp, qi, labels=lab)[1]  # pieces of every element (compiled)
        if np.unique(comp[units]).size != np.unique(lab[units]).size:
            return False
        chi = element_euler(mesh, graph, lab[finest], cells=np.flatnonzero(mine[lab[finest]]))
        if np.any(chi[els] != 1):
            return False
    return True


def _absorb_pieces(unit_to, before, on_path, qp, qi) -> None:
    """A thread that cuts an element of a level in pieces: every piece but the largest joins the
    element of a thread unit it touches, at that level and every coarser one (the levels stay
    nested), finest levels first. before: the labels before the threads. In place; on_path grows by
    the pieces."""
    from models.graph.csr import connected_components
    from models.mesh.cells import ranges

    ku = on_path.size
    for L in range(len(unit_to) - 1, -1, -1):  # a loop over the levels, finest first
        lab = unit_to[L]
        touched = np.unique(before[L][np.flatnonzero(on_path)])  # the elements threads went through
        mine = np.isin(lab, touched) & ~on_path
        units = np.flatnonzero(mine)
        if units.size == 0:
            continue
        # pieces: the thread's units each a label of their own, so no piece runs through them
        split = np.where(on_path, int(lab.max()) + 1 + np.arange(ku), lab)
        comp = connected_components(qp, qi, labels=split)[1].astype(np.int64)
        c = comp[units]
        size = np.bincount(c)
        el = lab[units]
        # the largest piece of each element stays
        order = np.lexsort((-size[c], el))
        first = np.r_[True, el[order][1:] != el[order][:-1]]
        keep_piece = np.zeros(size.size, dtype=bool)
        keep_piece[c[order][first]] = True
        loose = units[~keep_piece[c]]
        for _ in range(loose.size):  # a loop over rounds: pieces next to the thread first
            if loose.size == 0:
                break
            deg = qp[loose + 1] - qp[loose]
            src = np.repeat(loose, deg)
            nb = qi[ranges(qp[loose], deg)]
            hit = on_path[nb]
            if not hit.any():
                break
            u, first_hit = np.unique(src[hit], return_index=True)
            t = nb[hit][first_hit]
            pc = comp[u]  # whole pieces go with the first of their units that touches the thread
            pcs, at = np.unique(pc, return_index=True)
            go = np.isin(comp[loose], pcs)
            tgt = np.zeros(comp.max() + 1, dtype=np.int64)
            tgt[pcs] = t[at]
            moving = loose[go]
            for M in range(L + 1):
                unit_to[M][moving] = unit_to[M][tgt[comp[moving]]]
            on_path[moving] = True
            loose = loose[~go]


def _threadable(mesh, graph, cell_labels, hole_id, hole_unit, top, pairs, k0) -> np.ndarray:
    """For each pair (a * k0 + b, sorted) of neighbouring coarsest elements: does their union
    surround nothing but domain holes lying between the two alone (its Euler characteristic is 1
    less one per such hole)? A union around another element cannot be opened by threads."""
    from models.polytope.euler import union_euler

    def among(key):  # (positions in `pairs` of the keys found there; which keys those are)
        at = np.minimum(np.searchsorted(pairs, key), pairs.size - 1)
        hit = pairs[at] == key  # (pairs across physical groups are not candidates)
        return at[hit], hit

    a, b, uchi, _ = union_euler(mesh, graph, cell_labels)
    chi = np.zeros(pairs.size, dtype=np.int64)
    at, hit = among(a * np.int64(k0) + b)
    chi[at] = uchi[hit]
    he = np.unique(hole_id * np.int64(k0) + top[hole_unit])  # (hole, element) pairs
    h, el = he // k0, he % k0
    two = np.bincount(h)[h] == 2  # holes along exactly two elements: the union of those surrounds it
    holes = np.zeros(pairs.size, dtype=np.int64)
    np.add.at(holes, among(el[two][0::2] * np.int64(k0) + el[two][1::2])[0], 1)
    return chi + holes == 1


def rethread_coarse(
    mesh: Mesh,
    data: CellData,
    levels: list[np.ndarray],
    hole_pairs: tuple[np.ndarray, np.ndarray],
    target: int,
    groups: np.ndarray | None = None,
) -> tuple[list[np.ndarray], int]:
    """Merge coarsest elements pairwise (the smallest pair sharing most first) down to `target`,
    threading the holes each union would surround through every level (module docstring). 2D
    domains with holes only; groups (a compact group per cell): no merge across one. Returns the
    levels and the merges kept."""
    from models.hierarchy.holes import _path_out
    from models.partition.rtree import _quotient

    hole_id, hole_cell = hole_pairs
    if mesh.dim != 2 or hole_id.size == 0 or len(levels) < 2:
        return levels, 0
    g = data.graph
    finest = np.asarray(levels[-1], dtype=np.int64)
    ku = int(finest.max()) + 1
    qp, qi, qw = _quotient(g.indptr, g.indices, g.weights, finest, ku)
    unit_to = []
    for lv in levels[:-1]:
        u = np.zeros(ku, dtype=np.int64)
        u[finest] = lv
        unit_to.append(u)
    ugroup = None
    if groups is not None:
        ugroup = np.zeros(ku, dtype=np.int64)
        ugroup[finest] = groups
    hu = finest[hole_cell]
    hptr = np.searchsorted(hole_id, np.arange(int(hole_id[-1]) + 2))
    cells_of_unit = np.bincount(finest, minlength=ku)
    pred = np.full(ku, -2, dtype=np.int64)
    forbid: set = set()
    kept = 0
    viable = None
    k_start = int(unit_to[0].max()) + 1
    for _ in range(
        4 * max(k_start - target, 0) + 8
    ):  # a loop over tried merges (each about 1/100 of a METIS call)
        top = unit_to[0]
        k0 = int(top.max()) + 1
        if k0 <= target:
            break
        a = np.repeat(np.arange(ku), np.diff(qp))
        ea, eb = top[a], top[qi]
        cross = ea < eb
        if ugroup is not None:
            cross &= ugroup[a] == ugroup[qi]
        key = ea[cross] * np.int64(k0) + eb[cross]
        pairs, inv = np.unique(key, return_inverse=True)
        w = np.bincount(inv, weights=qw[cross])
        size = np.bincount(top, weights=cells_of_unit, minlength=k0)
        if pairs.size == 0:
            break
        pa, pb = pairs // k0, pairs % k0
        if viable is None or viable[0] != k0:  # (the labels changed: a merge was kept)
            viable = (k0, _threadable(mesh, g, top[finest], hole_id, hu, top, pairs, k0))
        # the pairs whose unions surround domain holes only (threads open nothing else), by the
        # smaller one's size, then the larger shared weight
        order = np.lexsort((-w, np.minimum(size[pa], size[pb])))
        order = order[viable[1][order]]
        first_unit = np.full(k0, ku, dtype=np.int64)
        np.minimum.at(first_unit, top, np.arange(ku))
        pick = None
        for i in order:  # a loop over the candidate pairs until one not tried before
            fk = (int(first_unit[pa[i]]), int(first_unit[pb[i]]))
            if fk not in forbid:
                pick = i, fk
                break
        if pick is None:
            break
        i, fk = pick
        e, f = int(pa[i]), int(pb[i])
        parent = np.zeros(k0, dtype=np.int64)  # threads end in an element of the same group
        if ugroup is not None:
            parent[top] = ugroup
        saved = [u.copy() for u in unit_to]
        counts = [int(np.unique(u).size) for u in unit_to]
        unit_to[0] = np.where(top == f, e, top)
        moved = unit_to[0] == e  # the units whose elements may change, at some level
        on_path = np.zeros(ku, dtype=bool)
        ok = True
        lo = np.full(hptr.size - 1, k0, dtype=np.int64)
        hi = np.full(hptr.size - 1, -1, dtype=np.int64)
        np.minimum.at(lo, hole_id, unit_to[0][hu])
        np.maximum.at(hi, hole_id, unit_to[0][hu])
        for h in np.flatnonzero((lo == e) & (hi == e)):  # a loop over the holes the union surrounds
            us = np.unique(hu[hptr[h] : hptr[h + 1]])
            if np.any(unit_to[0][us] != e):  # (opened by an earlier thread of this merge)
                continue
            found, seen = _path_out(qp, qi, unit_to[0], parent, us, e, pred)
            pred[seen] = -2
            if found is None or found[0].size >= int((unit_to[0] == e).sum()):
                ok = False
                break
            path, other = found
            nb = qi[qp[path[0]] : qp[path[0] + 1]]
            t = int(nb[unit_to[0][nb] == other][0])  # the unit the path reaches
            for L in range(len(unit_to)):
                unit_to[L][path] = unit_to[L][t]
            moved[path] = True
            on_path[path] = True
        if ok:
            _absorb_pieces(unit_to, saved, on_path, qp, qi)
        if ok:
            ok = int(np.unique(unit_to[0]).size) == counts[0] - 1 and all(
                int(np.unique(unit_to[L]).size) == counts[L] for L in range(1, len(unit_to))
            )  # no element emptied
        if ok:
            unit_to[0] = compact_labels(unit_to[0])
            # level 0: the merged element and every one a thread or a piece joined; finer levels: the
            # elements threads and pieces left or joined (the others are as they were)
            ch = [(0, np.unique(unit_to[0][moved]))]
            ch += [(L, np.union1d(unit_to[L][on_path], saved[L][on_path])) for L in range(1, len(unit_to))]
            ok = _sound(mesh, g, finest, unit_to, ch, qp, qi)
        if ok:
            kept += 1
        else:
            unit_to = saved
            forbid.add(fk)
    out = [u[finest] for u in unit_to] + [finest]
    return out, kept


def coarse_end(mesh, data, levels, polys, report, hole_pairs, plan, groups):
    """A coarsest level left above its count (plan: each level's count, coarsest first). 3D (rings
    cut): levels above their counts merged where the union's Euler characteristic is 1. 2D, by holes: merged down with the holes threaded, with the
    coarsest units that do it (a level's elements: only the levels above it change; the finest
    level's last: on 100 pinholes at 10^5 cells 0.75x pyamg's iterations, against 0.94x with the
    finest units alone). The finest units alone from the levels as given were tried as well where
    that stayed short: on 25 holed meshes (random holes, pinholes, plates) they never reached further,
    and on 100 pinholes they took half the build; the report's counts and ratios follow."""
    plan = [int(plan)] if np.ndim(plan) == 0 else [int(c) for c in plan]  # (an int: the coarsest's)
    want = plan[0]
    k0 = int(levels[0].max()) + 1
    if (
        mesh.dim == 3
        and len(levels) > 1
        and any(int(lv.max()) + 1 > c for lv, c in zip(levels, plan, strict=False))
    ):
        kept = [dict(r) for r in report]
        got = _safe_coarsest(mesh, data, levels, polys, report, plan, groups, hole_pairs)
        if _cavities_held(got[0], hole_pairs) > _cavities_held(levels, hole_pairs):
            return levels, polys, kept  # (a merge that surrounds a cavity the checks missed: not kept)
        return got
    if mesh.dim != 2 or k0 <= want or not hole_pairs[0].size or len(levels) < 2:
        return levels, polys, report
    new, kept = list(levels), 0
    for u in range(2, len(levels)):  # coarse units first (a thread changes the levels above them only;
        # the level below the coarsest is too coarse to thread: 1 merge kept in 49 tried on 100 pinholes)
        if int(new[0].max()) + 1 <= want:
            break
        sub, got = rethread_coarse(mesh, data, new[: u + 1], hole_pairs, want, groups=groups)
        new, kept = sub + new[u + 1 :], kept + got
    if not kept:
        return levels, polys, report
    report[0]["threaded_merges"] = kept
    return new, *_changed(mesh, levels, new, polys, report)


def _cavities_held(levels, hole_pairs) -> int:
    """The cavities of the domain (hole_pairs: (cavity, cell) pairs) along one element alone, summed
    over the levels."""
    from models.hierarchy.topology import alone_around

    return sum(int(alone_around(hole_pairs, lv)[0].size) for lv in levels)


def _excess(levels, plan) -> int:
    """Elements above the plan, summed over the levels."""
    return sum(max(int(lv.max()) + 1 - c, 0) for lv, c in zip(levels, plan, strict=False))


def _safe_coarsest(mesh, data, levels, polys, report, plan, groups, hole_pairs=None):
    """coarse_end in 3D: whole coarsest elements merged where their union's characteristic is 1 (no
    ring, no cavity made; models.polytope.euler.merge_safely): nested as before. On a torus of
    95,605 cells with rings cut, 8 -> 6 coarsest elements (5 planned) in 0.18 s. Where a level stays
    above its count, the levels above a finer level u (the one below the finest level stalled, then
    the next) are made again from u's elements the same way (UnitEuler: their skeleton alone is read;
    merged down to each level's count in turn, so they stay nested), the most compact unions first
    (then the smallest first): the elements that cuts and merges back leave are tangled (neighbours
    sharing faces in up to a dozen patches), finer levels' elements less so (METIS on a block with a
    square hole: 17 coarsest for 10 from level 1's elements, 10 from level 2's)."""
    from models.polytope.euler import merge_safely

    w = np.abs(data.measures)
    cells = np.arange(mesh.n_cells)
    new0, merged = merge_safely(
        mesh, data.graph, levels[0], plan[0], sizes=w, keep=groups, forbid=_enclosing(data, cells, hole_pairs)
    )
    new = [new0, *levels[1:]]
    stalled = [L for L in range(len(new) - 1) if int(new[L].max()) + 1 > plan[L]]
    repaired = 0
    if stalled:
        # merging is stuck: at the stall every union of neighbours has a handle. The levels above a
        # finer unit level (the one below the finest level stalled) cut anew and repaired into balls
        # (models.hierarchy.repair; a few seeds: each repair is a local search), before merging
        # again from finer units: a torus of 932,084 cells 4 coarsest for 4 where merging stayed at
        # 43-45, at a third of its time
        from models.hierarchy.repair import TRIES, balls_above

        u0 = min(stalled[-1] + 2, len(levels) - 1)
        # then the next finer unit level once: plane cuts of finer units are less jagged (4 fibres
        # through a cube, --groups: from level 2's 1,372 units the planes through the fibres left 3
        # handles after the repair, from level 3's 21,810 none: 7 coarsest for 6, merges gave 13)
        tries = [(u0, range(TRIES))] + ([(u0 + 1, (0,))] if u0 + 1 < len(levels) else [])
        for u, seeds in tries:  # a loop over the unit levels tried (balls_above tries the seeds)
            got = balls_above(
                mesh,
                data,
                levels,
                u,
                plan,
                hole_pairs,
                groups=groups,
                seeds=seeds,
                accept=lambda g, worst=_excess(new, plan): _excess(g, plan) < worst,
            )
            if got is not None:
                new, repaired, merged = got, u, 0
                break
    if stalled and _excess(new, plan):
        # two unit levels, the finer first: its elements tangle less (27 cavities at 2 10^5 cells: 10
        # coarsest from level 2's, 11 from level 1's; METIS on a block with a square hole: 10 and
        # 17); not the finest aggregates (a torus of 10^6 cells: 38 s, and no further)
        for u in range(min(stalled[-1] + 2, len(levels) - 1), stalled[-1], -1):  # a loop over unit levels
            got = _remade_above(mesh, data, levels, u, plan, w, groups, hole_pairs)
            if got is not None and _excess(got[0], plan) < _excess(new, plan):
                new, merged = got
            if _excess(new, plan) == 0:
                break
    if not merged and not repaired:
        return levels, polys, report
    report[0]["safe_merges"] = merged
    if repaired:
        report[0]["repaired_from_level"] = repaired
    return new, *_changed(mesh, levels, new, polys, report)


def _changed(mesh, levels, new, polys, report):
    """(polys, report) for levels made anew: a level's polytopes dropped where it changed (merged
    again on writing), every level's count and ratio from the new levels."""
    from models.hierarchy.holes import recount_report

    polys = [p if np.array_equal(a, b) else None for a, b, p in zip(levels, new, polys, strict=True)]
    recount_report(report, new, mesh.n_cells)
    return polys, report


def _enclosing(data, units: np.ndarray, hole_pairs):
    """merge_safely's forbid for unions of units (units: a unit per cell): the pairs of elements whose
    union would enclose a cavity of the domain (the only two elements along it) or another element
    (one off the outer boundary whose only neighbours are the two). A 3D union of characteristic 1
    may have a handle and a cavity: on 27 cavities at 10^5 cells, 5 of 10 coarsest elements did."""
    from models.hierarchy.topology import unit_sides
    from models.partition.rtree import _quotient

    g = data.graph
    ku = int(units.max()) + 1
    if ku == units.size and np.array_equal(units, np.arange(ku)):  # the cells themselves: their own graph
        qp, qi = g.indptr, g.indices
    else:
        qp, qi, _ = _quotient(g.indptr, g.indices, g.weights, units, ku)
    src = np.repeat(np.arange(ku), np.diff(qp))
    outer, cav_id, cav_unit = unit_sides(data, units, ku, hole_pairs)

    def forbid(lab, k):
        kk = np.int64(k)
        keys = []
        if cav_id.size:  # cavities along exactly two elements
            ce = np.unique(cav_id * kk + lab[cav_unit])
            h, e = ce // kk, ce % kk
            two = np.bincount(h)[h] == 2
            pair = e[two].reshape(-1, 2)
            keys.append(pair[:, 0] * kk + pair[:, 1])
        a, b = lab[src], lab[qi]
        m = a != b
        pe = np.unique(a[m] * kk + b[m])
        s_, d_ = pe // kk, pe % kk
        out_el = np.zeros(k, dtype=bool)
        out_el[lab[outer]] = True
        inner2 = (np.bincount(s_, minlength=k) == 2) & ~out_el
        nb = d_[inner2[s_]].reshape(-1, 2)  # (each such element's two neighbours, in order)
        keys.append(np.minimum(nb[:, 0], nb[:, 1]) * kk + np.maximum(nb[:, 0], nb[:, 1]))
        return np.concatenate(keys) if keys else np.zeros(0, dtype=np.int64)

    return forbid


AHEAD = 256  # the most elements a level is merged from looking one merge ahead (a few seconds at 10^6 cells)


def _remade_above(mesh, data, levels, u: int, plan, w, groups, hole_pairs=None):
    """Levels 0..u-1 made again by merging level u's elements where the union is a ball, down to each
    level's planned count in turn (finest first; a level that stops above it is kept so): (levels,
    merges), or None where u's elements are not all balls. Each level merges the one below's
    elements as units (UnitEuler.coarser: their skeleton alone); a level left above its count from
    at most AHEAD elements is merged again looking one merge ahead (merge_ahead)."""
    from models.polytope.euler import UnitEuler, merge_ahead, merge_safely

    units = levels[u]
    ku = int(units.max()) + 1
    ue0 = UnitEuler.of_cells(mesh, data.graph, units)
    if not np.all(ue0.chi == 1):  # (a union of units can be a ball only if they are)
        return None
    keep0 = None
    if groups is not None:
        keep0 = np.zeros(ku, dtype=np.int64)
        keep0[units] = groups
    best = None
    for compact in (True, False):  # compact unions first (60-80% of the pairs otherwise tangled)
        cur, ue, total, out = units, ue0, 0, []  # cur: each cell's element of the level below
        for L in range(u - 1, -1, -1):  # a loop over the levels remade, finest first
            k = int(cur.max()) + 1
            uw = np.bincount(cur, weights=w, minlength=k)
            keep = None
            if keep0 is not None:
                keep = np.zeros(k, dtype=np.int64)
                keep[cur] = groups
            if plan[L] == 1 and keep is None:  # one element: the whole (connected) domain, a ball
                # where the plan allows one (domain_plan), whatever unions lie on the way
                lab, m = np.zeros(k, dtype=np.int64), k - 1
            else:
                args = dict(sizes=uw, keep=keep, unions=ue.unions, forbid=_enclosing(data, cur, hole_pairs))
                lab, m = merge_safely(mesh, data.graph, np.arange(k), plan[L], compact=compact, **args)
                if compact and int(lab.max()) + 1 > plan[L] and k <= AHEAD:  # (once: it has no order)
                    la, ma = merge_ahead(mesh, data.graph, np.arange(k), plan[L], **args)
                    if la.max() < lab.max():
                        lab, m = la, ma
            total += m
            if L:
                ue = ue.coarser(lab)
            cur = lab[cur]
            out.insert(0, cur)
        got = [*out, *levels[u:]]
        if best is None or _excess(got, plan) < _excess(best[0], plan):
            best = (got, total)
        if _excess(best[0], plan) == 0:
            break
    return best

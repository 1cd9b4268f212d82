"""Coarse 3D levels made balls by moving units between neighbouring elements (issue 24, round
seventeen).

Where a 3D coarsest level stalls above its count, merging whole elements cannot go further: at the
stall every union of neighbours has a handle (graded 100:1 cube, 9 coarsest for 6: of the 2^9 - 1
unions of its elements, only the singletons and the whole domain are balls). The handles are made
where elements are cut from jagged units (aggregates of aggregates): a unit of one element reaches
around a unit of another and touches its own element again along an edge. Even the plane sweeps of
the finest aggregates have them (half a cube by aggregate centroids: characteristic -1 to -5).

So the levels above a unit level are cut anew (METIS k-way of the units, each element's share of
the next level inside it) and repaired: single units move to a neighbouring element of the same
parent where that lowers the total of handles and cavities (Euler characteristics of the elements
before and after, from the units' shared skeleton, `UnitEuler`), each move checked exactly (the
element connected, its complement connected: no cavity), sideways moves allowed a while under a
tabu. The levels stay nested: only units of the level below move, inside their parent.
"""

from __future__ import annotations

import numpy as np

from models.partition.rtree import RATIO_SLACK

BAD = 1 << 20  # an element in pieces
KICKS = 40  # moves up (one more handle or cavity) a repair may make
TENURE = 15  # moves before a unit moved may move again
TRIES = 3  # seeds of the METIS cut and of the repair's tie-breaks tried
# the most work a repair does: exact checks times the units they pass over. A successful repair of
# a plain cube's 10 coarsest elements from 3,221 units made 3,300-4,600 checks (1.5 10^7); a box
# refined 200:1 towards a point, 7 from 30,148 units, ran 800 moves in 83 s without one
WORK = 5 * 10**7
# all the levels made anew, every seed of their parents' children (a check costs OVERHEAD too):
# successful, a plain cube's 10 > 179 from 3,221 units 1.3-1.8 10^7, the 10^6 torus's 4 > 51 > 688
# from 9,352 units 4.5 10^7
TOTAL, OVERHEAD = 4 * WORK, 500
# nodes a check near the moved unit may pass before the whole graph is checked (Repair._near)
LOCAL = 512
VERIFY = False  # every check near a unit compared with the whole graph's (tests)


class Judge:
    """The topology of a set of units: 1 + cavities - chi = handles + cavities (0: a ball) of a
    connected set, None for one in pieces. Cavities: pieces of the set's complement, the outside
    and the domain's own cavities included (an augmented graph: units, one outside node, a node per
    cavity)."""

    def __init__(self, qp, qi, outer: np.ndarray, cav_id: np.ndarray, cav_unit: np.ndarray):
        import scipy.sparse as sp

        ku = qp.size - 1
        nc = int(cav_id.max()) + 1 if cav_id.size else 0
        src = np.r_[np.repeat(np.arange(ku), np.diff(qp)), np.flatnonzero(outer), cav_unit]
        dst = np.r_[qi, np.full(int(np.count_nonzero(outer)), ku), ku + 1 + cav_id]
        n = ku + 1 + nc
        a = sp.csr_matrix(
            (np.ones(2 * src.size, dtype=np.int8), (np.r_[src, dst], np.r_[dst, src])), shape=(n, n)
        )
        a.sum_duplicates()
        self.ap, self.ai, self.n = a.indptr.astype(np.int64), a.indices.astype(np.int64), n

    def __call__(self, units: np.ndarray, chi: int, cavities_only: bool = False):
        from models.graph.csr import connected_components

        if units.size == 0:
            return None
        lab = np.ones(self.n, dtype=np.int64)
        lab[units] = 0
        count, comp = connected_components(self.ap, self.ai, labels=lab)
        mine = comp[units]
        if np.any(mine != mine[0]):
            return None
        # the set is one piece: every other piece is of the complement (no np.unique: 0.8 of 6.5 s)
        cavities = count - 2  # (the pieces of the complement, the outside one not counted)
        return cavities if cavities_only else 1 + cavities - int(chi) + cavities


def _by_unit(items: np.ndarray, units: np.ndarray, ku: int):
    """CSR of each unit's items: (ptr, items)."""
    o = np.argsort(units, kind="stable")
    return np.searchsorted(units[o], np.arange(ku + 1)), items[o]


class Repair:
    """Moves of single units between neighbouring elements towards balls (module docstring)."""

    def __init__(self, ue, qp, qi, qw, judge: Judge, size: np.ndarray, outer: np.ndarray):
        ku = qp.size - 1
        self.ue, self.qp, self.qi, self.qw, self.judge, self.size, self.ku = ue, qp, qi, qw, judge, size, ku
        self.outer = outer  # units on the domain's outer boundary (the way out of any element)
        self.whole = (qp, qi)  # the units' whole graph (qp, qi: the moves', less where groups part it)
        self.checks = 0  # exact checks made (each a pass over the units' graph, or near a unit)
        self.near = 0  # of them, those answered near the moved unit (Repair._near)
        # work spent and allowed, shared with the subsets: [nodes passed over, plus OVERHEAD a check]
        self.spent, self.allowed = [0], [float("inf")]
        # per item kind (vertices +1, edges -1): each unit's classes, each class's units, weights
        self.kinds = []
        for (cls, un, w), sign in ((ue.v, 1.0), (ue.e, -1.0)):
            ptr, mine = _by_unit(cls, un, ku)
            cptr = np.searchsorted(cls, np.arange(w.size + 1))  # (pairs sorted by class)
            self.kinds.append((ptr, mine, cptr, un, sign * w))
        a, b, c = ue.f
        ends, other = np.r_[a, b], np.r_[b, a]
        o = np.argsort(ends, kind="stable")
        self.fptr = np.searchsorted(ends[o], np.arange(ku + 1))
        self.fnb, self.fct = other[o], np.r_[c, c][o]
        from models.native import compiled

        self._fast = compiled("graph._fastgraph")  # the checks near a move (None: the whole graph's)
        self._mark = np.full(judge.n, -1, dtype=np.int64)
        self._queue = np.empty(judge.n, dtype=np.int64)
        self._epoch = 0

    def subset(self, units: np.ndarray) -> Repair:
        """The same for unions of some units only (sorted), numbered in their order: the children of
        one element (a ball) of the level above. Their complements' way out: the domain's outer
        boundary or any unit outside them."""
        from models.polytope.euler import UnitEuler

        at = np.full(self.ku, -1, dtype=np.int64)
        at[units] = np.arange(units.size)
        skel = []
        for cls, un, w in (self.ue.v, self.ue.e):
            m = at[un] >= 0
            keep, inv = np.unique(cls[m], return_inverse=True)
            skel.append((inv.ravel(), at[un[m]], w[keep]))
        a, b, c = self.ue.f
        m = (at[a] >= 0) & (at[b] >= 0)
        ue = UnitEuler(self.ue.chi[units], skel[0], skel[1], (at[a[m]], at[b[m]], c[m]), self.ue.dim)
        from models.mesh.cells import ranges

        ip, ix, iw = _induced(self.qp, self.qi, units, self.ku, self.qw)
        wp, wi = self.whole
        deg = wp[units + 1] - wp[units]
        away = at[wi[ranges(wp[units], deg)]] < 0  # a neighbour outside them
        outer = self.outer[units] | (
            np.bincount(np.repeat(np.arange(units.size), deg)[away], minlength=units.size) > 0
        )
        empty = np.zeros(0, dtype=np.int64)
        sub = Repair(ue, ip, ix, iw, Judge(ip, ix, outer, empty, empty), self.size[units], outer)
        sub.spent, sub.allowed = self.spent, self.allowed
        return sub

    def run(self, lab: np.ndarray, lo, hi, maxit=3000, side_max=800, top=40, seed=0):
        """Repair `lab` (an element per unit, compact) in place where it can: (labels, the total of
        handles and cavities left, moves made). lo / hi: the sizes an element may have (one for all,
        or one each)."""
        ku, size = self.ku, self.size
        K = int(lab.max()) + 1
        lo, hi = np.broadcast_to(lo, (K,)), np.broadcast_to(hi, (K,))
        if max(self.kinds[0][4].size, self.kinds[1][4].size, ku) * K > 3 * 10**7:  # (dense: coarse levels)
            return lab, None, 0
        import scipy.sparse as sp

        # per kind: each class's count of units in each element; g1 / g2 [u, E]: the signed weight of
        # u's classes held by at least one / two units of E (what u shares with E, with E less u)
        cnts, g1, g2 = [], np.zeros((ku, K)), np.zeros((ku, K))
        for _, _, cptr, un, w in self.kinds:
            cnt = np.zeros((w.size, K), dtype=np.int32)
            cls = np.repeat(np.arange(w.size), np.diff(cptr))
            np.add.at(cnt, (cls, lab[un]), 1)
            inc = sp.csr_matrix((np.ones(un.size), (un, cls)), shape=(ku, w.size))
            g1 += inc @ (w[:, None] * (cnt >= 1))
            g2 += inc @ (w[:, None] * (cnt >= 2))
            cnts.append(cnt)
        fcnt = np.zeros((ku, K))
        np.add.at(fcnt, (np.repeat(np.arange(ku), np.diff(self.fptr)), lab[self.fnb]), self.fct)
        chi = self.ue(lab)
        cx = np.array([self._exact(np.flatnonzero(lab == e), chi[e]) for e in range(K)])
        esize = np.bincount(lab, weights=size, minlength=K)
        tabu = np.full(ku, -1)
        rng = np.random.default_rng(seed)
        src = np.repeat(np.arange(ku), np.diff(self.qp))
        best, side, kicks, moves, it = (int(cx.sum()), lab.copy()), 0, 0, 0, 0
        budget = self.checks + WORK // self.judge.n  # (each check a pass over the graph)
        for it in range(maxit):  # a loop over moves (each vectorized over the candidates)
            D = int(cx.sum())
            if D < best[0]:
                best = (D, lab.copy())
            if D == 0 or self.checks > budget or self.spent[0] > self.allowed[0]:
                break
            bad = cx > 0
            m = (lab[src] != lab[self.qi]) & (bad[lab[src]] | bad[lab[self.qi]])
            key = np.unique(src[m] * np.int64(K) + lab[self.qi[m]])
            cu, cB = key // K, key % K
            cA = lab[cu]
            ok = (esize[cA] - size[cu] >= lo[cA]) & (esize[cB] + size[cu] <= hi[cB]) & (tabu[cu] < it)
            cu, cA, cB = cu[ok], cA[ok], cB[ok]
            if cu.size == 0:
                break
            dA, dB = self._deltas(cu, cA, cB, g1, g2, fcnt)
            # a lower bound of the total after each move: |1 - chi| <= handles + cavities
            low = D - cx[cA] - cx[cB] + np.abs(1 - chi[cA] - dA) + np.abs(1 - chi[cB] - dB)
            order = np.lexsort((rng.random(cu.size), low))
            order = order[low[order] <= D + 1][:top]
            pick = None
            for i in order:  # a loop over the best candidates, each checked exactly
                if pick is not None and low[i] >= pick[0]:
                    break  # (sorted by their bound: none further on does better)
                u, A, B = cu[i], cA[i], cB[i]
                ca, cb = self._pair(lab, u, A, B, chi[A] + dA[i], chi[B] + dB[i], cx, chi)
                e = D - cx[A] - cx[B] + ca + cb
                if pick is None or e < pick[0]:
                    pick = (e, i, ca, cb)
                if e < D or e == low[i]:
                    break
            if pick is None or pick[0] > D + 1:
                break
            e, i, ca, cb = pick
            if e >= D:  # sideways (or, a few times, one up: out of a dead end)
                side += 1 if e == D else 0
                kicks += 1 if e > D else 0
                if side > side_max or kicks > KICKS:
                    break
            u, A, B = int(cu[i]), int(cA[i]), int(cB[i])
            self._move(u, A, B, lab, cnts, g1, g2, fcnt)
            chi[A] += dA[i]
            chi[B] += dB[i]
            cx[A], cx[B] = ca, cb
            esize[A] -= size[u]
            esize[B] += size[u]
            tabu[u] = it + TENURE
            moves += 1
        D = int(cx.sum())
        if D < best[0]:
            best = (D, lab.copy())
        return best[1], best[0], moves

    def _pair(self, lab, u, A, B, chi_a, chi_b, cx, chi):
        """(_exact of A less u, _exact of B with u) for u of A: found near u where they can be
        (_near), else on the whole graph; the checks counted as the whole graph's either way."""
        got = None if VERIFY == "whole" else self._near(lab, int(u), int(A), int(B), chi_a, chi_b, cx, chi)
        if got is None or VERIFY:
            lab[u] = B
            ca = self._exact(np.flatnonzero(lab == A), chi_a)
            cb = self._exact(np.flatnonzero(lab == B), chi_b) if ca < BAD else BAD
            lab[u] = A
            if got is not None:  # (VERIFY: both, compared)
                assert got == (ca, cb), (got, (ca, cb))
                self.near += 1 if ca >= BAD else 2
            return ca, cb
        ca, cb = got
        n = 1 if ca >= BAD else 2
        self.checks += n
        self.near += n
        self.spent[0] += n * (self.judge.n + OVERHEAD)
        return ca, cb

    def _near(self, lab, u: int, A: int, B: int, chi_a, chi_b, cx, chi):
        """_pair's two numbers from the pieces around u alone (models/graph/_fastgraph.c
        local_pieces), or None where a search passed LOCAL nodes or could not decide. A less u is
        connected where u's neighbours in A are one piece without u; its complement gains u, which
        joins the t pieces of A's complement u touches (t - 1 cavities fewer, one more where t = 0).
        B with u is connected (u touches B); its complement loses u, so u's piece there falls into
        the s pieces u's neighbours in it make (s - 1 cavities more). The value of each is
        handles + cavities = 1 + 2 cavities - chi, from the element's before (cx, chi)."""
        fast, j = self._fast, self.judge
        if (
            fast is None
            or cx[A] >= BAD
            or cx[B] >= BAD
            or lab.dtype != np.int64
            or not lab.flags.c_contiguous
        ):
            return None

        def pieces(elem, same, budget=LOCAL, count=1):
            self._epoch += 1
            return fast.local_pieces(
                j.ap, j.ai, lab, self._mark, self._queue, self.ku, u, elem, same, budget, self._epoch, count
            )

        twice_a, twice_b = int(cx[A]) - 1 + int(chi[A]), int(cx[B]) - 1 + int(chi[B])  # 2 cavities
        if twice_a % 2 or twice_b % 2:
            return None
        inside = pieces(A, 1, count=0)  # (1, or 2 for two or more)
        if inside < 0:
            return None
        if inside != 1:  # (0: A was u alone, now empty; 2 or more: A less u in pieces)
            return BAD, BAD
        t = pieces(A, 0)
        if t < 0 or pieces(B, 1, -1) < 1:
            return None
        ca = 1 + twice_a + 2 * (1 - t) - int(chi_a)
        s = pieces(B, 0)
        if s < 0:
            return None
        return ca, 1 + twice_b + 2 * (s - 1) - int(chi_b)

    def _exact(self, units, chi, cavities_only: bool = False):
        self.checks += 1
        self.spent[0] += self.judge.n + OVERHEAD
        j = self.judge(units, chi, cavities_only)
        return BAD if j is None else int(j)

    def _deltas(self, cu, cA, cB, g1, g2, fcnt):
        """Each candidate move's change of chi of its element A (u leaves) and of B (u joins):
        chi(A - u) = chi(A) - chi(u) + chi(u n (A - u)), chi(B + u) = chi(B) + chi(u) - chi(u n B)."""
        chi_u = self.ue.chi[cu].astype(np.float64)
        dA = -chi_u + g2[cu, cA] + fcnt[cu, cA]
        dB = chi_u - g1[cu, cB] - fcnt[cu, cB]
        return np.rint(dA).astype(np.int64), np.rint(dB).astype(np.int64)

    def _move(self, u, A, B, lab, cnts, g1, g2, fcnt):
        """u from A to B: the counts, g1 / g2 of the units sharing its classes, fcnt of its neighbours."""
        from models.mesh.cells import ranges

        lab[u] = B
        for (ptr, mine, cptr, un, w), cnt in zip(self.kinds, cnts, strict=True):
            c = mine[ptr[u] : ptr[u + 1]]
            for el, step in ((A, -1), (B, 1)):
                before = cnt[c, el]
                cnt[c, el] += step
                # the classes whose count crosses 1 (g1) or 2 (g2) at el
                for g, at in ((g1, 1), (g2, 2)):
                    hit = c[before == (at if step < 0 else at - 1)]
                    if hit.size:
                        ln = cptr[hit + 1] - cptr[hit]
                        pos = ranges(cptr[hit], ln)
                        np.add.at(g, (un[pos], np.full(pos.size, el)), step * np.repeat(w[hit], ln))
        nb, ct = self.fnb[self.fptr[u] : self.fptr[u + 1]], self.fct[self.fptr[u] : self.fptr[u + 1]]
        np.add.at(fcnt, (nb, np.full(nb.size, A)), -ct)
        np.add.at(fcnt, (nb, np.full(nb.size, B)), ct)


def _kway(qp, qi, qw, units, ku: int, k: int, size: np.ndarray, seed: int) -> np.ndarray:
    """METIS k-way of the graph the units induce, their cells balanced, the faces cut fewest (edge
    weights: the shared faces' measures, scaled to integers): smoother sides, fewer pinches."""
    import warnings

    import pymetis

    from models.partition.metis import integer_weights

    ip, ix, iw = _induced(qp, qi, units, ku, qw)
    dt = pymetis.zero_copy_dtype()
    adj = pymetis.CSRAdjacency(ip.astype(dt), ix.astype(dt))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        res = pymetis.part_graph(
            k,
            adj,
            vweights=integer_weights(size).astype(dt),
            eweights=integer_weights(iw).astype(dt),
            options=pymetis.Options(seed=seed),
        )
    return np.asarray(res.vertex_part, dtype=np.int64)


def _induced(qp, qi, units: np.ndarray, ku: int, qw=None):
    """CSR of the graph the given units induce, numbered in their order (and its weights)."""
    from models.mesh.cells import ranges

    at = np.full(ku, -1, dtype=np.int64)
    at[units] = np.arange(units.size)
    deg = qp[units + 1] - qp[units]
    edges = ranges(qp[units], deg)
    nb = at[qi[edges]]
    row = np.repeat(np.arange(units.size), deg)
    keep = nb >= 0
    ip = np.zeros(units.size + 1, dtype=np.int64)
    np.cumsum(np.bincount(row[keep], minlength=units.size), out=ip[1:])
    if qw is None:
        return ip, nb[keep]
    return ip, nb[keep], qw[edges][keep]


def shares(size: np.ndarray, n: int, least=1) -> np.ndarray:
    """n parts given out by size, at least `least` each (largest remainders)."""
    q = size / size.sum() * n
    least = np.broadcast_to(np.asarray(least, dtype=np.int64), q.shape)
    a = np.maximum(np.floor(q).astype(np.int64), least)
    while a.sum() > n and np.any(a > least):  # a loop over the parts taken back (few)
        a[np.argmax(np.where(a > least, a - q, -np.inf))] -= 1
    while a.sum() < n:  # a loop over the parts given (few)
        a[np.argmax(q - a)] += 1
    return a


def unit_repair(mesh, data, units: np.ndarray, hole_pairs=None, groups=None) -> Repair | None:
    """A Repair of unions of the given units (a unit per cell), or None where they are not all
    balls. Sizes: cells per unit. groups: each unit's physical group (no move, cut or union across
    one: the moves' graph keeps the edges inside a group; balls are judged in the whole domain)."""
    from models.hierarchy.topology import unit_sides
    from models.partition.rtree import _quotient
    from models.polytope.euler import UnitEuler

    g = data.graph
    ku = int(units.max()) + 1
    ue = UnitEuler.of_cells(mesh, g, units)
    if not np.all(ue.chi == 1):
        return None
    qp, qi, qw = _quotient(g.indptr, g.indices, g.weights, units, ku)
    outer, cav_id, cav_unit = unit_sides(data, units, ku, hole_pairs)
    size = np.bincount(units, minlength=ku).astype(np.float64)
    judge = Judge(qp, qi, outer, cav_id, cav_unit)
    whole = (qp, qi)
    if groups is not None:  # (the moves' graph: edges inside a group)
        src = np.repeat(np.arange(ku), np.diff(qp))
        inside = groups[src] == groups[qi]
        qi, qw = qi[inside], qw[inside]
        qp = np.zeros(ku + 1, dtype=np.int64)
        np.cumsum(np.bincount(src[inside], minlength=ku), out=qp[1:])
    rep = Repair(ue, qp, qi, qw, judge, size, outer)
    rep.whole = whole
    return rep


SLACK = 0.4  # an element may hold 1 -+ SLACK times its share of the cells while it is repaired


SHIFTS = (1.0, 0.9, 1.1, 0.8, 1.2, 0.7, 1.3)  # a plane's positions: its side's share times these


def _planes(rep: Repair, units: np.ndarray, n: int, cen: np.ndarray, shifts=(1.0,)) -> np.ndarray:
    """n parts of the given units (a ball or not) by planes, halving the count each time: of the
    principal axes of a part's units (and the coordinate axes) and of the positions `shifts` times
    the share (SHIFTS and the coordinate axes where inclusions are to be cut through; a tube's start
    is more often repaired without them), the cut whose two sides have the fewest handles and cavities (Judge; a side in
    pieces counts BAD), then the nearest the share, then the fewest cut edges. A label per unit given.
    A slice across a tube is two rings where a cut along it is two balls, and the other way round
    for a slab around a ring (a torus inclusion's matrix): k-way's cut (the least face) does not
    know which."""
    lab = np.zeros(units.size, dtype=np.int64)
    todo, nxt = [(np.arange(units.size), n)], 0
    src = np.repeat(np.arange(rep.ku), np.diff(rep.qp))
    while todo:  # a loop over the parts still to halve (n - 1 cuts)
        part, m = todo.pop()
        if m == 1 or part.size < 2:
            lab[part] = nxt
            nxt += 1
            continue
        mine, w = units[part], rep.size[units[part]]
        side = np.full(rep.ku, 2, dtype=np.int64)  # (2: outside the part)
        ue = _within(rep.ue, mine)  # (the part's skeleton: each side's chi at the part's cost)
        c = cen[mine] - np.average(cen[mine], axis=0, weights=w)
        m1, best = m // 2, None
        axes = np.linalg.eigh((c * w[:, None]).T @ c)[1].T
        if len(shifts) > 1:  # (a cube's principal axes are any: a diagonal cut misses the inclusions
            axes = np.r_[axes, np.eye(c.shape[1])]  # a cut along a coordinate axis goes through)
        for ax in axes:  # a loop over the principal axes (and the coordinate axes)
            o = np.argsort(c @ ax, kind="stable")
            cw = np.cumsum(w[o])
            for f in shifts:  # a loop over positions about the share (a cut through holes opens them)
                cut = min(max(int(np.searchsorted(cw, cw[-1] * m1 / m * f)), 1), part.size - 1)
                side[mine[o[:cut]]], side[mine[o[cut:]]] = 0, 1
                chi = ue(side)
                bad = sum(rep._exact(np.flatnonzero(side == j), chi[j]) for j in (0, 1))
                cross = int(
                    np.count_nonzero((side[src] < 2) & (side[rep.qi] < 2) & (side[src] != side[rep.qi]))
                )
                if best is None or (bad, abs(f - 1), cross) < best[0]:
                    best = ((bad, abs(f - 1), cross), part[o[:cut]], part[o[cut:]])
        todo += [(best[1], m1), (best[2], m - m1)]
    return lab


def _within(ue, units: np.ndarray):
    """ue (a UnitEuler) with the skeleton items of the given units alone: the same chi for every
    element made of them (an item of other units too counts only those of its units inside one such
    element), at their share's cost: _planes' sides of a part (a Menger sponge's 10,800 hexahedra,
    8 coarsest elements from 110: 1,053 evaluations of the whole skeleton, 0.95 of 2.3 s)."""
    inside = np.zeros(ue.chi.size, dtype=bool)
    inside[units] = True

    def kept(cls, unit, w):  # (the classes renumbered in order: still sorted, a span of the part's)
        keep = inside[unit]
        used = np.zeros(w.size, dtype=bool)
        used[cls[keep]] = True
        new = np.cumsum(used) - 1
        return new[cls[keep]], unit[keep], w[used]

    a, b, c = ue.f
    kf = inside[a] & inside[b]
    return type(ue)(ue.chi, kept(*ue.v), kept(*ue.e), (a[kf], b[kf], c[kf]), ue.dim)


def _cavities(rep: Repair, units: np.ndarray, lab: np.ndarray) -> int:
    """Cavities of the parts `lab` (a label per unit given) summed (BAD for one in pieces): what
    single moves cannot open (their handles they can)."""
    return sum(rep._exact(units[lab == j], 1, cavities_only=True) for j in range(int(lab.max()) + 1))


def _children(
    rep: Repair, k: int, seed: int, tries: int = 1, pieces=None, cen=None, fixed=None
) -> np.ndarray | None:
    """k balls made of all of rep's units (METIS k-way, connected, repaired; `tries` seeds): a label
    per unit, or None where a handle or a cavity is left. pieces: (each unit's connected piece, each
    piece's share of the k) where the units are in several. cen: each unit's centroid, where a start
    by planes (_planes) is tried after the seeds (k-way's sides are smoother: on a block around a
    cavity at 3.9 10^5 cells the planes' start left 5 handles after 816 moves, k-way's none after 194;
    on a tube around a core k-way's slices are rings, the planes' cut along it two balls). fixed:
    {piece: its parts} made already (by planes), kept in every start."""
    from models.mesh.celldata import compact_labels
    from models.partition.rtree import make_connected

    if k == 1:
        return np.zeros(rep.ku, dtype=np.int64)
    if k > rep.ku:
        return None
    starts = list(range(seed, seed + tries)) + ([-1] if cen is not None else [])
    for s in starts:  # a loop over seeds (a repair is a local search), then the planes' start
        try:
            comp, share = pieces if pieces is not None else (np.zeros(rep.ku, dtype=np.int64), [k])
            lab, nxt = np.empty(rep.ku, dtype=np.int64), 0
            for p, n in enumerate(share):  # a loop over the pieces (few): each its share, apart
                mine = np.flatnonzero(comp == p)
                if fixed and p in fixed:
                    lab[mine] = nxt + fixed[p]
                elif s < 0:  # (the planes' start)
                    lab[mine] = nxt + _planes(rep, mine, int(n), cen)
                else:
                    lab[mine] = nxt + (
                        _kway(rep.qp, rep.qi, rep.qw, mine, rep.ku, int(n), rep.size[mine], s) if n > 1 else 0
                    )
                nxt += int(n)
        except RuntimeError:  # (pymetis' METIS_ERROR: the merges' levels stay)
            return None
        lab, _ = make_connected(rep.qp, rep.qi, rep.qw, lab, measures=rep.size)
        lab = compact_labels(lab)
        if int(lab.max()) + 1 != k:  # (a part METIS left empty)
            continue
        mean = rep.size.sum() / k
        if pieces is not None:  # (each element's share of its own piece)
            comp, share = pieces
            mean = (np.bincount(comp, weights=rep.size) / share)[comp[np.unique(lab, return_index=True)[1]]]
        lab, left, _ = rep.run(lab, (1 - SLACK) * mean, (1 + SLACK) * mean, seed=max(s, seed))
        if left == 0:
            return lab
    return None


def balls_above(
    mesh, data, levels, u: int, plan, hole_pairs=None, seed: int = 0, groups=None, seeds=None, accept=None
):
    """Levels 0..u-1 cut anew from level u's elements (METIS k-way, each element's share of the next
    level inside it) and repaired into balls (Repair): the levels, or None where u's elements are not
    all balls or a level keeps a handle or a cavity. groups: each cell's physical group (compact),
    no element across one (each connected piece of a group its share, as separate solids). seeds:
    the seeds tried in turn (default: `seed` alone), the first levels `accept` takes (default: any)
    returned; the units' skeleton, the pieces and the planes through their holes are made once for
    all seeds (4 fibres through a cube: the two later seeds had cost 0.7 s each to fail as the first)."""
    seeds = (seed,) if seeds is None else tuple(seeds)
    units = np.asarray(levels[u], dtype=np.int64)
    if u < 1 or (hole_pairs is not None and np.unique(hole_pairs[0]).size > int(plan[0])):
        return None  # (more cavities than coarsest elements: below)
    ugroups = None
    if groups is not None:
        ku = int(units.max()) + 1
        ugroups = np.zeros(ku, dtype=np.int64)
        ugroups[units] = groups
        if np.unique(units * np.int64(groups.max() + 1) + groups).size != ku:
            return None  # (a unit across groups)
    rep = unit_repair(mesh, data, units, hole_pairs, ugroups)
    if rep is None:
        return None
    rep.allowed[0] = TOTAL
    from models.graph.csr import connected_components

    npieces, comp = connected_components(rep.qp, rep.qi)
    comp = comp.astype(np.int64)
    if npieces > int(plan[0]) or npieces * rep.judge.n > WORK:
        return None  # (many pieces, grains of a polycrystal say: a check each would pass over them all)
    holes = np.array(
        [rep._exact(np.flatnonzero(comp == p), int(rep.ue(comp != p)[0])) for p in range(npieces)]
    )
    pieces = None
    if npieces > 1:  # (two separate solids: each its share, two at least where it has a hole)
        least = 1 + (holes > 0)
        if least.sum() > int(plan[0]):
            return None
        pieces = (comp, shares(np.bincount(comp, weights=rep.size), int(plan[0]), least))
    ku = rep.ku
    cen = None
    if holes.any():  # (a start by planes too where a piece has a tunnel or a cavity)
        w = np.abs(data.measures)
        wu = np.bincount(units, weights=w, minlength=ku)
        cen = np.stack([np.bincount(units, weights=w * x, minlength=ku) for x in data.centroids.T], 1)
        cen /= np.maximum(wu, np.finfo(float).tiny)[:, None]
    share = pieces[1].copy() if pieces else np.array([int(plan[0])])
    fixed = {}
    for p in np.flatnonzero(holes > share):  # a loop over the pieces with more holes than elements (few)
        # opening a cavity or a tunnel by single moves takes a path of moves that change nothing until
        # the last (120 voxel cavities, 10 coarsest: 71 left after 818 moves; a matrix around 8
        # spheres, 2 of its own: 15 s of repairs, none left a ball). Planes through them can: the
        # fewest parts, up to the count's 25% slack, whose planes leave no cavity (the handles that
        # plane cuts of jagged units make are the repair's; with tunnels, the piece is repaired on
        # its own first: fibres through a matrix)
        mine = np.flatnonzero(comp == p)  # (holes there: cen is made above)
        tunnels = _cavities(rep, mine, np.zeros(mine.size, dtype=np.int64)) < holes[p]
        top = int(share[p]) + max(int(RATIO_SLACK * int(plan[0])), 1)
        for m in range(int(share[p]), min(top, int(holes[p]) + 1) + 1):  # a loop over the counts tried
            lab = _planes(rep, mine, m, cen, SHIFTS)
            if _cavities(rep, mine, lab):
                continue
            if tunnels:  # (jagged plane cuts make handles too: which are the tunnels' the repair tells)
                mean = rep.size[mine].sum() / m
                lab, left, _ = rep.subset(mine).run(lab, (1 - SLACK) * mean, (1 + SLACK) * mean)
                if left:
                    continue
            fixed[int(p)], share[p] = lab, m
            break
        else:
            return None
    if fixed:
        pieces = (comp, share)
    for s in seeds:  # a loop over the seeds tried (each repair a local search)
        if s != seeds[0]:  # (each seed its own budget, as a call of its own had)
            rep.spent[0], rep.checks = 0, 0
        got = _levels_above(rep, units, u, plan, int(share.sum()), s, pieces, cen if s == 0 else None, fixed)
        if got is not None:
            got = [lv[units] for lv in got] + list(levels[u:])
            if accept is None or accept(got):
                return got
    return None


def _levels_above(rep: Repair, units, u: int, plan, k0: int, seed: int, pieces, cen, fixed):
    """balls_above's levels 0..u-1 for one seed: a label per unit each, or None."""
    ku = rep.ku
    prev, out = np.zeros(ku, dtype=np.int64), []
    for L in range(u):  # a loop over the levels made again, coarsest first
        kp = int(prev.max()) + 1
        n = shares(np.bincount(prev, weights=rep.size, minlength=kp), int(plan[L])) if L else [k0]
        lab, nxt = np.empty(ku, dtype=np.int64), 0
        for e in range(kp):  # a loop over the elements of the level above: each one's children apart
            mine = np.flatnonzero(prev == e)
            sub = rep if L == 0 else rep.subset(mine)
            got = (
                _children(sub, int(n[e]), seed, 1, pieces, cen, fixed)
                if L == 0
                else _children(sub, int(n[e]), seed, TRIES)
            )
            if got is None:
                return None
            lab[mine] = nxt + got
            nxt += int(got.max()) + 1
        out.append(lab)
        prev = lab
    return out

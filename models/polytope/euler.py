"""Euler characteristics of agglomerated elements and of the unions of neighbouring ones.

A connected element made of cells is a disk (2D) exactly when the Euler characteristic of its cells
as a closed set, V - E + F, is 1: an element around a hole, and one that touches itself at a vertex
around something (a weakly simple polygon, whose boundary walk passes a vertex twice), have 1 - loops.
In 3D V - E + F - C is 1 - handles + cavities for a connected element (1 is necessary for a ball).

The union of two neighbouring elements A and B has chi(A) + chi(B) - chi(A n B), where A n B is
what their closed cells share: vertices, edges and (3D) faces. Two disks whose shared boundary is one
arc make a disk; a shared boundary in two arcs (a hole or another element between them) makes a ring.
So whether a merge would enclose anything is known before it is made, for every pair at once,
without merging polygons. Vectorized: sorts over (item, element) keys, no loop over elements.
"""

from __future__ import annotations

import numpy as np

from models.mesh.container import Mesh


def _owned(keys: np.ndarray, owner: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The distinct (item, element) pairs, sorted by item: (items, elements)."""
    from models.mesh.dual import sorted_unique

    kk = np.int64(k)
    u = sorted_unique(keys.astype(np.int64) * kk + owner)
    return u // kk, u % kk


def _runs(items: np.ndarray):
    """Runs of equal (sorted) items: (each run's start, its length, each entry's position in its run)."""
    start = np.flatnonzero(np.r_[True, items[1:] != items[:-1]])
    cnt = np.diff(np.r_[start, items.size])
    return start, cnt, np.arange(items.size) - np.repeat(start, cnt)


def _pairs_per_item(items: np.ndarray, els: np.ndarray, k: int, weights: np.ndarray | None = None):
    """Keys a * k + b (a < b) of the element pairs sharing each item, one per item they share
    (items sorted, each (item, element) once). With weights (one per (item, element) entry, the
    item's), (keys, the weight of the item each came from)."""
    if items.size == 0:
        z = np.zeros(0, dtype=np.int64)
        return z if weights is None else (z, np.zeros(0))
    start, cnt, pos = _runs(items)
    room = np.repeat(cnt, cnt) - pos  # entries from here to the run's end
    out, ws = [], []
    kk = np.int64(k)
    for d in range(1, int(cnt.max())):  # a loop over the run offsets (the most elements at one item)
        i = np.flatnonzero(room > d)
        a, b = els[i], els[i + d]
        out.append(np.minimum(a, b) * kk + np.maximum(a, b))
        if weights is not None:
            ws.append(weights[i])
    keys = np.concatenate(out) if out else np.zeros(0, dtype=np.int64)
    if weights is None:
        return keys
    return keys, (np.concatenate(ws) if ws else np.zeros(0))


def _incidence(mesh: Mesh, graph, labels: np.ndarray, k: int, cells: np.ndarray | None = None):
    """The distinct (vertex, element) and (edge, element) pairs of the elements' cells (or of
    `cells`), each sorted by vertex / edge: ((vertices, their elements), (edges, their elements)).
    Edges: 2D the cells' sides, 3D the sides of the cells' faces."""
    from models.mesh.cells import ranges
    from models.mesh.geometry import next_in_cycle

    n = np.int64(mesh.n_points)
    off = mesh.offsets
    cell = np.arange(mesh.n_cells) if cells is None else cells
    sizes = off[cell + 1] - off[cell]
    con = mesh.connectivity if cells is None else mesh.connectivity[ranges(off[cell], sizes)]
    con = con.astype(np.int64)
    owner = np.repeat(labels[cell], sizes)
    if mesh.dim == 2:
        lo = np.zeros(cell.size + 1, dtype=np.int64)
        np.cumsum(sizes, out=lo[1:])
        u, v, e_owner = con, con[next_in_cycle(lo)], owner
    else:
        f = graph.faces
        fo, fn, fc = f.offsets, f.nodes, f.cell
        if cells is not None:
            from models.polytope.merge import face_nodes

            mine = np.zeros(mesh.n_cells, dtype=bool)
            mine[cells] = True
            fc = fc[mine[fc]]
            fo, fn = face_nodes(f, np.flatnonzero(mine[f.cell]))
        u = fn.astype(np.int64)
        v = u[next_in_cycle(fo)]
        e_owner = np.repeat(labels[fc], np.diff(fo))
    return _owned(con, owner, k), _owned(np.minimum(u, v) * n + np.maximum(u, v), e_owner, k)


def cell_excess(mesh: Mesh, graph) -> np.ndarray | None:
    """(N,) each polyhedral cell's Euler characteristic (of its own faces) less 1, or None where the
    mesh has no polyhedron (every standard cell has 1). A polyhedron read back from our own output
    may have faces that make its characteristic 0 (3 of 20 on a cube agglomerated twice): an element
    is judged against its cells, not made a ring by one of them. Kept in mesh.meta."""
    if mesh.dim != 3:
        return None
    poly = np.flatnonzero(mesh.cell_types == 42)
    if poly.size == 0:
        return None
    got = mesh.meta.get("_cell_excess")
    if got is not None and got.size == mesh.n_cells:
        return got
    n = mesh.n_cells
    lab = np.arange(n, dtype=np.int64)
    (_, ve), (_, ee) = _incidence(mesh, graph, lab, n, poly)
    ex = np.zeros(n, dtype=np.int64)
    ex[poly] = (_euler(mesh, graph, lab, n, ve, ee, poly, correct=False) - 1)[poly]
    mesh.meta["_cell_excess"] = ex
    return ex


def _euler(
    mesh: Mesh, graph, labels: np.ndarray, k: int, ve, ee, cells: np.ndarray | None = None, correct=True
):
    """element_euler from the incidence's element columns (correct: less the cells' cell_excess)."""
    V = np.bincount(ve, minlength=k)
    E = np.bincount(ee, minlength=k)
    if mesh.dim == 2:
        return V - E + np.bincount(labels if cells is None else labels[cells], minlength=k)
    from models.polytope.merge import boundary_faces

    fel = labels[graph.faces.cell]
    bf = boundary_faces(graph, labels)
    if cells is not None:
        mine = np.zeros(mesh.n_cells, dtype=bool)
        mine[cells] = True
        fel, bf = fel[mine[graph.faces.cell]], bf[mine[graph.faces.cell[bf]]]
    # a face inside the element is listed once per cell: counted half each time
    F = (np.bincount(fel, minlength=k) + np.bincount(labels[graph.faces.cell[bf]], minlength=k)) // 2
    return V - E + F - cells_counted(mesh, graph, labels, k, cells, correct)


def cells_counted(mesh: Mesh, graph, labels: np.ndarray, k: int, cells=None, correct: bool = True):
    """(k,) the C of V - E + F - C: each element's cells (or those of `cells`), each polyhedron counted
    with its cell_excess where `correct` (3D), so an element is judged against its own cells."""
    own = labels if cells is None else labels[cells]
    C = np.bincount(own, minlength=k)
    ex = cell_excess(mesh, graph) if correct and mesh.dim == 3 else None
    if ex is not None:
        C = C + np.bincount(own, weights=ex if cells is None else ex[cells], minlength=k).astype(np.int64)
    return C


def element_euler(mesh: Mesh, graph, labels: np.ndarray, cells: np.ndarray | None = None) -> np.ndarray:
    """(k,) the Euler characteristic of each element's cells as a closed set: V - E + F in 2D,
    V - E + F - C in 3D. 1 for a disk (2D) or a ball (3D). cells: only these cells are read (every
    cell of each element wanted: the others' answers are meaningless)."""
    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1
    (_, ve), (_, ee) = _incidence(mesh, graph, labels, k, cells)
    return _euler(mesh, graph, labels, k, ve, ee, cells)


def union_euler(mesh: Mesh, graph, labels: np.ndarray, chi: np.ndarray | None = None):
    """Every pair of elements sharing a face: (a, b, chi of A u B, shared faces' weight), a < b.
    chi: element_euler's answer where known."""
    from models.mesh.dual import sorted_unique

    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1
    kk = np.int64(k)
    (vi, ve), (ei, ee) = _incidence(mesh, graph, labels, k)  # once, for the elements and the pairs
    if chi is None:
        chi = _euler(mesh, graph, labels, k, ve, ee)
    vk = _pairs_per_item(vi, ve, k)
    # faces between two elements, once per pair of cells (a < b keeps one of the two directions)
    rows = np.repeat(np.arange(graph.indptr.size - 1), np.diff(graph.indptr))
    la, lb = labels[rows], labels[graph.indices]
    s = la < lb
    fkey, finv, fcount = sorted_unique(la[s] * kk + lb[s], return_inverse=True, return_counts=True)
    weight = np.bincount(finv, weights=graph.weights[s], minlength=fkey.size)
    if mesh.dim == 2:  # shared sides are the faces
        share = _count_at(fkey, vk) - fcount
    else:
        share = _count_at(fkey, vk) - _count_at(fkey, _pairs_per_item(ei, ee, k)) + fcount
    a, b = fkey // kk, fkey % kk
    return a, b, chi[a] + chi[b] - share, weight


def _count_at(keys: np.ndarray, occurrences: np.ndarray) -> np.ndarray:
    """How often each of the sorted distinct `keys` occurs in `occurrences`."""
    if occurrences.size == 0:
        return np.zeros(keys.size, dtype=np.int64)
    occ = np.sort(occurrences)
    return np.searchsorted(occ, keys, side="right") - np.searchsorted(occ, keys, side="left")


def disjoint_pairs(order, src: np.ndarray, dst: np.ndarray, k: int, limit: int) -> tuple[np.ndarray, int]:
    """Greedy disjoint merges: pairs (src[i], dst[i]) taken in `order`, each element in at most one,
    up to `limit`. Returns (a map of the k elements: src -> dst, the rest to themselves; pairs taken)."""
    target = np.arange(k)
    used = np.zeros(k, dtype=bool)
    done = 0
    for i in order:  # a loop over candidate pairs until `limit` are taken
        if done >= limit:
            break
        p, q = src[i], dst[i]
        if used[p] or used[q]:
            continue
        used[p] = used[q] = True
        target[p] = q
        done += 1
    return target, done


def merge_safely(
    mesh: Mesh,
    graph,
    labels: np.ndarray,
    target: int,
    sizes: np.ndarray | None = None,
    keep: np.ndarray | None = None,
    rounds: int = 64,
    unions=None,
    compact: bool = False,
    forbid=None,
) -> tuple[np.ndarray, int]:
    """Merge pairs of neighbouring elements whose union has Euler characteristic 1 (a disk in 2D; in
    3D necessary for a ball) until `target` elements are left or no such pair is: the smallest
    element first, into the safe neighbour it shares most with; disjoint pairs per round. sizes: a
    weight per cell to balance (default: cells); keep: a label per cell that no merge may cross
    (physical groups). unions: UnitEuler.unions of units, labels then an element per unit (sizes and
    keep per unit too). compact: the pairs whose union is smallest for the faces they share first
    ((size a + size b) / sqrt(shared)), rounder unions that tangle less with their neighbours.
    forbid: labels, k -> keys a * k + b (a < b) of pairs not to merge (3D: a union of characteristic 1
    may hold a handle and a cavity: rethread._enclosing). Returns (labels compacted, pairs
    merged)."""
    from models.mesh.celldata import compact_labels

    labels = compact_labels(np.asarray(labels, dtype=np.int64))
    w = np.ones(labels.size) if sizes is None else np.asarray(sizes, dtype=np.float64)
    merged = 0
    for _ in range(rounds):  # a loop over rounds of disjoint merges (each vectorized)
        k = int(labels.max()) + 1
        excess = k - int(target)
        if excess <= 0:
            break
        small, other, key = _safe_pairs(mesh, graph, labels, w, keep, unions, forbid, compact)
        if small.size == 0:
            break
        tgt, done = disjoint_pairs(np.argsort(key, kind="stable"), small, other, k, excess)
        if done == 0:
            break
        labels = compact_labels(tgt[labels])
        merged += done
    return labels, merged


def _safe_pairs(mesh, graph, labels, w, keep, unions, forbid, compact=True):
    """merge_safely's candidates: (the smaller element, the other, a sort key: smallest first) of every
    neighbouring pair whose union is safe."""
    k = int(labels.max()) + 1
    a, b, uchi, wt = union_euler(mesh, graph, labels) if unions is None else unions(labels)
    ok = uchi == 1
    if forbid is not None:
        ok &= ~np.isin(a * np.int64(k) + b, forbid(labels, k))
    if keep is not None:
        ke = np.zeros(k, dtype=np.int64)
        ke[labels] = keep
        ok &= ke[a] == ke[b]
    a, b, wt = a[ok], b[ok], wt[ok]
    size = np.bincount(labels, weights=w, minlength=k)
    # each pair as (the smaller element, the other): the smallest elements first, then the
    # partner sharing the most, then the smaller partner
    small = np.where(size[a] <= size[b], a, b)
    other = np.where(small == a, b, a)
    if compact:
        key = (size[small] + size[other]) / np.sqrt(np.maximum(wt, 1e-300))
    else:
        rank = np.empty(a.size, dtype=np.int64)
        rank[np.lexsort((size[other], -wt, size[small]))] = np.arange(a.size)
        key = rank.astype(np.float64)
    return small, other, key


def merge_ahead(
    mesh: Mesh,
    graph,
    labels: np.ndarray,
    target: int,
    sizes: np.ndarray | None = None,
    keep: np.ndarray | None = None,
    unions=None,
    forbid=None,
    width: int = 4,
) -> tuple[np.ndarray, int]:
    """merge_safely one pair at a time, looking one merge ahead: of the `width` most compact safe
    pairs, the one that leaves the most safe pairs after it (ties: the most compact). Greedy rounds
    of compact merges tangle coarse 3D elements (neighbours sharing faces in many patches) until no
    pair's union is a ball: 27 cavities at 2 10^5 cells, 143 -> 12 elements for 10 planned; this
    reaches 10. Costs width + 1 union evaluations per merge: for the last levels (few elements)."""
    from models.mesh.celldata import compact_labels

    labels = compact_labels(np.asarray(labels, dtype=np.int64))
    w = np.ones(labels.size) if sizes is None else np.asarray(sizes, dtype=np.float64)
    merged = 0
    small, other, key = _safe_pairs(mesh, graph, labels, w, keep, unions, forbid)
    while int(labels.max()) + 1 > target and small.size:  # a loop over merges (few: coarse levels)
        best = None
        for i in np.argsort(key, kind="stable")[:width]:  # a loop over the candidates
            nl = compact_labels(np.where(labels == small[i], other[i], labels))
            nxt = _safe_pairs(mesh, graph, nl, w, keep, unions, forbid)
            if best is None or nxt[0].size > best[0] or int(nl.max()) + 1 <= target:
                best = (nxt[0].size, nl, nxt)
            if int(nl.max()) + 1 <= target:
                break
        _, labels, (small, other, key) = best
        merged += 1
    return labels, merged


def pinched(mesh: Mesh, graph, labels: np.ndarray):
    """2D elements that touch themselves at a vertex (their boundary walk passes a vertex twice, so
    they go around a hole or other elements with only a point closing the ring; chi below 1): an
    element's boundary sides meet in pairs at its boundary vertices, more than two at such a vertex.
    (elements, one such vertex of each). Polygon merging reads one boundary loop for them and finds
    no hole."""
    from models.mesh.dual import sorted_unique
    from models.polytope.merge import boundary_faces, face_nodes

    labels = np.asarray(labels, dtype=np.int64)
    none = np.zeros(0, dtype=np.int64)
    if mesh.dim != 2:
        return none, none
    f = graph.faces
    fel = labels[f.cell]
    bf = boundary_faces(graph, labels)
    fo, nodes = face_nodes(f, bf)
    n = np.int64(mesh.n_points)
    key, cnt = sorted_unique(np.repeat(fel[bf], np.diff(fo)) * n + nodes, return_counts=True)
    hit = key[cnt > 2]
    el, first = np.unique(hit // n, return_index=True)
    return el, (hit % n)[first]


def _weight_at(keys: np.ndarray, occurrences: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The summed weights of each of the sorted distinct `keys` in `occurrences`."""
    if occurrences.size == 0:
        return np.zeros(keys.size)
    o = np.argsort(occurrences)
    occ, cw = occurrences[o], np.r_[0.0, np.cumsum(weights[o])]
    return cw[np.searchsorted(occ, keys, side="right")] - cw[np.searchsorted(occ, keys, side="left")]


def _shared(items: np.ndarray) -> np.ndarray:
    """(n,) True where the item (sorted) appears more than once."""
    if items.size == 0:
        return np.zeros(0, dtype=bool)
    run = np.cumsum(np.r_[True, items[1:] != items[:-1]]) - 1
    return np.bincount(run)[run] > 1


class UnitEuler:
    """Euler characteristics of unions of units (the elements of a finer level), from what the units
    share alone: chi(E) = sum of its units' chi - (V counted more than once) + (E ...) - (F ...), the
    items on the units' interfaces (the skeleton) being all that differs. One incidence pass over the
    cells for the finest units; each coarser level's skeleton is the part of the finer one between
    different elements, so a whole hierarchy costs about one element_euler, and a level's labels can
    be judged again and again (fix_holes' rounds) at the cost of its skeleton, not of its cells.

    The skeleton is kept condensed: vertices (edges) shared by the same set of units are one item
    with a weight, the faces between two units one pair with a count. 27 cavities at 2 10^5 cells,
    143 units: 21,297 shared vertices and 69,290 shared edges (196,573 (item, unit) pairs) are 5,188
    classes (14,867 pairs), 47,757 faces 901 pairs; a union evaluation 24 -> 2.4 ms."""

    def __init__(self, chi, verts, edges, faces, dim):
        # verts / edges: (item class, unit) pairs sorted by class, each class's units ascending, and
        # (n_classes,) weights; faces: (a, b, count), a < b, distinct pairs
        self.chi, self.v, self.e, self.f, self.dim = chi, verts, edges, faces, dim

    @staticmethod
    def _condensed(items: np.ndarray, units: np.ndarray, weight: np.ndarray | None):
        """(class, unit) pairs and (n_classes,) weights for the items shared by more than one unit
        (items sorted, units ascending within an item): items shared by the same set of units are one
        class, its weight their total."""
        m = _shared(items)
        items, units = items[m], units[m]
        if items.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
        start, cnt, pos = _runs(items)
        table = np.full((start.size, int(cnt.max())), -1, dtype=np.int64)
        table[np.repeat(np.arange(start.size), cnt), pos] = units  # each item's units, one row
        w = np.ones(start.size) if weight is None else weight[items[start]]
        rows, inv = UnitEuler._unique_rows(table)
        cw = np.bincount(inv, weights=w, minlength=rows.shape[0])
        keep = rows >= 0
        cls = np.repeat(np.arange(rows.shape[0]), keep.sum(axis=1))
        return cls, rows[keep], cw

    @staticmethod
    def _unique_rows(table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """np.unique(table, axis=0, return_inverse=True), by a 64-bit hash of each row, checked
        (a collision falls back to numpy's row sort, 4-5x slower)."""
        from models.mesh.dual import sorted_unique

        mult = np.random.default_rng(12345).integers(1, 2**63 - 1, size=table.shape[1], dtype=np.int64) | 1
        with np.errstate(over="ignore"):
            h = np.zeros(table.shape[0], dtype=np.int64)
            for c in range(table.shape[1]):  # a loop over the columns (the most units at one item)
                h = (h ^ (table[:, c] + 1)) * mult[c]
        hk, inv = sorted_unique(h, return_inverse=True)
        first = np.zeros(hk.size, dtype=np.int64)
        first[inv[::-1]] = np.arange(inv.size)[::-1]
        if np.array_equal(table[first][inv], table):
            return table[first], inv
        rows, inv = np.unique(table, axis=0, return_inverse=True)
        return rows, inv.ravel()

    @staticmethod
    def _face_pairs(a: np.ndarray, b: np.ndarray, count: np.ndarray | None = None):
        """Distinct (a, b), a < b, of faces between different units, with their counts."""
        from models.mesh.dual import sorted_unique

        s = a != b
        lo, hi = np.minimum(a[s], b[s]), np.maximum(a[s], b[s])
        kk = np.int64(max(int(hi.max()) + 1, 1)) if hi.size else np.int64(1)
        key, inv = sorted_unique(lo * kk + hi, return_inverse=True)
        c = np.bincount(inv, weights=None if count is None else count[s], minlength=key.size)
        return key // kk, key % kk, c

    @classmethod
    def of_cells(cls, mesh: Mesh, graph, units: np.ndarray) -> UnitEuler:
        """The units given by a label per cell."""
        units = np.asarray(units, dtype=np.int64)
        k = int(units.max()) + 1
        (vi, ve), (ei, ee) = _incidence(mesh, graph, units, k)
        chi = _euler(mesh, graph, units, k, ve, ee)
        vc, vu, vw = cls._condensed(vi, ve, None)
        ec, eu, ew = cls._condensed(ei, ee, None)
        faces = (np.zeros(0, dtype=np.int64),) * 2 + (np.zeros(0),)
        if mesh.dim == 3:  # faces between cells of two units
            p = graph.partner
            i = np.flatnonzero(p > np.arange(p.size))
            faces = cls._face_pairs(units[graph.faces.cell[i]], units[graph.faces.cell[p[i]]])
        return cls(chi.astype(np.int64), (vc, vu, vw), (ec, eu, ew), faces, mesh.dim)

    def _counted(self, coarse: np.ndarray, K: int):
        """Per item kind: (the sorted distinct class * K + element keys, their classes' weights, the
        excess count per element)."""
        from models.mesh.dual import sorted_unique

        kk = np.int64(K)
        out = []
        for items, us, w in (self.v, self.e):
            keys = items * kk + coarse[us]
            span = (int(items.max()) + 1) * K if items.size else 0
            if span <= max(8 * items.size, 1 << 20):  # few elements (a plane's sides): counted, not sorted
                # (4 fibres through a cube, 21,810 units: the planes' 3-element evaluations 5.2 s of sorts)
                full = np.bincount(keys, minlength=span)
                key = np.flatnonzero(full)
                cnt = full[key]
            else:
                key, cnt = sorted_unique(keys, return_counts=True)
            kw = w[key // kk]
            out.append((key, kw, np.bincount(key % kk, weights=(cnt - 1) * kw, minlength=K)))
        return out

    def __call__(self, coarse: np.ndarray) -> np.ndarray:
        """(K,) chi of each element of `coarse` (an element label per unit)."""
        coarse = np.asarray(coarse, dtype=np.int64)
        K = int(coarse.max()) + 1
        return self._chi(coarse, K, self._counted(coarse, K))

    def _chi(self, coarse: np.ndarray, K: int, counted) -> np.ndarray:
        (_, _, dv), (_, _, de) = counted
        chi = np.bincount(coarse, weights=self.chi, minlength=K) - dv + de
        if self.dim == 3:
            a, b = coarse[self.f[0]], coarse[self.f[1]]
            chi -= np.bincount(a[a == b], weights=self.f[2][a == b], minlength=K)
        return np.rint(chi).astype(np.int64)

    def unions(self, coarse: np.ndarray):
        """union_euler for the elements of `coarse` (an element label per unit): every pair sharing
        a face (2D: a side), as (a, b, chi of A u B, shared faces / sides), a < b."""
        from models.mesh.dual import sorted_unique

        coarse = np.asarray(coarse, dtype=np.int64)
        K = int(coarse.max()) + 1
        kk = np.int64(K)
        counted = self._counted(coarse, K)
        chi = self._chi(coarse, K, counted)
        (kv, wv, _), (ke, we, _) = counted
        vk, vw = _pairs_per_item(kv // kk, kv % kk, K, wv)
        ek, ew = _pairs_per_item(ke // kk, ke % kk, K, we)
        if self.dim == 3:
            lo, hi, count = self._face_pairs(coarse[self.f[0]], coarse[self.f[1]], self.f[2])
            key = lo * kk + hi
            share = _weight_at(key, vk, vw) - _weight_at(key, ek, ew) + count
        else:
            key = sorted_unique(ek)
            count = _weight_at(key, ek, ew)
            share = _weight_at(key, vk, vw) - count
        a, b = key // kk, key % kk
        return a, b, np.rint(chi[a] + chi[b] - share).astype(np.int64), count.astype(np.float64)

    def coarser(self, coarse: np.ndarray) -> UnitEuler:
        """The same for the elements of `coarse` as units (a level above)."""
        coarse = np.asarray(coarse, dtype=np.int64)
        K = int(coarse.max()) + 1
        kk = np.int64(K)
        counted = self._counted(coarse, K)
        skel = []
        for (key, _, _), (_, _, w) in zip(counted, (self.v, self.e), strict=True):
            # each fine class is one coarse item (weight w) held by the elements its units are in
            skel.append(self._condensed(key // kk, key % kk, w))
        faces = self._face_pairs(coarse[self.f[0]], coarse[self.f[1]], self.f[2])
        return UnitEuler(self._chi(coarse, K, counted), skel[0], skel[1], faces, self.dim)


def level_euler(mesh: Mesh, graph, levels: list) -> list[np.ndarray]:
    """element_euler of every level of a nested hierarchy (coarsest first, labels per cell), finest
    first through UnitEuler: one incidence pass."""
    levels = [np.asarray(lv, dtype=np.int64) for lv in levels]
    ue = UnitEuler.of_cells(mesh, graph, levels[-1])
    out = [ue.chi]
    for L in range(len(levels) - 2, -1, -1):  # a loop over the levels, finest first
        node_to = np.zeros(int(levels[L + 1].max()) + 1, dtype=np.int64)
        node_to[levels[L + 1]] = levels[L]
        out.insert(0, ue(node_to))
        if L:
            ue = ue.coarser(node_to)
    return out

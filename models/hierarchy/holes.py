"""No element of a hierarchy encloses a hole: ring cuts instead of stalls (issue 24).

An element that would enclose a hole (2D: a polygon with an inner loop; 3D: an inner shell, or on a
domain without voids an element whose removal cuts other elements off the boundary) is cut in two
along a line (plane) through the hole's centre, across the element's principal axis: the ring
around the hole becomes two elements. Each half is made connected inside the old element. The level
then has a few more elements than requested, so as many pairs of small neighbouring elements of the
same coarser parent are merged back (a merge that would enclose a hole is undone), and the level
keeps its count. Only where a cut does not resolve an element after a few rounds is the element
replaced by its children (the old behaviour, a last resort). fix_holes reports per level the
elements found holed, the ring cuts, the children splits and the merged pairs.
"""

from __future__ import annotations

import numpy as np

from models.hierarchy.topology import alone_around, domain_holes, handle_elements
from models.mesh.celldata import CellData, compact_labels
from models.mesh.container import Mesh
from models.polytope.euler import disjoint_pairs, pinched

RING_ROUNDS = 4  # ring cuts tried per level before an element is replaced by its children
# rounds of merging pairs back while they merge (a round's merges that enclose a hole are undone)
MERGE_ROUNDS = 12


def _without_holes(mesh: Mesh, data: CellData, coarse: np.ndarray, finer: np.ndarray) -> np.ndarray:
    """Replace every coarse element that encloses a hole (or a cavity) by its children."""
    from models.polytope.merge import merge

    for _ in range(int(coarse.max()) + 2):
        _, holes = merge(mesh, data.graph, coarse, data.measures)
        bad = np.unique(holes.elements)
        if bad.size == 0:
            return coarse
        coarse = _split_elements(coarse, bad, finer)
    return coarse


def _sparse_min(values: np.ndarray) -> list[np.ndarray]:
    """Sparse table: tab[j][i] = min(values[i : i + 2**j])."""
    tab = [values]
    j = 1
    while (1 << j) <= values.size:
        prev = tab[-1]
        h = 1 << (j - 1)
        tab.append(np.minimum(prev[:-h], prev[h:]))
        j += 1
    return tab


def _element_graph(graph, labels: np.ndarray):
    """CSR graph of the elements `labels` of the fine graph plus one outside node (id k), joined to
    every element with a boundary face."""
    import scipy.sparse as sp

    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1
    rows = np.repeat(np.arange(labels.size), np.diff(graph.indptr))
    a, b = labels[rows], labels[graph.indices]
    off = a != b
    on_bnd = np.unique(labels[graph.faces.cell[graph.partner < 0]])
    ea = np.concatenate([a[off], on_bnd, np.full(on_bnd.size, k)])
    eb = np.concatenate([b[off], np.full(on_bnd.size, k), on_bnd])
    G = sp.csr_matrix((np.ones(ea.size, dtype=np.int8), (ea, eb)), shape=(k + 1, k + 1))
    G.sum_duplicates()
    return G


def _with_outside(graph, labels: np.ndarray, qptr: np.ndarray, qind: np.ndarray, boundary_cells=None):
    """_element_graph from the elements' own graph (CSR (qptr, qind) without repeats or self loops,
    as rtree_levels gives it): the outside node k is appended to the rows of the elements with a
    boundary face and gets their row; no pass over the fine graph's edges. The same entries as
    _element_graph's, in the given order within rows (sorted rows give the same CSR; the cavity
    check's articulation points do not depend on the order). boundary_cells:
    graph.faces.cell[graph.partner < 0] when already known."""
    import scipy.sparse as sp

    from models.graph.csr import row_pointers

    labels = np.asarray(labels, dtype=np.int64)
    k = qptr.size - 1
    if boundary_cells is None:  # the cells with a face on the domain's boundary
        boundary_cells = graph.faces.cell[graph.partner < 0]
    on_bnd = np.unique(labels[boundary_cells])
    touch = np.zeros(k, dtype=bool)
    touch[on_bnd] = True
    deg = np.diff(qptr)
    ptr = row_pointers(np.r_[deg + touch, on_bnd.size])
    ind = np.empty(int(ptr[-1]), dtype=np.int64)
    ind[np.repeat(ptr[:k] - qptr[:-1], deg) + np.arange(qind.size)] = qind
    ind[ptr[1 : k + 1][touch] - 1] = k
    ind[ptr[k] :] = on_bnd
    return sp.csr_matrix((np.ones(ind.size, dtype=np.int8), ind, ptr), shape=(k + 1, k + 1))


def _coarser_graph(G, node_to: np.ndarray, k: int):
    """The element graph (with the outside node) of a coarser level from a finer level's one:
    node_to maps the finer elements to the coarser ones; the outside node stays the last."""
    import scipy.sparse as sp

    m = np.r_[node_to, k]
    rows = np.repeat(np.arange(G.shape[0]), np.diff(G.indptr))
    a, b = m[rows], m[G.indices]
    off = a != b
    Q = sp.csr_matrix((np.ones(int(off.sum()), dtype=np.int8), (a[off], b[off])), shape=(k + 1, k + 1))
    Q.sum_duplicates()
    return Q


def cavity_elements(graph, labels: np.ndarray, G=None) -> np.ndarray | None:
    """3D elements that enclose a cavity (other elements), found on the graph of the elements, not by
    merging them: with one extra node for the outside (joined to every element with a boundary face),
    an element encloses something exactly when removing it cuts part of the graph off the outside,
    i.e. it is an articulation point of a depth-first tree rooted outside whose child's subtree has
    no edge above it. One DFS (scipy) and sparse-table range minima, no loop over elements. Assumes
    a domain without voids (see _has_voids); pinched contacts count as enclosing (conservative).
    G: the elements' graph (_element_graph) when already known. None: some element never reaches
    the boundary (let merging decide)."""
    from scipy.sparse.csgraph import depth_first_order

    if G is None:
        G = _element_graph(graph, labels)
    k = G.shape[0] - 1
    out_node = k
    order, pred = depth_first_order(G, out_node, directed=True, return_predecessors=True)  # G is symmetric
    N = order.size
    if N < k + 1:  # part of the graph never reaches the boundary (not a mesh we know): let merging decide
        return None
    pre = np.empty(k + 1, dtype=np.int64)
    pre[order] = np.arange(N)
    # depth in the DFS tree by pointer jumping (anc: an ancestor, d: the edges up to it)
    par = np.where(pred < 0, out_node, pred).astype(np.int64)
    anc = par.copy()
    d = (np.arange(k + 1) != out_node).astype(np.int64)
    for _ in range(70):
        if np.all(anc == out_node):
            break
        d, anc = d + d[anc], anc[anc]
    d_by_pos = d[order]
    # end of every subtree: the first later position not deeper than the node
    tab_d = _sparse_min(d_by_pos)
    q = np.arange(1, N + 1)
    dv = d_by_pos
    for j in range(len(tab_d) - 1, -1, -1):
        t = tab_d[j]
        ok = q <= t.size - 1
        step = np.zeros(N, dtype=bool)
        step[ok] = t[q[ok]] > dv[ok]
        q = np.where(step, q + (1 << j), q)
    end = np.minimum(q, N)
    # lowest preorder number any node of a subtree touches
    nb_pre = pre[G.indices]
    deg = np.diff(G.indptr)
    nbmin = np.full(k + 1, N, dtype=np.int64)
    has = deg > 0
    nbmin[has] = np.minimum.reduceat(nb_pre, G.indptr[:-1][has])
    tab = _sparse_min(nbmin[order])
    start = np.arange(N)
    length = end - start
    lj = np.floor(np.log2(np.maximum(length, 1))).astype(np.int64)
    low = np.empty(N, dtype=np.int64)
    for j in np.unique(lj):  # a loop over the table's rows
        s = lj == j
        low[s] = np.minimum(tab[j][start[s]], tab[j][end[s] - (1 << j)])
    child = order  # position i holds node order[i]
    p = par[child]
    cut = (child != out_node) & (p != out_node) & (low >= pre[p])
    return np.unique(p[cut])


def _has_voids(mesh: Mesh, graph) -> bool:
    """3D: does the domain's boundary have more than one shell (a void, or several bodies)? The
    shells of merge_3d's one element, without building the polyhedron."""
    from models.polytope.merge import _shells, face_nodes

    bf = np.flatnonzero(graph.partner < 0)
    fo, nodes = face_nodes(graph.faces, bf)
    return bool(_shells(mesh.points, np.zeros(bf.size, dtype=np.int64), fo, nodes).elements.size)


def _atoms(data: CellData, finer: np.ndarray, kf: int) -> tuple[np.ndarray, np.ndarray]:
    """Measures and measure-weighted centroids of the finer level's elements."""
    w = np.abs(np.asarray(data.measures, dtype=np.float64))
    m = np.bincount(finer, weights=w, minlength=kf)
    c = np.asarray(data.centroids, dtype=np.float64)
    x = np.column_stack([np.bincount(finer, weights=w * c[:, d], minlength=kf) for d in range(c.shape[1])])
    return m, x / np.maximum(m, 1e-300)[:, None]


def ring_cut(
    data: CellData,
    coarse: np.ndarray,
    bad: np.ndarray,
    centers: np.ndarray | None,
    finer: np.ndarray,
    holes: tuple[np.ndarray, np.ndarray] | None = None,
    handles: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Every element `bad` of `coarse` cut in two (unions of `finer`'s elements) by the line/plane
    through its hole's centre (`centers[i]` for bad[i]; None or a degenerate cut: the element's own
    centroid) normal to the element's principal axis; each half made connected inside the element.
    holes: (element, centre) of every hole found (sorted by element); an element with two or more
    holes is cut through all of their centres at once where they lie on a line (plane): the cut
    passes through the centres' mean and contains their principal direction, its normal the
    element's principal axis made orthogonal to that direction (so several holes are opened by one
    cut instead of one per round).
    handles: elements among `bad` that are rings around a tunnel (handle_elements): cut through
    their centroid normal to their SECOND principal axis, a plane that contains the first: a slice of
    a pipe (its first two axes in the slice's plane) and a sleeve along a pipe (its first axis along
    the pipe) are both opened, where a cut across the first axis leaves the sleeve two sleeves.
    Returns the labels (compacted) and the number of elements cut."""
    from models.partition.rtree import _quotient, make_connected

    g = data.graph
    coarse = np.asarray(coarse, dtype=np.int64)
    finer = np.asarray(finer, dtype=np.int64)
    bad = np.asarray(bad, dtype=np.int64)
    k, kf = int(coarse.max()) + 1, int(finer.max()) + 1
    node_to = np.zeros(kf, dtype=np.int64)
    node_to[finer] = coarse
    m, x = _atoms(data, finer, kf)
    dim = x.shape[1]
    isbad = np.zeros(k, dtype=bool)
    isbad[bad] = True
    sel = np.flatnonzero(isbad[node_to])
    e, xa, ma = node_to[sel], x[sel], m[sel]
    M = np.maximum(np.bincount(e, weights=ma, minlength=k), 1e-300)
    mu = (
        np.column_stack([np.bincount(e, weights=ma * xa[:, d], minlength=k) for d in range(dim)]) / M[:, None]
    )
    dx = xa - mu[e]
    C = np.zeros((k, dim, dim))
    for i in range(dim):  # a loop over pairs of axes
        for j in range(i, dim):
            C[:, i, j] = C[:, j, i] = np.bincount(e, weights=ma * dx[:, i] * dx[:, j], minlength=k)
    v = np.zeros((k, dim))
    vecs = np.linalg.eigh(C[bad])[1]
    v[bad] = vecs[:, :, -1]  # the principal axis of each bad element
    if handles is not None and len(handles) and dim == 3:
        ring = np.isin(bad, handles)
        v[bad[ring]] = vecs[ring][:, :, -2]
    h = mu.copy()
    if centers is not None and len(centers):
        h[bad] = np.asarray(centers, dtype=np.float64)[:, :dim]
    if holes is not None and len(holes[0]):
        _through_centres(holes, isbad, h, v, C, dim)
    side = ((xa - h[e]) * v[e]).sum(axis=1) > 0
    n = np.bincount(e, minlength=k)
    n1 = np.bincount(e, weights=side, minlength=k)
    deg = isbad & ((n1 == 0) | (n1 == n))  # the centre's cut misses the element: cut at its centroid
    if deg.any():
        side = np.where(deg[e], ((xa - mu[e]) * v[e]).sum(axis=1) > 0, side)
        n1 = np.bincount(e, weights=side, minlength=k)
    new_id = np.full(k, -1, dtype=np.int64)
    new_id[bad] = k + np.arange(bad.size)
    lab = node_to.copy()
    lab[sel[side]] = new_id[e[side]]
    qp, qi, qw = _quotient(g.indptr, g.indices, g.weights, finer, kf)
    # compact first: an element wholly on one side of its cut leaves its old id empty, and
    # make_connected counts parts as max + 1 (it took 45 pieces of 40 labels for 45 parts, done)
    lab, _ = make_connected(qp, qi, qw, compact_labels(lab), parent=node_to, measures=m)
    lab = compact_labels(lab)
    return lab[finer], int(((n1 > 0) & (n1 < n) & isbad).sum())


def _through_centres(holes, isbad, h, v, C, dim) -> None:
    """Elements with two or more holes: h (the point the cut passes through) becomes the holes'
    mean centre and v (the cut's normal) the element's principal axis made orthogonal to the
    centres' principal direction u (the cut contains the line of the centres); where v is parallel
    to u, the element's second axis. In place."""
    be, cc = np.asarray(holes[0], dtype=np.int64), np.asarray(holes[1], dtype=np.float64)[:, :dim]
    k = isbad.size
    keep = (be < k) & isbad[np.minimum(be, k - 1)]
    be, cc = be[keep], cc[keep]
    nh = np.bincount(be, minlength=k)
    multi = np.flatnonzero(nh >= 2)
    if multi.size == 0:
        return
    cm = np.column_stack([np.bincount(be, weights=cc[:, d], minlength=k) for d in range(dim)])
    cm /= np.maximum(nh, 1)[:, None]
    dc = cc - cm[be]
    S = np.zeros((k, dim, dim))
    for i in range(dim):  # a loop over pairs of axes
        for j in range(i, dim):
            S[:, i, j] = S[:, j, i] = np.bincount(be, weights=dc[:, i] * dc[:, j], minlength=k)
    u = np.linalg.eigh(S[multi])[1][:, :, -1]  # the centres' principal direction
    vm = v[multi] - (v[multi] * u).sum(axis=1)[:, None] * u
    nrm = np.linalg.norm(vm, axis=1)
    flat = nrm < 1e-6
    if flat.any():  # the element's axis along the centres' line: its second axis
        second = np.linalg.eigh(C[multi[flat]])[1][:, :, -2]
        vm[flat] = second - (second * u[flat]).sum(axis=1)[:, None] * u[flat]
        nrm[flat] = np.linalg.norm(vm[flat], axis=1)
    ok = nrm > 1e-9
    h[multi[ok]] = cm[multi[ok]]
    v[multi[ok]] = vm[ok] / nrm[ok][:, None]


def merge_pairs(
    data: CellData,
    labels: np.ndarray,
    parent: np.ndarray,
    origin: np.ndarray,
    forbid: set,
    r: int,
    holes: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, int]:
    """Up to r disjoint pairs of neighbouring elements with the same parent (`parent`: the coarser
    level's label of each cell) merged, the pairs with the fewest cells first; two halves of one
    ring cut (the same `origin`, a label per cell, -1: not cut) never, nor the pairs in `forbid`
    (pairs of the elements' first cells), nor two elements that are the only ones along a hole of
    the domain (`holes`: domain_holes' pairs; their union would surround it: on a domain with many
    holes most merges would, and were made, found holed and undone round after round). Returns
    (labels compacted, pairs merged)."""
    from models.partition.rtree import _quotient

    g = data.graph
    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1
    if r <= 0 or k < 2:
        return labels, 0
    pe = np.zeros(k, dtype=np.int64)
    pe[labels] = parent
    rep = np.full(k, labels.size, dtype=np.int64)
    np.minimum.at(rep, labels, np.arange(labels.size))  # each element's first cell
    og = origin[rep]
    size = np.bincount(labels, minlength=k)
    qp, qi, _ = _quotient(g.indptr, g.indices, g.weights, labels, k)
    a = np.repeat(np.arange(k), np.diff(qp))
    b = qi
    ok = (a < b) & (pe[a] == pe[b])
    if holes is None or not holes[0].size:  # (with the holes known, the rule below decides)
        ok &= (og[a] < 0) | (og[a] != og[b])
    a, b = a[ok], b[ok]
    if holes is not None and holes[0].size:
        hid, hc = holes
        key = np.unique(hid * np.int64(k) + labels[hc])  # (hole, element) pairs, sorted
        h, e = key // k, key % k
        two = np.bincount(h)[h] == 2  # holes along exactly two elements: those two never merge
        lone = np.unique(e[two][0::2] * np.int64(k) + e[two][1::2])
        keep = ~np.isin(np.minimum(a, b) * np.int64(k) + np.maximum(a, b), lone)
        a, b = a[keep], b[keep]
        import scipy.sparse as sp

        HE = sp.csr_matrix((np.ones(h.size), (h, e)), shape=(int(h[-1]) + 1, k))
        shared = np.asarray((HE[:, a].multiply(HE[:, b])).sum(axis=0)).ravel()
    else:
        shared = np.zeros(a.size)
    if forbid:
        key = np.minimum(rep[a], rep[b]) * labels.size + np.maximum(rep[a], rep[b])
        keep = ~np.isin(key, np.fromiter(forbid, dtype=np.int64, count=len(forbid)))
        a, b, shared = a[keep], b[keep], shared[keep]
    order = np.lexsort((size[a] + size[b], shared))  # the fewest holes between them, then the smallest
    target, done = disjoint_pairs(order, b, a, k, r)  # (r: about the ring cuts of one level)
    return compact_labels(target[labels]), done


def _changed(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """The elements of `new` that are not exactly one element of `old` (the same cells)."""
    ko = np.int64(int(old.max()) + 1)
    pair = np.unique(new * ko + old)
    e, o = pair // ko, pair % ko
    k = int(new.max()) + 1
    single = np.bincount(e, minlength=k) == 1
    o_of = np.zeros(k, dtype=np.int64)
    o_of[e[single[e]]] = o[single[e]]
    same = single & (np.bincount(new, minlength=k) == np.bincount(old, minlength=int(ko))[o_of])
    return np.flatnonzero(~same)


class _Detector:
    """Finds the holed elements of one level after another (finest first), with fix_holes' fast
    paths: the elements' graph from rtree's quotient or the finer level's graph (3D domains without
    voids), the finer level's boundary edges (2D)."""

    def __init__(self, mesh: Mesh, data: CellData, graphs: dict | None, rings: bool = False):
        self.mesh, self.data, self.graphs = mesh, data, dict(graphs or {})
        self.bf = None  # 2D: the finer level's boundary faces (None: all faces)
        self.bcells = None  # the cells on the domain's boundary
        self.by_graph = mesh.dim == 3 and not _has_voids(mesh, data.graph)
        # 3D domains with tunnels: elements may be rings around them (handle_elements)
        # 3D: elements may be rings around a tunnel of the domain, or around a neighbour (a band of
        # a thin wall around the bottom of a cup, an element around a cavity and its neighbours):
        # on every 3D domain (handle_elements at the finest level, UnitEuler above it)
        self.tunnels = rings and mesh.dim == 3
        self.handles = np.zeros(0, dtype=np.int64)  # the last call's rings
        self.h_labels = None  # the labels they were found for
        self.ue, self.ue_units = None, None  # UnitEuler of a finer level's elements, their labels
        self.cavities = None  # 3D: domain_holes' (cavity, cell) pairs (fix_holes sets them)

    def _unit_chi(self, lab, finer):
        """Above the finest level: the Euler characteristic of each element of `lab` from the finer
        level's elements' skeleton (UnitEuler, made once per level); None at the finest level."""
        if finer is None or int(finer.max()) + 1 >= finer.size:
            return None
        from models.polytope.euler import UnitEuler

        if self.ue_units is None or not np.array_equal(self.ue_units, finer):
            prev, node_to = self.ue_units, None
            if prev is not None and self.ue is not None:
                node_to = np.zeros(int(prev.max()) + 1, dtype=np.int64)
                node_to[prev] = finer
                if not np.array_equal(node_to[prev], finer):
                    node_to = None  # not nested on the last units
            if node_to is None:
                self.ue = UnitEuler.of_cells(self.mesh, self.data.graph, finer)
            else:
                self.ue = self.ue.coarser(node_to)
            self.ue_units = finer
        unit_to = np.zeros(int(finer.max()) + 1, dtype=np.int64)
        unit_to[finer] = lab
        if not np.array_equal(unit_to[finer], lab):  # (nested always: cuts and merges keep units whole)
            return None
        return self.ue(unit_to)

    def _handles(self, lab, first, finer, chi=None):
        """The rings among the elements of `lab`: above the finest level the elements whose Euler
        characteristic (chi: _unit_chi's, where known) is below 1. At the finest: handle_elements,
        looking only at the elements that changed since the last call on this level (an element is a
        ring or not by its own cells) and at the last rings still there: the merge rounds check a few
        merged pairs, not the whole level, each time."""
        chi = self._unit_chi(lab, finer) if chi is None else chi
        if chi is not None:
            return np.flatnonzero(chi < 1)
        prev = None if first else self.h_labels
        only = None
        if prev is not None and prev.size == lab.size:
            only = _changed(prev, lab)
            if self.handles.size:  # the last rings, by their first cell, where they are unchanged
                first_cell = np.full(int(prev.max()) + 1, lab.size, dtype=np.int64)
                np.minimum.at(first_cell, prev, np.arange(prev.size))
                only = np.union1d(only, lab[first_cell[self.handles]])
        self.h_labels = lab
        return handle_elements(self.mesh, self.data.graph, lab, only)

    def __call__(self, lab, first, L, finer, G_finer):
        """(bad elements, (their holes' elements, centres) or None, polytopes or None, element graph
        or None) of the labels `lab` of level L; first: the level as given (the fast paths apply)."""
        from models.polytope.merge import boundary_faces, merge, merge_2d

        mesh, data = self.mesh, self.data
        if self.by_graph:
            k = int(lab.max()) + 1
            q = self.graphs.pop(L, None) if first else None  # made for the level's labels as given
            if q is not None and q[0].size == k + 1:
                if self.bcells is None:
                    self.bcells = data.graph.faces.cell[data.graph.partner < 0]
                Gl = _with_outside(data.graph, lab, *q, boundary_cells=self.bcells)
            elif G_finer is None or not first:
                Gl = _element_graph(data.graph, lab)
            else:
                node_to = np.zeros(G_finer.shape[0] - 1, dtype=np.int64)
                node_to[finer] = lab
                Gl = _coarser_graph(G_finer, node_to, k)
            bad = cavity_elements(data.graph, lab, Gl)
            if bad is not None:
                if self.tunnels:  # rings around a tunnel: cut through their centroid
                    self.handles = self._handles(lab, first, finer)
                    bad = np.union1d(bad, self.handles)
                return bad, None, None, Gl
            self.by_graph = False  # some element never reaches the boundary: merging decides
        if mesh.dim == 2 and first:  # a nested coarser level's boundary edges are among the finer's
            if self.bf is not None:
                node_to = np.zeros(int(finer.max()) + 1, dtype=np.int64)
                node_to[finer] = lab
                if not np.array_equal(node_to[finer], lab):
                    self.bf = None
            self.bf = boundary_faces(data.graph, lab, among=self.bf)
            p, holes = merge_2d(mesh, data.graph, lab, data.measures, faces=self.bf)
        else:
            chi = self._unit_chi(lab, finer) if self.tunnels else None
            own = alone_around(self.cavities, lab, data.centroids)  # (3D only: fix_holes sets them)
            if chi is not None and not np.any(chi > 1) and not own[0].size:  # no element around a
                p, holes = None, None  # cavity: nothing to merge
            elif chi is not None:  # the shells of the elements around a void only (their own faces)
                from models.polytope.merge import cavity_holes

                p, holes = None, cavity_holes(mesh, data.graph, lab, np.flatnonzero(chi > 1))
            else:
                p, holes = merge(mesh, data.graph, lab, data.measures)
            self.bf = None if mesh.dim != 2 else boundary_faces(data.graph, lab)
        if holes is None:
            be, cen = np.zeros(0, dtype=np.int64), np.zeros((0, mesh.dim))
        else:
            be = np.asarray(holes.elements, dtype=np.int64)
            cen = np.asarray(holes.centers, dtype=np.float64)
        if mesh.dim == 2:  # elements that touch themselves at a vertex around something: that vertex
            pe, pv = pinched(mesh, data.graph, lab)
            new = ~np.isin(pe, be)
            if new.any():
                cen = cen.reshape(be.size, 2) if be.size else np.zeros((0, 2))
                be, cen = np.r_[be, pe[new]], np.vstack([cen, mesh.points[pv[new], :2]])
        if mesh.dim == 3 and own[0].size:  # alone around a cavity: cut through the cavity's centre
            new = ~np.isin(own[0], be)
            if new.any():
                cen = cen.reshape(be.size, 3) if be.size else np.zeros((0, 3))
                be, cen = np.r_[be, own[0][new]], np.vstack([cen, own[1][new]])
        if self.tunnels:  # rings: their centroid as the hole's centre
            self.handles = self._handles(lab, first, finer, chi)
            hb = np.setdiff1d(self.handles, be)
            if hb.size:
                _, x = _atoms(data, lab, int(lab.max()) + 1)
                cen = cen.reshape(be.size, x.shape[1]) if be.size else np.zeros((0, x.shape[1]))
                be, cen = np.r_[be, hb], np.vstack([cen, x[hb]])
        order = np.argsort(be, kind="stable")
        be, cen = be[order], cen[order]
        return np.unique(be), (be, cen), p, None


def thread_holes(
    data: CellData,
    coarse: np.ndarray,
    finer: np.ndarray,
    parent: np.ndarray,
    hole_id: np.ndarray,
    hole_cell: np.ndarray,
) -> tuple[np.ndarray, int]:
    """Elements of `coarse` that alone surround a hole of the domain opened without a new element:
    the shortest path of the finer level's elements from the hole through the element to a
    neighbouring element of the same coarser parent (`parent`: its label per cell) is moved to that
    neighbour, so the hole lies between two elements and the level keeps its count (ring cuts add
    an element per hole; on a domain with many holes the level could not be merged back to its
    count). A move that would disconnect the element is not made. Returns (labels, holes opened)."""
    from models.partition.rtree import _quotient

    if hole_id.size == 0:
        return coarse, 0
    g = data.graph
    coarse = np.asarray(coarse, dtype=np.int64)
    finer = np.asarray(finer, dtype=np.int64)
    kf, k = int(finer.max()) + 1, int(coarse.max()) + 1
    node_to = np.zeros(kf, dtype=np.int64)
    node_to[finer] = coarse
    pe = np.zeros(k, dtype=np.int64)
    pe[coarse] = parent
    hu = finer[hole_cell]
    nh = int(hole_id[-1]) + 1
    lo = np.full(nh, k, dtype=np.int64)
    hi = np.full(nh, -1, dtype=np.int64)
    np.minimum.at(lo, hole_id, node_to[hu])
    np.maximum.at(hi, hole_id, node_to[hu])
    bad = np.flatnonzero(lo == hi)
    if bad.size == 0:
        return coarse, 0
    qp, qi, _ = _quotient(g.indptr, g.indices, g.weights, finer, kf)
    hptr = np.searchsorted(hole_id, np.arange(nh + 1))
    size = np.bincount(node_to, minlength=k)
    pred = np.full(kf, -2, dtype=np.int64)
    mark = np.zeros(kf, dtype=bool)
    opened = 0
    for h in bad:  # a loop over the holes an element surrounds alone (each a search in that element)
        units = np.unique(hu[hptr[h] : hptr[h + 1]])
        grp = int(node_to[units[0]])
        if np.any(node_to[units] != grp):
            continue  # opened by an earlier move
        found, seen = _path_out(qp, qi, node_to, pe, units, grp, pred)
        pred[seen] = -2
        if found is None or found[0].size >= size[grp]:
            continue
        path, target = found
        node_to[path] = target
        rest = np.setdiff1d(seen, path)
        if rest.size == 0 or _reach(qp, qi, node_to, grp, int(rest[0]), mark) != size[grp] - path.size:
            node_to[path] = grp  # it would cut the element in two
            continue
        size[grp] -= path.size
        size[target] += path.size
        opened += 1
    return compact_labels(node_to)[finer], opened


def _path_out(qp, qi, node_to, pe, units, grp, pred):
    """Breadth-first from `units` inside element grp to the first unit with a neighbour in another
    element of grp's parent: ((the path's units, that element), the units searched) or
    (None, searched). pred: -2 everywhere on entry (set on the searched units)."""
    from models.mesh.cells import ranges

    frontier = units
    pred[units] = -1
    seen = [units]
    while frontier.size:
        st = qp[frontier]
        deg = qp[frontier + 1] - st
        nb = qi[ranges(st, deg)]
        src = np.repeat(frontier, deg)
        other = node_to[nb]
        out = (other != grp) & (pe[other] == pe[grp])
        if out.any():
            i = int(np.flatnonzero(out)[0])
            path = [int(src[i])]
            while pred[path[-1]] >= 0:
                path.append(int(pred[path[-1]]))
            return (np.array(path, dtype=np.int64), int(other[i])), np.concatenate(seen)
        inside = (other == grp) & (pred[nb] == -2)
        nb, first = np.unique(nb[inside], return_index=True)
        pred[nb] = src[inside][first]
        seen.append(nb)
        frontier = nb
    return None, np.concatenate(seen)


def _reach(qp, qi, node_to, grp, start, mark) -> int:
    """Units of element grp reached from unit `start` without leaving it (mark: False everywhere on
    entry and on return)."""
    from models.mesh.cells import ranges

    frontier = np.array([start], dtype=np.int64)
    mark[start] = True
    reached = [frontier]
    while frontier.size:
        st = qp[frontier]
        nb = np.unique(qi[ranges(st, qp[frontier + 1] - st)])
        nb = nb[(node_to[nb] == grp) & ~mark[nb]]
        mark[nb] = True
        reached.append(nb)
        frontier = nb
    r = np.concatenate(reached)
    mark[r] = False
    return int(r.size)


def fix_holes(
    mesh: Mesh,
    data: CellData,
    levels: list[np.ndarray],
    graphs: dict | None = None,
    ratio: float | None = None,
    hole_pairs: tuple[np.ndarray, np.ndarray] | None = None,
    rings: bool = False,
    groups: np.ndarray | None = None,
) -> tuple[list[np.ndarray], list, list[dict]]:
    """No element of any level encloses a hole, finest level first (the levels stay nested): each
    holed element is ring-cut (ring_cut), then as many pairs merged back (merge_pairs) so the level
    keeps its count; after RING_ROUNDS rounds an element still holed is replaced by its children.
    Returns the levels, their merged polytopes (for write_hierarchy's `merged`; None where a level
    was checked on the elements' graph: 3D domains without voids, cavity_elements) and a report per
    level (coarsest first): elements, ratio to the finer level, holed elements found, ring cuts,
    elements split into their children, pairs merged back. graphs: level -> the CSR (indptr,
    indices) of the graph of that level's elements where known (rtree_levels'), no repeats or self
    loops. groups: (N,) a compact physical group per cell where no element may cross one: holes are
    threaded, and pairs merged back, within a group only."""
    from models.polytope.merge import merge

    out = list(levels)
    polys = [None] * len(out)
    report = [None] * len(out)
    finer = np.arange(mesh.n_cells)
    detector = _Detector(mesh, data, graphs, rings)
    if hole_pairs is None:  # (domain_holes' pairs where the caller has them)
        hole_pairs = domain_holes(mesh, data)
    detector.cavities = hole_pairs if mesh.dim == 3 else None
    G_finer = None  # the finer level's element graph (each level's comes from it, not from the cells)
    for L in range(len(out) - 1, -1, -1):
        k0 = int(out[L].max()) + 1
        poly = G = None

        bad, cen, poly, G = detector(out[L], True, L, finer, G_finer)
        found, cuts, splits, merged, rounds, threaded = int(bad.size), 0, 0, 0, 0, 0
        if bad.size and hole_pairs[0].size:  # first a path to a neighbour through each holed element
            parent = _parent(out, L, groups, mesh.n_cells)
            out[L], threaded = thread_holes(data, out[L], finer, parent, *hole_pairs)
            if threaded:
                bad, cen, poly, G = detector(out[L], False, L, finer, G_finer)
        touched = np.zeros(mesh.n_cells, dtype=bool)  # cells of elements that were cut
        given = out[L]
        while bad.size:
            touched |= np.isin(out[L], bad)
            if rounds < RING_ROUNDS:
                centres = None
                if cen is not None:  # the first hole of each bad element
                    be, cc = cen
                    first = np.r_[True, be[1:] != be[:-1]]
                    centres = cc[first]
                out[L], c = ring_cut(data, out[L], bad, centres, finer, holes=cen, handles=detector.handles)
                cuts += c
            else:
                out[L] = _split_elements(out[L], bad, finer)
                splits += int(bad.size)
            rounds += 1
            bad, cen, poly, G = detector(out[L], False, L, finer, G_finer)
        parent = _parent(out, L, groups, mesh.n_cells)
        origin = np.where(touched, given, -1)  # the element each cut cell came from
        forbid: set = set()  # pairs (of first cells) whose merge enclosed a hole
        for _ in range(MERGE_ROUNDS):  # merge back as many pairs, inside the coarser level's elements
            extra = int(out[L].max()) + 1 - k0
            if extra <= 0:
                break
            before = out[L]
            after, m = merge_pairs(data, before, parent, origin, forbid, extra, hole_pairs)
            if m == 0:
                break
            bad2, _, p2, G2 = detector(after, False, L, finer, G_finer)
            if bad2.size:  # a merge that encloses a hole: undone, and not tried again
                undo = np.isin(after, bad2)
                cells = np.flatnonzero(undo)
                kb = int(before.max()) + 1
                fb = np.full(kb, mesh.n_cells, dtype=np.int64)
                np.minimum.at(fb, before[cells], cells)  # first cell of each merged half
                hb = np.unique(before[cells])
                ea = after[fb[hb]]  # the merged element of each half
                lo = np.full(int(after.max()) + 1, mesh.n_cells, dtype=np.int64)
                hi = np.full(int(after.max()) + 1, -1, dtype=np.int64)
                np.minimum.at(lo, ea, fb[hb])
                np.maximum.at(hi, ea, fb[hb])
                pair = (hi >= 0) & (lo < hi)
                forbid |= set((lo[pair] * mesh.n_cells + hi[pair]).tolist())
                after = after.copy()
                after[undo] = int(after.max()) + 1 + before[undo]
                after = compact_labels(after)
                m -= int(bad2.size)
                bad2, _, p2, G2 = detector(after, False, L, finer, G_finer)
                if bad2.size:  # cannot happen (the undone elements are the hole-free ones of before)
                    break
            out[L], poly, G = after, p2, G2
            merged += m
        if detector.by_graph:
            if G is None or G.shape[0] != int(out[L].max()) + 2:
                G = _element_graph(data.graph, out[L])
            G_finer = G
        elif poly is None or poly.n_elements != int(out[L].max()) + 1:
            poly, _ = merge(mesh, data.graph, out[L], data.measures)
        polys[L] = None if detector.by_graph else poly
        report[L] = {
            "elements": int(out[L].max()) + 1,
            "holed_elements": found,
            "holes_threaded": threaded,
            "ring_cuts": cuts,
            "split_into_children": splits,
            "merged_pairs": merged,
        }
        finer = out[L]
    recount_report(report, out, mesh.n_cells)
    return out, polys, report


def recount_report(report: list[dict], levels: list[np.ndarray], n_cells: int) -> None:
    """Each level's report (coarsest first) gets its element count and its ratio to the finer level
    (the finest level's to the cells), in place."""
    for L, r in enumerate(report):
        r["elements"] = int(levels[L].max()) + 1
    for L, r in enumerate(report):
        below = n_cells if L + 1 == len(levels) else report[L + 1]["elements"]
        r["ratio"] = below / max(r["elements"], 1)


def _parent(levels: list, L: int, groups: np.ndarray | None, n: int) -> np.ndarray:
    """The label per cell that a move or a merge at level L must keep: the coarser level's element
    (none above the coarsest), with `groups` (physical groups no element crosses) and the group."""
    parent = levels[L - 1] if L > 0 else np.zeros(n, dtype=np.int64)
    if groups is None:
        return parent
    return parent * (int(groups.max()) + 1) + groups


def _split_elements(coarse: np.ndarray, bad: np.ndarray, finer: np.ndarray) -> np.ndarray:
    """The elements `bad` of `coarse` replaced by their children in `finer` (labels compacted)."""
    is_bad = np.zeros(int(coarse.max()) + 1, dtype=bool)
    is_bad[bad] = True
    sel = is_bad[coarse]
    coarse = coarse.copy()
    coarse[sel] = int(coarse.max()) + 1 + finer[sel]
    return compact_labels(coarse)

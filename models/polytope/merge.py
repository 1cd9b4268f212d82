"""Merge each part into one element: 2D boundary loops, 3D boundary faces (vectorized).

2D: the boundary edges of a part keep the counter-clockwise orientation of their cell, so
chaining them gives counter-clockwise outer loops and clockwise hole loops. At a vertex where
the part touches itself, the outgoing edge is the first one met turning clockwise from the
incoming edge (each loop stays simple). Loops are ordered by pointer jumping, no Python loop.
3D: the boundary faces of a part, outward; shells are found by edge connectivity.

Holes. A VTK_POLYGON (and a lymph element) has one boundary loop, so a 2D element that encloses
something (another element, or a hole of the domain) cannot be written as it is. A 3D element with
an inner shell (a cavity) is likewise an object most polyhedral codes reject. `find_holes` reports
them; the pipeline then splits such an element in two across the hole (see pipeline.py): we never
write silently wrong geometry.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from models.errors import MeshError
from models.graph.csr import connected_components, edge_components
from models.mesh.container import Mesh, PolyMesh
from models.mesh.dual import DualGraph, sorted_unique


@dataclass
class Holes:
    """Elements with more than one boundary loop/shell, and a point inside each extra one."""

    elements: np.ndarray  # (H,) element id per hole
    centers: np.ndarray  # (H, dim) a point of the hole (mean of its boundary vertices)
    # 3D: elements whose boundary surface is not a set of spheres (V - E + F of its faces other than
    # 2 per shell: a handle, or a touch along an edge or at a vertex), candidates for
    # models.hierarchy.topology.handle_elements; None where not computed
    odd_surface: np.ndarray | None = None


def boundary_faces(graph: DualGraph, labels: np.ndarray, among: np.ndarray | None = None) -> np.ndarray:
    """Ids of the faces on the boundary of their part. among: only these face ids are looked at (a
    superset of the answer, e.g. the boundary faces of finer parts nested in these), increasing."""
    f = graph.faces
    if among is None:
        lab = labels[f.cell]
        p = graph.partner
        other = np.where(p >= 0, labels[f.cell[np.maximum(p, 0)]], -1)
        return np.flatnonzero((p < 0) | (other != lab))
    p = graph.partner[among]
    other = np.where(p >= 0, labels[f.cell[np.maximum(p, 0)]], -1)
    return among[(p < 0) | (other != labels[f.cell[among]])]


def _list_rank(nxt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cycles of the permutation `nxt`: (cycle id, position in the cycle from its smallest edge)."""
    n = nxt.size
    _, cyc = connected_components(np.arange(n + 1), nxt)  # each edge i -> nxt[i], taken either way
    head = np.full(cyc.max() + 1, n, dtype=np.int64)
    np.minimum.at(head, cyc, np.arange(n))
    is_head = np.zeros(n, dtype=bool)
    is_head[head] = True
    # distance from each edge to the end of its list (the edge before the head), pointer doubling
    succ = np.where(is_head[nxt], np.arange(n), nxt)
    dist = np.where(is_head[nxt], 0, 1).astype(np.int64)
    for _ in range(64):
        if np.all(succ[succ] == succ):
            break
        dist = dist + dist[succ]
        succ = succ[succ]
    length = np.bincount(cyc, minlength=cyc.max() + 1)
    pos = length[cyc] - 1 - dist
    return cyc, pos


def _pair_edges(key_start: np.ndarray, want: np.ndarray) -> np.ndarray | None:
    """merge_2d's successor of every boundary edge when one edge leaves every (element, vertex) and
    one arrives there: the edges sorted by where they end meet, rank for rank, the edges sorted by
    where they start (two sorts, no search; the keys are distinct, so no sort need be stable).
    None where a key repeats (an element touching itself at a vertex) or the boundary is open."""
    order = np.argsort(key_start)
    sk = key_start[order]
    if sk.size == 0 or bool((sk[1:] == sk[:-1]).any()):
        return None
    qo = np.argsort(want)
    if not np.array_equal(want[qo], sk):
        return None
    nxt = np.empty_like(order)
    nxt[qo] = order
    return nxt


def _compiled_loops(key_start: np.ndarray, want: np.ndarray):
    """(nxt, cyc, pos) of _pair_edges + _list_rank from models/graph/_fastgraph.c's loops (a hash table of
    the start keys, then one walk per loop), or None where it is not built or the boundary needs
    the numpy path (a repeated start key: an element touching itself at a vertex; an open or
    non-manifold boundary, which the numpy path reports)."""
    from models.native import compiled

    fg = compiled("graph._fastgraph")
    m = key_start.size
    if fg is None or m == 0:
        return None
    nxt, cyc, pos = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
    ks, wt = np.ascontiguousarray(key_start, dtype=np.int64), np.ascontiguousarray(want, dtype=np.int64)
    if fg.loops(ks, wt, nxt, cyc, pos) < 0:
        return None
    return nxt, cyc, pos


def _next_edges(key_start: np.ndarray, want: np.ndarray):
    """merge_2d's successor of every boundary edge by a search (first match in a stable order), with
    the edges that have more than one candidate (an element touching itself at a vertex)."""
    order = np.argsort(key_start, kind="stable")
    sk = key_start[order]
    lo = np.minimum(np.searchsorted(sk, want, "left"), sk.size - 1)
    if sk.size == 0 or not np.array_equal(sk[lo], want):
        raise MeshError("an element boundary is not closed (the mesh is not a valid 2D manifold)")
    nxt = order[lo]
    # more than one edge leaving the vertex in the element (one searchsorted, not two)
    pinch = np.flatnonzero(sk[np.minimum(lo + 1, sk.size - 1)] == want)
    pinch = pinch[lo[pinch] + 1 < sk.size]
    return nxt, pinch, lo, order, sk


def merge_2d(
    mesh: Mesh, graph: DualGraph, labels: np.ndarray, measures: np.ndarray, faces: np.ndarray | None = None
) -> tuple[PolyMesh, Holes]:
    """Polygons (outer loop CCW first, then holes CW) for every element. faces: the boundary faces
    of the parts when already known (boundary_faces; a coarser level's are among a finer one's)."""
    f = graph.faces
    bf = boundary_faces(graph, labels) if faces is None else faces
    a = f.nodes[2 * bf]
    b = f.nodes[2 * bf + 1]
    e = labels[f.cell[bf]]
    hanging = hanging_edges(mesh, graph)
    if hanging[0].size:  # T-junctions: edges split at the nodes on them, an element's slits closed
        a, b, e = _split_at_hanging(bf, a, b, e, hanging)
    P = np.int64(mesh.n_points)
    key_start = e * P + a
    want = e * P + b
    loops = _compiled_loops(key_start, want)
    if loops is not None:  # one hash pass and one walk in C: the same successors and loops
        nxt, cyc, pos = loops
        pinch = np.zeros(0, dtype=np.int64)
    else:
        nxt = _pair_edges(key_start, want)
        if nxt is None:  # an element touching itself at a vertex, or an open boundary
            nxt, pinch, lo, order, sk = _next_edges(key_start, want)
        else:
            pinch = np.zeros(0, dtype=np.int64)
    if pinch.size:
        pts = mesh.points
        hi = lo.copy()
        hi[pinch] = np.searchsorted(sk, want[pinch], "right")
        for i in pinch:  # rare: vertices where an element touches itself
            cands = order[lo[i] : hi[i]]
            back = pts[a[i]] - pts[b[i]]
            out = pts[b[cands]] - pts[b[i]]
            ang_back = np.arctan2(back[1], back[0])
            ang = np.arctan2(out[:, 1], out[:, 0])
            cw = np.mod(ang_back - ang, 2 * np.pi)  # clockwise turn from the way back
            cw[cw == 0] = 2 * np.pi
            nxt[i] = cands[np.argmin(cw)]
    if loops is None:
        if np.bincount(nxt, minlength=nxt.size).max() > 1:
            raise MeshError("element boundaries could not be ordered (non-manifold vertex)")
        cyc, pos = _list_rank(nxt)
    # signed area of each loop
    p = mesh.points
    pa = p[a]
    ref = np.array([pa[:, 0].min(), pa[:, 1].min()])  # = pa.min(axis=0), 30x faster on (N, 2)
    xa, ya = (pa - ref).T
    xb, yb = (p[b] - ref).T
    area = 0.5 * np.bincount(cyc, weights=xa * yb - xb * ya)
    loop_elem = np.zeros(area.size, dtype=np.int64)
    loop_elem[cyc] = e
    n_elem = int(labels.max()) + 1
    # outer loop = the loop of largest signed area of the element; others are holes
    order_l = np.lexsort((-area, loop_elem))
    first = np.r_[True, loop_elem[order_l][1:] != loop_elem[order_l][:-1]]
    is_outer = np.zeros(area.size, dtype=bool)
    is_outer[order_l[first]] = True
    loop_rank = np.empty(area.size, dtype=np.int64)
    loop_rank[order_l] = np.arange(area.size)
    loop_len = np.bincount(cyc, minlength=area.size)[order_l]
    loop_offsets = np.zeros(area.size + 1, dtype=np.int64)
    np.cumsum(loop_len, out=loop_offsets[1:])
    loop_nodes = np.empty_like(a)  # edges by (loop rank, position in the loop): a scatter, no sort
    loop_nodes[loop_offsets[loop_rank[cyc]] + pos] = a
    per_elem = np.bincount(loop_elem, minlength=n_elem)
    elem_offsets = np.zeros(n_elem + 1, dtype=np.int64)
    np.cumsum(per_elem, out=elem_offsets[1:])
    hole_loops = np.flatnonzero(~is_outer)
    if hole_loops.size:
        centers = np.column_stack(
            [
                np.bincount(cyc, weights=pa[:, d], minlength=area.size)
                / np.bincount(cyc, minlength=area.size)
                for d in range(2)
            ]
        )[hole_loops]
    else:
        centers = np.zeros((0, 2))
    holes = Holes(elements=loop_elem[hole_loops], centers=centers)
    return _polymesh(mesh, elem_offsets, loop_offsets, loop_nodes, labels, measures), holes


def hanging_edges(mesh: Mesh, graph: DualGraph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """2D: the edges on the domain's boundary (face ids, sorted) with boundary nodes strictly inside
    them (hanging nodes, T-junctions: the cells on the two sides are no neighbours), and those nodes
    in order from the edge's first node (CSR: offsets, nodes). Made once per graph."""
    got = getattr(graph, "_hanging", None)
    if got is not None:
        return got
    empty = np.zeros(0, dtype=np.int64)
    got = (empty, np.zeros(1, dtype=np.int64), empty)
    bf = np.flatnonzero(graph.partner < 0) if mesh.dim == 2 else empty
    if bf.size:
        from models.mesh.cells import ranges

        p = mesh.points
        u, v = graph.faces.nodes[2 * bf], graph.faces.nodes[2 * bf + 1]
        verts = np.unique(np.r_[u, v])
        # candidates: the boundary nodes whose x lies within each edge's x range (sorted by x; no
        # scipy: a command that reads a 2D mesh and merges it does not pay its import)
        xs_order = np.argsort(p[verts, 0], kind="stable")
        xs = p[verts[xs_order], 0]
        x0, x1 = np.minimum(p[u, 0], p[v, 0]), np.maximum(p[u, 0], p[v, 0])
        pad = 1e-9 * (x1 - x0) + 1e-12 * max(float(np.ptp(xs)), 1e-300)
        lo, hi = np.searchsorted(xs, x0 - pad, "left"), np.searchsorted(xs, x1 + pad, "right")
        counts = hi - lo
        if counts.sum() > 4 * 10**7:  # (a very long boundary of long edges: a few at a time is no help)
            counts[:] = 0
        if counts.sum():
            edge = np.repeat(np.arange(bf.size), counts)
            cand = verts[xs_order[ranges(lo, counts)]]
            d, w = p[v[edge]] - p[u[edge]], p[cand] - p[u[edge]]
            L2 = np.einsum("ij,ij->i", d, d)
            t = np.einsum("ij,ij->i", w, d) / np.where(L2 > 0, L2, 1.0)
            off = w - t[:, None] * d
            on = (cand != u[edge]) & (cand != v[edge]) & (t > 1e-9) & (t < 1 - 1e-9)
            on &= np.einsum("ij,ij->i", off, off) <= 1e-18 * L2
            edge, cand, t = edge[on], cand[on], t[on]
            if edge.size:
                o = np.lexsort((t, edge))
                edge, cand = edge[o], cand[o]
                ids, n = np.unique(edge, return_counts=True)
                offs = np.zeros(ids.size + 1, dtype=np.int64)
                np.cumsum(n, out=offs[1:])
                got = (bf[ids], offs, cand)
    graph._hanging = got
    return got


def _split_at_hanging(bf, a, b, e, hanging):
    """merge_2d's boundary edges (a -> b of element e) with each edge that has hanging nodes on it
    split at them, then the pairs an element has both ways (a slit: its cells on the two sides of a
    T-junction) dropped."""
    from models.mesh.cells import ranges

    hf, offs, nodes = hanging
    at = np.minimum(np.searchsorted(hf, bf), hf.size - 1)
    split = hf[at] == bf
    if split.any():
        i = np.flatnonzero(split)
        k = offs[at[i] + 1] - offs[at[i]]  # nodes on each split edge
        start = np.zeros(i.size + 1, dtype=np.int64)
        np.cumsum(k + 2, out=start[1:])  # each chain: a, its nodes, b
        chain = np.empty(int(start[-1]), dtype=np.int64)
        chain[start[:-1]] = a[i]
        chain[start[1:] - 1] = b[i]
        inner = ranges(start[:-1] + 1, k)
        chain[inner] = nodes[ranges(offs[at[i]], k)]
        first = ranges(start[:-1], k + 1)  # each chain's edges: (chain[j], chain[j + 1])
        keep = ~split
        a = np.r_[a[keep], chain[first]]
        b = np.r_[b[keep], chain[first + 1]]
        e = np.r_[e[keep], np.repeat(e[i], k + 1)]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    o = np.lexsort((hi, lo, e))
    same = (e[o][1:] == e[o][:-1]) & (lo[o][1:] == lo[o][:-1]) & (hi[o][1:] == hi[o][:-1])
    same &= a[o][1:] != a[o][:-1]  # (both ways)
    if same.any():
        j = np.flatnonzero(same)
        drop = np.zeros(a.size, dtype=bool)
        drop[o[j]] = drop[o[j + 1]] = True
        a, b, e = a[~drop], b[~drop], e[~drop]
    return a, b, e


def merge_3d(
    mesh: Mesh, graph: DualGraph, labels: np.ndarray, measures: np.ndarray
) -> tuple[PolyMesh, Holes]:
    """Polyhedra as their outward boundary faces; inner shells (cavities) reported as holes."""
    f = graph.faces
    bf = boundary_faces(graph, labels)
    e = labels[f.cell[bf]]
    order = np.argsort(e, kind="stable")
    bf, e = bf[order], e[order]
    fo, nodes = face_nodes(f, bf)
    n_elem = int(labels.max()) + 1
    per_elem = np.bincount(e, minlength=n_elem)
    elem_offsets = np.zeros(n_elem + 1, dtype=np.int64)
    np.cumsum(per_elem, out=elem_offsets[1:])
    holes = _shells(mesh.points, e, fo, nodes)
    return _polymesh(mesh, elem_offsets, fo, nodes, labels, measures), holes


def cavity_holes(mesh: Mesh, graph: DualGraph, labels: np.ndarray, elements: np.ndarray) -> Holes:
    """merge_3d's holes (inner shells) of the given elements only: their boundary faces alone are
    walked (each element's shells are its own), so a level with a few elements around a void costs a
    few elements' faces, not every element's."""
    f = graph.faces
    bf = boundary_faces(graph, labels)
    e = labels[f.cell[bf]]
    keep = np.isin(e, elements)
    bf, e = bf[keep], e[keep]
    order = np.argsort(e, kind="stable")
    bf, e = bf[order], e[order]
    fo, nodes = face_nodes(f, bf)
    return _shells(mesh.points, e, fo, nodes, pinched=True)


def face_nodes(faces, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(offsets, nodes) of the faces `ids`, in that order (a CSR of their vertex lists)."""
    sizes = np.diff(faces.offsets)[ids]
    fo = np.zeros(ids.size + 1, dtype=np.int64)
    np.cumsum(sizes, out=fo[1:])
    src = np.repeat(faces.offsets[ids] - fo[:-1], sizes) + np.arange(fo[-1])
    return fo, faces.nodes[src]


def _shells(points, face_elem, fo, nodes, pinched: bool = False) -> Holes:
    """Connected face shells per element; every shell but the largest-volume one is a cavity.
    pinched: at an edge of 4, 6, ... of an element's faces, link them across the sectors outside it
    (_edge_links: a void meeting the outside along an edge is a cavity), else all of them (a void
    pinched to the outer surface is no cavity: the k-way path's holes, which meet k that way)."""
    from models.mesh.geometry import cell_index, fan_triangles, next_in_cycle

    nf = face_elem.size
    face_of = cell_index(fo)
    nx = next_in_cycle(fo)
    u, v = nodes, nodes[nx]
    lo, hi = np.minimum(u, v), np.maximum(u, v)
    key_e = face_elem[face_of]
    # sort edges by (element, lo, hi); equal neighbours link two faces (one int64 key where it fits:
    # one argsort, not a three-key lexsort)
    npts = np.int64(points.shape[0])
    if nf and (int(face_elem.max()) + 1) * int(npts) * int(npts) < 2**62:
        key = (key_e * npts + lo) * npts + hi
        s = np.argsort(key)
        ks = key[s]
        same = ks[1:] == ks[:-1]
    else:
        s = np.lexsort((hi, lo, key_e))
        same = (key_e[s][1:] == key_e[s][:-1]) & (lo[s][1:] == lo[s][:-1]) & (hi[s][1:] == hi[s][:-1])
    if pinched:
        fa, fb = _edge_links(points, nodes, fo, face_of, s, same, lo, hi)
    else:
        i = np.flatnonzero(same)
        fa, fb = face_of[s[i]], face_of[s[i + 1]]
    nshell, shell = edge_components(nf, fa, fb)
    odd = _odd_surfaces(face_elem, key_e[s], same, shell, nodes, fo)
    if nf == 0 or nshell == np.count_nonzero(np.bincount(face_elem)):
        return Holes(elements=np.zeros(0, np.int64), centers=np.zeros((0, points.shape[1])), odd_surface=odd)
    owner, tri = fan_triangles(fo, nodes)
    sh = shell[owner]
    ref = points.min(axis=0)
    pa, pb, pc = points[tri[:, 0]] - ref, points[tri[:, 1]] - ref, points[tri[:, 2]] - ref
    vol = np.bincount(sh, weights=np.einsum("ij,ij->i", pa, np.cross(pb, pc)) / 6.0, minlength=nshell)
    shell_elem = np.zeros(nshell, dtype=np.int64)
    shell_elem[shell] = face_elem
    o = np.lexsort((-vol, shell_elem))
    first = np.r_[True, shell_elem[o][1:] != shell_elem[o][:-1]]
    inner = o[~first]
    cnt = np.bincount(shell[face_of], minlength=nshell).astype(np.float64)
    centers = np.column_stack(
        [np.bincount(shell[face_of], weights=points[nodes, d], minlength=nshell) / cnt for d in range(3)]
    )
    return Holes(elements=shell_elem[inner], centers=centers[inner], odd_surface=odd)


def _edge_links(points, nodes, fo, face_of, s, same, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of an element's boundary faces that _shells links (fa, fb): at an edge of two of its
    faces, those two. At an edge of 4, 6, ... (the element's surface pinched there: two voxels meeting
    along an edge), the faces in their order around the edge, each linked to the next across the
    sector outside the element (its outward normal points into it), so that each shell bounds one
    side of the complement: a void meeting the outside or another void only along an edge is still
    a cavity (a voxel block's voids touching diagonally: an element around one had Euler
    characteristic 2 and no inner shell). Odd counts (not one element's surface): all linked.
    s, same: the edge occurrences sorted by (element, lo, hi) and where a key repeats."""
    from models.mesh.geometry import cell_index, next_in_cycle, reorder_csr

    run = np.cumsum(np.r_[True, ~same]) - 1
    size = np.bincount(run)
    pinch = (size[run] > 2) & (size[run] % 2 == 0)  # an occurrence at an edge of 4, 6, ... faces
    i = np.flatnonzero(same & ~pinch[:-1])
    fa, fb = face_of[s[i]], face_of[s[i + 1]]
    big = np.flatnonzero(pinch)
    if big.size == 0:
        return fa, fb
    occ, r = s[big], run[big]  # the edge occurrences at pinched edges, grouped by edge
    faces = face_of[occ]
    base = points.min(axis=0)
    pl = points[lo[occ]] - base
    d = points[hi[occ]] - base - pl
    d /= np.linalg.norm(d, axis=1)[:, None]
    # the centroid (of its nodes) and outward normal (Newell's, as the faces are ordered) of each
    # face met there (only those: on voxel staircases such edges are many, the faces few of all)
    uf, loc = np.unique(faces, return_inverse=True)
    ufo, unodes = reorder_csr(fo, nodes, uf)
    owner = cell_index(ufo)
    p_at = points[unodes] - base
    cross = np.cross(p_at, p_at[next_in_cycle(ufo)])
    cen = np.column_stack([np.bincount(owner, weights=p_at[:, c]) / np.diff(ufo) for c in range(3)])[loc]
    normal = np.column_stack([np.bincount(owner, weights=cross[:, c]) for c in range(3)])[loc]
    w = cen - pl
    w -= np.einsum("ij,ij->i", w, d)[:, None] * d
    w /= np.maximum(np.linalg.norm(w, axis=1), 1e-300)[:, None]
    first = np.r_[True, r[1:] != r[:-1]]
    ref = w[first][np.cumsum(first) - 1]  # the first face's direction at each edge
    ang = np.arctan2(np.einsum("ij,ij->i", np.cross(d, ref), w), np.einsum("ij,ij->i", ref, w))
    o = np.lexsort((ang, r))
    faces, r, w, d, normal = faces[o], r[o], w[o], d[o], normal[o]
    first = np.r_[True, r[1:] != r[:-1]]
    gstart = np.flatnonzero(first)
    nxt = np.arange(r.size) + 1
    last = np.r_[gstart[1:], r.size] - 1
    nxt[last] = gstart  # cyclic around each edge
    out = np.einsum("ij,ij->i", normal, np.cross(d, w)) > 0  # the sector after it is outside
    return np.r_[fa, faces[out]], np.r_[fb, faces[nxt[out]]]


def _odd_surfaces(face_elem, edge_elem_sorted, same, shell, nodes, fo) -> np.ndarray:
    """The elements whose boundary faces have V - E + F other than 2 per shell, or an edge on more
    than two of them (_shells' sorted edges: a shell of genus g has 2 - 2g; an element touching
    itself along an edge has such an edge). face_elem ascending; V by the compiled per-element
    distinct nodes (cells.distinct_nodes), no global sort."""
    from models.mesh.cells import distinct_nodes

    if face_elem.size == 0:
        return np.zeros(0, dtype=np.int64)
    k = int(face_elem.max()) + 1
    start = np.r_[True, ~same]
    run = np.cumsum(start) - 1
    edge_el = edge_elem_sorted[start]
    F = np.bincount(face_elem, minlength=k)
    E = np.bincount(edge_el, minlength=k)
    V, _ = distinct_nodes(F, np.diff(fo), nodes)
    shell_elem = np.zeros(int(shell.max()) + 1, dtype=np.int64)
    shell_elem[shell] = face_elem
    S = np.bincount(shell_elem, minlength=k)
    odd = (F > 0) & (V - E + F != 2 * S)
    odd[edge_el[np.bincount(run) > 2]] = True
    return np.flatnonzero(odd)


def _polymesh(mesh: Mesh, elem_offsets, loop_offsets, loop_nodes, labels, measures) -> PolyMesh:
    """The PolyMesh of merged elements, with per-element measure, fine-cell count and group."""
    n_elem = elem_offsets.size - 1
    # signed measures when the reader recorded them: a folded cell counts negatively, so that an
    # element's measure is the area/volume its boundary encloses
    signed = mesh.meta.get("signed_measures")
    if signed is not None and signed.shape == measures.shape:
        measures = signed
    return PolyMesh(
        points=mesh.points,
        elem_offsets=elem_offsets,
        loop_offsets=loop_offsets,
        loop_nodes=loop_nodes,
        measure=np.bincount(labels, weights=measures, minlength=n_elem),
        n_fine=np.bincount(labels, minlength=n_elem),
        labels=labels,
        tags=_majority(labels, mesh.tags, n_elem),
        frame=mesh.frame,
    )


def _majority(labels: np.ndarray, tags: np.ndarray | None, n_elem: int) -> np.ndarray | None:
    """Physical group of each element: the group of most of its fine cells."""
    if tags is None:
        return None
    groups, t = sorted_unique(tags, return_inverse=True)
    counts = np.bincount(labels * groups.size + t, minlength=n_elem * groups.size).reshape(
        n_elem, groups.size
    )
    return groups[counts.argmax(axis=1)]


def sort_by_vertex_count(poly: PolyMesh) -> PolyMesh:
    """3D: renumber the elements by their number of distinct vertices (stable).

    meshio reads VTU polyhedra into blocks keyed by vertex count in order of first appearance, but
    splits the cell data by sorted vertex count: the two agree only when the file lists the
    elements sorted that way. Writing them so keeps every 3D result readable by meshio (and so by
    our own reader)."""
    if poly.dim != 3 or poly.n_elements < 2:
        return poly
    from models.mesh.geometry import cell_index, reorder_csr

    e = poly.n_elements
    face_elem = cell_index(poly.elem_offsets)
    node_elem = face_elem[cell_index(poly.loop_offsets)]
    pairs = sorted_unique(node_elem * np.int64(poly.points.shape[0]) + poly.loop_nodes)
    nverts = np.bincount(pairs // poly.points.shape[0], minlength=e)
    perm = np.argsort(nverts, kind="stable")
    if np.array_equal(perm, np.arange(e)):
        return poly
    inv = np.empty(e, dtype=np.int64)
    inv[perm] = np.arange(e)
    elem_offsets, face_ids = reorder_csr(poly.elem_offsets, np.arange(face_elem.size), perm)
    loop_offsets, loop_nodes = reorder_csr(poly.loop_offsets, poly.loop_nodes, face_ids)
    per_face = {
        k: None if getattr(poly, k) is None else getattr(poly, k)[face_ids]
        for k in ("facet_tags", "facet_on_boundary")
    }
    return dataclasses.replace(
        poly,
        elem_offsets=elem_offsets,
        loop_offsets=loop_offsets,
        loop_nodes=loop_nodes,
        measure=poly.measure[perm],
        n_fine=poly.n_fine[perm],
        labels=inv[poly.labels],
        tags=None if poly.tags is None else poly.tags[perm],
        **per_face,
    )


def merge(mesh: Mesh, graph: DualGraph, labels: np.ndarray, measures: np.ndarray) -> tuple[PolyMesh, Holes]:
    """One polygon/polyhedron per element id in `labels` (ids 0..E-1, every part connected)."""
    if mesh.dim == 2:
        return merge_2d(mesh, graph, labels, measures)
    return merge_3d(mesh, graph, labels, measures)

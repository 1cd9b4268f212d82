"""The domain's topology as hierarchies need it (issue 24, round ten): its holes (inner boundary
loops, cavities) and the cells along them, the genus of its boundary (tunnels), the fewest elements
a level may have, and the elements that are rings around a tunnel (handles, by Euler
characteristics). Arrays in, arrays out; models.hierarchy.holes uses them to keep elements from
surrounding holes."""

from __future__ import annotations

import numpy as np

from models.mesh.celldata import CellData
from models.mesh.container import Mesh


def domain_holes(mesh: Mesh, data: CellData) -> tuple[np.ndarray, np.ndarray]:
    """The domain's holes (2D: inner boundary loops; 3D: inner boundary shells, the cavities) and the
    cells along each: (hole id per pair, cell per pair), sorted by hole, each pair once. The outer
    boundary of each connected piece (the component holding the piece's boundary point of least x)
    is no hole. Boundary facets that share a node are one component."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    from models.graph.csr import connected_components as pieces_of
    from models.mesh.geometry import cell_index, next_in_cycle
    from models.polytope.merge import face_nodes

    g = data.graph
    empty = np.zeros(0, dtype=np.int64)
    bf = np.flatnonzero(g.partner < 0)
    if bf.size == 0:
        return empty, empty
    fo, nodes = face_nodes(g.faces, bf)
    n = mesh.n_points
    u, v = nodes, nodes[next_in_cycle(fo)]
    B = sp.csr_matrix((np.ones(u.size, dtype=np.int8), (u, v)), shape=(n, n))
    _, comp = connected_components(B, directed=False)
    cells = np.asarray(g.faces.cell[bf], dtype=np.int64)
    _, body = pieces_of(g.indptr, g.indices)
    owner = cell_index(fo)
    occ_body, occ_comp = body[cells[owner]], comp[nodes]
    order = np.lexsort((mesh.points[nodes, 0], occ_body))
    first = np.r_[True, occ_body[order][1:] != occ_body[order][:-1]]
    outer = np.zeros(int(comp.max()) + 1, dtype=bool)
    outer[occ_comp[order][first]] = True
    fcomp = comp[nodes[fo[:-1]]]
    inner = ~outer[fcomp]
    if not inner.any():
        return empty, empty
    hid = np.unique(fcomp[inner], return_inverse=True)[1].astype(np.int64)
    key = np.unique(hid * np.int64(mesh.n_cells) + cells[inner])
    return key // mesh.n_cells, key % mesh.n_cells


def alone_around(hole_pairs, labels: np.ndarray, centroids: np.ndarray | None = None):
    """The elements of `labels` (one per cell) that alone hold every cell along some hole of the
    domain (hole_pairs: domain_holes' (hole, cell) pairs, or None): in 3D each surrounds a cavity,
    whatever its Euler characteristic says (a cavity and a handle pinched at an edge cancel there).
    (elements, each such hole's centre: its cells' mean centroid, where centroids are given)."""
    hid, hc = hole_pairs if hole_pairs is not None else (None, None)
    dim = 0 if centroids is None else centroids.shape[1]
    none = np.zeros(0, dtype=np.int64), np.zeros((0, dim))
    if hid is None or hc is None or not np.size(hid):
        return none
    nh = int(hid.max()) + 1
    lo, hi = np.full(nh, int(labels.max()) + 1, dtype=np.int64), np.full(nh, -1, dtype=np.int64)
    np.minimum.at(lo, hid, labels[hc])
    np.maximum.at(hi, hid, labels[hc])
    alone = np.flatnonzero(lo == hi)
    if not alone.size or centroids is None:
        return lo[alone], none[1]
    cnt = np.bincount(hid, minlength=nh)[alone]
    x = centroids[hc]
    cen = np.column_stack([np.bincount(hid, weights=x[:, d], minlength=nh)[alone] / cnt for d in range(dim)])
    return lo[alone], cen


def unit_sides(data: CellData, units: np.ndarray, ku: int, hole_pairs=None):
    """Where unions of units (a unit per cell, ku of them) meet the domain's boundary: (each unit on
    the outer boundary, (cavity, unit) pairs of the units along each cavity). A unit on both counts
    as a cavity's only (a cavity's side is no way out; conservative)."""
    g = data.graph
    outer = np.zeros(ku, dtype=bool)
    outer[units[g.faces.cell[g.partner < 0]]] = True
    if hole_pairs is None or hole_pairs[1] is None or not hole_pairs[1].size:
        none = np.zeros(0, dtype=np.int64)
        return outer, none, none
    hole_id, hole_cell = hole_pairs
    outer[units[hole_cell]] = False
    cav = np.unique(hole_id * np.int64(ku) + units[hole_cell])
    return outer, cav // ku, cav % ku


def fewest_elements(
    data: CellData, hole_pairs: tuple[np.ndarray, np.ndarray], genus=None, components=None
) -> tuple[int, str]:
    """The fewest elements a level of this domain can have: one per connected piece, two for a piece
    with a hole (one element would enclose it) or, in 3D, with a tunnel (one element would be a
    ring; genus: each piece's, piece_genus); and why, in words ("" where that is 1). Two linked
    tori: 4 (3 before: a tunnel was counted once for the domain). components: (pieces, each cell's
    piece) where the caller has them."""
    from models.graph.csr import connected_components

    pieces, body = components or connected_components(data.graph.indptr, data.graph.indices)
    with_hole = np.zeros(pieces, dtype=bool)
    with_hole[body[hole_pairs[1]]] = True
    if genus is not None:
        with_hole |= genus[:pieces] > 0
    holed = int(np.count_nonzero(with_hole))
    why = []
    if pieces > 1:
        why.append(f"the mesh has {pieces} separate pieces")
    if holed:
        why.append(
            "one element cannot surround a hole" + ("" if pieces == 1 else f" ({holed} pieces have one)")
        )
    return pieces + holed, "; ".join(why)


def handle_elements(
    mesh: Mesh, graph, labels: np.ndarray, only: np.ndarray | None = None, cavities: bool = False
):
    """3D elements with a handle: rings around a tunnel of the domain (a pipe cut into slices along
    its length, a torus cut across its tube) are no polyhedra a solver's element may be, as a polygon
    around a hole is none. Candidates: elements whose boundary faces (on the domain's boundary or
    next to another element) have Euler characteristic V - E + F below 2 (a shell of genus g has
    2 - 2g; an element touching itself at a vertex also falls below 2). Each candidate is then judged
    by the Euler characteristic of its cells (V - E + F - C = 1 - handles + cavities for a connected
    element; a touch at a vertex leaves it 1): fewer than 1 is a handle. No loop over elements.
    only: the elements to look at (the others are not handles in the answer). cavities: also the
    elements around a cavity whose inner surface touches the outer one along an edge or at a vertex
    (one non-manifold shell: polyhedron merging finds no inner shell), whose cells have a
    characteristic above 1 (their boundary's above 2): then (handles, those)."""
    from models.mesh.dual import sorted_unique
    from models.mesh.geometry import next_in_cycle
    from models.polytope.merge import boundary_faces, face_nodes

    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1
    n = np.int64(mesh.n_points)
    f = graph.faces

    pinch = np.zeros(k, dtype=bool)  # elements with a boundary edge on more than two of their faces

    def chi(face_ids, el, edges_seen=False):
        """V - E of each element's faces (sorts, not numpy's hash-based unique); edges_seen: mark
        `pinch`."""
        fo, nodes = face_nodes(f, face_ids)
        owner = np.repeat(el, np.diff(fo))
        V = np.bincount(sorted_unique(owner * n + nodes) // n, minlength=k)
        u, v = nodes, nodes[next_in_cycle(fo)]
        edge = sorted_unique(np.minimum(u, v) * n + np.maximum(u, v), return_inverse=True)[1]
        m = np.int64(edge.max() + 1) if edge.size else np.int64(1)
        key, count = sorted_unique(owner * m + edge, return_counts=True)
        if edges_seen:
            pinch[key[count > 2] // m] = True
        return V - np.bincount(key // m, minlength=k)

    bf = boundary_faces(graph, labels)
    look = np.ones(k, dtype=bool)
    if only is not None:
        look[:] = False
        look[np.asarray(only, dtype=np.int64)] = True
        bf = bf[look[labels[f.cell[bf]]]]
    bel = labels[f.cell[bf]]
    nb = np.bincount(bel, minlength=k)  # (complete for the elements looked at)
    surface = chi(bf, bel, cavities) + nb
    cand = np.flatnonzero(((surface < 2) | (cavities & ((surface > 2) | pinch))) & look)
    if cand.size == 0:
        return (cand, cand) if cavities else cand
    mine = np.zeros(k, dtype=bool)
    mine[cand] = True
    fc = np.flatnonzero(mine[labels[f.cell]])  # every face of the candidates' cells
    fel = labels[f.cell[fc]]
    # faces of the element's cells: one inside the element is listed twice (once per cell)
    F = (np.bincount(fel, minlength=k) + nb) // 2
    from models.polytope.euler import cells_counted

    C = cells_counted(mesh, graph, labels, k)  # (polyhedra read back: against their own characteristic)
    volume_chi = chi(fc, fel) + F - C
    if cavities:
        return cand[volume_chi[cand] < 1], cand[volume_chi[cand] > 1]
    return cand[volume_chi[cand] < 1]


def domain_genus(mesh: Mesh, graph, with_shells: bool = False):
    """3D: the summed genus of the domain's boundary shells (a torus 1, a block with two crossing
    tunnels 2; 0 for a ball, a box with cavities): (2 S - (V - E + F)) / 2 over its boundary faces.
    with_shells: (genus, S), S the number of boundary shells (above 1: cavities or separate pieces)."""
    genus, shells = piece_genus(mesh, graph, with_shells=True)
    return (int(genus[0]), int(shells[0])) if with_shells else int(genus[0])


def piece_genus(
    mesh: Mesh,
    graph,
    body: np.ndarray | None = None,
    pieces: int = 1,
    with_shells: bool = False,
    across: bool = False,
):
    """3D: the genus of each connected piece's boundary shells, summed ((pieces,); body: each cell's
    piece, None: the domain as one), and with_shells the number of shells of each too (2D: 0 and the
    boundary loops). across: faces between two pieces are on both pieces' boundaries (the pieces of
    physical groups: a group's piece around another has two shells)."""
    from models.graph.csr import connected_components
    from models.mesh.geometry import next_in_cycle
    from models.polytope.merge import face_nodes

    on = graph.partner < 0
    if across and body is not None:
        other = graph.faces.cell[np.maximum(graph.partner, 0)]
        on |= body[graph.faces.cell] != body[other]
    bf = np.flatnonzero(on)
    if bf.size == 0:
        zero = np.zeros(pieces, dtype=np.int64)
        return (zero, zero.copy()) if with_shells else zero
    fo, nodes = face_nodes(graph.faces, bf)
    face_piece = (
        np.zeros(bf.size, dtype=np.int64) if body is None else body[graph.faces.cell[bf]].astype(np.int64)
    )
    piece_of = np.repeat(face_piece, np.diff(fo))
    n = np.int64(mesh.n_points)
    # each piece's boundary points apart (two pieces' shells may share points), their edges as a CSR
    # (the compiled union-find: no scipy import in a run)
    pts, at = np.unique(piece_of * n + nodes, return_inverse=True)
    at = at.reshape(-1).astype(np.int64)
    u, v = at, at[next_in_cycle(fo)]
    a, b = np.r_[u, v], np.r_[v, u]
    order = np.argsort(a, kind="stable")
    indptr = np.zeros(pts.size + 1, dtype=np.int64)
    np.cumsum(np.bincount(a, minlength=pts.size), out=indptr[1:])
    shells = connected_components(indptr, b[order])[1].astype(np.int64)
    pp = pts // n  # (each point's piece)
    V = np.bincount(pp, minlength=pieces)
    m = np.int64(pts.size)
    E = np.bincount(pp[np.unique(np.minimum(u, v) * m + np.maximum(u, v)) // m], minlength=pieces)
    F = np.bincount(face_piece, minlength=pieces)
    S = np.bincount(np.unique(pp * m + shells) // m, minlength=pieces)
    if mesh.dim == 2:  # (loops: no genus)
        genus = np.zeros(pieces, dtype=np.int64)
    else:
        genus = np.maximum(np.rint((2 * S - (V - E + F)) / 2).astype(np.int64), 0)
    return (genus, S) if with_shells else genus

"""Orientation by topology: make every cell agree with its neighbours, then fix each piece's sign.

Orienting each cell by the sign of its own measure breaks a mesh with one folded cell (a sliver
whose vertex lies across its opposite edge): the folded cell gets flipped against its neighbours
and no element boundary containing it closes. Instead:

1. two cells sharing an edge (2D) or a face (3D) are consistent when they run through it in
   opposite directions; a parity bit per shared face says whether one of them must be flipped;
2. a spanning forest of the dual graph (scipy breadth-first search from a virtual root joined to
   one cell per connected piece) carries the parities to every cell (pointer doubling, no Python
   loop over cells);
3. every non-tree pair is checked: a contradiction means the mesh cannot be oriented (a Moebius
   strip, an inconsistent 3D mesh) and is reported with the cells involved;
4. each connected piece is flipped as a whole when its total signed measure is negative.

Cells whose signed measure is still negative afterwards are *folded*: they are kept as they are
(their faces match their neighbours', so merged elements come out closed) and reported.
"""

from __future__ import annotations

import numpy as np

from models.errors import MeshError, id_list
from models.mesh.geometry import Faces, cell_faces


def _face_direction(faces: Faces) -> np.ndarray:
    """(F,) one bit per face: the direction in which it runs around its smallest node.

    Two copies of the same face have opposite bits exactly when they run in opposite directions.
    """
    sizes = faces.sizes()
    if np.all(sizes == 2):
        e = faces.nodes.reshape(-1, 2)
        return e[:, 0] < e[:, 1]
    if faces.nodes.size == 3 * faces.n:  # all triangles: the same bit from three comparisons
        t = faces.nodes.reshape(-1, 3)
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        return ~((a < b) ^ (b < c) ^ (c < a))
    _, nxt, prv = _rotation(faces)
    return nxt < prv


def _face_pairs(faces: Faces, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (fa, fb) of faces with the same nodes, only where exactly two cells share the face."""
    from models.mesh.dual import face_keys, sort_keys

    # keep runs of exactly two (a face shared by 3+ cells is a non-manifold seam: left to the graph check)
    return _pairs_of(*sort_keys(face_keys(faces, n_points)))


def _consistent_2d(offsets: np.ndarray, conn: np.ndarray, flip: np.ndarray, n_points: int) -> bool:
    """_consistent for 2D cells straight from the CSR arrays (no edge list is built when all cells
    have the same number of nodes, the usual case)."""
    sizes = np.diff(offsets)
    if sizes.size == 0 or sizes.min() != sizes.max():
        faces = Faces(
            cell=np.repeat(np.arange(sizes.size), sizes),
            offsets=np.arange(0, 2 * conn.size + 1, 2),
            nodes=np.column_stack([conn, conn[_next(offsets)]]).reshape(-1),
        )
        return bool(_consistent(faces, flip, n_points))
    c = conn.reshape(-1, int(sizes[0]))
    if flip.any():
        c = np.where(flip[:, None], c[:, ::-1], c)
    keys = c * np.int64(n_points) + np.roll(c, -1, axis=1)
    s = np.sort(keys, axis=None)
    return not np.any(s[1:] == s[:-1])


def _next(offsets: np.ndarray) -> np.ndarray:
    from models.mesh.geometry import next_in_cycle

    return next_in_cycle(offsets)


def _triangle_rotation(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(smallest node, the node after it, the node before it) of each triangle (T, 3), elementwise."""
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    at_a = (a < b) & (a < c)
    at_b = ~at_a & (b < c)
    m = np.where(at_a, a, np.where(at_b, b, c))
    nxt = np.where(at_a, b, np.where(at_b, c, a))
    prv = np.where(at_a, c, np.where(at_b, a, b))
    return m, nxt, prv


def _rotation(faces: Faces) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(smallest node, the node after it, the node before it) of each face (not edges)."""
    if faces.nodes.size == 3 * faces.n:  # all triangles: no padded table
        return _triangle_rotation(faces.nodes.reshape(-1, 3))
    sizes = faces.sizes()
    pad = faces.padded()
    j = pad.argmin(axis=1)
    r = np.arange(faces.n)
    return pad[r, j], pad[r, (j + 1) % sizes], pad[r, (j - 1) % sizes]


def _consistent(faces: Faces, flip: np.ndarray, n_points: int) -> bool | None:
    """True when, with the cells in `flip` reversed, no face is met twice in the same direction
    (every shared face is then run through oppositely by its two cells). One np.sort of directed
    face keys, no argsort: this is the common case (no folded cell) and must stay cheap.
    False/None: there may be a contradiction (None: keys too wide here), take the full path."""
    sizes = faces.sizes()
    if np.all(sizes == 2):
        e = faces.nodes.reshape(-1, 2)
        f = flip[faces.cell]
        a, b = np.where(f, e[:, 1], e[:, 0]), np.where(f, e[:, 0], e[:, 1])
        keys = a * np.int64(n_points) + b
    else:
        from models.native import compiled

        fast = compiled("mesh._fastmesh")
        if fast is not None:  # the same directed keys, bucketed by smallest node (models/mesh/_fastmesh.c)
            return bool(
                fast.consistent(
                    faces.offsets.astype(np.int64, copy=False),
                    faces.nodes.astype(np.int64, copy=False),
                    faces.cell.astype(np.int64, copy=False),
                    flip.view(np.uint8),
                )
            )
        bits = max(int(n_points - 1).bit_length(), 1)
        if 3 * bits + 3 > 63:
            return None
        m, nxt, prv = _rotation(faces)
        f = flip[faces.cell]
        nxt, prv = np.where(f, prv, nxt), np.where(f, nxt, prv)
        keys = (((m << bits) | nxt) << bits | prv) << 3 | np.minimum(sizes, 7)
    s = np.sort(keys)
    return not np.any(s[1:] == s[:-1])


def _pairing(faces: Faces, n_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(order, same) of models.mesh.dual.sort_keys (not stable: see _shared_pairs) for all-triangle
    faces whose key fits in int64 (the pairing the dual graph needs too) and the faces'
    _face_direction bits (from the same pass over the nodes as the keys), else None."""
    from models.mesh.dual import _triangle_keys, sort_keys

    bits = max(int(n_points - 1).bit_length(), 1)
    if faces.nodes.size != 3 * faces.n or not faces.n or 3 * bits + 3 > 63:
        return None
    direction = np.empty(faces.n, dtype=bool)
    keys = _triangle_keys(faces.nodes.reshape(-1, 3), bits, direction=direction)
    return (*sort_keys(keys, stable=False), direction)


def _shared_pairs(order: np.ndarray, same: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(fa, fb): the two faces of every key of a sorted pairing, fa < fb (stable or not), or None
    when a key is met 3+ times (a non-manifold seam)."""
    if same.size > 1 and np.any(same[1:] & same[:-1]):
        return None
    from models.mesh.dual import shared_pairs

    return shared_pairs(order[:-1][same], order[1:][same])  # by the mask: no index array of the pairs


def _consistent_paired(faces: Faces, flip: np.ndarray, fa: np.ndarray, fb: np.ndarray, bit=None) -> bool:
    """_consistent for all-triangle faces from the undirected pairs (_shared_pairs: every key met
    at most twice): no face is met twice in the same direction. Two triangles with the same nodes
    have the same directed key exactly when their direction bits (after the flips) agree."""
    bit = _face_direction(faces) if bit is None else bit
    if not flip.any():  # e.g. tetrahedra already mirrored by their own sign
        return not np.any(bit[fa] == bit[fb])
    return not np.any((bit[fa] ^ flip[faces.cell[fa]]) == (bit[fb] ^ flip[faces.cell[fb]]))


def _pairs_of(order: np.ndarray, same: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (fa, fb) from a sorted pairing, only where exactly two faces have the key."""
    before = np.r_[False, same[:-1]] if same.size else same
    after = np.r_[same[1:], False] if same.size else same
    from models.mesh.dual import shared_pairs

    i = np.flatnonzero(same & ~before & ~after)
    return shared_pairs(order[i], order[i + 1])


def orientation_flips(
    mesh, measures: np.ndarray, faces: Faces | None = None, pairing: dict | None = None
) -> np.ndarray:
    """(C,) bool: the cells to flip so that neighbours agree and every piece is positive overall.

    `measures` are the signed measures in the cells' current node order. Raises MeshError when no
    consistent orientation exists. `pairing`: a dict that receives, when the faces were paired here
    (before any flip), for the dual graph: "pairs", the (fa, fb) of _shared_pairs, or "order" and
    "same" (models.mesh.dual.sort_keys) when a face is met 3+ times (the graph reports it).
    """
    n = mesh.n_cells
    own = measures < 0
    if mesh.dim == 2 and _consistent_2d(mesh.offsets, mesh.connectivity, own, mesh.n_points):
        return own  # fast path (one plain sort): flipping each cell by its own sign is consistent
    if faces is None and mesh.dim == 3:
        from models.mesh.geometry import fixed_layout_compiled, fixed_template

        fixed = fixed_layout_compiled(mesh)
        if fixed is not None and fixed[0].fixed_consistent(
            mesh.connectivity.astype(np.int64, copy=False),
            *fixed_template(fixed[1]),
            own.view(np.uint8),
            np.array([mesh.n_points], dtype=np.int64),
        ):
            return own  # no face array: the dual graph builds it when it needs it
    faces = faces or cell_faces(mesh)
    paired = _pairing(faces, mesh.n_points) if mesh.dim == 3 else None
    pairs = None
    if paired is not None:
        pairs = _shared_pairs(*paired[:2])
        if pairing is not None:
            if pairs is not None:  # the graph needs these pairs only, not the sorted order
                pairing["pairs"] = pairs
            else:
                pairing["order"], pairing["same"] = paired[:2]
        if pairs is not None and _consistent_paired(faces, own, *pairs, paired[2]):
            return own
    elif mesh.dim == 3 and _consistent(faces, own, mesh.n_points):
        return own
    if pairs is not None:  # every key met at most twice: _pairs_of would give these
        fa, fb = pairs
    else:
        fa, fb = _pairs_of(*paired[:2]) if paired is not None else _face_pairs(faces, mesh.n_points)
    ca, cb = faces.cell[fa], faces.cell[fb]
    keep = ca != cb
    fa, fb, ca, cb = fa[keep], fb[keep], ca[keep], cb[keep]
    bit = paired[2] if paired is not None else _face_direction(faces)
    parity = bit[fa] == bit[fb]  # True: same direction, one of the two must flip
    if not np.any(parity ^ own[ca] ^ own[cb]):
        return own
    flip, piece, n_pieces = _propagate(n, ca, cb, parity, mesh.dim)
    signed = np.where(flip, -measures, measures)
    total = np.bincount(piece, weights=signed, minlength=n_pieces)
    return flip ^ (total[piece] < 0)


def _propagate(n: int, ca: np.ndarray, cb: np.ndarray, parity: np.ndarray, dim: int):
    """Flips from the parities of the pairs: spanning forest + xor along the tree paths."""
    import scipy.sparse as sp  # here only: a consistently oriented mesh never comes here (~0.2 s of start-up)
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    sym_r, sym_c = np.concatenate([ca, cb]), np.concatenate([cb, ca])
    g = sp.csr_matrix((np.ones(sym_r.size, dtype=np.int8), (sym_r, sym_c)), shape=(n, n))
    n_pieces, piece = connected_components(g, directed=True, connection="weak")
    # virtual root n joined to the first cell of every piece; one BFS gives a spanning forest
    first = np.full(n_pieces, n, dtype=np.int64)
    np.minimum.at(first, piece, np.arange(n))
    rows = np.concatenate([sym_r, np.full(n_pieces, n), first])
    cols = np.concatenate([sym_c, first, np.full(n_pieces, n)])
    big = sp.csr_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(n + 1, n + 1))
    _, pred = breadth_first_order(big, n, directed=True, return_predecessors=True)
    pred = pred[:n].astype(np.int64)
    # parity of every tree edge (v, pred[v]): look the pair up among the shared faces
    pair_key = np.minimum(ca, cb) * np.int64(n) + np.maximum(ca, cb)
    korder = np.argsort(pair_key, kind="stable")
    skeys = pair_key[korder]
    v = np.arange(n, dtype=np.int64)
    is_root = pred == n
    par = np.where(is_root, v, pred)
    want = np.minimum(v, par) * np.int64(n) + np.maximum(v, par)
    pos = np.minimum(np.searchsorted(skeys, want), max(skeys.size - 1, 0))
    acc = np.zeros(n, dtype=bool)
    if skeys.size:
        acc = ~is_root & parity[korder[pos]]
    # flip[v] = xor of the parities on the path to the root: pointer doubling
    anc = par
    while not np.array_equal(anc[anc], anc):
        acc = acc ^ acc[anc]
        anc = anc[anc]
    bad = (acc[ca] ^ acc[cb]) != parity
    if bad.any():
        i = np.flatnonzero(bad)
        cells = np.unique(np.concatenate([ca[i], cb[i]]))
        what = (
            "surface is not orientable (a Moebius-like strip)"
            if dim == 2
            else "3D cells cannot be oriented consistently (inconsistent faces)"
        )
        raise MeshError(
            f"the mesh {what}: {i.size} shared {'edges' if dim == 2 else 'faces'} contradict the others, "
            f"e.g. between cells {id_list(cells, 6)}; check the connectivity of these cells"
        )
    return acc, piece, n_pieces

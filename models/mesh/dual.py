"""The dual graph of a mesh, built by sorting face keys (no Python loop over cells).

Two cells are neighbours when they share an edge (2D) or a face (3D). A face is keyed by its
three smallest node ids and its size (a conforming mesh has no two different faces with the same
key), so a pyramid's quad face meets a hexahedron's and its triangles meet tetrahedra.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from models.errors import MeshError, id_list
from models.mesh.container import Mesh
from models.mesh.geometry import Faces, cell_faces, face_measures

if TYPE_CHECKING:
    import scipy.sparse as sp


@dataclass
class DualGraph:
    """Symmetric CSR adjacency of the cells.

    indptr (C+1,), indices (2E,): neighbours of each cell, sorted; weights (2E,): measure of the
    shared edge/face. faces: every cell face; partner (F,): the matching face of the neighbour
    cell, -1 on the domain boundary.
    """

    indptr: np.ndarray
    indices: np.ndarray
    weights: np.ndarray
    faces: Faces
    partner: np.ndarray

    @property
    def n(self) -> int:
        return int(self.indptr.shape[0] - 1)

    @property
    def n_edges(self) -> int:
        return int(self.indices.shape[0] // 2)

    def degrees(self) -> np.ndarray:
        return np.diff(self.indptr)

    def matrix(self) -> sp.csr_matrix:
        import scipy.sparse as sp  # here only: scipy.sparse costs ~0.2 s of a command's start-up

        return sp.csr_matrix((self.weights, self.indices, self.indptr), shape=(self.n, self.n))

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Each undirected edge once: (u, v) with u < v."""
        rows = np.repeat(np.arange(self.n), np.diff(self.indptr))
        keep = rows < self.indices
        return rows[keep], self.indices[keep]


def face_keys(faces: Faces, n_points: int) -> np.ndarray:
    """One sortable int64 key per face, or an (F, 4) key table when the ids do not fit."""
    bits = max(int(n_points - 1).bit_length(), 1)
    if faces.nodes.size == 3 * faces.n and faces.n and 3 * bits + 3 <= 63:
        return _triangle_keys(faces.nodes.reshape(-1, 3), bits)
    sizes = faces.sizes()
    if np.all(sizes == 2):
        return _edge_keys(faces.nodes.reshape(-1, 2), n_points)
    bits = max(int(n_points - 1).bit_length(), 1)
    if faces.nodes.size == 3 * faces.n:  # all triangles: sorted by elementwise min / max
        t = faces.nodes.reshape(-1, 3)
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        lo, hi = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
        mid = a + b + c - lo - hi
        if 3 * bits + 3 <= 63:  # the same key as below, without the (F, 3) table
            lo <<= bits
            lo |= mid
            lo <<= bits
            lo |= hi
            lo <<= 3
            lo |= 3
            return lo
        three = np.column_stack([lo, mid, hi])
    else:
        pad = faces.padded()
        if pad.shape[1] > 3:
            pad.partition(2, axis=1)  # three smallest first
            three = np.sort(pad[:, :3], axis=1)
        else:
            three = np.sort(pad, axis=1)
    s = np.minimum(sizes, 7).astype(np.int64)
    big = np.flatnonzero(sizes >= 5)
    h = _node_set_hash(faces)[big] >> np.uint64(4) if big.size else None  # 60 bits
    if 3 * bits + 3 <= 63:
        keys = (((three[:, 0] << bits) | three[:, 1]) << bits | three[:, 2]) << 3 | s
        if h is not None:  # (low 3 bits 5-7: never a triangle's or a quadrilateral's key)
            keys[big] = (h.astype(np.int64) << 3) | s[big]
        return keys
    if h is not None:  # a negative first column: never a real face's smallest node
        three[big, 0] = -1 - (h >> np.uint64(30)).astype(np.int64)
        three[big, 1] = (h & np.uint64((1 << 30) - 1)).astype(np.int64)
        three[big, 2] = -1
    return np.column_stack([three, s])


def _node_set_hash(faces: Faces) -> np.ndarray:
    """(F,) uint64: a hash of each face's set of nodes, whatever their order (splitmix64 of each
    node, summed). Faces of five nodes and more are keyed by it: two of them may share their three
    smallest nodes (an edge and its midpoint, in a refined polyhedral mesh: snappyHexMesh's, say),
    so the three smallest alone would take them for one face."""
    z = faces.nodes.astype(np.uint64) + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z ^= z >> np.uint64(31)
    return np.add.reduceat(z, faces.offsets[:-1])


def _edge_keys(e: np.ndarray, n_points: int, chunk: int = 1 << 16) -> np.ndarray:
    """face_keys of edges: min * n_points + max, elementwise (not e.min(axis=1): a reduction over
    rows of length 2 is ~10x slower), in chunks whose temporaries stay in cache."""
    out = np.empty(e.shape[0], dtype=np.int64)
    for s in range(0, e.shape[0], chunk):
        a, b = e[s : s + chunk, 0], e[s : s + chunk, 1]
        lo = np.minimum(a, b)
        lo *= np.int64(n_points)
        lo += np.maximum(a, b)
        out[s : s + chunk] = lo
    return out


def _triangle_keys(
    t: np.ndarray, bits: int, chunk: int = 1 << 16, direction: np.ndarray | None = None
) -> np.ndarray:
    """face_keys of all-triangle faces (sorted nodes by elementwise min / max, then the size 3), in
    chunks whose temporaries stay in cache (the same key, elementwise). direction: (F,) bool filled
    with models.mesh.orientation._face_direction's bits from the same chunks."""
    out = np.empty(t.shape[0], dtype=np.int64)
    for s in range(0, t.shape[0], chunk):
        a, b, c = t[s : s + chunk, 0], t[s : s + chunk, 1], t[s : s + chunk, 2]
        if direction is not None:
            np.invert((a < b) ^ (b < c) ^ (c < a), out=direction[s : s + chunk])
        lo, hi = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
        mid = a + b + c - lo - hi
        lo <<= bits
        lo |= mid
        lo <<= bits
        lo |= hi
        lo <<= 3
        lo |= 3
        out[s : s + chunk] = lo
    return out


def sort_keys(keys: np.ndarray, stable: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(order, same): a stable sort of face keys (1D, or rows of a key table) and, for each sorted
    position but the last, whether its key equals the next one (the two faces are one face).
    stable=False: equal 1D keys in any order (numpy's quicksort: 2-3x timsort's speed on keys of an
    unstructured mesh, slower only on nearly sorted ones), for callers that order each pair
    themselves (shared_pairs)."""
    if keys.ndim == 1:
        order = np.argsort(keys, kind="stable" if stable else None)
        same = np.empty(max(keys.size - 1, 0), dtype=bool)
        chunk = 1 << 16  # the sorted keys a chunk at a time (no sorted copy of every key)
        for s in range(0, same.size, chunk):
            sk = keys[order[s : s + chunk + 1]]
            np.equal(sk[1:], sk[:-1], out=same[s : s + chunk])
        return order, same
    order = np.lexsort(keys.T[::-1])
    sk = keys[order]
    return order, np.all(sk[1:] == sk[:-1], axis=1)


def shared_pairs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The faces (a[i], b[i]) of each shared key as (smaller id, larger id): the pairs a stable
    sort gives, whatever the order of equal keys (each key held by exactly these two faces).
    `b` is overwritten (the larger ids): pass arrays of your own, e.g. order[1:][same]."""
    lo = np.minimum(a, b)
    np.maximum(a, b, out=b)
    return lo, b


def dual_graph(mesh: Mesh, faces: Faces | None = None, measures: bool = True) -> DualGraph:
    """Build the dual graph (linear after one sort of the face keys). measures=False: unit edge
    weights instead of shared edge lengths / face areas (for callers that need the topology only)."""
    if faces is None:
        c = cached_faces(mesh)
        faces = c["faces"] if c is not None else cell_faces(mesh)
    n = mesh.n_cells
    fixed = _fixed_layout(faces, n)  # face id k * cell + local face
    k = faces.n // n if fixed else 0
    pairs = _cached_pairs(mesh, faces)  # reading paired the faces (every face met at most twice)
    if pairs is not None:
        fa, fb = pairs
        del pairs  # dropped with fa and fb once used
    else:
        order, same = _cached_pairing(mesh, faces) or sort_keys(face_keys(faces, mesh.n_points), stable=False)
        if same.size > 1 and np.any(same[1:] & same[:-1]):
            j = np.flatnonzero(same[1:] & same[:-1])
            cells = sorted_unique(faces.cell[order[np.concatenate([j, j + 1, j + 2])]])
            raise MeshError(
                f"the mesh is not a manifold: {j.size} edges/faces are shared by more than two cells, "
                f"e.g. by cells {id_list(cells, 6)}; remove the overlapping cells or split the mesh there"
            )
        # temporaries are dropped as soon as they are used: at millions of cells the stage's peak
        # memory is what costs (fresh pages), more than the arithmetic
        fa, fb = shared_pairs(order[:-1][same], order[1:][same])
        del order, same
    if fixed:  # the cells by shifts, not gathers: faces.cell[f] == f // k
        self_loop = (fa >> 2) == (fb >> 2) if k == 4 else (fa // k) == (fb // k)
    else:
        ca, cb = faces.cell[fa], faces.cell[fb]
        self_loop = ca == cb
    if self_loop.any():
        bad = sorted_unique(faces.cell[fa[self_loop]])
        raise MeshError(
            f"{bad.size} cells have the same edge/face twice (duplicated nodes in a cell), e.g. cells "
            f"{id_list(bad, 6)}; fix their connectivity"
        )
    del self_loop
    partner = np.full(faces.n, -1, dtype=np.int64)
    partner[fa] = fb
    partner[fb] = fa
    kept = None
    if not measures:
        fm = np.ones(fa.size)
    else:  # only the shared faces; reading computed every tetrahedron's face areas with its volume
        kept = _cached_areas(mesh, faces, take=fixed)
        fm = kept[fa] if kept is not None else face_measures(mesh.points, faces, fa)
    if fixed:
        # per face: the measure of the face it is shared with (the kept areas, taken from the cache,
        # already hold it on the side fa: no array of every face's measure made anew)
        w = kept if kept is not None else np.empty(faces.n)
        if kept is None:
            w[fa] = fm
        w[fb] = fm
        nnz = 2 * fa.size
        del fa, fb, fm, kept
        direct = _fixed_csr(k, partner, w, nnz)
        if direct is not None:
            indptr, indices, weights = direct
            return DualGraph(indptr=indptr, indices=indices, weights=weights, faces=faces, partner=partner)
        f = np.flatnonzero(partner >= 0)  # a row with a neighbour twice: rebuild the pairs
        fa = f[f < partner[f]]
        fb = partner[fa]
        fm, ca, cb = w[fa], faces.cell[fa], faces.cell[fb]
        del w, f
    rows = np.concatenate([ca, cb])
    cols = np.concatenate([cb, ca])
    w = np.concatenate([fm, fm])
    import scipy.sparse as sp  # here only: triangles, quads and tetrahedra take _fixed_csr

    a = sp.csr_matrix((w, (rows, cols)), shape=(n, n))
    a.sum_duplicates()  # two cells sharing two faces (possible for polyhedra): one edge, summed measure
    a.sort_indices()
    return DualGraph(
        indptr=a.indptr.astype(np.int64),
        indices=a.indices.astype(np.int64),
        weights=a.data.astype(np.float64),
        faces=faces,
        partner=partner,
    )


_NETWORKS = {3: ((0, 1), (1, 2), (0, 1)), 4: ((0, 1), (2, 3), (0, 2), (1, 3), (1, 2))}


def _fixed_layout(faces: Faces, n: int) -> bool:
    """Every cell has k = 3 or 4 faces, laid out cell by cell (triangles, quads, tetrahedra)."""
    k = faces.n // n if n else 0
    if k not in _NETWORKS or faces.n != k * n:
        return False
    ck = faces.cell.reshape(-1, k)
    return np.array_equal(ck[:, 0], np.arange(n)) and all(
        np.array_equal(ck[:, 0], ck[:, j]) for j in range(1, k)
    )


def _fixed_csr(k: int, partner: np.ndarray, w: np.ndarray, nnz: int):
    """The canonical CSR straight from `partner` for the _fixed_layout (k faces per cell): each row
    sorted among its own k entries by a sorting network of elementwise min / max, in chunks written
    straight into the outputs (no COO conversion, no temporaries of the size of the mesh). w: (F,)
    the measure of every shared face; nnz: the number of shared faces (partner >= 0). None when a
    row has a neighbour twice (the general path sums the measures)."""
    n = partner.size // k
    big = np.iinfo(np.int64).max
    p = partner.reshape(n, k)  # face id k * neighbour + local face: the neighbours' order
    indptr = np.zeros(n + 1, dtype=np.int64)
    indices = np.empty(nnz, dtype=np.int64)
    weights = np.empty(nnz)
    pos = 0
    chunk = 1 << 15
    for s in range(0, n, chunk):
        # copies (written below): a one-row chunk's column is contiguous, and ascontiguousarray would
        # hand back a view of `partner` itself (a mesh of one cell got int64 max for its partners)
        c = [p[s : s + chunk, j].copy() for j in range(k)]
        has = [x >= 0 for x in c]
        for j in range(k):
            c[j][~has[j]] = big  # the domain boundary sorts last
        for i, j in _NETWORKS[k]:
            lo = np.minimum(c[i], c[j])
            np.maximum(c[i], c[j], out=c[j])
            c[i] = lo
        cell = [x >> 2 for x in c] if k == 4 else [x // k for x in c]  # entries are >= 0
        for j in range(1, k):
            if np.any((cell[j] == cell[j - 1]) & (c[j] != big)):
                return None
        indptr[s + 1 : s + 1 + c[0].size] = sum(has)
        q = np.stack(c, axis=1)
        q = q[q != big]  # row by row, the boundary (last in each row) left out
        end = pos + q.size
        np.take(w, q, out=weights[pos:end])  # a shared face's two sides have the same measure
        if k == 4:
            np.right_shift(q, 2, out=indices[pos:end])
        else:
            np.floor_divide(q, k, out=indices[pos:end])
        pos = end
    if pos != nnz:
        raise AssertionError(f"_fixed_csr: {pos} neighbours for {nnz} shared faces")
    np.cumsum(indptr[1:], out=indptr[1:])
    return indptr, indices, weights


def _cached_pairing(mesh: Mesh, faces: Faces) -> tuple[np.ndarray, np.ndarray] | None:
    """The (order, same) that reading sorted for the orientation (models.mesh.read._keep_faces), when it
    is still this mesh's: same connectivity array, the faces reading kept."""
    c = cached_faces(mesh)
    if c is None or c["faces"] is not faces or c["order"] is None:
        return None
    return c["order"], c["same"]


def _cached_pairs(mesh: Mesh, faces: Faces) -> tuple[np.ndarray, np.ndarray] | None:
    """The (fa, fb) face pairs reading made for the orientation (models.mesh.orientation._shared_pairs:
    no face met 3+ times), when they are still this mesh's and `faces` are the faces reading kept.
    Taken from the cache (held until the graph is built, not for the mesh's life: a later graph of
    the mesh sorts the face keys again, to the same pairs)."""
    c = cached_faces(mesh)
    if c is None or c["faces"] is not faces:
        return None
    return c.pop("pairs", None)


def _cached_areas(mesh: Mesh, faces: Faces, take: bool = False) -> np.ndarray | None:
    """(F,) the area of every face of `faces` when reading computed them (all tetrahedra), else None.
    take: the caller gets the array to overwrite, and the cache drops it (a later graph of the mesh
    measures the faces again: face_measures gives these areas bit for bit)."""
    c = cached_faces(mesh)
    if c is None or c["faces"] is not faces:
        return None
    return c.pop("areas", None) if take else c.get("areas")


def cached_faces(mesh: Mesh) -> dict | None:
    """mesh.meta["cell_faces"] when it still belongs to this mesh's connectivity array. Whoever edits
    a read mesh's connectivity in place drops meta["cell_faces"] (as for meta["measures"])."""
    c = mesh.meta.get("cell_faces")
    if c is None or c["connectivity"] is not mesh.connectivity:
        return None
    return c


def sorted_unique(x: np.ndarray, return_inverse: bool = False, return_counts: bool = False):
    """np.unique by sorting (numpy 2.4's hash-based np.unique is ~100x slower on wide int64 ranges)."""
    x = np.asarray(x).ravel()
    order = np.argsort(x, kind="stable") if return_inverse else None
    s = x[order] if return_inverse else np.sort(x)
    first = np.ones(s.size, dtype=bool)
    first[1:] = s[1:] != s[:-1]
    uniq = s[first]
    out = [uniq]
    if return_inverse:
        inv = np.empty(x.size, dtype=np.int64)
        inv[order] = np.cumsum(first) - 1
        out.append(inv)
    if return_counts:
        idx = np.flatnonzero(first)
        out.append(np.diff(np.append(idx, s.size)))
    return out[0] if len(out) == 1 else tuple(out)


def stable_order(labels: np.ndarray) -> np.ndarray:
    """argsort(labels, stable), using numpy's radix sort when the labels fit in 16 bits."""
    if labels.size and labels.min() >= 0 and labels.max() < 65536:
        return np.argsort(labels.astype(np.uint16), kind="stable")
    return np.argsort(labels, kind="stable")


def kept_edges(indptr: np.ndarray, indices: np.ndarray, lab: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The CSR (same numbering) keeping only edges between nodes of equal label >= 0. No sort."""
    n = indptr.size - 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    lr = lab[rows]
    e = (lr >= 0) & (lr == lab[indices])
    return kept_indptr(rows, e, n), e


def kept_indptr(rows: np.ndarray, keep: np.ndarray, n: int) -> np.ndarray:
    """The offsets of a CSR of n rows keeping the edges where `keep` is True (rows: each edge's row)."""
    new_indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows[keep], minlength=n), out=new_indptr[1:])
    return new_indptr


def subgraph_by_labels(
    indptr: np.ndarray,
    indices: np.ndarray,
    weights: np.ndarray,
    labels: np.ndarray,
    nodes: np.ndarray | None = None,
):
    """Disjoint union of the subgraphs induced by each label (vectorized, no sort of the edges).

    labels (N,) in 0..K-1 for the nodes considered (all nodes, or `nodes`). Returns
    (order, ptr, sub_indptr, sub_indices, sub_weights): `order` lists the kept original nodes
    grouped by label, ptr (K+1,) the block offsets, and a CSR in the new (local) numbering.
    """
    from models.mesh.geometry import reorder_csr

    n = indptr.size - 1
    if nodes is None:
        lab = np.asarray(labels, dtype=np.int64)
        order = stable_order(lab)
    else:
        lab = np.full(n, -1, dtype=np.int64)
        lab[nodes] = labels
        order = nodes[stable_order(np.asarray(labels))]
    counts = np.bincount(lab[order], minlength=int(lab.max()) + 1 if order.size else 0)
    ptr = np.zeros(counts.size + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    kp, e = kept_edges(indptr, indices, lab)
    new_id = np.full(n, -1, dtype=np.int64)
    new_id[order] = np.arange(order.size)
    if order.size == n and np.array_equal(order, np.arange(n)):
        return order, ptr, kp, indices[e], weights[e]
    sub_indptr, pos = reorder_csr(kp, np.arange(int(kp[-1])), order)
    return order, ptr, sub_indptr, new_id[indices[e][pos]], weights[e][pos]

"""A polyhedron's faces made to agree with each other.

Formats that store each face once and let the two cells beside it refer to it (Exodus NFACED
blocks, Fluent's polyhedral cells) keep the face's own order in both cells: VTK's readers pass it
on, so in one of the two cells the face points inwards, and the cell's volume (a sum over its faces)
comes out wrong, often zero. In a closed polyhedron whose faces agree, every edge is walked once in
each direction by the two faces that share it. Here the faces that disagree are found and reversed,
for every polyhedron at once: two faces walking a shared edge the same way must have opposite
orientations, the other way the same; a two-colouring of each cell's faces by those constraints
(connected components of the graph of (face, orientation) pairs) gives the faces to reverse. The
cell as a whole may still point inwards: reading orients whole cells by their sign afterwards.
"""

from __future__ import annotations

import numpy as np

from models.mesh.geometry import cell_index, next_in_cycle


def agree_faces(
    cell_faces: np.ndarray, face_offsets: np.ndarray, face_nodes: np.ndarray
) -> tuple[int, np.ndarray]:
    """Reverse, in face_nodes (in place), the faces that disagree with most faces of their
    polyhedron (with its first face on a tie). cell_faces: (Q + 1,) CSR of the faces per
    polyhedron; face_offsets: (F + 1,) CSR of the nodes per face. Returns the number of faces
    reversed (0: nothing changed) and the polyhedra that are not closed (an edge of their faces met
    by one face only: a face missing from the file's lists), by their index among the polyhedra. A
    face whose constraints contradict each other (an edge met by three faces of one cell) is left as
    it is; the checks after reading judge such a cell."""
    n_faces = face_offsets.size - 1
    if n_faces == 0:
        return 0, np.zeros(0, dtype=np.int64)
    agreed = _agree_compiled(cell_faces, face_offsets, face_nodes)
    if agreed is not None:  # every cell's faces agree (the usual file): nothing to colour
        return 0, agreed
    face_of = cell_index(face_offsets)  # the face of each node position
    owner = cell_index(cell_faces)  # the polyhedron of each face
    a, b = face_nodes, face_nodes[next_in_cycle(face_offsets)]
    cell = owner[face_of]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((hi, lo, cell))
    lo, hi, cell = lo[order], hi[order], cell[order]
    pair = (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1]) & (cell[1:] == cell[:-1])
    first = np.flatnonzero(pair)
    alone = np.ones(lo.size, dtype=bool)  # an edge no other face of its cell walks
    alone[first] = alone[first + 1] = False
    open_cells = np.unique(cell[alone])
    forward = (a < b)[order]
    same_way = forward[first] == forward[first + 1]
    if not same_way.any():  # every shared edge walked both ways: the faces agree
        return 0, open_cells
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f1, f2 = face_of[order[first]], face_of[order[first + 1]]
    flip = same_way.astype(np.int64)  # node 2f: the face as it is, 2f + 1: reversed
    rows = np.concatenate([2 * f1, 2 * f1 + 1])
    cols = np.concatenate([2 * f2 + flip, 2 * f2 + 1 - flip])
    graph = coo_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(2 * n_faces, 2 * n_faces))
    _, label = connected_components(graph, directed=False)
    per_cell = np.diff(cell_faces)
    first_face = np.minimum(cell_faces[:-1], n_faces - 1)  # (a cell of no faces: never an owner)
    ref = label[2 * first_face][owner]  # the class of each face's cell's first face
    agree, opposite = label[0::2] == ref, label[1::2] == ref
    decided = agree != opposite  # (both: contradictory constraints; neither: not linked to the first)
    agree &= decided
    opposite &= decided
    # the larger class of each cell stays as stored (the first face's on a tie): fewest reversals
    keep_agree = np.bincount(owner, weights=agree, minlength=per_cell.size) >= np.bincount(
        owner, weights=opposite, minlength=per_cell.size
    )
    reverse = np.where(keep_agree[owner], opposite, agree)
    n = int(np.count_nonzero(reverse))
    if n:
        sel = np.flatnonzero(reverse[face_of])  # node positions of the faces to reverse
        f = face_of[sel]
        face_nodes[sel] = face_nodes[face_offsets[f] + face_offsets[f + 1] - 1 - sel]
    return n, open_cells


def _agree_compiled(cell_faces, face_offsets, face_nodes) -> np.ndarray | None:
    """The polyhedra not closed, where every cell's faces agree (agree_faces' first answer, by
    poly_agree in models/mesh/_fastpoly.c); None where some faces disagree (or it is not built)."""
    from models.native import compiled

    fast = compiled("mesh._fastmesh")
    if fast is None:
        return None
    open_cells = np.empty(cell_faces.size - 1, np.uint8)
    answer = fast.poly_agree(
        np.ascontiguousarray(cell_faces, dtype=np.int64),
        np.ascontiguousarray(face_offsets, dtype=np.int64),
        np.ascontiguousarray(face_nodes, dtype=np.int64),
        open_cells,
    )
    return np.flatnonzero(open_cells) if answer == 0 else None


def without_repeats(
    cell_faces: np.ndarray, face_offsets: np.ndarray, face_nodes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The polyhedra's faces without nodes repeated next to each other (a b b c, cyclically: some
    writers repeat a node where an edge collapses), and without the faces left with fewer than
    three nodes: (cell_faces, face_offsets, face_nodes) anew, or None where no node repeats. A
    repeated node makes a zero-length edge that no other face walks: the cell looked open."""
    n_faces = face_offsets.size - 1
    if n_faces == 0:
        return None
    repeat = face_nodes == face_nodes[next_in_cycle(face_offsets)]
    if not repeat.any():
        return None
    face_of = cell_index(face_offsets)
    keep = ~repeat
    left = np.bincount(face_of[keep], minlength=n_faces)
    whole = left >= 3  # (a face of fewer nodes has no area: it is left out)
    keep &= whole[face_of]
    counts = np.bincount(cell_index(cell_faces)[whole], minlength=cell_faces.size - 1)
    return (
        np.concatenate([[0], np.cumsum(counts)]).astype(cell_faces.dtype),
        np.concatenate([[0], np.cumsum(left[whole])]).astype(face_offsets.dtype),
        face_nodes[keep],
    )

"""Building a validated `Mesh` from the cells a reader made: points checked, points welded on
request, polyhedra attached, boundary cells kept, 2D meshes projected onto their plane, cells
checked for degeneracy and oriented by topology (see orientation.py). Every reader ends here.
"""

from __future__ import annotations

import numpy as np

from models.errors import MeshError, ParameterError, id_list
from models.mesh import deferred
from models.mesh.container import (
    VTK_HEXAHEDRON,
    VTK_POLYGON,
    VTK_PYRAMID,
    VTK_QUAD,
    VTK_TETRA,
    VTK_TRIANGLE,
    VTK_WEDGE,
    Mesh,
)
from models.mesh.dropped import few_bad, record_dropped
from models.mesh.invariants import in_range
from models.mesh.plane import FILL_HINT, project_to_plane  # noqa: F401 (FILL_HINT: its users import it here)

# Node permutation that mirrors a cell (turns a negatively oriented cell into a positive one).
MIRROR = {
    VTK_TETRA: np.array([0, 2, 1, 3]),
    VTK_HEXAHEDRON: np.array([0, 3, 2, 1, 4, 7, 6, 5]),
    VTK_WEDGE: np.array([0, 2, 1, 3, 5, 4]),
    VTK_PYRAMID: np.array([0, 3, 2, 1, 4]),
}


# coordinates beyond _HUGE overflow in the measures (the dual graph's face areas square areas: the
# fourth power of lengths); a mesh spanning less than _TINY underflows the same way (volumes, and
# the 1e-14 of the box's that tells a degenerate cell, below the smallest double)
_HUGE, _TINY = 1e75, 1e-75


def mesh_from_cells(
    points: np.ndarray,
    offsets: np.ndarray,
    conn: np.ndarray,
    cell_types: np.ndarray,
    tags: np.ndarray | None,
    tag_name: str | None,
    poly_faces: list,
    bnd,
    lower: dict,
    dim: int,
    weld: float | None = None,
    meta: dict | None = None,
    grid: dict | None = None,
) -> Mesh:
    """Our cells, as a reader made them (see cells.normalize), into a validated, oriented `Mesh`:
    points (P, 2|3) float64; elements in CSR with our VTK types and tags; poly_faces
    [(cell ids, faces per cell, face sizes, face nodes)]; bnd (offsets, conn, types, tags) or None.
    grid: vtk_readers._lattice's hint for a whole 3D structured grid (hexahedra in VTK's lattice
    order), or None. In the sandbox's reading child, the arguments as a Deferred (models.mesh.deferred:
    the caller checks and builds)."""
    if points.ndim != 2 or len(points) == 0:
        raise MeshError("the mesh has no points")
    if points.shape[1] == 1:
        raise MeshError("1D meshes are not supported: the mesh has 1D coordinates")
    if points.shape[1] not in (2, 3):  # (a reader that missed the file's dimension: 0 coordinates)
        raise MeshError(f"its points have {points.shape[1]} coordinates each, where a mesh has 2 or 3")
    if deferred.DEFER:  # (the reading child: the caller checks the rest and builds)
        return deferred.cells(
            points, offsets, conn, cell_types, tags, tag_name, poly_faces, bnd, lower, dim, weld, meta, grid
        )
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    bounds = _bounds(points)  # NaN and infinities show in them (min and max propagate NaN)
    nonfinite = None
    if not (np.isfinite(bounds[0]).all() and np.isfinite(bounds[1]).all()):
        bad = ~np.isfinite(points).all(axis=1)
        unused = _unused_points(bad, len(points), conn, bnd, poly_faces)
        if unused is not None:  # only points no cell uses: left out (VTK reads such a file), and said
            points, conn, bnd, poly_faces = _without_points(points, conn, bnd, poly_faces, unused)
            bounds, nonfinite = _bounds(points), int(unused.sum())
    if not (np.isfinite(bounds[0]).all() and np.isfinite(bounds[1]).all()):
        bad = ~np.isfinite(points).all(axis=1)
        raise MeshError(
            f"the mesh has {'a point' if int(bad.sum()) == 1 else f'{int(bad.sum()):,} points'} with NaN or "
            f"infinite coordinates (first: point {int(np.flatnonzero(bad)[0])})"
        )
    huge = float(max(np.abs(bounds[0]).max(), np.abs(bounds[1]).max()))
    if huge > _HUGE:  # squares overflow: no measure could be computed (numpy warned, every cell
        # came out degenerate)
        from models.mesh.degenerate import point_text

        bad = np.flatnonzero((np.abs(points) > _HUGE).any(axis=1))
        raise MeshError(
            f"the mesh has {'a point' if bad.size == 1 else f'{bad.size:,} points'} with a coordinate "
            f"beyond 1e75 (first: point {int(bad[0])} at {point_text(points[bad[0]])}): too large to compute "
            "with (its measures would overflow); a corrupted coordinate? fix it, or scale the mesh, and retry"
        )
    span = float(np.max(bounds[1] - bounds[0]))  # (no squares: they underflow first)
    if 0 < span < _TINY:  # (every point at one place: refused as degenerate, with the cells' ids)
        raise MeshError(
            f"the mesh spans only {span:.3g} (its bounding box's longest side): too small to compute with (its "
            "measures would underflow); scale its coordinates (to millimetres or metres, say) "
            "and retry"
        )
    if tags is not None and len(tags) != len(cell_types):
        raise MeshError("physical group data does not match the number of cells")

    dropped = None
    if not in_range(conn, len(points)):  # one pass; min and max only to say what was found
        from models.mesh.geometry import cell_index

        if conn.size and int(conn.min()) >= 1 and int(conn.max()) == len(points):
            raise MeshError(  # every cell's ids one too high: written from a 1-based list
                f"the cells number their points from 1 (ids 1..{len(points):,}, as Matlab and Fortran count), "
                f"but the file's format numbers them from 0 (0..{len(points) - 1:,}): subtract 1 from every point id"
            )

        cell = cell_index(offsets)
        bad = np.bincount(cell[(conn < 0) | (conn >= len(points))], minlength=cell_types.size) > 0
        if not few_bad(int(bad.sum()), cell_types.size) or poly_faces:
            lo, hi, n = int(conn.min()), int(conn.max()), len(points)
            found = (  # ids far beyond any count: garbage (a reader's memory past a short array)
                f"found {lo:,}..{hi:,}"
                if lo >= -(n + 1) and hi <= 4 * n + 16
                else "found ids far outside that range (the cells' data does not match what the file declares)"
            )
            raise MeshError(
                f"cells refer to missing points: point ids must be in 0..{n - 1:,}, {found} in "
                f"{int(bad.sum()):,} of the {cell_types.size:,} cells"
            )
        # a few bad cells among many: left out, the rest agglomerated (and said: meta "dropped_cells")
        offsets, conn, cell_types, tags = _without_cells(offsets, conn, cell_types, tags, bad)
        dropped = [("referring to missing points", np.flatnonzero(bad))]

    merged = None
    if weld is None and _no_shared_points(conn, len(points), cell_types.size):
        points, conn, bnd, poly_faces, merged = _merge_copies(points, conn, bnd, poly_faces)
    mesh = Mesh(
        points=points,
        offsets=offsets,
        connectivity=conn,
        cell_types=cell_types,
        tags=tags,
        tag_name=tag_name if tags is not None else None,
    )
    if meta:
        mesh.meta.update(meta)
    if nonfinite:
        mesh.meta["nonfinite_points"] = {
            "count": nonfinite,
            "message": f"{nonfinite:,} point{'s' if nonfinite > 1 else ''} with NaN or infinite coordinates, "
            "used by no cell, left out",
        }
    if dropped:
        record_dropped(mesh, dropped, cell_types.size + dropped[0][1].size)
    if merged:
        mesh.meta["merged_points"] = {
            "count": merged,
            "message": f"no two cells shared a point (each cell had its own copies of its corners, as "
            f"deal.II's DataOut writes): {merged:,} coincident copies merged, so that cells meet their neighbours",
        }
    welded = None
    if weld is not None:
        welded = weld_points(points, weld)
        mesh.connectivity = welded[conn]
        mesh.meta["welded"] = int(np.count_nonzero(welded != np.arange(len(points))))
    if dim == 2:
        _collapse_repeated_nodes(mesh)
    mesh.meta["lower_dim_cells"] = lower
    if poly_faces:
        _attach_polyhedra(mesh, poly_faces)
        pf = mesh.poly_face_nodes
        if pf.min() < 0 or pf.max() >= len(points):
            raise MeshError("polyhedron faces refer to missing points")
        if welded is not None:
            mesh.poly_face_nodes = welded[pf]

    if bnd is not None:
        mesh.boundary_offsets, mesh.boundary_connectivity, mesh.boundary_types, mesh.boundary_tags = bnd
        bc = mesh.boundary_connectivity
        if bc.size and (bc.min() < 0 or bc.max() >= len(points)):
            raise MeshError("boundary cells refer to missing points")
        if welded is not None:
            mesh.boundary_connectivity = welded[bc]

    if dim == 2:
        project_to_plane(mesh)
    if grid is not None and weld is None and not poly_faces:
        _orient_lattice(mesh, grid)
    else:
        _orient_and_check(mesh, bounds if dim == 3 else None)  # (2D points were projected since)
    return mesh


def _unused_points(bad: np.ndarray, n: int, conn, bnd, poly_faces) -> np.ndarray | None:
    """`bad` (points) where no cell, boundary cell or polyhedron face uses any of them, else None."""
    used = np.zeros(n, dtype=bool)
    for ids in (conn, None if bnd is None else bnd[1], *(f[3] for f in poly_faces or ())):
        if ids is not None and len(ids):
            ids = np.asarray(ids)
            used[ids[(ids >= 0) & (ids < n)]] = True
    return None if np.any(bad & used) else bad


def _without_points(points, conn, bnd, poly_faces, drop: np.ndarray):
    """The points less `drop` (unused: _unused_points), every id renumbered (ids out of range stay
    out of range, for the checks that say so)."""
    new_id = np.cumsum(~drop) - 1

    def renumber(ids):
        ids = np.asarray(ids, dtype=np.int64)
        ok = (ids >= 0) & (ids < drop.size)
        return np.where(ok, new_id[np.where(ok, ids, 0)], -1)

    if bnd is not None:
        bnd = (bnd[0], renumber(bnd[1]), *bnd[2:])
    poly_faces = [(*f[:3], renumber(f[3])) for f in poly_faces] if poly_faces else poly_faces
    return np.ascontiguousarray(points[~drop]), renumber(conn), bnd, poly_faces


def _no_shared_points(conn: np.ndarray, n_points: int, n_cells: int) -> bool:
    """True when no point is a corner of two cells (a "cell soup": every cell has its own copies of
    its points). Only then are there at least as many points as corner references, so the count is
    taken only then."""
    if n_cells < 2 or n_points < conn.size or conn.size == 0:
        return False
    head = conn[:4096]  # a point shared among the first cells: no soup (the usual answer, cheaply)
    if np.unique(head).size < head.size:
        return False
    return int(np.bincount(conn, minlength=n_points).max()) <= 1


def _merge_copies(points, conn, bnd, poly_faces):
    """A cell soup's bitwise-equal points merged (first copy kept, points in order of first use),
    applied to the cells, boundary cells and polyhedron faces; (points, conn, bnd, poly_faces,
    copies merged). Only exact copies: distinct points, however close, stay (no tolerance guessed)."""
    _, first, inverse = np.unique(points, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(first, kind="stable")
    new_id = np.empty(first.size, np.int64)
    new_id[order] = np.arange(first.size)
    to = new_id[inverse]
    if bnd is not None:
        bnd = (bnd[0], to[bnd[1]], *bnd[2:])
    poly_faces = [(*f[:3], to[f[3]]) for f in poly_faces] if poly_faces else poly_faces
    return points[first[order]], to[conn], bnd, poly_faces, int(len(points) - first.size)


def weld_points(points: np.ndarray, tol: float) -> np.ndarray:
    """(P,) the point each point is merged into: the smallest id of its group of points closer
    than `tol` (transitively). A k-d tree finds the pairs; groups are connected components."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    if not (isinstance(tol, int | float) and np.isfinite(tol) and tol >= 0):
        raise ParameterError(f"weld tolerance must be a finite number >= 0, got {tol!r}")
    n = len(points)
    pairs = (
        cKDTree(points).query_pairs(float(tol), output_type="ndarray")
        if tol > 0
        else np.zeros((0, 2), np.int64)
    )
    if pairs.size == 0:
        return np.arange(n)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, comp = connected_components(g, directed=False)
    first = np.full(comp.max() + 1, n, dtype=np.int64)
    np.minimum.at(first, comp, np.arange(n))
    return first[comp]


def _collapse_repeated_nodes(mesh: Mesh) -> None:
    """2D: drop a node equal to the next one in its cell's cycle (a quad with a repeated corner
    is a triangle). Cells left with fewer than 3 nodes stay, and are refused as degenerate."""
    from models.mesh.geometry import cell_index, next_in_cycle

    conn = mesh.connectivity
    sizes = np.diff(mesh.offsets)
    if sizes.size and sizes.min() == sizes.max():  # the usual case: one cell size, a cheap test first
        c = conn.reshape(-1, int(sizes[0]))
        if not (np.any(c[:, 1:] == c[:, :-1]) or np.any(c[:, 0] == c[:, -1])):
            return
    rep = conn == conn[next_in_cycle(mesh.offsets)]
    # keep at least one node per cell (a cell whose nodes are all equal keeps one)
    cell = cell_index(mesh.offsets)
    all_rep = np.bincount(cell, weights=rep, minlength=sizes.size) == sizes
    rep &= ~(all_rep[cell] & (np.arange(conn.size) == mesh.offsets[:-1][cell]))
    if not rep.any():
        return
    mesh.meta["collapsed"] = int(rep.sum())
    new_sizes = sizes - np.bincount(cell, weights=rep, minlength=sizes.size).astype(np.int64)
    mesh.connectivity = conn[~rep]
    mesh.offsets = np.concatenate([[0], np.cumsum(new_sizes)]).astype(np.int64)
    mesh.cell_types = np.where(
        new_sizes == 3, VTK_TRIANGLE, np.where(new_sizes == 4, VTK_QUAD, VTK_POLYGON)
    ).astype(np.uint8)


def _attach_polyhedra(mesh: Mesh, poly_faces) -> None:
    mesh.poly_cells = np.concatenate([c for c, _, _, _ in poly_faces])
    nfaces = np.concatenate([n for _, n, _, _ in poly_faces])
    fsizes = np.concatenate([f for _, _, f, _ in poly_faces])
    mesh.poly_cell_faces = np.concatenate([[0], np.cumsum(nfaces)])
    mesh.poly_face_offsets = np.concatenate([[0], np.cumsum(fsizes)])
    mesh.poly_face_nodes = np.concatenate([f for _, _, _, f in poly_faces])
    from models.mesh.polyfaces import agree_faces, without_repeats

    fixed = without_repeats(mesh.poly_cell_faces, mesh.poly_face_offsets, mesh.poly_face_nodes)
    if fixed is not None:  # nodes repeated along a face (a collapsed edge): dropped, as VTK draws it
        mesh.poly_cell_faces, mesh.poly_face_offsets, mesh.poly_face_nodes = fixed
    turned, open_cells = agree_faces(mesh.poly_cell_faces, mesh.poly_face_offsets, mesh.poly_face_nodes)
    if open_cells.size:  # a face missing from a cell's list: its volume is not that of a closed cell
        ids = mesh.poly_cells[open_cells]
        mesh.meta["open_polyhedra"] = {
            "count": int(ids.size),
            "cells": ids[:20].tolist(),
            "message": f"{ids.size:,} polyhedra are not closed (an edge of their faces belongs to one "
            f"face only: a face is missing from the file's lists), e.g. cells {id_list(ids, 6)}; "
            "they are kept, their measures are not exact",
        }
    if turned:  # a format storing each face once for both its cells (Exodus NFACED, Fluent)
        mesh.meta["reversed_faces"] = {
            "count": turned,
            "message": f"{turned:,} polyhedron faces reversed to agree with the other faces of their "
            "cell (the file stores each face once, in one cell's direction)",
        }


def _orient_lattice(mesh: Mesh, grid: dict) -> None:
    """_orient_and_check for a whole 3D structured grid: consistently oriented by construction, so
    no face keys; each cell's signed volume, the degeneracy check and one global flip (lattice.py)."""
    from models.mesh.lattice import lattice_flips, lattice_measures

    vol, cen = lattice_measures(mesh, grid)
    mesh.meta["measures"] = np.abs(vol)
    mesh.meta["centroids"] = cen
    refuse_degenerate(mesh, vol)
    flip = lattice_flips(vol)
    if flip.any():
        _flip_cells(mesh, flip)
    _record_orientation(mesh, np.where(flip, -vol, vol), flip)


def _record_orientation(mesh: Mesh, signed: np.ndarray, flip: np.ndarray) -> None:
    folded = np.flatnonzero(signed < 0)
    mesh.meta["signed_measures"] = signed
    mesh.meta["orientation"] = {
        "flipped": int(np.count_nonzero(flip)),
        "folded": int(folded.size),
        "folded_cells": folded[:20].tolist(),
    }


def _orient_and_check(mesh: Mesh, bounds=None) -> None:
    """Reject degenerate cells, orient cells by topology (see orientation.py), record what was fixed.
    bounds: the points' (min, max) per coordinate where the caller has them."""
    from models.mesh.geometry import (
        _all_tetrahedra,
        _measures_and_centroids,
        _tetra_measures,
        cell_faces,
        cells_validate,
        fixed_layout_compiled,
        tetra_face_areas,
    )
    from models.mesh.orientation import orientation_flips

    fused = cells_validate(mesh)  # template cells or polygons: one compiled pass, no face array
    if fused is not None:
        vol, cen, own, consistent = fused
        mesh.meta["measures"] = np.abs(vol)
        mesh.meta["centroids"] = cen
        if _drop_degenerate(mesh, vol, bounds):  # a few degenerate cells left out: again without them
            return _orient_and_check(mesh, bounds)
        if consistent:  # every cell by its own sign; faces and their pairing left to the dual graph
            if own.any():
                _flip_cells(mesh, own)
            _record_orientation(mesh, np.where(own, -vol, vol), own)
            return
    if mesh.dim == 3:  # wedges, pyramids, tetrahedra written as hexahedra: as the cells they are
        _collapse_hexahedra(mesh)  # (measured below, like every cell of the full path)
    tets = _all_tetrahedra(mesh)
    areas = None  # all tetrahedra: the face areas for the dual graph, from the same corners
    if tets:
        faces = None  # built once the cells are mirrored by their own sign (below)
        vol, cen, areas = _tetra_measures(mesh, face_areas=True)
    else:
        # one cell type of fixed node count, compiled helpers: measures and the orientation check
        # from the cells' template, no face array (the dual graph makes it when it needs it)
        faces = cell_faces(mesh) if mesh.dim == 3 and fixed_layout_compiled(mesh) is None else None
        vol, cen = _measures_and_centroids(mesh, faces)
    mesh.meta["measures"] = np.abs(vol)  # orientation does not change measure or centroid
    mesh.meta["centroids"] = cen
    if _drop_degenerate(mesh, vol, bounds):
        return _orient_and_check(mesh, bounds)
    pairing: dict = {}
    if tets:
        # Mirror every negative tetrahedron first (the usual answer), then build the faces and their
        # pairing once, on the mirrored cells: nothing to rebuild or renumber unless the orientation
        # flips more cells (folded ones). The same result as orienting the cells as they came: the
        # topology fixes each piece up to one global flip, chosen by the sign of its total volume.
        own = vol < 0
        if own.any():
            c = mesh.connectivity.reshape(-1, 4)
            sel = np.flatnonzero(own)
            c[sel, 1], c[sel, 2] = c[sel, 2], c[sel, 1]  # MIRROR[VTK_TETRA]
        faces = cell_faces(mesh)
        more = orientation_flips(mesh, np.abs(vol), faces, pairing)
        flip = own ^ more
    else:
        more = flip = orientation_flips(mesh, vol, faces, pairing)
    # a cell written twice meets its twin's faces in their direction (fused's check says so), one of the
    # two flipped against its own sign, or in 3D a face met 3+ times: only then are repeats looked for
    met_twice = fused is not None and not fused[3]
    if ("order" in pairing or met_twice or np.any(flip != (vol < 0))) and _drop_repeated(mesh):
        return _orient_and_check(mesh, bounds)
    signed = np.where(flip, -vol, vol)
    if more.any():
        _flip_cells(mesh, more)
    if faces is not None:
        _keep_faces(mesh, more, faces, pairing, None if areas is None else tetra_face_areas(areas, flip))
    _record_orientation(mesh, signed, flip)


# a hexahedron's faces (VTK order) and, for each, the opposite face node for node (along the edges
# that join them): a wedge collapses one edge of two opposite faces, a pyramid one face to a point
_HEX_FACES = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [3, 2, 6, 7], [0, 3, 7, 4], [1, 2, 6, 5]])
_HEX_OPPOSITE = np.array([1, 0, 3, 2, 5, 4])


def _collapse_hexahedra(mesh: Mesh) -> bool:
    """Hexahedra with repeated nodes (Tecplot's FEBRICK and many finite-element codes write wedges,
    pyramids and tetrahedra as 8-node bricks) as the cells they are: 6 distinct nodes with one edge
    of two opposite faces collapsed -> a wedge; 5 with a face collapsed to one node -> a pyramid on the
    opposite face; 4 -> a tetrahedron. Orientation is left to the topology (as for any cell). Any other
    collapse stays a hexahedron. Counted in mesh.meta["collapsed_hexahedra"]; True when any changed."""
    hexes = np.flatnonzero(mesh.cell_types == VTK_HEXAHEDRON)
    if hexes.size == 0:
        return False
    at = mesh.offsets[hexes][:, None] + np.arange(8)
    c = mesh.connectivity[at]
    srt = np.sort(c, axis=1)
    distinct = 1 + np.count_nonzero(srt[:, 1:] != srt[:, :-1], axis=1)
    cand = np.flatnonzero(distinct < 8)
    if cand.size == 0:
        return False
    c, d = c[cand], distinct[cand]
    rows = np.full((cand.size, 8), -1, dtype=np.int64)
    types = np.full(cand.size, VTK_HEXAHEDRON, dtype=np.uint8)
    tet = d == 4  # the four distinct nodes in the order they come
    if tet.any():
        ct = c[tet]
        first = ~np.tril(ct[:, :, None] == ct[:, None, :], -1).any(axis=2)
        rows[tet, :4] = ct[first].reshape(-1, 4)
        types[tet] = VTK_TETRA
    for f, face in enumerate(_HEX_FACES):
        opp = _HEX_FACES[_HEX_OPPOSITE[f]]
        fc, oc = c[:, face], c[:, opp]
        pyr = (d == 5) & (types == VTK_HEXAHEDRON) & (oc == oc[:, :1]).all(axis=1)
        if pyr.any():  # the base as the face, the apex the opposite face's one node
            rows[pyr, :5] = np.column_stack([fc[pyr], oc[pyr, 0]])
            types[pyr] = VTK_PYRAMID
        if f % 2:
            continue
        for q in range(4):  # the edge (q, q + 1) of this face and of its opposite collapsed
            a, b = q, (q + 1) % 4
            wedge = (d == 6) & (types == VTK_HEXAHEDRON) & (fc[:, a] == fc[:, b]) & (oc[:, a] == oc[:, b])
            if wedge.any():
                keep = [j for j in range(4) if j != b]
                rows[wedge, :6] = np.column_stack([fc[wedge][:, keep], oc[wedge][:, keep]])
                types[wedge] = VTK_WEDGE
    done = types != VTK_HEXAHEDRON
    if not done.any():
        return False
    new_types = mesh.cell_types.copy()
    new_types[hexes[cand[done]]] = types[done]
    sizes = np.diff(mesh.offsets)
    sizes[hexes[cand[done]]] = np.count_nonzero(rows[done] >= 0, axis=1)
    r, pos = rows[done], at[cand[done]]  # each new row on its cell's first slots, the rest dropped
    conn = mesh.connectivity.copy()
    conn[pos[r >= 0]] = r[r >= 0]
    keep = np.ones(conn.size, dtype=bool)
    keep[pos[r < 0]] = False
    mesh.connectivity = conn[keep]
    mesh.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    mesh.cell_types = new_types
    names = {VTK_WEDGE: "wedge", VTK_PYRAMID: "pyramid", VTK_TETRA: "tetra"}
    mesh.meta["collapsed_hexahedra"] = {
        names[int(t)]: int(n) for t, n in zip(*np.unique(types[done], return_counts=True), strict=True)
    }
    return True


def _without_cells(offsets, conn, cell_types, tags, bad: np.ndarray):
    """The CSR cells without those where `bad` is True (offsets, connectivity, types, tags)."""
    sizes = np.diff(offsets)[~bad]
    keep = np.repeat(~bad, np.diff(offsets))
    new_offsets = np.zeros(sizes.size + 1, dtype=np.int64)
    np.cumsum(sizes, out=new_offsets[1:])
    return new_offsets, conn[keep], cell_types[~bad], None if tags is None else tags[~bad]


def _drop_degenerate(mesh: Mesh, vol: np.ndarray, bounds=None) -> bool:
    """refuse_degenerate, except that a few degenerate cells among many (few_bad) are left out of the
    mesh (True: the caller orients it again without them)."""
    degenerate = _degenerate(mesh, vol, bounds)
    if not degenerate.any():
        return False
    from models.mesh.degenerate import far_point

    if not few_bad(int(degenerate.sum()), degenerate.size) or mesh.poly_cells is not None or far_point(mesh):
        refuse_degenerate(mesh, vol, bounds, degenerate)
        return False
    kind = "area" if mesh.dim == 2 else "volume"
    n_before = mesh.n_cells
    mesh.offsets, mesh.connectivity, mesh.cell_types, mesh.tags = _without_cells(
        mesh.offsets, mesh.connectivity, mesh.cell_types, mesh.tags, degenerate
    )
    record_dropped(mesh, [(f"degenerate (zero-{kind})", np.flatnonzero(degenerate))], n_before)
    for key in ("measures", "centroids"):
        mesh.meta.pop(key, None)
    return True


def _drop_repeated(mesh: Mesh) -> bool:
    """Cells written twice (the same type and the same nodes as an earlier cell): a few among many
    (few_bad) are left out and said (True: the caller orients the mesh again without them); more is
    refused in one sentence. Looked for only where the orientation had to flip cells or met a face
    3+ times (a repeated cell does both); polyhedra are not compared."""
    if mesh.poly_cells is not None or mesh.n_cells < 2:
        return False
    sizes = np.diff(mesh.offsets)
    repeated = np.zeros(mesh.n_cells, dtype=bool)
    for k in np.unique(sizes):  # (a loop over cell sizes, not cells)
        sel = np.flatnonzero(sizes == k)
        rows = np.sort(mesh.connectivity[mesh.offsets[sel][:, None] + np.arange(k)], axis=1)
        rows = np.column_stack([mesh.cell_types[sel].astype(np.int64), rows])
        _, first = np.unique(rows, axis=0, return_index=True)
        twin = np.ones(sel.size, dtype=bool)
        twin[first] = False
        repeated[sel[twin]] = True
    n = int(repeated.sum())
    if n == 0:
        return False
    ids = np.flatnonzero(repeated)
    if not few_bad(n, mesh.n_cells):
        raise MeshError(
            f"{'a cell is' if n == 1 else f'{n:,} cells are'} written twice (the same nodes as an earlier cell), "
            f"e.g. cell{'s' if n > 1 else ''} {id_list(ids, 6)}: remove the repeats"
        )
    n_before = mesh.n_cells
    mesh.offsets, mesh.connectivity, mesh.cell_types, mesh.tags = _without_cells(
        mesh.offsets, mesh.connectivity, mesh.cell_types, mesh.tags, repeated
    )
    record_dropped(mesh, [("written twice (the same nodes as an earlier cell)", ids)], n_before)
    for key in ("measures", "centroids", "cell_faces"):
        mesh.meta.pop(key, None)
    return True


def _degenerate(mesh: Mesh, vol: np.ndarray, bounds=None) -> np.ndarray:
    """(C,) True where a cell's measure is below 1e-14 of the bounding box's and flat for its own size
    too (degenerate.sized: a 1000:1 graded mesh's cells are small, not flat) (bounds: the points'
    (min, max) per coordinate, where the caller has them); MeshError when all points coincide."""
    lo, hi = _bounds(mesh.points) if bounds is None else bounds
    scale = float(np.linalg.norm(hi - lo)) ** mesh.dim
    if scale == 0:
        raise MeshError("the mesh is degenerate: all points coincide")
    small = np.abs(vol) <= 1e-14 * scale
    if small.any():  # (few: each one's own size)
        from models.mesh.degenerate import sized

        small[sized(mesh, vol, np.flatnonzero(small))] = False
    return small


def refuse_degenerate(mesh: Mesh, vol: np.ndarray, bounds=None, degenerate=None) -> None:
    """MeshError when all points coincide or a cell's measure is below 1e-14 of the bounding box's
    (_degenerate; degenerate: its answer, where the caller has it)."""
    degenerate = _degenerate(mesh, vol, bounds) if degenerate is None else degenerate
    if degenerate.any():
        ids = np.flatnonzero(degenerate)
        kind = "area" if mesh.dim == 2 else "volume"
        from models.mesh.degenerate import corners, far_point, flat_cause, welded_too_far

        far = far_point(mesh)
        if far is not None:  # one point far from the rest: its cells flat for their size
            raise MeshError(far)
        if 2 * ids.size >= mesh.n_cells:  # most cells flat: the points may say why
            cause = flat_cause(mesh)
            if cause:
                raise MeshError(
                    f"{ids.size:,} of the mesh's {mesh.n_cells:,} cells have zero {kind}: {cause}"
                )
        welded = welded_too_far(mesh, ids, kind)
        if welded:  # (the weld asked for made them)
            raise ParameterError(welded)
        hint = {  # --weld only helps where a cell's corners are distinct points at one place
            "coincident": "remove them (or merge their coincident points with --weld) and retry",
            "repeated": "a node is repeated in them: remove them and retry",
            "distinct": "their corners are distinct but collinear, coplanar or crossing: remove or fix them and retry",
        }[corners(mesh, ids[:200])]
        raise MeshError(
            f"the mesh has {ids.size} degenerate (zero-{kind}) cells, e.g. cells {id_list(ids)}; {hint}"
        )


def _bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) per coordinate: the same values as points.min(axis=0) / max(axis=0) (NaN where a
    coordinate has one), a reduction numpy does slowly over rows of 2 or 3 (~30x at a million
    points): in one compiled pass (models/mesh/_fastmesh.c bounds), else one column at a time."""
    from models.native import compiled

    d = points.shape[1]
    fast = compiled("mesh._fastmesh") if len(points) and 1 <= d <= 3 else None
    if fast is not None and points.dtype == np.float64 and points.flags.c_contiguous:
        lo, hi = np.empty(d), np.empty(d)
        fast.bounds(points, lo, hi)
        return lo, hi
    cols = range(d)
    return np.array([points[:, d].min() for d in cols]), np.array([points[:, d].max() for d in cols])


def _keep_faces(mesh: Mesh, flip: np.ndarray, faces, pairing: dict, areas=None) -> None:
    """Keep the faces and the face pairing the orientation sorted, for prepare / dual_graph (one
    sort and one gather of every face: the costliest steps of reading, not done twice).
    They were made before the flips: a flipped tetrahedron lists the same faces in another local
    order and direction, so its faces are rebuilt in place and face ids in the pairing renumbered
    (the keys, hence the pairs, do not change). Other meshes keep them only when nothing was flipped.
    areas: all tetrahedra, every face's area (face id 4 * cell + local face) after the flips."""
    from models.mesh.geometry import FACE_TEMPLATES, _all_tetrahedra

    order, pairs = pairing.get("order"), pairing.get("pairs")
    if flip.any():
        if not _all_tetrahedra(mesh):
            return
        tmpl = FACE_TEMPLATES[VTK_TETRA]
        sel = np.flatnonzero(flip)
        faces.nodes.reshape(-1, 12)[sel] = np.take(
            mesh.connectivity.reshape(-1, 4)[sel], np.array(tmpl).reshape(-1), axis=1
        )
        m = MIRROR[VTK_TETRA]
        # new local face k has the nodes of old local face m[tmpl[k]]: old j -> new k
        mirrored = [frozenset(m[list(f)].tolist()) for f in tmpl]
        new_of_old = np.array([mirrored.index(frozenset(f)) for f in tmpl])

        def renumber(ids: np.ndarray) -> np.ndarray:
            local = ids & 3  # face id = 4 * cell + local face
            return np.where(flip[ids >> 2], ids - local + new_of_old[local], ids)

        order = None if order is None else renumber(order)
        pairs = None if pairs is None else (renumber(pairs[0]), renumber(pairs[1]))
    mesh.meta["cell_faces"] = {
        "connectivity": mesh.connectivity,
        "faces": faces,
        "order": order,
        "same": pairing.get("same"),
        "pairs": pairs,
        "areas": areas,
    }


def _flip_cells(mesh: Mesh, flip: np.ndarray) -> None:
    """Reverse the orientation of the cells where `flip` is True (in place, vectorized)."""
    if mesh.dim == 2:
        mesh.connectivity = _reverse_rows(mesh.offsets, mesh.connectivity, flip)
        return
    for t, perm in MIRROR.items():
        sel = np.flatnonzero(flip & (mesh.cell_types == t))
        if sel.size:
            n = perm.size
            rows = mesh.offsets[sel][:, None] + np.arange(n)[None, :]
            mesh.connectivity[rows] = mesh.connectivity[rows[:, perm]]
    if mesh.poly_cells is not None and flip[mesh.poly_cells].any():
        # reverse every face of the flipped polyhedra
        face_flip = np.repeat(flip[mesh.poly_cells], np.diff(mesh.poly_cell_faces))
        mesh.poly_face_nodes = _reverse_rows(mesh.poly_face_offsets, mesh.poly_face_nodes, face_flip)


def _reverse_rows(offsets: np.ndarray, values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """CSR `values` with the rows where `mask` is True reversed (vectorized)."""
    sizes = np.diff(offsets)
    starts = offsets[:-1]
    idx = np.arange(values.size)
    row = np.repeat(np.arange(sizes.size), sizes)
    src = np.where(mask[row], 2 * starts[row] + sizes[row] - 1 - idx, idx)
    return values[src]


def build_deferred(d, memory_bytes: int | None = None) -> Mesh:
    """The Mesh of a read whose builder the reading child deferred (models.mesh.deferred), built
    here after every check of its arguments: deferred.Inconsistent for an argument that lies,
    MemoryError for an image beyond memory_bytes, MeshError as the builder refuses."""
    deferred.check(d)
    if d.builder == "cells":
        mesh = mesh_from_cells(*deferred.cells_args(d.args, d.dim))
    elif d.builder == "fixed":
        mesh = mesh_from_cells(*deferred.fixed_args(d.args, d.dim))
    else:
        mesh = mesh_from_image(*deferred.image_args(d.args, memory_bytes))
        if mesh is None:
            raise deferred.Inconsistent("image axes")
    mesh.meta.update(d.meta)
    return mesh


def mesh_from_image(axes, tags, tag_name, meta: dict) -> Mesh | None:
    """The Mesh of a whole 3D axis-aligned image (every dimension >= 2 points, no blanking), built
    directly: the points and hexahedra from the axes (x fastest, VTK's numbering), each cell's signed
    volume and centroid in closed form, and the one global flip folded into the node template. The
    same Mesh, field for field, as the general path (normalize, mesh_from_cells, _orient_lattice);
    None where the coordinates overflow (the general path says which points)."""
    from models.mesh.lattice import _box_measures, cell_nodes

    x, y, z = axes
    if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(z).all()):
        return None
    if deferred.DEFER:  # the reading child: the caller builds it (models.mesh.deferred)
        return deferred.image(axes, tags, tag_name, meta)
    nx, ny, nz = x.size, y.size, z.size
    pts = np.empty((nz, ny, nx, 3))
    pts[..., 0] = x[None, None, :]
    pts[..., 1] = y[None, :, None]
    pts[..., 2] = z[:, None, None]
    pts = pts.reshape(-1, 3)
    vol, cen = _box_measures(axes)
    lo = np.array([x.min(), y.min(), z.min()])
    hi = np.array([x.max(), y.max(), z.max()])
    flip = bool(vol.sum() < 0)
    sx, sy, sz = 1, nx, nx * ny
    corner = np.array([0, sx, sx + sy, sy, sz, sz + sx, sz + sx + sy, sz + sy], np.int64)
    if flip:
        corner = corner[MIRROR[VTK_HEXAHEDRON]]
    cx, cy, cz = nx - 1, ny - 1, nz - 1
    n = cx * cy * cz
    mesh = Mesh(
        points=pts,
        offsets=np.arange(0, 8 * n + 1, 8, dtype=np.int64),
        connectivity=cell_nodes([0, 1, 2], [cx, cy, cz], [sx, sy, sz], corner),
        cell_types=np.full(n, VTK_HEXAHEDRON, np.uint8),
        tags=tags,
        tag_name=tag_name if tags is not None else None,
    )
    mesh.meta.update(meta)
    mesh.meta["lower_dim_cells"] = {}
    mesh.meta["measures"] = measures = np.abs(vol)
    mesh.meta["centroids"] = cen
    scale = float(np.linalg.norm(hi - lo)) ** 3  # refuse_degenerate's bound, from the axes
    if scale == 0 or np.any(measures <= 1e-14 * scale):
        refuse_degenerate(mesh, vol)  # says which cells
    flips = np.full(n, flip)
    _record_orientation(mesh, -vol if flip else vol, flips)
    return mesh

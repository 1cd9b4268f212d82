"""Closed surfaces (STL, OBJ, PLY, OFF) filled with tetrahedra (`magnet generate stl`,
`magnet agglomerate shell.stl --fill`, job option `fill`).

By default the surface is filled as it stands: its triangles are the faces of the tetrahedra on
the boundary, so the filled volume equals the enclosed volume of the surface (divergence theorem on
the triangles). With remesh=True the surface is re-meshed first (gmsh classifySurfaces +
createGeometry) at a size relative to the bounding-box diagonal (`size`, a fraction) or absolute
(`size_abs`, in the file's own length unit).

Before gmsh runs the surface is checked with numpy (no loop over triangles): an open surface
(edges of one triangle only) or a non-manifold one (edges of three or more) is refused saying where;
the cell count is estimated and refused beyond `max_cells`. When gmsh's boundary recovery finds a
segment crossing a facet (a self-intersecting surface), the crossing is located here (segment /
triangle tests on the pairs of triangles whose boxes overlap) and reported with its point. gmsh is
imported lazily: models.mesh stays light.
"""

from __future__ import annotations

import contextlib
import io
import os
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from models.errors import MeshError, ParameterError

SURFACE_SUFFIXES = (".stl", ".obj", ".ply", ".off")
DEFAULT_MAX_CELLS = 5_000_000
DEFAULT_REL_SIZE = 0.02  # remesh: size = 0.02 x bounding-box diagonal unless told
# tetrahedra per (volume / h^3) that gmsh's Delaunay makes for a size field h (measured on a sphere,
# a box and a CAD-like shell, kept or re-meshed: 4.1 - 5.3; a regular tetrahedron of edge h has h^3 / 8.49)
_TETS_PER_H3 = 4.7
REPAIR = "repair it first, e.g. with MeshLab or meshfix (https://github.com/MarcoAttene/MeshFix-V2.1)"


@dataclass
class Surface:
    """A triangulated surface: points (P, 3), triangles (T, 3) int64, with what was measured on it."""

    name: str
    points: np.ndarray
    triangles: np.ndarray
    info: dict = field(default_factory=dict)
    shells: np.ndarray | None = None  # (T,) the shell of each triangle (check_closed)
    depth: np.ndarray | None = None  # (S,) how many shells enclose each (odd: it bounds a cavity)
    inside: np.ndarray | None = None  # (S, S) shell i inside shell j

    @property
    def diagonal(self) -> float:
        return float(np.linalg.norm(self.points.max(0) - self.points.min(0)))

    def areas(self) -> np.ndarray:
        p = self.points[self.triangles]
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)

    def signed_volume(self) -> float:
        """The enclosed volume by the divergence theorem (sum of p0 . (p1 x p2) / 6); its sign
        follows the orientation of the triangles (positive for outward normals)."""
        p = self.points[self.triangles]
        c = self.points.mean(0)  # about the centroid: smaller round-off than about the origin
        a, b, d = p[:, 0] - c, p[:, 1] - c, p[:, 2] - c
        return float(np.einsum("ij,ij->i", a, np.cross(b, d)).sum() / 6.0)


@dataclass
class Filled:
    """Tetrahedra filling a surface: points (P, 3), tets (C, 4) int64, and a summary."""

    points: np.ndarray
    tets: np.ndarray
    info: dict

    def volume(self) -> float:
        p = self.points[self.tets]
        return float(
            np.abs(
                np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]))
            ).sum()
            / 6.0
        )

    def to_mesh(self):
        from models.mesh.read import mesh_from_arrays

        return mesh_from_arrays(self.points, [("tetra", self.tets)])

    def write(self, path) -> None:
        import meshio

        meshio.write(os.fspath(path), meshio.Mesh(self.points, [("tetra", self.tets)]))


# a refused surface's crossings are looked for up to this many triangles (find_intersection: about
# a second per 10^5 triangles here); a larger one is told to try --fill, which looks if gmsh fails
CROSSING_CHECKED = 300_000


def _fmt_point(p) -> str:
    return "(" + ", ".join(f"{float(x):.6g}" for x in p) + ")"


def is_surface_file(path) -> bool:
    return os.path.splitext(os.fspath(path))[1].lower() in SURFACE_SUFFIXES


def open_surface_refusal(path, refused: Exception) -> Exception:
    """A surface file refused as a mesh (curved: not a planar 2D mesh): where it cannot be filled
    either (open, crossing), one sentence saying both, as the CLI's check and the service's upload
    check say it; `refused` itself where it could be filled (or is no surface file)."""
    from models.errors import MagnetError, MeshError
    from models.mesh.build import FILL_HINT

    if not is_surface_file(path) or FILL_HINT not in str(refused):
        return refused  # (not the curved surface's refusal: unreadable, or a flat mesh refused later)
    try:
        surface = read_surface(path)
    except MagnetError:  # (the filling's reader cannot read it either: the refusal says enough)
        return refused
    try:
        check_closed(surface)
        if len(surface.triangles) <= CROSSING_CHECKED:  # (closed: does it cross itself? seconds at most)
            crossing = _crossing_error(surface)
            if crossing is not None:
                raise crossing
    except MagnetError as why:
        name = os.path.basename(os.fspath(path))
        tail = str(why)
        for prefix in (f"{name} ", f"cannot read {name}: "):
            if tail.startswith(prefix):
                tail = "it " + tail[len(prefix) :] if prefix == f"{name} " else tail[len(prefix) :]
                break
        return MeshError(f"{refused}; nor can it be filled as it is: {tail}")
    return refused


# ------------------------------------------------------------------------------------------ read


def _ply_faces(path: str):
    """(points, face offsets, face nodes) of a PLY file by VTK's vtkPLYReader (ParaView's; meshio's
    refuses big-endian files and extra face properties), read in a forked child under the reading
    limits (a C++ reader may crash on a corrupted file: models/mesh/sandbox.py)."""
    from models.mesh.ply import check_header
    from models.mesh.read import default_memory
    from models.mesh.sandbox import _default_timeout, call_in_child, sandbox_enabled

    with open(path, "rb") as fh:
        check_header(path, os.path.basename(path), fh.read(4096))
    if not sandbox_enabled():
        return _vtk_ply(path)
    return call_in_child(
        _vtk_ply, (path,), path=path, timeout_s=_default_timeout(), memory_bytes=default_memory()
    )


def _vtk_ply(path: str):
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOPLY import vtkPLYReader

    from models.mesh.vtk_readers import _Captured

    with _Captured() as cap:  # (VTK's messages kept off the terminal; what failed said below)
        reader = vtkPLYReader()
        reader.SetFileName(path)
        reader.Update()
    pd = reader.GetOutput()
    if cap.failed or pd is None or pd.GetNumberOfPolys() == 0 or pd.GetPoints() is None:
        raise MeshError("it holds no faces that VTK's PLY reader can read")
    polys = pd.GetPolys()
    return (
        vtk_to_numpy(pd.GetPoints().GetData()).astype(np.float64),
        vtk_to_numpy(polys.GetOffsetsArray()).astype(np.int64),
        vtk_to_numpy(polys.GetConnectivityArray()).astype(np.int64),
    )


def read_surface(path) -> Surface:
    """The triangles of a surface file (STL ASCII or binary, OBJ, PLY, OFF; quads and polygons are
    cut into triangles), with coincident points merged and collapsed triangles dropped."""
    path = os.fspath(path)
    name = os.path.basename(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in SURFACE_SUFFIXES:
        raise ParameterError(
            f"{name}: filling takes a closed surface ({', '.join(SURFACE_SUFFIXES)}), not a {ext or 'file without extension'}"
        )
    if not os.path.isfile(path):
        raise MeshError(f"surface file not found: {path}")
    if os.path.getsize(path) == 0:
        raise MeshError(f"surface file is empty: {name}")
    import meshio

    from models.mesh import surface_text

    fmt = ext.lstrip(".").upper()
    own = surface_text.READERS.get(ext)
    try:
        if own is not None:  # (meshio's readers refuse OFF polygons, colours, OBJ's v/vt/vn and -1)
            m = surface_text.as_meshio(*own(path))
        else:
            with (
                warnings.catch_warnings(),
                contextlib.redirect_stdout(io.StringIO()),
                contextlib.redirect_stderr(io.StringIO()),
                np.errstate(all="ignore"),
            ):
                warnings.simplefilter("ignore")
                try:
                    m = meshio.read(path, file_format=ext.lstrip("."))
                except (Exception, SystemExit):
                    if ext != ".ply":
                        raise
                    # what meshio refuses, VTK's reader (ParaView's) in a child, as read_mesh does
                    m = surface_text.as_meshio(*_ply_faces(path))
    except MeshError as exc:  # ours: what is wrong in the file
        said = str(exc)
        raise MeshError(
            said if said.startswith(f"cannot read {name} ") else f"cannot read {name} as {fmt}: {said}"
        ) from None
    except (Exception, SystemExit):  # meshio raises many kinds (even SystemExit) on broken input
        raise MeshError(f"cannot read {name} as {fmt}: the file is corrupted or not {fmt}") from None
    tris, volume_cells = [], 0
    for block in m.cells:
        d = np.asarray(block.data, dtype=np.int64)
        if block.type == "triangle":
            tris.append(d)
        elif block.type == "quad" or block.type.startswith("polygon"):
            w = d.shape[1]  # fan from the first corner: (0, i, i+1)
            fan = np.stack([np.repeat(d[:, :1], w - 2, 1), d[:, 1:-1], d[:, 2:]], axis=2)
            tris.append(fan.reshape(-1, 3))
        elif block.type in ("tetra", "hexahedron", "wedge", "pyramid") or block.type.startswith("polyhedron"):
            volume_cells += len(d)
    if volume_cells:
        raise ParameterError(
            f"{name} holds {volume_cells:,} volume cells already: agglomerate it as it is, without filling"
        )
    if not tris or not sum(len(t) for t in tris):
        raise MeshError(f"{name} holds no triangles or polygons: there is no surface to fill")
    pts = np.asarray(m.points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise MeshError(f"{name}: points must have 2 or 3 coordinates")
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    if not np.isfinite(pts).all():
        raise MeshError(f"{name}: some point coordinates are not finite numbers (NaN or infinity)")
    tri = np.concatenate(tris)
    if tri.min() < 0 or tri.max() >= len(pts):
        raise MeshError(f"{name}: some faces refer to points that do not exist (corrupted file)")
    # merge coincident points (STL repeats every corner; some writers repeat points anyway)
    uniq, inverse = np.unique(pts, axis=0, return_inverse=True)
    tri = inverse.reshape(-1)[tri]
    collapsed = (tri[:, 0] == tri[:, 1]) | (tri[:, 1] == tri[:, 2]) | (tri[:, 0] == tri[:, 2])
    tri = tri[~collapsed]
    used = np.unique(tri)
    remap = np.full(len(uniq), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    s = Surface(name, uniq[used], remap[tri])
    s.info = {"triangles": len(tri), "points": len(used), "collapsed_dropped": int(collapsed.sum())}
    return s


# ----------------------------------------------------------------------------------------- check


def check_closed(s: Surface) -> None:
    """Refuse an open or non-manifold surface, saying where and how to repair it. Records in s.info
    whether the triangles are consistently oriented, the area and the enclosed volume."""
    t = s.triangles
    n = len(s.points)
    a = t.reshape(-1)
    b = t[:, [1, 2, 0]].reshape(-1)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * n + hi
    uniq, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    where_open = np.flatnonzero(counts == 1)
    if len(where_open):
        k = uniq[where_open[0]]
        mid = 0.5 * (s.points[k // n] + s.points[k % n])
        tee = _t_junction(s.points, uniq[where_open] // n, uniq[where_open] % n)
        if tee is not None:
            raise MeshError(
                f"{s.name} is closed in space but not as triangles: {len(where_open):,} edges belong to one "
                f"triangle only, a corner of other triangles lying on them (T-junctions), e.g. at "
                f"{_fmt_point(tee)}; split those edges at the corners that lie on them (conform the surface), "
                f"or {REPAIR.replace('repair it first, ', 'repair it, ')}"
            )
        raise MeshError(
            f"{s.name} is not a closed surface: {len(where_open):,} boundary edges (edges of one triangle "
            f"only), e.g. at {_fmt_point(mid)}; close its holes first, e.g. MeshLab's Filters > Remeshing > "
            "Close Holes, or meshfix"
        )
    where_nm = np.flatnonzero(counts > 2)
    if len(where_nm):
        k = uniq[where_nm[0]]
        mid = 0.5 * (s.points[k // n] + s.points[k % n])
        raise MeshError(
            f"{s.name} is not a manifold surface: {len(where_nm):,} edges are shared by more than two "
            f"triangles (duplicated faces or touching shells), e.g. at {_fmt_point(mid)}; {REPAIR}"
        )
    # consistently oriented: every edge is walked once each way (a < b on exactly one of its two uses)
    forward = np.bincount(inv, weights=(a < b), minlength=len(uniq))
    oriented = bool((forward == 1).all())
    flipped = 0 if oriented else _reorient(s, key, a < b)
    area = float(s.areas().sum())
    vol = _outward(s)
    s.info.update(
        area=area,
        oriented=oriented,
        reoriented=flipped,
        enclosed_volume=vol,
        bbox=[s.points.min(0).tolist(), s.points.max(0).tolist()],
    )
    if area <= 0 or (vol is not None and vol <= 1e-12 * s.diagonal**3):
        raise MeshError(
            f"{s.name} encloses no volume (its triangles lie in a plane): there is nothing to fill"
        )


def _t_junction(points: np.ndarray, a: np.ndarray, b: np.ndarray, most: int = 4000) -> np.ndarray | None:
    """A corner of the open edges (a, b) that lies inside another of them, away from its ends (a
    T-junction: the surface closed in space, its triangles not sharing that edge), or None; only
    looked for among at most `most` open edges."""
    if a.size > most:
        return None
    ends = np.unique(np.r_[a, b])
    p, q = points[a], points[b]
    d = q - p
    length2 = np.einsum("ij,ij->i", d, d)
    for c in ends:  # a loop over the open edges' corners (at most 2 * most), each against every edge
        rel = points[c] - p
        t = np.einsum("ij,ij->i", rel, d) / np.where(length2 > 0, length2, 1.0)
        off = rel - t[:, None] * d
        near = np.einsum("ij,ij->i", off, off) <= 1e-18 * np.maximum(length2, 1e-300)
        inside = near & (t > 1e-9) & (t < 1 - 1e-9) & (a != c) & (b != c)
        if inside.any():
            return points[c]
    return None


def _reorient(s: Surface, key: np.ndarray, forward: np.ndarray) -> int | None:
    """Flip triangles so that each shell is consistently oriented (the file's triangles disagree):
    a breadth-first tree over the triangles' shared edges per shell, the flips along it summed by
    pointer jumping (log depth numpy steps). Returns the number flipped, None if not orientable."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    t = len(s.triangles)
    order = np.argsort(key, kind="stable")  # a closed manifold: every edge has exactly two uses
    u, v = order[0::2], order[1::2]
    ti, tj = u // 3, v // 3
    rel = (forward[u] == forward[v]).astype(np.int8)  # 1: the two triangles disagree across this edge
    adj = coo_matrix((np.r_[rel, rel] + 1, (np.r_[ti, tj], np.r_[tj, ti])), shape=(t, t)).tocsr()
    n_comp, comp = connected_components(adj, directed=False)
    parent = np.arange(t)
    for root in np.unique(comp, return_index=True)[1]:  # one breadth-first tree per shell
        _, pred = breadth_first_order(adj, int(root), directed=False, return_predecessors=True)
        reached = pred >= 0
        parent[reached] = pred[reached]
    flip = np.asarray(adj[np.arange(t), parent]).ravel().astype(np.int8) - 1
    flip[parent == np.arange(t)] = 0
    while (parent != parent[parent]).any():
        flip, parent = flip ^ flip[parent], parent[parent]
    tris = s.triangles.copy()
    tris[flip == 1] = tris[flip == 1][:, [0, 2, 1]]
    old, s.triangles = s.triangles, tris
    if _consistent(s) is None:
        s.triangles = old
        return None  # not orientable (cannot enclose a volume as one consistent shell)
    return int(flip.sum())


def _consistent(s: Surface) -> np.ndarray | None:
    """The first corner of every edge use (flat, 3 per triangle) if every edge is walked once each
    way, else None."""
    t = s.triangles
    a = t.reshape(-1)
    b = t[:, [1, 2, 0]].reshape(-1)
    key = np.minimum(a, b) * len(s.points) + np.maximum(a, b)
    _, inv = np.unique(key, return_inverse=True)
    return a if (np.bincount(inv, weights=(a < b)) == 1).all() else None


def _outward(s: Surface) -> float | None:
    """Turn every shell (edge-connected set of triangles) outward if it is consistently oriented and
    return the enclosed volume (None if the orientation is not consistent)."""
    t, n = s.triangles, len(s.points)
    a = _consistent(s)
    if a is None:
        return None
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    # shells: triangles connected through points (a vertex-touching pair of shells counts as one)
    rows = np.repeat(np.arange(len(t)), 3)
    inc = coo_matrix((np.ones(len(rows)), (rows, a)), shape=(len(t), n)).tocsr()
    _, comp = connected_components(inc @ inc.T, directed=False)
    p = s.points[t] - s.points.mean(0)
    per = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])) / 6.0
    vol = np.bincount(comp, weights=per)
    s.shells = comp
    s.inside = _enclosing(s.points, t, comp, vol.size)
    s.depth = depth = s.inside.sum(axis=1)
    # a shell inside an odd number of others bounds a cavity: its normals point into it (inward)
    outward = depth % 2 == 0
    wrong = (vol < 0) == outward
    if wrong.any():
        s.triangles = t.copy()
        s.triangles[wrong[comp]] = t[wrong[comp]][:, [0, 2, 1]]
    return float(np.where(outward, np.abs(vol), -np.abs(vol)).sum())


def estimate_cells(s: Surface, h: float | None = None) -> int:
    """About how many tetrahedra gmsh makes: volume / h^3 x a measured constant; h is the remesh
    size, or (surface kept) the side of an equilateral triangle of the surface's mean area."""
    vol = s.info.get("enclosed_volume")
    if vol is None:  # orientation unknown: the bounding box's volume over-estimates it
        vol = float(np.prod(s.points.max(0) - s.points.min(0)))
    if h is None:
        h = float(np.sqrt(4.0 / np.sqrt(3.0) * s.info["area"] / len(s.triangles)))
    return int(round(max(_TETS_PER_H3 * vol / h**3, len(s.triangles) / 3)))


# -------------------------------------------------------------------------------- intersections


def _box_pairs(lo: np.ndarray, hi: np.ndarray, max_entries: int, max_pairs: int) -> np.ndarray:
    """(M, 2) pairs i < j of boxes that share a cell of a uniform grid (each box entered in every cell
    it overlaps; the cell grows until the entries fit in max_entries), at most max_pairs of them."""
    gmin = lo.min(0)
    ext = (hi - lo).max(1)
    cell = max(float(np.median(ext)), float(np.ptp(np.vstack([lo, hi]), axis=0).max()) * 1e-6, 1e-300)
    while True:
        i0 = np.floor((lo - gmin) / cell).astype(np.int64)
        span = np.floor((hi - gmin) / cell).astype(np.int64) - i0 + 1
        counts = span.prod(1)
        if counts.sum() <= max_entries:
            break
        cell *= 2
    dims = (i0 + span).max(0) + 1
    box = np.repeat(np.arange(len(lo)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    sx, sy = span[box, 0], span[box, 1]
    cx = i0[box, 0] + local % sx
    cy = i0[box, 1] + (local // sx) % sy
    cz = i0[box, 2] + local // (sx * sy)
    key = (cx * dims[1] + cy) * dims[2] + cz
    order = np.argsort(key, kind="stable")
    key, box = key[order], box[order]
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    size = np.diff(np.r_[start, len(key)])
    rank = np.arange(len(key)) - np.repeat(start, size)  # each entry pairs with the earlier ones of its cell
    total = int(rank.sum())
    if total > max_pairs:  # keep the first cells' pairs (a partial search)
        rank = rank * (np.cumsum(rank) <= max_pairs)
        total = int(rank.sum())
    first = np.repeat(np.arange(len(key)), rank)
    second = np.repeat(np.repeat(start, size), rank) + (
        np.arange(total) - np.repeat(np.cumsum(rank) - rank, rank)
    )
    a, b = box[first], box[second]
    pairs = np.column_stack([np.minimum(a, b), np.maximum(a, b)])
    return np.unique(pairs, axis=0) if len(pairs) else pairs


def find_intersection(
    s: Surface, max_entries: int = 20_000_000, max_pairs: int = 20_000_000, chunk: int = 1_000_000
) -> tuple[int, np.ndarray | None]:
    """(number of crossing triangle pairs found, one crossing point or None): every edge of a
    triangle tested against every triangle with no shared corner whose box overlaps its own (pairs
    from a uniform grid, tested a chunk at a time)."""
    p = s.points[s.triangles]  # (T, 3, 3)
    lo, hi = p.min(1), p.max(1)
    pairs = _box_pairs(lo, hi, max_entries, max_pairs)
    count, point = 0, None
    for c in range(0, len(pairs), chunk):
        i, j = pairs[c : c + chunk, 0], pairs[c : c + chunk, 1]
        keep = (lo[i] <= hi[j]).all(1) & (lo[j] <= hi[i]).all(1)
        ti, tj = s.triangles[i], s.triangles[j]
        keep &= ~(ti[:, :, None] == tj[:, None, :]).any((1, 2))
        i, j = i[keep], j[keep]
        hits = np.zeros(len(i), dtype=bool)
        for first, second in ((i, j), (j, i)):
            for e in range(3):
                o = p[first, e]
                d = p[first, (e + 1) % 3] - o
                ok, t = _segment_triangle(o, d, p[second])
                hits |= ok
                if point is None and ok.any():
                    k = int(np.flatnonzero(ok)[0])
                    point = o[k] + t[k] * d[k]
        count += int(hits.sum())
    return count, point


def _segment_triangle(o: np.ndarray, d: np.ndarray, tri: np.ndarray, eps: float = 1e-12):
    """Möller-Trumbore for segments o + t d, t in [0, 1], against triangles (vectorized)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    pv = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pv)
    scale = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1) * np.linalg.norm(d, axis=1)
    ok = np.abs(det) > eps * np.maximum(scale, 1e-300)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = o - tri[:, 0]
    u = np.einsum("ij,ij->i", tv, pv) * inv
    qv = np.cross(tv, e1)
    v = np.einsum("ij,ij->i", d, qv) * inv
    t = np.einsum("ij,ij->i", e2, qv) * inv
    ok &= (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)
    return ok, t


# ------------------------------------------------------------------------------------------ fill


@contextlib.contextmanager
def _gmsh(seed: int = 0):
    import gmsh

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.option.setNumber("Mesh.RandomSeed", float(seed % 2**31))
        gmsh.model.add("fill")
        yield gmsh
    finally:
        gmsh.finalize()


@contextlib.contextmanager
def _ticking(progress: Callable[[float, str], None] | None, stage: str, expected_s: float):
    """Call progress(fraction, stage) every half second from a side thread while gmsh works (gmsh's
    calls release the GIL); the fraction follows the expected time, never reaching 1. An exception
    raised by progress (a cancelled job) is raised again once gmsh has returned."""
    if progress is None:
        yield
        return
    stop = threading.Event()
    raised: list[BaseException] = []
    t0 = time.perf_counter()

    def run():
        while not stop.wait(0.5):
            el = time.perf_counter() - t0
            try:
                progress(min(0.95, el / max(expected_s, 1e-3) * 0.9), f"{stage} {el:.0f}s")
            except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
                raised.append(exc)
                return

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        yield
    finally:
        stop.set()
        th.join()
    if raised:
        raise raised[0]


def _surface_into_gmsh(gmsh, s: Surface) -> int:
    tag = gmsh.model.addDiscreteEntity(2)
    gmsh.model.mesh.addNodes(2, tag, np.arange(1, len(s.points) + 1), s.points.reshape(-1))
    gmsh.model.mesh.addElementsByType(tag, 2, [], (s.triangles + 1).reshape(-1))
    return tag


def _volumes_with_cavities(gmsh, s: Surface) -> None:
    """One discrete surface per shell and one volume per solid: a shell at even depth bounds a solid,
    the shells one level deeper inside it its cavities (gmsh fills a single loop of every shell
    through its cavities). The shells share no point (they are the surface's point-connected parts)."""
    tags = []
    for j in range(s.depth.size):  # a loop over shells
        tri = s.triangles[s.shells == j]
        used = np.unique(tri)
        tag = gmsh.model.addDiscreteEntity(2)
        gmsh.model.mesh.addNodes(2, tag, used + 1, s.points[used].reshape(-1))
        gmsh.model.mesh.addElementsByType(tag, 2, [], (tri + 1).reshape(-1))
        tags.append(gmsh.model.geo.addSurfaceLoop([tag]))
    for j in np.flatnonzero(s.depth % 2 == 0):
        holes = [tags[c] for c in np.flatnonzero((s.depth == s.depth[j] + 1) & s.inside[:, j])]
        gmsh.model.geo.addVolume([tags[j], *holes])


def _enclosing(points: np.ndarray, t: np.ndarray, comp: np.ndarray, n: int) -> np.ndarray:
    """(S, S) bool: shell i lies inside shell j. The winding number of shell j at a point of shell i
    (the solid angle its triangles make there over 4 pi, Van Oosterom & Strackee's formula: 1 inside a
    closed shell, 0 outside; the shells share no point), for the shells within shell j's bounding box
    only. A loop over shells and chunks of triangles, not over triangles."""
    out = np.zeros((n, n), dtype=bool)
    if n < 2:
        return out
    first = np.zeros(n, dtype=np.int64)
    first[comp[::-1]] = np.arange(len(t))[::-1]
    probe = points[t[first, 0]]  # a point of each shell
    corner = np.repeat(comp, 3)
    lo = np.full((n, 3), np.inf)
    hi = np.full((n, 3), -np.inf)
    np.minimum.at(lo, corner, points[t.reshape(-1)])
    np.maximum.at(hi, corner, points[t.reshape(-1)])
    for j in range(n):
        # only shells inside shell j's box can be inside it (many bodies side by side: none is)
        cand = np.flatnonzero((lo >= lo[j]).all(1) & (hi <= hi[j]).all(1))
        cand = cand[cand != j]
        if cand.size == 0:
            continue
        mine = t[comp == j]
        w = np.zeros(cand.size)
        step = max(1, 4_000_000 // cand.size)
        for k in range(0, len(mine), step):
            a, b, c = (points[mine[k : k + step, i]][None] - probe[cand][:, None] for i in range(3))
            la, lb, lc = (np.linalg.norm(v, axis=2) for v in (a, b, c))
            num = np.einsum("pti,pti->pt", a, np.cross(b, c))
            den = la * lb * lc + (a * b).sum(2) * lc + (b * c).sum(2) * la + (c * a).sum(2) * lb
            w += np.arctan2(num, den).sum(axis=1)
        out[cand, j] = np.abs(w / (2 * np.pi)) > 0.5
    return out


def _tets_out(gmsh) -> tuple[np.ndarray, np.ndarray]:
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    coords = coords.reshape(-1, 3)
    index = np.full(int(node_tags.max()) + 1, -1, dtype=np.int64)
    index[node_tags.astype(np.int64)] = np.arange(len(node_tags))
    _, enodes = gmsh.model.mesh.getElementsByType(4)
    tets = index[np.asarray(enodes, dtype=np.int64)].reshape(-1, 4)
    used = np.unique(tets)
    remap = np.full(len(coords), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return coords[used].copy(), remap[tets]


def _crossing_error(s: Surface) -> MeshError | None:
    count, point = find_intersection(s)
    if point is None:
        return None
    return MeshError(
        f"{s.name} intersects itself: {count:,} {'pair' if count == 1 else 'pairs'} of triangles "
        f"cross{'es' if count == 1 else ''}, e.g. at {_fmt_point(point)}; {REPAIR}"
    )


def _gmsh_failure(s: Surface, exc: Exception) -> MeshError:
    """Our sentence for gmsh's failure (never gmsh's own text): where the surface crosses itself if
    it does, else what gmsh's failure means."""
    crossing = _crossing_error(s)
    if crossing is not None:
        return crossing
    text = str(exc)
    if "intersect" in text or "PLC" in text or "overlap" in text.lower():
        return MeshError(
            f"{s.name} could not be filled: its triangles overlap or touch somewhere (two facets meet "
            f"away from their edges); {REPAIR}"
        )
    return MeshError(
        f"{s.name} could not be filled with tetrahedra (the mesher gave up on its boundary: facets that "
        f"overlap or nearly touch); {REPAIR}, or try --remesh"
    )


def fill_surface(
    path,
    remesh: bool = False,
    size: float | None = None,
    size_abs: float | None = None,
    max_cells: int | None = DEFAULT_MAX_CELLS,
    angle_deg: float = 40.0,
    seed: int = 0,
    progress: Callable[[float, str], None] | None = None,
    surface: Surface | None = None,
) -> Filled:
    """Tetrahedra filling the closed surface in `path` (see the module doc). size: remesh size as a
    fraction of the bounding-box diagonal (default 0.02); size_abs: in the file's own unit (either
    one implies remesh). max_cells: refuse beyond this estimate (None: no limit)."""
    if size is not None and size_abs is not None:
        raise ParameterError("give the fill size either relative (size) or absolute (size_abs), not both")
    if size is not None and not 0 < size <= 1:
        raise ParameterError(f"fill size is a fraction of the bounding-box diagonal, in (0, 1]; got {size}")
    if size_abs is not None and not (np.isfinite(size_abs) and size_abs > 0):
        raise ParameterError(f"absolute fill size must be a positive length, got {size_abs}")
    remesh = remesh or size is not None or size_abs is not None
    t0 = time.perf_counter()
    s = surface if surface is not None else read_surface(path)
    check_closed(s)
    t_check = time.perf_counter() - t0
    h = None
    if remesh:
        h = size_abs if size_abs is not None else (size or DEFAULT_REL_SIZE) * s.diagonal
    estimate = estimate_cells(s, h)
    if max_cells is not None and estimate > max_cells:
        how = "a larger size" if remesh else "--remesh with a larger size"
        raise ParameterError(
            f"filling {s.name} would make about {estimate:,} tetrahedra, more than the limit of {max_cells:,}: "
            f"use {how}, or raise the limit (--max-cells)"
        )
    cavities = s.depth is not None and bool((s.depth % 2 == 1).any())
    if remesh and cavities:
        raise ParameterError(
            f"{s.name} has inner shells that bound cavities: it is filled as it stands (its cavities left "
            "empty), not re-meshed; drop --remesh / the fill size"
        )
    if remesh:  # re-meshing a surface that crosses itself can end in a wrong volume without an error
        crossing = _crossing_error(s)
        if crossing is not None:
            raise crossing
    expected = estimate / 60_000.0  # seconds: gmsh makes about 40-80k tetrahedra a second here
    t1 = time.perf_counter()
    with _gmsh(seed) as gmsh:
        if cavities:  # a volume per solid, its cavities left empty (never re-meshed: refused above)
            _volumes_with_cavities(gmsh, s)
        else:
            tag = _surface_into_gmsh(gmsh, s)
            surfaces = [tag]
            if remesh:
                gmsh.option.setNumber("Mesh.MeshSizeMin", 0.5 * h)
                gmsh.option.setNumber("Mesh.MeshSizeMax", h)
                gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
                gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
                gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
                try:
                    gmsh.model.mesh.classifySurfaces(np.radians(angle_deg), True, True, np.pi)
                    gmsh.model.mesh.createGeometry()
                except Exception as exc:  # gmsh raises plain Exception
                    raise _gmsh_failure(s, exc) from None
                surfaces = [e for _, e in gmsh.model.getEntities(2)]
            gmsh.model.geo.addVolume([gmsh.model.geo.addSurfaceLoop(surfaces)])
        gmsh.model.geo.synchronize()
        try:
            with _ticking(progress, "fill", expected):
                gmsh.model.mesh.generate(3)
        except MeshError:
            raise
        except Exception as exc:  # gmsh raises plain Exception
            raise _gmsh_failure(s, exc) from None
        points, tets = _tets_out(gmsh)
    if not len(tets):
        raise _gmsh_failure(s, RuntimeError(""))
    filled = Filled(points, tets, {})
    filled.info = {
        "surface": s.name,
        "triangles": len(s.triangles),
        "remeshed": bool(remesh),
        "size": h,
        "estimated_cells": estimate,
        "cells": len(tets),
        "points": len(points),
        "enclosed_volume": s.info.get("enclosed_volume"),
        "reoriented": s.info.get("reoriented"),
        "volume": filled.volume(),
        "timings": {"check": t_check, "fill": time.perf_counter() - t1},
    }
    return filled


def fill_mesh(path, **kwargs):
    """fill_surface(path, ...) as the library's Mesh container, with the fill summary in meta['fill']."""
    filled = fill_surface(path, **kwargs)
    mesh = filled.to_mesh()
    mesh.meta["fill"] = filled.info
    return mesh


def describe_fill(info: dict) -> str:
    """One line on a fill: 'filled shell.stl (10,910 triangles kept): 18,488 tetrahedra in 0.70 s'."""
    how = (
        f"re-meshed at size {info['size']:.4g}"
        if info["remeshed"]
        else f"{info['triangles']:,} triangles kept"
    )
    return (
        f"filled {info['surface']} ({how}): {info['cells']:,} tetrahedra (estimated {info['estimated_cells']:,}) "
        f"in {info['timings']['fill']:.2f}s"
    )

"""Seeded mesh generators for training and benchmarks (`magnet generate`).

2D, on the unit square: structured triangles or quads, random Delaunay triangles, random Voronoi
polygons clipped to the square, random circular holes, random circular inclusions (physical groups
0 = matrix, 1 = inclusions), split by a random line (groups 0 / 1).
3D: unit cube tetrahedra, random portions of the cube, the cube cut into 1-4 heterogeneous parts by
random planes (groups 0 / 1, alternating across each plane), tetrahedra inside an STL surface.

Every generator takes a seed and gives the same mesh for the same seed. gmsh runs through its
Python API, with no configuration files read, no terminal output and one thread.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models.errors import MeshError, ParameterError, listed

KINDS_2D = ("square-tri", "square-quad", "delaunay", "voronoi", "holes", "inclusions", "split")
KINDS_3D = ("cube", "cube-portion", "cube-hetero", "stl")
KINDS = KINDS_2D + KINDS_3D

# gmsh element type ids of the linear cells we extract.
_GMSH_TYPES = {2: ("triangle", 3), 3: ("quad", 4), 4: ("tetra", 4)}


@dataclass
class GeneratedMesh:
    """Plain arrays: points (P, dim); cells as meshio-style blocks; tags (C,) over the blocks in order."""

    points: np.ndarray
    cells: list[tuple[str, np.ndarray]]
    tags: np.ndarray | None
    kind: str
    seed: int
    info: dict | None = None

    @property
    def dim(self) -> int:
        return int(self.points.shape[1])

    @property
    def n_cells(self) -> int:
        return int(sum(len(c) for _, c in self.cells))

    def to_mesh(self):
        """The library's Mesh container (through models.mesh.read.mesh_from_arrays)."""
        from models.mesh.read import mesh_from_arrays

        return mesh_from_arrays(self.points, self.cells, tags=self.block_tags())

    def block_tags(self) -> list[np.ndarray] | None:
        """The tags split per cell block (meshio's cell_data layout)."""
        if self.tags is None:
            return None
        return np.split(self.tags, np.cumsum([len(c) for _, c in self.cells])[:-1])

    def write(self, path: str | Path) -> None:
        """Write with meshio (format from the suffix); tags go to cell data 'gmsh:physical'."""
        import meshio

        pts = self.points if self.dim == 3 else np.column_stack([self.points, np.zeros(len(self.points))])
        tags = self.block_tags()
        cell_data = None if tags is None else {"gmsh:physical": [t.astype(np.int64) for t in tags]}
        meshio.write(str(path), meshio.Mesh(pts, self.cells, cell_data=cell_data))


# ---------------------------------------------------------------------------------------- gmsh


@contextlib.contextmanager
def _gmsh(seed: int, h: float):
    import gmsh

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.option.setNumber("Mesh.RandomSeed", float(seed % 2**31))
        gmsh.option.setNumber("Mesh.MeshSizeMin", h * 0.5)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.model.add("magnet")
        yield gmsh
    finally:
        gmsh.finalize()


def _extract(
    gmsh, dim: int, tag_of_entity: dict[int, int] | None
) -> tuple[np.ndarray, list, np.ndarray | None]:
    """Linear cells of dimension `dim` from the current gmsh model, with used nodes only."""
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    coords = coords.reshape(-1, 3)
    index = np.full(int(node_tags.max()) + 1, -1, dtype=np.int64)
    index[node_tags.astype(np.int64)] = np.arange(len(node_tags))
    blocks: dict[str, list[np.ndarray]] = {}
    tags: dict[str, list[np.ndarray]] = {}
    for _, entity in gmsh.model.getEntities(dim):
        types, _, nodes = gmsh.model.mesh.getElements(dim, entity)
        for etype, enodes in zip(types, nodes, strict=False):
            if int(etype) not in _GMSH_TYPES:
                raise MeshError(f"gmsh produced unexpected element type {etype}")
            name, nn = _GMSH_TYPES[int(etype)]
            conn = index[enodes.astype(np.int64)].reshape(-1, nn)
            blocks.setdefault(name, []).append(conn)
            t = 0 if tag_of_entity is None else tag_of_entity[entity]
            tags.setdefault(name, []).append(np.full(len(conn), t, dtype=np.int64))
    cells = [(name, np.concatenate(b)) for name, b in blocks.items()]
    if not cells:
        raise MeshError("gmsh produced no cells")
    used = np.unique(np.concatenate([c.ravel() for _, c in cells]))
    remap = np.full(len(coords), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    cells = [(name, remap[c]) for name, c in cells]
    points = coords[used, :dim].copy() if dim == 2 else coords[used].copy()
    cell_tags = None if tag_of_entity is None else np.concatenate([np.concatenate(tags[n]) for n, _ in cells])
    return points, cells, cell_tags


def _disks(rng: np.random.Generator, n: int, rmin: float, rmax: float, margin: float) -> list[tuple]:
    """n random non-overlapping disks inside the unit square (rejection sampling)."""
    disks: list[tuple[float, float, float]] = []
    for _ in range(200 * n):
        if len(disks) == n:
            break
        r = rng.uniform(rmin, rmax)
        x, y = rng.uniform(r + margin, 1 - r - margin, size=2)
        if all((x - a) ** 2 + (y - b) ** 2 > (r + c + margin) ** 2 for a, b, c in disks):
            disks.append((x, y, r))
    return disks


def _regular_disks(n: int) -> list[tuple]:
    """n = m^2 equal disks on a regular m x m grid (the paper's 4/16/36/64-inclusion squares)."""
    m = int(round(np.sqrt(n)))
    if m * m != n:
        raise ParameterError("--regular needs a square number of inclusions (4, 16, 36, 64, ...)")
    c = (np.arange(m) + 0.5) / m
    return [(x, y, 0.25 / m) for y in c for x in c]


def square_with_disks(seed: int, n: int, h: float, inclusions: bool, regular: bool = False) -> GeneratedMesh:
    """Unit square with n circular holes (removed) or inclusions (kept, group 1)."""
    rng = np.random.default_rng(seed)
    disks = _regular_disks(n) if regular else _disks(rng, n, 0.03, 0.12 if n < 8 else 0.08, 0.02)
    with _gmsh(seed, h) as gmsh:
        occ = gmsh.model.occ
        square = occ.addRectangle(0, 0, 0, 1, 1)
        tools = [(2, occ.addDisk(x, y, 0, r, r)) for x, y, r in disks]
        if not tools:
            occ.synchronize()
            tag_of = {e: 0 for _, e in gmsh.model.getEntities(2)} if inclusions else None
        elif inclusions:
            occ.fragment([(2, square)], tools)
            occ.synchronize()
            tag_of = {}
            for _, e in gmsh.model.getEntities(2):
                x, y, _ = occ.getCenterOfMass(2, e)
                inside = any((x - a) ** 2 + (y - b) ** 2 < r * r for a, b, r in disks)
                tag_of[e] = int(inside)
        else:
            occ.cut([(2, square)], tools)
            occ.synchronize()
            tag_of = None
        gmsh.model.mesh.generate(2)
        points, cells, tags = _extract(gmsh, 2, tag_of)
    return GeneratedMesh(points, cells, tags, "inclusions" if inclusions else "holes", seed)


def square_split(seed: int, h: float) -> GeneratedMesh:
    """Unit square cut in two by a random line through an interior point (groups 0 and 1)."""
    rng = np.random.default_rng(seed)
    cx, cy = rng.uniform(0.25, 0.75, size=2)
    angle = rng.uniform(0, np.pi)
    d = np.array([np.cos(angle), np.sin(angle)])
    with _gmsh(seed, h) as gmsh:
        occ = gmsh.model.occ
        square = occ.addRectangle(0, 0, 0, 1, 1)
        p0 = occ.addPoint(cx - 2 * d[0], cy - 2 * d[1], 0)
        p1 = occ.addPoint(cx + 2 * d[0], cy + 2 * d[1], 0)
        line = occ.addLine(p0, p1)
        occ.fragment([(2, square)], [(1, line)])
        occ.synchronize()
        tag_of = {}
        for _, e in gmsh.model.getEntities(2):
            x, y, _ = occ.getCenterOfMass(2, e)
            tag_of[e] = int((x - cx) * d[1] - (y - cy) * d[0] > 0)
        gmsh.model.mesh.generate(2)
        points, cells, tags = _extract(gmsh, 2, tag_of)
    return GeneratedMesh(points, cells, tags, "split", seed)


def cube(seed: int, h: float) -> GeneratedMesh:
    """Unit cube, unstructured tetrahedra."""
    with _gmsh(seed, h) as gmsh:
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.model.mesh.generate(3)
        points, cells, _ = _extract(gmsh, 3, None)
    return GeneratedMesh(points, cells, None, "cube", seed)


def cube_portion(seed: int, h: float) -> GeneratedMesh:
    """A random box inside the unit cube, half of the time with a random corner box cut away."""
    rng = np.random.default_rng(seed)
    size = rng.uniform(0.35, 1.0, size=3)
    origin = rng.uniform(0, 1 - size)
    with _gmsh(seed, h) as gmsh:
        occ = gmsh.model.occ
        box = occ.addBox(*origin, *size)
        if rng.random() < 0.5:
            cut = size * rng.uniform(0.3, 0.7, size=3)
            corner = origin + (size - cut) * rng.integers(0, 2, size=3)
            occ.cut([(3, box)], [(3, occ.addBox(*corner, *cut))])
        occ.synchronize()
        gmsh.model.mesh.generate(3)
        points, cells, _ = _extract(gmsh, 3, None)
    return GeneratedMesh(points, cells, None, "cube-portion", seed)


def cube_hetero(seed: int, h: float, parts: int | None = None) -> GeneratedMesh:
    """Unit cube cut by (parts - 1) random planes; groups 0/1 alternate across every plane."""
    rng = np.random.default_rng(seed)
    parts = int(rng.integers(1, 5)) if parts is None else parts
    if not 1 <= parts <= 4:
        raise ParameterError("cube-hetero needs 1 to 4 parts")
    planes = []
    for _ in range(parts - 1):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        planes.append((rng.uniform(0.25, 0.75, size=3), normal))
    with _gmsh(seed, h) as gmsh:
        occ = gmsh.model.occ
        box = occ.addBox(0, 0, 0, 1, 1, 1)
        tools = []
        for point, normal in planes:
            disk = occ.addDisk(0, 0, 0, 3, 3)
            z = np.array([0.0, 0.0, 1.0])
            axis = np.cross(z, normal)
            angle = float(np.arccos(np.clip(normal @ z, -1, 1)))
            if np.linalg.norm(axis) > 1e-9:
                occ.rotate([(2, disk)], 0, 0, 0, *axis, angle)
            occ.translate([(2, disk)], *point)
            tools.append((2, disk))
        if tools:
            occ.fragment([(3, box)], tools)
        occ.synchronize()
        # Drop the pieces of the cutting disks that lie outside the cube.
        volumes = gmsh.model.getEntities(3)
        tag_of = {}
        for _, e in volumes:
            c = np.array(occ.getCenterOfMass(3, e))
            tag_of[e] = int(sum((c - p) @ n > 0 for p, n in planes) % 2)
        gmsh.model.mesh.generate(3)
        points, cells, tags = _extract(gmsh, 3, tag_of)
    return GeneratedMesh(points, cells, tags, "cube-hetero", seed)


def from_stl(
    path: str | Path,
    seed: int = 0,
    size: float | None = None,
    size_abs: float | None = None,
    remesh: bool = False,
    max_cells: int | None = None,
    progress=None,
) -> GeneratedMesh:
    """Tetrahedra filling a closed surface (STL, OBJ, PLY, OFF): as it stands by default, or re-meshed
    at `size` x the bounding-box diagonal / at `size_abs` in the file's unit (models.mesh.fill)."""
    from models.mesh.fill import DEFAULT_MAX_CELLS, fill_surface

    filled = fill_surface(
        path,
        remesh=remesh,
        size=size,
        size_abs=size_abs,
        max_cells=DEFAULT_MAX_CELLS if max_cells is None else max_cells,
        seed=seed,
        progress=progress,
    )
    g = GeneratedMesh(filled.points, [("tetra", filled.tets)], None, "stl", seed)
    g.info = filled.info
    return g


def sphere_stl(path: str | Path, h: float = 0.2) -> None:
    """Write a closed triangulated sphere surface as STL (a test input for `from_stl`)."""
    with _gmsh(0, h) as gmsh:
        gmsh.model.occ.addSphere(0, 0, 0, 1)
        gmsh.model.occ.synchronize()
        gmsh.model.mesh.generate(2)
        gmsh.write(str(path))


# ------------------------------------------------------------------------------------- numpy 2D


def square_structured(seed: int, n: int, quads: bool) -> GeneratedMesh:
    """n x n structured grid of the unit square, quads or each quad cut in two triangles."""
    x = np.linspace(0.0, 1.0, n + 1)
    points = np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1).reshape(-1, 2)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="xy")
    a = (j * (n + 1) + i).ravel()
    b, c, d = a + 1, a + n + 2, a + n + 1
    if quads:
        cells = [("quad", np.stack([a, b, c, d], axis=1))]
    else:
        cells = [("triangle", np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]))]
    return GeneratedMesh(points, cells, None, "square-quad" if quads else "square-tri", seed)


def _square_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """n random points in the unit square, kept a little apart from each other (Poisson-like)."""
    m = int(np.ceil(np.sqrt(n)))
    cell = (np.arange(m * m) % m, np.arange(m * m) // m)
    pts = (np.column_stack(cell) + rng.uniform(0.1, 0.9, size=(m * m, 2))) / m
    return pts[rng.permutation(m * m)[:n]]


def delaunay(seed: int, n: int) -> GeneratedMesh:
    """Delaunay triangulation of ~n random points of the unit square plus its boundary."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(seed)
    m = max(2, int(np.sqrt(n)))
    t = np.linspace(0, 1, m + 1)[:-1]
    boundary = np.concatenate(
        [
            np.column_stack([t, 0 * t]),
            np.column_stack([1 + 0 * t, t]),
            np.column_stack([1 - t, 1 + 0 * t]),
            np.column_stack([0 * t, 1 - t]),
        ]
    )
    interior = _square_points(rng, n) * (1 - 1.0 / m) + 0.5 / m
    points = np.concatenate([boundary, interior])
    tri = Delaunay(points).simplices.astype(np.int64)
    # Drop degenerate slivers along the boundary (collinear boundary points).
    e1, e2 = points[tri[:, 1]] - points[tri[:, 0]], points[tri[:, 2]] - points[tri[:, 0]]
    area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    tri = tri[np.abs(area) > 1e-12]
    flip = (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])[np.abs(area) > 1e-12] < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return GeneratedMesh(points, [("triangle", tri)], None, "delaunay", seed)


def voronoi(seed: int, n: int) -> GeneratedMesh:
    """Voronoi cells of n random points, clipped to the unit square (seeds mirrored across the sides,
    so that every cell of a real seed is bounded and its boundary lies on the square)."""
    from scipy.spatial import Voronoi

    rng = np.random.default_rng(seed)
    seeds = _square_points(rng, n)
    mirrored = [seeds]
    for axis, side in ((0, 0.0), (0, 1.0), (1, 0.0), (1, 1.0)):
        m = seeds.copy()
        m[:, axis] = 2 * side - m[:, axis]
        mirrored.append(m)
    vor = Voronoi(np.concatenate(mirrored))
    vertices = np.clip(vor.vertices, 0.0, 1.0)
    # Merge vertices that coincide (the mirror construction duplicates those on the sides).
    key = np.round(vertices * 1e9).astype(np.int64)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    points = np.zeros((len(uniq), 2))
    points[inverse] = vertices
    polys: dict[int, list[np.ndarray]] = {}
    for i in range(len(seeds)):
        region = vor.regions[vor.point_region[i]]
        ids = inverse[np.asarray(region, dtype=np.int64)]
        # Remove repeated consecutive ids left by merging, then order counter-clockwise.
        ids = ids[np.r_[True, ids[1:] != ids[:-1]]]
        if len(ids) > 1 and ids[0] == ids[-1]:
            ids = ids[:-1]
        ids = np.unique(ids)
        c = points[ids].mean(axis=0)
        ids = ids[np.argsort(np.arctan2(points[ids, 1] - c[1], points[ids, 0] - c[0]))]
        polys.setdefault(len(ids), []).append(ids)
    used = np.unique(np.concatenate([np.concatenate(v) for v in polys.values()]))
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    cells = []
    for k in sorted(polys):
        name = {3: "triangle", 4: "quad"}.get(k, "polygon")
        cells.append((name, remap[np.array(polys[k], dtype=np.int64)]))
    return GeneratedMesh(points[used], cells, None, "voronoi", seed)


# -------------------------------------------------------------------------------------- dispatch


def generate(
    kind: str,
    seed: int = 0,
    size: float | None = None,
    n: int | None = None,
    parts: int | None = None,
    regular: bool = False,
    stl: str | Path | None = None,
    fill: dict | None = None,
) -> GeneratedMesh:
    """One mesh of the given kind. `size` is the mesh size h (gmsh kinds) or 1/divisions (structured);
    `n` the number of points (delaunay, voronoi) or holes / inclusions; random within a range when
    left out (drawn from the seed). Kind stl: the surface is kept unless `size` (a fraction of its
    bounding-box diagonal) or fill = {"size_abs", "remesh"} asks for re-meshing; fill may also hold
    "max_cells" and "progress" (see from_stl)."""
    if kind not in KINDS:
        raise ParameterError(f"unknown mesh kind {kind!r}; choose one of {listed(KINDS)}")
    rng = np.random.default_rng([seed, 7])
    if size is not None and kind != "stl" and not 0 < size <= 1:
        raise ParameterError("size must be in (0, 1]")
    if kind in ("square-tri", "square-quad"):
        div = int(round(1 / size)) if size else int(rng.integers(10, 41))
        return square_structured(seed, div, quads=kind == "square-quad")
    if kind in ("delaunay", "voronoi"):
        npts = n if n else int(1 / size**2) if size else int(rng.integers(150, 1200))
        if npts < 4:
            raise ParameterError("delaunay / voronoi need n >= 4 points")
        return (delaunay if kind == "delaunay" else voronoi)(seed, npts)
    h2 = size if size else float(rng.uniform(0.025, 0.06))
    h3 = size if size else float(rng.uniform(0.08, 0.15))
    if kind == "holes":
        return square_with_disks(seed, n if n is not None else int(rng.integers(1, 7)), h2, False, regular)
    if kind == "inclusions":
        return square_with_disks(seed, n if n is not None else int(rng.integers(6, 13)), h2, True, regular)
    if kind == "split":
        return square_split(seed, h2)
    if kind == "cube":
        return cube(seed, h3)
    if kind == "cube-portion":
        return cube_portion(seed, h3)
    if kind == "cube-hetero":
        return cube_hetero(seed, h3, parts)
    if stl is None:
        raise ParameterError("kind 'stl' needs --stl FILE (a closed surface: .stl, .obj, .ply or .off)")
    return from_stl(stl, seed, size, **(fill or {}))

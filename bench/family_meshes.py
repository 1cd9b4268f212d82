"""The mesh family of bench_hierarchy_family.py, built with gmsh at bench time (never stored).

Every maker takes a size factor `s` (1: about 10^4 cells; the cell count grows like s^dim) and
returns (points, [(meshio type, connectivity)], tags or None). 2D points have two columns.
"""

from __future__ import annotations

import contextlib

import numpy as np

# gmsh element type -> (meshio name, corner nodes)
_GMSH = {
    2: ("triangle", 3),
    3: ("quad", 4),
    4: ("tetra", 4),
    5: ("hexahedron", 8),
    6: ("wedge", 6),
    7: ("pyramid", 5),
}


@contextlib.contextmanager
def _gmsh():
    import gmsh

    gmsh.initialize(["-nt", "1"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
        gmsh.model.add("m")
        yield gmsh
    finally:
        gmsh.finalize()


def _extract(gmsh, dim: int):
    """Points and cell blocks of the model's `dim`-dimensional elements; tags = the entity of each cell
    when more than one entity holds cells."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    index = np.empty(int(tags.max()) + 1, dtype=np.int64)
    index[tags.astype(np.int64)] = np.arange(tags.size)
    pts = np.asarray(coords).reshape(-1, 3)
    blocks, tag_list, ents = [], [], gmsh.model.getEntities(dim)
    for _, ent in ents:
        types, _, nodes = gmsh.model.mesh.getElements(dim, ent)
        for t, nd in zip(types, nodes, strict=True):
            name, nv = _GMSH[int(t)]
            conn = index[np.asarray(nd, dtype=np.int64)].reshape(-1, nv)
            blocks.append((name, conn))
            tag_list.append(np.full(conn.shape[0], ent, dtype=np.int64))
    used = np.unique(np.concatenate([c.ravel() for _, c in blocks]))
    remap = np.full(pts.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    pts = pts[used][:, :dim]
    blocks = [(n, remap[c]) for n, c in blocks]
    tags = tag_list if len(ents) > 1 else None
    return pts, blocks, tags


def _size(gmsh, h: float) -> None:
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)


def plate_holes(s: float, holes: int):
    """Unit square with holes x holes disks of radius 0.3 / sqrt(holes) on a grid (1, 4, 16)."""
    with _gmsh() as g:
        occ = g.model.occ
        sq = occ.addRectangle(0, 0, 0, 1, 1)
        m = int(round(np.sqrt(holes)))
        r = 0.3 / m
        disks = [(2, occ.addDisk((i + 0.5) / m, (j + 0.5) / m, 0, r, r)) for i in range(m) for j in range(m)]
        occ.cut([(2, sq)], disks)
        occ.synchronize()
        _size(g, 0.0125 / s)
        g.model.mesh.generate(2)
        return _extract(g, 2)


def pinholes(s: float, n: int = 10):
    """Unit square with n x n holes about a cell across (radius 0.4 of the cell size), jittered off
    the grid: many small holes, the coarse end's hardest case."""
    rng = np.random.default_rng(1)
    with _gmsh() as g:
        occ = g.model.occ
        sq = occ.addRectangle(0, 0, 0, 1, 1)
        h = 0.0125 / s
        r = 0.4 * 0.0125
        c = (np.arange(n) + 0.5) / n
        xy = np.stack(np.meshgrid(c, c), -1).reshape(-1, 2) + rng.uniform(-0.25, 0.25, (n * n, 2)) / n
        disks = [(2, occ.addDisk(x, y, 0, r, r)) for x, y in xy]
        occ.cut([(2, sq)], disks)
        occ.synchronize()
        _size(g, h)
        g.model.mesh.generate(2)
        return _extract(g, 2)


def cavities(s: float, n: int = 3):
    """A cube with n x n x n closed spherical cavities (voids: n^3 inner boundary shells)."""

    def build(occ):
        c = (np.arange(n) + 0.5) / n
        balls = [(3, occ.addSphere(x, y, z, 0.12 / n * 3 / 3)) for x in c for y in c for z in c]
        occ.cut([(3, occ.addBox(0, 0, 0, 1, 1, 1))], balls)

    return _solid(s, build, 0.06)


def lshape(s: float, graded: float = 1.0):
    """L-shape (unit square minus its upper right quarter); graded > 1: cell size growing linearly
    from h / graded at the re-entrant corner to h (a length ratio `graded`)."""
    with _gmsh() as g:
        occ = g.model.occ
        a = occ.addRectangle(0, 0, 0, 1, 1)
        b = occ.addRectangle(0.5, 0.5, 0, 0.5, 0.5)
        occ.cut([(2, a)], [(2, b)])
        occ.synchronize()
        h = 0.014 / s
        if graded > 1:
            h = 0.032 / s
            _size(g, h)
            g.option.setNumber("Mesh.MeshSizeMin", h / graded)
            corner = g.model.getEntitiesInBoundingBox(0.49, 0.49, -1, 0.51, 0.51, 1, 0)
            f = g.model.mesh.field.add("Distance")
            g.model.mesh.field.setNumbers(f, "PointsList", [t for _, t in corner])
            t = g.model.mesh.field.add("Threshold")
            g.model.mesh.field.setNumber(t, "InField", f)
            g.model.mesh.field.setNumber(t, "SizeMin", h / graded)
            g.model.mesh.field.setNumber(t, "SizeMax", h)
            g.model.mesh.field.setNumber(t, "DistMin", 0.0)
            g.model.mesh.field.setNumber(t, "DistMax", 0.5)
            g.model.mesh.field.setAsBackgroundMesh(t)
        else:
            _size(g, h)
        g.model.mesh.generate(2)
        return _extract(g, 2)


def slit(s: float):
    """Unit square with a crack from the middle of the right side to the centre (a notch 0.004 wide
    at the mouth, closing to a point at the tip)."""
    with _gmsh() as g:
        geo = g.model.geo
        e = 0.002
        xy = [(0, 0), (1, 0), (1, 0.5 - e), (0.5, 0.5), (1, 0.5 + e), (1, 1), (0, 1)]
        p = [geo.addPoint(x, y, 0) for x, y in xy]
        lines = [geo.addLine(p[i], p[(i + 1) % len(p)]) for i in range(len(p))]
        geo.addPlaneSurface([geo.addCurveLoop(lines)])
        geo.synchronize()
        _size(g, 0.015 / s)
        g.model.mesh.generate(2)
        return _extract(g, 2)


def boundary_layer(s: float, aspect: float = 50.0):
    """[0, 1] x [0, 0.25] triangles, structured: nx columns, rows graded from the wall y = 0, whose
    first row is `aspect` times flatter than wide (the wall's cells aspect:1)."""
    nx = int(round(140 * s))
    ny = int(round(36 * s))
    dx = 1.0 / nx
    dy0 = dx / aspect
    H = 0.25
    lo, hi = 1.0 + 1e-9, 3.0  # growth factor q with dy0 (q^ny - 1) / (q - 1) = H (bisection)
    for _ in range(200):
        q = 0.5 * (lo + hi)
        if dy0 * (q**ny - 1) / (q - 1) > H:
            hi = q
        else:
            lo = q
    with _gmsh() as g:
        geo = g.model.geo
        p = [geo.addPoint(x, y, 0) for x, y in ((0, 0), (1, 0), (1, H), (0, H))]
        ln = [geo.addLine(p[i], p[(i + 1) % 4]) for i in range(4)]
        geo.addPlaneSurface([geo.addCurveLoop(ln)])
        geo.synchronize()
        g.model.mesh.setTransfiniteCurve(ln[0], nx + 1)
        g.model.mesh.setTransfiniteCurve(ln[2], nx + 1)
        g.model.mesh.setTransfiniteCurve(ln[1], ny + 1, "Progression", q)
        g.model.mesh.setTransfiniteCurve(ln[3], ny + 1, "Progression", 1.0 / q)
        g.model.mesh.setTransfiniteSurface(1)
        g.model.mesh.generate(2)
        return _extract(g, 2)


def two_materials(s: float):
    """Unit square with an inner disk as a second surface (conforming; tags = the two materials)."""
    with _gmsh() as g:
        occ = g.model.occ
        sq = occ.addRectangle(0, 0, 0, 1, 1)
        d = occ.addDisk(0.45, 0.5, 0, 0.25, 0.25)
        occ.fragment([(2, sq)], [(2, d)])
        occ.synchronize()
        _size(g, 0.015 / s)
        g.model.mesh.generate(2)
        return _extract(g, 2)


def quads(s: float, mixed: bool = False):
    """Unstructured quads of a plate with one off-centre hole (gmsh's recombination); mixed: only the
    left half recombined (triangles and quads)."""
    with _gmsh() as g:
        occ = g.model.occ
        a = occ.addRectangle(0, 0, 0, 0.5, 1)
        b = occ.addRectangle(0.5, 0, 0, 0.5, 1)
        d = occ.addDisk(0.7, 0.6, 0, 0.12, 0.12)
        out, _ = occ.fragment([(2, a)], [(2, b)])
        occ.cut(out, [(2, d)])
        occ.synchronize()
        _size(g, (0.018 if mixed else 0.02) / s)
        for _, t in g.model.getEntities(2):
            x0, _, _, x1, _, _ = g.model.getBoundingBox(2, t)
            if not mixed or x0 + x1 < 1.0:
                g.model.mesh.setRecombine(2, t)
        g.option.setNumber("Mesh.Algorithm", 8)
        if not mixed:  # every triangle the recombination leaves split into quads
            g.option.setNumber("Mesh.SubdivisionAlgorithm", 1)
        g.model.mesh.generate(2)
        return _extract(g, 2)


def _solid(s: float, build, h: float):
    with _gmsh() as g:
        build(g.model.occ)
        g.model.occ.synchronize()
        _size(g, h / s)
        g.model.mesh.generate(3)
        return _extract(g, 3)


def torus(s: float):
    return _solid(s, lambda occ: occ.addTorus(0, 0, 0, 1.0, 0.4), 0.115)


def double_torus(s: float):
    """Genus two: a slab with two round holes through it (gmsh's fuse of two tori fails)."""

    def build(occ):
        slab = occ.addBox(0, 0, 0, 2, 1, 0.3)
        c1 = occ.addCylinder(0.5, 0.5, -0.1, 0, 0, 0.5, 0.25)
        c2 = occ.addCylinder(1.5, 0.5, -0.1, 0, 0, 0.5, 0.25)
        occ.cut([(3, slab)], [(3, c1), (3, c2)])

    return _solid(s, build, 0.065)


def cavity(s: float):
    def build(occ):
        occ.cut([(3, occ.addBox(0, 0, 0, 1, 1, 1))], [(3, occ.addSphere(0.5, 0.5, 0.5, 0.25))])

    return _solid(s, build, 0.07)


def tunnels(s: float):
    def build(occ):
        box = occ.addBox(0, 0, 0, 1, 1, 0.6)
        c1 = occ.addCylinder(-0.1, 0.3, 0.3, 1.2, 0, 0, 0.12)
        c2 = occ.addCylinder(0.7, -0.1, 0.3, 0, 1.2, 0, 0.12)
        occ.cut([(3, box)], [(3, c1), (3, c2)])

    return _solid(s, build, 0.06)


def thin_walled(s: float):
    """An open box (a cup) with walls 0.06 thick: two or three cells across the wall."""

    def build(occ):
        occ.cut([(3, occ.addBox(0, 0, 0, 1, 1, 0.6))], [(3, occ.addBox(0.06, 0.06, 0.06, 0.88, 0.88, 1))])

    return _solid(s, build, 0.035)


def _extruded(s: float, mixed: bool):
    """A plate with a hole extruded in layers: hexahedra (recombined quads), or mixed: the left half's
    triangles become prisms and the right half's quads hexahedra."""
    with _gmsh() as g:
        occ = g.model.occ
        a = occ.addRectangle(0, 0, 0, 0.5, 1)
        b = occ.addRectangle(0.5, 0, 0, 0.5, 1)
        d = occ.addDisk(0.7, 0.5, 0, 0.15, 0.15)
        out, _ = occ.fragment([(2, a)], [(2, b)])
        occ.cut(out, [(2, d)])
        occ.synchronize()
        h = (0.04 if mixed else 0.032) / s
        _size(g, h)
        surfs = g.model.getEntities(2)
        for _, t in surfs:
            x0, _, _, x1, _, _ = g.model.getBoundingBox(2, t)
            if not mixed or x0 + x1 > 1.0:
                g.model.mesh.setRecombine(2, t)
        g.option.setNumber("Mesh.Algorithm", 8)
        g.option.setNumber("Mesh.RecombineAll", 0)
        layers = max(2, int(round(0.3 / h)))
        g.model.occ.extrude(surfs, 0, 0, 0.3, [layers], recombine=True)
        g.model.occ.synchronize()
        g.model.mesh.generate(3)
        return _extract(g, 3)


def hexes(s: float):
    return _extruded(s, mixed=False)


def mixed_3d(s: float):
    return _extruded(s, mixed=True)


# name -> (maker, dim, anisotropic diffusion tensor matching the mesh or None)
FAMILY = {
    "plate-1hole": (lambda s: plate_holes(s, 1), None),
    "plate-4holes": (lambda s: plate_holes(s, 4), None),
    "plate-16holes": (lambda s: plate_holes(s, 16), None),
    "plate-36holes": (lambda s: plate_holes(s, 36), None),
    "pinholes-100": (pinholes, None),
    "L-shape": (lambda s: lshape(s), None),
    "slit": (slit, None),
    "graded-100": (lambda s: lshape(s, graded=100.0), None),
    "layer-50": (boundary_layer, (50.0, 1.0)),
    "two-materials": (two_materials, None),
    "quads": (quads, None),
    "tri+quad": (lambda s: quads(s, mixed=True), None),
    "torus": (torus, None),
    "double-torus": (double_torus, None),
    "cavity": (cavity, None),
    "cavities-27": (cavities, None),
    "tunnels": (tunnels, None),
    "thin-walled": (thin_walled, None),
    "hexes": (hexes, None),
    "hex+prism": (mixed_3d, None),
}

"""Make the small gmsh meshes with named boundary groups that tests/test_boundary.py uses.

    .venv/bin/python tests/data/make_boundary_meshes.py      # writes tests/data/*.msh

- square_sides.msh: unit square, surface group 1 "domain", sides as physical curves
  2 "bottom" (y=0), 3 "right" (x=1), 4 "top" (y=1), 5 "left" (x=0) (the tags of lymph's squares).
- square_inclusion.msh: the same square with a disc inclusion (centre (0.5, 0.5), radius 0.25):
  materials 1 "matrix" and 2 "inclusion", sides 2..5 as above and the interface circle as
  physical curve 6 "interface".
- cube_faces.msh: unit cube, volume group 1 "domain", faces 11 "x0", 12 "x1", 13 "y0", 14 "y1",
  15 "z0", 16 "z1".
- cube_inclusion.msh: the cube with a box inclusion [0.3, 0.7]^3: materials 1 "matrix" and
  2 "inclusion", faces 11..16 as above, the inclusion's six faces as surface 20 "interface".
Deterministic (gmsh's default algorithms, fixed sizes); ASCII MSH 4.1.
"""

from __future__ import annotations

import os
import sys

import gmsh

HERE = os.path.dirname(os.path.abspath(__file__))
SIDES = {
    2: ("bottom", lambda x, y: abs(y) < 1e-9),
    3: ("right", lambda x, y: abs(x - 1) < 1e-9),
    4: ("top", lambda x, y: abs(y - 1) < 1e-9),
    5: ("left", lambda x, y: abs(x) < 1e-9),
}


def _tag_sides(curves) -> list[int]:
    """Physical curves 2..5 for the square's four sides; returns the curves not on a side."""
    rest = []
    by_tag = {t: [] for t in SIDES}
    for _, c in curves:
        x, y, _ = gmsh.model.occ.getCenterOfMass(1, c)
        for t, (_, on) in SIDES.items():
            if on(x, y):
                by_tag[t].append(c)
                break
        else:
            rest.append(c)
    for t, (name, _) in SIDES.items():
        gmsh.model.addPhysicalGroup(1, by_tag[t], t, name=name)
    return rest


FACES = {(0, 0): "x0", (0, 1): "x1", (1, 0): "y0", (1, 1): "y1", (2, 0): "z0", (2, 1): "z1"}


def _tag_faces(surfaces) -> list[int]:
    """Physical surfaces 11..16 (FACES) for the unit cube's six faces; returns the surfaces not on one."""
    rest = []
    for _, f in surfaces:
        c = gmsh.model.occ.getCenterOfMass(2, f)
        hit = [(a, s) for a in range(3) for s in (0, 1) if abs(c[a] - s) < 1e-9]
        if hit:
            a, s = hit[0]
            gmsh.model.addPhysicalGroup(2, [f], 11 + 2 * a + s, name=FACES[a, s])
        else:
            rest.append(f)
    return rest


def _write(name: str) -> None:
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    path = os.path.join(HERE, name)
    gmsh.write(path)
    print(f"wrote {path}")


def square_sides() -> None:
    gmsh.model.add("square_sides")
    s = gmsh.model.occ.addRectangle(0, 0, 0, 1, 1)
    gmsh.model.occ.synchronize()
    gmsh.model.addPhysicalGroup(2, [s], 1, name="domain")
    _tag_sides(gmsh.model.getEntities(1))
    gmsh.option.setNumber("Mesh.MeshSizeMax", 0.08)
    gmsh.model.mesh.generate(2)
    _write("square_sides.msh")


def square_inclusion() -> None:
    gmsh.model.add("square_inclusion")
    sq = gmsh.model.occ.addRectangle(0, 0, 0, 1, 1)
    disc = gmsh.model.occ.addDisk(0.5, 0.5, 0, 0.25, 0.25)
    out, _ = gmsh.model.occ.fragment([(2, sq)], [(2, disc)])
    gmsh.model.occ.synchronize()
    surfaces = [s for _, s in out]
    areas = {s: gmsh.model.occ.getMass(2, s) for s in surfaces}
    inner = min(surfaces, key=areas.get)
    outer = [s for s in surfaces if s != inner]
    gmsh.model.addPhysicalGroup(2, outer, 1, name="matrix")
    gmsh.model.addPhysicalGroup(2, [inner], 2, name="inclusion")
    rest = _tag_sides(gmsh.model.getEntities(1))
    gmsh.model.addPhysicalGroup(1, rest, 6, name="interface")
    gmsh.option.setNumber("Mesh.MeshSizeMax", 0.07)
    gmsh.model.mesh.generate(2)
    _write("square_inclusion.msh")


def cube_faces() -> None:
    gmsh.model.add("cube_faces")
    v = gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
    gmsh.model.occ.synchronize()
    gmsh.model.addPhysicalGroup(3, [v], 1, name="domain")
    _tag_faces(gmsh.model.getEntities(2))
    gmsh.option.setNumber("Mesh.MeshSizeMax", 0.3)
    gmsh.model.mesh.generate(3)
    _write("cube_faces.msh")


def cube_inclusion() -> None:
    gmsh.model.add("cube_inclusion")
    box = gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
    inner = gmsh.model.occ.addBox(0.3, 0.3, 0.3, 0.4, 0.4, 0.4)
    out, _ = gmsh.model.occ.fragment([(3, box)], [(3, inner)])
    gmsh.model.occ.synchronize()
    vols = [v for _, v in out]
    small = min(vols, key=lambda v: gmsh.model.occ.getMass(3, v))
    gmsh.model.addPhysicalGroup(3, [v for v in vols if v != small], 1, name="matrix")
    gmsh.model.addPhysicalGroup(3, [small], 2, name="inclusion")
    rest = _tag_faces(gmsh.model.getEntities(2))
    gmsh.model.addPhysicalGroup(2, rest, 20, name="interface")
    gmsh.option.setNumber("Mesh.MeshSizeMax", 0.3)
    gmsh.model.mesh.generate(3)
    _write("cube_inclusion.msh")


def main() -> int:
    gmsh.initialize(["gmsh", "-v", "0"] if "-v" not in sys.argv else [])
    try:
        square_sides()
        square_inclusion()
        cube_faces()
        cube_inclusion()
    finally:
        gmsh.finalize()
    return 0


if __name__ == "__main__":
    sys.exit(main())

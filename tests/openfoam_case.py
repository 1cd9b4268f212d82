"""OpenFOAM cases written at test time (no OpenFOAM here): a polyMesh in OpenFOAM's ASCII format
(points, faces, owner, neighbour, boundary) from cells given as their outward faces, laid out as
OpenFOAM's own tools write it: internal faces first, in upper-triangular order (by owner, then
neighbour), each oriented from its owner (the lower cell) to its neighbour; then the boundary
faces patch by patch."""

from __future__ import annotations

import os

import numpy as np

HEADER = """FoamFile
{{
    version     2.0;
    format      ascii;
    class       {cls};
    location    "{loc}";
    object      {obj};
}}
"""

HEX_FACES = ((0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7))


def hex_grid(nx: int, ny: int, nz: int, size=(1.0, 0.8, 0.6)):
    """Points (x fastest) and hexahedra (VTK order) of an nx x ny x nz grid, slightly sheared."""
    x, y, z = np.meshgrid(
        *(np.linspace(0, size[a], n + 1) for a, n in enumerate((nx, ny, nz))), indexing="ij"
    )
    p = np.column_stack([x.ravel("F"), y.ravel("F"), z.ravel("F")])
    p[:, 0] += 0.1 * p[:, 1]  # (planar faces: an affine map)
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    b = (i + (nx + 1) * (j + (ny + 1) * k)).ravel("F")
    sy, sz = nx + 1, (nx + 1) * (ny + 1)
    return p, np.stack([b, b + 1, b + 1 + sy, b + sy, b + sz, b + sz + 1, b + sz + 1 + sy, b + sz + sy], 1)


def hex_cells(hexes) -> list[list[list[int]]]:
    """Each hexahedron as its six outward faces."""
    return [[[int(h[n]) for n in f] for f in HEX_FACES] for h in hexes]


def merged_pairs(hexes, nx: int) -> list[list[list[int]]]:
    """Cells of two hexahedra side by side along x (x index 2m and 2m+1) merged into one cell of
    ten faces (its sides keep the two halves' faces): polyhedra, as a coarsened or split-hex
    mesh has them; nx even."""
    cells = []
    faces = hex_cells(hexes)
    for c in range(0, len(hexes), 2):
        a, b = faces[c], faces[c + 1]
        cells.append([a[0], b[0], a[1], b[1], a[2], b[2], b[3], a[4], b[4], a[5]])
    assert nx % 2 == 0
    return cells


def write_case(root, points, cells, patch_of=None, order=(), types=None) -> str:
    """The case in `root` (constant/polyMesh, system/controlDict, an empty root/case.foam); cells:
    per cell its faces (node lists, outward). patch_of(centre) -> patch name of a boundary face by
    its centre (default: 'walls'). order: patch names first, in this order (written even where
    empty, as decomposePar keeps every processor's list), then the others sorted; types: patch
    name -> its boundary entry's lines (default: 'type patch;'). Returns the .foam file's path."""
    keys: dict[tuple, list] = {}
    for c, faces in enumerate(cells):
        for f in faces:
            keys.setdefault(tuple(sorted(f)), []).append((c, f))
    internal, boundary = [], {}
    for users in keys.values():
        if len(users) == 2:
            (c0, f0), (c1, _) = sorted(users, key=lambda u: u[0])
            internal.append((c0, c1, f0))  # oriented out of the owner
        else:
            (c0, f0) = users[0]
            name = patch_of(points[f0].mean(axis=0)) if patch_of else "walls"
            boundary.setdefault(name, []).append((c0, f0))
    internal.sort(key=lambda t: (t[0], t[1]))
    faces = [f for _, _, f in internal]
    owner = [o for o, _, _ in internal]
    neighbour = [n for _, n, _ in internal]
    patches = []
    for name in [*order, *sorted(set(boundary) - set(order))]:
        patches.append((name, len(faces), len(boundary.get(name, []))))
        for c, f in boundary.get(name, []):
            faces.append(f)
            owner.append(c)
    mesh = os.path.join(root, "constant", "polyMesh")
    os.makedirs(mesh, exist_ok=True)
    os.makedirs(os.path.join(root, "system"), exist_ok=True)
    with open(os.path.join(root, "system", "controlDict"), "w") as f:
        f.write(HEADER.format(cls="dictionary", loc="system", obj="controlDict"))
        f.write("application simpleFoam;\nstartFrom startTime;\nstartTime 0;\nendTime 1;\ndeltaT 1;\n")

    def field(name: str, cls: str, rows: list[str]) -> None:
        with open(os.path.join(mesh, name), "w") as f:
            f.write(HEADER.format(cls=cls, loc="constant/polyMesh", obj=name))
            f.write(f"\n{len(rows)}\n(\n" + "\n".join(rows) + "\n)\n")

    field("points", "vectorField", [f"({a!r} {b!r} {c!r})" for a, b, c in np.asarray(points, float).tolist()])
    field("faces", "faceList", [f"{len(f)}(" + " ".join(map(str, f)) + ")" for f in faces])
    field("owner", "labelList", [str(o) for o in owner])
    field("neighbour", "labelList", [str(n) for n in neighbour])
    with open(os.path.join(mesh, "boundary"), "w") as f:
        f.write(HEADER.format(cls="polyBoundaryMesh", loc="constant/polyMesh", obj="boundary"))
        f.write(f"\n{len(patches)}\n(\n")
        for name, start, n in patches:
            f.write(
                f"    {name}\n    {{\n        {(types or {}).get(name, 'type patch;')}\n        nFaces {n};\n"
                f"        startFace {start};\n    }}\n"
            )
        f.write(")\n")
    foam = os.path.join(root, "case.foam")
    open(foam, "w").close()
    return foam


def vtk_internal(path: str):
    """VTK's own reading of the case: its internal mesh (vtkUnstructuredGrid)."""
    from vtkmodules.vtkIOGeometry import vtkOpenFOAMReader

    r = vtkOpenFOAMReader()
    r.SetFileName(path)
    r.Update()
    out = r.GetOutput()
    for i in range(out.GetNumberOfBlocks()):
        if out.GetMetaData(i).Get(out.NAME()) == "internalMesh":
            return out.GetBlock(i)
    raise AssertionError("no internal mesh")


def write_cell_zones(root, zones: dict) -> None:
    """constant/polyMesh/cellZones as OpenFOAM's tools (topoSet, setsToZones, snappyHexMesh)
    write it: zone name -> cell labels; short lists on one line, long ones a line per label."""
    rows = [
        HEADER.format(cls="regIOobject", loc="constant/polyMesh", obj="cellZones"),
        f"\n{len(zones)}\n(\n",
    ]
    for name, labels in zones.items():
        labels = [int(c) for c in labels]
        if len(labels) < 11:
            body = f"List<label> {len(labels)}(" + " ".join(map(str, labels)) + ")"
        else:
            body = f"List<label> {len(labels)}\n(\n" + "\n".join(map(str, labels)) + "\n)\n"
        rows.append(f"{name}\n{{\n    type cellZone;\ncellLabels      {body};\n}}\n\n")
    rows.append(")\n")
    with open(os.path.join(root, "constant", "polyMesh", "cellZones"), "w") as f:
        f.write("".join(rows))

"""What this session's checks of files that hold no area or volume found: a file of points alone
was said to be a "1D mesh"."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from models.errors import MeshError
from models.mesh.read import read_mesh


@pytest.mark.parametrize("fmt,ext", [("vtu", ".vtu"), ("gmsh22", ".msh")])
def test_points_alone_and_lines_alone_are_said_as_such(tmp_path, fmt, ext):
    p = np.random.default_rng(0).random((10, 3))
    pts = tmp_path / f"pts{ext}"
    lines = tmp_path / f"lines{ext}"
    meshio.write(pts, meshio.Mesh(p, [("vertex", np.arange(10)[:, None])]), file_format=fmt)
    meshio.write(lines, meshio.Mesh(p, [("line", np.c_[np.arange(9), np.arange(1, 10)])]), file_format=fmt)
    with pytest.raises(MeshError) as e:
        read_mesh(str(pts))
    msg = str(e.value)
    assert "points alone are not supported" in msg and "1D" not in msg and "vertex" in msg
    with pytest.raises(MeshError) as e:
        read_mesh(str(lines))
    msg = str(e.value)
    assert "1D meshes are not supported" in msg and "line" in msg


def _su2_xz(path, n=12):
    """A plate in the XZ plane as a 2D SU2 file keeps it (NDIME= 2: x and a y that is 0 everywhere,
    as gmsh's SU2 export writes it), triangles."""
    x, z = np.meshgrid(np.linspace(0, 3, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    lines = ["NDIME= 2", f"NELEM= {len(tri)}"]
    lines += [f"5 {t[0]} {t[1]} {t[2]} {i}" for i, t in enumerate(tri)]
    lines += [f"NPOIN= {x.size}"] + [f"{xi!r} 0 {i}" for i, xi in enumerate(x.ravel().tolist())]
    lines += ["NMARK= 0"]
    path.write_text("\n".join(lines) + "\n")


def test_a_plane_whose_writer_dropped_a_coordinate_is_said_so(tmp_path):
    f = tmp_path / "plate_xz.su2"
    _su2_xz(f)
    with pytest.raises(MeshError) as e:
        read_mesh(str(f))
    msg = str(e.value)
    assert "288 of the mesh's 288 cells have zero area" in msg
    assert "all of its points lie on one line" in msg and "y is 0 for every point" in msg
    assert "write the plane in XY" in msg and "remove" not in msg


def test_coordinates_rounded_far_from_the_origin_are_said_so(tmp_path):
    """gmsh's small-field Nastran export of a tilted disk at (1e6, 2e6, 300): 8-character fields keep
    y as 2.00E+06 for every point, so most cells are flat; the refusal says why, not "remove them"."""
    gmsh = pytest.importorskip("gmsh")
    f = tmp_path / "disk.bdf"
    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        occ = gmsh.model.occ
        s = occ.addDisk(0, 0, 0, 1.0, 0.6)
        occ.rotate([(2, s)], 0, 0, 0, 1, 1, 0, 0.7)
        occ.translate([(2, s)], 1e6, 2e6, 300.0)
        occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [s], name="disk")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.1)
        gmsh.model.mesh.generate(2)
        gmsh.write(str(f))
    finally:
        gmsh.finalize()
    with pytest.raises(MeshError) as e:
        read_mesh(str(f))
    msg = str(e.value)
    assert "cells have zero area: its coordinates are rounded" in msg and "y is 2e+06 for every point" in msg
    assert "too few digits" in msg and "remove them" not in msg


def test_a_few_flat_cells_keep_the_old_words():
    """flat_cause is for meshes that are mostly flat: a sound mesh has no cause to say."""
    from meshes import triangles

    from models.mesh.degenerate import flat_cause
    from models.mesh.read import mesh_from_arrays

    p, t = triangles(6)
    assert flat_cause(mesh_from_arrays(p, [("triangle", t)])) is None
    assert flat_cause(mesh_from_arrays(p + 1e7, [("triangle", t)])) is None


def test_a_tilted_plane_rounded_to_a_third_of_its_cells_is_refused_not_projected(tmp_path):
    """A tilted plane of 160 triangles (area 2) 1e5 from the origin, written with 7 significant
    digits: the rounding (0.1) is a third of the cells' size, so projecting it gave an area of 1.976
    (VTK's reading of the rounded points: 2.027); it is refused, saying so. The same plane near the
    origin (at 300: a rounding of 1e-4), is read and projected with its area."""
    nx, ny = 10, 8
    x, y = np.meshgrid(np.linspace(0, 2, nx + 1), np.linspace(0, 1, ny + 1), indexing="ij")
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    a = (i * (ny + 1) + j).ravel()
    tri = np.r_[np.c_[a, a + ny + 1, a + ny + 2], np.c_[a, a + ny + 2, a + 1]]
    ca, sa, cb, sb = np.cos(0.3), np.sin(0.3), np.cos(0.7), np.sin(0.7)
    rot = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]]) @ np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    plane = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)] @ rot.T

    def written(shift, name):
        pts = np.array([[float(f"{v:.7g}") for v in row] for row in plane + shift])
        path = tmp_path / name
        meshio.write(str(path), meshio.Mesh(pts, [("triangle", tri)]), file_format="vtk", binary=False)
        return str(path)

    with pytest.raises(MeshError) as e:
        read_mesh(written(1e5, "far.vtk"))
    msg = str(e.value)
    assert "off their plane" in msg and "7 significant digits" in msg and "small cells' size" in msg
    assert "move the mesh near the origin" in msg
    near = read_mesh(written(300.0, "near.vtk"))
    assert "rounded_plane" in near.meta
    assert abs(near.meta["measures"].sum() - 2.0) < 1e-3


def test_a_bad_point_id_in_one_piece_of_a_vtkhdf_does_not_reach_into_another(tmp_path):
    """A VTKHDF of one partitioned dataset (two pieces of 135 tetrahedra): a connectivity id of -1 in
    the second piece named, once the pieces were joined, the last point of the first (volume 2.0123
    against 2); it is a cell referring to a missing point, left out and said, as in a single grid."""
    vtk = pytest.importorskip("vtk")
    h5py = pytest.importorskip("h5py")
    from test_readers_sweep47b import _tetra_box, _vtkhdf

    p = vtk.vtkPartitionedDataSet()
    p.SetPartition(0, _tetra_box(0.0, 3))
    p.SetPartition(1, _tetra_box(1.0, 3))
    path = _vtkhdf(p, tmp_path / "pieces.vtkhdf")
    good = read_mesh(path)
    assert good.n_cells == 270 and abs(good.meta["measures"].sum() - 2.0) < 1e-12
    with h5py.File(path, "r+") as h:
        conn = h["VTKHDF/Connectivity"][()]
        conn[540 + 7] = -1  # the second piece's cell 1 (its connectivity starts at 540)
        h["VTKHDF/Connectivity"][...] = conn
    mesh = read_mesh(path)
    assert mesh.n_cells == 269
    assert mesh.meta["dropped_cells"]["ids_all"] == [136]
    assert abs(mesh.meta["measures"].sum() - (2.0 - 1.0 / 162)) < 1e-6  # (float32 points)


def test_an_xyz_text_file_is_refused_the_same_way_every_time(tmp_path):
    """An XYZ list of atoms named by words ("Oxygen") with CRLF line ends was not recognised, and
    VTK's PLOT3D reader said "truncated?" or "corrupted" from one run to the next; other text that
    is no PLOT3D grid is refused by its line."""
    atoms = tmp_path / "water.xyz"
    atoms.write_bytes(
        b"3\r\nwater molecule\r\nOxygen 0.0 0.0 0.0\r\nH 0.757 0.586 0.0\r\nH -0.757 0.586 0.0\r\n"
    )
    said = set()
    for _ in range(3):
        with pytest.raises(MeshError) as e:
            read_mesh(str(atoms))
        said.add(str(e.value))
    assert len(said) == 1 and "XYZ list of 3 atoms" in said.pop()
    other = tmp_path / "t.xyz"
    other.write_text("3\nwater\nfoo bar baz\n")
    with pytest.raises(MeshError, match=r"line 2 holds 'water' where the grid's point counts"):
        read_mesh(str(other))


@pytest.mark.parametrize(
    "row,coord,said",
    [
        (
            "63    96    1     0      2     2     1",
            "0.0",
            "line 7 (section CONTROL INFO): 7 numbers where the row",
        ),
        ("63    96    1     0      2     2", "inf", "'inf' where a finite coordinate is expected"),
        ("63.0  96    1     0      2     2", "0.0", "'63.0' where the number of nodes (NUMNP) is expected"),
    ],
)
def test_a_damaged_gambit_header_is_said_by_its_line(tmp_path, row, coord, said):
    """meshpy's layout with a seventh number in the count row, an 'inf' coordinate, a float count:
    "its cells cannot be read", or "the reader crashed on this file: line 7 ..."; now the line and
    what is wrong there, without "crashed" where the place says why."""
    n = 6
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1) + 1
    a, b, c = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    d = idx[:-1, 1:].ravel()
    tri = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    lines = ["CONTROL INFO 2.1.2", "** GAMBIT NEUTRAL FILE", "t", "PROGRAM: MeshPy VERSION: 1", "date"]
    lines += ["NUMNP NELEM NGRPS NBSETS NDFCD NDFVL", row, "ENDOFSECTION", "NODAL COORDINATES 2.1.2"]
    pts = [
        f"{i + 1} {px!r} {py!r}"
        for i, (px, py) in enumerate(zip(x.ravel().tolist(), y.ravel().tolist(), strict=True))
    ]
    pts[0] = f"1 {coord} 0.0"
    lines += pts + ["ENDOFSECTION", "ELEMENTS/CELLS 2.1.2"]
    lines += [f"{i + 1:>8d}{3:>3d}{3:>3d} " + "".join(f"{v:>8d}" for v in t) for i, t in enumerate(tri)]
    lines += ["ENDOFSECTION"]
    path = tmp_path / "m.neu"
    path.write_text("\n".join(lines) + "\n")
    from models.mesh.sandbox import read_mesh_safe

    with pytest.raises(MeshError) as e:  # (in a child, as every way in reads: VTK's reader dies on some)
        read_mesh_safe(str(path))
    msg = str(e.value)
    assert said in msg and "crashed" not in msg and "cannot be read" not in msg, msg


def test_a_gambit_title_with_a_tab_is_read(tmp_path):
    """'CONTROL<tab>INFO': refused "no 'CONTROL INFO' section", though the copy VTK's reader gets
    has its tabs made spaces."""
    n = 3
    g = np.stack(np.meshgrid(*[np.linspace(0, 1, n + 1)] * 2, indexing="ij"), -1).reshape(-1, 2)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1) + 1
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    lines = ["CONTROL\tINFO 2.1.2", "** GAMBIT NEUTRAL FILE", "t", "PROGRAM: x VERSION: 1", "date"]
    lines += ["     NUMNP     NELEM     NGRPS    NBSETS     NDFCD     NDFVL"]
    lines += [f"{len(g):>10d}{len(tri):>10d}{0:>10d}{0:>10d}{2:>10d}{2:>10d}", "ENDOFSECTION"]
    lines += ["   NODAL COORDINATES 2.1.2"] + [
        f"{i + 1:>10d}{p[0]:20.11e}{p[1]:20.11e}" for i, p in enumerate(g)
    ]
    lines += ["ENDOFSECTION", "      ELEMENTS/CELLS 2.1.2"]
    lines += [f"{i + 1:>8d}{3:>3d}{3:>3d} " + "".join(f"{v:>8d}" for v in t) for i, t in enumerate(tri)]
    lines += ["ENDOFSECTION"]
    path = tmp_path / "tab.neu"
    path.write_text("\n".join(lines) + "\n")
    from models.mesh.sandbox import read_mesh_safe

    mesh = read_mesh_safe(str(path))
    assert mesh.n_cells == 18 and abs(mesh.meta["measures"].sum() - 1.0) < 1e-12


def test_meshio_cgns_missing_a_node_is_said_by_that_node(tmp_path):
    """meshio's CGNS layout with CoordinateX's data deleted was "an element type or a keyword that
    this reader does not know"; it is now the node that has no data."""
    h5py = pytest.importorskip("h5py")
    from meshes import tets

    p, t = tets(3)
    path = tmp_path / "m.cgns"
    meshio.write(str(path), meshio.Mesh(p, [("tetra", t)]))
    assert read_mesh(str(path)).n_cells == len(t)
    with h5py.File(path, "r+") as f:
        del f["Base/Zone1/GridCoordinates/CoordinateX/ data"]
    with pytest.raises(MeshError) as e:
        read_mesh(str(path))
    msg = str(e.value)
    assert "GridCoordinates/CoordinateX node has no data" in msg and "keyword" not in msg

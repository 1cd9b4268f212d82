"""CGNS written by the CGNS library itself, the one bundled in the vtk wheel (libvtkcgns.so, its
mid-level API called through ctypes: tests/format_writers.write_cgns_lib), in both containers:
ADF and HDF5. Several zones (each with its own points), one section per cell type or one MIXED
section per zone, 3D (hexahedra, wedges) and 2D (quads, triangles). Each file is read by VTK and by
our dispatch: the same number of cells and total volume / area (1e-9 relative), then agglomerated
by the Python API, the output read back by VTK holding the same volume.
"""

from __future__ import annotations

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")
import format_writers as fw  # noqa: E402
import vtk_corpus as vc  # noqa: E402

from models.errors import MeshError  # noqa: E402
from models.mesh.read import pick_reader, read_mesh  # noqa: E402
from models.mesh.sandbox import read_mesh_safe  # noqa: E402

TOL = 1e-9
if fw.cgns_library() is None:
    pytest.skip(
        "the vtk wheel here has no CGNS library with a writer (libvtkcgns.so)", allow_module_level=True
    )
MAGIC = {"adf": b"\xc0\xa8\xa3\xa9ADF Database Version", "hdf5": b"\x89HDF\r\n\x1a\n"}


def _zones_3d():
    """Two zones of hexahedra (a grid cut in two, interface points repeated) and a third of
    hexahedra and wedges on top."""
    p, blocks = fw.blocks(4, 2, 2)
    zones = [(zp, [("hexahedron", zc)]) for zp, zc in fw.split_zones(p, blocks[0][1])]
    tp, tblocks = fw.blocks(2, 2, 2)
    return [*zones, (tp + [0.0, 0.0, 10.0], tblocks)]


def _zones_2d():
    """Two zones of quadrilaterals and triangles (x, y only)."""
    p, q = vc.quad_grid(4, 3)
    tri = np.concatenate([q[6:, [0, 1, 2]], q[6:, [0, 2, 3]]])
    right = p[:, :2] + [20.0, 0.0]
    return [(p[:, :2], [("quad", q[:6]), ("triangle", tri)]), (right, [("triangle", tri), ("quad", q[:6])])]


CASES = [(ft, mixed, dim) for ft in ("adf", "hdf5") for mixed in (False, True) for dim in (3, 2)]


def _write(tmp, ft, mixed, dim):
    zones = _zones_3d() if dim == 3 else _zones_2d()
    name = f"{ft}_{'mixed' if mixed else 'sections'}_{dim}d.cgns"
    return fw.write_cgns_lib(tmp / name, zones, ft, mixed=mixed, cell_dim=dim), zones


@pytest.mark.parametrize(("file_type", "mixed", "dim"), CASES)
def test_cgns_library_file_matches_vtk_and_agglomerates(tmp_path, file_type, mixed, dim):
    path, zones = _write(tmp_path, file_type, mixed, dim)
    with open(path, "rb") as f:
        assert f.read(len(MAGIC[file_type])) == MAGIC[file_type]  # really that container
    assert pick_reader(path) == ("vtk", "cgns")
    n_ref, size_ref = vc.vtk_reference(path)
    assert n_ref == sum(len(c) for _, blocks in zones for _, c in blocks)
    mesh = read_mesh(path)
    assert mesh.dim == dim and mesh.n_cells == n_ref
    assert mesh.meta["orientation"]["folded"] == 0
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(size_ref, rel=TOL)
    res, n_out, size_out = vc.agglomerate_read_back(path, 4, tmp_path / "out.vtu")
    assert res.n_elements == 4 and res.labels.shape == (n_ref,)
    assert float(np.sum(res.elements.measure)) == pytest.approx(size_ref, rel=TOL)
    assert n_out == 4 and size_out == pytest.approx(size_ref, rel=TOL)


def test_library_hdf5_and_hand_written_hdf5_agree(tmp_path):
    """The h5py writer of the SIDS mapping (format_writers.write_cgns) and the library give the
    same mesh: same cells, same volume, same points."""
    zones = _zones_3d()
    a = read_mesh(fw.write_cgns_lib(tmp_path / "lib.cgns", zones, "hdf5"))
    b = read_mesh(fw.write_cgns(tmp_path / "h5py.cgns", zones))
    assert a.n_cells == b.n_cells and a.n_points == b.n_points
    assert float(np.abs(a.meta["measures"]).sum()) == pytest.approx(
        float(np.abs(b.meta["measures"]).sum()), rel=TOL
    )


@pytest.mark.parametrize("file_type", ["adf", "hdf5"])
def test_truncated_cgns_is_one_sentence(tmp_path, file_type):
    path, _ = _write(tmp_path, file_type, False, 3)
    with open(path, "rb") as f:
        data = f.read()
    with open(path, "wb") as f:
        f.write(data[: len(data) // 3])
    with pytest.raises(MeshError) as err:
        read_mesh_safe(
            path
        )  # a damaged file is read as an upload is: in a child (VTK's HDF5 state is process-wide)
    msg = str(err.value)
    assert path.rsplit("/", 1)[-1] in msg and "CGNS" in msg and "\n" not in msg, msg


def test_gmsh_cgns_families_are_the_physical_groups(tmp_path):
    """gmsh's CGNS export keeps physical groups as CGNS families (a BC at the cell centres per
    family, the family's FamilyName the group's name), and its surface groups as sections of faces;
    VTK's reader shows one grid and drops the faces. Read as the groups and boundary groups of the
    same model written as MSH: names, volumes, faces (outside sweep V)."""
    gmsh = pytest.importorskip("gmsh")
    pytest.importorskip("h5py")
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("two")
        a = gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        b = gmsh.model.occ.addBox(1, 0, 0, 2, 1, 1)
        gmsh.model.occ.fragment([(3, a)], [(3, b)])
        gmsh.model.occ.synchronize()
        vols = [t for _, t in gmsh.model.getEntities(3)]
        gmsh.model.addPhysicalGroup(3, [vols[0]], name="steel")
        gmsh.model.addPhysicalGroup(3, [vols[1]], name="core")
        surf = [t for _, t in gmsh.model.getEntities(2)]
        gmsh.model.addPhysicalGroup(2, surf[:2], name="inlet")  # (one of them between the boxes)
        gmsh.model.addPhysicalGroup(2, surf[2:4], name="wall")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.4)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(tmp_path / "two.cgns"))
        gmsh.write(str(tmp_path / "two.msh"))
    finally:
        gmsh.finalize()
    got, ref = read_mesh(str(tmp_path / "two.cgns")), read_mesh(str(tmp_path / "two.msh"))

    def volumes(m):
        names = m.meta["group_names"]
        return {names[int(t)]: float(m.meta["measures"][m.tags == t].sum()) for t in np.unique(m.tags)}

    vg, vr = volumes(got), volumes(ref)
    assert set(vg) == {"steel", "core"} and set(vr) == set(vg)
    for name in vg:
        assert vg[name] == pytest.approx(vr[name], rel=1e-12)
    assert vg["core"] == pytest.approx(2.0, rel=1e-12)
    from models.mesh.boundary import summary

    def faces(m):
        return {
            g["name"]: (g["on_boundary"], g["interior"], round(g["measure"], 9)) for g in summary(m)["groups"]
        }

    assert faces(got) == faces(ref) and set(faces(got)) == {"inlet", "wall"}, (faces(got), faces(ref))


@pytest.mark.parametrize(
    "break_it, said",
    [
        (lambda z: z.__delitem__("GridCoordinates"), "zone 'Zone1': it has no GridCoordinates"),
        (lambda z: z["Elements0"].__delitem__("ElementRange"), "section 'Elements0' has no ElementRange"),
        ("short", "section 'Elements0' holds 32 node ids for the 8 elements of its ElementRange (64 needed)"),
        ("vertices", "holds 27 values for the 77 vertices the zone declares"),
    ],
)
def test_a_broken_cgns_zone_says_what_is_wrong(tmp_path, break_it, said):
    """VTK's reader crashes on a connectivity shorter than its range, and says 'corrupted' or
    worse ('all points coincide') on the others: the zone's layout is checked first (outside sweep X)."""
    h5py = pytest.importorskip("h5py")
    p, h = fw.grid(2, 2, 2)
    path = fw.write_cgns(tmp_path / "m.cgns", [(p, [("hexahedron", h)])])
    with h5py.File(path, "a") as f:
        zone = next(f[k]["Zone1"] for k in f if isinstance(f[k], h5py.Group) and "Zone1" in f[k])
        if break_it == "short":
            conn = zone["Elements0/ElementConnectivity"]
            keep = conn[" data"][: conn[" data"].shape[0] // 2]
            del conn[" data"]
            conn.create_dataset(" data", data=keep)
        elif break_it == "vertices":
            zone[" data"][0, 0] = len(p) + 50
        else:
            break_it(zone)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(path)
    msg = str(err.value)
    assert msg.startswith("cannot read m.cgns as CGNS: zone 'Zone1': ") and said in msg, msg

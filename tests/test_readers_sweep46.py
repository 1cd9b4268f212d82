"""What an outside sweep of files written by other tools (session 46: gmsh's, meshio's and VTK's
exporters, 314 files) found: MSH 4.1 files saved with parametric coordinates refused at a wrong
place, gmsh's SaveAll turning what lies in no physical group into a boundary group 0, tilted planar
meshes whose coordinates a text format rounded refused as curved, gmsh's large-field Nastran
hexahedra (a continuation line with a blank first field) refused with no reason, Nastran element
cards in large field said to be "no cells", and meshio's list of reader names where a file's
extension is unknown."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from models.errors import MeshError
from models.mesh.read import mesh_from_meshio, read_mesh


@pytest.fixture(scope="module")
def gmsh():
    return pytest.importorskip("gmsh")


def _two_boxes(gmsh, path, size=0.25, **options):
    """Two unit boxes side by side (physical volumes 1 and 2, an outer boundary group 3), meshed with
    tetrahedra (order 1) and written with gmsh's options."""
    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("boxes")
        occ = gmsh.model.occ
        a, b = occ.addBox(0, 0, 0, 1, 1, 1), occ.addBox(1, 0, 0, 1, 1, 1)
        occ.fragment([(3, a)], [(3, b)])
        occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [a], 1)
        gmsh.model.addPhysicalGroup(3, [b], 2)
        outer = [t for _, t in gmsh.model.getBoundary([(3, a), (3, b)], oriented=False)]
        gmsh.model.addPhysicalGroup(2, outer, 3)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.model.mesh.generate(3)
        for key, value in options.items():
            gmsh.option.setNumber(key, value)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return str(path)


def _volume(mesh):
    from models.mesh.geometry import cell_measures

    return float(np.abs(cell_measures(mesh)).sum())


def test_msh41_with_parametric_coordinates_reads_as_without(gmsh, tmp_path):
    plain = read_mesh(_two_boxes(gmsh, tmp_path / "plain.msh", **{"Mesh.MshFileVersion": 4.1}))
    param = read_mesh(
        _two_boxes(gmsh, tmp_path / "param.msh", **{"Mesh.MshFileVersion": 4.1, "Mesh.SaveParametric": 1})
    )
    assert param.n_cells == plain.n_cells and param.n_points == plain.n_points
    assert abs(_volume(param) - 2.0) < 1e-12
    assert np.array_equal(np.unique(param.tags), [1, 2])


def test_save_all_leaves_what_lies_in_no_group_untagged(gmsh, tmp_path):
    """Mesh.SaveAll writes the inner wall between the boxes (in no physical group) with tag 0: it is
    no boundary group 0; the boundary faces are group 3's, as without SaveAll."""
    plain = read_mesh(_two_boxes(gmsh, tmp_path / "plain.msh", **{"Mesh.MshFileVersion": 4.1}))
    every = read_mesh(
        _two_boxes(gmsh, tmp_path / "all.msh", **{"Mesh.MshFileVersion": 4.1, "Mesh.SaveAll": 1})
    )
    assert every.n_cells == plain.n_cells
    assert np.array_equal(np.unique(every.boundary_tags), [3])
    assert np.array_equal(np.unique(plain.boundary_tags), [3])
    assert every.boundary_tags.size == plain.boundary_tags.size


def _tilted_triangles(n=12):
    """A planar mesh of n x n squares cut in triangles, tilted out of every coordinate plane and far
    from the origin (x about 10): written in 8-character fields, its points leave the plane by the
    rounding of the 7 digits they keep."""
    u, v = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    q = (np.arange(n)[:, None] * (n + 1) + np.arange(n)).ravel()
    tri = np.r_[np.c_[q, q + 1, q + n + 2], np.c_[q, q + n + 2, q + n + 1]]
    e1, e2 = np.array([0.6, 0.8, 0.0]), np.array([-0.48, 0.36, 0.8])
    pts = 10.0 + u.ravel()[:, None] * e1 + v.ravel()[:, None] * e2
    return pts, tri


def test_a_tilted_plane_rounded_by_its_format_is_read_and_said(tmp_path):
    pts, tri = _tilted_triangles()
    rounded = np.array([[float(f"{x:.7g}") for x in row] for row in pts])  # an 8-character field's digits
    path = tmp_path / "tilted.vtu"
    meshio.write(str(path), meshio.Mesh(rounded, [("triangle", tri)]))
    mesh = read_mesh(str(path))
    assert mesh.dim == 2 and mesh.n_cells == len(tri)
    assert "7 significant digits" in mesh.meta["rounded_plane"]["message"]
    area = float(np.abs(mesh_area(mesh)).sum())
    assert abs(area - 1.0) < 1e-5
    exact = tmp_path / "exact.vtu"  # the same plane at full precision: nothing to say
    meshio.write(str(exact), meshio.Mesh(pts, [("triangle", tri)]))
    assert "rounded_plane" not in read_mesh(str(exact)).meta
    bent = rounded.copy()  # a real bend (1e-3 of the width) is still no plane
    bent[: len(bent) // 2] += 1e-3 * np.array([0.0, -0.8, 0.6])
    curved = tmp_path / "bent.vtu"
    meshio.write(str(curved), meshio.Mesh(bent, [("triangle", tri)]))
    with pytest.raises(MeshError, match="non-planar surface"):
        read_mesh(str(curved))


def mesh_area(mesh):
    from models.mesh.geometry import cell_measures

    return cell_measures(mesh)


def test_gmsh_large_field_nastran_hexahedra_are_read(gmsh, tmp_path):
    """gmsh's Nastran export in large field (Mesh.BdfFieldFormat 2) continues each CHEXA on a line
    whose first field is blank."""
    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("hex")
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        for c in gmsh.model.getEntities(1):
            gmsh.model.mesh.setTransfiniteCurve(c[1], 4)
        for s in gmsh.model.getEntities(2):
            gmsh.model.mesh.setTransfiniteSurface(s[1])
            gmsh.model.mesh.setRecombine(2, s[1])
        gmsh.model.mesh.setTransfiniteVolume(1)
        gmsh.model.addPhysicalGroup(3, [1], 1)
        gmsh.model.mesh.generate(3)
        gmsh.option.setNumber("Mesh.BdfFieldFormat", 2)
        gmsh.write(str(tmp_path / "hex.bdf"))
    finally:
        gmsh.finalize()
    mesh = read_mesh(str(tmp_path / "hex.bdf"))
    assert mesh.n_cells == 27 and np.all(mesh.cell_types == 12)
    assert abs(_volume(mesh) - 1.0) < 1e-9


def test_large_field_element_cards_and_short_rows_are_said(tmp_path):
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    path = tmp_path / "large.nas"
    meshio.write(
        str(path), meshio.Mesh(pts, [("tetra", tets)]), point_format="fixed-large", cell_format="fixed-large"
    )
    with pytest.raises(MeshError, match=r"large-field form \(such as CTETRA\*\)"):  # (the card found)
        read_mesh(str(path))
    short = meshio.Mesh(pts, [("hexahedron", np.array([[0, 1, 2, 3, 4, 0]]))])  # a lost continuation
    with pytest.raises(MeshError, match="hexahedron cells list 6 nodes each, where a hexahedron has 8"):
        mesh_from_meshio(short)


def test_a_tag_of_0_on_every_element_is_no_group(tmp_path):
    """gmsh's SU2 export: su2:tag 0 on every volume cell, its markers on the boundary faces. The
    elements are in no group (not one group 0 over the whole mesh: lymph's region id 0); the
    markers stay boundary groups (the groups the reader makes of them, "group"). A tag array with
    other values on the elements stays as it is."""
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    tri = np.array([[0, 1, 2], [1, 4, 2]])
    for elem_tags, groups in ((np.zeros(2, int), None), (np.array([0, 5]), [0, 5])):
        m = meshio.Mesh(
            pts, [("tetra", tets), ("triangle", tri)], cell_data={"group": [elem_tags, np.array([3, 3])]}
        )
        mesh = mesh_from_meshio(m)
        assert (mesh.tags is None) if groups is None else sorted(set(mesh.tags.tolist())) == groups
        assert np.array_equal(np.unique(mesh.boundary_tags), [3])


def test_a_format_meshio_only_writes_gets_our_list_of_extensions(tmp_path):
    path = tmp_path / "mesh.svg"
    path.write_text("<svg/>")
    with pytest.raises(MeshError) as refused:
        read_mesh(str(path))
    said = str(refused.value)
    assert "unknown mesh format '.svg'" in said and ".vtu, .vtk, .msh" in said and ".wkt" in said
    assert "neuroglancer" not in said


def test_xdmf_attributes_whose_data_is_missing_leave_the_mesh_read_and_said(tmp_path):
    """VTK's XDMF writer leaves files whose attributes point at HDF5 datasets it did not write
    (integer arrays it stores as "Compound"): VTK reads the mesh and says "Failed to read attribute
    data", and so does ParaView. The mesh is read; the lost arrays are said (groups may be among
    them)."""
    vtk = pytest.importorskip("vtk")
    import vtk_corpus as vc
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkIOXdmf2 import vtkXdmfWriter

    p, h = vc.grid(3, 3, 3)
    grid = vc.unstructured(np.asarray(p, float), [(vtk.VTK_HEXAHEDRON, h)])
    tags = numpy_to_vtk(np.arange(27, dtype=np.int32) % 2 + 1, deep=1)
    tags.SetName("gmsh:physical")
    grid.GetCellData().AddArray(tags)
    writer = vtkXdmfWriter()
    writer.SetFileName(str(tmp_path / "b.xmf"))
    writer.SetInputData(grid)
    writer.Write()
    text = (tmp_path / "b.xmf").read_text()
    lost = (
        '<Attribute Name="material" Active="1" AttributeType="None" Center="Cell">\n'
        '<DataItem Dimensions="27" NumberType="Compound" Format="HDF">b.h5:/Block_0_t000000/Cell/material'
        "</DataItem>\n</Attribute>\n"
    )
    (tmp_path / "b.xmf").write_text(text.replace("    </Grid>", lost + "    </Grid>"))
    mesh = read_mesh(str(tmp_path / "b.xmf"))
    ref = read_mesh(vc.write_xml(tmp_path / "b.vtu", grid))
    assert mesh.n_cells == 27 and abs(_volume(mesh) - _volume(ref)) < 1e-12 * _volume(ref)
    assert "could not be read" in mesh.meta["lost_data"]["message"]


@pytest.mark.parametrize("compressed", [False, True])
def test_mixed_runs_of_linear_cells_read_by_numpy_as_vtk_reads_them(tmp_path, compressed):
    """A VTU of hexahedra then tetrahedra (and a boundary triangle after them) is read by our numpy
    path (runs of one type: meshio's blocks), the same arrays as VTK's reader gives; types
    interleaved cell by cell (more runs than _MAX_RUNS) go to VTK's reader, with the same result."""
    pytest.importorskip("vtk")
    import vtk_corpus as vc

    from models.mesh.vtk_readers import read_vtk
    from models.mesh.vtu import read_vtu_simple

    p, h = vc.grid(5, 4, 4)
    h = np.asarray(h)
    five = np.array([[0, 1, 3, 4], [1, 2, 3, 6], [1, 4, 5, 6], [3, 4, 6, 7], [1, 3, 4, 6]])
    hexes, tets = h[:40], h[40:][:, five].reshape(-1, 4)  # (the other half in 5 tetrahedra each)
    cases = {
        "runs": [(12, hexes), (10, tets), (5, np.array([[0, 1, 5]]))],
        "interleaved": [
            b for i in range(40) for b in ((12, hexes[i : i + 1]), (10, tets[5 * i : 5 * i + 5]))
        ],
    }
    for name, blocks in cases.items():
        grid = vc.unstructured(np.asarray(p, dtype=float), blocks)
        path = vc.write_xml(tmp_path / f"{name}.vtu", grid, encode=compressed, compress=compressed)
        ours, theirs = read_mesh(str(path)), read_vtk(str(path), "xml")
        for key in ("points", "offsets", "connectivity", "cell_types"):
            assert np.array_equal(getattr(ours, key), getattr(theirs, key)), (name, key)
        simple = read_vtu_simple(str(path))  # (the common layout's path: one block per run)
        assert (simple is None) == (name == "interleaved")
        if simple is not None:
            assert [b.type for b in simple.cells] == ["hexahedron", "tetra", "triangle"]


def _zone(name: str, x0: float, tag: int | None) -> str:
    """A Tecplot FE zone of 2 x 2 quads at x0, with a cell-centred tag (or none)."""
    pts = [(x0 + i * 0.5, j * 0.5) for j in range(3) for i in range(3)]
    cells = [
        (j * 3 + i + 1, j * 3 + i + 2, (j + 1) * 3 + i + 2, (j + 1) * 3 + i + 1)
        for j in range(2)
        for i in range(2)
    ]
    where = ", VARLOCATION=([3]=CELLCENTERED)" if tag is not None else ""
    text = f'ZONE T="{name}", NODES=9, ELEMENTS=4, DATAPACKING=BLOCK, ZONETYPE=FEQUADRILATERAL{where}\n'
    text += " ".join(str(p[0]) for p in pts) + "\n" + " ".join(str(p[1]) for p in pts) + "\n"
    text += "" if tag is None else " ".join([str(tag)] * 4) + "\n"
    return text + "".join(" ".join(map(str, c)) + "\n" for c in cells)


@pytest.mark.parametrize(
    "tags, named",
    [
        ((2, 1), {1: "solid", 2: "fluid"}),  # the zones' tags in the other order than the zones
        ((7, 9), {7: "fluid", 9: "solid"}),  # tags that are not the zones' numbers
        ((None, None), {1: "fluid", 2: "solid"}),  # no tags: the zones are the groups
    ],
)
def test_zone_names_go_to_the_groups_their_cells_carry(tmp_path, tags, named):
    """Tecplot zone names (and a .vtm's block names, the same code) name the group that their cells
    carry where the file also has a tag array (gmsh:physical); they were matched by position: the
    first zone's name on group 1 whatever its cells held, or dropped."""
    pytest.importorskip("vtk")
    head = 'TITLE="t"\nVARIABLES="X","Y"' + (',"gmsh:physical"' if tags[0] is not None else "") + "\n"
    path = tmp_path / "zones.dat"
    path.write_text(head + _zone("fluid", 0.0, tags[0]) + _zone("solid", 1.0, tags[1]))
    mesh = read_mesh(str(path))
    names = mesh.meta["group_names"]
    assert {int(k): v for k, v in names.items()} == named
    left = mesh.points[:, 0] < 1.0  # (the fluid zone's cells: x in 0..1)
    centre = np.array(
        [
            mesh.points[mesh.connectivity[mesh.offsets[i] : mesh.offsets[i + 1]], 0].mean()
            for i in range(mesh.n_cells)
        ]
    )
    fluid_tag = next(k for k, v in named.items() if v == "fluid")
    assert set(mesh.tags[centre < 1.0].tolist()) == {fluid_tag} and left.any()


def test_meshio_s_cgns_layout_is_read_with_meshio(tmp_path):
    """meshio's CGNS writer makes plain HDF5 groups (Base/Zone1/...) without CGNS's labels: VTK's
    reader refuses them ("not enough bases"), meshio reads them back, and so do we now."""
    pytest.importorskip("h5py")
    from meshes import tets as tet_box

    pts, tets = tet_box(3)
    path = tmp_path / "box.cgns"
    meshio.write(str(path), meshio.Mesh(pts, [("tetra", tets)]))
    mesh = read_mesh(str(path))
    meshio.write(str(tmp_path / "box.vtu"), meshio.Mesh(pts, [("tetra", tets)]))
    ref = read_mesh(str(tmp_path / "box.vtu"))
    assert mesh.n_cells == len(tets) and abs(_volume(mesh) - _volume(ref)) < 1e-12 * _volume(ref)

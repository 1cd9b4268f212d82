"""gmsh's own files that meshio's gmsh readers refuse (models/mesh/gmsh_native.py): partitioned
meshes (MSH 4.1 ascii and binary, MSH 2.2), MSH 4.0, Mesh.SaveAll beside physical groups, a
partitioned quadratic mesh; each written by gmsh itself at test time and checked against the same
model written plainly and read by meshio: cells, points, volume, physical groups. The CLI reads
them in the sandbox (gmsh's library is native code); a corrupted one keeps meshio's refusal."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from models.errors import MeshError
from models.mesh.read import NativeReaderNeeded, read_mesh
from models.mesh.sandbox import read_mesh_cli

gmsh = pytest.importorskip("gmsh")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def write(
    path, dim=3, part=0, version=4.1, binary=False, saveall=False, order=1, recombine=False, ghosts=False
):
    """A box (3D: volume group 7 'body', one face group 8 'inlet') or a two-material square (2D:
    groups 5 'left' and 6 'right'), meshed and written by gmsh with these options."""
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("m")
        occ = gmsh.model.occ
        if dim == 3:
            occ.addBox(0, 0, 0, 1, 1, 0.5)
            occ.synchronize()
            gmsh.model.addPhysicalGroup(3, [1], 7, name="body")
            gmsh.model.addPhysicalGroup(2, [1], 8, name="inlet")
        else:
            occ.addRectangle(0, 0, 0, 0.5, 1)
            occ.addRectangle(0.5, 0, 0, 0.5, 1)
            occ.fragment([(2, 1)], [(2, 2)])
            occ.synchronize()
            gmsh.model.addPhysicalGroup(2, [1], 5, name="left")
            gmsh.model.addPhysicalGroup(2, [2], 6, name="right")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.12)
        if recombine:  # (2D) the right material in quads, the left in triangles
            gmsh.model.mesh.setRecombine(2, 2)
        gmsh.model.mesh.generate(dim)
        if order > 1:
            gmsh.model.mesh.setOrder(order)
        if part:
            gmsh.option.setNumber("Mesh.PartitionCreateGhostCells", int(ghosts))
            gmsh.model.mesh.partition(part)
        gmsh.option.setNumber("Mesh.MshFileVersion", version)
        gmsh.option.setNumber("Mesh.Binary", int(binary))
        gmsh.option.setNumber("Mesh.SaveAll", int(saveall))
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return str(path)


def summary(mesh):
    groups = {int(t): float(mesh.meta["measures"][mesh.tags == t].sum()) for t in np.unique(mesh.tags)}
    return mesh.n_cells, mesh.n_points, float(mesh.meta["measures"].sum()), groups


VARIANTS = {
    "partitioned-4.1": {"part": 4},
    "partitioned-4.1-binary": {"part": 4, "binary": True},
    "partitioned-2.2": {"part": 3, "version": 2.2},
    "partitioned-ghosts": {"part": 3, "ghosts": True},  # (ghost cells: copies of neighbours' cells)
    "msh-4.0": {"version": 4.0},
    "msh-1.0": {"version": 1.0},  # ($NOD / $ELM: the tags, no group names in the format)
    "saveall": {"saveall": True},
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
@pytest.mark.parametrize("dim", [3, 2])
def test_gmsh_files_meshio_refuses_read_as_the_plain_file(tmp_path, variant, dim):
    opts = dict(VARIANTS[variant], recombine=dim == 2)
    plain = read_mesh(write(tmp_path / "plain.msh", dim, recombine=dim == 2))
    assert plain.meta.get("reader") != "gmsh's library (models/mesh/gmsh_native.py)"  # meshio's
    path = write(tmp_path / f"{variant}.msh", dim, **opts)
    mesh = read_mesh(path)
    n, p, vol, groups = summary(mesh)
    n0, p0, vol0, groups0 = summary(plain)
    assert (n, p) == (n0, p0)
    assert vol == pytest.approx(vol0, rel=1e-12)
    assert groups.keys() == groups0.keys() and all(groups[g] == pytest.approx(groups0[g]) for g in groups)
    if variant != "msh-1.0":
        assert mesh.meta["group_names"] == plain.meta["group_names"]
    if dim == 2:
        assert sorted(np.unique(mesh.cell_types).tolist()) == [5, 9]  # triangles and quads
    assert read_mesh_cli(path).n_cells == n0  # the CLI's way: in the sandbox


def test_a_partitioned_quadratic_mesh_is_read_on_its_corners(tmp_path):
    path = write(tmp_path / "o2.msh", 3, part=3, order=2)
    plain = read_mesh(write(tmp_path / "plain.msh", 3))
    mesh = read_mesh(path)
    assert mesh.n_cells == plain.n_cells
    assert float(mesh.meta["measures"].sum()) == pytest.approx(float(plain.meta["measures"].sum()), rel=1e-12)
    assert "agglomerated on their 4 corner nodes" in mesh.meta["higher_order"]


def test_gmsh_library_only_in_the_sandbox_from_the_cli(tmp_path):
    """In-process (native=False, the CLI's first try) a file that needs gmsh's library is handed
    on (NativeReaderNeeded), never read by native code in the CLI's own process; `magnet
    agglomerate` then reads and agglomerates it."""
    path = write(tmp_path / "part.msh", 3, part=4)
    with pytest.raises(NativeReaderNeeded):
        read_mesh(path, native=False)
    out = tmp_path / "out.vtu"
    r = subprocess.run(
        [sys.executable, "-m", "models.cli", "agglomerate", path, "--k", "6", "-o", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert out.exists() and "6 elements" in r.stdout


def test_a_corrupted_partitioned_file_keeps_the_refusal_with_its_place(tmp_path):
    """A partitioned file with a node id beyond its nodes: our scan of its sections finds the place,
    so gmsh's library is not tried, and the refusal says where."""
    path = write(tmp_path / "part.msh", 3, part=2)
    text = open(path).read().splitlines()
    start = text.index("$Elements")
    line = start + 3  # the first element line of the first block
    ids = text[line].split()
    ids[-1] = "999999"
    text[line] = " ".join(ids)
    bad = tmp_path / "bad.msh"
    bad.write_text("\n".join(text) + "\n")
    with pytest.raises(MeshError) as err:
        read_mesh(str(bad))
    msg = str(err.value)
    assert "bad.msh" in msg and "gmsh" in msg and "line" in msg, msg


@pytest.mark.parametrize("ext", [".inp", ".su2", ".med"])
def test_groups_of_gmsh_exports_keep_their_names(tmp_path, ext):
    """The same model exported by gmsh as Abaqus (*ELSET sets), SU2 (MARKER_TAG markers) and MED
    (families of groups): the groups and boundary groups, with their names and sizes, are those of
    the .msh file. Before, none were read from .inp and .su2 (meshio keeps them apart from a tag
    array, and drops the markers' names), and MED gave its family numbers (-1 ... -7)."""
    if ext == ".med":
        pytest.importorskip("h5py")
    msh = read_mesh(write(tmp_path / "box.msh", 3))
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.merge(str(tmp_path / "box.msh"))
        gmsh.write(str(tmp_path / f"box{ext}"))
    finally:
        gmsh.finalize()
    mesh = read_mesh(str(tmp_path / f"box{ext}"))
    assert mesh.n_cells == msh.n_cells

    def named(m, tags, names):
        return {names[int(t)]: int(np.count_nonzero(tags == t)) for t in np.unique(tags) if int(t) in names}

    assert (
        named(mesh, mesh.boundary_tags, mesh.meta["boundary_names"])
        == named(msh, msh.boundary_tags, msh.meta["boundary_names"])
        == {"inlet": named(msh, msh.boundary_tags, msh.meta["boundary_names"])["inlet"]}
    )
    if ext != ".su2":  # (SU2 has no volume groups)
        assert sorted(mesh.meta["group_names"].values()) == ["body"]


def _quadratic_with_boundary(path, dim):
    """A model of order 2 with a volume (surface) group and a boundary group 'inlet' of one face
    (edge) and 'walls' of the rest, written by gmsh as `path` and as MSH beside it."""
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        occ = gmsh.model.occ
        occ.addBox(0, 0, 0, 1, 0.8, 0.6) if dim == 3 else occ.addRectangle(0, 0, 0, 1, 0.8)
        occ.synchronize()
        gmsh.model.addPhysicalGroup(dim, [1], 10, name="body")
        sides = [t for _, t in gmsh.model.getEntities(dim - 1)]
        gmsh.model.addPhysicalGroup(dim - 1, sides[:1], 20, name="inlet")
        gmsh.model.addPhysicalGroup(dim - 1, sides[1:], 21, name="walls")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.2)
        gmsh.model.mesh.generate(dim)
        gmsh.model.mesh.setOrder(2)
        gmsh.write(str(path))
        gmsh.write(str(path) + ".msh")
    finally:
        gmsh.finalize()
    return str(path)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("ext", [".inp", ".cgns"])
def test_quadratic_exports_keep_their_boundary_groups(tmp_path, ext, dim):
    """gmsh's order-2 exports: Abaqus numbers a 3-node line end, middle, end (T3D3), where VTK and
    meshio put the middle last, so its boundary edges matched no triangle's side (83 '1D cells are
    no edge of any 2D cell'); CGNS families were dropped silently for quadratic sections (TETRA_10,
    TRI_6, BAR_3). Both now have the .msh's groups, their names and sizes."""
    if ext == ".cgns":
        pytest.importorskip("h5py")
        pytest.importorskip("vtk")
    path = _quadratic_with_boundary(tmp_path / f"m{dim}{ext}", dim)
    msh = read_mesh(path + ".msh")
    mesh = read_mesh_cli(path) if ext == ".cgns" else read_mesh(path)

    def named(m, tags, names):
        return {names[int(t)]: int(np.count_nonzero(tags == t)) for t in np.unique(tags) if int(t) in names}

    want = named(msh, msh.boundary_tags, msh.meta["boundary_names"])
    assert set(want) == {"inlet", "walls"}
    assert named(mesh, mesh.boundary_tags, mesh.meta["boundary_names"]) == want
    assert sorted(mesh.meta["group_names"].values()) == ["body"]
    assert mesh.n_cells == msh.n_cells
    from models.mesh.check import mesh_report

    kinds = [i["kind"] for i in mesh_report(mesh)["issues"]]
    assert "mixed-dimension" not in kinds, kinds  # (every boundary edge a side of a cell)


def test_medit_of_order_two_is_refused_by_what_it_holds(tmp_path):
    """meshio's medit reader exits (SystemExit) on gmsh's order-2 keywords; the refusal names them
    and says what to do, not "corrupted"."""
    path = _quadratic_with_boundary(tmp_path / "m3.mesh", 3)
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    msg = str(err.value)
    assert "m3.mesh" in msg and "TetrahedraP2" in msg and "order 1" in msg, msg
    assert "corrupted" not in msg and "SystemExit" not in msg


def test_gmsh_nastran_export_without_begin_bulk(tmp_path):
    """gmsh's Nastran export is bulk data only (no BEGIN BULK line, which meshio's reader looks
    for first, and refused it): read as the bulk data it is."""
    msh = read_mesh(write(tmp_path / "box.msh", 3))
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.merge(str(tmp_path / "box.msh"))
        gmsh.write(str(tmp_path / "box.bdf"))
    finally:
        gmsh.finalize()
    assert b"BEGIN BULK" not in (tmp_path / "box.bdf").read_bytes()
    mesh = read_mesh(str(tmp_path / "box.bdf"))
    assert mesh.n_cells == msh.n_cells
    assert float(mesh.meta["measures"].sum()) == pytest.approx(float(msh.meta["measures"].sum()), rel=1e-5)


@pytest.mark.parametrize("binary", [True, False])
def test_a_cut_gmsh_file_is_said_to_be_truncated(tmp_path, binary):
    """A gmsh file cut short ends inside a section: said so, naming the section (outside sweep U:
    binary files cut at every tenth got "a section holds fewer or more numbers than its header
    announces")."""
    data = open(write(tmp_path / "whole.msh", 3, binary=binary), "rb").read()
    for frac in (0.3, 0.6, 0.9):
        cut = tmp_path / f"cut{int(frac * 10)}.msh"
        cut.write_bytes(data[: int(len(data) * frac)])
        with pytest.raises(
            MeshError,
            match=rf"^cannot read {cut.name} as gmsh: the file ends inside its \$(Nodes|Elements) section \(no \$End(Nodes|Elements)\): it is truncated",
        ):
            read_mesh(str(cut))


def test_group_names_beyond_ascii_reach_the_output(tmp_path):
    """Group names with umlauts and spaces (outside sweep V: 'Stahl äußen' made `agglomerate`
    stop with an internal error: the VTU was written as ASCII). The output VTU is UTF-8, its names
    read back by VTK as given."""
    import vtk

    from models import agglomerate

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("m")
        occ = gmsh.model.occ
        occ.addRectangle(0, 0, 0, 0.5, 1)
        occ.addRectangle(0.5, 0, 0, 0.5, 1)
        occ.fragment([(2, 1)], [(2, 2)])
        occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [1], 5, name="Stahl äußen")
        gmsh.model.addPhysicalGroup(2, [2], 6, name="Wärme / soft")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.1)
        gmsh.model.mesh.generate(2)
        gmsh.write(str(tmp_path / "odd.msh"))
    finally:
        gmsh.finalize()
    res = agglomerate(str(tmp_path / "odd.msh"), model="metis", k=6, metrics=False)
    res.write(str(tmp_path / "out.vtu"))
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(tmp_path / "out.vtu"))
    r.Update()
    fd = r.GetOutput().GetFieldData()
    assert {fd.GetArrayName(i) for i in range(fd.GetNumberOfArrays())} >= {"Stahl äußen", "Wärme / soft"}


@pytest.mark.parametrize("version", [4.1, 2.2])
def test_cells_in_two_physical_groups_go_to_the_smaller(tmp_path, version):
    """A surface in both "all" and "inclusion" (outside sweep V): MSH 4.1 lists both groups for the
    entity (meshio kept the first: "inclusion" was lost without a word), MSH 2.2 writes those
    triangles twice (refused as "not a manifold"). Each cell once, in the smaller group, said."""
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("m")
        occ = gmsh.model.occ
        occ.addRectangle(0, 0, 0, 1, 1)
        occ.addDisk(0.5, 0.5, 0, 0.2, 0.2)
        occ.fragment([(2, 1)], [(2, 2)])
        occ.synchronize()
        surfaces = [t for _, t in gmsh.model.getEntities(2)]
        disk = min(surfaces, key=lambda t: gmsh.model.occ.getMass(2, t))
        gmsh.model.addPhysicalGroup(2, surfaces, 1, name="all")
        gmsh.model.addPhysicalGroup(2, [disk], 2, name="inclusion")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.08)
        gmsh.model.mesh.generate(2)
        n_disk = len(gmsh.model.mesh.getElements(2, disk)[1][0])
        n_all = sum(len(gmsh.model.mesh.getElements(2, t)[1][0]) for t in surfaces)
        gmsh.option.setNumber("Mesh.MshFileVersion", version)
        gmsh.write(str(tmp_path / "m.msh"))
    finally:
        gmsh.finalize()
    mesh = read_mesh(str(tmp_path / "m.msh"))
    assert mesh.n_cells == n_all
    names = {n: t for t, n in mesh.meta["group_names"].items()}
    assert set(names) == {"all", "inclusion"}
    assert int(np.count_nonzero(mesh.tags == names["inclusion"])) == n_disk
    assert int(np.count_nonzero(mesh.tags == names["all"])) == n_all - n_disk
    assert "each is kept once, in the smallest of them" in mesh.meta["overlapping_groups"]


def test_physical_tag_zero_is_no_group(tmp_path):
    """gmsh's MSH 2.2 writes physical tag 0 for what it saves outside any group (Mesh.SaveAll):
    no group "0", and its edges no boundary group "0" (outside sweep V: the output's boundary
    tag became 0 instead of the default)."""
    path = write(tmp_path / "all.msh", 2, version=2.2, saveall=True)
    import meshio

    raw = meshio.read(path)
    assert all(not np.asarray(t).any() for t in raw.cell_data["gmsh:physical"])  # (gmsh wrote 0s only)
    mesh = read_mesh(path)
    assert mesh.tags is None and mesh.meta["boundary_names"] == {}
    assert mesh.boundary_tags is None or not np.any(mesh.boundary_tags == 0)

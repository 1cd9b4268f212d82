"""The format families beyond VTK's own writers (Exodus II, XDMF + HDF5 and an XDMF time series,
CGNS, Gambit neutral, binary AVS UCD, Fluent mesh), each file written at test time
(tests/format_writers.py), read by our dispatch and checked against VTK's own reading of the same
file: number of cells and total volume (1e-9 relative: planar faces), then agglomerated and our
output VTU, read back by VTK, holding the same volume.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")
import format_writers as fw  # noqa: E402
import vtk_corpus as vc  # noqa: E402

from models import pipeline  # noqa: E402
from models.errors import MeshError  # noqa: E402
from models.mesh.read import pick_reader, read_mesh  # noqa: E402

TOL = 1e-9


def _exodus(tmp, ext):
    pytest.importorskip("netCDF4")
    p, blocks = fw.blocks()
    return fw.write_exodus(tmp / f"blocks{ext}", p, blocks)


def _xdmf(tmp):
    p, blocks = fw.blocks()
    return fw.write_xdmf(tmp / "mesh.xdmf", p, blocks)


def _cgns(tmp):
    p, blocks = fw.blocks(4, 2, 2)
    hexes = blocks[0][1]
    zones = [(zp, [("hexahedron", zc)]) for zp, zc in fw.split_zones(p, hexes)]
    # a third zone of two blocks (hexahedra and wedges) on top
    tp, tblocks = fw.blocks(2, 2, 2)
    zones.append((tp + [0.0, 0.0, 10.0], tblocks))
    return fw.write_cgns(tmp / "zones.cgns", zones)


def _gambit(tmp):
    p, blocks = fw.blocks()
    return fw.write_gambit(tmp / "mesh.neu", p, blocks)


def _avs(tmp):
    p, blocks = fw.blocks()
    return fw.write_avs_binary(tmp / "mesh.inp", p, blocks)


def _fluent(tmp):
    p, h = fw.grid(3, 2, 2)
    return fw.write_fluent(tmp / "case.msh", p, h)


CASES = {
    "exodus-exo": lambda t: _exodus(t, ".exo"),
    "exodus-e": lambda t: _exodus(t, ".e"),
    "xdmf-hdf5": _xdmf,
    "cgns-zones": _cgns,
    "gambit-neu": _gambit,
    "avs-binary": _avs,
    "fluent-msh": _fluent,
}
FAMILY = {
    "exodus-exo": "exodus", "exodus-e": "exodus", "xdmf-hdf5": "xdmf", "cgns-zones": "cgns",
    "gambit-neu": "gambit", "avs-binary": "avs-binary", "fluent-msh": "fluent",
}  # fmt: skip


def _total(mesh) -> float:
    return float(np.abs(mesh.meta["measures"]).sum())


def _agglomerated_volume(mesh, path: str, k: int = 3) -> tuple[int, float]:
    """Agglomerate with METIS, write our VTU and read it back with VTK: (cells, volume)."""
    out = path + ".out.vtu"
    res = pipeline.run(mesh, model="metis", mode="kway", k=k, compute_metrics=False)
    pipeline.write_outputs(res, vtu=out)
    return vc.vtk_reference(out)


@pytest.mark.parametrize("name", sorted(CASES))
def test_family_matches_vtk_and_agglomerates(tmp_path, name):
    path = CASES[name](tmp_path)
    assert pick_reader(path) == ("vtk", FAMILY[name])
    n_ref, vol_ref = vc.vtk_reference(path)
    mesh = read_mesh(path)
    assert mesh.n_cells == n_ref
    assert _total(mesh) == pytest.approx(vol_ref, rel=TOL)
    n_out, vol_out = _agglomerated_volume(mesh, path)
    assert n_out >= 3
    assert vol_out == pytest.approx(vol_ref, rel=TOL)


def test_exodus_blocks_become_groups(tmp_path):
    path = _exodus(tmp_path, ".exo")
    mesh = read_mesh(path)
    types = mesh.cell_type_counts()
    assert set(types) == {"hexahedron", "wedge"}, types
    assert len(mesh.physical_groups()) == 2


def test_an_exodus_file_numbered_from_zero_is_refused_not_shifted(tmp_path):
    """Exodus II numbers nodes from 1; a file whose connect arrays start at 0 (a hand-rolled writer)
    was read with every node shifted by one (folded cells, a wrong volume, exit 0): now refused in
    one sentence (outside sweep X)."""
    import netCDF4

    path = _exodus(tmp_path, ".e")
    with netCDF4.Dataset(path, "a") as nc:
        for name in [v for v in nc.variables if v.startswith("connect")]:
            nc.variables[name][:] = nc.variables[name][:] - 1
    with pytest.raises(MeshError, match=r"numbers the nodes from 0, but Exodus II numbers them from 1"):
        read_mesh(path)


def test_exodus_side_sets_become_named_boundary_groups(tmp_path):
    """Side sets (Cubit's and MOOSE's boundary conditions) are boundary groups with their names,
    element block names name the physical groups; a side set on the faces between two blocks is an
    interface (check says so), and the file agglomerates."""
    pytest.importorskip("netCDF4")
    from models.mesh.check import check_file

    p, hexes = vc.grid(4, 3, 2)
    i = np.arange(len(hexes)) % 4  # x index (x runs fastest)
    path = fw.write_exodus(
        tmp_path / "sets.exo", p, [("hexahedron", hexes[i < 2]), ("hexahedron", hexes[i >= 2])]
    )
    first = np.arange(int((i < 2).sum()))  # the first block's cells, in file order
    x = np.concatenate([i[i < 2], i[i >= 2]])
    # Exodus' hexahedron sides: 4 is (1, 5, 8, 4), x-min for VTK's node order; 2 is (2, 3, 7, 6), x-max
    fw.add_exodus_sets(
        path,
        side_sets=[
            ("inlet", 11, np.flatnonzero(x == 0), 4),
            ("outlet", 12, np.flatnonzero(x == 3), 2),
            ("interface", 13, first[x[first] == 1], 2),
        ],
        block_names=["steel", "copper"],
    )
    mesh = read_mesh(path)
    assert mesh.n_cells == len(hexes)
    assert sorted(mesh.meta["group_names"].values()) == ["copper", "steel"]
    names = mesh.meta["boundary_names"]
    assert sorted(names.values()) == ["inlet", "interface", "outlet"]
    by_name = {n: int(np.count_nonzero(mesh.boundary_tags == t)) for t, n in names.items()}
    assert by_name == {"inlet": 6, "outlet": 6, "interface": 6}
    rep = check_file(path)
    assert "6 tagged faces lie inside the domain" in " ".join(i["message"] for i in rep["issues"])
    n_ref, vol_ref = vc.vtk_reference(path)
    n_out, vol_out = _agglomerated_volume(mesh, path)
    assert vol_out == pytest.approx(vol_ref, rel=TOL)


def test_structured_cgns_zones_are_one_mesh(tmp_path):
    """Two structured CGNS zones side by side (a multi-block grid): hexahedra from each zone's
    dimensions, the points of the face they share merged (one piece), the zones the groups; volume
    as VTK reads it; agglomerated and read back."""
    pytest.importorskip("h5py")
    from models.mesh.check import check_file

    def block(x0, x1, n=(5, 4, 3)):
        x, y, z = np.meshgrid(
            np.linspace(x0, x1, n[0]), np.linspace(0, 1, n[1]), np.linspace(0, 0.5, n[2]), indexing="ij"
        )
        return x + 0.1 * y, y, z

    path = fw.write_cgns_structured(tmp_path / "blocks.cgns", [block(0, 1), block(1, 2)])
    n_ref, vol_ref = vc.vtk_reference(path)
    mesh = read_mesh(path)
    assert (mesh.n_cells, mesh.n_points) == (n_ref, 2 * 60 - 12) and n_ref == 48
    assert _total(mesh) == pytest.approx(vol_ref, rel=TOL)
    assert len(mesh.physical_groups()) == 2 and check_file(path)["components"] == 1
    n_out, vol_out = _agglomerated_volume(mesh, path)
    assert vol_out == pytest.approx(vol_ref, rel=TOL)


def test_dolfinx_xdmf_tags_are_groups(tmp_path):
    """dolfinx's XDMF (its mesh, then a grid of cell tags and a grid of facet tags, the geometry
    shared by xi:include): the cell tags are the physical groups, the facet tags the boundary
    groups (the tags grid, a repeat of the mesh's cells, is read once)."""
    pytest.importorskip("h5py")
    p, hexes = vc.grid(3, 3, 3)
    six = np.array([[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]])
    tets = hexes[:, six].reshape(-1, 4)
    x = (p @ np.linalg.inv(vc.A).T)[:, 0]  # the grid's own x (the points are an affine image)
    cell_tags = np.where(x[tets].mean(axis=1) < 1.5, 1, 2)
    faces = tets[:, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]].reshape(-1, 3)
    xmin = faces[np.all(np.abs(x[faces]) < 1e-9, axis=1)]  # the x = 0 side: 2 triangles per square
    assert len(xmin) == 18
    path = fw.write_xdmf_dolfinx(tmp_path / "mesh.xdmf", p, tets, cell_tags, xmin, np.full(len(xmin), 3))
    n_ref, vol_ref = vc.vtk_reference(fw.write_xdmf(tmp_path / "plain.xdmf", p, [("tetra", tets)]))
    assert vc.vtk_reference(path)[0] == 2 * n_ref  # (VTK draws the tags' grid too: the cells twice)
    mesh = read_mesh(path)
    assert mesh.n_cells == len(tets) == n_ref
    assert _total(mesh) == pytest.approx(vol_ref, rel=TOL)
    assert sorted(mesh.physical_groups()) == [1, 2]
    assert [int(np.count_nonzero(mesh.tags == g)) for g in (1, 2)] == [
        int(np.count_nonzero(cell_tags == g)) for g in (1, 2)
    ]
    assert int(np.count_nonzero(mesh.boundary_tags == 3)) == 18


def test_dolfinx_2d_facet_tags_are_boundary_groups(tmp_path):
    """dolfinx's 2D XDMF writes its facets as PolyLine of two points (outside sweep V: ignored, no
    boundary group): they are edges, the boundary groups."""
    pytest.importorskip("h5py")
    p, q = vc.quad_grid(6, 4)
    tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    x = (p[:, :2] @ np.linalg.inv(vc.A[:2, :2]).T)[:, 0]  # the grid's own x (an affine image)
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    left = np.unique(np.sort(edges[np.all(np.abs(x[edges] - x.min()) < 1e-9, axis=1)], axis=1), axis=0)
    assert len(left) == 4
    cell_tags = np.where(x[tris].mean(axis=1) < np.median(x), 1, 2)
    path = fw.write_xdmf_dolfinx(
        tmp_path / "mesh.xdmf", p[:, :2], tris, cell_tags, left, np.full(len(left), 7)
    )
    mesh = read_mesh(path)
    assert mesh.dim == 2 and mesh.n_cells == len(tris)
    assert sorted(mesh.physical_groups()) == [1, 2]
    assert int(np.count_nonzero(mesh.boundary_tags == 7)) == 4


def test_ensight_cases_read_with_their_parts(tmp_path):
    """EnSight Gold (ParaView opens it; Fluent, CFX and STAR-CCM+ export it): VTK's own binary
    writer's case, and an ASCII case of a volume part and a surface part (each part its own
    coordinates): the volume part a named group, the surface part a named boundary group, the
    parts' shared points merged; cells and volume as VTK reads them. A case naming a file outside
    its folder is refused before any reader opens it."""
    from vtkmodules.vtkIOEnSight import vtkGenericEnSightReader

    from models.mesh.check import check_file

    def vtk_volume(case):
        r = vtkGenericEnSightReader()
        r.SetCaseFileName(case)
        r.Update()
        block = r.GetOutput().GetBlock(0)
        out = tmp_path / "vtk_part.vtu"
        w = vtk.vtkXMLUnstructuredGridWriter()
        w.SetFileName(str(out))
        w.SetInputData(block)
        assert w.Write() == 1
        return vc.vtk_reference(str(out))

    p, hexes = vc.grid(4, 3, 2)
    ug = vc.unstructured(p, [(12, hexes)])
    w = vtk.vtkEnSightWriter()
    w.SetInputData(ug)
    w.SetPath(str(tmp_path) + "/")
    w.SetBaseName("vtkw")
    w.SetTimeStep(0)
    w.Write()
    w.WriteCaseFile(1)
    case = str(tmp_path / "vtkw.0.case")
    n_ref, vol_ref = vtk_volume(case)
    mesh = read_mesh(case)
    assert mesh.n_cells == n_ref == len(hexes) and _total(mesh) == pytest.approx(vol_ref, rel=TOL)

    x = (p @ np.linalg.inv(vc.A).T)[:, 0]
    faces = hexes[:, [0, 4, 7, 3]][np.arange(len(hexes)) % 4 == 0]  # the x = 0 side's quads
    assert np.all(np.abs(x[faces]) < 1e-9)
    case = fw.write_ensight(tmp_path, "two", p, [("fluid", "hexa8", hexes), ("inlet", "quad4", faces)])
    mesh = read_mesh(case)
    n_ref, vol_ref = vtk_volume(case)
    assert (mesh.n_cells, mesh.n_points) == (len(hexes), len(p))
    assert _total(mesh) == pytest.approx(vol_ref, rel=TOL)
    assert sorted(mesh.meta["group_names"].values()) == ["fluid"]
    names = mesh.meta["boundary_names"]
    assert [names[int(t)] for t in np.unique(mesh.boundary_tags) if int(t) in names] == ["inlet"]
    assert int(np.count_nonzero(mesh.boundary_tags == next(iter(names)))) == len(faces)
    assert check_file(case)["components"] == 1
    bad = tmp_path / "bad.case"
    bad.write_text("FORMAT\ntype: ensight gold\n\nGEOMETRY\nmodel: ../../etc/passwd\n")
    with pytest.raises(MeshError, match="lies outside"):
        read_mesh(str(bad))


def test_xdmf_time_series_gives_its_mesh_once(tmp_path):
    """meshio's TimeSeriesWriter writes the mesh once and a grid per time step (all referring to
    it): the mesh is read once, as the plain XDMF file of the same mesh."""
    p, blocks = fw.blocks()
    series = fw.write_xdmf_series(tmp_path / "series.xdmf", p, blocks, steps=3)
    assert os.path.exists(tmp_path / "series.h5")
    plain = fw.write_xdmf(tmp_path / "plain.xdmf", p, blocks)
    n_ref, vol_ref = vc.vtk_reference(plain)
    mesh = read_mesh(series)
    assert mesh.n_cells == n_ref
    assert _total(mesh) == pytest.approx(vol_ref, rel=TOL)
    n_out, vol_out = _agglomerated_volume(mesh, series)
    assert vol_out == pytest.approx(vol_ref, rel=TOL)


def test_multiblock_volume_with_an_unrelated_planar_block(tmp_path):
    """A .vtm holding a volume block and a 2D block whose cells are no face of it (elsewhere, or a
    single quad): the 2D cells are ignored with a notice and the volume agglomerates (the 2D block
    once made the boundary-group matching index an empty selection: a traceback)."""
    from models.mesh.check import check_file

    p3, h3 = vc.grid(6, 5, 4)
    p2, q2 = vc.quad_grid(8, 8)
    vol_ref = vc.vtk_reference(vc.write_xml(str(tmp_path / "hex.vtu"), vc.unstructured(p3, [(12, h3)])))[1]
    for name, second in (
        ("far", vc.unstructured(p2 + 50.0, [(9, q2)])),
        ("one", vc.unstructured(p2, [(9, q2[:1])])),
    ):
        mb = vtk.vtkMultiBlockDataSet()
        mb.SetNumberOfBlocks(2)
        mb.SetBlock(0, vc.unstructured(p3, [(12, h3)]))
        mb.SetBlock(1, second)
        w = vtk.vtkXMLMultiBlockDataWriter()
        path = str(tmp_path / f"{name}.vtm")
        w.SetFileName(path)
        w.SetInputData(mb)
        assert w.Write() == 1
        _, n_out, vol_out = vc.agglomerate_read_back(path, 4, tmp_path / f"{name}.vtu")
        assert n_out == 4 and vol_out == pytest.approx(vol_ref, rel=TOL)
        report = check_file(path)
        assert report["verdict"] == "warnings"
        assert any("no face of any 3D cell" in i["message"] for i in report["issues"])


@pytest.mark.parametrize("family", [10, 5])
def test_vtkhdf_reads_as_vtk_writes_it(tmp_path, family):
    """VTKHDF (ParaView reads it; VTK's vtkHDFWriter writes it): read by VTK's vtkHDFReader, the
    cells and the measure of the same grid written as VTU, agglomerated."""
    if not hasattr(vtk, "vtkHDFWriter"):
        pytest.skip("this vtk wheel has no vtkHDFWriter")
    p, cells = vc.linear_cells(family)
    ug = vc.unstructured(p, [(family, cells)])
    n_ref, vol_ref = vc.vtk_reference(vc.write_xml(str(tmp_path / "ref.vtu"), ug))
    w = vtk.vtkHDFWriter()
    path = str(tmp_path / "grid.vtkhdf")
    w.SetFileName(path)
    w.SetInputData(ug)
    assert w.Write() == 1
    assert pick_reader(path) == ("vtk", "vtkhdf")
    mesh = read_mesh(path)
    assert mesh.n_cells == n_ref and _total(mesh) == pytest.approx(vol_ref, rel=TOL)
    n_out, vol_out = _agglomerated_volume(mesh, path)
    assert vol_out == pytest.approx(vol_ref, rel=TOL)


def test_xdmf_heavy_data_missing_or_outside_is_named(tmp_path):
    """XDMF names its HDF5 files: a missing one is named; one outside the file's folder (absolute,
    or up with '..') is refused before VTK's reader opens it."""
    p, blocks = fw.blocks()
    path = fw.write_xdmf(tmp_path / "a.xdmf", p, blocks)
    text = open(path).read()
    assert "a.h5:" in text
    for name, heavy, words in (
        ("gone.xdmf", "gone.h5", "is missing"),
        ("up.xdmf", "../a.h5", "lies outside"),
        ("abs.xdmf", "/etc/secret.h5", "lies outside"),
    ):
        bad = tmp_path / name
        bad.write_text(text.replace("a.h5:", heavy + ":"))
        with pytest.raises(MeshError, match=words) as err:
            read_mesh(str(bad))
        assert name in str(err.value) and heavy in str(err.value)


def test_xdmf_binary_and_included_files_outside_are_refused(tmp_path):
    """An XDMF taken alone over HTTP (its data may be inline) names files by more than HDF5
    references: a Binary data item's file, an xi:include's href, an HDF file of any name. One outside
    the file's folder is refused before VTK's reader opens it (an upload never reads a server file)."""
    p, blocks = fw.blocks()
    text = open(fw.write_xdmf(tmp_path / "a.xdmf", p, blocks)).read()
    binary = '<DataItem Dimensions="3" NumberType="Float" Format="Binary">/etc/hostname</DataItem>'
    include = '<xi:include href="../other.xmf" xpointer="xpointer(//Xdmf/Domain/Grid)"/>'
    odd_hdf = '<DataItem Dimensions="3" Format="HDF">/srv/data/mesh.dat:/coords</DataItem>'
    for name, extra, named in (
        ("bin.xdmf", binary, "/etc/hostname"),
        ("inc.xdmf", include, "../other.xmf"),
        ("hdf.xdmf", odd_hdf, "/srv/data/mesh.dat"),
    ):
        bad = tmp_path / name
        bad.write_text(text.replace("<Domain>", "<Domain>" + extra, 1))
        with pytest.raises(MeshError, match="lies outside") as err:
            read_mesh(str(bad))
        assert name in str(err.value) and named in str(err.value)


def test_ensight_mutants_are_a_mesh_or_one_clear_sentence(tmp_path):
    """The mutation test (tests/mutants.py) over an ASCII EnSight geometry file, read in the sandbox
    as the service reads: a Mesh, or one sentence naming the case and the format with no library
    text; a crash or a hang of VTK's reader is a sentence too."""
    from mutants import mutants
    from test_read_fuzz import RAW_RE

    from models.errors import ParameterError
    from models.mesh.container import Mesh
    from models.mesh.sandbox import read_mesh_safe

    p, hexes = vc.grid(3, 2, 2)
    case = fw.write_ensight(tmp_path, "good", p, [("fluid", "hexa8", hexes)])
    data = (tmp_path / "good.geo").read_bytes()
    refused = 0
    for i, (how, bad) in enumerate(mutants(data, seed=4000, n=14)):
        (tmp_path / "good.geo").write_bytes(bad)
        try:
            mesh = read_mesh_safe(case, timeout_s=20, memory_bytes=2 << 30)
        except (MeshError, ParameterError) as exc:
            msg = str(exc)
            refused += 1
            assert "good.case" in msg and "EnSight" in msg, (i, how, msg)
            assert not RAW_RE.search(msg) and "\n" not in msg, (i, how, msg)
        else:
            assert isinstance(mesh, Mesh) and mesh.n_cells > 0
    assert refused >= 5


@pytest.mark.parametrize("keep", [0.5, 0.9])
def test_a_fluent_file_cut_short_is_said_to_be_truncated(tmp_path, keep):
    """A Fluent file is a sequence of parenthesised sections: cut short, it ends inside one. Said so
    (models.mesh.locate), in place of 'it is corrupted or not a Fluent case file' (outside sweep X)."""
    from models.mesh.sandbox import read_mesh_safe

    path = _fluent(tmp_path)
    data = open(path, "rb").read()
    cut = tmp_path / "cut.msh"
    cut.write_bytes(data[: int(len(data) * keep)].rstrip(b")\n "))
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(cut))
    msg = str(err.value)
    assert msg.startswith("cannot read cut.msh as Fluent") and msg.endswith("it is truncated"), msg
    assert "corrupted or not" not in msg, msg


def _classic_exodus(
    src, dst, elem_type=None, drop=None, per_el=None, extra_dims=(), short=False, fmt="NETCDF3_64BIT_OFFSET"
) -> str:
    """meshio's Exodus (netCDF-4) copied as netCDF classic (CDF-2, coordx/y/z, 32-bit ids, as Cubit
    and SEACAS write it; or as `fmt`: NETCDF4, HDF5), block 1 altered: its elem_type, its
    connectivity dropped, or its nodes per element cut to per_el."""
    import netCDF4

    with netCDF4.Dataset(src) as a, netCDF4.Dataset(dst, "w", format=fmt) as b:
        for name, d in a.dimensions.items():
            if d.isunlimited() and name != "time_step":
                continue  # (classic netCDF has one unlimited dimension)
            n = per_el if (per_el and name == "num_nod_per_el1") else (None if d.isunlimited() else len(d))
            b.createDimension(name, n)
        for name, n in extra_dims:
            b.createDimension(name, n)
        b.setncatts({k: a.getncattr(k) for k in a.ncattrs()})
        b.setncatts(  # (a large model's header, as SEACAS writes it)
            {"file_size": np.int32(1), "int64_status": np.int32(0), "maximum_name_length": np.int32(32)}
        )
        b.setncattr("floating_point_word_size", np.int32(8))
        b.createVariable("eb_status", "i4", ("num_el_blk",))[:] = 1
        for name, v in a.variables.items():
            if name == drop:
                continue
            data = v[:]
            if name == "coord":  # one variable per axis
                for axis, row in zip("xyz", data, strict=False):
                    b.createVariable(f"coord{axis}", "f8", ("num_nodes",))[:] = row
                continue
            dtype = "i4" if v.dtype.kind in "iu" else ("S1" if v.dtype == str else v.dtype)
            dims = v.dimensions
            if short and name == "connect1":  # one element fewer than the block declares
                b.createDimension("short_num_el_in_blk1", len(a.dimensions["num_el_in_blk1"]) - 1)
                dims = ("short_num_el_in_blk1", dims[1])
                data = data[:-1]
            w = b.createVariable(name, dtype, dims)
            attrs = {k: v.getncattr(k) for k in v.ncattrs() if k != "_FillValue"}
            if name == "connect1" and elem_type:
                attrs["elem_type"] = elem_type
            w.setncatts(attrs)
            w[:] = data[:, :per_el] if (per_el and name == "connect1") else data
    return str(dst)


@pytest.mark.parametrize(
    "change, said",
    [
        (
            {"elem_type": "FOOBAR"},
            "element block 1 has element type 'FOOBAR', which is not an Exodus II element type",
        ),
        ({"drop": "connect1"}, "has no connectivity (no variable connect1)"),
        ({"per_el": 7}, "with 7 nodes per element, which that type does not have (8, 9, 20, 27)"),
        (
            {"short": True},
            "connectivity (connect1) holds 88 node ids, fewer than its 12 elements of 8 nodes need (96)",
        ),
    ],
)
@pytest.mark.parametrize("fmt", ["NETCDF3_64BIT_OFFSET", "NETCDF4"])
def test_an_exodus_block_that_cannot_be_read_says_why(tmp_path, change, said, fmt):
    """VTK's reader crashes on an unknown element type and on a block of fewer nodes than its type
    (reading past the array), and says nothing useful on a missing connectivity: the header's
    blocks are checked first, in one sentence (outside sweep X). netCDF classic by our own header
    reader; netCDF-4 (HDF5) with h5py in the reading child (there it was "corrupted or not an
    Exodus II file", garbage point ids, or "numbered from 0")."""
    pytest.importorskip("netCDF4")
    from models.mesh.sandbox import read_mesh_safe

    p, h = fw.grid(3, 2, 2)
    src = fw.write_exodus(tmp_path / "hex.e", p, [("hexahedron", h)])
    good = _classic_exodus(src, tmp_path / "good.e", fmt=fmt)
    assert read_mesh(good).n_cells == len(h)  # the copy itself reads
    bad = _classic_exodus(src, tmp_path / "bad.e", fmt=fmt, **change)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(bad)
    msg = str(err.value)
    assert msg.startswith("cannot read bad.e as Exodus II: element block 1") and said in msg, msg


@pytest.mark.parametrize("keep", [0.3, 0.8])
def test_a_binary_ucd_file_cut_short_is_said_to_be_truncated(tmp_path, keep):
    """Its header declares how many nodes, cells and connectivity entries follow: a file shorter than
    that is refused as truncated, with both sizes (before: 'corrupted or not a binary AVS UCD file';
    outside sweep X). The whole file reads."""
    from models.mesh.sandbox import read_mesh_safe

    p, blocks = fw.blocks()
    path = fw.write_avs_binary(tmp_path / "m.inp", p, blocks, node_data=False)
    data = open(path, "rb").read()
    assert read_mesh(path).n_cells == sum(len(c) for _, c in blocks)
    cut = tmp_path / "cut.inp"
    cut.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(cut))
    msg = str(err.value)
    assert msg.startswith("cannot read cut.inp as binary AVS UCD: the file is truncated: it holds ") and (
        f"of the {len(data):,} its header's" in msg
    ), msg


def _nsided(path, counts, fmt="NETCDF3_64BIT_OFFSET") -> str:
    """A 2D Exodus II of one NSIDED block (a square and a triangle beside it) in netCDF classic,
    its ebepecnt1 (nodes per element) as given."""
    import netCDF4

    x, y = [0.0, 1.0, 1.0, 0.0, 2.0], [0.0, 0.0, 1.0, 1.0, 0.5]
    conn = [1, 2, 3, 4, 2, 5, 3]
    with netCDF4.Dataset(path, "w", format=fmt) as nc:
        nc.setncatts({"api_version": np.float32(8.03), "version": np.float32(8.03), "file_size": np.int32(1)})
        nc.setncattr("floating_point_word_size", np.int32(8))
        nc.setncatts({"maximum_name_length": np.int32(32), "int64_status": np.int32(0), "title": "nsided"})
        for name, n in (("len_string", 33), ("len_name", 33), ("four", 4), ("num_dim", 2), ("num_nodes", 5),
                        ("num_elem", 2), ("num_el_blk", 1), ("num_el_in_blk1", 2), ("num_nod_per_el1", 7)):  # fmt: skip
            nc.createDimension(name, n)
        nc.createDimension("time_step", None)
        nc.createVariable("time_whole", "f8", ("time_step",))
        nc.createVariable("coordx", "f8", ("num_nodes",))[:] = x
        nc.createVariable("coordy", "f8", ("num_nodes",))[:] = y
        nc.createVariable("eb_status", "i4", ("num_el_blk",))[:] = 1
        prop = nc.createVariable("eb_prop1", "i4", ("num_el_blk",))
        prop.setncattr("name", "ID")
        prop[:] = 1
        c = nc.createVariable("connect1", "i4", ("num_nod_per_el1",))
        c.setncattr("elem_type", "NSIDED")
        c[:] = conn
        nc.createVariable("ebepecnt1", "i4", ("num_el_in_blk1",))[:] = counts
    return str(path)


@pytest.mark.parametrize("fmt", ["NETCDF3_64BIT_OFFSET", "NETCDF4"])
def test_an_exodus_nsided_block_whose_counts_overrun_its_connectivity_is_named(tmp_path, fmt):
    """VTK's reader reads past the connectivity (a segmentation fault, or ids from past the array)
    when an NSIDED block's nodes per element add up to more than it holds (outside sweep X), in
    netCDF classic and netCDF-4."""
    pytest.importorskip("netCDF4")
    from models.mesh.sandbox import read_mesh_safe

    good = read_mesh(_nsided(tmp_path / "good.e", [4, 3], fmt))
    assert good.n_cells == 2 and float(good.meta["measures"].sum()) == pytest.approx(1.5, rel=1e-12)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(_nsided(tmp_path / "bad.e", [4, 9], fmt))
    assert str(err.value) == (
        "cannot read bad.e as Exodus II: element block 1 (NSIDED) gives its elements 13 nodes in all "
        "(ebepecnt1), but its connectivity holds 7"
    ), str(err.value)


def test_an_exodus_file_declaring_qa_records_it_lacks_is_read(tmp_path):
    """num_qa_rec declared, no qa_records variable: VTK's reader logs an error and reads the whole
    mesh; that error refused the file (outside sweep Y)."""
    pytest.importorskip("netCDF4")
    p, h = fw.grid(3, 2, 2)
    src = fw.write_exodus(tmp_path / "hex.e", p, [("hexahedron", h)])
    whole = read_mesh(_classic_exodus(src, tmp_path / "whole.e"))
    mesh = read_mesh(_classic_exodus(src, tmp_path / "qa.e", extra_dims=[("num_qa_rec", 1)]))
    assert mesh.n_cells == len(h)
    assert float(mesh.meta["measures"].sum()) == pytest.approx(float(whole.meta["measures"].sum()), rel=1e-12)


def test_a_binary_ucd_file_is_named_so_in_every_refusal(tmp_path):
    """.inp is Abaqus's and AVS's extension; a file starting with AVS's binary magic byte is named
    'binary AVS UCD' (it was 'Abaqus or AVS UCD'; mutation sweep Z)."""
    from models.mesh.formats import format_name

    p, blocks = fw.blocks()
    path = fw.write_avs_binary(tmp_path / "m.inp", p, blocks)
    assert format_name(path) == "binary AVS UCD"
    text = tmp_path / "t.inp"
    text.write_text("*NODE\n1, 0, 0, 0\n")
    assert format_name(text) == "Abaqus"  # (its keywords say so: sweep 47)
    text.write_text("# a comment\n1 0 0 0 0\n1 0 0 0\n")
    assert format_name(text) == "AVS UCD"
    text.write_text("neither\n")
    assert format_name(text) == "Abaqus or AVS UCD"


def test_xdmf_data_file_named_by_its_absolute_path_beside_it_is_read(tmp_path):
    """meshio writes a Binary XDMF's data files by absolute path: one that lies in the file's own
    folder is read (only paths elsewhere are refused)."""
    p, blocks = fw.blocks()
    path = fw.write_xdmf(tmp_path / "a.xdmf", p, blocks)
    text = open(path).read()
    absolute = tmp_path / "abs.xdmf"
    absolute.write_text(text.replace("a.h5:", str(tmp_path / "a.h5") + ":"))
    assert str(tmp_path / "a.h5") in absolute.read_text()
    assert read_mesh(str(absolute)).n_cells == read_mesh(path).n_cells


def test_wkt_with_exponents_reads_at_once(tmp_path):
    """meshio's WKT pattern knows no exponents and backtracked for minutes on a 3 KiB file of 48
    triangles with a coordinate like 6.1e-17 (an outside sweep's file): our reader takes each
    polygon's ring, merges equal points, and says what is wrong in one sentence."""
    xs, ys = np.meshgrid(np.linspace(0, 1, 8), np.linspace(0, 1, 7), indexing="ij")
    pts = np.c_[xs.ravel(), ys.ravel() + 1e-17, np.zeros(xs.size)]
    i, j = np.meshgrid(np.arange(7), np.arange(6), indexing="ij")
    a = (i * 7 + j).ravel()
    tri = np.r_[np.c_[a, a + 7, a + 8], np.c_[a, a + 8, a + 1]]

    def ring(t):
        return "((" + ", ".join(" ".join(repr(float(v)) for v in pts[k]) for k in [*t, t[0]]) + "))"

    path = tmp_path / "plate.wkt"
    path.write_text("TIN (" + ", ".join(ring(t) for t in tri) + ")")
    assert "e-17" in path.read_text()
    mesh = read_mesh(str(path))
    assert mesh.n_cells == 84 and mesh.n_points == 56 and mesh.dim == 2
    bad = tmp_path / "open.wkt"
    bad.write_text("TIN (((0 0 0, 1 0 0, 0 1 0, 0 0 1)))")
    with pytest.raises(MeshError, match=r"^cannot read open.wkt as WKT: 1 polygons are not closed"):
        read_mesh(str(bad))


def test_gmsh_med_without_physical_groups_reads(tmp_path):
    """gmsh's MED export of a mesh with no physical group writes families without groups (GRO);
    meshio's MED reader failed on every such file with KeyError('GRO')."""
    gmsh = pytest.importorskip("gmsh")
    path = str(tmp_path / "box.med")
    gmsh.initialize(["", "-v", "0"])
    try:
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.5)
        gmsh.model.mesh.generate(3)
        n = sum(len(t) for t in gmsh.model.mesh.getElements(3)[1])
        gmsh.write(path)
    finally:
        gmsh.finalize()
    mesh = read_mesh(path)
    assert mesh.dim == 3 and mesh.n_cells == n
    assert mesh.tags is None  # no group (not one group numbered 0)

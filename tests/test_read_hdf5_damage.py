"""HDF5 containers (CGNS, Exodus II in netCDF-4, Fluent .cas.h5, ...) with a damaged object: the
refusal names the object and its byte address (models.mesh.containers.hdf5_damage, run in a reading
child), whether VTK's reader failed on the file or crashed on it (then in another child, after the
crash). Before, both said "it is corrupted or not CGNS" (a mutation sweep of 150 CGNS files: 14
crashes, 103 vague refusals, and 12 of 26 reads holding half the cells: VTK's reader leaves a zone
whose metadata it cannot read out, without a word).
"""

from __future__ import annotations

import pytest

pytest.importorskip("vtk")
h5py = pytest.importorskip("h5py")
import format_writers as fw  # noqa: E402

from models.errors import MeshError  # noqa: E402
from models.mesh.sandbox import read_mesh_safe  # noqa: E402


def _cgns(tmp_path) -> str:
    p, blocks = fw.blocks(4, 2, 2)
    zones = [(zp, [("hexahedron", zc)]) for zp, zc in fw.split_zones(p, blocks[0][1])]
    return fw.write_cgns(tmp_path / "zones.cgns", zones)


def _damaged(src: str, dst, obj: str) -> tuple[str, int]:
    """A copy of src with one bit flipped inside the object header of `obj` (its checksum then
    fails), and that header's byte address."""
    parent, name = obj.rsplit("/", 1)
    with h5py.File(src, "r") as f:
        addr = h5py.h5o.get_info(f[parent or "/"].id, name.encode()).addr
    data = bytearray(open(src, "rb").read())
    assert data[addr : addr + 4] == b"OHDR"  # (version 2 object headers: with a checksum)
    data[addr + 12] ^= 0x40
    dst.write_bytes(bytes(data))
    return str(dst), addr


@pytest.mark.parametrize(
    "obj",
    [
        "/Base/Zone1/Elements0/ElementConnectivity",  # VTK's CGNS reader crashes (SIGSEGV) on this one
        "/Base/Zone1/GridCoordinates",  # VTK's reader fails with an error
        "/Base/Zone1",
    ],
)
def test_a_damaged_cgns_object_is_named_with_its_address(tmp_path, obj):
    src = _cgns(tmp_path)
    assert read_mesh_safe(src).n_cells > 0
    bad, addr = _damaged(src, tmp_path / "bad.cgns", obj)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(bad)
    msg = str(err.value)
    assert msg.startswith("cannot read bad.cgns as CGNS: "), msg
    assert msg.endswith(
        f"the HDF5 object '{obj}' (at byte {addr:,}) is damaged: its metadata fails its checksum"
    ), msg
    assert "corrupted or not" not in msg, msg


def test_a_zone_vtk_leaves_out_without_a_word_is_refused_not_lost(tmp_path):
    """ZoneType's header damaged: VTK's CGNS reader reads on, leaving the zone out (4 of 8 cells,
    no error), and so did we. A read of an HDF5 container is now followed by the walk over its
    metadata (in the reading child): the damaged object is named instead of half the mesh read."""
    src = _cgns(tmp_path)
    assert read_mesh_safe(src).n_cells == 8
    bad, addr = _damaged(src, tmp_path / "bad.cgns", "/Base/Zone1/ZoneType")
    import vtk

    r = vtk.vtkCGNSReader()
    r.SetFileName(bad)
    r.UpdateInformation()
    r.EnableAllBases()
    r.Update()
    it = r.GetOutput().NewIterator()
    it.InitTraversal()
    vtk_cells = 0
    while not it.IsDoneWithTraversal():
        vtk_cells += it.GetCurrentDataObject().GetNumberOfCells()
        it.GoToNextItem()
    assert vtk_cells == 4  # (VTK's own reading: one zone of two)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(bad)
    assert str(err.value) == (
        f"cannot read bad.cgns as CGNS: the HDF5 object '/Base/Zone1/ZoneType' (at byte {addr:,}) is "
        "damaged: its metadata fails its checksum"
    ), str(err.value)


def test_a_zone_type_cgns_does_not_have_is_named(tmp_path):
    """A byte flipped in ZoneType's text ('Unstrucuured'): VTK's reader leaves the zone out without
    a word; cgns_fault names it before VTK opens the file."""
    src = _cgns(tmp_path)
    data = open(src, "rb").read()
    at = data.index(b"Unstructured", data.index(b"Unstructured") + 1)  # (the second zone's)
    bad = tmp_path / "bad.cgns"
    bad.write_bytes(data[:at] + b"Unstrucuured" + data[at + 12 :])
    with h5py.File(bad, "r") as f:
        assert [bytes(f[f"/Base/{z}/ZoneType/ data"][()]) for z in ("Zone1", "Zone2")].count(
            b"Unstrucuured"
        ) == 1
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(bad))
    msg = str(err.value)
    assert msg.startswith("cannot read bad.cgns as CGNS: zone 'Zone") and msg.endswith(
        ": its zone type is 'Unstrucuured', which CGNS does not have (Structured or Unstructured)"
    ), msg


def test_a_damaged_netcdf4_exodus_variable_is_named(tmp_path):
    pytest.importorskip("netCDF4")
    p, blocks = fw.blocks()
    src = fw.write_exodus(tmp_path / "blocks.e", p, blocks)
    assert open(src, "rb").read(4) == b"\x89HDF"  # (meshio writes netCDF-4)
    bad, addr = _damaged(src, tmp_path / "bad.e", "/coord")
    with pytest.raises(MeshError) as err:
        read_mesh_safe(bad)
    assert str(err.value) == (
        f"cannot read bad.e as Exodus II: the HDF5 object '/coord' (at byte {addr:,}) is damaged: "
        "its metadata fails its checksum"
    ), str(err.value)


def test_an_hdf5_end_address_far_past_the_file_is_a_damaged_header(tmp_path):
    """A bit flipped high in the superblock's end-of-file address declared an exabyte file
    ("it holds 18,378 bytes of the 1,152,921,504,606,865,354 its header declares")."""
    src = _cgns(tmp_path)
    data = bytearray(open(src, "rb").read())
    at = {0: 40, 1: 44, 2: 28, 3: 28}[data[8]]  # the end-of-file address, by superblock version
    assert int.from_bytes(data[at : at + 8], "little") == len(data)
    data[at + 7] ^= 0x10  # (a high bit: 2^60 bytes more)
    bad = tmp_path / "bad.cgns"
    bad.write_bytes(bytes(data))
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(bad))
    msg = str(err.value)
    assert msg.startswith("cannot read bad.cgns as CGNS: its header declares ") and (
        f"far more than the {len(data):,} it holds: the header is damaged" in msg
    ), msg

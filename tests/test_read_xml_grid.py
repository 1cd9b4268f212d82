""".vts, .vtr and .vti files read by our numpy path (models/mesh/xml_grid.py): the same Mesh as VTK's
path (vtk_readers), field by field and bit for bit but for meta["reader"], in every data layout
VTK's writers write; the layouts it does not read left to VTK's reader (and still the same Mesh);
refusals in VTK's path's words or one sentence of ours; mutated files a Mesh or one sentence."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import vtk
import vtk_corpus as vc
from mutants import mutants
from test_read_fuzz import assert_sentence
from test_read_raw_answer import same
from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy

from models.errors import MeshError, ParameterError
from models.mesh import read, sandbox, xml_grid
from models.mesh.read import read_mesh

OURS = xml_grid.READER
# (data mode, zlib, base64-encoded appended data)
LAYOUTS = {
    "appended-base64": ("appended", False, True),
    "appended-raw": ("appended", False, False),
    "inline-binary": ("binary", False, True),
    "zlib": ("appended", True, True),
    "zlib-raw": ("appended", True, False),
    "zlib-inline": ("binary", True, True),
}
SHAPES = {"3d": ((5, 4, 3), (0, 0, 0)), "offset": ((4, 3, 5), (2, -3, 7)), "2d": ((5, 4, 1), (0, 0, 0))}
SHAPES["2d-xz"] = ((4, 1, 3), (1, 5, -2))


def dataset(kind: str, dims, start=(0, 0, 0), tagged: bool = False):
    """Image data, a structured or a rectilinear grid of dims points from `start`; tagged: a
    gmsh:physical cell array, other cell and point arrays, and field data (group names, a float
    array and a string array)."""
    ds = {"vti": vc.image, "vts": vc.structured_grid, "vtr": vc.rectilinear}[kind](dims)
    ds.SetExtent(*[v for a in range(3) for v in (start[a], start[a] + dims[a] - 1)])
    if tagged:
        n, dim = ds.GetNumberOfCells(), 3 if min(dims) > 1 else 2
        for name, values in (
            ("gmsh:physical", np.arange(n, dtype=np.int32) % 3 + 1),
            ("velocity", np.linspace(0.0, 1.0, 3 * n).reshape(n, 3)),
            ("quality", np.linspace(0.0, 1.0, n)),
        ):
            ds.GetCellData().AddArray(_named(numpy_to_vtk(values, deep=True), name))
        ds.GetPointData().AddArray(
            _named(numpy_to_vtk(np.arange(ds.GetNumberOfPoints(), dtype=float), deep=True), "u")
        )
        for name, values in (("inner", [1, dim]), ("scale", [0.5, 2.0]), ("wall", [2, dim - 1])):
            ds.GetFieldData().AddArray(_named(numpy_to_vtk(np.array(values), deep=True), name))
        note = vtk.vtkStringArray()
        note.SetName("note")
        note.InsertNextValue("written by a test")
        ds.GetFieldData().AddArray(note)
    return ds


def _named(array, name: str):
    array.SetName(name)
    return array


def write(path: Path, ds, layout: str = "appended-base64", **kw) -> Path:
    mode, zlib, encode = LAYOUTS[layout]
    return Path(vc.write_xml(path, ds, mode, compress=zlib, encode=encode, **kw))


def vtk_path(monkeypatch, path, **kw):
    """read_mesh through VTK's reader (our numpy path off): the Mesh, or the exception it raised."""
    with monkeypatch.context() as m:
        m.setattr(xml_grid, "read_xml_grid", lambda *a, **k: None)
        try:
            return read_mesh(path, **kw)
        except (MeshError, ParameterError) as exc:
            return exc


def assert_same_as_vtk(monkeypatch, path, reader: str = OURS, **kw):
    ours = read_mesh(path, **kw)
    theirs = vtk_path(monkeypatch, path, **kw)
    assert ours.meta["reader"] == reader, path.name
    assert theirs.meta["reader"].startswith("VTK vtkXML"), path.name
    assert ours.meta["format"] == theirs.meta["format"]
    ours.meta.pop("reader"), theirs.meta.pop("reader")
    same(ours, theirs, path.name)
    return ours


@pytest.mark.parametrize("tagged", [False, True], ids=["plain", "tagged"])
@pytest.mark.parametrize("shape", sorted(SHAPES))
@pytest.mark.parametrize("layout", sorted(LAYOUTS))
@pytest.mark.parametrize("kind", ["vti", "vts", "vtr"])
def test_ours_is_the_vtk_path_mesh_bit_for_bit(tmp_path, monkeypatch, kind, layout, shape, tagged):
    dims, start = SHAPES[shape]
    path = write(tmp_path / f"grid.{kind}", dataset(kind, dims, start, tagged), layout)
    mesh = assert_same_as_vtk(monkeypatch, path)
    assert mesh.n_cells == np.prod([d - 1 for d in dims if d > 1]) and mesh.dim == (2 if 1 in dims else 3)
    if tagged:
        assert mesh.tag_name == "gmsh:physical" and sorted(np.unique(mesh.tags)) == [1, 2, 3]
        assert mesh.meta["group_names"] == {1: "inner"} and mesh.meta["boundary_names"] == {2: "wall"}


@pytest.mark.parametrize("kind", ["vti", "vts", "vtr"])
def test_a_named_tag_a_missing_one_and_welding_as_the_vtk_path(tmp_path, monkeypatch, kind):
    path = write(tmp_path / f"grid.{kind}", dataset(kind, (4, 5, 3), tagged=True), "zlib")
    mesh = assert_same_as_vtk(monkeypatch, path, physical_tag="quality")
    assert mesh.tag_name == "quality" and mesh.tags.dtype == np.int64
    assert_same_as_vtk(monkeypatch, path, weld=1e-9)
    with pytest.raises(ParameterError) as err:
        read_mesh(path, physical_tag="velocity")  # three components: not a tag, as in VTK's path
    assert str(err.value) == str(vtk_path(monkeypatch, path, physical_tag="velocity"))
    assert "available: gmsh:physical, quality" in str(err.value)


@pytest.mark.parametrize("layout", ["appended-raw", "zlib"])
def test_float32_points_and_coordinates_as_the_vtk_path(tmp_path, monkeypatch, layout):
    sg = vc.structured_grid((4, 5, 3))
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(vtk_to_numpy(sg.GetPoints().GetData()).astype(np.float32) * 1.1, deep=True))
    sg.SetPoints(pts)
    assert_same_as_vtk(monkeypatch, write(tmp_path / "f32.vts", sg, layout))
    rg = vc.rectilinear((4, 5, 3))
    rg.SetYCoordinates(numpy_to_vtk(np.array([0.1, 0.7, 0.9, 2.3, 4.1], np.float32), deep=True))
    assert_same_as_vtk(monkeypatch, write(tmp_path / "f32.vtr", rg, layout))


def _ghost(ds):
    ghost = np.zeros(ds.GetNumberOfCells(), np.uint8)
    ghost[0] = 32  # HIDDEN_CELL
    ds.GetCellData().AddArray(_named(numpy_to_vtk(ghost, deep=True), "vtkGhostType"))
    return ds


def _rotated():
    im = vc.image((4, 5, 3))
    im.SetDirectionMatrix(0, -1, 0, 1, 0, 0, 0, 0, 1)
    return im


DECLINED = {
    "pieces": lambda p: vc.write_xml(p.with_suffix(".vts"), vc.structured_grid((5, 4, 6)), pieces=2),
    "ascii": lambda p: vc.write_xml(p.with_suffix(".vtr"), vc.rectilinear(), "ascii"),
    "ghost": lambda p: vc.write_xml(p.with_suffix(".vti"), _ghost(vc.image((4, 5, 3)))),
    "rotated": lambda p: vc.write_xml(p.with_suffix(".vti"), _rotated()),
    "lz4": lambda p: _lz4(p.with_suffix(".vts")),
}


def _lz4(path: Path) -> str:
    w = vtk.vtkXMLStructuredGridWriter()
    w.SetFileName(str(path))
    w.SetInputData(vc.structured_grid())
    w.SetCompressorTypeToLZ4()
    assert w.Write() == 1
    return str(path)


@pytest.mark.parametrize("case", sorted(DECLINED))
def test_other_layouts_are_left_to_vtk_and_are_the_same_mesh(tmp_path, monkeypatch, case):
    path = Path(DECLINED[case](tmp_path / "grid"))
    assert xml_grid.read_xml_grid(path) is None
    with pytest.raises(read.NativeReaderNeeded):
        read_mesh(path, native=False)
    reader = {".vts": "VTK vtkXMLStructuredGridReader", ".vtr": "VTK vtkXMLRectilinearGridReader"}
    assert_same_as_vtk(monkeypatch, path, reader.get(path.suffix, "VTK vtkXMLImageDataReader"))


def test_the_scan_declines_xml_it_would_read_otherwise_than_vtk(tmp_path):
    sg = vc.structured_grid()
    write(tmp_path / "good.vts", sg)  # the points' norm range is computed: the next file has it
    good = write(tmp_path / "good.vts", sg)
    data = good.read_bytes()
    assert xml_grid.read_xml_grid(good) is not None
    edits = {
        "a single-quoted attribute": (b'WholeExtent="0 4 0 3 0 2"', b"WholeExtent='0 4 0 3 0 2'"),
        "the XML declaration not first": (b'<?xml version="1.0"?>\n', b'\n<?xml version="1.0"?>\n'),
        "text between tags": (b"<Points>", b"<Points>points:"),
        "a control character": (b"<Points>", b"<Points>\x01"),
        "a norm range VTK cannot parse": (b'<Value index="1">\n', b'<Value index="1">\nnan'),
        "an extent in hex": (b'WholeExtent="0 4', b'WholeExtent="0x0 4'),
        "a piece smaller than the whole": (b'Extent="0 4 0 3 0 2"   ', b'Extent="0 3 0 3 0 2"   '),
        "two pieces' worth of sections": (b"<PointData>", b"<CellData>\n</CellData>\n<PointData>"),
    }
    for what, (old, new) in edits.items():
        assert old in data, what
        bad = tmp_path / "bad.vts"
        bad.write_bytes(data.replace(old, new, 1))
        assert xml_grid.read_xml_grid(bad) is None, what


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # both paths: a 1e308 spacing
@pytest.mark.parametrize(
    "spacing, origin",
    [((0.5, 0.0, 2.0), (0, 0, 0)), ((0.5, 1.0, 2.0), (0, float("inf"), 0)), ((1e308, 1.0, 1.0), (0, 0, 0))],
)
@pytest.mark.parametrize("dims", [(4, 3, 5), (4, 3, 1)])
def test_bad_image_geometry_is_the_vtk_path_sentence(tmp_path, monkeypatch, spacing, origin, dims):
    im = vc.image(dims)
    im.SetSpacing(*spacing)
    im.SetOrigin(*origin)
    path = write(tmp_path / "bad.vti", im)
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    assert str(err.value) == str(vtk_path(monkeypatch, path))
    if spacing[0] == 1e308:  # a lattice beyond float64: the points are refused
        assert "points with NaN or infinite coordinates" in str(err.value)
        return
    assert "the image data's" in str(err.value) and "must be finite" in str(err.value)
    if np.isfinite(origin).all():  # ours refuses it
        with pytest.raises(MeshError):
            xml_grid.read_xml_grid(path)
    else:  # "inf" in the header: VTK's parser reads it otherwise, VTK's path words it
        assert xml_grid.read_xml_grid(path) is None


@pytest.mark.parametrize("kind", ["vts", "vti"])
def test_an_extent_beyond_what_the_file_holds_is_one_sentence(tmp_path, kind):
    ds = vc.image((4, 5, 3)) if kind == "vti" else vc.structured_grid((4, 5, 3))
    if kind == "vti":  # image data holds its points implicitly: a cell array makes the claim
        ds.GetCellData().AddArray(_named(numpy_to_vtk(np.ones(24, np.int32), deep=True), "gmsh:physical"))
    path = write(tmp_path / f"big.{kind}", ds, "zlib")
    data = path.read_bytes()
    big = re.sub(rb'Extent="0 3 0 4 0 2"', b'Extent="0 999999999 0 999999999 0 2"', data)
    assert big.count(b"999999999") == 4
    path.write_bytes(big)
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    msg = str(err.value)
    assert_sentence(msg, path)
    what = "points" if kind == "vts" else "cells"
    assert re.search(rf"the file is corrupted: its Piece announces [\d,]+ {what}, more than its", msg), msg


def test_in_process_a_lattice_beyond_the_read_memory_is_left_to_the_sandbox(tmp_path, monkeypatch):
    path = write(tmp_path / "image.vti", vc.image((40, 40, 40)))  # ~7 MB built, a 1 KB file
    monkeypatch.setenv("MAGNET_READ_MEMORY_MB", "1")
    with pytest.raises(read.NativeReaderNeeded):
        read_mesh(path, native=False)
    assert read_mesh(path).meta["reader"] == OURS  # no limit in-process (native=True)


def test_cli_reads_ours_in_process_and_the_rest_in_the_sandbox(tmp_path, monkeypatch, child_calls):
    monkeypatch.delenv("MAGNET_READ_SANDBOX", raising=False)
    calls = child_calls
    ours = write(tmp_path / "grid.vts", dataset("vts", (5, 4, 3), tagged=True), "zlib")
    mesh = sandbox.read_mesh_cli(ours)
    assert calls == [] and mesh.meta["reader"] == OURS
    ascii_vts = Path(vc.write_xml(tmp_path / "ascii.vts", vc.structured_grid(), "ascii"))
    mesh = sandbox.read_mesh_cli(ascii_vts)
    assert calls == [1] and mesh.meta["reader"] == "VTK vtkXMLStructuredGridReader"


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # mutated coordinates
def test_mutants_are_the_vtk_path_mesh_or_one_sentence(tmp_path, monkeypatch):
    """Seeded mutants of each kind and layout, read in the sandbox (VTK's reader may crash on them):
    a Mesh or one sentence. Where ours read one and VTK's path reads it too, the same Mesh; VTK's
    path may refuse one that ours reads (a broken array that ours does not read: point data, a
    cell array other than the tag, a string array)."""
    files = []
    for kind in ("vti", "vts", "vtr"):
        for layout in ("appended-base64", "inline-binary", "zlib-raw"):
            ds = dataset(kind, (4, 3, 3), tagged=True)
            files.append(write(tmp_path / f"{layout}.{kind}", ds, layout))
    compared = 0
    for k, path in enumerate(files):
        for i, (how, bad) in enumerate(mutants(path.read_bytes(), seed=2300 + k, n=14)):
            target = tmp_path / f"m{i}_{path.name}"
            target.write_bytes(bad)
            mesh = _sandboxed(target)
            if isinstance(mesh, Exception):
                assert_sentence(str(mesh), target)
                continue
            if mesh.meta["reader"] != OURS:
                continue
            with monkeypatch.context() as m:  # the direct fork inherits the switch
                m.setattr(xml_grid, "read_xml_grid", lambda *a, **kw: None)
                theirs = _sandboxed(target)
            if not isinstance(theirs, Exception):
                mesh.meta.pop("reader"), theirs.meta.pop("reader")
                same(mesh, theirs, f"{target.name} ({how})")
                compared += 1
    assert compared >= 5


def _sandboxed(path: Path):
    try:
        return sandbox.read_mesh_safe(path, zygote=False, timeout_s=30, memory_bytes=2 << 30)
    except (MeshError, ParameterError) as exc:
        return exc

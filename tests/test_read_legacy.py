"""The numpy path for legacy VTK files of the common layout, binary or ASCII (models/mesh/legacy.py):
the same Mesh as VTK's reader gives, bit for bit; any other layout, any word of ASCII text that is
not a plain number, declined (None: VTK's reader)."""

from __future__ import annotations

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")
import vtk_corpus as vc  # noqa: E402

from models.errors import MeshError  # noqa: E402
from models.mesh.legacy import read_legacy_simple  # noqa: E402
from models.mesh.read import read_mesh  # noqa: E402
from models.mesh.vtk_readers import read_vtk  # noqa: E402

KUHN = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]


def _grids():
    p, h = vc.grid(4, 3, 5)
    rng = np.random.default_rng(3)
    p = p + rng.uniform(-0.05, 0.05, p.shape)
    yield "hexahedra", vc.unstructured(p, [(12, h)])
    mirrored = h[:, [0, 3, 2, 1, 4, 7, 6, 5]]  # inside out: the read flips them
    yield "mirrored hexahedra", vc.unstructured(p, [(12, mirrored)])
    yield "tetrahedra", vc.unstructured(p, [(10, np.concatenate([h[:, k] for k in KUHN]))])
    q2, q = vc.quad_grid(5, 4)
    yield "quads", vc.unstructured(q2, [(9, q)])
    yield "triangles", vc.unstructured(q2, [(5, np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))])


def _float32_points(ug):
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    p = vtk_to_numpy(ug.GetPoints().GetData()).astype(np.float32)
    ug.GetPoints().SetData(numpy_to_vtk(p, deep=True))
    return ug


@pytest.mark.parametrize("metadata", [False, True], ids=["", "metadata"])
@pytest.mark.parametrize("binary", [True, False], ids=["binary", "ascii"])
@pytest.mark.parametrize("version", [42, 51])
@pytest.mark.parametrize("case", list(_grids()), ids=lambda c: c[0])
def test_numpy_path_equals_vtk_reader(tmp_path, case, version, binary, metadata):
    name, ug = case
    if name == "quads":  # float points too (the ASCII path parses them as floats)
        ug = _float32_points(ug)
    if metadata:  # METADATA blocks after the arrays: the ranges an XML writer computed, names
        ug, shared = vtk.vtkUnstructuredGrid(), ug
        ug.DeepCopy(shared)
        ug.GetPoints().GetData().SetComponentName(1, "y axis")
        vc.write_xml(str(tmp_path / "ranges.vtu"), ug)
    path = vc.write_legacy(str(tmp_path / "m.vtk"), ug, version, binary)
    if metadata:
        with open(path, "rb") as fh:
            assert b"METADATA" in fh.read()
    assert read_legacy_simple(path) is not None
    ours, ref = read_mesh(path), read_vtk(path, "legacy")
    assert ours.meta["reader"].startswith("numpy")
    for key in ("points", "offsets", "connectivity", "cell_types"):
        assert np.array_equal(getattr(ours, key), getattr(ref, key)), key
    for key in ("measures", "centroids", "signed_measures"):
        assert np.array_equal(ours.meta[key], ref.meta[key]), key
    assert ours.meta["orientation"] == ref.meta["orientation"]


def _mixed():
    p, h = vc.grid(2, 2, 2)
    return vc.unstructured(p, [(12, h[:4]), (10, h[4:][:, KUHN[0]])])


def _with_cell_data():
    p, h = vc.grid(2, 2, 2)
    ug = vc.unstructured(p, [(12, h)])
    from vtkmodules.util.numpy_support import numpy_to_vtk

    a = numpy_to_vtk(np.arange(len(h), dtype=np.int32))
    a.SetName("gmsh:physical")
    ug.GetCellData().AddArray(a)
    return ug


@pytest.mark.parametrize("what", ["mixed cell types", "cell data", "truncated", "wrong count", "not legacy"])
def test_other_layouts_are_left_to_vtk(tmp_path, what):
    p, h = vc.grid(2, 2, 2)
    path = str(tmp_path / "m.vtk")
    if what == "mixed cell types":
        vc.write_legacy(path, _mixed(), 42, True)
    elif what == "cell data":
        vc.write_legacy(path, _with_cell_data(), 42, True)
    else:
        vc.write_legacy(path, vc.unstructured(p, [(12, h)]), 42, True)
        data = open(path, "rb").read()
        if what == "truncated":
            data = data[: len(data) // 2]
        elif what == "wrong count":
            data = data.replace(b"CELL_TYPES 8", b"CELL_TYPES 9")
        else:
            data = data.replace(b"# vtk DataFile", b"# not DataFile")
        open(path, "wb").write(data)
    assert read_legacy_simple(path) is None
    if what in ("mixed cell types", "cell data"):
        mesh = read_mesh(path)  # VTK's reader, as before
        assert mesh.meta["reader"].startswith("VTK")
        if what == "cell data":
            assert mesh.tags is not None
    else:
        with pytest.raises(MeshError):
            read_mesh(path)


@pytest.mark.parametrize(
    "edit",
    [
        (b"double\n0 0 0", b"double\n0 nan 0"),  # a point VTK's stream reader does not take as a number
        (b"double\n0 0 0", b"double\n0 0x1 0"),
        (b"double\n0 0 0", b"double\n0 0 zero"),
        (b"double\n0 0 0", b"double\n0 0 -"),
        (b"double\n0 0 0", b"double\n0 0 1e"),
        (b"double\n0 0 0", b"double\n0 0 .e1"),
        (b"CONNECTIVITY vtktypeint64\n0", b"CONNECTIVITY vtktypeint64\n0.5"),
        (b"CONNECTIVITY vtktypeint64\n0", b"CONNECTIVITY vtktypeint64\n99999999999999999999"),
        (b"CELL_TYPES 8\n", b"CELL_TYPES 9\n"),
        (b"POINTS 27", b"POINTS 28"),
    ],
    ids=[
        "nan",
        "hex",
        "word",
        "sign alone",
        "bare exponent",
        "no digits",
        "fraction id",
        "huge id",
        "count",
        "too few points",
    ],
)
def test_ascii_garbage_is_left_to_vtk(tmp_path, edit):
    """A word of an ASCII file that is not a plain number (or too few of them): the numpy path
    declines, and VTK's reader reads the file or the read refuses it in one sentence."""
    p, h = vc.grid(2, 2, 2)
    path = vc.write_legacy(str(tmp_path / "m.vtk"), vc.unstructured(p, [(12, h)]), 51, False)
    data = open(path, "rb").read()
    assert edit[0] in data
    open(path, "wb").write(data.replace(edit[0], edit[1], 1))
    assert read_legacy_simple(path) is None
    try:
        mesh = read_mesh(path)
    except MeshError as e:
        msg = str(e)
        assert msg.startswith("cannot read m.vtk") and ". " not in msg and "\n" not in msg
    else:
        assert mesh.meta["reader"].startswith("VTK")


def test_ascii_numbers_correctly_rounded():
    """ascii_values against the C library's strtod / strtof (correctly rounded, as VTK's reader):
    the exact fast path and the fallback give the same bits, for doubles and floats."""
    import ctypes

    from models.native import compiled

    fast = compiled("mesh._fastmesh")
    assert fast is not None
    rng = np.random.default_rng(0)
    v = np.concatenate(
        [
            rng.uniform(-10, 10, 2000),
            rng.standard_normal(500) * 10.0 ** rng.integers(-30, 30, 500),
            [
                0.0,
                -0.0,
                5e-324,
                1.7976931348623157e308,
                2.0**53,
                2.0**53 + 2,
                0.1,
                1e22,
                1e23,
                9007199254740993,
            ],
        ]
    )
    words = [repr(float(x)) for x in v] + [f"{x:.6g}" for x in v] + [f"{x:.9e}" for x in v]
    words += [
        "1.",
        ".5",
        "-.5",
        "+3",
        "007",
        "0.000000000000000000000000001",
        "1" * 30,
        "1" * 25 + ".5e-10",
        "123456789012345678901234567890e-25",
        "9007199254740993",
        "4.35",
        "1E5",
        "1e+05",
    ]
    text = (" \n\t".join(words) + "\n").encode()
    libc = ctypes.CDLL(None)
    libc.strtod.restype, libc.strtof.restype = ctypes.c_double, ctypes.c_float
    libc.strtod.argtypes = libc.strtof.argtypes = [ctypes.c_char_p, ctypes.c_void_p]
    d = np.empty(len(words))
    assert fast.ascii_values(text, 0, d, 1) > 0
    ref = np.array([libc.strtod(w.encode(), None) for w in words])
    assert np.array_equal(d.view(np.int64), ref.view(np.int64))
    f = np.empty(len(words), np.float32)
    assert fast.ascii_values(text, 0, f, 2) > 0
    ref32 = np.array([libc.strtof(w.encode(), None) for w in words], np.float32)
    assert np.array_equal(f.view(np.int32), ref32.view(np.int32))
    i = np.empty(4, np.int64)
    assert fast.ascii_values(b"  0 -12\n+7 123456789012345678 ", 0, i, 0) == 29
    assert i.tolist() == [0, -12, 7, 123456789012345678]
    for bad in (b"1 2 3", b"1 2 x 4", b"1 2 3.0 4", b"1 2 3 1234567890123456789"):
        assert fast.ascii_values(bad, 0, i, 0) == -1


def _binary_hexes(first_count: int) -> bytes:
    """A binary legacy file of two hexahedra; the first cell's node count as given (8 when sound)."""
    pts = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1, 2)], dtype=">f4")
    cells = np.array([first_count, 0, 1, 4, 3, 6, 7, 10, 9, 8, 1, 2, 5, 4, 7, 8, 11, 10], dtype=">i4")
    head = b"# vtk DataFile Version 4.2\nhand\nBINARY\nDATASET UNSTRUCTURED_GRID\nPOINTS 12 float\n"
    return (
        head
        + pts.tobytes()
        + b"\nCELLS 2 18\n"
        + cells.tobytes()
        + b"\nCELL_TYPES 2\n"
        + np.array([12, 12], dtype=">i4").tobytes()
        + b"\n"
    )


def test_short_data_vtk_reads_without_a_word_is_refused(tmp_path):
    """VTK's legacy reader takes a damaged cell count as that many nodes (the cells after it vanish)
    and fills a truncated ASCII file's missing points with zeros, without an error: both refused,
    saying what the file declares against what it holds (an outside sweep's corrupted files)."""
    from models.mesh.sandbox import read_mesh_safe

    ok = tmp_path / "two.vtk"
    ok.write_bytes(_binary_hexes(8))
    assert read_mesh_safe(str(ok)).n_cells == 2
    swallowed = tmp_path / "swallowed.vtk"
    swallowed.write_bytes(_binary_hexes(17))
    with pytest.raises(MeshError, match=r"declares 2 cells \(CELLS\) but its cell list holds 1"):
        read_mesh_safe(str(swallowed))
    from models.mesh.legacy import _binary_cells

    with open(swallowed, "rb") as fh:  # (found by a seek past the points, not a scan of the file)
        assert _binary_cells(fh, fh.read(4096)).group(1) == b"2"
    grid = ["# vtk DataFile Version 3.0", "g", "ASCII", "DATASET STRUCTURED_GRID", "DIMENSIONS 3 2 2"]
    grid += ["POINTS 12 float", *[f"{x} {y} {z}" for z in (0, 1) for y in (0, 1) for x in (0, 1, 2)]]
    whole = tmp_path / "grid.vtk"
    whole.write_text("\n".join(grid) + "\n")
    assert read_mesh_safe(str(whole)).n_cells == 2
    cut = tmp_path / "cut.vtk"
    cut.write_text("\n".join(grid[:-5]) + "\n")
    with pytest.raises(
        MeshError, match=r"declares 12 points \(POINTS\) but holds coordinates for 7: .*truncated"
    ):
        read_mesh_safe(str(cut))

"""Image data read directly as a lattice (build.mesh_from_image, no normalize, no generic checks), and
whole structured grids without normalize (vtk_readers._lattice_cells): the Mesh is the general
path's, field for field and bit for bit; a zero, NaN or infinite spacing or origin is one sentence."""

import numpy as np
import pytest
import vtk
import vtk_corpus as vc
from vtkmodules.util.numpy_support import numpy_to_vtk

from models.errors import MeshError
from models.mesh import vtk_readers as vr
from models.mesh.read import read_mesh

# these tests check VTK's path (vtk_readers): our numpy path for .vti/.vts/.vtr (xml_grid) is off
pytestmark = pytest.mark.usefixtures("vtk_xml_path")


def _image(dims, spacing=(0.5, 1.0, 2.0), origin=(1.0, -2.0, 3.0), start=(0, 0, 0), tags=False):
    im = vc.image(dims)
    im.SetExtent(*[v for a in range(3) for v in (start[a], start[a] + dims[a] - 1)])
    im.SetSpacing(*spacing)
    im.SetOrigin(*origin)
    if tags:
        n = im.GetNumberOfCells()
        arr = numpy_to_vtk(np.arange(n, dtype=np.int32) % 3 + 1, deep=True)
        arr.SetName("gmsh:physical")
        im.GetCellData().AddArray(arr)
        fd = numpy_to_vtk(np.array([2, 3], dtype=np.int64), deep=True)
        fd.SetName("inner")
        im.GetFieldData().AddArray(fd)
    return im


CASES = {
    "3d": lambda: _image((5, 4, 6)),
    "3d-tags": lambda: _image((5, 4, 6), tags=True),
    "3d-negative-x": lambda: _image((5, 4, 6), spacing=(-0.5, 1.0, 2.0)),
    "3d-negative-xz": lambda: _image((5, 4, 6), spacing=(-0.5, 1.0, -2.0)),
    "3d-negative-all": lambda: _image((3, 4, 5), spacing=(-0.5, -1.0, -0.25)),
    "3d-extent-offset": lambda: _image((5, 4, 6), start=(2, -3, 7)),
    "3d-one-layer": lambda: _image((6, 5, 2), start=(0, 0, 4)),
    "3d-one-layer-x": lambda: _image((2, 5, 4), spacing=(-3.0, 1.0, 1.0)),
    "2d": lambda: _image((6, 5, 1)),
    "2d-negative-y": lambda: _image((6, 5, 1), spacing=(0.5, -1.0, 1.0), start=(1, 2, 3)),
    "2d-xz": lambda: _image((6, 1, 5)),
}


def _write(tmp, case, kind):
    im = CASES[case]()
    if kind == "vti":
        return str(vc.write_xml(tmp / f"{case}.vti", im, "appended"))
    return str(vc.write_legacy(tmp / f"{case}.vtk", im, 42, True))  # STRUCTURED_POINTS


def _same(a, b, where=""):
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        assert isinstance(a, np.ndarray) and isinstance(b, np.ndarray), where
        assert a.dtype == b.dtype and a.shape == b.shape, where
        assert a.tobytes() == b.tobytes(), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and sorted(a, key=str) == sorted(b, key=str), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    else:
        assert type(a) is type(b) and a == b, where


def _general(monkeypatch, path):
    with monkeypatch.context() as m:
        m.setattr(vr, "_image_mesh", lambda *a: None)
        m.setattr(vr, "_lattice_cells", lambda *a: None)
        return read_mesh(path)


def _assert_same_mesh(fast, ref):
    for f in (
        "points offsets connectivity cell_types tags tag_name frame poly_cells poly_cell_faces "
        "poly_face_offsets poly_face_nodes boundary_offsets boundary_connectivity boundary_types "
        "boundary_tags"
    ).split():
        _same(getattr(fast, f), getattr(ref, f), f)
    _same(fast.meta, ref.meta, "meta")


@pytest.mark.parametrize("kind", ["vti", "structured-points"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_image_direct_is_the_general_mesh_bit_for_bit(tmp_path, monkeypatch, case, kind):
    path = _write(tmp_path, case, kind)
    fast = read_mesh(path)
    ref = _general(monkeypatch, path)
    _assert_same_mesh(fast, ref)
    assert np.all(fast.meta["signed_measures"] > 0)
    if case.startswith("3d"):
        assert fast.meta["orientation"]["flipped"] in (0, fast.n_cells)


def test_image_direct_is_taken_for_3d(tmp_path, monkeypatch):
    path = _write(tmp_path, "3d-negative-x", "vti")
    called = []
    real = vr._image_mesh

    def spy(*a):
        out = real(*a)
        called.append(out is not None)
        return out

    monkeypatch.setattr(vr, "_image_mesh", spy)
    mesh = read_mesh(path)
    assert called == [True]
    assert mesh.meta["orientation"]["flipped"] == mesh.n_cells == 4 * 3 * 5


@pytest.mark.parametrize("dims", [(4, 5, 6), (6, 5, 1)])
def test_structured_grid_without_normalize_is_the_general_mesh(tmp_path, monkeypatch, dims):
    path = str(vc.write_xml(tmp_path / "s.vts", vc.structured_grid(dims), "binary"))
    _assert_same_mesh(read_mesh(path), _general(monkeypatch, path))
    rg = str(vc.write_xml(tmp_path / "r.vtr", vc.rectilinear(dims), "binary"))
    _assert_same_mesh(read_mesh(rg), _general(monkeypatch, rg))


@pytest.mark.parametrize(
    "spacing, origin, what",
    [
        ((0.5, 0.0, 2.0), (0, 0, 0), "spacing"),
        ((0.5, float("nan"), 2.0), (0, 0, 0), "spacing"),
        ((float("inf"), 1.0, 2.0), (0, 0, 0), "spacing"),
        ((0.5, 1.0, 2.0), (0, float("inf"), 0), "origin"),
        ((0.5, 1.0, 2.0), (float("nan"), 0, 0), "origin"),
    ],
)
@pytest.mark.parametrize("dims", [(4, 3, 5), (4, 3, 1)])
def test_image_bad_geometry_is_one_sentence(tmp_path, spacing, origin, what, dims):
    im = _image(dims, spacing=spacing, origin=origin)
    path = str(vc.write_xml(tmp_path / "bad.vti", im, "ascii"))
    with pytest.raises(MeshError) as exc:
        read_mesh(path)
    msg = str(exc.value)
    assert f"the image data's {what} must be finite" in msg and "bad.vti" in msg
    assert msg.count(". ") == 0 and "vtk" not in msg.lower().replace("vtk xml", "")


def test_image_zero_spacing_on_a_flat_axis_is_fine(tmp_path):
    im = _image((4, 3, 1), spacing=(0.5, 1.0, 0.0))
    mesh = read_mesh(str(vc.write_xml(tmp_path / "flat.vti", im, "appended")))
    assert mesh.n_cells == 6 and mesh.dim == 2


def test_vtk_is_imported(tmp_path):
    assert vtk.vtkImageData is not None

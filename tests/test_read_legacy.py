"""The numpy path for legacy VTK files of the common binary layout (models/mesh/legacy.py): the
same Mesh as VTK's reader gives, bit for bit; any other layout declined (None: VTK's reader)."""

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


@pytest.mark.parametrize("version", [42, 51])
@pytest.mark.parametrize("case", list(_grids()), ids=lambda c: c[0])
def test_numpy_path_equals_vtk_reader(tmp_path, case, version):
    name, ug = case
    path = vc.write_legacy(str(tmp_path / "m.vtk"), ug, version, True)
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


@pytest.mark.parametrize(
    "what", ["ascii", "mixed cell types", "cell data", "truncated", "wrong count", "not legacy"]
)
def test_other_layouts_are_left_to_vtk(tmp_path, what):
    p, h = vc.grid(2, 2, 2)
    path = str(tmp_path / "m.vtk")
    if what == "ascii":
        vc.write_legacy(path, vc.unstructured(p, [(12, h)]), 42, False)
    elif what == "mixed cell types":
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
    if what in ("ascii", "mixed cell types", "cell data"):
        mesh = read_mesh(path)  # VTK's reader, as before
        assert mesh.meta["reader"].startswith("VTK")
        if what == "cell data":
            assert mesh.tags is not None
    else:
        with pytest.raises(MeshError):
            read_mesh(path)

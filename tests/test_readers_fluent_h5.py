"""Fluent CFF case files (.cas.h5, HDF5), written at test time by tests/format_writers.py in the
layout VTK's vtkFLUENTCFFReader reads (derived from that reader's source): tetrahedra, hexahedra,
pyramids, hexahedra + wedges (one zone per type, and one mixed zone typed by a ctype section), and
2D triangles, quadrilaterals and both mixed. Each is read by VTK and by our dispatch: the same
number of cells and total volume / area (1e-9 relative), then agglomerated by the Python API and
the output, read back by VTK, holds the same volume.
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest

vtk = pytest.importorskip("vtk")
import format_writers as fw  # noqa: E402
import vtk_corpus as vc  # noqa: E402

from models.errors import MeshError  # noqa: E402
from models.mesh.read import pick_reader, read_mesh  # noqa: E402
from models.mesh.sandbox import read_mesh_safe  # noqa: E402

TOL = 1e-9
KUHN = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]


def _hexes():
    return fw.grid(3, 2, 2)


def _tets():
    p, h = _hexes()
    return p, [("tetra", np.concatenate([h[:, k] for k in KUHN]))]


def _pyramids():
    """Each hexahedron as six pyramids around its centre (a new point)."""
    p, h = _hexes()
    c = len(p) + np.arange(len(h))
    pyr = np.concatenate([np.column_stack([h[:, f], c]) for f in fw.HEX_FACES])
    return np.vstack([p, p[h].mean(axis=1)]), [("pyramid", pyr)]


def _quads():
    p, q = vc.quad_grid(4, 3)
    return p[:, :2], q


def _tri(q):
    return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


CASES = {  # name -> (points, blocks, mixed_zone, dimension)
    "tetra": lambda: (*_tets(), False, 3),
    "hexahedron": lambda: (_hexes()[0], [("hexahedron", _hexes()[1])], False, 3),
    "pyramid": lambda: (*_pyramids(), False, 3),
    "hex-wedge-zones": lambda: (*fw.blocks(), False, 3),
    "hex-wedge-mixed": lambda: (*fw.blocks(), True, 3),
    "triangle": lambda: (_quads()[0], [("triangle", _tri(_quads()[1]))], False, 2),
    "quad": lambda: (_quads()[0], [("quad", _quads()[1])], False, 2),
    "tri-quad-mixed": lambda: (
        _quads()[0],
        [("quad", _quads()[1][:6]), ("triangle", _tri(_quads()[1][6:]))],
        True,
        2,
    ),
}


def _write(tmp, name):
    p, blocks, mixed, dim = CASES[name]()
    return fw.write_fluent_h5(tmp / f"{name}.cas.h5", p, blocks, mixed_zone=mixed), blocks, dim


@pytest.mark.parametrize("name", sorted(CASES))
def test_fluent_h5_matches_vtk_and_agglomerates(tmp_path, name):
    path, blocks, dim = _write(tmp_path, name)
    assert pick_reader(path) == ("vtk", "fluent-h5")
    n_ref, size_ref = vc.vtk_reference(path)
    assert n_ref == sum(len(c) for _, c in blocks)
    mesh = read_mesh(path)
    assert mesh.dim == dim
    assert mesh.n_cells == n_ref
    assert mesh.meta["orientation"]["folded"] == 0
    want = {"tetra": "tetra", "hexahedron": "hexahedron", "pyramid": "pyramid", "wedge": "wedge"}
    want.update(triangle="triangle", quad="quad")
    assert mesh.cell_type_counts() == {want[k]: len(c) for k, c in blocks}
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(size_ref, rel=TOL)
    res, n_out, size_out = vc.agglomerate_read_back(path, 3, tmp_path / "out.vtu")
    assert res.n_elements == 3 and res.labels.shape == (n_ref,)
    assert float(np.sum(res.elements.measure)) == pytest.approx(size_ref, rel=TOL)
    assert n_out == 3 and size_out == pytest.approx(size_ref, rel=TOL)


def test_fluent_h5_zones_become_groups(tmp_path):
    """One cell zone per block: VTK gives a block per zone, our mesh a group per zone."""
    path, _, _ = _write(tmp_path, "hex-wedge-zones")
    assert len(read_mesh(path).physical_groups()) == 2
    path, _, _ = _write(tmp_path, "hex-wedge-mixed")
    assert len(read_mesh(path).physical_groups()) == 1


@pytest.mark.parametrize("damage", ["no-settings", "no-c0", "not-hdf5"])
def test_fluent_h5_refusal_names_file_and_format(tmp_path, damage):
    path, _, _ = _write(tmp_path, "hexahedron")
    if damage == "not-hdf5":
        with open(path, "wb") as f:
            f.write(b"(0 not an HDF5 file)\n")
    else:
        with h5py.File(path, "a") as f:
            del f["settings" if damage == "no-settings" else "meshes/1/faces/c0"]
    with pytest.raises(MeshError) as err:
        read_mesh_safe(
            path
        )  # a damaged file is read as an upload is: in a child (VTK's HDF5 state is process-wide)
    msg = str(err.value)
    assert "hexahedron.cas.h5" in msg and "Fluent" in msg and "\n" not in msg, msg

"""Abaqus element types meshio's table lacks (models/mesh/abaqus_types.py): plane-strain,
axisymmetric, heat-transfer and coupled-temperature elements read by the shape of their nodes;
a type no table knows is named in the refusal (outside sweep S: plane-strain CPE4 was refused as
"corrupted or not in this format")."""

from __future__ import annotations

import numpy as np
import pytest
import vtk_corpus as vc

from models.errors import MeshError
from models.mesh.read import read_mesh


def write_inp(path, points, cells, etype, elset="PART-1"):
    """An Abaqus input file as Abaqus/CAE writes a flat one: *NODE rows id, x, y[, z] and an
    *ELEMENT block of one type, ids from 1."""
    lines = ["*HEADING", "written at test time", "*NODE"]
    lines += [f"{i + 1}, " + ", ".join(f"{v:.17g}" for v in p) for i, p in enumerate(points)]
    lines.append(f"*ELEMENT, TYPE={etype}, ELSET={elset}")
    lines += [f"{i + 1}, " + ", ".join(str(int(v) + 1) for v in c) for i, c in enumerate(cells)]
    lines.append("*END PART")
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _square(nx=4, ny=3):
    p, q = vc.quad_grid(nx, ny)
    return p[:, :2], q


@pytest.mark.parametrize(
    "etype,shape",
    [
        ("CPE4", "quad"),
        ("CPE4R", "quad"),
        ("CAX4R", "quad"),
        ("DC2D4", "quad"),
        ("CPE3", "tri"),
        ("CAX3", "tri"),
    ],
)
def test_planar_types_read_with_their_area(tmp_path, etype, shape):
    p, q = _square()
    cells = q if shape == "quad" else np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    mesh = read_mesh(write_inp(tmp_path / f"{etype}.inp", p, cells, etype))
    assert mesh.dim == 2 and mesh.n_cells == len(cells)
    d1, d2 = p[q[:, 2]] - p[q[:, 0]], p[q[:, 3]] - p[q[:, 1]]
    area = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).sum() / 2
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(area, rel=1e-12)


@pytest.mark.parametrize("etype", ["C3D8T", "C3D8RT", "DC3D8"])
def test_solid_types_read_with_their_volume(tmp_path, etype):
    p, h = vc.grid(3, 2, 2)
    path = write_inp(tmp_path / f"{etype}.inp", p, h, etype)
    mesh = read_mesh(path)
    assert mesh.dim == 3 and mesh.n_cells == len(h)
    ref = read_mesh(write_inp(tmp_path / "plain.inp", p, h, "C3D8"))
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(
        float(np.abs(ref.meta["measures"]).sum()), rel=1e-12
    )


def test_an_unknown_type_is_named(tmp_path):
    p, q = _square()
    path = write_inp(tmp_path / "odd.inp", p, q, "CPE9Q")
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    msg = str(err.value)
    assert "odd.inp" in msg and "CPE9Q" in msg and "corrupted" not in msg

"""Meshes of one cell, and a last chunk of one row in the dual graph's fixed-layout CSR.

A mesh of one triangle, quad or tetrahedron died in `magnet agglomerate` with a raw IndexError
(outside sweep S): the dual graph's CSR (models/mesh/dual.py _fixed_csr) marked boundary faces in
copies of each chunk's columns, and a one-row chunk's column is contiguous, so numpy handed back a
view of `partner` itself and the marks overwrote it (int64 max for "no partner"). The same held for
any mesh whose cell count is one more than a multiple of the chunk (32,769 cells)."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from models import agglomerate
from models.cli.main import main
from models.mesh.dual import dual_graph
from models.mesh.read import mesh_from_arrays

ONE = {
    "triangle": (np.array([[0.0, 0], [1, 0], [0, 1]]), np.array([[0, 1, 2]]), 0.5),
    "quad": (np.array([[0.0, 0], [2, 0], [2, 1], [0, 1]]), np.array([[0, 1, 2, 3]]), 2.0),
    "tetra": (np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), np.array([[0, 1, 2, 3]]), 1 / 6),
    "hexahedron": (
        np.array([[x, y, z] for z in (0.0, 1) for y in (0.0, 1) for x in (0.0, 1)])[[0, 1, 3, 2, 4, 5, 7, 6]],
        np.arange(8)[None, :],
        1.0,
    ),
}


@pytest.mark.parametrize("kind", list(ONE))
def test_one_cell_agglomerates_into_one_element(kind):
    points, cells, measure = ONE[kind]
    res = agglomerate(points=points, cells=[(kind, cells)], model="metis", k=1)
    assert res.n_elements == 1
    assert np.array_equal(res.labels, [0])
    assert res.elements.measure.sum() == pytest.approx(measure, rel=1e-12)


@pytest.mark.parametrize("kind", list(ONE))
def test_one_cell_file_through_the_cli(kind, tmp_path, capsys):
    points, cells, _ = ONE[kind]
    if points.shape[1] == 2:
        points = np.c_[points, np.zeros(len(points))]
    src = tmp_path / f"one_{kind}.vtu"
    meshio.write(src, meshio.Mesh(points, [(kind, cells)]))
    rc = main(["agglomerate", str(src), "--k", "1", "-o", str(tmp_path / "out.vtu")])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "Traceback" not in err and "Error" not in err
    assert (tmp_path / "out.vtu").exists()


def test_a_last_chunk_of_one_row_keeps_the_partners():
    """32,769 triangles in a strip: the CSR's last chunk is one row; every cell but the two ends
    has two neighbours, and no partner is out of range."""
    n = 32769
    m = n // 2 + 2  # points per row
    x = np.arange(m, dtype=np.float64)
    points = np.r_[np.c_[x, np.zeros(m)], np.c_[x, np.ones(m)]]
    i = np.arange(m - 1)
    low = np.c_[i, i + 1, m + i]  # lower triangles
    up = np.c_[i + 1, m + i + 1, m + i]  # upper triangles
    tri = np.empty((2 * (m - 1), 3), dtype=np.int64)
    tri[0::2], tri[1::2] = low, up
    tri = tri[:n]
    mesh = mesh_from_arrays(points, [("triangle", tri)], None)
    g = dual_graph(mesh)
    deg = np.diff(g.indptr)
    assert deg.sum() == 2 * (n - 1)
    assert deg[0] == 1 and deg[-1] == 1 and np.all(deg[1:-1] == 2)
    assert g.partner.max() < g.faces.n and g.partner.min() >= -1

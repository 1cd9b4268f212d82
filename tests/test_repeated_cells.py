"""Cells written twice (the same nodes as an earlier cell; outside sweep S): a few among many are
left out and said, as other bad cells are (models/mesh/build.py _drop_repeated), and the rest is
agglomerated; more than that is refused in one sentence naming the file. Before, `check` called them
'folded' and `agglomerate` refused the whole mesh as 'not a manifold' without naming the file."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
import vtk_corpus as vc

from models import agglomerate
from models.errors import MeshError
from models.mesh.read import read_mesh

KUHN = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]


def _cases():
    p, h = vc.grid(10, 10, 5)  # 500 hexahedra
    tets = np.concatenate([h[:, k] for k in KUHN])  # 3,000 tetrahedra
    q, quads = vc.quad_grid(20, 15)  # 300 quads
    tri = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])  # 600 triangles
    return {
        "hexahedron": (p, h),
        "tetra": (p, tets),
        "triangle": (q, tri),
        "quad": (q, quads),
    }


@pytest.mark.parametrize("kind", ["hexahedron", "tetra", "triangle", "quad"])
def test_a_few_repeated_cells_are_left_out_and_said(tmp_path, kind):
    p, cells = _cases()[kind]
    plain = tmp_path / "plain.vtu"
    meshio.write(plain, meshio.Mesh(p, [(kind, cells)]))
    ref = read_mesh(str(plain))
    twins = cells[[0, len(cells) // 2]]
    twins[1] = np.roll(twins[1], 1) if kind in ("triangle", "quad") else twins[1]  # another start
    path = tmp_path / "twice.vtu"
    meshio.write(path, meshio.Mesh(p, [(kind, np.concatenate([cells, twins]))]))
    mesh = read_mesh(str(path))
    assert mesh.n_cells == len(cells)
    d = mesh.meta["dropped_cells"]
    assert d["ids_all"] == [len(cells), len(cells) + 1]
    assert list(d["reasons"]) == ["written twice (the same nodes as an earlier cell)"]
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(
        float(np.abs(ref.meta["measures"]).sum()), rel=1e-12
    )
    assert mesh.meta["orientation"]["folded"] == 0
    res = agglomerate(str(path), model="metis", k=4)
    assert res.n_elements == 4
    assert len(res.labels) == len(cells)  # per kept cell (labels.json: -1 for the two left out)


def test_many_repeated_cells_are_refused_in_one_sentence(tmp_path):
    p, h = vc.grid(2, 2, 2)
    path = tmp_path / "twice.vtu"
    meshio.write(path, meshio.Mesh(p, [("hexahedron", np.concatenate([h, h[:2]]))]))
    with pytest.raises(MeshError) as err:
        read_mesh(str(path))
    msg = str(err.value)
    assert "twice.vtu" in msg and "2 cells are written twice" in msg and "\n" not in msg

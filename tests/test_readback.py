"""Every result we write reads back (our reader and meshio) and can be agglomerated again."""

from __future__ import annotations

import subprocess
import sys

import meshio
import numpy as np
import pytest
from meshes import mixed_3d, quads, tets, triangles

from models import pipeline
from models.export.vtu import write_vtu
from models.mesh.read import mesh_from_arrays, read_mesh

CASES = {
    "triangles": lambda: triangles(10),
    "quads": lambda: quads(9),
    "tets": lambda: tets(4),
    "mixed3d": lambda: mixed_3d(4),
}


def _mesh(name):
    if name == "mixed3d":
        p, blocks = mixed_3d(4)
        return mesh_from_arrays(p, blocks)
    p, c = CASES[name]()
    return mesh_from_arrays(
        p, [("quad" if name == "quads" else "triangle" if name == "triangles" else "tetra", c)]
    )


@pytest.mark.parametrize("name", list(CASES))
def test_result_reads_back_and_agglomerates_again(tmp_path, name):
    m = _mesh(name)
    total = m.meta["signed_measures"].sum()
    res = pipeline.run(m, model="metis", mode="kway", k=12)
    out = tmp_path / "level1.vtu"
    pipeline.write_outputs(res, vtu=str(out), labels=str(tmp_path / "l.json"))
    mm = meshio.read(out)  # meshio itself, not only our reader
    assert sum(len(c) for c in mm.cells) == res.poly.n_elements
    ids = np.concatenate(mm.cell_data["element_id"])
    assert ids.tolist() == list(range(res.poly.n_elements))  # cell data stays with its cells
    assert np.allclose(np.concatenate(mm.cell_data["measure"]), res.poly.measure)
    again = read_mesh(out)
    assert again.n_cells == res.poly.n_elements
    assert np.isclose(again.meta["signed_measures"].sum(), total, rtol=1e-9)
    assert again.meta["orientation"]["folded"] == 0
    res2 = pipeline.run(again, model="metis", mode="kway", k=3)
    assert res2.poly.n_elements >= 3
    assert np.isclose(res2.poly.measure.sum(), total, rtol=1e-9)
    out2 = tmp_path / "level2.vtu"
    pipeline.write_outputs(res2, vtu=str(out2))
    assert sum(len(c) for c in meshio.read(out2).cells) == res2.poly.n_elements


def test_unsorted_polyhedra_file_still_reads(tmp_path):
    """A polyhedral VTU whose elements are not sorted by vertex count (as older versions and other
    writers produce) trips meshio's cell-data split; our reader reads it itself."""
    m = _mesh("tets")
    res = pipeline.run(m, model="metis", mode="kway", k=12)
    poly = res.poly
    perm = np.arange(poly.n_elements)[::-1]  # the other order: decreasing vertex count
    from models.mesh.geometry import reorder_csr

    eo, fids = reorder_csr(poly.elem_offsets, np.arange(poly.elem_offsets[-1]), perm)
    lo, ln = reorder_csr(poly.loop_offsets, poly.loop_nodes, fids)
    poly.elem_offsets, poly.loop_offsets, poly.loop_nodes = eo, lo, ln
    poly.measure, poly.n_fine = poly.measure[perm], poly.n_fine[perm]
    out = tmp_path / "unsorted.vtu"
    write_vtu(out, poly)
    with pytest.raises(Exception, match="Incompatible cell data"):
        meshio.read(out)
    again = read_mesh(out)
    assert again.n_cells == 12 and np.isclose(again.meta["measures"].sum(), 1.0)


def test_cli_reagglomerates_its_own_3d_output(tmp_path):
    p, t = tets(4)
    src = tmp_path / "cube.vtu"
    meshio.write(src, meshio.Mesh(p, [("tetra", t)]))
    cli = [sys.executable, "-m", "models.cli"]
    r = subprocess.run(
        cli + ["agglomerate", str(src), "-o", str(tmp_path / "a.vtu"), "--k", "20"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    r = subprocess.run(
        cli + ["agglomerate", str(tmp_path / "a.vtu"), "-o", str(tmp_path / "b.vtu"), "--k", "4"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    assert sum(len(c) for c in meshio.read(tmp_path / "b.vtu").cells) >= 4
    r = subprocess.run(cli + ["info", str(tmp_path / "b.vtu")], capture_output=True, text=True)
    assert r.returncode == 0 and '"dim": 3' in r.stdout

"""Nested hierarchies: every level's element is exactly a union of elements of the next finer level."""

import json

import numpy as np
import pytest
from conftest import BRAIN
from meshes import tets

from models.errors import ParameterError
from models.hierarchy import is_nested, nested_levels
from models.io import mesh_from_arrays, read_mesh
from models.pipeline import run, write_hierarchy


def check_nested_files(out, index, n_cells):
    levels = [np.asarray(json.load(open(out / lv["labels"]))) for lv in index["levels"]]
    assert all(lab.size == n_cells for lab in levels)
    counts = [int(lab.max()) + 1 for lab in levels]
    assert counts == [lv["elements"] for lv in index["levels"]]
    assert counts == sorted(counts) and len(set(counts)) == len(counts)
    for L in range(1, len(levels)):
        parent = np.asarray(json.load(open(out / index["levels"][L]["parent"])))
        assert parent.size == counts[L]
        # exact nesting: the coarse label of every cell is the parent of its fine element
        assert np.array_equal(parent[levels[L]], levels[L - 1])
        assert (out / index["levels"][L]["mesh"]).is_file()
    return levels


@pytest.mark.parametrize("mode,extra", [("nref", {"nref": 4}), ("multilevel", {"nref": 4, "refiner": "fm"}),
                                        ("mult-factor", {"mult_factor": 0.3})])
def test_brain_hierarchy_is_nested(tmp_path, mode, extra):
    mesh = read_mesh(BRAIN)
    res = run(mesh, model="metis", mode=mode, record_levels=True, compute_metrics=False, **extra)
    index = write_hierarchy(res, str(tmp_path), metrics=False)
    assert index["nested"]
    levels = check_nested_files(tmp_path, index, mesh.n_cells)
    assert np.array_equal(levels[-1], res.agglomeration.labels)  # the finest level is the result
    assert levels[0].max() == 0  # the coarsest is the whole (connected) mesh
    if mode != "mult-factor":
        assert len(levels) == 5
    json.load(open(tmp_path / "level_2.metrics.json"))["partition"]["normalized_cut"]


def test_3d_hierarchy_with_metrics(tmp_path):
    p, t = tets(6)
    mesh = mesh_from_arrays(p, [("tetra", t)])
    res = run(mesh, model="metis", mode="nref", nref=3, record_levels=True, compute_metrics=False)
    index = write_hierarchy(res, str(tmp_path), metrics=True)
    check_nested_files(tmp_path, index, mesh.n_cells)
    rep = json.load(open(tmp_path / "level_3.metrics.json"))
    assert "sphericity" in rep["summary"]


def test_nesting_survives_fragment_absorption(tmp_path):
    mesh = read_mesh(BRAIN)
    res = run(mesh, model="kmeans", mode="nref", nref=5, absorb_fraction=0.3, record_levels=True,
              compute_metrics=False)
    levels = nested_levels(res.data, res.agglomeration.labels, res.agglomeration.levels, res.agglomeration.nodes, mesh)
    assert is_nested(levels)
    assert np.array_equal(levels[-1], res.agglomeration.labels)


def test_kway_has_no_hierarchy(tmp_path):
    mesh = read_mesh(BRAIN)
    res = run(mesh, model="metis", mode="kway", k=8, record_levels=True, compute_metrics=False)
    with pytest.raises(ParameterError, match="recursive mode"):
        write_hierarchy(res, str(tmp_path))

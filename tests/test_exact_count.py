"""k elements asked for: exactly k elements (fragments merged, the largest elements split again),
or a refusal that says why; `allow_extra` keeps every connected fragment (issue 25, section 4)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import BRAIN, EMILIA, pieces
from meshes import quads, tets

from models import agglomerate
from models.errors import ParameterError


def _check(res, k):
    assert res.n_elements == k
    assert np.array_equal(np.unique(res.labels), np.arange(k))
    assert pieces(res.result.graph, res.labels) == k  # every element connected


@pytest.mark.parametrize("model", ["metis", "kmeans", "rtree"])
@pytest.mark.parametrize("k", [7, 64])
def test_brain_exact_k(model, k):
    _check(agglomerate(BRAIN, model=model, k=k, metrics=False), k)


def test_kmeans_fragment_is_merged_unless_extra_allowed():
    res = agglomerate(BRAIN, model="kmeans", k=64, metrics=False)
    _check(res, 64)
    extra = agglomerate(BRAIN, model="kmeans", k=64, metrics=False, allow_extra=True)
    s = extra.summary()
    assert extra.n_elements == 64 + s["parts_split"] - s["fragments_absorbed"]
    if s["parts_split"]:  # the case of the issue: a part in two pieces
        assert extra.n_elements > 64 and res.summary()["recount"]["merged"] >= 1


@pytest.mark.parametrize("model", ["metis", "rtree"])
def test_k_near_the_number_of_cells(model):
    n = 14372
    for k in (n, n - 5):
        res = agglomerate(BRAIN, model=model, k=k, metrics=False)
        _check(res, k)
    extra = agglomerate(BRAIN, model="metis", k=n, metrics=False, allow_extra=True)
    assert extra.n_elements <= n


@pytest.mark.parametrize("model", ["metis", "kmeans", "rtree"])
def test_generated_3d_mesh(model):
    p, t = tets(5)  # 750 tetrahedra
    for k in (50, 700, 750):
        if model == "kmeans" and k == 750:
            continue  # k-means with as many clusters as points is no test of the recount
        _check(agglomerate(points=p, cells=[("tetra", t)], model=model, k=k, metrics=False), k)


@pytest.mark.parametrize("model", ["metis", "kmeans", "rtree"])
def test_emilia_with_groups(model):
    res = agglomerate(EMILIA, model=model, k=40, metrics=False)
    _check(res, 40)
    n = res.mesh.n_cells
    _check(agglomerate(EMILIA, model="metis", k=n - 2, metrics=False), n - 2)


def test_coarsen_subset_exact():
    part = np.flatnonzero(agglomerate(BRAIN, k=4, metrics=False).labels == 0)  # one connected piece
    res = agglomerate(BRAIN, model="kmeans", k=20, subset=part, metrics=False)
    assert res.n_elements == 20 + 14372 - part.size
    assert np.unique(res.labels[part]).size == 20
    with pytest.raises(ParameterError, match="separate pieces"):  # the first 3000 cells lie scattered
        agglomerate(BRAIN, model="kmeans", k=20, subset=np.arange(3000), metrics=False)


def test_a_count_that_cannot_be_met_is_refused_with_the_reason():
    p, q = quads(4)
    far = p + [5.0, 0.0]  # a second square, apart from the first
    pts = np.vstack([p, far])
    cells = [("quad", np.vstack([q, q + len(p)]))]
    with pytest.raises(ParameterError, match="2 separate pieces"):
        agglomerate(points=pts, cells=cells, k=1)
    _check(agglomerate(points=pts, cells=cells, k=2), 2)
    with pytest.raises(ParameterError, match="larger than the number of cells"):
        agglomerate(points=pts, cells=cells, k=33)


def test_job_hierarchy_with_k_has_the_agglomeration_as_its_finest_level(tmp_path):
    import json
    import zipfile

    from models import api

    s = api.run_job(
        BRAIN,
        tmp_path,
        {"model": "metis", "k": 64, "options": {"hierarchy": True, "ratio": 4, "coarsest": 4}},
    )
    index = json.loads(zipfile.ZipFile(tmp_path / "hierarchy.zip").read("hierarchy.json"))
    sizes = [lv["elements"] for lv in index["levels"]]
    assert s["elements"] == 64 and sizes == [4, 16, 64] and index["nested"]
    finest = json.loads(zipfile.ZipFile(tmp_path / "hierarchy.zip").read(index["levels"][-1]["labels"]))
    assert finest == json.loads((tmp_path / "labels.json").read_text())

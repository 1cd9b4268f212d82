"""--size-measure: a part's size from its cell centroids (the paper's, default) or its vertices."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import EMILIA

from models.api import validate_params
from models.errors import ParameterError
from models.mesh.geometry import mesh_diameter
from models.mesh.read import read_mesh
from models.partition.agglomerate import agglomerate
from models.pipeline import prepare


@pytest.fixture(scope="module")
def emilia():
    m = read_mesh(EMILIA)
    g, d = prepare(m)
    return m, d


def _element_sizes(m, d, labels, measure):
    out = []
    for e in np.unique(labels):  # test-side reference, one element at a time
        cells = np.flatnonzero(labels == e)
        if measure == "centroids":
            pts = d.centroids[cells]
        else:
            pts = m.points[
                np.unique(np.concatenate([m.connectivity[m.offsets[c] : m.offsets[c + 1]] for c in cells]))
            ]
        out.append(mesh_diameter(pts))
    return np.array(out)


@pytest.mark.parametrize("mode", ["mult-factor", "segregated"])
def test_both_measures_on_emilia(emilia, mode):
    m, d = emilia
    f = 0.04
    n = {}
    for measure, diameter in (
        ("centroids", mesh_diameter(d.centroids)),
        ("vertices", mesh_diameter(m.points)),
    ):
        r = agglomerate(m, d, mode=mode, mult_factor=f, size_measure=measure)
        h = f * diameter
        sizes = _element_sizes(m, d, r.labels, measure)
        assert sizes.max() < h  # the guarantee each measure gives, measured its own way
        n[measure] = r.n_elements
    # the paper's measure gives far fewer elements (paper, segregated f = 0.04: 363; vertices: ~690)
    assert n["centroids"] < 0.7 * n["vertices"]
    if mode == "segregated":
        assert 300 <= n["centroids"] <= 450 and n["vertices"] > 600


def test_default_is_centroids(emilia):
    m, d = emilia
    a = agglomerate(m, d, mode="mult-factor", mult_factor=0.05)
    b = agglomerate(m, d, mode="mult-factor", mult_factor=0.05, size_measure="centroids")
    assert np.array_equal(a.labels, b.labels)
    with pytest.raises(ParameterError, match="size_measure"):
        agglomerate(m, d, mode="mult-factor", mult_factor=0.05, size_measure="hull")


def test_api_option():
    p = validate_params({"mode": "mult-factor", "mult_factor": 0.1, "options": {"size_measure": "vertices"}})
    assert p["options"]["size_measure"] == "vertices"
    assert (
        validate_params({"mode": "mult-factor", "mult_factor": 0.1})["options"]["size_measure"] == "centroids"
    )
    with pytest.raises(ParameterError, match="size_measure"):
        validate_params({"mode": "mult-factor", "mult_factor": 0.1, "options": {"size_measure": "x"}})


def test_api_weld_option(tmp_path):
    from defects import OUT

    from models.api import run_job

    p = validate_params({"k": 1, "options": {"weld": 1e-9}})
    assert p["options"]["weld"] == 1e-9 and validate_params({"k": 1})["options"]["weld"] is None
    with pytest.raises(ParameterError, match="weld"):
        validate_params({"k": 1, "options": {"weld": -1}})
    seam = f"{OUT}/duplicate_seam.vtu"
    with pytest.raises(ParameterError, match="2 separate pieces"):  # exactly k, or the reason
        run_job(seam, tmp_path / "a0", {"k": 1})
    assert (
        run_job(seam, tmp_path / "a", {"k": 1, "options": {"allow_extra": True}})["elements"] == 2
    )  # the seam splits it
    assert run_job(seam, tmp_path / "b", {"k": 1, "options": {"weld": 1e-9}})["elements"] == 1

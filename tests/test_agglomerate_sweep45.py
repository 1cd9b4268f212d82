"""What an outside sweep of `magnet agglomerate` across modes and odd inputs found (session 45: 218
runs over 21 inputs): a refused hole was worded as a failed read and named the Python keyword;
subset ids were taken after the read had left a few bad cells out, so the wrong cells were
coarsened; the count asked of nref and multilevel was missed without a word."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from meshes import triangles

from models.agglomeration import agglomerate
from models.errors import HoleError, MeshError


def _ring(n: int = 12):
    """(points, triangles, ids) of an n x n square of triangles whose middle 4 x 4 block is left out:
    a square with a square hole."""
    p, t = triangles(n)
    c = p[t].mean(axis=1)
    keep = ~np.all((c > 4 / n) & (c < 8 / n), axis=1)
    return p, t[keep]


def test_a_hole_refused_by_the_policy_is_no_read_error(tmp_path):
    import meshio

    p, t = _ring()
    path = str(tmp_path / "ring.vtu")
    meshio.write(path, meshio.Mesh(p, [("triangle", t)]))
    with pytest.raises(HoleError) as err:
        agglomerate(path, model="metis", k=1, hole_policy="error")
    said = str(err.value)
    assert isinstance(err.value, MeshError)  # (a MeshError as before: 422 over HTTP)
    assert said.startswith("1 agglomerated element encloses a hole (element 0)")
    assert "--hole-policy split" in said and "hole_policy=" not in said
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "models.cli",
            "agglomerate",
            path,
            "-o",
            str(tmp_path / "o.vtu"),
            "-k",
            "1",
        ]
        + ["--hole-policy", "error"],
        capture_output=True,
        text=True,
        cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
    )
    assert run.returncode != 0
    assert "cannot read" not in run.stderr and "encloses a hole (element 0)" in run.stderr


def test_subset_ids_are_the_files_cell_ids_when_bad_cells_are_left_out(tmp_path):
    import meshio

    p, t = triangles(16)
    bad = np.array([[0, 0, 1], [2, 2, 3], [5, 5, 6]])  # three zero-area triangles, first in the file
    path = str(tmp_path / "bad_first.vtu")
    meshio.write(path, meshio.Mesh(p, [("triangle", np.r_[bad, t])]))
    c = p[t].mean(axis=1)
    left = np.flatnonzero(c[:, 0] < 0.5) + 3  # the left half, as the file numbers its cells
    res = agglomerate(path, model="metis", k=4, subset=left.tolist())
    lab = np.asarray(res.input_labels)
    assert lab.size == len(t) + 3 and np.all(lab[:3] == -1)
    inside = np.zeros(lab.size, dtype=bool)
    inside[left] = True
    assert np.unique(lab[inside]).size == 4  # the left half in 4 elements
    right = ~inside & (lab >= 0)
    assert np.unique(lab[right]).size == np.count_nonzero(right)  # the rest as it was: a cell each
    with pytest.raises(Exception, match=r"the mesh has cells 0\.\.514\), e\.g\. 515"):
        agglomerate(path, model="metis", k=4, subset=[*left.tolist(), len(t) + 3])
    assert json.dumps(res.summary())  # (plain values)


def _islands():
    """Three separate squares of triangles side by side (gaps between them), one mesh."""
    p, t = triangles(12)
    pts, tri = [], []
    for i, dx in enumerate((0.0, 1.5, 3.0)):
        pts.append(p + [dx, 0.0])
        tri.append(t + i * len(p))
    return np.vstack(pts), np.vstack(tri)


@pytest.mark.parametrize("mode", ["nref", "multilevel"])
def test_nref_gives_two_to_the_nref_elements_on_islands(mode):
    p, t = _islands()
    res = agglomerate(points=p, cells=[("triangle", t)], model="metis", mode=mode, nref=3)
    assert res.n_elements == 8
    assert res.summary()["asked"] == "2^nref" and res.summary()["requested"] == 8


@pytest.mark.parametrize("model", ["metis", "kmeans"])
def test_a_subset_around_a_cell_outside_it_meets_k(model):
    # before: METIS k = 3, 5 and k-means 3, 4, 5 refused on the first, 2, 5, 8 on the second
    from conftest import pieces

    from models.polytope.merge import merge

    p, t = triangles(20)
    c = p[t].mean(axis=1)
    left = np.flatnonzero(c[:, 0] < 0.5)
    for at in ([0.25, 0.5], [0.2, 0.3]):
        inner = left[np.argmin(np.linalg.norm(c[left] - at, axis=1))]  # a cell inside the left half
        subset = np.setdiff1d(left, [inner])
        outside = np.setdiff1d(np.arange(len(t)), subset)
        for k in (2, 3, 4, 5, 8):
            res = agglomerate(points=p, cells=[("triangle", t)], model=model, k=k, subset=subset.tolist())
            lab = np.asarray(res.labels)
            assert np.unique(lab[subset]).size == k
            assert np.unique(lab[outside]).size == outside.size  # untouched: a cell each
            assert not np.isin(lab[outside], lab[subset]).any()
            assert pieces(res.result.graph, lab) == res.n_elements  # connected elements
            _, holes = merge(res.mesh, res.result.graph, lab, res.result.data.measures)
            assert holes.elements.size == 0  # none around the inner cell


def test_a_weld_larger_than_the_cells_is_said_as_such():
    from models.errors import ParameterError

    p, t = triangles(12)
    with pytest.raises(
        ParameterError, match=r"weld tolerance \(--weld\) left 288 of the 288 cells degenerate"
    ):
        agglomerate(points=p, cells=[("triangle", t)], k=4, weld=0.5)
    assert agglomerate(points=p, cells=[("triangle", t)], k=4, weld=1e-12).n_elements == 4


def test_a_bad_flag_is_one_line(tmp_path):
    run = subprocess.run(
        [sys.executable, "-m", "models.cli", "hierarchy", "x.vtu", "-o", str(tmp_path), "--ratio", "abc"],
        capture_output=True,
        text=True,
        cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
    )
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [
        "magnet hierarchy: error: argument --ratio: invalid float value: 'abc' (see `magnet hierarchy --help`)"
    ]

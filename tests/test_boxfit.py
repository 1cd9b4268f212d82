"""models.hierarchy.boxfit (issue 24, box measures): the post-pass keeps the levels nested, every
element connected and the counts exact, and makes the boxes tighter on an unstructured triangle mesh."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from models.hierarchy.boxfit import boxfit_levels
from models.hierarchy.nested import build_hierarchy, is_nested
from models.mesh.read import mesh_from_arrays
from models.partition.rtree import _label_pieces, cell_boxes
from models.pipeline import prepare
from models.quality.report import box_measures


@pytest.fixture(scope="module")
def delaunay():
    """About 3000 Delaunay triangles of random points in the unit square (seeded)."""
    rng = np.random.default_rng(7)
    s = np.linspace(0.0, 1.0, 31)[:-1]
    edge = np.vstack([np.c_[s, 0 * s], np.c_[1 + 0 * s, s], np.c_[1 - s, 1 + 0 * s], np.c_[0 * s, 1 - s]])
    pts = np.vstack([edge, 0.01 + 0.98 * rng.random((1500, 2))])
    tri = Delaunay(pts).simplices
    mesh = mesh_from_arrays(pts, [("triangle", tri)])
    graph, data = prepare(mesh)
    return mesh, data


def _coverage(mesh, data, lv):
    return box_measures(mesh.points, mesh.offsets, mesh.connectivity, lv, data.measures)["coverage"]


def _connected(data, lv):
    n_pieces, _ = _label_pieces(data.graph.indptr, data.graph.indices, lv)
    return n_pieces == int(lv.max()) + 1


def test_boxfit_keeps_nesting_connectivity_counts_and_tightens_boxes(delaunay):
    mesh, data = delaunay
    levels, _ = build_hierarchy(mesh, data, model="rtree", ratio=16.0, coarsest=10)
    lo, hi = cell_boxes(data.points, data.offsets, data.connectivity)
    out = boxfit_levels(levels, lo, hi, data.measures, data.graph.indptr, data.graph.indices)
    assert is_nested(out)
    assert [int(lv.max()) + 1 for lv in out] == [int(lv.max()) + 1 for lv in levels]
    for before, after in zip(levels, out, strict=True):
        assert np.array_equal(np.unique(after), np.arange(int(before.max()) + 1))  # no element emptied
        assert _connected(data, after)
        k = int(before.max()) + 1
        sb, sa = np.bincount(before, minlength=k), np.bincount(after, minlength=k)
        assert np.all(np.abs(sa - sb) <= 0.15 * sb + 1e-9)  # sizes within +-15% (in cells)
    assert not np.array_equal(out[-1], levels[-1])  # something moved
    cov_b = _coverage(mesh, data, levels[-1])
    cov_a = _coverage(mesh, data, out[-1])
    assert cov_a < cov_b - 0.02, (cov_b, cov_a)


def test_build_hierarchy_boxfit_option(delaunay):
    mesh, data = delaunay
    plain, _ = build_hierarchy(mesh, data, model="rtree", ratio=16.0, coarsest=10)
    fitted, info = build_hierarchy(
        mesh, data, model="rtree", ratio=16.0, coarsest=10, model_options={"boxfit": True}
    )
    assert is_nested(fitted)
    assert [int(lv.max()) + 1 for lv in fitted] == [int(lv.max()) + 1 for lv in plain]
    assert all(_connected(data, lv) for lv in fitted)
    assert _coverage(mesh, data, fitted[-1]) < _coverage(mesh, data, plain[-1])

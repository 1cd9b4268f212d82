"""The defect corpus (tests/data/defects/, written by tests/defects.py): every mesh either
agglomerates with its total area/volume preserved to 1e-9 relative, or is refused in one line that
names the defect, the first ids and what to do. `magnet check` reports each defect."""

from __future__ import annotations

import os

import meshio
import numpy as np
import pytest
from defects import OUT, corpus, normalized
from test_cli import _bad, magnet

from models import pipeline
from models.errors import ParameterError
from models.mesh.check import check_file
from models.mesh.read import mesh_from_arrays, read_mesh

AREA = {  # exact total measure, where the construction fixes it
    "folded_sliver_2d": 1.0,
    "folded_tet_3d": 1.0,
    "unused_points": 1.0,
    "duplicate_seam": 1.0,
    "pinch": 2.0,
    "hanging_node": 1.0,
    "disconnected": 3.0,
    "repeated_vertex": 1.0,
    "nonplanar_quads": 1.0,
    "mixed_2d_3d": 1.0,
    "far_from_origin": 36e-6,
    "micro_scale": 36e-18,
}
REFUSED = {
    "zero_area": ("degenerate (zero-area) cells", "cells 3", "collinear, coplanar or crossing"),
    "repeated_vertex_triangle": ("degenerate (zero-area) cells", "cells 3", "remove them"),
    "nonplanar_surface": (
        "non-planar",
        "surface",
        "give a volume mesh, or fill a closed surface (.stl, .obj, .ply, .off)",
    ),
    "nonmanifold_edge": ("not a manifold", "cells 0, 1, 2", "remove the overlapping cells"),
}


def path(name: str) -> str:
    ext = corpus_ext()[name]
    return os.path.join(OUT, f"{name}.{ext}")


_EXT: dict = {}


def corpus_ext() -> dict:
    if not _EXT:
        _EXT.update({k: v[3] for k, v in corpus().items()})
    return _EXT


def test_the_corpus_files_are_what_the_script_writes(tmp_path):
    from defects import write_corpus

    for fresh in write_corpus(str(tmp_path)):
        name = os.path.basename(fresh)
        a, b = meshio.read(fresh), meshio.read(os.path.join(OUT, name))
        assert np.array_equal(a.points, b.points), name
        assert all(np.array_equal(x.data, y.data) for x, y in zip(a.cells, b.cells, strict=True)), name
    assert sorted(os.listdir(OUT)) == sorted(os.listdir(tmp_path))


def _total_of_written(res, tmp_path) -> float:
    out = tmp_path / "out.vtu"
    pipeline.write_outputs(res, vtu=str(out))
    assert sum(len(c) for c in meshio.read(out).cells) == res.poly.n_elements
    return float(read_mesh(out).meta["signed_measures"].sum())


@pytest.mark.parametrize("name", sorted(AREA))
@pytest.mark.parametrize(
    "model,mode,kw", [("metis", "kway", {"k": 4}), ("kmeans", "mult-factor", {"mult_factor": 0.3})]
)
def test_agglomerates_with_the_measure_preserved(name, model, mode, kw, tmp_path):
    m = read_mesh(path(name))
    total = m.meta["signed_measures"].sum()
    assert np.isclose(total, AREA[name], rtol=1e-7)  # the far mesh's points are rounded at 1e6
    res = pipeline.run(m, model=model, mode=mode, compute_metrics=True, **kw)
    assert np.isclose(res.poly.measure.sum(), total, rtol=1e-9, atol=0)
    assert np.isclose(_total_of_written(res, tmp_path), total, rtol=1e-9, atol=0)
    assert (
        res.metrics is not None and len(res.metrics["per_element"]) > 0
    )  # the metrics survive the defect too


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_refused_in_one_line(name, tmp_path):
    words = REFUSED[name]
    for w in words:
        _bad(tmp_path, "agglomerate", path(name), "-o", tmp_path / "x.vtu", "--k", 2, match=w)
    r = magnet("check", path(name))
    assert r.returncode == 2 and "verdict: error" in r.stdout and words[0] in r.stdout
    # every refusal names the file and the format, those found after reading too (not a manifold:
    # it did not; mutation sweep Z)
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("error: "))
    assert line.startswith(f"error: cannot read {os.path.basename(path(name))} as "), line


def _kinds(rep) -> dict:
    return {i["kind"]: i for i in rep["issues"]}


def test_check_reports_each_defect():
    rep = check_file(path("folded_sliver_2d"))
    assert rep["verdict"] == "warnings" and _kinds(rep)["folded"]["count"] == 1
    assert check_file(path("folded_tet_3d"))["orientation"]["folded"] == 1
    rep = check_file(path("unused_points"))
    assert (
        rep["verdict"] == "ok"
        and rep["unused_points"] == 4
        and _kinds(rep)["unused-points"]["ids"] == [49, 50, 51, 52]
    )
    rep = check_file(path("duplicate_seam"))
    dup = _kinds(rep)["duplicate-points"]
    assert rep["components"] == 2 and rep["duplicate_points"] == 7 and "--weld" in dup["message"]
    assert dup["count"] == 7 and dup["ids"][:7] == list(range(21, 28))  # the seam x = 1/2, then its copies
    rep = check_file(path("pinch"))
    assert _kinds(rep)["pinch"]["ids"] == [15] and rep["components"] == 2
    rep = check_file(path("hanging_node"))
    assert rep["hanging_nodes"] == 2 and _kinds(rep)["non-conforming"]["ids"] == [9, 12]
    rep = check_file(path("disconnected"))
    assert rep["components"] == 3 and _kinds(rep)["disconnected"]["count"] == 3 and rep["holes"] == 0
    rep = check_file(path("repeated_vertex"))
    assert rep["verdict"] == "ok" and rep["collapsed_repeated_vertices"] == 16
    assert rep["cell_types"] == {"triangle": 16, "quad": 8}
    rep = check_file(path("mixed_2d_3d"))
    assert _kinds(rep)["mixed-dimension"]["ids"] == [0, 1] and rep["dim"] == 3
    assert check_file(path("nonplanar_quads"))["verdict"] == "ok"
    for name in REFUSED:
        assert check_file(path(name))["verdict"] == "error"


def test_weld_merges_the_seam(tmp_path):
    rep = check_file(path("duplicate_seam"), weld=1e-9)
    assert rep["components"] == 1 and rep["duplicate_points"] == 0 and rep["welded_points"] == 7
    assert rep["verdict"] == "ok"
    apart = pipeline.run(read_mesh(path("duplicate_seam")), k=1, allow_extra=True, compute_metrics=False)
    welded = pipeline.run(read_mesh(path("duplicate_seam"), weld=1e-9), k=1, compute_metrics=False)
    assert apart.poly.n_elements == 2 and welded.poly.n_elements == 1  # an element can now cross the seam
    with pytest.raises(ParameterError, match="2 separate pieces"):  # exactly k, or the reason
        pipeline.run(read_mesh(path("duplicate_seam")), k=1, compute_metrics=False)
    r = magnet("agglomerate", path("duplicate_seam"), "-o", tmp_path / "w.vtu", "--k", 1, "--weld", "1e-9")
    assert r.returncode == 0 and r.stdout.startswith("1 elements"), r.stdout + r.stderr


@pytest.mark.parametrize("name,scale", [("far_from_origin", 6e-3), ("micro_scale", 6e-9)])
@pytest.mark.parametrize(
    "model,mode,kw",
    [
        ("metis", "kway", {"k": 5}),
        ("kmeans", "kway", {"k": 5}),
        ("metis", "nref", {"nref": 3}),
        ("metis", "mult-factor", {"mult_factor": 0.3}),
    ],
)
def test_far_and_tiny_meshes_give_the_normalized_results(name, scale, model, mode, kw):
    p, cells = normalized(name)
    ref = pipeline.run(mesh_from_arrays(p, cells), model=model, mode=mode, compute_metrics=False, **kw)
    res = pipeline.run(read_mesh(path(name)), model=model, mode=mode, compute_metrics=False, **kw)
    assert np.array_equal(res.agglomeration.labels, ref.agglomeration.labels)
    assert np.allclose(res.poly.measure / scale**2, ref.poly.measure, rtol=1e-6)


def test_point_ids_far_beyond_any_count_are_not_quoted():
    """A reader's garbage past a short array (Exodus with fewer nodes per element than its type)
    gave ids such as 8868868570035056718, different on every run: said as far outside the range."""
    import numpy as np

    from models.errors import MeshError
    from models.mesh.read import mesh_from_arrays

    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    with pytest.raises(MeshError) as err:
        mesh_from_arrays(pts, [("tetra", np.array([[0, 1, 2, 3], [0, 1, 2, 8868868570035056718]]))])
    msg = str(err.value)
    assert "far outside that range" in msg and "8868868570035056718" not in msg, msg
    with pytest.raises(MeshError, match=r"found 0\.\.5 in 1 of the 2 cells"):  # near ids: quoted
        mesh_from_arrays(pts, [("tetra", np.array([[0, 1, 2, 3], [0, 1, 2, 5]]))])


def test_a_degenerate_cell_of_coincident_points_names_weld_and_others_do_not():
    """--weld merges distinct points at one place: named where a degenerate cell has such corners,
    not where its corners are distinct (collinear, crossing: outside sweep Y's bow-tie)."""
    import numpy as np

    from models.errors import MeshError
    from models.mesh.read import mesh_from_arrays

    p = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [1, 1.0], [2, 2]], dtype=float)
    with pytest.raises(MeshError, match=r"merge their coincident points with --weld"):
        mesh_from_arrays(p, [("triangle", np.array([[0, 1, 2], [1, 3, 2], [3, 4, 2]]))])
    with pytest.raises(MeshError, match=r"distinct but collinear, coplanar or crossing") as err:
        mesh_from_arrays(p, [("triangle", np.array([[0, 1, 2], [1, 3, 2], [0, 3, 5]]))])
    assert "--weld" not in str(err.value)


@pytest.mark.parametrize(
    "value, said",
    [
        (1e300, "a coordinate beyond 1e75"),
        (1e80, "a coordinate beyond 1e75"),
        (1e30, "a point lies far from all the others"),
    ],
)
def test_one_corrupted_coordinate_is_named_not_every_cell_degenerate(value, said, recwarn):
    """One coordinate set to 1e300 made numpy print its overflow warnings and every cell degenerate;
    one set to 1e30 made every cell degenerate beside the bounding box it spans (mutation sweep Z)."""
    import numpy as np

    from models.errors import MeshError
    from models.mesh.read import mesh_from_arrays

    n = 12
    g = np.arange(n + 1, dtype=float)
    pts = np.array([(x, y) for y in g for x in g])
    q = (np.arange(n)[:, None] * (n + 1) + np.arange(n)).ravel()
    tris = np.vstack([np.c_[q, q + 1, q + n + 2], np.c_[q, q + n + 2, q + n + 1]])
    pts[40, 1] = value
    with pytest.raises(MeshError) as err:
        mesh_from_arrays(pts, [("triangle", tris)])
    msg = str(err.value)
    assert said in msg and "point 40 at" in msg and "degenerate" not in msg, msg
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]

"""Hierarchies that respect physical groups (`magnet hierarchy --groups`, rtree, metis, kmeans): no element of any
level holds cells of two groups, on groups that are islands inside another group and groups of
several separate pieces; every element connected, the levels nested. A mesh whose groups leave
nothing to coarsen (a checkerboard: every cell a group piece of its own) is refused in one
sentence. Notes say the real reason a coarsest level is above --coarsest."""

from __future__ import annotations

import numpy as np
import pytest
from meshes import hexes, quads, triangles

from models.agglomeration import build_hierarchy
from models.errors import ParameterError
from models.hierarchy.nested import is_nested


def centres(p, cells):
    return p[cells].mean(axis=1)


def materials_quads(n=60):
    """Quads of [0, 1]^2: group 1 around, 2 a disk inside it (an island), 3 two corner squares
    (one group in two separate pieces)."""
    p, q = quads(n)
    c = centres(p, q)
    tags = np.ones(len(q), np.int64)
    tags[np.hypot(c[:, 0] - 0.5, c[:, 1] - 0.5) < 0.2] = 2
    tags[(c[:, 0] < 0.15) & (c[:, 1] < 0.15)] = 3
    tags[(c[:, 0] > 0.85) & (c[:, 1] > 0.85)] = 3
    return p, [("quad", q)], [tags]


def rings_triangles(n=70):
    """Triangles: nested rings of groups 1, 2, 3 and group 1 again at the centre (two pieces)."""
    p, t = triangles(n)
    r = np.hypot(*(centres(p, t) - 0.5).T)
    tags = np.ones(len(t), np.int64)
    tags[r < 0.35] = 2
    tags[r < 0.2] = 3
    tags[r < 0.08] = 1
    return p, [("triangle", t)], [tags]


def assert_pure(h, tags):
    for L, lv in enumerate(h.levels):
        k = int(lv.max()) + 1
        per = np.unique(lv * (int(tags.max()) + 1) + tags)
        assert per.size == k, f"level {L}: {per.size - k} elements cross a group"
    assert is_nested(h.levels)
    for r in h.info["report"]:
        assert r.get("extra_pieces", 0) == 0


@pytest.mark.parametrize("make", [materials_quads, rings_triangles])
@pytest.mark.parametrize("finest", [None, "cuts"])
def test_no_element_crosses_a_group(make, finest):
    p, cells, tags = make()
    h = build_hierarchy(points=p, cells=cells, tags=tags, groups=True, finest=finest)
    assert len(h.levels) >= 3
    assert_pure(h, tags[0])


@pytest.mark.parametrize("model", ["metis", "kmeans"])
def test_k_way_models_keep_the_groups_apart_too(model):
    """metis and kmeans cut each connected piece of a group on its own, its share of each level's
    count; each of the three rings around another piece (groups 1, 2, 3 from outside in) is
    planned two coarsest elements (one would enclose what it surrounds), the centre's disc one."""
    p, cells, tags = rings_triangles()
    h = build_hierarchy(points=p, cells=cells, tags=tags, groups=True, model=model, coarsest=4)
    assert_pure(h, tags[0])
    assert h.info["requested"][0] == 7  # 4 pieces, 3 of them rings around another
    assert [int(lv.max()) + 1 for lv in h.levels] == h.info["requested"]
    assert all(r.get("holed", 0) == 0 for r in h.info["report"])


def test_bisection_models_refuse_groups_in_one_sentence():
    p, cells, tags = rings_triangles(20)
    with pytest.raises(ParameterError, match="cuts by bisection only; use rtree, metis or kmeans"):
        build_hierarchy(points=p, cells=cells, tags=tags, groups=True, model="sage-base")


def test_groups_leaving_nothing_to_coarsen_are_refused():
    p, q = quads(20)
    c = centres(p, q)
    checker = ((np.floor(c[:, 0] * 20) + np.floor(c[:, 1] * 20)) % 2).astype(np.int64) + 1
    with pytest.raises(ParameterError, match="leave nothing to coarsen") as err:
        build_hierarchy(points=p, cells=[("quad", q)], tags=[checker], groups=True)
    assert "400 cells" in str(err.value) and "\n" not in str(err.value)


def test_a_note_gives_the_real_reason():
    """Two separate bodies asked down to one element: the note says the bodies, not holes cut."""
    p, q = quads(30, 10)
    far = p.copy()
    far[:, 1] += 2.0  # a second body, apart from the first
    pts = np.vstack([p, far])
    h = build_hierarchy(points=pts, cells=[("quad", np.vstack([q, q + len(p)]))], coarsest=1)
    notes = " ".join(h.info["notes"])
    assert "2 separate pieces" in notes and "could not all be merged back" not in notes


def test_level_files_carry_the_group_names_and_boundary_groups(tmp_path):
    """Each level's VTU holds, as agglomerate's output does, the groups' names (field data) and the
    fine mesh's boundary groups as tagged edges after the elements (outside sweep V: group ids
    only, no names, no boundary groups)."""
    import os

    import vtk
    from vtkmodules.util.numpy_support import vtk_to_numpy

    path = os.path.join(os.path.dirname(__file__), "data", "square_inclusion.msh")
    h = build_hierarchy(path, model="rtree")
    h.write(str(tmp_path))
    for L, n in enumerate(int(lab.max()) + 1 for lab in h.levels):
        r = vtk.vtkXMLUnstructuredGridReader()
        r.SetFileName(str(tmp_path / f"level_{L}.vtu"))
        r.Update()
        out = r.GetOutput()
        fd = out.GetFieldData()
        assert {fd.GetArrayName(i) for i in range(fd.GetNumberOfArrays())} >= {
            "matrix",
            "inclusion",
            "left",
            "top",
        }
        tags = vtk_to_numpy(out.GetCellData().GetArray("boundary_tag"))
        assert np.count_nonzero(tags == -1) == n and set(tags[tags >= 0].tolist()) >= {2, 3, 4, 5}


def test_a_raised_plan_reaches_the_fewest_elements_and_notes_give_the_final_count():
    """at_least drops a level that would not coarsen and raises the next one to the fewest elements
    (a 24^3 block of 200 grains planned 7 > 108 > 1728: 108 was kept below the 204 pieces); every
    note that gives the coarsest count gives the one made (the finest aggregation plans again)."""
    import re

    from scipy.spatial import cKDTree

    from models.hierarchy.plan import at_least

    assert at_least([7, 108, 1728], 204) == [204, 1728]
    assert at_least([7, 108, 1728], 100) == [108, 1728] and at_least([7, 108], 3) == [7, 108]
    p, h = hexes(12)
    c = p[h].mean(axis=1)
    grain = cKDTree(np.random.default_rng(0).random((40, 3))).query(c)[1] + 1
    grains = (p, [("hexahedron", h)], [grain])
    rings = rings_triangles()
    for model, mesh in (("rtree", grains), ("metis", grains), ("rtree", rings), ("kmeans", rings)):
        got = build_hierarchy(points=mesh[0], cells=mesh[1], tags=mesh[2], groups=True, model=model)
        k0 = int(got.levels[0].max()) + 1
        assert got.info["requested"][0] >= k0 >= np.unique(mesh[2][0]).size
        for note in got.info["notes"]:
            for said in re.findall(r"coarsest level has ([\d,]+) elements", note):
                assert int(said.replace(",", "")) == k0, note

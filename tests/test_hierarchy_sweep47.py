"""What an outside sweep of `magnet hierarchy` over 29 meshes found (session 47): levels more than
25% off the ratio asked with no note (only the plan, itself moved by the domain, was compared);
--coarsest below what the domain allows planned a level that coarsened 1.33x; mgcheck's "500*" with
no legend and a ratio against pyamg's capped count; level files of an earlier, deeper hierarchy left
in a reused folder without a word."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from meshes import quads

from models.agglomeration import build_hierarchy
from models.hierarchy.nested import is_nested
from models.polytope.merge import merge


def _rings(nr=10, nt=80, pieces=3):
    """`pieces` separate annuli of quads side by side, each around a hole (6 elements at least)."""
    r = np.linspace(1.0, 2.0, nr + 1)
    t = np.linspace(0, 2 * np.pi, nt, endpoint=False)
    R, T = np.meshgrid(r, t, indexing="ij")
    one = np.c_[(R * np.cos(T)).ravel(), (R * np.sin(T)).ravel()]
    i, j = (a.ravel() for a in np.meshgrid(np.arange(nr), np.arange(nt), indexing="ij"))
    a, b = i * nt + j, i * nt + (j + 1) % nt
    q = np.c_[a, b, b + nt, a + nt]
    pts = np.vstack([one + [5.0 * p, 0.0] for p in range(pieces)])
    return pts, np.vstack([q + p * one.shape[0] for p in range(pieces)])


def _ring_inclusions(n=3, r=0.3, h=0.008):
    """A unit square with n x n ring inclusions of a second physical group (a disk in each ring of
    the matrix's group): (points, triangles, group of each triangle)."""
    import gmsh

    gmsh.initialize(["-nt", "1"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        occ = gmsh.model.occ
        box = occ.addRectangle(0, 0, 0, 1, 1)
        c = [((i + 0.5) / n, (j + 0.5) / n) for i in range(n) for j in range(n)]
        disks = [occ.addDisk(x, y, 0, r / n, r / n) for x, y in c]
        inner = [occ.addDisk(x, y, 0, r / n / 2, r / n / 2) for x, y in c]
        occ.fragment([(2, box)], [(2, d) for d in disks + inner])
        occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.model.mesh.generate(2)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        index = np.empty(int(tags.max()) + 1, dtype=np.int64)
        index[tags.astype(np.int64)] = np.arange(tags.size)
        surfaces = [t for _, t in gmsh.model.getEntities(2)]
        area = [occ.getMass(2, t) for t in surfaces]
        rings = {
            t for t, a in zip(surfaces, area, strict=True) if abs(a - 0.75 * np.pi * (r / n) ** 2) < 1e-6
        }
        tri, grp = [], []
        for t in surfaces:
            types, _, nodes = gmsh.model.mesh.getElements(2, t)
            cells = np.concatenate(
                [np.asarray(v).reshape(-1, 3) for k, v in zip(types, nodes, strict=True) if k == 2]
            )
            tri.append(index[cells.astype(np.int64)])
            grp.append(np.full(len(cells), 2 if t in rings else 1))
    finally:
        gmsh.finalize()
    return np.asarray(coords).reshape(-1, 3)[:, :2], np.vstack(tri), np.concatenate(grp)


def test_a_level_far_off_the_ratio_asked_is_said_though_near_its_plan():
    """9 ring inclusions, --groups, --ratio 16: 13 coarsest elements for the 11 planned make level 0
    11.4x where 16x was asked (13.5x planned, within 25% of the plan): the only note named the
    coarsest count. Now one note names the level, the ratio achieved and the ratio asked, and the
    report (and its table) holds the ratio asked of every level."""
    from models.cli.hierarchy import format_levels

    pts, tri, grp = _ring_inclusions()
    h = build_hierarchy(points=pts, cells=[("triangle", tri)], tags=[grp], groups=True, ratio=16)
    rep = h.info["report"]
    assert all(r["asked_ratio"] == 16.0 for r in rep) and is_nested(h.levels)
    far = [r for r in rep if abs(r["ratio"] / 16.0 - 1.0) > 0.25]
    assert far, [r["ratio"] for r in rep]
    said = [n for n in h.info["notes"] if "off the ratio asked" in n]
    assert len(said) == 1, h.info["notes"]
    for r in far:
        assert f"level {r['level']} {r['ratio']:.1f}x where 16x was asked" in said[0], said[0]
    table = format_levels(rep).splitlines()
    assert "planned" in table[0] and "asked" in table[0] and "requested" not in table[0]
    assert all("!" in table[1 + r["level"]] for r in far)


def test_the_ratio_asked_above_an_aggregated_finest_level_is_the_schedule_step():
    """The sweep's 3D inclusions (default schedule): 6 > 65 > 832 > 10737, level 0 10.8x where 16x
    was asked, 13x planned; the finest level, pyamg's aggregation of the cells, was asked no ratio."""
    from models.hierarchy.plan import said_off_plan, with_asked, with_requested

    counts, got = [5, 65, 832, 10737], [6, 65, 832, 10737]
    report = [{"elements": k, "ratio": b / k} for k, b in zip(got, [*got[1:], 76045], strict=True)]
    report = with_asked(with_requested(report, counts, 76045), (8.0, 16.0), finest=False, head=False)
    assert [r.get("asked_ratio") for r in report] == [16.0, 16.0, 16.0, None]
    notes = []
    levels = [np.zeros(76045, dtype=np.int64)] * 4
    said_off_plan(levels, report, 10, notes, None, 1, "", 5, 16.0)
    assert (
        notes[-1]
        == "a level coarsens more than 25% off the ratio asked: level 0 10.8x where 16x was asked (13.0x planned)"
    )
    assert not any("off the plan" in n for n in notes)


@pytest.mark.parametrize(("model", "ratio"), [("rtree", None), ("rtree", 8), ("metis", None)])
def test_coarsest_below_what_the_domain_allows_plans_no_level_that_barely_coarsens(model, ratio):
    """3 separate rings need 6 elements; --coarsest 1 planned 1, raised to 6 under a level of 8-10
    (6 > 9 > 60 with rtree, 6 > 10 > 71 with METIS: a level that coarsens 1.5x, which the docs drop).
    Now the plan goes down to the 6 the domain allows: every level at least 2x coarser than the one
    below, nested, no element around a hole, and the note that says why there are 6."""
    pts, q = _rings()
    h = build_hierarchy(points=pts, cells=[("quad", q)], coarsest=1, model=model, ratio=ratio)
    sizes = [int(lv.max()) + 1 for lv in h.levels]
    assert sizes[0] == 6 and all(b >= 2 * a for a, b in zip(sizes, sizes[1:], strict=False)), sizes
    assert is_nested(h.levels)
    for lv in h.levels:
        _, holes = merge(h.mesh, h.graph, lv, h.data.measures)
        assert np.unique(holes.elements).size == 0
    assert any("6 elements, more than --coarsest 1" in n for n in h.info["notes"]), h.info["notes"]


def test_mgcheck_says_what_the_asterisk_means_and_gives_no_ratio_against_an_unconverged_count(monkeypatch):
    """A solve that stops at the iteration cap: "500*" had no legend, and "smoothed 0.38x" was
    reported against pyamg's capped count. Now one line explains the asterisk, the text gives no
    iteration ratio where a solve did not converge (and says which), --json has null and the list."""
    import models.hierarchy.multigrid as mg
    from models import read_mesh
    from models.pipeline import prepare

    p, q = quads(24)
    h = build_hierarchy(points=p, cells=[("quad", q)], ratio=4)
    mesh = read_mesh(points=p, cells=[("quad", q)])
    _, data = prepare(mesh)
    monkeypatch.setattr(mg, "MAXITER", 3)
    rep = mg.mgcheck(mesh, data, h.levels)
    assert set(rep["unconverged"]) == {"unsmoothed", "smoothed", "pyamg_ua", "pyamg_sa"}
    assert rep["ratios"]["smoothed_iterations_vs_pyamg"] is None
    assert rep["ratios"]["unsmoothed_iterations_vs_pyamg"] is None
    assert rep["ratios"]["smoothed_complexity_vs_pyamg"] > 0 and rep["max_iterations"] == 3
    json.dumps(rep)  # (--json)
    text = mg.format_report(rep)
    assert "3*" in text and "*: hit the 3-iteration cap without reaching the relative residual 1e-8" in text
    assert "no iteration ratio, neither solve did not converge" not in text
    assert "unsmoothed: no iteration ratio, neither solve converged" in text
    assert "x iterations" not in text
    monkeypatch.setattr(mg, "MAXITER", 500)
    rep = mg.mgcheck(mesh, data, h.levels)
    assert rep["unconverged"] == [] and rep["ratios"]["smoothed_iterations_vs_pyamg"] > 0
    assert "*" not in mg.format_report(rep)


def test_a_reused_folder_keeps_no_level_files_of_an_earlier_deeper_hierarchy(tmp_path, capsys):
    """A 6-level hierarchy, then a 3-level one into the same folder: level_3.* to level_5.* were left
    beside the new levels, not nested with them, without a word. Now they are removed and one line
    says so; files not named like a level's (and folders, links) are left alone."""
    import meshio

    from models.cli.main import main

    p, q = quads(40)
    path = str(tmp_path / "sq.vtu")
    meshio.write(path, meshio.Mesh(np.c_[p, np.zeros(len(p))], [("quad", q)]))
    out = tmp_path / "h"
    deep = build_hierarchy(path, ratio=2.5, coarsest=2)
    deep.write(out)
    n_deep = len(deep.levels)
    keep = ["level_7.notes.txt", "mine.vtu", "level_01.vtu", "level_3.vtu.bak"]
    for name in keep:
        (out / name).write_text("x")
    (out / f"level_{n_deep + 1}.vtu").mkdir()  # (a folder: left alone)
    os.symlink(out / "mine.vtu", out / f"level_{n_deep + 2}.vtu")  # (a link: left alone)
    capsys.readouterr()
    assert main(["hierarchy", path, "-o", str(out), "--ratio", "8"]) == 0
    printed = capsys.readouterr().out
    index = json.load(open(out / "hierarchy.json"))
    n = len(index["levels"])
    assert 2 <= n < n_deep
    ours = [
        f
        for f in os.listdir(out)
        if f not in keep and os.path.isfile(out / f) and not os.path.islink(out / f)
    ]
    levels = sorted({int(f.split(".")[0].removeprefix("level_")) for f in ours if f.startswith("level_")})
    assert levels == list(range(n)), sorted(os.listdir(out))
    assert all((out / name).exists() for name in keep)
    assert (out / f"level_{n_deep + 1}.vtu").is_dir() and os.path.islink(out / f"level_{n_deep + 2}.vtu")
    said = [line for line in printed.splitlines() if "earlier hierarchy" in line]
    assert len(said) == 1 and f"level_{n}.*" in said[0] and f"level_{n_deep - 1}.*" in said[0], printed
    again = build_hierarchy(path, ratio=8)
    again.write(out)
    assert again.removed == []


def test_the_planes_judge_a_part_on_its_own_skeleton_with_the_same_characteristics():
    """_planes' sides of a part judged on the part's skeleton alone (models.hierarchy.repair._within:
    a Menger sponge's 10,800 hexahedra 1.72 -> 1.33 s, the same levels) give each side the Euler
    characteristic the whole skeleton gives it, rings and cavities included."""
    from meshes import hexes

    from models import read_mesh
    from models.hierarchy.repair import _within
    from models.pipeline import prepare
    from models.polytope.euler import UnitEuler

    p, h = hexes(8)
    mesh = read_mesh(points=p, cells=[("hexahedron", h)])
    graph, data = prepare(mesh)
    c = data.centroids
    units = (np.floor(c[:, 0] * 4) + 4 * np.floor(c[:, 1] * 4) + 16 * np.floor(c[:, 2] * 4)).astype(np.int64)
    ue = UnitEuler.of_cells(mesh, graph, units)
    rng = np.random.default_rng(3)
    ring = np.array([0, 1, 2, 6, 10, 9, 8, 4])  # (units around unit 5 in the bottom layer: a ring)
    for part in (np.arange(64), np.arange(32), ring, rng.choice(64, 20, replace=False)):
        sub = _within(ue, part)
        for _ in range(5):
            side = np.full(64, 2, dtype=np.int64)
            side[part] = rng.integers(0, 2, part.size)
            side[part[:2]] = [0, 1]
            assert np.array_equal(ue(side)[:2], sub(side)[:2])
    side = np.full(64, 2, dtype=np.int64)
    side[ring] = 0
    side[ring[1]] = 1  # (not a corner: the corner's two neighbours would touch along an edge)
    assert _within(ue, ring)(side)[0] == ue(side)[0] == 1  # (7 of the ring's 8: a ball)
    side[ring[1]] = 0
    side[5] = 1
    assert _within(ue, np.r_[ring, 5])(side)[0] == ue(side)[0] == 0  # (the whole ring: a handle)


def test_agglomerate_hierarchy_into_a_reused_folder_says_what_it_removed(tmp_path, capsys):
    """`magnet agglomerate --hierarchy` shares the writer: an earlier, deeper run's level files are
    removed there too, and said in one line."""
    import meshio

    from models.cli.main import main

    p, q = quads(24)
    path = str(tmp_path / "sq.vtu")
    meshio.write(path, meshio.Mesh(np.c_[p, np.zeros(len(p))], [("quad", q)]))
    out = tmp_path / "h"
    assert (
        main(["agglomerate", path, "--nref", "5", "-o", str(tmp_path / "a.vtu"), "--hierarchy", str(out)])
        == 0
    )
    deep = len(json.load(open(out / "hierarchy.json"))["levels"])
    capsys.readouterr()
    assert (
        main(["agglomerate", path, "--nref", "2", "-o", str(tmp_path / "a.vtu"), "--hierarchy", str(out)])
        == 0
    )
    printed = capsys.readouterr().out
    n = len(json.load(open(out / "hierarchy.json"))["levels"])
    assert n < deep
    assert not any(f.startswith(f"level_{n}.") for f in os.listdir(out))
    said = [line for line in printed.splitlines() if "earlier hierarchy" in line]
    assert len(said) == 1 and said[0].startswith("note: "), printed

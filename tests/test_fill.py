"""Closed surfaces filled with tetrahedra (models.mesh.fill, `magnet generate stl`,
`magnet agglomerate shell.stl --fill`, job option fill). Every surface is made at test time with
gmsh (OCC shapes, surface-meshed) and written by meshio (STL binary and ASCII, OBJ, PLY, OFF)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

gmsh = pytest.importorskip("gmsh")

from surfaces import enclosed_volume, surface_of  # noqa: E402

from models import api  # noqa: E402
from models.errors import MeshError, ParameterError  # noqa: E402
from models.mesh.fill import (  # noqa: E402
    _box_pairs,
    check_closed,
    fill_surface,
    find_intersection,
    read_surface,
)
from models.mesh.read import read_mesh  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def sphere(occ):
    occ.addSphere(0, 0, 0, 1)


def torus(occ):
    occ.addTorus(0, 0, 0, 1, 0.35)


def box(occ, origin=(0, 0, 0)):
    occ.addBox(*origin, 1, 1, 1)


def cad(occ):
    """About 130 units across: a plate with two bores, a dome and a ring fused on."""
    plate = occ.addBox(-65, -40, -20, 130, 80, 40)
    bores = [(3, occ.addCylinder(-30, 0, -30, 0, 0, 60, 15)), (3, occ.addCylinder(30, 0, -30, 0, 0, 60, 12))]
    cut, _ = occ.cut([(3, plate)], bores)
    occ.fuse(cut, [(3, occ.addSphere(0, 0, 20, 25)), (3, occ.addTorus(0, 0, -20, 40, 6))])


def _write(path, points, tris):
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris)]))
    return path


def tet_volume(points, tets) -> float:
    p = points[tets]
    d = np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]))
    return float(np.abs(d).sum() / 6)


def boundary_faces(tets) -> np.ndarray:
    faces = np.sort(tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
    uniq, counts = np.unique(faces, axis=0, return_counts=True)
    return uniq[counts == 1]


def triangle_keys(points, tris) -> set:
    """Each triangle as the sorted tuple of its corners' coordinates (independent of point numbering)."""
    return {tuple(sorted(map(tuple, points[t]))) for t in tris}


@pytest.fixture(scope="module")
def shapes():
    return {
        "sphere": surface_of(sphere, 0.15),
        "torus": surface_of(torus, 0.12),
        "box": surface_of(box, 0.2),
    }


WRITERS = {
    "stl-binary": ("sphere", "stl", {"binary": True}),
    "stl-ascii": ("torus", "stl", {"binary": False}),
    "obj": ("box", "obj", {}),
    "ply": ("sphere", "ply", {}),
    "off": ("torus", "off", {}),
}


@pytest.mark.filterwarnings("ignore:overflow:RuntimeWarning")  # meshio's ASCII STL sniffing
@pytest.mark.parametrize("case", list(WRITERS))
def test_kept_surface_is_filled_to_its_enclosed_volume(tmp_path, shapes, case):
    shape, ext, kw = WRITERS[case]
    points, tris = shapes[shape]
    path = tmp_path / f"{shape}.{ext}"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris)]), **kw)
    f = fill_surface(path)
    ref = enclosed_volume(points, tris)
    assert abs(tet_volume(f.points, f.tets) - ref) <= 1e-9 * ref
    assert abs(f.info["volume"] - ref) <= 1e-9 * ref and abs(f.info["enclosed_volume"] - ref) <= 1e-9 * ref
    # kept as it stands: the tetrahedra's boundary faces are the surface's triangles, corner for corner
    bnd = boundary_faces(f.tets)
    assert len(bnd) == len(tris) and f.info["remeshed"] is False
    read = meshio.read(str(path))  # the coordinates as the file holds them (ASCII STL rounds)
    assert triangle_keys(f.points, bnd) == triangle_keys(read.points, read.cells_dict["triangle"])
    assert 0.5 <= f.info["cells"] / f.info["estimated_cells"] <= 2.0


def test_badly_oriented_triangles_are_turned(tmp_path, shapes):
    points, tris = shapes["torus"]
    bad = tris.copy()
    bad[::5] = bad[::5, ::-1]  # every fifth triangle reversed
    inside_out = tris[:, ::-1]  # all reversed: consistent, but inward
    ref = enclosed_volume(points, tris)
    for name, t in (("some.stl", bad), ("inward.stl", inside_out)):
        meshio.write(str(tmp_path / name), meshio.Mesh(points, [("triangle", t)]))
        f = fill_surface(tmp_path / name)
        assert abs(f.info["enclosed_volume"] - ref) <= 1e-9 * ref
        assert abs(f.info["volume"] - ref) <= 1e-9 * ref
    s = read_surface(tmp_path / "some.stl")
    check_closed(s)
    assert s.info["oriented"] is False and s.info["reoriented"] in (
        len(tris[::5]),
        len(tris) - len(tris[::5]),
    )
    assert enclosed_volume(s.points, s.triangles) == pytest.approx(ref, rel=1e-12)
    p = s.points[s.triangles]  # now outward: the signed volume is positive
    assert np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() > 0


def test_remesh_relative_and_absolute_size(tmp_path, shapes):
    points, tris = shapes["sphere"]
    path = tmp_path / "sphere.stl"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris)]))
    diag = np.linalg.norm(points.max(0) - points.min(0))
    rel = fill_surface(path, size=0.05)
    assert rel.info["remeshed"] and rel.info["size"] == pytest.approx(0.05 * diag)
    assert rel.info["volume"] == pytest.approx(enclosed_volume(points, tris), rel=0.03)
    assert 0.5 <= rel.info["cells"] / rel.info["estimated_cells"] <= 2.0
    absolute = fill_surface(path, size_abs=0.1)
    assert absolute.info["size"] == 0.1
    assert absolute.info["cells"] > 2 * rel.info["cells"]  # a smaller size, more tetrahedra
    with pytest.raises(ParameterError, match="not both"):
        fill_surface(path, size=0.1, size_abs=0.2)
    with pytest.raises(ParameterError, match="fraction of the bounding-box diagonal"):
        fill_surface(path, size=3)


def test_estimate_over_the_limit_is_refused_before_meshing(tmp_path, shapes):
    points, tris = shapes["box"]
    path = tmp_path / "box.stl"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris)]))
    with pytest.raises(
        ParameterError, match=r"about [\d,]+ tetrahedra, more than the limit of 1,000.*--max-cells"
    ):
        fill_surface(path, size=0.01, max_cells=1000)


def _no_library_text(message: str) -> None:
    for raw in ("PLC", "Exception", "Traceback", "gmsh", "Error:", "Singular"):
        assert raw not in message


def test_open_surface_is_refused_saying_where(tmp_path, shapes):
    points, tris = shapes["box"]
    top = np.isclose(points[tris][:, :, 2], 1.0).all(1)  # the face z = 1 removed
    path = tmp_path / "open.stl"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris[~top])]))
    with pytest.raises(MeshError) as err:
        fill_surface(path)
    msg = str(err.value)
    assert msg.startswith("open.stl is not a closed surface: ") and "boundary edges" in msg
    count = int(re.search(r"([\d,]+) boundary edges", msg).group(1).replace(",", ""))
    rim = np.sort(tris[top][:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    _, seen = np.unique(rim, axis=0, return_counts=True)
    assert count == (seen == 1).sum() > 4  # the rim of the removed face
    x, y, z = map(float, re.search(r"e\.g\. at \(([^)]*)\)", msg).group(1).split(","))
    assert z == pytest.approx(1.0) and (min(x, y) == pytest.approx(0) or max(x, y) == pytest.approx(1))
    assert "MeshLab" in msg
    _no_library_text(msg)


def test_self_intersecting_surface_is_refused_with_a_point(tmp_path, shapes):
    points, tris = shapes["box"]
    shift = np.array([0.5, 0.3, 0.4])
    both = meshio.Mesh(
        np.vstack([points, points + shift]), [("triangle", np.vstack([tris, tris + len(points)]))]
    )
    path = tmp_path / "overlap.stl"
    meshio.write(str(path), both)
    with pytest.raises(MeshError) as err:
        fill_surface(path)
    msg = str(err.value)
    assert msg.startswith("overlap.stl intersects itself: ") and "meshfix" in msg
    with pytest.raises(MeshError, match="intersects itself"):  # checked before re-meshing too
        fill_surface(path, remesh=True)
    p = np.array([float(v) for v in re.search(r"e\.g\. at \(([^)]*)\)", msg).group(1).split(",")])
    # the point lies on both boxes' surfaces: inside (or on) each box, on a face of each
    for lo in (np.zeros(3), shift):
        assert (p >= lo - 1e-9).all() and (p <= lo + 1 + 1e-9).all()
        assert np.isclose(p, lo).any() or np.isclose(p, lo + 1).any()
    _no_library_text(msg)


def test_clean_surfaces_have_no_crossing(tmp_path, shapes):
    for name, (points, tris) in shapes.items():
        s = read_surface(_write(tmp_path / f"{name}.stl", points, tris))
        assert find_intersection(s) == (0, None)


@pytest.mark.parametrize("seed", [0, 1])
def test_grid_finds_every_overlapping_box_pair(seed):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(0, 10, size=(400, 3))
    hi = lo + rng.uniform(0, 1, size=(400, 3)) ** 4 * 4  # mostly small boxes, a few long ones
    overlap = (lo[:, None] <= hi[None]).all(2) & (lo[None] <= hi[:, None]).all(2)
    want = {(i, j) for i, j in zip(*np.nonzero(np.triu(overlap, 1)), strict=True)}
    for entries in (10**6, 2000):  # a fine grid, and one coarsened to fit 2,000 entries
        got = {tuple(map(int, q)) for q in _box_pairs(lo, hi, entries, 10**7)}
        assert want <= got


def test_non_manifold_and_unreadable_surfaces(tmp_path, shapes):
    points, tris = shapes["box"]
    path = tmp_path / "twice.stl"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", np.vstack([tris, tris[:1]]))]))
    with pytest.raises(MeshError, match=r"twice.stl is not a manifold surface: 3 edges are shared by more"):
        fill_surface(path)
    bad = tmp_path / "garbage.stl"
    bad.write_bytes(b"solid x\n facet normal 0 0 1\n  outer loop\n   vertex 1 2\n")
    with pytest.raises(MeshError) as err:
        read_surface(bad)
    assert str(err.value) == "cannot read garbage.stl as STL: the file is corrupted or not STL"
    with pytest.raises(ParameterError, match="not a .vtu"):
        read_surface(tmp_path / "cube.vtu")


def _magnet(*args, cwd):
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-m", "models.cli", *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
    )


@pytest.fixture(scope="module")
def cad_shell(tmp_path_factory):
    points, tris = surface_of(cad, 4.0, curvature=12)
    assert 7_000 <= len(tris) <= 13_000  # a real CAD export's size (the had 10,910)
    assert 120 <= np.ptp(points, axis=0).max() <= 140
    path = tmp_path_factory.mktemp("cad") / "shell.stl"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris)]))
    return path, enclosed_volume(points, tris)


def test_cad_shell_fills_and_agglomerates_in_one_command(tmp_path, cad_shell):
    path, ref = cad_shell
    out = tmp_path / "out.vtu"
    r = _magnet(
        "agglomerate", path, "--fill", "--k", "64", "-o", out, "--metrics", tmp_path / "m.json", cwd=tmp_path
    )
    assert r.returncode == 0, r.stderr
    assert re.search(r"filled shell.stl \([\d,]+ triangles kept\): [\d,]+ tetrahedra", r.stdout)
    assert "64 elements" in r.stdout
    back = read_mesh(out)  # the polyhedra of the output, volumes from their faces
    assert back.n_cells == 64
    assert abs(back.meta["signed_measures"].sum() - ref) <= 1e-9 * ref
    assert json.loads((tmp_path / "m.json").read_text())


def test_generate_stl_cli_writes_and_refuses_in_one_line(tmp_path, cad_shell, shapes):
    path, ref = cad_shell
    out = tmp_path / "filled.vtu"
    r = _magnet("generate", "stl", "--stl", path, "-o", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    m = meshio.read(out)
    assert abs(tet_volume(m.points, m.cells_dict["tetra"]) - ref) <= 1e-9 * ref
    points, tris = shapes["box"]
    open_path = tmp_path / "open.obj"
    meshio.write(str(open_path), meshio.Mesh(points, [("triangle", tris[: len(tris) // 2])]))
    for args in (
        ["--stl", open_path],
        ["--stl", path, "--size", "0.001"],
        ["--stl", path, "--size", "0.05", "--size-abs", "3"],
    ):
        r = _magnet("generate", "stl", *args, "-o", tmp_path / "x.vtu", cwd=tmp_path)
        assert r.returncode == 2
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("magnet: error: "), r.stderr
    assert "--max-cells" in _magnet("generate", "stl", "--help", cwd=tmp_path).stdout


def test_agglomerate_a_surface_without_fill_points_to_fill(tmp_path, shapes):
    points, tris = shapes["sphere"]
    path = tmp_path / "ball.stl"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris)]))
    r = _magnet("agglomerate", path, "--k", "4", "-o", tmp_path / "o.vtu", cwd=tmp_path)
    assert r.returncode == 2 and "magnet agglomerate ball.stl --fill" in r.stderr


def test_job_option_fill(tmp_path, shapes):
    points, tris = shapes["sphere"]
    path = tmp_path / "ball.ply"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris)]))
    info = api.inspect_mesh(path, check=True)
    assert info["surface"]["triangles"] == len(tris) and info["cells"] == info["surface"]["estimated_cells"]
    with pytest.raises(ParameterError, match="options.fill: the mesh is a closed surface"):
        api.validate_params({"k": 8}, info)
    with pytest.raises(ParameterError, match="go with options.fill"):
        api.validate_params({"k": 8, "options": {"fill_remesh": True}})
    with pytest.raises(ParameterError, match="fill_size must be <= 1"):
        api.validate_params({"k": 8, "options": {"fill": True, "fill_size": 2}})
    p = api.validate_params({"k": 8, "options": {"fill": "true"}}, info)
    assert p["options"]["fill"] is True and "fill" not in api.validate_params({"k": 8})["options"]
    stages = []
    s = api.run_job(
        path, tmp_path / "job", {"k": 8, "options": {"fill": True}}, lambda f, st: stages.append(st)
    )
    assert s["elements"] == 8 and stages[0] == "fill" and "fill" in s["timings"]
    ref = enclosed_volume(points, tris)
    assert abs(s["fill"]["volume"] - ref) <= 1e-9 * ref
    assert abs(read_mesh(tmp_path / "job" / "mesh.vtu").meta["signed_measures"].sum() - ref) <= 1e-9 * ref


def _nested(shapes, radii):
    """Concentric copies of the sphere's triangles scaled by `radii` (largest first), each with
    outward normals as gmsh makes them (a writer that orients every shell outward), as one surface."""
    points, tris = shapes["sphere"]
    pts, tri = [], []
    for r in radii:
        tri.append(tris + sum(len(p) for p in pts))
        pts.append(points * r)
    return np.concatenate(pts), np.concatenate(tri)


@pytest.mark.parametrize("radii", [(2.0, 0.5), (2.0, 1.0, 0.4)])
def test_inner_shells_bound_cavities_and_stay_empty(tmp_path, shapes, radii):
    """A hollow body (a shell inside a shell) is filled between them, its cavity left empty; a ball
    inside that cavity (three shells) is filled again. Sweep T: the cavity was filled, a volume of
    the outer sphere's (1.6% too much), whichever way the inner shell's normals pointed."""
    points, tris = _nested(shapes, radii)
    vols = [enclosed_volume(*_nested(shapes, (r,))) for r in radii]
    ref = vols[0] - vols[1] + (vols[2] if len(vols) > 2 else 0.0)
    for flip_inner in (False, True):
        t = tris.copy()
        if flip_inner:  # the cavity's normals into it, as a careful writer makes them
            n0 = len(shapes["sphere"][1])
            t[n0 : 2 * n0] = t[n0 : 2 * n0, ::-1]
        f = fill_surface(_write(tmp_path / "hollow.stl", points, t))
        assert tet_volume(f.points, f.tets) == pytest.approx(ref, rel=1e-9)
        assert f.info["enclosed_volume"] == pytest.approx(ref, rel=1e-9)
        c = f.points[f.tets].mean(axis=1)
        r = np.linalg.norm(c, axis=1)
        empty = (r < 0.97 * radii[1]) & (r > 1.03 * radii[2]) if len(radii) > 2 else r < 0.97 * radii[1]
        assert not empty.any()  # no tetrahedron inside the cavity
    with pytest.raises(ParameterError, match="cavities"):
        fill_surface(_write(tmp_path / "hollow.stl", points, tris), remesh=True)


def _box_quads(n=4):
    """A unit cube's surface as n x n quads per side: (points, quads), as a writer with no care for
    orientation makes them."""
    import itertools

    g = np.linspace(0.0, 1.0, n + 1)
    pts, quads = [], []
    for axis, side in itertools.product(range(3), (0.0, 1.0)):
        u, v = [a for a in range(3) if a != axis]
        base = len(pts)
        for j, i in itertools.product(range(n + 1), range(n + 1)):
            p = [0.0, 0.0, 0.0]
            p[axis], p[u], p[v] = side, g[i], g[j]
            pts.append(p)
        for j, i in itertools.product(range(n), range(n)):
            q = [
                base + j * (n + 1) + i,
                base + j * (n + 1) + i + 1,
                base + (j + 1) * (n + 1) + i + 1,
                base + (j + 1) * (n + 1) + i,
            ]
            quads.append(q)  # (orientation: the fill turns each shell outward itself)
    return np.array(pts), np.array(quads)


def test_off_and_obj_as_other_tools_write_them(tmp_path):
    """Sweep T: OFF with quads or with a colour after each face, and OBJ faces 'v/vt/vn' with fewer
    texture coordinates than points and negative (relative) indices, were refused as corrupted
    (meshio's readers). Each now fills the cube to volume 1 (the quads cut into triangles)."""
    pts, quads = _box_quads()
    off = tmp_path / "cube.off"
    lines = ["OFF", "# a comment", f"{len(pts)} {len(quads)} 0"]
    lines += [f"{x:.17g} {y:.17g} {z:.17g}" for x, y, z in pts]
    lines += ["4 " + " ".join(map(str, q)) + " 255 0 0" for q in quads]  # a colour after each face
    off.write_text("\n".join(lines) + "\n")
    obj = tmp_path / "cube.obj"
    lines = ["mtllib cube.mtl", "o cube"] + [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in pts]
    lines += ["vt 0 0", "vt 1 0", "vt 1 1", "vn 0 0 1"]
    for q in quads:  # negative indices: counted back from the last point
        lines.append("f " + " ".join(f"{int(i) - len(pts)}/{1 + k % 3}/1" for k, i in enumerate(q)))
    obj.write_text("\n".join(lines) + "\n")
    for path in (off, obj):
        f = fill_surface(path)
        assert tet_volume(f.points, f.tets) == pytest.approx(1.0, rel=1e-12)
        assert f.info["enclosed_volume"] == pytest.approx(1.0, rel=1e-12)
    # one face of the cube alone is a planar mesh of quads: read as quads, not refused
    face = tmp_path / "face.obj"
    keep = quads[:16]
    used = np.unique(keep)
    remap = np.full(len(pts), -1)
    remap[used] = np.arange(used.size)
    face.write_text(
        "\n".join(
            [f"v {x} {y} {z}" for x, y, z in pts[used]]
            + ["f " + " ".join(str(i + 1) for i in remap[q]) for q in keep]
        )
    )
    mesh = read_mesh(str(face))
    assert (
        mesh.dim == 2
        and mesh.n_cells == 16
        and float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(1.0)
    )
    bad = tmp_path / "bad.off"
    bad.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n")
    with pytest.raises(MeshError, match=r"cannot read bad\.off as OFF: it announces 3 points and 1 faces"):
        read_surface(bad)


def test_an_open_curved_surface_is_refused_alike_by_check_and_upload(tmp_path, shapes):
    """A curved surface that is open can be neither agglomerated (not planar) nor filled (not
    closed): `magnet check` and the service's upload check (api.inspect_mesh) say both, in the
    same sentence (outside sweep V: the CLI said the first, HTTP the second)."""
    from models.api import inspect_mesh
    from models.mesh.check import check_file

    points, tris = shapes["box"]
    top = np.isclose(points[tris][:, :, 2], 1.0).all(1)
    path = tmp_path / "cap.stl"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris[~top])]))
    said = check_file(str(path))["issues"][0]["message"]
    with pytest.raises(MeshError) as err:
        inspect_mesh(str(path))
    assert str(err.value) == said
    assert (
        "non-planar surface" in said and "nor can it be filled as it is: it is not a closed surface" in said
    )
    import subprocess
    import sys

    r = subprocess.run(  # agglomerate says the same (it used to suggest --fill for it)
        [
            sys.executable,
            "-m",
            "models.cli",
            "agglomerate",
            str(path),
            "-o",
            str(tmp_path / "o.vtu"),
            "--k",
            "2",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 2 and r.stderr.strip() == f"magnet: error: {said}", r.stderr

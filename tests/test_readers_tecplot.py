"""Tecplot ASCII files as CFD codes write them, read by VTK's vtkTecplotReader (as ParaView reads
them): ordered (structured I, J, K) zones in POINT and BLOCK packing, finite-element zones of the
new (ZONETYPE=...) and old (F=FEPOINT, ET=...) headers, several zones in one file (their shared
points merged, each zone a named group), comment and AUXDATA lines. Outside sweep S found every
ordered zone refused, files with comments refused, and a second zone silently dropped (meshio's
reader, which read .dat/.tec before). Each file is checked against VTK's own reading of it (cells,
total volume / area) and agglomerated; our VTU read back by VTK holds the same measure. Binary
Tecplot is refused in one sentence, and a mutation test covers the family."""

from __future__ import annotations

import numpy as np
import pytest
import vtk_corpus as vc

from models.errors import MeshError
from models.mesh.read import pick_reader, read_mesh

TOL = 1e-9
KUHN = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]


def _num(a) -> str:
    return "\n".join(" ".join(f"{v:.17g}" for v in row) for row in np.atleast_2d(a))


def _lattice(ni: int, nj: int, nk: int):
    """x, y, z of a graded rectilinear lattice (I fastest, as Tecplot orders points): planar faces."""
    rng = np.random.default_rng(3)
    xs, ys, zs = (np.r_[0, np.cumsum(rng.uniform(0.5, 1.5, n - 1))] for n in (ni, nj, nk))
    z, y, x = np.meshgrid(zs, ys, xs, indexing="ij")
    return x.ravel(), y.ravel(), z.ravel()


def ordered(path, ni, nj, nk=1, packing="POINT", cell_centred=False, chatter=False, two_d=False):
    x, y, z = _lattice(ni, nj, nk)
    p = x * 0.1 + y
    names = '"X", "Y"' if two_d else '"X", "Y", "Z"'
    lines = []
    if chatter:
        lines += ["# written by FlowSolver 3.2", '# date "2024-01-01"']
    lines += ['TITLE = "ordered grid"', f'VARIABLES = {names}, "Pressure"']
    if chatter:
        lines += ['DATASETAUXDATA Solver="flow"']
    dims = f"I={ni}, J={nj}" + ("" if nk == 1 else f", K={nk}")
    loc = ""
    if cell_centred:
        loc = f", VARLOCATION=([{3 if two_d else 4}]=CELLCENTERED)"
    lines.append(f'ZONE T="block1", {dims}, DATAPACKING={packing}{loc}')
    if chatter:
        lines += ['AUXDATA Common.Time="0.0"', "STRANDID=0, SOLUTIONTIME=0"]
    cols = [x, y] if two_d else [x, y, z]
    if packing == "POINT":
        lines.append(_num(np.column_stack([*cols, p])))
    else:
        ncell = (ni - 1) * (nj - 1) * max(nk - 1, 1)
        pc = np.linspace(0, 1, ncell) if cell_centred else p
        lines += [_num(c.reshape(-1, 5) if c.size % 5 == 0 else c[None, :]) for c in (*cols, pc)]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _fe_zone(name, pts, cells, zonetype, old=False, packing="POINT"):
    n, e = len(pts), len(cells)
    if old:
        et = {"FEBRICK": "BRICK", "FETETRAHEDRON": "TETRAHEDRON", "FEQUADRILATERAL": "QUADRILATERAL"}
        head = f'ZONE T="{name}", N={n}, E={e}, F=FE{packing}, ET={et[zonetype]}'
    else:
        head = f'ZONE T="{name}", NODES={n}, ELEMENTS={e}, DATAPACKING={packing}, ZONETYPE={zonetype}'
    val = pts[:, 0] + 2 * pts[:, 1]
    if packing == "POINT":
        body = _num(np.column_stack([pts, val]))
    else:
        body = "\n".join(_num(c[None, :]) for c in (*pts.T, val))
    return "\n".join([head, body, _num(np.asarray(cells) + 1).replace(".0", "")])


def fe(path, zones, dims=3, chatter=False):
    names = '"X", "Y", "Z", "T"' if dims == 3 else '"X", "Y", "T"'
    lines = ['TITLE = "fe"', f"VARIABLES = {names}"]
    if chatter:
        lines = ["# exported by a solver", *lines, 'DATASETAUXDATA Version="7"']
    lines += [_fe_zone(*z[:4], **(z[4] if len(z) > 4 else {})) for z in zones]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _hexes(nx=3, ny=2, nz=2, shift=0.0):
    """vc.grid's hexahedra on an axis-aligned lattice of binary fractions: VTK's Tecplot reader
    keeps points in float32, and these survive it exactly (faces stay planar)."""
    _, h = vc.grid(nx, ny, nz)
    idx = np.arange((nx + 1) * (ny + 1) * (nz + 1))
    i, j, k = idx % (nx + 1), (idx // (nx + 1)) % (ny + 1), idx // ((nx + 1) * (ny + 1))
    return np.column_stack([i * 0.5 + shift, j * 0.25, k * 0.75]), h


def _quads(nx=4, ny=3):
    p, q = vc.quad_grid(nx, ny)
    return p[:, :2], q


def _cases(tmp):
    p, h = _hexes()
    tets = np.concatenate([h[:, k] for k in KUHN])
    q2, quads = _quads()
    tri = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    return {
        "ordered-3d-point": ordered(tmp / "o3p.dat", 5, 4, 3),
        "ordered-3d-block": ordered(tmp / "o3b.tec", 5, 4, 3, packing="BLOCK"),
        "ordered-3d-cell-centred": ordered(tmp / "o3c.dat", 5, 4, 3, packing="BLOCK", cell_centred=True),
        "ordered-3d-chatter": ordered(tmp / "o3x.dat", 5, 4, 3, chatter=True),
        "ordered-2d-xy": ordered(tmp / "o2.dat", 6, 5, two_d=True),
        "ordered-2d-xyz0": ordered(tmp / "o2z.tp", 6, 5),
        "febrick": fe(tmp / "fb.dat", [("fe", p, h, "FEBRICK")]),
        "febrick-block-chatter": fe(tmp / "fbb.dat", [("fe", p, h, "FEBRICK", {"packing": "BLOCK"})], chatter=True),
        "fepoint-brick-old": fe(tmp / "fo.dat", [("fe", p, h, "FEBRICK", {"old": True})]),
        "fetetrahedron": fe(tmp / "ft.dat", [("fe", p, tets, "FETETRAHEDRON")]),
        "fequadrilateral": fe(tmp / "fq.dat", [("s", q2, quads, "FEQUADRILATERAL")], dims=2),
        "fetriangle": fe(tmp / "ftr.dat", [("s", q2, tri, "FETRIANGLE")], dims=2),
    }  # fmt: skip


CASES = (
    "ordered-3d-point", "ordered-3d-block", "ordered-3d-cell-centred", "ordered-3d-chatter",
    "ordered-2d-xy", "ordered-2d-xyz0", "febrick", "febrick-block-chatter", "fepoint-brick-old",
    "fetetrahedron", "fequadrilateral", "fetriangle",
)  # fmt: skip


@pytest.mark.parametrize("name", CASES)
def test_tecplot_matches_vtk_and_agglomerates(tmp_path, name):
    path = _cases(tmp_path)[name]
    assert pick_reader(path) == ("vtk", "tecplot")
    n_ref, vol_ref = vc.vtk_reference(path)
    mesh = read_mesh(path)
    assert mesh.n_cells == n_ref
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(vol_ref, rel=TOL)
    res, n_out, vol_out = vc.agglomerate_read_back(path, 3, tmp_path / "out.vtu")
    assert res.n_elements == 3 and n_out == 3
    assert vol_out == pytest.approx(vol_ref, rel=TOL)


def test_tecplot_zones_are_one_mesh_with_named_groups(tmp_path):
    """Two FEBRICK zones, each with its own copy of the points of the face they share (as a
    multi-zone export writes them), and a third ordered zone beside them: every zone is read (meshio
    kept the first alone, silently), the shared points merged into one connected mesh, each zone a
    group named by its T=."""
    from scipy.sparse.csgraph import connected_components

    from models.pipeline import prepare

    pl, hl = _hexes(2, 2, 2)
    pr, hr = _hexes(3, 2, 2, shift=1.0)
    path = fe(tmp_path / "zones.tec", [("left", pl, hl, "FEBRICK"), ("right", pr, hr, "FEBRICK")])
    mesh = read_mesh(path)
    n_ref, vol_ref = vc.vtk_reference(path)
    assert mesh.n_cells == n_ref == len(hl) + len(hr)
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(vol_ref, rel=TOL)
    assert mesh.n_points == len(pl) + len(pr) - 9  # the 9 points of the shared face once
    graph, _ = prepare(mesh)
    assert connected_components(graph.matrix())[0] == 1
    assert mesh.meta["group_names"] == {1: "left", 2: "right"}
    assert np.array_equal(np.unique(mesh.tags), [1, 2])
    assert (mesh.tags == 1).sum() == len(hl)


def test_binary_and_foreign_files_are_refused_in_one_sentence(tmp_path):
    plt = tmp_path / "run.plt"
    plt.write_bytes(b"#!TDV112" + bytes(range(256)) * 4)
    with pytest.raises(MeshError) as err:
        read_mesh(str(plt))
    msg = str(err.value)
    assert "run.plt" in msg and "binary Tecplot" in msg and "ASCII" in msg
    dat = tmp_path / "table.dat"
    dat.write_text("1 2 3\n4 5 6\n")
    with pytest.raises(MeshError) as err:
        read_mesh(str(dat))
    assert "table.dat" in str(err.value) and "Tecplot" in str(err.value)
    assert "\n" not in str(err.value)


def test_a_zone_type_its_rows_do_not_fit_is_said(tmp_path):
    """meshio's Tecplot writer, given triangles then tetrahedra, writes the tetrahedra as 8-node rows
    under ZONETYPE = FEQUADRILATERAL; VTK's reader reads quads and then fails: the refusal says the
    header does not fit the data (it was "corrupted or not a Tecplot file")."""
    import meshio
    from meshes import tets

    from models.mesh.sandbox import read_mesh_safe

    p, t = tets(3)
    faces = np.sort(t[:, [0, 1, 2]], axis=1)[:10]
    path = tmp_path / "mixed.dat"
    with _quiet():  # (meshio prints that it skips the triangles)
        meshio.write(str(path), meshio.Mesh(p, [("triangle", faces), ("tetra", t)]), file_format="tecplot")
    assert "FEQUADRILATERAL" in path.read_text()
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(path))
    msg = str(err.value)
    assert msg.startswith("cannot read mixed.dat as Tecplot: its zone is FEQUADRILATERAL (4 nodes"), msg
    assert "rows hold 8 node ids" in msg, msg


def _quiet():
    import contextlib
    import io

    return contextlib.redirect_stdout(io.StringIO())


def test_tecplot_mutants_are_a_mesh_or_one_clear_sentence(tmp_path):
    """The mutation test (tests/mutants.py) over an ordered and an FE Tecplot file, read in the
    sandbox as the service reads: a Mesh, or one sentence naming the file and the format with no
    library text (a crash or a hang of VTK's reader is a sentence too)."""
    from mutants import read_mutants

    p, h = _hexes()
    sources = [
        ordered(tmp_path / "src_o.dat", 5, 4, 3),
        fe(tmp_path / "src_f.dat", [("fe", p, h, "FEBRICK")]),
    ]
    refused = 0
    for s, src in enumerate(sources):
        refused += read_mutants(tmp_path, open(src, "rb").read(), f"m{s}_", ".dat", "Tecplot", 5100 + s, 12)[
            "refused"
        ]
    assert refused >= 5

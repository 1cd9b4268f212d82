"""The compiled read-stage helpers (models/mesh/_fastmesh.c) against their numpy twins in
models/mesh/geometry.py and orientation.py: the same measures, centroids, orientation flips and
connectivity bit for bit, on perturbed meshes (no ties), mixed ones and meshes that need flips."""

from __future__ import annotations

import numpy as np
import pytest
from meshes import hexes, mixed_2d, mixed_3d, quads, tets, triangles, wedges

from models.errors import MeshError
from models.mesh.read import mesh_from_arrays
from models.native import compiled


def _perturbed(p, seed=0, amount=0.15):
    rng = np.random.default_rng(seed)
    h = 1.0 / round(len(p) ** (1 / 3))
    return p + rng.uniform(-amount * h, amount * h, p.shape)


def _meshes():
    p, h = hexes(6)
    yield "hexahedra", _perturbed(p), [("hexahedron", h)]
    p7, h7 = hexes(7)  # 343 cells: blocks of four (measure_hex4) and a remainder of three
    yield "hexahedra, 7^3", _perturbed(p7, 6), [("hexahedron", h7)]
    rng = np.random.default_rng(1)
    mirrored = h.copy()
    sel = rng.random(len(h)) < 0.3  # some cells given inside out: the orientation flips them
    mirrored[sel] = mirrored[sel][:, [0, 3, 2, 1, 4, 7, 6, 5]]
    yield "hexahedra, 30% mirrored", _perturbed(p, 2), [("hexahedron", mirrored)]
    yield "hexahedra, all mirrored", _perturbed(p, 3), [("hexahedron", h[:, [0, 3, 2, 1, 4, 7, 6, 5]])]
    p, w = wedges(5)
    yield "wedges", _perturbed(p, 4), [("wedge", w)]
    p, blocks = mixed_3d(4)
    yield "hexahedra, pyramids, tetrahedra", _perturbed(p, 5, 0.05), blocks
    p, blocks = mixed_3d(24)  # 8,192 cells and more: the general layout in threads
    mirrored = [(name, c[:, [0, 2, 1, 3]] if name == "tetra" else c) for name, c in blocks]
    yield "hexahedra, pyramids, tetrahedra, 24^3, tetrahedra mirrored", _perturbed(p, 6, 0.05), mirrored
    # planar meshes: measure_polygon and the edge check (cells_validate in 2D)
    p, t = triangles(60)
    yield "triangles", _perturbed_2d(p, 7), [("triangle", t)]
    p, q = quads(50)
    sel = np.random.default_rng(8).random(len(q)) < 0.3
    q[sel] = q[sel][:, ::-1]
    yield "quads, 30% mirrored", _perturbed_2d(p, 9), [("quad", q)]
    p, blocks = mixed_2d(40)
    yield "quads and triangles", _perturbed_2d(p, 10), blocks
    yield "polygons of 8 to 22 nodes", *_strips(30)


def _perturbed_2d(p, seed):
    rng = np.random.default_rng(seed)
    h = 1.0 / round(len(p) ** 0.5)
    return p + rng.uniform(-0.15 * h, 0.15 * h, p.shape)


def _strips(n: int):
    """Polygons of 8, 12 and 22 nodes (rows of 3, 5 and 10 quads of an n x n grid merged), some
    given clockwise: sums over more than 8 terms (numpy would sum those pairwise; both sides here
    sum in cycle order)."""
    p = _perturbed_2d(*quads(n)[:1], 11)
    v = lambda a, b: a * (n + 1) + b  # noqa: E731
    blocks, x = [], 0
    for w in (3, 5, 10):  # strips of w quads along x, for every row y
        rows = []
        for y in range(n):
            bottom = [v(x + i, y) for i in range(w + 1)]
            top = [v(x + i, y + 1) for i in range(w, -1, -1)]
            cell = bottom + top
            rows.append(cell if y % 3 else cell[::-1])
        blocks.append(("polygon", np.array(rows)))
        x += w
    rest = quads(n)[1]
    rest = rest[rest[:, 0] // (n + 1) >= x]  # the columns of quads right of the strips
    return p, blocks + [("quad", rest)]


def _read(points, blocks):
    m = mesh_from_arrays(points, blocks)
    return m


@pytest.mark.parametrize("case", list(_meshes()), ids=lambda c: c[0])
def test_compiled_validation_equals_numpy(case, monkeypatch):
    assert compiled("mesh._fastmesh") is not None, (
        "models/mesh/_fastmesh.c was not built (setup.py build_ext)"
    )
    _, points, blocks = case
    a = _read(points, blocks)
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    assert compiled("mesh._fastmesh") is None
    b = _read(points, blocks)
    for key in ("measures", "centroids", "signed_measures"):
        assert np.array_equal(a.meta[key], b.meta[key]), key
    assert np.array_equal(a.connectivity, b.connectivity)
    assert a.meta["orientation"] == b.meta["orientation"]
    assert (a.meta["signed_measures"] > 0).all()


def test_compiled_consistency_check_finds_a_contradiction():
    """Two hexahedra glued through a face that both run the same way, one folded: no orientation
    exists where every cell is positive, so the fast check must answer False (and the full path
    then decides), never True."""
    fast = compiled("mesh._fastmesh")
    from models.mesh.container import VTK_HEXAHEDRON
    from models.mesh.geometry import fixed_template

    p, h = hexes(2)
    tmpl, tsize = fixed_template(VTK_HEXAHEDRON)
    conn = np.ascontiguousarray(h, dtype=np.int64).reshape(-1)
    npts = np.array([len(p)], dtype=np.int64)
    none = np.zeros(len(h), np.uint8)
    assert fast.fixed_consistent(conn, tmpl, tsize, none, npts)
    one = none.copy()
    one[0] = 1  # cell 0 reversed: its shared faces now run the same way as its neighbours'
    assert not fast.fixed_consistent(conn, tmpl, tsize, one, npts)
    assert fast.fixed_consistent(conn, tmpl, tsize, np.ones(len(h), np.uint8), npts)


def test_a_degenerate_hexahedron_is_still_refused():
    p, h = hexes(2)
    p = p.copy()
    h = h.copy()
    h[3, 4:] = h[3, :4]  # its top on its bottom: zero volume
    with pytest.raises(MeshError, match="degenerate"):
        _read(p, [("hexahedron", h)])


def test_compiled_consistency_in_large_buckets_equals_numpy():
    """Tetrahedra: ~24 faces share a smallest node (the buckets compared by chains of keys, not
    pairwise); the compiled check answers as orientation._consistent for the cells' own signs and
    for random flips (most of them contradictions)."""
    fast = compiled("mesh._fastmesh")
    from models.mesh.container import VTK_TETRA
    from models.mesh.geometry import cell_faces, fixed_template
    from models.mesh.orientation import _consistent

    p, t = tets(5)
    m = mesh_from_arrays(p, [("tetra", t)])  # oriented: every cell positive
    c = m.connectivity.reshape(-1, 4)
    tmpl, tsize = fixed_template(VTK_TETRA)
    conn = np.ascontiguousarray(c, dtype=np.int64).reshape(-1)
    npts = np.array([len(p)], dtype=np.int64)
    faces = cell_faces(m)
    starts = np.bincount(c[:, tmpl.reshape(4, 3)].min(axis=2).reshape(-1))  # faces per smallest node
    assert starts.max() > 8  # the chained comparison is exercised
    rng = np.random.default_rng(7)
    flips = [np.zeros(len(c), np.uint8), np.ones(len(c), np.uint8)]
    flips += [(rng.random(len(c)) < q).astype(np.uint8) for q in (0.01, 0.5)]
    one = np.zeros(len(c), np.uint8)
    one[len(c) // 2] = 1
    flips.append(one)
    answers = []
    for f in flips:
        want = _consistent(faces, f.view(bool), len(p))
        got = fast.fixed_consistent(conn, tmpl, tsize, f, npts)
        assert want is not None
        assert got == bool(want)
        answers.append(got)
    assert answers[:2] == [True, True] and not any(answers[2:])  # every flip here contradicts


def test_face_check_leaves_huge_meshes_to_the_full_path():
    """Packed face keys are exact for point ids < 2^30: a mesh with more points gets False (the
    full path decides), never a wrong True; the measures are still taken."""
    fast = compiled("mesh._fastmesh")
    from models.mesh.container import VTK_HEXAHEDRON
    from models.mesh.geometry import fixed_template

    p, h = hexes(2)
    tmpl, tsize = fixed_template(VTK_HEXAHEDRON)
    conn = np.ascontiguousarray(h, dtype=np.int64).reshape(-1)
    flip = np.zeros(len(h), np.uint8)
    assert fast.fixed_consistent(conn, tmpl, tsize, flip, np.array([len(p)], dtype=np.int64))
    huge = np.array([1 << 30], dtype=np.int64)
    assert not fast.fixed_consistent(conn, tmpl, tsize, flip, huge)
    vol, cen = np.empty(len(h)), np.empty((len(h), 3))
    pts = np.ascontiguousarray(p, dtype=np.float64)
    one = np.array([1], dtype=np.int64)
    assert not fast.fixed_validate(pts, conn, tmpl, tsize, vol, cen, flip, huge, one)
    assert np.allclose(vol, 1.0 / 8)


@pytest.mark.parametrize("kind", ["hexahedra", "tetrahedra"])
def test_the_threaded_face_check_answers_as_the_sequential_one(kind):
    """fixed_validate in 2 threads (meshes of 8,192 cells and 65,536 faces or more: the counting
    sort per thread, the buckets by ranges of points) gives the measures, flips and answer of one
    thread: True on a valid mesh, False with a cell repeated (its faces met twice the same way),
    near the start, in the middle or at the end, in small buckets (hexahedra) and chained ones
    (tetrahedra: ~24 faces a node)."""
    fast = compiled("mesh._fastmesh")
    from models.mesh.container import VTK_HEXAHEDRON, VTK_TETRA
    from models.mesh.geometry import fixed_template

    if kind == "hexahedra":
        p, c = hexes(24)
        t = VTK_HEXAHEDRON
    else:
        p, c = tets(15)
        t = VTK_TETRA
    p = _perturbed(p, 9, 0.05)
    tmpl, tsize = fixed_template(t)
    pts = np.ascontiguousarray(p, dtype=np.float64)
    npts = np.array([len(p)], dtype=np.int64)
    assert len(c) * len(tsize) >= 65536 and len(c) >= 8192

    def run(cells, threads):
        n = len(cells)
        vol, cen, flip = np.empty(n), np.empty((n, 3)), np.empty(n, np.uint8)
        conn = np.ascontiguousarray(cells, dtype=np.int64).reshape(-1)
        ok = fast.fixed_validate(pts, conn, tmpl, tsize, vol, cen, flip, npts, np.array([threads]))
        return ok, vol, cen, flip

    cases = [c] + [np.concatenate([c, c[i : i + 1]]) for i in (0, len(c) // 2, len(c) - 1)]
    answers = []
    for cells in cases:
        one = run(cells, 1)
        for threads in (2, 3, 8):  # helpers claim chunks as they come (one may find none left)
            other = run(cells, threads)
            assert one[0] == other[0]
            for a, b in zip(one[1:], other[1:], strict=True):
                assert np.array_equal(a, b)
        answers.append(one[0])
    assert answers == [True, False, False, False]


def test_concurrent_validations_each_answer_their_own():
    """Four Python threads validating at once (the scratch arena taken by one, the others'
    scratch allocated for the call) each get the answer and measures of a call made alone, the
    meshes of different sizes (the arena grown between calls)."""
    from concurrent.futures import ThreadPoolExecutor

    fast = compiled("mesh._fastmesh")
    from models.mesh.container import VTK_HEXAHEDRON
    from models.mesh.geometry import fixed_template

    tmpl, tsize = fixed_template(VTK_HEXAHEDRON)
    cases = []
    for n, seed in ((8, 1), (20, 2), (24, 3), (12, 4)):
        p, c = hexes(n)
        p = np.ascontiguousarray(_perturbed(p, seed, 0.05), dtype=np.float64)
        if seed == 3:
            c = np.concatenate([c, c[:1]])  # a repeated cell: False
        cases.append((p, np.ascontiguousarray(c, dtype=np.int64).reshape(-1), len(c)))

    def run(case):
        p, conn, n = case
        vol, cen, flip = np.empty(n), np.empty((n, 3)), np.empty(n, np.uint8)
        ok = fast.fixed_validate(
            p, conn, tmpl, tsize, vol, cen, flip, np.array([len(p)], dtype=np.int64), np.array([2])
        )
        return ok, vol, cen, flip

    alone = [run(case) for case in cases]
    with ThreadPoolExecutor(4) as pool:
        for _ in range(3):
            together = list(pool.map(run, cases))
            for a, b in zip(alone, together, strict=True):
                assert a[0] == b[0]
                for x, y in zip(a[1:], b[1:], strict=True):
                    assert np.array_equal(x, y)
    assert [a[0] for a in alone] == [True, True, False, True]


def _cells_validate(points, offsets, conn, types, threads, mode=0):
    from models.mesh.geometry import _templates

    fast = compiled("mesh._fastmesh")
    n, d = len(types), points.shape[1]
    vol, cen, flip = np.empty(n), np.empty((n, d)), np.empty(n, np.uint8)
    ok = fast.cells_validate(
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(offsets, dtype=np.int64),
        np.ascontiguousarray(conn, dtype=np.int64),
        np.ascontiguousarray(types, dtype=np.uint8),
        *_templates(),
        vol,
        cen,
        flip,
        np.array([len(points)], dtype=np.int64),
        np.array([threads], dtype=np.int64),
        np.array([mode], dtype=np.int64),
    )
    return ok, vol, cen, flip


@pytest.mark.parametrize("kind", ["quads and triangles", "hexahedra and tetrahedra"])
def test_cells_validate_in_threads_answers_as_one_thread(kind):
    """cells_validate (polygons in 2D, mixed types in 3D) in 1, 2, 3 and 8 threads: the same
    measures, flips and answer; True on a valid mesh, False with a cell repeated near the start, in
    the middle or at the end (its edges or faces met twice the same way)."""
    from models.mesh.container import VTK_HEXAHEDRON, VTK_QUAD, VTK_TETRA, VTK_TRIANGLE

    if kind.startswith("quads"):
        p, blocks = mixed_2d(90)
        p = _perturbed_2d(p, 12)
        types = {"quad": VTK_QUAD, "triangle": VTK_TRIANGLE}
    else:
        p, h = hexes(20)
        kuhn = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]
        right = p[h].mean(axis=1)[:, 0] > 0.5
        blocks = [("hexahedron", h[~right]), ("tetra", np.concatenate([h[right][:, k] for k in kuhn]))]
        p = _perturbed(p, 13, 0.05)
        types = {"hexahedron": VTK_HEXAHEDRON, "tetra": VTK_TETRA}
    cells = [row for name, c in blocks for row in c.tolist()]
    kinds = [types[name] for name, c in blocks for _ in range(len(c))]
    assert len(cells) >= 8192

    def run(rows, t, threads, mode=0):
        offsets = np.concatenate([[0], np.cumsum([len(r) for r in rows])])
        return _cells_validate(p, offsets, np.concatenate(rows), np.array(t), threads, mode)

    answers = []
    for i in (None, 0, len(cells) // 2, len(cells) - 1):
        rows = cells if i is None else cells + [cells[i]]
        t = kinds if i is None else kinds + [kinds[i]]
        one = run(rows, t, 1)
        for threads in (2, 3, 8):
            other = run(rows, t, threads)
            assert one[0] == other[0]
            for a, b in zip(one[1:], other[1:], strict=True):
                assert np.array_equal(a, b)
        answers.append(one[0])
        measured = run(rows, t, 2, mode=1)  # measures only: the same numbers, no answer
        assert measured[0] == 0
        for a, b in zip(one[1:], measured[1:], strict=True):
            assert np.array_equal(a, b)
    assert answers == [1, 0, 0, 0]


def test_cells_validate_declines_what_it_does_not_take():
    """-1 (the caller takes the full path, nothing written): a 3D cell type without a template (a
    polygon among hexahedra), a cell whose node count is not its type's, offsets beyond the
    connectivity. (Point ids are trusted: mesh_from_cells checked them.)"""
    from models.mesh.container import VTK_HEXAHEDRON, VTK_POLYGON

    p, h = hexes(2)
    conn = h.reshape(-1)
    offsets = np.arange(0, conn.size + 1, 8)
    types = np.full(len(h), VTK_HEXAHEDRON)
    assert _cells_validate(p, offsets, conn, types, 1)[0] == 1
    other = types.copy()
    other[3] = VTK_POLYGON
    assert _cells_validate(p, offsets, conn, other, 1)[0] == -1
    short = offsets.copy()
    short[2:] -= 1  # cell 1 of 7 nodes
    assert _cells_validate(p, short, conn[:-1], types, 1)[0] == -1
    assert _cells_validate(p, offsets, conn[:-1], types, 1)[0] == -1


@pytest.mark.parametrize("d", [2, 3])
def test_compiled_bounds_equal_numpy(d):
    """build._bounds by the compiled pass: numpy's min and max per coordinate, NaN where a
    coordinate has one (a NaN is how the read finds such points), infinities kept."""
    from models.mesh.build import _bounds

    rng = np.random.default_rng(d)
    p = rng.normal(size=(5000, d)) * 1e3
    for edit in (None, (17, 0, np.nan), (4999, d - 1, -np.inf), (0, 0, np.nan)):
        q = p.copy()
        if edit:
            q[edit[0], edit[1]] = edit[2]
        lo, hi = _bounds(q)
        want_lo, want_hi = q.min(axis=0), q.max(axis=0)
        assert np.array_equal(lo, want_lo, equal_nan=True) and np.array_equal(hi, want_hi, equal_nan=True)


def _polyhedra_file(tmp_path, kind: str) -> str:
    """Hexahedra as VTK polyhedra (perturbed), some with triangulated faces (faces of 3 and 4
    nodes: the triangles first, then the fans), and by kind: some faces stored reversed (as Exodus
    NFACED and Fluent store them: agree_faces colours them), or a face missing (an open cell)."""
    import vtk
    import vtk_corpus as vc

    p, h = hexes(5)
    p = _perturbed(p, 21, 0.1)
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    rng = np.random.default_rng(22)
    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetData(vc.numpy_to_vtk(np.ascontiguousarray(p), deep=True))
    ug.SetPoints(pts)
    for i, c in enumerate(h):  # (a test fixture of 125 cells)
        faces = []
        for j, f in enumerate(quads):
            nodes = c[f].tolist()
            if (i + j) % 5 == 0:  # this side cut into two triangles
                faces += [nodes[:3], [nodes[0], nodes[2], nodes[3]]]
            else:
                faces.append(nodes)
        if kind == "reversed" and rng.random() < 0.3:
            faces[1] = faces[1][::-1]
        if kind == "open" and i == 7:
            faces = faces[1:]
        stream = [len(faces)] + [v for f in faces for v in [len(f), *f]]
        ids = vtk.vtkIdList()
        for v in stream:
            ids.InsertNextId(int(v))
        ug.InsertNextCell(vtk.VTK_POLYHEDRON, ids)
    return vc.write_xml(str(tmp_path / f"{kind}.vtu"), ug)


@pytest.mark.parametrize("kind", ["plain", "reversed", "open"])
def test_compiled_polyhedra_equal_numpy(tmp_path, kind, monkeypatch):
    """Polyhedra through the compiled helpers (_fastpoly.c: distinct nodes, the faces' agreement,
    measures) and through their numpy twins: the same Mesh bit for bit, the same notes (faces
    reversed, cells not closed)."""
    from models.mesh.read import read_mesh

    path = _polyhedra_file(tmp_path, kind)
    monkeypatch.setenv("MAGNET_READ_SANDBOX", "0")
    a = read_mesh(path)
    monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
    b = read_mesh(path)
    assert a.poly_cells is not None and a.n_cells == 125
    for key in (
        "points",
        "offsets",
        "connectivity",
        "poly_cell_faces",
        "poly_face_offsets",
        "poly_face_nodes",
    ):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
    for key in ("measures", "centroids", "signed_measures"):
        assert np.array_equal(a.meta[key], b.meta[key]), key
    for key in ("reversed_faces", "open_polyhedra", "orientation"):
        assert a.meta.get(key) == b.meta.get(key), key
    if kind == "reversed":
        assert a.meta["reversed_faces"]["count"] > 0
    if kind == "open":
        assert a.meta["open_polyhedra"]["cells"] == [7]
    assert (a.meta["signed_measures"] > 0).all()


@pytest.mark.parametrize("kind", ["hexahedra, pyramids, tetrahedra", "polyhedra"])
def test_compiled_consistent_answers_as_numpy(tmp_path, kind, monkeypatch):
    """orientation._consistent on a face list (mixed cell types, polyhedra): the compiled check (the
    faces' keys bucketed by smallest node) answers as the numpy sort of the same keys, for the
    cells' own orientation and for random flips (contradictions)."""
    from models.mesh.geometry import cell_faces
    from models.mesh.orientation import _consistent
    from models.mesh.read import read_mesh

    if kind == "polyhedra":
        monkeypatch.setenv("MAGNET_READ_SANDBOX", "0")
        m = read_mesh(_polyhedra_file(tmp_path, "plain"))
    else:
        p, blocks = mixed_3d(6)
        m = mesh_from_arrays(_perturbed(p, 23, 0.05), blocks)
    faces = cell_faces(m)
    rng = np.random.default_rng(24)
    flips = [np.zeros(m.n_cells, bool), np.ones(m.n_cells, bool)]
    one = np.zeros(m.n_cells, bool)
    one[m.n_cells // 2] = True  # one cell reversed among consistent neighbours
    flips += [one, rng.random(m.n_cells) < 0.3]
    answers = []
    for f in flips:
        got = _consistent(faces, f, m.n_points)
        monkeypatch.setenv("MAGNET_NO_COMPILED", "1")
        want = _consistent(faces, f, m.n_points)
        monkeypatch.delenv("MAGNET_NO_COMPILED")
        assert got == want
        answers.append(got)
    assert answers[:2] == [True, True] and not any(answers[2:])

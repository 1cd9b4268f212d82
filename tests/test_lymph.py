"""lymph export: region / neighbor structs, max_kb, .mat and .json writers."""

import json
import shutil
import subprocess

import numpy as np
import pytest
from scipy.io import loadmat

from models.errors import ParameterError
from models.export.lymph import lymph_from_mat, lymph_structs, max_kb, write_lymph_json, write_lymph_mat
from models.mesh.container import PolyMesh


def poly_from_loops(points, loops, tags=None) -> PolyMesh:
    """A 2D PolyMesh with one loop per element."""
    points = np.asarray(points, dtype=np.float64)
    sizes = [len(lp) for lp in loops]
    return PolyMesh(
        points=points,
        elem_offsets=np.arange(len(loops) + 1),
        loop_offsets=np.r_[0, np.cumsum(sizes)].astype(np.int64),
        loop_nodes=np.concatenate([np.asarray(lp, dtype=np.int64) for lp in loops]),
        measure=np.zeros(len(loops)),
        n_fine=np.ones(len(loops), dtype=np.int64),
        labels=np.zeros(0, dtype=np.int64),
        tags=None if tags is None else np.asarray(tags, dtype=np.int64),
    )


def grid_2x2() -> PolyMesh:
    pts = [(x, y) for y in range(3) for x in range(3)]

    def idx(x, y):
        return 3 * y + x

    loops = [[idx(x, y), idx(x + 1, y), idx(x + 1, y + 1), idx(x, y + 1)] for y in range(2) for x in range(2)]
    return poly_from_loops(pts, loops)


def triangle_pentagon() -> PolyMesh:
    """The square [0,2]^2 cut along (2,1)-(1,2): a pentagon and a triangle."""
    pts = [(0, 0), (2, 0), (2, 1), (1, 2), (0, 2), (2, 2)]
    return poly_from_loops(pts, [[0, 1, 2, 3, 4], [2, 5, 3]], tags=[3, 8])


def shoelace(xy):
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


def check_neighbours(region, neighbor):
    """neigh / neighedges are mutual, and the shared edge is the same vertex pair reversed."""
    conn = region["connectivity"]
    for i in range(region["ne"]):
        n_i = len(conn[i])
        for j in range(n_i):
            k, m = neighbor["neigh"][i][j], neighbor["neighedges"][i][j]
            if k == -1:
                assert m == -1
                continue
            assert neighbor["neigh"][k - 1][m - 1] == i + 1
            assert neighbor["neighedges"][k - 1][m - 1] == j + 1
            a, b = conn[i][j], conn[i][(j + 1) % n_i]
            ck = conn[k - 1]
            c, d = ck[m - 1], ck[m % len(ck)]
            assert (a, b) == (d, c)


# ---------------------------------------------------------------------------------------------
# structs


def test_grid_counts_connectivity_and_boundary():
    region, neighbor = lymph_structs(grid_2x2(), boundary_tag=7)
    assert region["ne"] == 4
    assert region["tag"] == "P"
    assert region["coord"].shape == (9, 2)
    assert list(region["nedges"]) == [4, 4, 4, 4] == list(neighbor["nedges"])
    allc = np.concatenate(region["connectivity"])
    assert allc.min() == 1 and allc.max() == 9
    for conn, xy in zip(region["connectivity"], region["coords_element"], strict=True):
        np.testing.assert_array_equal(region["coord"][conn - 1], xy)
        assert shoelace(xy) > 0  # counter-clockwise
    assert region["connectivity_bc"].shape == (8, 2)
    assert np.all(region["bc_tag"] == 7)
    # boundary edges are the domain boundary: both ends on x or y in {0, 2}, same side
    ends = region["coord"][region["connectivity_bc"] - 1]
    on_side = np.any(np.all(np.isin(ends, [0.0, 2.0]) & (ends[:, :1] == ends[:, 1:]), axis=1), axis=1)
    assert on_side.all()
    np.testing.assert_allclose(region["area"], 1.0)
    assert region["area"].sum() == pytest.approx(4.0)
    np.testing.assert_array_equal(region["BBox"], [[0, 1, 0, 1], [1, 2, 0, 1], [0, 1, 1, 2], [1, 2, 1, 2]])
    np.testing.assert_array_equal(region["id"], [1, 1, 1, 1])
    for kb in region["max_kb"]:
        np.testing.assert_allclose(kb, 0.5)  # unit square: half of it
    n_boundary = sum(int(np.sum(n == -1)) for n in neighbor["neigh"])
    assert n_boundary == len(region["bc_tag"])
    check_neighbours(region, neighbor)
    # element 1 (lower left): right edge -> element 2, top edge -> element 3
    np.testing.assert_array_equal(neighbor["neigh"][0], [-1, 2, 3, -1])


def test_triangle_pentagon_split():
    region, neighbor = lymph_structs(triangle_pentagon())
    np.testing.assert_array_equal(region["nedges"], [5, 3])
    np.testing.assert_array_equal(region["id"], [3, 8])
    np.testing.assert_allclose(region["area"], [3.5, 0.5])
    np.testing.assert_array_equal(neighbor["neigh"][0], [-1, -1, 2, -1, -1])
    np.testing.assert_array_equal(neighbor["neighedges"][0], [-1, -1, 3, -1, -1])
    np.testing.assert_array_equal(neighbor["neigh"][1], [-1, -1, 1])
    np.testing.assert_array_equal(neighbor["neighedges"][1], [-1, -1, 3])
    assert region["connectivity_bc"].shape == (6, 2)
    check_neighbours(region, neighbor)
    np.testing.assert_allclose(region["max_kb"][0], [2.0, 1.0, 1.5, 1.0, 2.0])
    np.testing.assert_allclose(region["max_kb"][1], [0.5, 0.5, 0.5])
    np.testing.assert_array_equal(region["BBox"], [[0, 2, 0, 2], [1, 2, 1, 2]])


def test_compact_renumbering_orientation_and_closing_node():
    # unused points, a clockwise loop and a loop that repeats its first node at the end
    pts = np.array([(9, 9), (0, 0), (5, 5), (1, 0), (1, 1), (0, 1), (2, 0), (2, 1), (7, 7)], float)
    poly = poly_from_loops(pts, [[1, 5, 4, 3], [3, 6, 7, 4, 3]])  # CW square, closed CCW square
    region, neighbor = lymph_structs(poly)
    assert region["coord"].shape == (6, 2)
    assert not np.any(np.all(region["coord"] == [9, 9], axis=1))
    np.testing.assert_array_equal(region["nedges"], [4, 4])
    for xy in region["coords_element"]:
        assert shoelace(xy) == pytest.approx(1.0)
    np.testing.assert_allclose(region["area"], [1.0, 1.0])
    assert region["connectivity_bc"].shape == (6, 2)
    check_neighbours(region, neighbor)
    assert sum(int(np.sum(n > 0)) for n in neighbor["neigh"]) == 2


def test_domain_area_and_symmetry_on_a_larger_split():
    # a 6 x 4 grid of unit squares, agglomerated into 2 x 2 blocks; loops go through the
    # midpoints (fine vertices), so neighbours share two fine edges each
    nx, ny = 6, 4
    pts = np.array([(x, y) for y in range(ny + 1) for x in range(nx + 1)], float)

    def idx(x, y):
        return y * (nx + 1) + x

    loops = []
    for by in range(0, ny, 2):
        for bx in range(0, nx, 2):
            ring = [
                (bx, by),
                (bx + 1, by),
                (bx + 2, by),
                (bx + 2, by + 1),
                (bx + 2, by + 2),
                (bx + 1, by + 2),
                (bx, by + 2),
                (bx, by + 1),
            ]
            loops.append([idx(x, y) for x, y in ring])
    region, neighbor = lymph_structs(poly_from_loops(pts, loops))
    assert region["ne"] == 6
    assert region["area"].sum() == pytest.approx(nx * ny)
    assert len(region["bc_tag"]) == 2 * (nx + ny)
    check_neighbours(region, neighbor)
    for kb in region["max_kb"]:
        np.testing.assert_allclose(kb, 1.0)  # half edge (1) times full height (2) / 2


def test_tags_3d_and_holes_rejected():
    poly = grid_2x2()
    poly3 = PolyMesh(
        points=np.zeros((4, 3)),
        elem_offsets=np.array([0, 4]),
        loop_offsets=np.arange(5) * 3,
        loop_nodes=np.array([0, 2, 1, 0, 1, 3, 1, 2, 3, 0, 3, 2]),
        measure=np.ones(1),
        n_fine=np.ones(1, dtype=np.int64),
        labels=np.zeros(1, dtype=np.int64),
    )
    with pytest.raises(ParameterError):
        lymph_structs(poly3)
    holed = PolyMesh(
        points=poly.points,
        elem_offsets=np.array([0, 2]),
        loop_offsets=np.array([0, 4, 8]),
        loop_nodes=np.array([0, 2, 8, 6, 1, 4, 5, 2]),
        measure=np.ones(1),
        n_fine=np.ones(1, dtype=np.int64),
        labels=np.zeros(1, dtype=np.int64),
    )
    with pytest.raises(ParameterError):
        lymph_structs(holed)


# ---------------------------------------------------------------------------------------------
# max_kb


def one(points):
    p = np.asarray(points, dtype=np.float64)
    return max_kb(p, np.array([0]), np.array([len(p)]))


def test_max_kb_nonconvex_excludes_the_largest_triangle():
    # a square with a deep notch from the top: for the bottom edge every far vertex would give
    # a triangle of area 8 that contains the notch tip (2, 1); the largest inside one is 2
    notch = [(0, 0), (4, 0), (4, 4), (3, 4), (2, 1), (1, 4), (0, 4)]
    np.testing.assert_allclose(one(notch), [2.0, 4.0, 2.0, 3.5, 3.5, 2.0, 4.0])
    # L shape: the bottom edge's triangle with (0, 2) touches the reflex corner (1, 1) on its
    # side and is inside; the one with (2, 1) or (1, 1) is smaller, the one with (1, 2) is out
    ell = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]
    np.testing.assert_allclose(one(ell), [2.0, 1.0, 0.5, 0.5, 1.0, 2.0])


def test_max_kb_rejects_edges_crossing_without_a_vertex_inside():
    # A slot cut from the right side at height 2..2.2 reaches x = 0.5, left of the triangle
    # (0,0),(4,0),(2,4): no polygon vertex lies inside that triangle, but the slot's edges cross
    # it, so its area 8 is not admissible; the apexes (4,5) / (0,5) (area 10) are crossed as
    # well. The best admissible triangles stay below the slot: (4,2) or (0.5,2), area 4.
    slot = [(0, 0), (4, 0), (4, 2), (0.5, 2), (0.5, 2.2), (4, 2.2), (4, 5), (2, 4), (0, 5)]
    kb = one(slot)
    assert kb[0] == pytest.approx(4.0)
    np.testing.assert_allclose(kb, reference_max_kb(np.array(slot, float)))


def _clip_area(poly, tri):
    """Area of (simple) polygon clipped by a CCW triangle (Sutherland-Hodgman)."""
    out = [tuple(p) for p in poly]
    for i in range(3):
        a, b = tri[i], tri[(i + 1) % 3]
        inp, out = out, []
        if not inp:
            break

        def side(p, a=a, b=b):
            return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])

        for k in range(len(inp)):
            p, q = inp[k], inp[(k + 1) % len(inp)]
            sp, sq = side(p), side(q)
            if sp >= 0:
                out.append(p)
            if (sp >= 0) != (sq >= 0):
                t = sp / (sp - sq)
                out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
    return shoelace(np.array(out)) if len(out) >= 3 else 0.0


def reference_max_kb(p, edges=None):
    """Independent slow reference: a triangle is inside iff clipping the polygon by it keeps
    the triangle's whole area (the criterion lymph's Matlab code uses, with polybool)."""
    p = p - p.mean(axis=0)  # local coordinates: the area test is relative
    n = len(p)
    out = np.zeros(n)
    for j in range(n) if edges is None else edges:
        a, b = p[j], p[(j + 1) % n]
        areas = 0.5 * ((b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0]))
        for k in np.argsort(-areas):
            if k in (j, (j + 1) % n) or areas[k] <= 1e-12:
                continue
            if _clip_area(p, np.array([a, b, p[k]])) >= areas[k] * (1 - 1e-10):
                out[j] = areas[k]
                break
    return out


def _is_simple(p):
    n = len(p)

    def orient(a, b, c):
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])

    def on_segment(a, b, q):
        return min(a[0], b[0]) <= q[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= q[1] <= max(a[1], b[1])

    for i in range(n):
        a, b = p[i], p[(i + 1) % n]
        if orient(p[i - 1], a, b) == 0 and np.dot(a - p[i - 1], b - a) < 0:
            return False  # folds back on itself
        for j in range(i + 2, n):
            if (j + 1) % n == i:
                continue
            c, d = p[j], p[(j + 1) % n]
            o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
            if o1 * o2 < 0 and o3 * o4 < 0:
                return False
            for s, e, q, o in ((a, b, c, o1), (a, b, d, o2), (c, d, a, o3), (c, d, b, o4)):
                if o == 0 and on_segment(s, e, q):
                    return False
    return True


def test_max_kb_matches_clipping_reference_on_random_polygons():
    rng = np.random.default_rng(0)
    polys = []
    while len(polys) < 40:
        n = int(rng.integers(5, 22))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        r = rng.uniform(0.2, 1.0, n)
        p = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
        if len(polys) % 2:
            p = np.round(p * 4) / 4  # collinear and touching configurations
        p = p[np.any(p != np.roll(p, -1, axis=0), axis=1)]
        if len(p) < 3 or len(np.unique(p, axis=0)) < len(p) or shoelace(p) <= 0 or not _is_simple(p):
            continue
        polys.append(p)
    sizes = np.array([len(p) for p in polys])
    got = max_kb(np.concatenate(polys), np.r_[0, np.cumsum(sizes)[:-1]], sizes)
    expected = np.concatenate([reference_max_kb(p) for p in polys])
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)


def test_lymph_structs_on_nonconvex_elements():
    # 400 star-shaped (strongly non-convex) elements of 100 vertices each (no timing here: house
    # rule, speed belongs in bench/)
    rng = np.random.default_rng(1)
    n_el, n_v = 400, 100
    ang = np.sort(rng.uniform(0, 2 * np.pi, (n_el, n_v)), axis=1)
    rad = rng.uniform(0.2, 0.45, (n_el, n_v))
    cx, cy = np.divmod(np.arange(n_el), 20)
    pts = np.stack([cx[:, None] + rad * np.cos(ang), cy[:, None] + rad * np.sin(ang)], axis=-1).reshape(-1, 2)
    loops = np.arange(n_el * n_v).reshape(n_el, n_v)
    poly = poly_from_loops(pts, list(loops))
    region, neighbor = lymph_structs(poly)
    assert all(np.all(n == -1) for n in neighbor["neigh"])
    assert all(np.all(kb > 0) for kb in region["max_kb"])
    # spot check against the reference
    for e in (0, 123, 399):
        ref = reference_max_kb(region["coords_element"][e], edges=range(0, n_v, 25))
        np.testing.assert_allclose(region["max_kb"][e][::25], ref[::25], rtol=1e-9)


# ---------------------------------------------------------------------------------------------
# writers


def test_mat_round_trip_keeps_cell_arrays(tmp_path):
    region, neighbor = lymph_structs(triangle_pentagon())
    path = write_lymph_mat(tmp_path / "mesh.mat", region, neighbor)
    raw = loadmat(path)
    reg, nb = raw["region"][0, 0], raw["neighbor"][0, 0]
    for name in ("connectivity", "coords_element", "max_kb"):
        assert reg[name].dtype == object and reg[name].shape == (1, 2)  # 1 x ne cell array
    assert nb["neigh"].dtype == object and nb["neighedges"].dtype == object
    np.testing.assert_array_equal(reg["connectivity"][0, 1], [[3, 6, 4]])  # 1-based, row
    assert reg["coords_element"][0, 0].shape == (5, 2)
    assert reg["max_kb"][0, 0].shape == (5, 1)
    assert str(reg["tag"][0]) == "P"
    np.testing.assert_array_equal(nb["neigh"][0, 0], [[-1, -1, 2, -1, -1]])

    back_region, back_neighbor = lymph_from_mat(path)
    for key in ("coord", "nedges", "id", "connectivity_bc", "bc_tag", "BBox", "area"):
        np.testing.assert_array_equal(back_region[key], region[key])
    assert back_region["ne"] == 2 and back_region["tag"] == "P"
    for key in ("connectivity", "coords_element", "max_kb"):
        for a, b in zip(back_region[key], region[key], strict=True):
            np.testing.assert_array_equal(a, b)
    for key in ("neigh", "neighedges"):
        for a, b in zip(back_neighbor[key], neighbor[key], strict=True):
            np.testing.assert_array_equal(a, b)


def test_json_writer(tmp_path):
    region, neighbor = lymph_structs(grid_2x2())
    path = write_lymph_json(tmp_path / "mesh.json", region, neighbor)
    data = json.loads(open(path).read())
    assert data["region"]["ne"] == 4
    assert data["region"]["tag"] == "P"
    assert data["region"]["connectivity"][0] == [1, 2, 5, 4]
    assert data["neighbor"]["neigh"][0] == [-1, 2, 3, -1]
    assert data["neighbor"]["neighedges"][0] == [-1, 4, 1, -1]
    assert data["region"]["max_kb"][3] == [0.5, 0.5, 0.5, 0.5]
    assert len(data["region"]["connectivity_bc"]) == 8


@pytest.mark.octave
@pytest.mark.skipif(shutil.which("octave-cli") is None, reason="octave-cli not installed")
def test_octave_reads_the_mat_file(tmp_path):
    region, neighbor = lymph_structs(triangle_pentagon())
    path = write_lymph_mat(tmp_path / "mesh.mat", region, neighbor)
    script = (
        f"load('{path}'); "
        "printf('%s|%s|%d|%s|%d|%d|%g\\n', class(region.connectivity), region.tag, region.ne, "
        "mat2str(region.connectivity{2}), neighbor.neigh{1}(3), neighbor.neighedges{2}(3), "
        "sum(region.max_kb{1}));"
    )
    out = subprocess.run(
        ["octave-cli", "--no-gui", "--quiet", "--eval", script], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "cell|P|2|[3 6 4]|2|3|7.5"

"""Pictures: agglomeration previews (2D, 2D with holes, 3D exploded) and metric box plots."""

import itertools

import matplotlib.image as mpimg
import numpy as np
import pytest

from models.errors import ParameterError
from models.mesh.container import VTK_QUAD, Mesh, PolyMesh
from models.quality.plot import (
    color_elements,
    element_adjacency,
    metrics_table,
    plot_agglomeration,
    plot_metric_boxplots,
)


def check_png(path, min_size=100):
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > min_size and img.shape[1] > min_size
    flat = img.reshape(-1, img.shape[2])
    assert len(np.unique(flat[:: max(1, len(flat) // 20000)], axis=0)) > 3  # not a single colour
    return img


def grid_mesh(n=4):
    """n x n unit-square quads on [0, n]^2."""
    pts = np.array([(x, y) for y in range(n + 1) for x in range(n + 1)], float)
    cells = np.array(
        [
            [y * (n + 1) + x, y * (n + 1) + x + 1, (y + 1) * (n + 1) + x + 1, (y + 1) * (n + 1) + x]
            for y in range(n)
            for x in range(n)
        ]
    )
    return Mesh(
        points=pts,
        offsets=np.arange(len(cells) + 1) * 4,
        connectivity=cells.ravel(),
        cell_types=np.full(len(cells), VTK_QUAD, dtype=np.uint8),
    )


def grid_poly_2x2():
    """The 4 x 4 grid agglomerated into four 2 x 2 blocks (loops through the fine vertices)."""
    n = 4

    def idx(x, y):
        return y * (n + 1) + x

    loops = []
    for by, bx in itertools.product((0, 2), (0, 2)):
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
    labels = np.array([(y // 2) * 2 + x // 2 for y in range(n) for x in range(n)])
    return PolyMesh(
        points=grid_mesh(n).points,
        elem_offsets=np.arange(5),
        loop_offsets=np.arange(5) * 8,
        loop_nodes=np.concatenate(loops),
        measure=np.full(4, 4.0),
        n_fine=np.full(4, 4),
        labels=labels,
    )


def two_cubes():
    """[0,1]^3 and [1,2]x[0,1]^2 as two polyhedra with outward quad faces."""
    pts = np.array([(x, y, z) for x in range(3) for y in range(2) for z in range(2)], float)

    def pid(x, y, z):
        return x * 4 + y * 2 + z

    faces, offs = [], [0]
    for x0 in (0, 1):
        corners = [(x0 + dx, dy, dz) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]
        center = np.array([x0 + 0.5, 0.5, 0.5])
        for axis, val in itertools.product(range(3), (0, 1)):
            quad = [c for c in corners if c[axis] == (x0 + val if axis == 0 else val)]
            # order the 4 corners around the face centre, then orient outwards
            fc = np.mean(quad, axis=0)
            u, v = [d for d in range(3) if d != axis]
            quad.sort(key=lambda c, fc=fc, u=u, v=v: np.arctan2(c[v] - fc[v], c[u] - fc[u]))
            q = np.array(quad, float)
            normal = np.cross(q[1] - q[0], q[2] - q[0])
            if normal @ (fc - center) < 0:
                quad = quad[::-1]
            faces.extend(pid(*c) for c in quad)
            offs.append(len(faces))
    return PolyMesh(
        points=pts,
        elem_offsets=np.array([0, 6, 12]),
        loop_offsets=np.array(offs),
        loop_nodes=np.array(faces),
        measure=np.ones(2),
        n_fine=np.ones(2, dtype=np.int64),
        labels=np.array([0, 1]),
    )


def test_adjacency_and_colouring():
    poly = grid_poly_2x2()
    pairs = element_adjacency(poly)
    np.testing.assert_array_equal(pairs, [[0, 1], [0, 2], [1, 3], [2, 3]])
    colors = color_elements(poly.n_elements, pairs)
    assert np.all(colors[pairs[:, 0]] != colors[pairs[:, 1]])
    # a dense graph (complete on 30 nodes) needs 30 colours, more than the palette
    full = np.array(list(itertools.combinations(range(30), 2)))
    c = color_elements(30, full, n_colors=8)
    assert len(np.unique(c)) == 30
    # a long random planar-ish graph stays properly coloured
    rng = np.random.default_rng(0)
    edges = rng.integers(0, 500, (1500, 2))
    edges = edges[edges[:, 0] != edges[:, 1]]
    c = color_elements(500, edges, seed=3)
    assert np.all(c[edges[:, 0]] != c[edges[:, 1]]) and c.min() >= 0


def test_plot_2d_with_fine_mesh(tmp_path):
    poly = grid_poly_2x2()
    out = plot_agglomeration(poly, tmp_path / "agg.png", fine_mesh=grid_mesh(4), title="2 x 2", dpi=80)
    assert out == str(tmp_path / "agg.png")
    img = check_png(out)
    # the four elements get at least two different fill colours
    h, w = img.shape[:2]
    centres = [img[int(h * fy), int(w * fx), :3] for fy in (0.3, 0.75) for fx in (0.3, 0.7)]
    assert len({tuple(np.round(c, 2)) for c in centres}) >= 2


def test_plot_2d_element_with_a_hole(tmp_path):
    # a 3 x 3 block ring around the centre square: the ring has an outer loop and a hole
    mesh = grid_mesh(3)

    def idx(x, y):
        return y * 4 + x

    outer = [
        idx(x, y)
        for x, y in [
            (0, 0),
            (1, 0),
            (2, 0),
            (3, 0),
            (3, 1),
            (3, 2),
            (3, 3),
            (2, 3),
            (1, 3),
            (0, 3),
            (0, 2),
            (0, 1),
        ]
    ]
    hole = [idx(x, y) for x, y in [(1, 1), (1, 2), (2, 2), (2, 1)]]  # clockwise
    centre = [idx(x, y) for x, y in [(1, 1), (2, 1), (2, 2), (1, 2)]]
    poly = PolyMesh(
        points=mesh.points,
        elem_offsets=np.array([0, 2, 3]),
        loop_offsets=np.array([0, 12, 16, 20]),
        loop_nodes=np.array(outer + hole + centre),
        measure=np.array([8.0, 1.0]),
        n_fine=np.array([8, 1]),
        labels=np.array([0, 0, 0, 0, 1, 0, 0, 0, 0]),
    )
    check_png(plot_agglomeration(poly, tmp_path / "ring.png", fine_mesh=mesh, dpi=60))


def test_plot_3d_exploded_two_cubes(tmp_path):
    poly = two_cubes()
    np.testing.assert_array_equal(element_adjacency(poly), [[0, 1]])
    check_png(plot_agglomeration(poly, tmp_path / "cubes.png", title="two cubes", dpi=60))
    # only the front layer within a tiny face budget: still a picture
    check_png(plot_agglomeration(poly, tmp_path / "cubes_small.png", dpi=60, max_faces=3))


def test_plot_rejects_bad_input(tmp_path):
    poly = grid_poly_2x2()
    with pytest.raises(ParameterError):
        plot_agglomeration(
            poly,
            tmp_path / "x.png",
            fine_mesh=Mesh(
                points=np.zeros((1, 3)),
                offsets=np.zeros(1, int),
                connectivity=np.zeros(0, int),
                cell_types=np.zeros(0, np.uint8),
            ),
        )
    with pytest.raises(ParameterError):
        plot_metric_boxplots({}, tmp_path / "b.png")


def fake_report(rng, n, shift, with_time=True):
    per = {
        "circle_ratio": list(np.clip(rng.normal(0.5 + shift, 0.1, n), 0, 1)),
        "area_perimeter_ratio": list(np.clip(rng.normal(0.6 + shift, 0.1, n), 0, 1)),
        "uniformity_factor": list(np.clip(rng.normal(0.7, 0.1, n), 0, 1)),
        "volume_difference": list(np.clip(rng.normal(0.8, 0.1, n), 0, 1)),
    }
    per["circle_ratio"][0] = None  # undefined values are skipped
    report = {"elements": n, "per_element": per, "partition": {"normalized_cut": 0.1 + shift}}
    if with_time:
        report["time"] = 1.5 + shift
    return report


def test_boxplots_and_table(tmp_path):
    rng = np.random.default_rng(0)
    results = {
        "metis": fake_report(rng, 64, 0.0),
        "kmeans": fake_report(rng, 64, 0.05, with_time=False),
        "sage-base": fake_report(rng, 60, 0.1),
    }
    results["sage-base"]["per_element"]["heterogeneity_preservation"] = list(rng.uniform(0.8, 1, 60))
    out = plot_metric_boxplots(results, tmp_path / "box.png")
    assert out == str(tmp_path / "box.png")
    img = check_png(out)
    assert img.shape[1] > img.shape[0]  # subplots side by side

    table = metrics_table(results)
    lines = table.splitlines()
    assert len(lines) == 2 + 3
    header = lines[0].split()
    for col in ("method", "elements", "CR", "APR", "UF", "VD", "HP", "NC"):
        assert col in header
    assert "time" in lines[0]
    metis = lines[2].split()
    assert metis[0] == "metis" and metis[1] == "64"
    cr = np.mean([v for v in results["metis"]["per_element"]["circle_ratio"] if v is not None])
    assert metis[2] == f"{cr:.3f}"
    assert "0.1000" in lines[2] and "1.50" in lines[2]
    kmeans = lines[3].split()
    assert kmeans[-1] == "-"  # no time for this one
    assert lines[3].split()[header.index("HP")] == "-"

"""Mesh generators and training data sets: valid meshes, physical groups, seeded reproducibility."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

pytest.importorskip("gmsh")

from models.cli.generate import add_generate_args, generate_main  # noqa: E402
from models.errors import MeshError, ParameterError  # noqa: E402
from models.learn.dataset import GraphDataset, build_dataset, get_recipe  # noqa: E402
from models.learn.generate import KINDS_2D, generate, sphere_stl  # noqa: E402
from models.mesh.dual import dual_graph  # noqa: E402
from models.mesh.geometry import measures_and_centroids  # noqa: E402
from models.mesh.read import read_mesh  # noqa: E402

SMALL = {
    "square-tri": dict(size=0.1),
    "square-quad": dict(size=0.1),
    "delaunay": dict(n=200),
    "voronoi": dict(n=200),
    "holes": dict(size=0.08, n=3),
    "inclusions": dict(size=0.08, n=4),
    "split": dict(size=0.08),
    "cube": dict(size=0.25),
    "cube-portion": dict(size=0.25),
    "cube-hetero": dict(size=0.25, parts=3),
}


def _same(a, b) -> bool:
    return (
        np.array_equal(a.points, b.points)
        and len(a.cells) == len(b.cells)
        and all(
            n1 == n2 and np.array_equal(c1, c2) for (n1, c1), (n2, c2) in zip(a.cells, b.cells, strict=True)
        )
        and (a.tags is None) == (b.tags is None)
        and (a.tags is None or np.array_equal(a.tags, b.tags))
    )


@pytest.mark.parametrize("kind", list(SMALL))
def test_kind_is_a_valid_connected_mesh_and_reproducible(kind):
    g = generate(kind, seed=5, **SMALL[kind])
    mesh = g.to_mesh()  # the library's reader checks orientation and degenerate cells
    assert mesh.n_cells == g.n_cells > 10
    assert mesh.dim == (2 if kind in KINDS_2D else 3)
    measures, _ = measures_and_centroids(mesh)
    assert np.all(measures > 0)
    total = measures.sum()
    if kind in ("holes", "cube-portion"):
        assert 0.1 < total < 1.0
    else:
        assert total == pytest.approx(1.0, rel=1e-6)  # the unit square / cube, exactly covered
    graph = dual_graph(mesh)
    from scipy.sparse.csgraph import connected_components

    assert connected_components(graph.matrix(), directed=False)[0] == 1
    assert _same(g, generate(kind, seed=5, **SMALL[kind]))  # same seed, same mesh


@pytest.mark.parametrize("kind", ["delaunay", "voronoi", "holes", "inclusions", "split", "cube-hetero"])
def test_different_seeds_differ(kind):
    assert not _same(generate(kind, seed=1, **SMALL[kind]), generate(kind, seed=2, **SMALL[kind]))


@pytest.mark.parametrize("kind", ["inclusions", "split", "cube-hetero"])
def test_two_physical_groups(kind):
    mesh = generate(kind, seed=3, **SMALL[kind]).to_mesh()
    assert mesh.physical_groups() == [0, 1]


def test_regular_inclusions_and_homogeneous_hetero_cube():
    g = generate("inclusions", seed=0, n=16, regular=True, size=0.02)
    measures, _ = measures_and_centroids(g.to_mesh())
    assert measures[g.tags == 1].sum() == pytest.approx(16 * np.pi * (0.25 / 4) ** 2, rel=0.03)
    assert generate("cube-hetero", seed=0, size=0.3, parts=1).to_mesh().physical_groups() == [0]
    with pytest.raises(ParameterError):
        generate("inclusions", seed=0, n=15, regular=True)


def test_voronoi_cells_are_polygons():
    g = generate("voronoi", seed=0, n=300)
    assert g.n_cells == 300
    assert any(name == "polygon" for name, _ in g.cells)


def test_stl_is_filled_with_tetrahedra(tmp_path):
    stl = tmp_path / "sphere.stl"
    sphere_stl(stl, h=0.3)
    kept = generate("stl", seed=0, stl=stl)  # the surface as it stands (models.mesh.fill)
    assert not kept.info["remeshed"] and kept.info["volume"] == pytest.approx(kept.info["enclosed_volume"])
    g = generate("stl", seed=0, stl=stl, size=0.1)  # re-meshed at 0.1 x the bounding-box diagonal
    measures, _ = measures_and_centroids(g.to_mesh())
    assert g.info["remeshed"] and measures.sum() == pytest.approx(4 / 3 * np.pi, rel=0.1)
    with pytest.raises(MeshError, match="surface file not found"):
        generate("stl", seed=0, stl=tmp_path / "missing.stl")


def test_bad_parameters():
    with pytest.raises(ParameterError):
        generate("triangle-soup", seed=0)
    with pytest.raises(ParameterError):
        generate("cube", seed=0, size=2.0)
    with pytest.raises(ParameterError):
        generate("cube-hetero", seed=0, size=0.3, parts=5)


def test_cli_writes_readable_files(tmp_path):
    parser = argparse.ArgumentParser()
    add_generate_args(parser)
    out = tmp_path / "incl.vtu"
    assert (
        generate_main(parser.parse_args(["inclusions", "-o", str(out), "--seed", "2", "--size", "0.08"])) == 0
    )
    mesh = read_mesh(out)
    assert mesh.physical_groups() == [0, 1]
    folder = tmp_path / "many"
    assert (
        generate_main(parser.parse_args(["square-quad", "-o", str(folder), "--count", "3", "--size", "0.2"]))
        == 0
    )
    assert len(list(folder.glob("*.vtu"))) == 3


def test_dataset_roundtrip_and_loader(tmp_path):
    recipe = get_recipe(
        "sage-hetero-2d", n_meshes=6, pieces=0.5, size_range=(0.08, 0.12), points_range=(60, 120)
    )
    path = tmp_path / "ds.npz"
    ds = build_dataset(recipe, path, seed=1, log=None)
    again = GraphDataset.load(path)
    assert len(again) == 6 and again.dim == 2 and again.hetero
    assert np.array_equal(again.x, ds.x) and np.array_equal(again.edges, ds.edges)
    assert np.array_equal(build_dataset(recipe, None, seed=1, log=None).x, ds.x)  # reproducible
    for i in range(len(again)):
        a = again.arrays(i)
        assert a.x.shape[1] == 4 and set(np.unique(a.x[:, 3])) <= {0.0, 1.0}
        assert np.all(a.edges[:, 0] < a.edges[:, 1])
        assert np.array_equal(np.bincount(a.edges.ravel(), minlength=len(a.x)), a.degree)
    import torch

    batches = list(again.batches(4, shuffle=True, generator=torch.Generator().manual_seed(0), rotate=True))
    assert [b.num_graphs for b in batches] == [4, 2]
    b = batches[0]
    assert b.x.shape[1] == 4 and b.edge_index.shape[0] == 2 and b.degree.shape[0] == b.num_nodes

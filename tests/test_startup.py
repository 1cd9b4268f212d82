"""Start-up of `magnet agglomerate` (issue 25, section 5): what the command loads, how the CLI reads
a VTU, and the graph helper that replaced scipy's connected components on its path."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components as scipy_components

from models.graph import csr
from models.mesh import read, sandbox

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BRAIN = os.path.join(ROOT, "tests", "data", "BrainCoronalNoHoles.vtu")

# never loaded by `magnet agglomerate MESH.vtu --model metis --k K` (scipy.sparse alone is ~0.2 s)
HEAVY = ("matplotlib", "sklearn", "torch", "vtk", "vtkmodules", "fastapi", "celery", "meshio", "scipy")


def _imported(args: list[str], tmp_path, **env) -> set[str]:
    """The modules a whole `magnet` process imported (python -X importtime, its stderr)."""
    run_env = dict(os.environ, PYTHONPATH=ROOT, MPLBACKEND="Agg", **env)
    r = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "models.cli", *args],
        cwd=tmp_path,
        env=run_env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    names = set()
    for line in r.stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            names.add(line.rsplit("|", 1)[1].strip())
    assert "models.cli.main" in names and "pymetis" in names  # the parse works: the command's own modules
    return names


def _heavy(names: set[str]) -> list[str]:
    return sorted(n for n in names if n.split(".")[0] in HEAVY)


@pytest.mark.parametrize("sandbox", ["1", "0"])
def test_agglomerate_metis_loads_nothing_heavy(tmp_path, sandbox):
    out = tmp_path / "out.vtu"
    names = _imported(
        ["agglomerate", BRAIN, "-o", str(out), "--model", "metis", "--k", "32"],
        tmp_path,
        MAGNET_READ_SANDBOX=sandbox,
    )
    assert out.stat().st_size > 0
    assert _heavy(names) == []
    assert not [n for n in names if n.startswith("models.quality")]  # no --metrics: no metric computed


def test_agglomerate_gmsh_file_loads_meshio_but_not_scipy(tmp_path):
    """A gmsh file is read by meshio's reader (in-process: pure Python); still no scipy."""
    import meshio

    x, y = np.meshgrid(np.linspace(0, 1, 9), np.linspace(0, 1, 9))
    pts = np.c_[x.ravel(), y.ravel(), np.zeros(81)]
    q = (np.arange(8)[:, None] + 9 * np.arange(8)[None, :]).ravel()
    tri = np.r_[np.c_[q, q + 1, q + 10], np.c_[q, q + 10, q + 9]]
    msh = tmp_path / "square.msh"
    meshio.write(msh, meshio.Mesh(pts, [("triangle", tri)]), file_format="gmsh22", binary=False)
    names = _imported(
        ["agglomerate", str(msh), "-o", str(tmp_path / "o.vtu"), "--model", "metis", "--k", "8"], tmp_path
    )
    assert "meshio" in names  # the gmsh reader is meshio's
    assert [n for n in _heavy(names) if n.split(".")[0] != "meshio"] == []


def test_cli_reads_a_simple_vtu_in_process(monkeypatch):
    def no_fork(*a, **k):
        raise AssertionError("the CLI forked a reader for a VTU that numpy reads")

    monkeypatch.setattr(sandbox, "call_in_child", no_fork)
    monkeypatch.delenv("MAGNET_READ_SANDBOX", raising=False)
    mesh = sandbox.read_mesh_cli(BRAIN)
    assert mesh.n_cells == 14372
    ref = read.read_mesh(BRAIN)
    assert np.array_equal(mesh.points, ref.points) and np.array_equal(mesh.connectivity, ref.connectivity)
    assert np.array_equal(mesh.tags, ref.tags)


def _ascii_vtu(path) -> None:
    """A VTU with inline ascii arrays: our numpy path leaves it to VTK's reader."""
    path.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian">\n'
        '<UnstructuredGrid><Piece NumberOfPoints="4" NumberOfCells="2"><Points>\n'
        '<DataArray type="Float64" NumberOfComponents="3" format="ascii">0 0 0 1 0 0 1 1 0 0 1 0</DataArray>\n'
        '</Points><Cells><DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 0 2 3</DataArray>\n'
        '<DataArray type="Int64" Name="offsets" format="ascii">3 6</DataArray>\n'
        '<DataArray type="UInt8" Name="types" format="ascii">5 5</DataArray>\n'
        "</Cells></Piece></UnstructuredGrid></VTKFile>\n"
    )


def test_cli_reads_a_vtu_that_needs_vtk_in_the_sandbox(monkeypatch, tmp_path, child_calls):
    path = tmp_path / "ascii.vtu"
    _ascii_vtu(path)
    from models.mesh.vtu import read_vtu_simple

    assert read_vtu_simple(path) is None  # the case under test: numpy's path declines this file
    with pytest.raises(read.NativeReaderNeeded):
        read.read_mesh(path, native=False)
    calls = child_calls
    monkeypatch.delenv("MAGNET_READ_SANDBOX", raising=False)
    mesh = sandbox.read_mesh_cli(path)
    assert calls == [1] and mesh.n_cells == 2


def test_cli_words_a_bad_simple_vtu_as_the_sandbox_does(tmp_path, monkeypatch):
    """A VTU our numpy path reads but whose cells are bad: the same sentence in-process."""
    pytest.importorskip("meshio")
    import meshio

    path = tmp_path / "bad.vtu"
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    meshio.write(path, meshio.Mesh(pts, [("triangle", np.array([[0, 1, 7]]))]))  # node 7: no such point
    from models.errors import MeshError

    monkeypatch.delenv("MAGNET_READ_SANDBOX", raising=False)
    with pytest.raises(MeshError) as cli:
        sandbox.read_mesh_cli(path)
    with pytest.raises(MeshError) as safe:
        sandbox.read_mesh_safe(path)
    assert str(cli.value) == str(safe.value) and "bad.vtu" in str(cli.value)


def _random_graph(rng, n: int, m: int):
    a, b = rng.integers(0, n, m), rng.integers(0, n, m)
    keep = a != b
    a, b = a[keep], b[keep]
    g = sp.csr_matrix((np.ones(2 * a.size), (np.r_[a, b], np.r_[b, a])), shape=(n, n))
    g.sum_duplicates()
    return g.indptr.astype(np.int64), g.indices.astype(np.int64), a, b


@pytest.mark.parametrize("compiled", ["", "1"])
def test_connected_components_match_scipy(monkeypatch, compiled):
    monkeypatch.setenv("MAGNET_NO_COMPILED", compiled)
    rng = np.random.default_rng(5)
    for n, m in ((1, 0), (7, 3), (200, 150), (1000, 900), (3000, 6000)):
        indptr, indices, a, b = _random_graph(rng, n, m)
        g = sp.csr_matrix((np.ones(indices.size), indices, indptr), shape=(n, n))
        want_n, want = scipy_components(g, directed=False)
        got_n, got = csr.connected_components(indptr, indices)
        assert got_n == want_n and np.array_equal(got, want) and got.dtype == np.int32
        en, ec = csr.edge_components(n, a, b)
        assert en == want_n and np.array_equal(ec, want)
        labels = rng.integers(-1, 4, n)
        same = np.repeat(labels, np.diff(indptr)) == labels[indices]
        gl = sp.csr_matrix(
            (np.ones(int(same.sum())), indices[same], csr.kept_pointers(same, indptr)), shape=(n, n)
        )
        want_n, want = scipy_components(gl, directed=False)
        got_n, got = csr.connected_components(indptr, indices, labels)
        assert got_n == want_n and np.array_equal(got, want)
    # a permutation's cycles, one edge per node (directed, weak): merge's boundary loops
    nxt = rng.permutation(500)
    g = sp.csr_matrix((np.ones(500), (np.arange(500), nxt)), shape=(500, 500))
    want_n, want = scipy_components(g, directed=True, connection="weak")
    got_n, got = csr.connected_components(np.arange(501), nxt)
    assert got_n == want_n and np.array_equal(got, want)
    assert csr.connected_components(np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64))[0] == 0

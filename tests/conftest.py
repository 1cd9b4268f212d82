import os
import sys

import pytest

HERE = os.path.dirname(__file__)
sys.path.insert(0, HERE)
os.environ.setdefault("MPLBACKEND", "Agg")

DATA = os.path.join(HERE, "data")
BRAIN = os.path.join(DATA, "BrainCoronalNoHoles.vtu")
EMILIA = os.path.join(DATA, "MeshEmilia.vtk")


@pytest.fixture
def vtk_xml_path(monkeypatch):
    """.vti, .vts and .vtr files read by VTK's path (vtk_readers) only: our numpy path
    (models/mesh/xml_grid.py, held to that path bit for bit by tests/test_read_xml_grid.py) is off."""
    from models.mesh import xml_grid

    monkeypatch.setattr(xml_grid, "read_xml_grid", lambda *a, **k: None)


@pytest.fixture
def brain_path():
    return BRAIN


@pytest.fixture
def emilia_path():
    return EMILIA


def pieces(graph, labels) -> int:
    """Connected pieces of a labelling over the dual graph (each element connected: pieces == count)."""
    import numpy as np
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    rows = np.repeat(np.arange(graph.n), np.diff(graph.indptr))
    keep = labels[rows] == labels[graph.indices]
    m = sp.csr_matrix((np.ones(keep.sum()), (rows[keep], graph.indices[keep])), shape=(graph.n, graph.n))
    return connected_components(m, directed=False)[0]


@pytest.fixture(scope="module")
def brain():
    """The brain read and prepared once per module: (mesh, dual graph, cell data)."""
    from models.mesh.read import read_mesh
    from models.pipeline import prepare

    m = read_mesh(BRAIN)
    g, d = prepare(m)
    return m, g, d


@pytest.fixture
def child_calls(monkeypatch):
    """Every call of models.mesh.sandbox.call_in_child from here on, counted (the real one runs)."""
    from models.mesh import sandbox

    calls = []
    real = sandbox.call_in_child

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(sandbox, "call_in_child", counted)
    return calls

"""The public Python API (docs/python.md): the documented example runs as written, every kind of
mesh input gives the same agglomeration, and the API, the CLI and the service's validation say
the same words for the same mistake."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import meshio
import numpy as np
import pytest
from conftest import BRAIN, EMILIA
from meshes import mixed_2d

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOC = os.path.join(ROOT, "docs", "python.md")


def doc_example() -> str:
    text = open(DOC, encoding="utf-8").read()
    m = re.search(r"<!-- the example:[^\n]*-->\n```python\n(.*?)```", text, re.S)
    assert m, "docs/python.md lost its example block"
    return m.group(1)


def readme_example() -> str:
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    m = re.search(r"## Python\n\n<!-- the example:[^\n]*-->\n```python\n(.*?)```", text, re.S)
    assert m, "README.md lost its Python example block"
    return m.group(1)


def test_the_readme_shows_the_documented_example():
    assert readme_example() == doc_example()


def _env():
    return dict(os.environ, PYTHONPATH=ROOT, MPLBACKEND="Agg")


def test_the_documented_example_runs(tmp_path):
    code = doc_example()
    assert len(code.strip().splitlines()) <= 14
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=_env(), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[0] == "16"
    back = meshio.read(tmp_path / "square.vtu")
    assert sum(len(c.data) for c in back.cells) == 16
    assert "circle_ratio" in back.cell_data


def test_import_models_is_lazy():
    code = (
        "import sys, models\n"
        "heavy = [m for m in ('numpy', 'meshio', 'torch', 'scipy', 'models.pipeline') if m in sys.modules]\n"
        "assert heavy == [], heavy\n"
        "from models import agglomerate, build_hierarchy, read_mesh, check\n"
        "assert callable(agglomerate) and 'torch' not in sys.modules\n"
    )
    r = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_every_kind_of_input_gives_the_same_labels():
    import vtk

    from models import agglomerate

    ref = agglomerate(BRAIN, k=32, metrics=False)
    m = meshio.read(BRAIN)
    from_meshio = agglomerate(m, k=32, metrics=False)
    cells = [(c.type, c.data) for c in m.cells]
    from_arrays = agglomerate(points=m.points, cells=cells, k=32, metrics=False)
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(BRAIN)
    reader.Update()
    from_vtk = agglomerate(reader.GetOutput(), k=32, metrics=False)
    assert ref.n_elements == 32
    for other in (from_meshio, from_arrays, from_vtk):
        assert np.array_equal(other.labels, ref.labels)


def test_mixed_arrays_with_tags_and_the_writers(tmp_path):
    from models import agglomerate

    p, blocks = mixed_2d(12)
    tags = [np.full(len(b), 1 + i) for i, (_, b) in enumerate(blocks)]
    res = agglomerate(points=p, cells=blocks, tags=tags, mode="segregated", mult_factor=0.3)
    assert set(np.unique(res.mesh.tags)) == {1, 2}
    for e in range(res.n_elements):  # segregated: no element crosses the two groups
        assert np.unique(res.mesh.tags[res.labels == e]).size == 1
    assert res.polygon(0).size >= 3
    res.write(tmp_path / "m.json")
    res.write(tmp_path / "l.mat")
    res.write(tmp_path / "labels.json", kind="labels")
    assert json.loads((tmp_path / "labels.json").read_text()) == res.labels.tolist()
    rep = json.loads((tmp_path / "m.json").read_text())
    assert rep["run"]["elements"] == res.n_elements and rep["run"]["params"]["mode"] == "segregated"
    assert (tmp_path / "l.mat").stat().st_size > 0
    out = res.to_meshio()
    assert sum(len(c.data) for c in out.cells) == res.n_elements


def test_3d_result_to_meshio():
    from meshes import tets

    from models import agglomerate

    p, t = tets(4)
    res = agglomerate(points=p, cells=[("tetra", t)], model="rtree", k=10)
    assert res.n_elements == 10 and res.elements.dim == 3
    m = res.to_meshio()
    assert sum(len(c.data) for c in m.cells) == 10
    with pytest.raises(Exception, match="2D"):
        res.polygon(0)


@pytest.mark.parametrize(
    "kw, flags",
    [
        ({"k": 0}, ["--k", "0"]),
        ({"k": 10**6}, ["--k", str(10**6)]),
        ({"model": "nope", "k": 3}, ["--model", "nope", "--k", "3"]),
        ({"nref": 40}, ["--nref", "40"]),
        ({"k": 4, "nref": 2}, ["--k", "4", "--nref", "2"]),
        ({"mode": "kway", "nref": 2}, ["--mode", "kway", "--nref", "2"]),
    ],
)
def test_api_cli_and_service_validation_say_the_same(tmp_path, kw, flags):
    from models import agglomerate
    from models.errors import ParameterError
    from models.params import validate_params

    with pytest.raises(ParameterError) as api_err:
        agglomerate(BRAIN, **kw)
    r = subprocess.run(
        [sys.executable, "-m", "models.cli", "agglomerate", BRAIN, "-o", str(tmp_path / "x.vtu"), *flags],
        env=_env(),
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    said = r.stderr.strip().removeprefix("magnet: error: ")
    # the same sentence, each parameter named as the command line names it (--mult-factor)
    assert re.sub(r"--([a-z]+(?:-[a-z]+)*)", lambda m: m.group(1).replace("-", "_"), said) == str(
        api_err.value
    )
    with pytest.raises(ParameterError) as svc_err:
        validate_params(kw, {"cells": 14372, "physical_groups": [], "dim": 2})
    assert str(svc_err.value) == str(api_err.value)
    assert svc_err.value.field == api_err.value.field


def test_bad_sources_are_one_sentence():
    from models import agglomerate, check
    from models.errors import MagnetError

    for bad in (dict(source=42), dict(points=np.zeros((3, 2)))):
        with pytest.raises(MagnetError) as err:
            agglomerate(k=2, **bad)
        assert "\n" not in str(err.value) and "give" in str(err.value)
    rep = check(EMILIA)
    assert rep["verdict"] in ("ok", "warnings")


def test_build_hierarchy_api(tmp_path):
    from models import build_hierarchy

    h = build_hierarchy(BRAIN, ratio=8, coarsest=10)
    sizes = [int(lv.max()) + 1 for lv in h.levels]
    assert sizes == sorted(sizes) and sizes[-1] == int(np.ceil(14372 / 8))
    index = h.write(tmp_path / "h")
    assert [lv["elements"] for lv in index["levels"]] == sizes


def test_rl_partitioner_outside_multilevel_warns():
    from models import agglomerate
    from models.errors import ParameterError

    said = []

    class Stop(Exception):
        pass

    def warn(line):
        said.append(line)
        raise Stop  # the warning comes before the slow part: stop there

    with pytest.raises(Stop):
        agglomerate(BRAIN, model="rl-partitioner", nref=2, warn=warn)
    assert len(said) == 1 and "about 2 minutes" in said[0] and "multilevel" in said[0]
    with pytest.raises(ParameterError):
        agglomerate(BRAIN, model="rl-partitioner", k=4, warn=warn)


def test_a_kept_hierarchy_says_why_its_count_is_not_2_to_the_nref():
    """multilevel nref = 7 with its levels kept: the last bisection's parts stay as they are (a
    nested level), so a part in pieces gives more than 128 elements; that is said, and without the
    levels the count is exact."""
    from models import agglomerate

    said = []
    kept = agglomerate(BRAIN, mode="multilevel", nref=7, hierarchy=True, metrics=False, warn=said.append)
    exact = agglomerate(BRAIN, mode="multilevel", nref=7, metrics=False, warn=said.append)
    assert exact.n_elements == 128
    if kept.n_elements == 128:
        assert not said
    else:
        assert len(said) == 1 and f"{kept.n_elements} elements, not 2^nref = 128" in said[0]
        assert "hierarchy=True" in said[0]

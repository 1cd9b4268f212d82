"""`magnet hierarchy` options an outside sweep (session 43) found crashing or accepted and ignored:
--finest cuts with a model other than rtree crashed (exit 70); --keep-rings in 2D, --lymph in 3D
and --kappa with another model and no --mgcheck did nothing without a word; refusals named the
service's options.ratio instead of --ratio, and lists came as Python lists."""

import os
import subprocess
import sys

import meshio
import numpy as np
import pytest
from meshes import quads, tets

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENV = {**os.environ, "PYTHONPATH": f"{ROOT}:{ROOT}/client", "MPLBACKEND": "Agg"}


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("opts")
    p, q = quads(24)
    flat = tmp / "q.vtu"
    meshio.write_points_cells(str(flat), np.column_stack([p, np.zeros(len(p))]), [("quad", q)])
    p3, t3 = tets(6)
    solid = tmp / "t.vtu"
    meshio.write_points_cells(str(solid), p3, [("tetra", t3)])
    return tmp, str(flat), str(solid)


def _run(*args):
    return subprocess.run(
        [sys.executable, "-m", "models.cli", *args], capture_output=True, text=True, env=ENV, cwd=ROOT
    )


@pytest.mark.parametrize("model", ["metis", "kmeans"])
def test_finest_cuts_goes_with_any_model(meshes, model):
    tmp, flat, _ = meshes
    r = _run("hierarchy", flat, "-o", str(tmp / f"cuts-{model}"), "--model", model, "--finest", "cuts")
    assert r.returncode == 0, r.stderr
    assert os.path.exists(tmp / f"cuts-{model}" / "hierarchy.json")


@pytest.mark.parametrize(
    "which, args, said",
    [
        ("flat", ["--keep-rings"], "keeping rings (--keep-rings) is for 3D meshes"),
        ("solid", ["--lymph"], "lymph's mesh structs (--lymph) are for 2D meshes only; this mesh is 3D"),
        ("flat", ["--ratio", "1"], "--ratio must be >= 2"),
        ("flat", ["--finest", "nested", "--model", "metis"], "needs model rtree and no --ratio"),
        ("flat", ["--model", "nope"], "model must be one of metis, kmeans, rtree"),
        ("flat", ["--physical-tag", "nope"], "available: none"),
    ],
)
def test_options_that_do_not_apply_are_refused_in_our_words(meshes, which, args, said):
    tmp, flat, solid = meshes
    out = tmp / "refused"
    r = _run("hierarchy", flat if which == "flat" else solid, "-o", str(out), *args)
    assert r.returncode == 2, r.stdout + r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert said in line and "options." not in line and "[" not in line, line
    assert not os.path.exists(out / "hierarchy.json")


def test_agglomerate_hierarchy_refusal_names_no_flag_it_lacks(meshes):
    tmp, flat, _ = meshes
    r = _run("agglomerate", flat, "-k", "20", "--hierarchy", str(tmp / "h"), "-o", str(tmp / "a.vtu"))
    assert r.returncode == 2
    line = r.stderr.strip().splitlines()[-1]
    assert "--hierarchy needs a recursive mode" in line and "`magnet hierarchy`" in line
    assert "options." not in line and "ratio" not in line, line

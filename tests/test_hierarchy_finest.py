"""The finest-level choice of a hierarchy (issue 24) the same way in: the Python API
(models.agglomeration.build_hierarchy finest= / boxfit=), `magnet hierarchy --finest --boxfit`,
and the job option options.finest / options.boxfit (validated by models.params, 422 over HTTP)."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import meshio
import numpy as np
import pytest
from meshes import quads

from models.agglomeration import build_hierarchy as api_build
from models.errors import ParameterError
from models.hierarchy.nested import build_hierarchy, is_nested
from models.mesh.read import mesh_from_arrays
from models.params import validate_params
from models.pipeline import prepare

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENV = {**os.environ, "PYTHONPATH": f"{ROOT}:{ROOT}/client", "MPLBACKEND": "Agg"}


@pytest.fixture(scope="module")
def square(tmp_path_factory):
    p, q = quads(24)
    src = tmp_path_factory.mktemp("mesh") / "q.vtu"
    meshio.write_points_cells(str(src), np.column_stack([p, np.zeros(len(p))]), [("quad", q)])
    return src, p, q


def _cli(*argv):
    return subprocess.run(
        [sys.executable, "-m", "models.cli", "hierarchy", *map(str, argv)],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
    )


def _written(out):
    index = json.load(open(out / "hierarchy.json", encoding="utf-8"))
    levels = [np.asarray(json.load(open(out / lv["labels"], encoding="utf-8"))) for lv in index["levels"]]
    return index, levels


def test_cli_finest_cuts_is_the_librarys(tmp_path, square):
    src, p, q = square
    m = mesh_from_arrays(p, [("quad", q)])
    _, d = prepare(m)
    want, info = build_hierarchy(m, d, model="rtree", coarsest=10, model_options={"finest": "cuts"})
    default, _ = build_hierarchy(m, d, model="rtree", coarsest=10)
    assert info["finest"] == "cuts" and [int(lv.max()) for lv in want] != [int(lv.max()) for lv in default]
    r = _cli(src, "-o", tmp_path / "h", "--finest", "cuts")
    assert r.returncode == 0, r.stderr
    index, levels = _written(tmp_path / "h")
    assert index["finest"] == "cuts" and index["boxfit"] is False
    assert len(levels) == len(want) and all(np.array_equal(a, b) for a, b in zip(levels, want, strict=True))
    # the Python API gives the same levels
    h = api_build(str(src), finest="cuts")
    assert all(np.array_equal(a, b) for a, b in zip(h.levels, want, strict=True))


def test_cli_boxfit_is_the_librarys(tmp_path, square):
    src, p, q = square
    m = mesh_from_arrays(p, [("quad", q)])
    _, d = prepare(m)
    want, info = build_hierarchy(m, d, model="rtree", coarsest=10, model_options={"boxfit": True})
    assert info["boxfit"] is True and is_nested(want)
    r = _cli(src, "-o", tmp_path / "h", "--boxfit")
    assert r.returncode == 0, r.stderr
    index, levels = _written(tmp_path / "h")
    assert index["boxfit"] is True and index["finest"] == "aggregation"
    assert all(np.array_equal(a, b) for a, b in zip(levels, want, strict=True))


@pytest.mark.parametrize(
    "argv,words",
    [
        (["--finest", "box"], "--finest must be aggregation, cuts, quality or nested"),
        (["--finest", "quality", "--model", "metis"], "needs model rtree and no --ratio"),
        (["--finest", "nested", "--ratio", "8"], "needs model rtree and no --ratio"),
    ],
)
def test_cli_refuses_a_bad_finest_in_one_sentence(tmp_path, square, argv, words):
    src = square[0]
    r = _cli(src, "-o", tmp_path / "h", *argv)
    assert r.returncode != 0 and words in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr and not (tmp_path / "h").exists()


def test_params_validate_finest_and_boxfit():
    base = {"model": "rtree", "mode": "kway", "k": 4}
    o = validate_params({**base, "options": {"hierarchy": True, "finest": "quality", "boxfit": True}})
    assert (
        o["options"]["finest"] == "quality" and o["options"]["boxfit"] is True
    )  # k-way: levels of their own
    o = validate_params({**base, "options": {"hierarchy": True, "finest": "cuts", "ratio": 8}})
    assert o["options"]["finest"] == "cuts" and o["options"]["boxfit"] is False
    assert validate_params(base)["options"]["finest"] is None
    for opts, words in (
        ({"hierarchy": True, "finest": "boxes"}, "options.finest must be"),
        ({"hierarchy": True, "finest": 3}, "options.finest must be"),
        ({"finest": "cuts"}, "go with options.hierarchy = true"),
        ({"boxfit": True}, "go with options.hierarchy = true"),
        ({"hierarchy": True, "boxfit": "yes"}, "options.boxfit"),
        ({"hierarchy": True, "finest": "aggregation", "ratio": 8}, "needs model rtree and no options.ratio"),
    ):
        with pytest.raises(ParameterError, match=words):
            validate_params({**base, "options": opts})
    with pytest.raises(ParameterError, match="needs model rtree"):
        validate_params(
            {"model": "metis", "mode": "kway", "k": 4, "options": {"hierarchy": True, "finest": "nested"}}
        )


def test_service_job_with_finest(tmp_path, square):
    from service_fixtures import square_mesh
    from test_service_api import auth, make, upload

    from worker.tasks import execute_job

    client, settings = make(tmp_path)
    with client:
        h = auth("alice")
        mesh = upload(client, square_mesh(tmp_path / "square.vtu", n=16))
        for bad, words in (
            ({"hierarchy": True, "finest": "boxes"}, "options.finest must be"),
            ({"finest": "cuts"}, "options.hierarchy"),
            ({"hierarchy": True, "finest": "quality", "ratio": 8}, "needs model rtree"),
        ):
            body = {"mesh_id": mesh["id"], "model": "rtree", "mode": "kway", "k": 4, "options": bad}
            r = client.post("/v1/jobs", json=body, headers=h)
            assert r.status_code == 422 and words in r.text, r.text
        body = {
            "mesh_id": mesh["id"],
            "model": "rtree",
            "mode": "kway",
            "k": 4,
            "options": {"hierarchy": True, "finest": "cuts", "boxfit": True},
        }
        job = client.post("/v1/jobs", json=body, headers=h).json()
        assert job["params"]["options"]["finest"] == "cuts"
        assert execute_job(job["id"], settings) == "succeeded"
        zf = zipfile.ZipFile(io.BytesIO(client.get(f"/v1/jobs/{job['id']}/hierarchy", headers=h).content))
        index = json.loads(zf.read("hierarchy.json"))
        assert index["finest"] == "cuts" and index["boxfit"] is True and index["nested"]
        assert index["levels"][-1]["elements"] > 4  # levels of their own, not above the job's 4 elements


def test_service_hierarchy_with_groups_and_keep_rings(tmp_path):
    """options.groups / options.keep_rings: `magnet hierarchy --groups --keep-rings` over HTTP; no
    element of any level crosses a physical group, and a mesh without groups is refused at
    submission."""
    from service_fixtures import square_mesh
    from test_service_api import auth, make, upload

    from worker.tasks import execute_job

    client, settings = make(tmp_path)
    with client:
        h = auth("alice")
        plain = upload(client, square_mesh(tmp_path / "square.vtu", n=16))
        base = {"model": "metis", "mode": "kway", "k": 8}
        for bad, words in (
            ({"hierarchy": True, "groups": True}, "go with a hierarchy of its own"),
            ({"hierarchy": True, "ratio": 4, "groups": True}, "need a mesh with them"),
            ({"hierarchy": True, "ratio": 4, "keep_rings": "yes"}, "options.keep_rings must be"),
            ({"hierarchy": True, "ratio": 4, "keep_rings": True}, "options.keep_rings is for 3D meshes"),
            ({"hierarchy": True, "finest": "cuts", "kappa": [1, 0]}, "options.kappa must be"),
            ({"hierarchy": True, "ratio": 4, "kappa": [1, 2]}, "rtree's levels of their own from the cells"),
        ):
            r = client.post("/v1/jobs", json={"mesh_id": plain["id"], **base, "options": bad}, headers=h)
            assert r.status_code == 422 and words in r.json()["detail"], r.text
        three = {"hierarchy": True, "finest": "cuts", "kappa": [1, 2, 3]}
        r = client.post(
            "/v1/jobs", json={"mesh_id": plain["id"], **base, "model": "rtree", "options": three}, headers=h
        )
        assert r.status_code == 422 and "give one per axis" in r.json()["detail"], r.text
        tagged = upload(client, Path(__file__).parent / "data" / "square_inclusion.msh")
        body = {"mesh_id": tagged["id"], **base, "options": {"hierarchy": True, "finest": "cuts"}}
        body["options"] |= {"groups": True, "keep_rings": False}
        job = client.post("/v1/jobs", json=body, headers=h).json()
        assert job["params"]["options"]["groups"] is True
        assert execute_job(job["id"], settings) == "succeeded"
        zf = zipfile.ZipFile(io.BytesIO(client.get(f"/v1/jobs/{job['id']}/hierarchy", headers=h).content))
        index = json.loads(zf.read("hierarchy.json"))
        body = {
            "mesh_id": plain["id"],
            **base,
            "model": "rtree",
            "options": {"hierarchy": True, "finest": "cuts"},
        }
        body["options"]["kappa"] = [
            10,
            1,
        ]  # (cut for a tensor 10x stronger along x: recorded with the levels)
        aniso = client.post("/v1/jobs", json=body, headers=h).json()
        assert execute_job(aniso["id"], settings) == "succeeded"
        got = client.get(f"/v1/jobs/{aniso['id']}/hierarchy", headers=h).content
        assert json.loads(zipfile.ZipFile(io.BytesIO(got)).read("hierarchy.json"))["kappa"] == [10.0, 1.0]
        from models.mesh.read import read_mesh

        tags = read_mesh(str(Path(__file__).parent / "data" / "square_inclusion.msh")).tags
        for level in index["levels"]:
            labels = np.asarray(json.loads(zf.read(level["labels"])))
            per = {int(e): set(tags[labels == e].tolist()) for e in np.unique(labels)}
            assert all(len(g) == 1 for g in per.values()), level

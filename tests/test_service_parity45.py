"""The HTTP API refuses a job's parameters in the library's words, as the CLI and Python do (session
45's parity sweep: the wire format took "8", 8.0 and true as k = 8 and 1, and refused in its own
text: "k: Input should be greater than or equal to 1"); subset ids are the file's cell ids over
HTTP too, where the read left a few bad cells out."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient
from meshes import triangles

from jobqueue.settings import Settings
from service.app import create_app
from service.wording import json_values

KEYS = "alice:alice-token"
AUTH = {"Authorization": "Bearer alice-token"}


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(Settings(data_dir=tmp_path / "data", api_keys=KEYS))) as c:
        yield c


def _upload(client, path) -> str:
    r = client.post(
        "/v1/meshes",
        params={"filename": path.name},
        content=path.read_bytes(),
        headers={"Content-Type": "application/octet-stream", **AUTH},
    )
    assert r.status_code == 201, r.text
    return r.json()["id"]


@pytest.fixture
def bad_first(tmp_path):
    """A square of 512 triangles after 3 zero-area ones: the file has 515 cells, 512 are read."""
    import meshio

    p, t = triangles(16)
    bad = np.array([[0, 0, 1], [2, 2, 3], [5, 5, 6]])
    path = tmp_path / "bad_first.vtu"
    meshio.write(str(path), meshio.Mesh(np.c_[p, np.zeros(len(p))], [("triangle", np.r_[bad, t])]))
    return path


@pytest.mark.parametrize(
    "params, said",
    [
        ({"k": "8"}, "k must be an integer, got '8'"),
        ({"k": True}, "k must be an integer, got True"),
        ({"k": 0}, "k must be >= 1, got 0"),
        ({"k": 4, "options": {"allow_extra": "yes"}}, "options.allow_extra must be true or false, got 'yes'"),
        ({"k": 4, "options": {"seed": "7"}}, "seed must be an integer, got '7'"),
        ({"k": 4, "bogus": 1}, "unknown parameter(s): bogus"),
        ({"target_size": True}, "target_size must be a number, got True"),
    ],
)
def test_job_parameters_are_refused_in_the_librarys_words(client, bad_first, params, said):
    from models import api
    from models.errors import ParameterError

    with pytest.raises(ParameterError) as lib:
        api.validate_params(params)
    assert str(lib.value) == said  # the library's sentence ...
    mesh_id = _upload(client, bad_first)
    r = client.post("/v1/jobs", json={"mesh_id": mesh_id, **params}, headers=AUTH)
    assert r.status_code == 422, r.text
    # ... word for word over HTTP, an option named as the request names it (options.seed) and the
    # value echoed as the request wrote it (JSON: true, "8"; tests/test_service_sweep47.py)
    said = json_values(said)
    assert r.json()["detail"] in (said, f"options.{said}")
    assert "Input should" not in r.text


def test_subset_ids_over_http_are_the_files(client, bad_first):
    mesh_id = _upload(client, bad_first)
    r = client.post("/v1/jobs", json={"mesh_id": mesh_id, "k": 4, "subset": [514]}, headers=AUTH)
    assert (
        r.status_code == 422
        and "k = 4 is larger than the number of cells to agglomerate (1)" in r.json()["detail"]
    )
    r = client.post(
        "/v1/jobs", json={"mesh_id": mesh_id, "k": 2, "subset": [0, 1, 2, 500, 514]}, headers=AUTH
    )
    assert r.status_code == 202, r.text  # (file ids 0..2 are the cells left out: 2 cells to agglomerate)
    r = client.post("/v1/jobs", json={"mesh_id": mesh_id, "k": 2, "subset": [515]}, headers=AUTH)
    assert r.status_code == 422 and "(the mesh has cells 0..514), e.g. 515" in r.json()["detail"]


def test_a_coarsest_level_above_the_cells_is_refused_before_the_job(client, bad_first):
    """options.coarsest at or above the mesh's cells: refused at submission (422, naming the option),
    as `magnet hierarchy` refuses it, not accepted and then failed by the worker."""
    mesh_id = _upload(client, bad_first)
    body = {"mesh_id": mesh_id, "k": 8, "options": {"hierarchy": True, "finest": "cuts", "coarsest": 600}}
    r = client.post("/v1/jobs", json=body, headers=AUTH)
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == "the mesh has 512 cells: nothing to coarsen with options.coarsest = 600"
    assert r.json()["field"] == "options.coarsest"
    body["options"]["coarsest"] = 10
    assert client.post("/v1/jobs", json=body, headers=AUTH).status_code in (201, 202)

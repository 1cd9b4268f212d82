"""What the web page needs from the API, in-process: the page and its files at `/`, the polygons of
a finished 2D job (GET /v1/jobs/{id}/polygons) and removing a job from the list (?purge=true)."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
from fastapi.testclient import TestClient
from meshes import tets
from service_fixtures import square_mesh

from jobqueue.settings import Settings
from service.app import create_app
from worker.tasks import execute_job

KEYS = "alice:alice-token,bob:bob-token"
ALICE = {"Authorization": "Bearer alice-token"}
BOB = {"Authorization": "Bearer bob-token"}


@pytest.fixture
def app(tmp_path):
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS)
    with TestClient(create_app(settings)) as client:
        yield client, settings


def finished_job(client, settings, path, **params) -> dict:
    mesh = client.post(
        "/v1/meshes", params={"filename": path.name}, content=path.read_bytes(), headers=ALICE
    ).json()
    job = client.post("/v1/jobs", json={"mesh_id": mesh["id"], **params}, headers=ALICE).json()
    assert execute_job(job["id"], settings) == "succeeded"
    return client.get(f"/v1/jobs/{job['id']}", headers=ALICE).json()


def test_page_and_static_files_need_no_key(app):
    client, _ = app
    page = client.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert 'src="static/app.js"' in page.text and "https://" not in page.text  # nothing from elsewhere
    assert "default-src 'self'" in page.headers["content-security-policy"]
    for name, media in (("app.js", "javascript"), ("style.css", "text/css")):
        r = client.get(f"/static/{name}")
        assert r.status_code == 200 and media in r.headers["content-type"], name
        assert "http://" not in r.text and "https://" not in r.text
    assert client.get("/static/nothing.js").status_code == 404
    assert "/" not in client.get("/openapi.json").json()["paths"]


def test_polygons_of_a_2d_job(app, tmp_path):
    client, settings = app
    job = finished_job(client, settings, square_mesh(tmp_path / "square.vtu", 12), k=9)
    r = client.get(f"/v1/jobs/{job['id']}/polygons", headers=ALICE)
    assert r.status_code == 200, r.text
    poly = r.json()
    n = job["result"]["elements"]
    offsets = np.array(poly["offsets"])
    assert len(offsets) == n + 1 and offsets[0] == 0 and offsets[-1] == len(poly["connectivity"])
    assert poly["cell_data"]["element_id"] == list(range(n))
    points = np.array(poly["points"])
    assert points.shape[1] == 2 and set(poly["connectivity"]) == set(range(len(points)))
    # shoelace areas: each polygon's area is the element's measure, and they tile the unit square
    areas = []
    for e in range(n):
        x, y = points[poly["connectivity"][offsets[e] : offsets[e + 1]]].T
        areas.append(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    assert np.allclose(areas, poly["cell_data"]["measure"], rtol=1e-5)
    assert abs(sum(areas) - 1.0) < 1e-6
    metrics = client.get(f"/v1/jobs/{job['id']}/metrics", headers=ALICE).json()
    for name, values in metrics["per_element"].items():
        assert np.allclose(poly["cell_data"][name], values, atol=1e-6), name
    assert client.get(f"/v1/jobs/{job['id']}/polygons", headers=BOB).status_code == 404
    assert client.get(f"/v1/jobs/{job['id']}/polygons").status_code == 401


def test_polygons_of_a_3d_job_are_refused(app, tmp_path):
    client, settings = app
    points, cells = tets(3)
    path = tmp_path / "cube.vtu"
    meshio.write(path, meshio.Mesh(points, [("tetra", cells)]))
    job = finished_job(client, settings, path, k=4)
    r = client.get(f"/v1/jobs/{job['id']}/polygons", headers=ALICE)
    assert r.status_code == 404 and "2D" in r.json()["detail"]


def test_purge_removes_a_job_from_the_list(app, tmp_path):
    client, settings = app
    done = finished_job(client, settings, square_mesh(tmp_path / "square.vtu", 6), k=4)
    r = client.delete(f"/v1/jobs/{done['id']}", headers=ALICE)
    assert r.status_code == 409 and "purge" in r.json()["detail"]
    assert client.delete(f"/v1/jobs/{done['id']}?purge=true", headers=BOB).status_code == 404
    assert client.delete(f"/v1/jobs/{done['id']}?purge=true", headers=ALICE).status_code == 204
    assert client.get(f"/v1/jobs/{done['id']}", headers=ALICE).status_code == 404
    assert client.get("/v1/jobs", headers=ALICE).json()["total"] == 0
    # a queued job is cancelled, then removed; the same job submitted again still runs
    queued = client.post("/v1/jobs", json={"mesh_id": done["mesh_id"], "k": 5}, headers=ALICE).json()
    assert client.delete(f"/v1/jobs/{queued['id']}?purge=true", headers=ALICE).status_code == 204
    assert execute_job(queued["id"], settings) == "skipped"
    again = client.post("/v1/jobs", json={"mesh_id": done["mesh_id"], "k": 5}, headers=ALICE).json()
    assert execute_job(again["id"], settings) == "succeeded"

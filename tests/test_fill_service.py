"""A closed surface through the HTTP API (in-process app, embedded broker, the worker's execute_job):
the upload is accepted as a surface, its jobs need options.fill, and the filled result keeps the
enclosed volume. An open surface is refused at upload with our sentence."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
from fastapi.testclient import TestClient

pytest.importorskip("gmsh")

from service_fixtures import upload_raw  # noqa: E402
from surfaces import enclosed_volume, surface_of  # noqa: E402

from jobqueue.settings import Settings  # noqa: E402
from service.app import create_app  # noqa: E402
from worker.tasks import execute_job  # noqa: E402

KEYS = "alice:alice-token"
H = {"Authorization": "Bearer alice-token"}


def ball(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A closed triangulated unit sphere, surface-meshed by gmsh."""
    return surface_of(lambda occ: occ.addSphere(0, 0, 0, 1), 2.0 / n)


def upload(client, name: str, data: bytes):
    return upload_raw(client, name, data, "alice-token")


def test_surface_upload_fill_job_and_open_surface(tmp_path):
    points, tris = ball()
    ref = enclosed_volume(points, tris)
    path = tmp_path / "ball.stl"
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tris)]))
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS)
    client = TestClient(create_app(settings))
    with client:
        r = upload(client, "ball.stl", path.read_bytes())
        assert r.status_code == 201, r.text
        mesh = r.json()
        surface = mesh["surface"]  # (the upload answer says it is a surface to fill, as GET does)
        assert surface["triangles"] == len(tris) and mesh["cells"] == surface["estimated_cells"]
        assert abs(surface["enclosed_volume"] - ref) <= 1e-9 * ref
        got = client.get(f"/v1/meshes/{mesh['id']}", headers=H).json()
        assert got["surface"] == surface
        r = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 8}, headers=H)
        assert r.status_code == 422 and "options.fill" in r.text
        r = client.post(
            "/v1/jobs", json={"mesh_id": mesh["id"], "k": 8, "options": {"fill": True}}, headers=H
        )
        assert r.status_code == 202, r.text
        job = r.json()
        assert execute_job(job["id"], settings) == "succeeded"
        done = client.get(f"/v1/jobs/{job['id']}", headers=H).json()
        assert done["result"]["elements"] == 8
        assert abs(done["result"]["fill"]["volume"] - ref) <= 1e-9 * ref
        assert not done["result"]["fill"]["remeshed"]
        opened = tmp_path / "open.stl"
        meshio.write(str(opened), meshio.Mesh(points, [("triangle", tris[: len(tris) // 2])]))
        r = upload(client, "open.stl", opened.read_bytes())
        assert r.status_code == 422
        assert "is not a closed surface" in r.text and "boundary edges" in r.text

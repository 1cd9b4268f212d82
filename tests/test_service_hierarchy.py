"""Multilevel jobs with a refiner through the HTTP API, and the nested hierarchy as a zip
(the real app, its SQLite job store and embedded broker; the job run by the worker's execute_job)."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
from service_fixtures import square_mesh
from test_service_api import auth, make, upload

from worker.tasks import execute_job


@pytest.fixture(scope="module")
def square(tmp_path_factory):
    return square_mesh(tmp_path_factory.mktemp("mesh") / "square.vtu", n=16)


def test_multilevel_fm_job_with_hierarchy_zip(tmp_path, square):
    client, settings = make(tmp_path)
    with client:
        h = auth("alice")
        mesh = upload(client, square)
        body = {
            "mesh_id": mesh["id"],
            "model": "metis",
            "mode": "multilevel",
            "nref": 3,
            "refiner": "fm",
            "options": {"threshold": 40, "hierarchy": True},
        }
        job = client.post("/v1/jobs", json=body, headers=h).json()
        assert job["params"]["refiner"] == "fm"
        assert execute_job(job["id"], settings) == "succeeded"
        done = client.get(f"/v1/jobs/{job['id']}", headers=h).json()
        assert done["result"]["elements"] == 8
        assert "partition.refine" in done["result"]["timings"]
        r = client.get(f"/v1/jobs/{job['id']}/hierarchy", headers=h)
        assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
        zf = zipfile.ZipFile(io.BytesIO(r.content))
        index = json.loads(zf.read("hierarchy.json"))
        assert index["nested"] and [lv["elements"] for lv in index["levels"]] == [1, 2, 4, 8]
        labels = [np.asarray(json.loads(zf.read(lv["labels"]))) for lv in index["levels"]]
        assert np.array_equal(labels[-1], client.get(f"/v1/jobs/{job['id']}/labels", headers=h).json())
        for L in range(1, 4):
            parent = np.asarray(json.loads(zf.read(index["levels"][L]["parent"])))
            assert np.array_equal(parent[labels[L]], labels[L - 1])
            lymph = json.loads(zf.read(index["levels"][L]["lymph"]))
            assert lymph["region"]["ne"] == index["levels"][L]["elements"]

        # a job without the option has no hierarchy: 404 that says how to get one
        plain = client.post(
            "/v1/jobs", json={"mesh_id": mesh["id"], "model": "metis", "mode": "nref", "nref": 2}, headers=h
        ).json()
        assert execute_job(plain["id"], settings) == "succeeded"
        r = client.get(f"/v1/jobs/{plain['id']}/hierarchy", headers=h)
        assert r.status_code == 404 and "options.hierarchy" in r.text
        # bad combinations are 422 at submission
        for bad in (
            {"mode": "kway", "k": 4, "options": {"hierarchy": True}},
            {"mode": "kway", "k": 4, "refiner": "rl-refiner"},
            {"mode": "nref", "nref": 2, "refiner": "nope"},
        ):
            r = client.post("/v1/jobs", json={"mesh_id": mesh["id"], **bad}, headers=h)
            assert r.status_code == 422, r.text

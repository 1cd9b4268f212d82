"""End to end on the brain slice (14,372 triangles): uvicorn + a Celery worker + Redis as real
processes; METIS and k-means jobs; the downloaded VTU, metrics, labels and lymph structs equal what
the in-process `magnet agglomerate` writes for the same parameters."""

from __future__ import annotations

import io
import json

import meshio
import numpy as np
import pytest
from scipy.io import loadmat
from service_fixtures import BRAIN, SHARED_REDIS, Api, service_env, start_api, start_worker
from test_queue_redis import redis_up

from models.cli.main import main as magnet

pytestmark = [pytest.mark.redis, pytest.mark.slow]
JOBS = [
    ("metis", ["--k", "128"], {"k": 128}),
    ("kmeans", ["--k", "64", "--seed", "7"], {"k": 64, "options": {"seed": 7}}),
]


def test_brain_end_to_end_matches_in_process_cli(tmp_path):
    if not redis_up():
        pytest.skip("Redis is not running at 127.0.0.1:6379")
    env = service_env(tmp_path / "data", broker_url=SHARED_REDIS)
    api_proc, url = start_api(env, tmp_path)
    worker = start_worker(env, tmp_path, "e2e")
    try:
        api = Api(url)
        mesh = api.upload(BRAIN)
        assert mesh["cells"] == 14372 and mesh["dim"] == 2
        submitted = [
            (model, flags, api.submit(mesh["id"], model=model, **params)) for model, flags, params in JOBS
        ]
        for model, flags, job in submitted:
            done = api.wait(job["id"], 180)
            assert done["status"] == "succeeded", done
            local = tmp_path / f"local-{model}"
            local.mkdir()
            rc = magnet(
                [
                    "agglomerate",
                    str(BRAIN),
                    "-o",
                    str(local / "mesh.vtu"),
                    "--model",
                    model,
                    *flags,
                    "--metrics",
                    str(local / "metrics.json"),
                    "--labels",
                    str(local / "labels.json"),
                    "--lymph",
                    str(local / "lymph.json"),
                ]
            )
            assert rc == 0

            def get(part, jid=job["id"], **kw):
                return api.http.get(f"/v1/jobs/{jid}/{part}", **kw)

            labels = get("labels").json()
            assert labels == json.loads((local / "labels.json").read_text())
            assert done["result"]["elements"] == len(set(labels))
            metrics = get("metrics").json()
            expected = json.loads((local / "metrics.json").read_text())
            assert metrics["elements"] == expected["elements"] == done["result"]["elements"]
            for name, value in expected["summary"].items():
                assert metrics["summary"][name] == pytest.approx(value, rel=1e-9), name
            remote_vtu = tmp_path / f"remote-{model}.vtu"
            remote_vtu.write_bytes(get("mesh").content)
            a, b = meshio.read(remote_vtu), meshio.read(local / "mesh.vtu")
            assert np.allclose(a.points, b.points)
            assert (
                sum(len(c.data) for c in a.cells) == sum(len(c.data) for c in b.cells) == metrics["elements"]
            )
            lymph = get("lymph").json()
            assert lymph == json.loads((local / "lymph.json").read_text())
            mat = loadmat(io.BytesIO(get("lymph", params={"format": "mat"}).content))
            assert int(mat["region"]["ne"][0, 0].squeeze()) == lymph["region"]["ne"] == metrics["elements"]
            assert get("preview.png").content[:4] == b"\x89PNG"
    finally:
        worker.stop()
        api_proc.stop()

"""The HTTP API in-process (the real app, its SQLite job store and embedded broker; no worker
process: jobs that must finish are run with the worker's own execute_job)."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import zlib

import pytest
from fastapi.testclient import TestClient
from service_fixtures import ROOT, square_mesh

from jobqueue.settings import Settings
from service.app import create_app
from worker.tasks import execute_job

KEYS = "alice:alice-token,bob:bob-token"


@pytest.fixture(scope="module")
def square(tmp_path_factory):
    return square_mesh(tmp_path_factory.mktemp("mesh") / "square.vtu", n=10)


def make(tmp_path, **overrides) -> tuple[TestClient, Settings]:
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS, **overrides)
    return TestClient(create_app(settings)), settings


def auth(user: str) -> dict:
    return {"Authorization": f"Bearer {user}-token"}


def upload(client, path, user="alice"):
    r = client.post(
        "/v1/meshes",
        params={"filename": path.name},
        content=path.read_bytes(),
        headers={"Content-Type": "application/octet-stream", **auth(user)},
    )
    assert r.status_code == 201, r.text
    return r.json()


@pytest.fixture
def app(tmp_path):
    client, settings = make(tmp_path)
    with client:
        yield client, settings


def test_service_never_imports_torch(tmp_path, square):
    code = f"""
import sys
from fastapi.testclient import TestClient
from service.app import create_app
from jobqueue.settings import Settings
import service.cli, worker.cli, worker.app
c = TestClient(create_app(Settings(data_dir={str(tmp_path)!r})))
assert c.get('/v1/models').status_code == 200
mesh = c.post('/v1/meshes', params={{'filename': 'sq.vtu'}}, content=open({str(square)!r}, 'rb').read()).json()
job = c.post('/v1/jobs', json={{'mesh_id': mesh['id'], 'model': 'sage-base', 'mode': 'nref', 'nref': 2}})
assert job.status_code == 202, job.text
print('torch' in sys.modules)
"""
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "False"


def test_keys_required_and_users_isolated(app, square):
    client, _ = app
    assert client.get("/v1/jobs").status_code == 401
    assert client.get("/v1/jobs", headers={"Authorization": "Bearer nope"}).status_code == 401
    assert client.get("/healthz").status_code == 200
    mesh = upload(client, square, "alice")
    assert client.get(f"/v1/meshes/{mesh['id']}", headers=auth("alice")).status_code == 200
    assert client.get(f"/v1/meshes/{mesh['id']}", headers=auth("bob")).status_code == 404
    r = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 4}, headers=auth("bob"))
    assert r.status_code == 404
    job = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 4}, headers=auth("alice")).json()
    assert client.get(f"/v1/jobs/{job['id']}", headers=auth("bob")).status_code == 404
    assert client.delete(f"/v1/jobs/{job['id']}", headers=auth("bob")).status_code == 404
    assert client.get("/v1/jobs", headers=auth("bob")).json()["total"] == 0
    # bob uploading the same bytes gets the same id, and now sees the mesh (not alice's jobs)
    assert upload(client, square, "bob")["id"] == mesh["id"]
    assert client.get("/v1/jobs", headers=auth("bob")).json()["total"] == 0


def test_upload_raw_and_multipart_same_id(app, square):
    client, _ = app
    mesh = upload(client, square)
    assert mesh["cells"] == 200 and mesh["dim"] == 2 and mesh["cell_types"] == {"triangle": 200}
    r = client.post("/v1/meshes", files={"file": ("square.vtu", square.read_bytes())}, headers=auth("alice"))
    assert r.status_code == 201 and r.json()["id"] == mesh["id"]


@pytest.mark.parametrize(
    "name,content,status,words",
    [
        ("mesh.exe", b"whatever", 422, "cannot read mesh.exe: unknown mesh format '.exe'"),  # (as the CLI)
        (
            "mesh.vtu",
            b"",
            422,
            "cannot read mesh.vtu as VTK XML (VTU): the file is empty (0 bytes)",
        ),  # (as the CLI)
        ("mesh.vtu", b"<VTKFile><garbage", 422, "XML"),
        *(  # a web page saved under a mesh's name, with and without its DOCTYPE: the CLI's words
            (
                "mesh.vtu",
                page,
                422,
                "cannot read mesh.vtu as VTK XML (VTU): it is a web page (HTML), not a VTK XML file",
            )
            for page in (
                b"<!DOCTYPE html>\n<html><head><title>404</title></head><body>Not found</body></html>",
                b"<html><body>Not found</body></html>",
            )
        ),
        ("mesh.msh", b"\x00\x01 not a gmsh file", 422, ""),
        (
            "mesh.vtu",
            b'<?xml version="1.0"?><!DOCTYPE lol [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;">]>'
            b'<VTKFile type="UnstructuredGrid"><UnstructuredGrid><Piece NumberOfPoints="1" NumberOfCells="1">'
            b"&b;</Piece></UnstructuredGrid></VTKFile>",
            422,
            "DOCTYPE",
        ),
        (
            "mesh.vtu",
            b'<?xml version="1.0"?><VTKFile type="UnstructuredGrid"><UnstructuredGrid>'
            b'<Piece NumberOfPoints="3" NumberOfCells="999999999"></Piece></UnstructuredGrid></VTKFile>',
            413,
            "limit",
        ),
    ],
)
def test_bad_uploads_rejected(app, name, content, status, words):
    client, _ = app
    r = client.post(
        "/v1/meshes",
        params={"filename": name},
        content=content,
        headers={"Content-Type": "application/octet-stream", **auth("alice")},
    )
    assert r.status_code == status, r.text
    assert words.lower() in r.json()["detail"].lower()


def test_upload_size_limit(tmp_path, square):
    client, _ = make(tmp_path, max_upload_bytes=1000)
    with client:
        r = client.post(
            "/v1/meshes",
            params={"filename": "s.vtu"},
            content=square.read_bytes(),
            headers={"Content-Type": "application/octet-stream", **auth("alice")},
        )
        assert r.status_code == 413
        # chunked (no Content-Length): counted as it streams
        r = client.post(
            "/v1/meshes",
            params={"filename": "s.vtu"},
            content=iter([square.read_bytes()] * 2),
            headers={"Content-Type": "application/octet-stream", **auth("alice")},
        )
        assert r.status_code == 413


def test_cell_limit(tmp_path, square):
    client, _ = make(tmp_path, max_cells=100)
    with client:
        r = client.post(
            "/v1/meshes",
            params={"filename": "s.vtu"},
            content=square.read_bytes(),
            headers={"Content-Type": "application/octet-stream", **auth("alice")},
        )
        assert r.status_code == 413 and "200" in r.json()["detail"]


def zlib_bomb_vtu(path, inflated: int) -> None:
    """A VTU whose point coordinates are one zlib block inflating to `inflated` bytes of zeros.

    Built without compressing it all: after a full flush the compressor emits the same bytes for
    every further chunk of zeros, so the stream is one chunk's output repeated, plus the trailer.
    """
    size = 1 << 24
    comp, chunk = zlib.compressobj(1), bytes(size)
    first = comp.compress(chunk) + comp.flush(zlib.Z_FULL_FLUSH)
    middle = comp.compress(chunk) + comp.flush(zlib.Z_FULL_FLUSH)
    adler = ((inflated % 65521) << 16) | 1  # adler32 of `inflated` zero bytes
    data = first + middle * (inflated // size - 1) + b"\x03\x00" + adler.to_bytes(4, "big")
    header = (
        (1).to_bytes(8, "little")
        + inflated.to_bytes(8, "little")
        + inflated.to_bytes(8, "little")
        + len(data).to_bytes(8, "little")
    )
    payload = base64.b64encode(header).decode() + base64.b64encode(data).decode()
    path.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" '
        'header_type="UInt64" compressor="vtkZLibDataCompressor"><UnstructuredGrid>'
        '<Piece NumberOfPoints="3" NumberOfCells="1"><Points>'
        f'<DataArray type="Float64" NumberOfComponents="3" format="binary">{payload}</DataArray></Points>'
        '<Cells><DataArray type="Int64" Name="connectivity" format="ascii">0 1 2</DataArray>'
        '<DataArray type="Int64" Name="offsets" format="ascii">3</DataArray>'
        '<DataArray type="UInt8" Name="types" format="ascii">5</DataArray></Cells>'
        "</Piece></UnstructuredGrid></VTKFile>\n"
    )


def test_compressed_bomb_does_not_take_the_server_down(tmp_path, square):
    bomb = tmp_path / "bomb.vtu"
    zlib_bomb_vtu(bomb, inflated=3 * 2**29)  # 1.5 GiB of zeros in 7 MB
    client, _ = make(tmp_path, parse_memory_bytes=2**30, parse_timeout_s=60)
    with client:
        r = client.post(
            "/v1/meshes",
            params={"filename": "bomb.vtu"},
            content=bomb.read_bytes(),
            headers={"Content-Type": "application/octet-stream", **auth("alice")},
        )
        assert r.status_code == 422, r.text
        assert upload(client, square)["cells"] == 200  # still serving


def test_job_parameters_validated_at_submission(app, square):
    client, _ = app
    mesh = upload(client, square)
    cases = [
        ({"k": 10_000}, "k"),
        ({"model": "nope", "k": 2}, "model"),
        ({"mode": "kway"}, "k"),
        ({"k": "many"}, "k"),
        ({"k": 2, "options": {"seed": -1}}, "seed"),
        ({"k": 2, "subset": [0, 99999], "mode": "coarsen"}, "subset"),
        ({"k": 2, "colour": 1}, "colour"),
    ]
    for params, field in cases:
        r = client.post("/v1/jobs", json={"mesh_id": mesh["id"], **params}, headers=auth("alice"))
        assert r.status_code == 422, (params, r.text)
        assert field in json.dumps(r.json()["detail"]) + str(r.json().get("field")), (params, r.text)
    assert (
        client.post("/v1/jobs", json={"mesh_id": "0" * 64, "k": 2}, headers=auth("alice")).status_code == 404
    )
    assert client.get("/v1/jobs", headers=auth("alice")).json()["total"] == 0


def test_job_lifecycle_results_dedup_and_cancel(app, square):
    client, settings = app
    mesh = upload(client, square)
    r = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "model": "metis", "k": 6}, headers=auth("alice"))
    assert r.status_code == 202 and r.headers["location"] == f"/v1/jobs/{r.json()['id']}"
    job = r.json()
    assert job["status"] == "queued" and job["params"]["k"] == 6
    assert client.get(f"/v1/jobs/{job['id']}/mesh", headers=auth("alice")).status_code == 409
    # an identical request while the first is in flight follows it
    follower = client.post(
        "/v1/jobs", json={"mesh_id": mesh["id"], "model": "metis", "k": 6}, headers=auth("alice")
    ).json()
    assert follower["id"] != job["id"] and follower["cached"]
    assert execute_job(job["id"], settings) == "succeeded"
    done = client.get(f"/v1/jobs/{job['id']}", headers=auth("alice")).json()
    assert done["status"] == "succeeded" and done["result"]["elements"] >= 6 and done["progress"] == 1.0
    assert done["started_at"] and done["finished_at"] and done["attempts"] == 1
    assert client.get(f"/v1/jobs/{follower['id']}", headers=auth("alice")).json()["status"] == "succeeded"
    # results
    h = auth("alice")
    assert client.get(f"/v1/jobs/{job['id']}/mesh", headers=h).content.startswith(b"<")
    assert (
        "summary" in json.dumps(client.get(f"/v1/jobs/{job['id']}/metrics", headers=h).json())
        or client.get(f"/v1/jobs/{job['id']}/metrics", headers=h).status_code == 200
    )
    labels = client.get(f"/v1/jobs/{job['id']}/labels", headers=h).json()
    assert len(labels) == 200
    assert "region" in client.get(f"/v1/jobs/{job['id']}/lymph", headers=h).json()
    mat = client.get(f"/v1/jobs/{job['id']}/lymph", headers={"Accept": "application/x-matlab-data", **h})
    assert mat.content[:6] == b"MATLAB"
    assert client.get(f"/v1/jobs/{job['id']}/lymph?format=mat", headers=h).content == mat.content
    assert client.get(f"/v1/jobs/{job['id']}/preview.png", headers=h).content[:4] == b"\x89PNG"
    # same mesh + params again: born succeeded, nothing recomputed
    again = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "model": "metis", "k": 6}, headers=h).json()
    assert again["status"] == "succeeded" and again["cached"] and again["result"] == done["result"]
    # cancel a queued job; a finished one cannot be cancelled
    other = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 5}, headers=h).json()
    assert client.delete(f"/v1/jobs/{other['id']}", headers=h).json()["status"] == "cancelled"
    assert client.delete(f"/v1/jobs/{other['id']}", headers=h).status_code == 409
    assert execute_job(other["id"], settings) == "skipped"
    listing = client.get("/v1/jobs", params={"limit": 2}, headers=h).json()
    assert listing["total"] == 4 and len(listing["items"]) == 2
    assert client.get("/v1/jobs", params={"status": "cancelled"}, headers=h).json()["total"] == 1


def test_cancelled_leader_hands_over_to_its_follower(app, square):
    client, settings = app
    h = auth("alice")
    mesh = upload(client, square)
    leader = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 3}, headers=h).json()
    follower = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 3}, headers=h).json()
    client.delete(f"/v1/jobs/{leader['id']}", headers=h)
    assert client.get(f"/v1/jobs/{follower['id']}", headers=h).json()["status"] == "queued"
    assert execute_job(follower["id"], settings) == "succeeded"
    assert client.get(f"/v1/jobs/{leader['id']}", headers=h).json()["status"] == "cancelled"


@pytest.mark.parametrize("gpu_queue,expected", [(False, "cpu"), (True, "gpu")])
def test_neural_models_routed_to_gpu_queue_only_when_configured(tmp_path, square, gpu_queue, expected):
    client, _ = make(tmp_path, gpu_queue=gpu_queue)
    with client:
        mesh = upload(client, square)
        job = client.post(
            "/v1/jobs",
            json={"mesh_id": mesh["id"], "model": "sage-base", "mode": "nref", "nref": 2},
            headers=auth("alice"),
        ).json()
        assert job["queue"] == expected
        job = client.post(
            "/v1/jobs", json={"mesh_id": mesh["id"], "model": "kmeans", "k": 3}, headers=auth("alice")
        ).json()
        assert job["queue"] == "cpu"


def test_queue_limit_429(tmp_path, square):
    client, _ = make(tmp_path, max_queued_jobs_per_user=2)
    with client:
        mesh = upload(client, square)
        for k in (2, 3):
            assert (
                client.post(
                    "/v1/jobs", json={"mesh_id": mesh["id"], "k": k}, headers=auth("alice")
                ).status_code
                == 202
            )
        r = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 4}, headers=auth("alice"))
        assert r.status_code == 429 and "limit" in r.json()["detail"]
        upload(client, square, "bob")
        assert (
            client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 4}, headers=auth("bob")).status_code
            == 202
        )


def test_broker_down_is_503_and_nothing_dangles(tmp_path, square):
    from service_fixtures import free_port

    client, _ = make(tmp_path, broker_url=f"redis://127.0.0.1:{free_port()}/0")
    with client:
        mesh = upload(client, square)
        r = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 4}, headers=auth("alice"))
        assert r.status_code == 503 and "broker" in r.json()["detail"] and r.headers["retry-after"]
        # the client never got an id: the job is not recorded at all
        assert client.get("/v1/jobs", headers=auth("alice")).json()["total"] == 0
        ready = client.get("/readyz")
        assert ready.status_code == 503 and ready.json()["checks"]["broker"].startswith("unreachable")


def test_one_call_multipart_and_octave_form(app, square):
    client, settings = app
    r = client.post(
        "/v1/agglomerate",
        files={"file": ("square.vtu", square.read_bytes())},
        data={"model": "kmeans", "k": "4", "seed": "3"},
        headers=auth("alice"),
    )
    assert r.status_code == 202, r.text
    assert r.json()["params"]["model"] == "kmeans" and r.json()["params"]["options"]["seed"] == 3
    form = {
        "file_b64": base64.b64encode(square.read_bytes()).decode(),
        "filename": "square.vtu",
        "k": "5",
        "token": "bob-token",
    }
    r = client.post("/v1/agglomerate/form", data=form)
    assert r.status_code == 202, r.text
    assert client.get(f"/v1/jobs/{r.json()['id']}", headers=auth("bob")).status_code == 200
    # errors in the body, for Octave
    r = client.post("/v1/agglomerate/form", data={**form, "k": "100000"}, headers={"X-Magnet-Errors": "body"})
    assert r.status_code == 200 and r.json()["status"] == 422 and "k" in r.json()["detail"]
    r = client.get("/v1/jobs/unknown?errors=body", headers=auth("bob"))
    assert r.status_code == 200 and r.json()["status"] == 404
    r = client.post("/v1/agglomerate/form", data={**form, "token": "wrong"})
    assert r.status_code == 401
    r = client.post("/v1/agglomerate/form", data={**form, "file_b64": "%%%"})
    assert r.status_code == 422 and "base64" in r.json()["detail"]


def test_models_and_health(app):
    client, _ = app
    models = client.get("/v1/models").json()
    assert {"metis", "kmeans"} <= {m["name"] for m in models}
    assert all({"name", "dimension", "modes", "description"} <= set(m) for m in models)
    ready = client.get("/readyz")
    assert ready.status_code == 503 and ready.json()["checks"]["workers"] == "none online"
    assert client.get("/docs").status_code == 200 and client.get("/openapi.json").json()["paths"]


def test_serve_refuses_public_bind_without_keys(tmp_path):
    env = {"PATH": "/usr/bin:/bin", "MAGNET_DATA_DIR": str(tmp_path)}
    out = subprocess.run(
        [sys.executable, "-m", "service", "serve", "--host", "0.0.0.0", "--port", "1"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode != 0 and "without API keys" in out.stderr


def test_cli_entry_points_register_subcommands():
    import argparse

    from service.cli import register_serve
    from worker.cli import register_worker

    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command")
    register_serve(sub)
    register_worker(sub)
    args = parser.parse_args(["serve", "--port", "9000", "--no-worker"])
    assert args.port == 9000 and args.no_worker and callable(args.func)
    args = parser.parse_args(["worker", "-Q", "gpu,cpu", "-c", "1"])
    assert args.queues == "gpu,cpu" and callable(args.func)


def test_every_422_has_one_shape(app, square):
    """Rule errors of the library (k above the cells, unknown model, nref over 30) answer the same
    {detail, field, errors} as FastAPI's own request errors (issue 25)."""
    client, _ = app
    mesh = upload(client, square)
    cases = [
        ({"k": 10_000}, "k"),
        ({"model": "nope", "k": 2}, "model"),
        ({"mode": "nref", "nref": 31}, "nref"),
        ({"nref": 3, "k": 4}, "nref"),  # (two sizes: the later of k, nref, target_size, mult_factor named)
        ({"mode": "kway", "nref": 3}, "nref"),
        ({"k": "many"}, "k"),
    ]
    for params, field in cases:
        r = client.post("/v1/jobs", json={"mesh_id": mesh["id"], **params}, headers=auth("alice"))
        body = r.json()
        assert r.status_code == 422 and set(body) == {"detail", "field", "errors"}, (params, r.text)
        assert body["field"] == field and body["errors"] and body["errors"][0]["msg"], (params, r.text)
        assert "\n" not in body["detail"] and "{" not in body["detail"], body
    r = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "nref": 2}, headers=auth("alice"))
    assert r.status_code in (201, 202), r.text  # nref alone means mode nref
    r = client.post("/v1/meshes", content=square.read_bytes(), headers=auth("alice"))
    body = r.json()
    assert r.status_code == 422 and set(body) == {"detail", "field", "errors"} and body["field"] == "filename"
    assert "None" not in body["detail"] and "filename=" in body["detail"] and ".vtu" in body["detail"]


def test_worker_says_in_plain_words_what_it_takes(tmp_path, monkeypatch, capsys):
    """No Celery banner (`cpu exchange=cpu(direct) key=cpu`): one line of ours instead."""
    import worker.app
    from worker.cli import main as worker_main

    seen = {}

    class FakeApp:
        def worker_main(self, argv):
            seen["argv"] = argv

    monkeypatch.setattr(worker.app, "make_worker_app", lambda settings: FakeApp())
    monkeypatch.setenv("MAGNET_DATA_DIR", str(tmp_path))
    assert worker_main(["worker", "-Q", "gpu,cpu", "-n", "w1"]) == 0
    out = capsys.readouterr().out
    assert out.strip() == (
        "magnet worker w1: takes gpu: GPU jobs (the neural models, sage-*, rl-*), cpu: CPU jobs (every model); "
        "1 job(s) at a time"
    )
    assert seen["argv"][0] == "--quiet" and "worker" in seen["argv"]

"""Session 47's sweep of the HTTP API: multipart and form submissions refuse a range in the library's
words with its bound ("k must be >= 1, got 0", not "k must be >= , got '0'") and refuse fields the job
does not know (seeed=5 ran with the default seed); the same bytes under another extension are another
upload (the extension picks the reader); the per-user queue limit holds under parallel submission (60
of 70 were accepted against 50); values are echoed as JSON, sizes in MiB, and a file inside an archive
is refused after the archive's name, as the CLI says it."""

from __future__ import annotations

import base64
import re
import subprocess
import sys
import zipfile
from concurrent.futures import ThreadPoolExecutor

import pytest
from fastapi.testclient import TestClient
from service_fixtures import ROOT, app_on_store, square_mesh

from jobqueue.settings import Settings
from service.app import create_app

KEYS = "alice:alice-token"
AUTH = {"Authorization": "Bearer alice-token"}


@pytest.fixture(scope="module")
def square(tmp_path_factory):
    return square_mesh(tmp_path_factory.mktemp("mesh") / "square.vtu", n=8)


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(Settings(data_dir=tmp_path / "data", api_keys=KEYS))) as c:
        yield c


def upload(client, path, name=None):
    r = client.post(
        "/v1/meshes",
        params={"filename": name or path.name},
        content=path.read_bytes(),
        headers={"Content-Type": "application/octet-stream", **AUTH},
    )
    return r


def multipart(client, square, fields: dict):
    return client.post(
        "/v1/agglomerate", files={"file": ("square.vtu", square.read_bytes())}, data=fields, headers=AUTH
    )


def form(client, square, fields: dict):
    data = {"file_b64": base64.b64encode(square.read_bytes()).decode(), "filename": "square.vtu", **fields}
    return client.post("/v1/agglomerate/form", data=data, headers=AUTH)


# form fields -> the same job as JSON, and the sentence all three ways in give
RANGES = [
    ({"k": "0"}, {"k": 0}, "k must be >= 1, got 0"),
    ({"nref": "-1"}, {"nref": -1}, "nref must be >= 0, got -1"),
    ({"k": "4", "seed": "-1"}, {"k": 4, "options": {"seed": -1}}, "options.seed must be >= 0, got -1"),
    ({"target_size": "0"}, {"target_size": 0}, "target_size must be > 0.0, got 0.0"),
    ({"mult_factor": "2"}, {"mult_factor": 2}, "mult_factor must be <= 1.0, got 2.0"),
    (
        {"k": "4", "absorb_fraction": "5"},
        {"k": 4, "options": {"absorb_fraction": 5}},
        "options.absorb_fraction must be a number in [0, 1), got 5",
    ),
    (
        {"k": "4", "hierarchy": "true", "ratio": "1"},
        {"k": 4, "options": {"hierarchy": True, "ratio": 1}},
        "options.ratio must be >= 2 (coarsening ratio per level), got 1.0",
    ),
    (
        {"k": "4", "hierarchy": "true", "ratio": "4", "coarsest": "0"},
        {"k": 4, "options": {"hierarchy": True, "ratio": 4, "coarsest": 0}},
        "options.coarsest must be >= 1, got 0",
    ),
    (
        {"mode": "multilevel", "nref": "2", "threshold": "1"},
        {"mode": "multilevel", "nref": 2, "options": {"threshold": 1}},
        "options.threshold must be >= 2, got 1",
    ),
]


@pytest.mark.parametrize("fields, body, said", RANGES)
def test_form_ranges_are_refused_with_their_bound_as_json_is(client, square, fields, body, said):
    mesh_id = upload(client, square).json()["id"]
    r = client.post("/v1/jobs", json={"mesh_id": mesh_id, **body}, headers=AUTH)
    assert r.status_code == 422 and r.json()["detail"] == said, r.text
    for way in (multipart, form):
        r = way(client, square, fields)
        assert r.status_code == 422, r.text
        assert r.json()["detail"] == said, (way.__name__, r.text)
        assert r.json()["field"] == said.split(" ", 1)[0]
    assert client.get("/v1/jobs", headers=AUTH).json()["total"] == 0


def test_the_cli_says_the_same_range_refusal(square, tmp_path):
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "models.cli",
            "agglomerate",
            str(square),
            "-o",
            str(tmp_path / "x.vtu"),
            "--k",
            "0",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert out.returncode != 0 and "k must be >= 1, got 0" in out.stderr, out.stderr


def test_unknown_form_fields_are_refused_as_json_refuses_them(client, square):
    mesh_id = upload(client, square).json()["id"]
    said = client.post("/v1/jobs", json={"mesh_id": mesh_id, "k": 8, "seeed": 5}, headers=AUTH).json()
    assert said["detail"] == "unknown parameter(s): seeed" and said["field"] == "seeed"
    for way in (multipart, form):
        r = way(client, square, {"k": "8", "seeed": "5"})
        assert r.status_code == 422 and r.json()["detail"] == said["detail"], r.text
        assert r.json()["field"] == "seeed"
    # an option of the library given flat is an option: kappa=50 is refused as options.kappa
    r = multipart(client, square, {"k": "8", "kappa": "50"})
    assert r.status_code == 422 and r.json()["field"] == "options.kappa", r.text
    assert r.json()["detail"].endswith("got 50"), r.text
    r = multipart(
        client, square, {"model": "rtree", "nref": "2", "hierarchy": "true", "finest": "cuts", "kappa": "1,4"}
    )
    assert r.status_code == 202 and r.json()["params"]["options"]["kappa"] == [1.0, 4.0], r.text
    # malformed subset / options text is blamed on its own field, not on the file
    for fields, field in (
        ({"k": "2", "subset": "[1, 2"}, "subset"),
        ({"k": "2", "options": "{seed: 1"}, "options"),
        ({"k": "2", "options": "[1]"}, "options"),
    ):
        r = multipart(client, square, fields)
        assert r.status_code == 422 and r.json()["field"] == field, r.text
        assert r.json()["detail"].startswith(f"{field}: expected a JSON"), r.text
    assert client.get("/v1/jobs", headers=AUTH).json()["total"] == 1


def test_the_same_bytes_under_another_extension_are_another_upload(client, square):
    first = upload(client, square, "quads.vtu")
    assert first.status_code == 201 and first.json()["filename"] == "quads.vtu"
    for name in ("quads.stl", "quads.msh"):
        r = upload(client, square, name)
        assert r.status_code == 422, r.text  # as `magnet check` refuses it: the reader is the extension's
        assert r.json()["detail"].startswith(f"cannot read {name}"), r.text
    again = upload(client, square, "again.vtu")  # the same bytes, the same reader: the same mesh
    assert again.status_code == 201 and again.json()["id"] == first.json()["id"]
    assert again.json()["filename"] == "again.vtu"


@pytest.fixture(params=["sqlite", "postgresql"])
def limited(request, tmp_path):
    """The app with a queue limit of 5, on SQLite, then on a fresh PostgreSQL database (skipped when
    PostgreSQL is down)."""
    with app_on_store(tmp_path, request.param, api_keys=KEYS, max_queued_jobs_per_user=5) as client:
        yield client


def test_the_queue_limit_holds_under_parallel_submission(limited, square):
    client = limited
    mesh_id = upload(client, square).json()["id"]

    def submit(k):
        return client.post("/v1/jobs", json={"mesh_id": mesh_id, "model": "kmeans", "k": k}, headers=AUTH)

    with ThreadPoolExecutor(16) as pool:
        answers = list(pool.map(submit, range(2, 42)))
    codes = [r.status_code for r in answers]
    assert codes.count(202) == 5 and codes.count(429) == 35, codes
    assert client.get("/v1/jobs", headers=AUTH).json()["total"] == 5
    said = next(r.json()["detail"] for r in answers if r.status_code == 429)
    assert said == "you have 5 queued or running jobs; the limit is 5: wait for some to finish"


def test_values_are_echoed_as_json(client, square):
    mesh_id = upload(client, square).json()["id"]
    for params, said in (
        ({"k": True}, "k must be an integer, got true"),
        ({"k": "8"}, 'k must be an integer, got "8"'),
        ({"k": 4, "options": {"seed": "7"}}, 'options.seed must be an integer, got "7"'),
        ({"k": 4, "options": {"allow_extra": None, "hierarchy": "yes"}}, None),
        ({"k": 4, "model": "nope"}, "model must be one of"),
    ):
        r = client.post("/v1/jobs", json={"mesh_id": mesh_id, **params}, headers=AUTH)
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert not re.search(r"\bgot (True|False|None|')", detail), detail
        if said:
            assert detail.startswith(said), detail
    r = multipart(client, square, {"k": "abc"})
    assert r.status_code == 422 and r.json()["detail"] == 'k must be an integer, got "abc"', r.text


def test_sizes_in_mib_and_empty_files_in_the_clis_words(tmp_path, square):
    from models.errors import MeshError
    from models.mesh.sandbox import read_mesh_safe

    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS, max_upload_bytes=1 << 20)
    with TestClient(create_app(settings)) as client:
        big = tmp_path / "big.vtu"
        big.write_bytes(b"0" * (3 << 19))  # 1.5 MiB: past the file's limit, not the body's
        r = upload(client, big)
        assert r.status_code == 413 and r.json()["detail"] == "mesh file too large: the limit is 1 MiB", (
            r.text
        )
        big.write_bytes(b"0" * (3 << 20))  # 3 MiB: refused as the body comes
        r = upload(client, big)
        assert r.status_code == 413, r.text
        assert r.json()["detail"] == "request body too large: a mesh file may be at most 1 MiB", r.text
        empty = tmp_path / "empty.vtu"
        empty.write_bytes(b"")
        with pytest.raises(MeshError) as cli:
            read_mesh_safe(str(empty))
        r = upload(client, empty)
        assert (
            r.status_code == 422
            and r.json()["detail"] == f"{cli.value}; send the mesh file as the request body"
        )
        r = client.post("/v1/meshes", files={"file": ("empty.vtu", b"")}, headers=AUTH)
        assert r.json()["detail"] == f"{cli.value}; send the mesh file in multipart field 'file'", r.text


def test_a_bad_file_in_an_archive_is_said_after_the_archive_as_the_cli_says_it(client, tmp_path):
    archive = tmp_path / "case.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr("big.xdmf", b"\x00\x01 not XML at all")
    cli = subprocess.run(
        [
            sys.executable,
            "-m",
            "models.cli",
            "agglomerate",
            str(archive),
            "-o",
            str(tmp_path / "x.vtu"),
            "--k",
            "2",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    said = cli.stderr.strip().splitlines()[-1].removeprefix("magnet: error: ")
    assert said.startswith("cannot read case.zip: cannot read big.xdmf"), cli.stderr
    r = upload(client, archive)
    assert r.status_code == 422 and r.json()["detail"] == said, r.text

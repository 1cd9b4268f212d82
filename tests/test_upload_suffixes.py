"""Uploads whose format lives in more than one suffix (an outside HTTP sweep, session 43): a
big-endian UGRID file (`.b8.ugrid`: meshio reads the byte order off the name) was stored as
`<id>.ugrid` and every job failed; a `.tar.gz` was named `x.tar.tar.gz` in its refusals."""

from __future__ import annotations

import io
import tarfile

import meshio
import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_fixtures import upload_raw

from jobqueue.settings import Settings
from service.app import create_app
from worker.tasks import execute_job

KEYS = "alice:alice-token"
H = {"Authorization": "Bearer alice-token"}


def _upload(client, name: str, data: bytes):
    return upload_raw(client, name, data, "alice-token")


@pytest.mark.parametrize("suffix", ["b8.ugrid", "lb8.ugrid"])
def test_a_ugrid_file_keeps_its_byte_order_suffix(tmp_path, suffix):
    i, j = np.meshgrid(np.arange(7.0), np.arange(7.0), indexing="ij")
    p = np.c_[i.ravel(), j.ravel(), np.zeros(i.size)]
    a = (np.arange(6)[:, None] * 7 + np.arange(6)[None, :]).ravel()
    tri = np.concatenate([np.c_[a, a + 7, a + 8], np.c_[a, a + 8, a + 1]])
    path = tmp_path / f"plate.{suffix}"
    meshio.write(str(path), meshio.Mesh(p, [("triangle", tri)]))
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS)
    with TestClient(create_app(settings)) as client:
        r = _upload(client, path.name, path.read_bytes())
        assert r.status_code == 201, r.text
        r = client.post("/v1/jobs", json={"mesh_id": r.json()["id"], "model": "metis", "k": 5}, headers=H)
        assert r.status_code == 202, r.text
        assert execute_job(r.json()["id"], settings) == "succeeded"
        assert client.get(f"/v1/jobs/{r.json()['id']}", headers=H).json()["result"]["elements"] == 5


def test_a_tar_gz_refusal_names_the_file_as_sent(tmp_path):
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        link = tarfile.TarInfo("link.vtu")
        link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
        tar.addfile(link)
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS)
    with TestClient(create_app(settings)) as client:
        r = _upload(client, "sl.tar.gz", buf.getvalue())
    assert r.status_code == 422 and "sl.tar.gz" in r.text and "sl.tar.tar.gz" not in r.text, r.text


def test_an_empty_archive_is_said_empty_as_on_the_command_line(tmp_path):
    from models.mesh.check import check_file

    (tmp_path / "empty.zip").write_bytes(b"")
    cli = check_file(str(tmp_path / "empty.zip"))["issues"][0]["message"]
    assert cli == "cannot read empty.zip: the file is empty (0 bytes)"
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS)
    with TestClient(create_app(settings)) as client:
        r = _upload(client, "empty.zip", b"")
    assert r.status_code == 422 and cli in r.text and "as mesh" not in r.text, r.text


def test_an_unknown_extension_is_one_sentence_on_the_command_line_and_over_http(tmp_path):
    from models.mesh.check import check_file

    (tmp_path / "part.unv").write_text("   -1\n  2411\n")
    cli = check_file(str(tmp_path / "part.unv"))["issues"][0]["message"]
    assert cli.startswith("cannot read part.unv: unknown mesh format '.unv'; use one of: ")
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS)
    with TestClient(create_app(settings)) as client:
        r = _upload(client, "part.unv", b"   -1\n  2411\n")
    assert r.status_code == 422 and r.json()["detail"] == cli, r.text


def test_a_failed_job_names_the_file_as_uploaded(tmp_path):
    """A job's refusal that names the stored file (its content hash) names the upload's file."""
    from types import SimpleNamespace

    from worker.tasks import _as_uploaded

    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS)
    with TestClient(create_app(settings)) as client:
        i, j = np.meshgrid(np.arange(4.0), np.arange(4.0), indexing="ij")
        path = tmp_path / "plate.vtu"
        a = (np.arange(3)[:, None] * 4 + np.arange(3)[None, :]).ravel()
        meshio.write(
            str(path), meshio.Mesh(np.c_[i.ravel(), j.ravel()], [("quad", np.c_[a, a + 4, a + 5, a + 1])])
        )
        mesh = _upload(client, "my plate.vtu", path.read_bytes()).json()
        db = client.app.state.ctx.db
        stored = client.app.state.ctx.storage.mesh_path(mesh["id"], "vtu")
        job = SimpleNamespace(mesh_id=mesh["id"], user="alice")
        said = f"cannot read {stored.name} as VTK XML (VTU): it is corrupted"
        assert (
            _as_uploaded(db, job, stored, said)
            == "cannot read my plate.vtu as VTK XML (VTU): it is corrupted"
        )
        assert _as_uploaded(db, job, stored, "k = 9 is too many") == "k = 9 is too many"

"""What a new user hit on the Redis + PostgreSQL deployment, each fixed and checked here against the
real app (in-process, its SQLite job store and embedded broker; PostgreSQL when it runs; jobs run
with the worker's own execute_job)."""

from __future__ import annotations

import json

import meshio
import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_fixtures import app_on_store, square_mesh

from jobqueue.settings import Settings
from models.errors import MeshError
from models.mesh.read import read_mesh
from service.app import create_app
from worker.tasks import execute_job

KEYS = "alice:alice-token,bob:bob-token"


def auth(user: str) -> dict:
    return {"Authorization": f"Bearer {user}-token"}


def upload(client, path, user="alice", name=None):
    r = client.post(
        "/v1/meshes", params={"filename": name or path.name}, content=path.read_bytes(), headers=auth(user)
    )
    assert r.status_code == 201, r.text
    return r.json()


@pytest.fixture(scope="module")
def square(tmp_path_factory):
    return square_mesh(tmp_path_factory.mktemp("mesh") / "square.vtu", n=8)


@pytest.fixture
def app(tmp_path):
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS)
    with TestClient(create_app(settings)) as client:
        yield client, settings


def test_non_finite_numbers_are_422_naming_the_field(app, square):
    client, _ = app
    mesh = upload(client, square)["id"]
    cases = [
        ('{"mesh_id": "x", "target_size": NaN}', "target_size"),
        (f'{{"mesh_id": "{mesh}", "mode": "mult-factor", "mult_factor": Infinity}}', "mult_factor"),
        (f'{{"mesh_id": "{mesh}", "k": -Infinity}}', "k"),
        (
            f'{{"mesh_id": "{mesh}", "k": 2, "options": {{"absorb_fraction": NaN}}}}',
            "options.absorb_fraction",
        ),
        (f'{{"mesh_id": "{mesh}", "k": 2, "options": {{"seed": Infinity}}}}', "options.seed"),
        (f'{{"mesh_id": "{mesh}", "k": 2, "subset": [0, NaN]}}', "subset"),
    ]
    for body, field in cases:
        r = client.post(
            "/v1/jobs", content=body, headers={**auth("alice"), "Content-Type": "application/json"}
        )
        assert r.status_code == 422, (body, r.status_code, r.text)
        assert r.json()["field"] == field and field in r.json()["detail"], r.text
        assert r.json()["errors"][0]["loc"][0] == "body"
    form = {"file_b64": "AAAA", "filename": "sq.vtu", "k": "2", "token": "alice-token"}
    for name, value in (("target_size", "nan"), ("absorb_fraction", "inf"), ("mult_factor", "-Infinity")):
        r = client.post("/v1/agglomerate/form", data={**form, name: value})
        assert r.status_code == 422 and name in r.json()["detail"], r.text
    assert client.get("/v1/jobs", headers=auth("alice")).json()["total"] == 0


@pytest.fixture(params=["sqlite", "postgresql"])
def any_store(request, tmp_path):
    """The app on SQLite, then on a fresh PostgreSQL database (skipped when PostgreSQL is down)."""
    with app_on_store(tmp_path, request.param, api_keys=KEYS) as client:
        yield client


def test_nul_bytes_are_404_or_422_on_every_store(any_store, square):
    client = any_store
    mesh = upload(client, square)["id"]
    for path in ("/v1/jobs/ab%00cd", "/v1/meshes/ab%00cd", "/v1/jobs/ab%00cd/mesh", "/v1/jobs/ab%00cd/lymph"):
        assert client.get(path, headers=auth("alice")).status_code == 404, path
    assert client.delete("/v1/jobs/ab%00cd", headers=auth("alice")).status_code == 404
    r = client.post("/v1/jobs", json={"mesh_id": mesh[:10] + "\x00", "k": 2}, headers=auth("alice"))
    assert r.status_code == 404, r.text
    r = client.post(
        "/v1/meshes", params={"filename": "a\x00b.vtu"}, content=square.read_bytes(), headers=auth("alice")
    )
    assert r.status_code == 422 and "filename" in r.json()["detail"], r.text
    r = client.post(
        "/v1/agglomerate",
        files={"file": ("sq\x00.vtu", square.read_bytes())},
        data={"k": "2"},
        headers=auth("alice"),
    )
    assert r.status_code in (202, 422), r.text  # httpx may encode the NUL in the part header
    accepted = int(r.status_code == 202)
    r = client.post(
        "/v1/jobs",
        json={"mesh_id": mesh, "k": 2, "options": {"physical_tag": "a\x00b"}},
        headers=auth("alice"),
    )
    assert r.status_code == 422 and r.json()["field"] == "options.physical_tag", r.text
    assert client.get("/v1/jobs", headers=auth("alice")).json()["total"] == accepted


def test_physical_tag_of_the_job_is_checked_at_submission(app, tmp_path):
    client, settings = app
    base = meshio.read(square_mesh(tmp_path / "plain.vtu", n=8))
    tri = base.cells[0].data
    groups = (base.points[tri].mean(axis=1)[:, 0] > 0.5).astype(np.int32)  # left / right halves
    path = tmp_path / "phys.vtu"
    meshio.write(str(path), meshio.Mesh(base.points, [("triangle", tri)], cell_data={"phys": [groups]}))
    mesh = upload(client, path)
    assert mesh["physical_groups"] == []  # no array of a default name
    seg = {"mesh_id": mesh["id"], "model": "metis", "mode": "segregated", "mult_factor": 0.5}
    r = client.post("/v1/jobs", json=seg, headers=auth("alice"))
    assert r.status_code == 422 and "physical groups" in r.json()["detail"]
    r = client.post("/v1/jobs", json={**seg, "options": {"physical_tag": "nope"}}, headers=auth("alice"))
    assert r.status_code == 422 and r.json()["field"] == "options.physical_tag", r.text
    assert "phys" in r.json()["detail"]  # the message lists what the mesh has
    r = client.post("/v1/jobs", json={**seg, "options": {"physical_tag": "phys"}}, headers=auth("alice"))
    assert r.status_code == 202, r.text
    assert execute_job(r.json()["id"], settings) == "succeeded"
    assert client.get(f"/v1/jobs/{r.json()['id']}", headers=auth("alice")).json()["status"] == "succeeded"
    # the groups under that tag are kept with the mesh: the second submission reads nothing
    r = client.post(
        "/v1/jobs",
        json={**seg, "mult_factor": 0.4, "options": {"physical_tag": "phys"}},
        headers=auth("alice"),
    )
    assert r.status_code == 202, r.text


def test_dedup_across_users_does_not_say_cached(app, square):
    client, settings = app
    mesh = upload(client, square, "alice")
    upload(client, square, "bob")
    job = {"mesh_id": mesh["id"], "model": "metis", "k": 5}
    first = client.post("/v1/jobs", json=job, headers=auth("alice")).json()
    assert execute_job(first["id"], settings) == "succeeded"
    elements = client.get(f"/v1/jobs/{first['id']}", headers=auth("alice")).json()["result"]["elements"]
    # alice's result exists: bob's job is queued like any other, and the worker reuses the result
    other = client.post("/v1/jobs", json=job, headers=auth("bob")).json()
    assert other["status"] == "queued" and other["cached"] is False
    assert execute_job(other["id"], settings) == "reused"
    done = client.get(f"/v1/jobs/{other['id']}", headers=auth("bob")).json()
    assert (
        done["status"] == "succeeded" and done["cached"] is False and done["result"]["elements"] == elements
    )
    # alice's own repeat is still answered at once, and says so
    mine = client.post("/v1/jobs", json=job, headers=auth("alice")).json()
    assert mine["status"] == "succeeded" and mine["cached"] is True
    # an identical job of alice in flight: bob's follows it (computed once), silently
    job6 = {**job, "k": 6}
    leader = client.post("/v1/jobs", json=job6, headers=auth("alice")).json()
    follower = client.post("/v1/jobs", json=job6, headers=auth("bob")).json()
    assert follower["status"] == "queued" and follower["cached"] is False
    assert execute_job(leader["id"], settings) == "succeeded"
    done = client.get(f"/v1/jobs/{follower['id']}", headers=auth("bob")).json()
    assert done["status"] == "succeeded" and done["cached"] is False
    assert execute_job(follower["id"], settings) == "skipped"  # nothing left to compute


VTU = """<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">
<UnstructuredGrid><Piece NumberOfPoints="3" NumberOfCells="{n}">
<Points><DataArray type="Float64" NumberOfComponents="3" format="ascii">0 0 0 1 0 0 0 1 0</DataArray></Points>
<Cells><DataArray type="Int64" Name="connectivity" format="ascii">{conn}</DataArray>
<DataArray type="Int64" Name="offsets" format="ascii">{off}</DataArray>
<DataArray type="UInt8" Name="types" format="ascii">{types}</DataArray></Cells>
</Piece></UnstructuredGrid></VTKFile>
"""


def test_mesh_errors_name_the_problem(app, tmp_path):
    client, _ = app
    cases = [
        ("zero.vtu", VTU.format(n=0, conn="", off="", types=""), "no cells"),
        ("neg.vtu", VTU.format(n=-5, conn="0 1 2", off="3", types="5"), "NumberOfCells=-5"),
        ("mesh.zzz", "whatever", ".vtu, .vtk, .msh"),
    ]
    for name, text, says in cases:
        r = client.post("/v1/meshes", params={"filename": name}, content=text.encode(), headers=auth("alice"))
        assert r.status_code == 422 and says in r.json()["detail"], (name, r.text)
        assert "NoneType" not in r.json()["detail"]
    r = client.post("/v1/meshes", params={"filename": "mesh.zzz"}, content=b"x", headers=auth("alice"))
    # the readers' list (models.mesh.formats), a parallel file only in an archive with its pieces
    assert ".med" in r.json()["detail"] and ".pvtu," not in r.json()["detail"]
    # the library (magnet agglomerate) lists the formats it supports, not all of meshio's
    bad = tmp_path / "mesh.qqq"
    bad.write_text("x")
    with pytest.raises(MeshError) as err:
        read_mesh(bad)
    assert (
        ".vtu" in str(err.value) and ".exo" in str(err.value) and "qqq" in str(err.value)
    )  # Exodus II: VTK's reader
    assert ".hmf" not in str(err.value)  # meshio reads it; we do not offer it


def test_lower_dimensional_cells_are_reported(app, tmp_path):
    client, _ = app
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    tris = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3]])
    lines = np.array([[0, 1]])
    path = tmp_path / "mixed.vtu"
    meshio.write(str(path), meshio.Mesh(pts, [("tetra", tets), ("triangle", tris), ("line", lines)]))
    mesh = upload(client, path)
    assert mesh["cells"] == 2 and mesh["dim"] == 3
    assert mesh["lower_dim_cells"] == {"triangle": 3, "line": 1}


def test_openapi_says_what_the_api_does(app):
    client, _ = app
    doc = client.get("/openapi.json").json()
    assert doc["components"]["securitySchemes"]["APIKey"] == {
        "type": "http",
        "scheme": "bearer",
        "description": doc["components"]["securitySchemes"]["APIKey"]["description"],
    }
    ops = {(m.upper(), p): op for p, item in doc["paths"].items() for m, op in item.items()}
    for (method, path), op in ops.items():
        if path.startswith("/v1/") and path != "/v1/models":
            assert op.get("security") == [{"APIKey": []}], (method, path)
        for param in op.get("parameters", []):
            assert param.get("description"), (method, path, param["name"])
        if "422" in op["responses"]:
            ref = op["responses"]["422"]["content"]["application/json"]["schema"]["$ref"]
            assert ref.endswith("/ValidationErrorOut"), (method, path)
    assert "HTTPValidationError" not in doc["components"]["schemas"]
    # impossible codes are not listed: a plain GET by id cannot be 413, 422, 429 or 503
    assert set(ops[("GET", "/v1/jobs/{job_id}")]["responses"]) == {"200", "401", "404"}
    assert set(ops[("GET", "/v1/meshes/{mesh_id}")]["responses"]) == {"200", "401", "404"}
    assert "409" not in ops[("POST", "/v1/jobs")]["responses"]
    media = {
        "/v1/jobs/{job_id}/mesh": "application/octet-stream",
        "/v1/jobs/{job_id}/metrics": "application/json",
        "/v1/jobs/{job_id}/labels": "application/json",
        "/v1/jobs/{job_id}/preview.png": "image/png",
    }
    for path, kind in media.items():
        assert list(ops[("GET", path)]["responses"]["200"]["content"]) == [kind], path
    assert set(ops[("GET", "/v1/jobs/{job_id}/lymph")]["responses"]["200"]["content"]) == {
        "application/json",
        "application/x-matlab-data",
    }
    # and the 422 body really has that shape
    r = client.get("/v1/jobs?limit=0", headers=auth("alice"))
    assert r.status_code == 422 and set(r.json()) == {"detail", "field", "errors"}
    assert r.json()["field"] == "limit" and json.dumps(r.json())


def _create_schema_in_a_new_process(url: str) -> None:
    from jobqueue.db import Database

    Database(url).create_schema()


def test_processes_meeting_a_fresh_store_all_create_its_schema(tmp_path):
    """API, worker, its pool children and the reaper may open a new SQLite store at the same moment:
    none of them may fail with 'table ... already exists' (seen killing a worker's first task)."""
    import multiprocessing as mp

    from sqlalchemy import inspect

    from jobqueue.db import Base, Database

    for round_ in range(3):
        url = f"sqlite:///{tmp_path / f'jobs{round_}.sqlite'}"
        ctx = mp.get_context("fork")
        procs = [ctx.Process(target=_create_schema_in_a_new_process, args=(url,)) for _ in range(6)]
        for p in procs:
            p.start()
        for p in procs:
            p.join(60)
        assert [p.exitcode for p in procs] == [0] * 6
        assert set(inspect(Database(url).engine).get_table_names()) >= set(Base.metadata.tables)


def test_files_that_name_other_files_are_asked_for_in_an_archive(app):
    """A file whose mesh lies in other files beside it (a parallel file's pieces, an OpenFOAM or
    EnSight case's files) uploaded alone: 422, asking for a .zip or .tar.gz of them all. (An XDMF may
    hold its data inline: it is read alone, and its missing .h5 named: test_read_fuzz.)"""
    client, _ = app
    for name in ("mesh.pvtu", "case.foam", "flow.case", "flow.encas", "u.pvd"):
        r = client.post("/v1/meshes", params={"filename": name}, content=b"x", headers=auth("alice"))
        assert r.status_code == 422 and "upload a .zip or .tar.gz" in r.json()["detail"], (name, r.text)


def test_a_parallel_file_and_its_pieces_in_one_archive_are_one_mesh(app, tmp_path):
    """A .pvtu (or .pvtk) with its pieces, zipped as asked: the file naming the pieces is the mesh,
    not "the archive holds 4 mesh files" (the pieces are meshes too); a .pvd naming .pvtu files:
    the .pvd."""
    import os
    import zipfile

    import vtk
    import vtk_corpus as vc
    from vtkmodules.vtkFiltersParallel import vtkExtractUnstructuredGridPiece

    client, _ = app
    p, h = vc.grid(4, 3, 2)
    cut = vtkExtractUnstructuredGridPiece()
    cut.SetInputData(vc.unstructured(p, [(12, h)]))
    folder = tmp_path / "pieces"
    folder.mkdir()
    vc.write_pieces(folder / "cut.pvtu", vtk.vtkXMLPUnstructuredGridWriter(), cut, 3)
    (folder / "series.pvd").write_text(
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n<Collection>\n'
        '<DataSet timestep="0" part="0" file="cut.pvtu"/>\n</Collection>\n</VTKFile>\n'
    )
    for members, name in (
        (["cut.pvtu", "cut_0.vtu", "cut_1.vtu", "cut_2.vtu"], "pvtu.zip"),
        (None, "pvd.zip"),
    ):
        with zipfile.ZipFile(tmp_path / name, "w") as zf:
            for f in members or sorted(os.listdir(folder)):
                zf.write(folder / f, f)
        mesh = upload(client, tmp_path / name)
        assert mesh["cells"] == len(h), mesh

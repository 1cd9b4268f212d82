"""`magnet check`: the report, its verdict, and where else it appears (metrics JSON, POST /v1/meshes)."""

from __future__ import annotations

import json
import os

import pytest
from conftest import BRAIN, EMILIA
from defects import write_folded_brain
from test_cli import magnet

from models.mesh.check import check_file


def test_brain_report():
    rep = check_file(BRAIN)
    assert rep["verdict"] == "ok"
    assert rep["dim"] == 2 and rep["cells"] == 14372 and rep["cell_types"] == {"triangle": 14372}
    assert rep["components"] == 1 and rep["boundary_loops"] == 1 and rep["holes"] == 0
    assert rep["orientation"] == {"flipped": 7158, "folded": 0}  # the file mixes both orientations
    assert rep["unused_points"] == 30252 - 7440
    assert rep["duplicate_points"] == 0 and rep["hanging_nodes"] == 0


def test_emilia_report_groups():
    rep = check_file(EMILIA)
    assert rep["physical_groups"] == [1, 2, 3, 4, 5, 6, 7] and rep["verdict"] == "ok"
    assert rep["cell_types"] == {"polygon": 1610, "quad": 3260}


def test_cli_check_text_json_and_exit_codes(tmp_path):
    fb = tmp_path / "folded.vtu"
    cell = write_folded_brain(str(fb))
    r = magnet("check", fb)
    assert r.returncode == 0, r.stderr
    assert (
        "1 folded" in r.stdout
        and f"(ids {cell})" in r.stdout
        and r.stdout.strip().endswith("verdict: warnings")
    )
    r = magnet("check", fb, "--json")
    rep = json.loads(r.stdout)
    assert (
        rep["verdict"] == "warnings"
        and rep["issues"][0]["kind"] == "folded"
        and rep["issues"][0]["ids"] == [cell]
    )
    bad = tmp_path / "deg.vtk"
    bad.write_text(
        "# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 double\n0 0 0\n1 0 0\n"
        "2 0 0\n0 1 0\nCELLS 2 8\n3 0 1 2\n3 0 1 3\nCELL_TYPES 2\n5\n5\n"
    )
    r = magnet("check", bad)
    assert r.returncode == 2 and "degenerate" in r.stdout and "verdict: error" in r.stdout
    assert "Traceback" not in r.stderr


def test_agglomerate_metrics_carry_the_mesh_report(tmp_path):
    fb = tmp_path / "folded.vtu"
    cell = write_folded_brain(str(fb))
    r = magnet("agglomerate", fb, "-o", tmp_path / "o.vtu", "--k", 16, "--metrics", tmp_path / "m.json")
    assert r.returncode == 0, r.stderr
    rep = json.load(open(tmp_path / "m.json"))["mesh_report"]
    assert rep["verdict"] == "warnings" and rep["orientation"]["folded"] == 1
    assert rep["issues"][0]["ids"] == [cell]


def test_upload_returns_the_check(tmp_path):
    pytest.importorskip("fastapi")
    from test_service_api import auth, make

    fb = tmp_path / "folded.vtu"
    cell = write_folded_brain(str(fb))
    client, _ = make(tmp_path)
    with client:
        r = client.post(
            "/v1/meshes",
            params={"filename": "folded.vtu"},
            content=fb.read_bytes(),
            headers={"Content-Type": "application/octet-stream", **auth("alice")},
        )
        assert r.status_code == 201, r.text
        check = r.json()["check"]
        assert check["verdict"] == "warnings" and check["orientation"]["folded"] == 1
        assert check["issues"][0]["ids"] == [cell]
        again = client.get(f"/v1/meshes/{r.json()['id']}", headers=auth("alice")).json()
        assert again["check"] == check


def test_every_defect_upload_is_201_or_422(tmp_path):
    pytest.importorskip("fastapi")
    from test_defects import AREA, REFUSED, path
    from test_service_api import auth, make

    client, _ = make(tmp_path)
    with client:
        for name in sorted(AREA) + sorted(REFUSED):
            p = path(name)
            r = client.post(
                "/v1/meshes",
                params={"filename": os.path.basename(p)},
                content=open(p, "rb").read(),
                headers={"Content-Type": "application/octet-stream", **auth("alice")},
            )
            if name in REFUSED:
                assert r.status_code == 422 and REFUSED[name][0] in r.text, (name, r.text)
            else:
                assert r.status_code == 201, (name, r.text)
                assert r.json()["check"]["verdict"] in ("ok", "warnings")


def test_3d_cavity_and_2d_hole_are_counted():
    import numpy as np
    from meshes import hexes, quads

    from models.mesh.check import mesh_report
    from models.mesh.read import mesh_from_arrays

    p, h = hexes(3)
    inner = np.all(np.abs(p[h].mean(axis=1) - 0.5) < 0.2, axis=1)  # the middle hexahedron removed
    rep = mesh_report(mesh_from_arrays(p, [("hexahedron", h[~inner])]))
    assert (
        rep["components"] == 1
        and rep["boundary_shells"] == 2
        and rep["holes"] == 1
        and rep["boundary_facets"] == 60
    )
    p, q = quads(3)
    inner = np.all(np.abs(p[q].mean(axis=1) - 0.5) < 0.2, axis=1)
    rep = mesh_report(mesh_from_arrays(p, [("quad", q[~inner])]))
    assert rep["boundary_loops"] == 2 and rep["holes"] == 1 and rep["verdict"] == "ok"

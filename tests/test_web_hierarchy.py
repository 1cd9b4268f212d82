"""Hierarchies on the web page: the JSON the page draws them from (in-process, the worker's
execute_job), and the page itself in Debian's chromium (Playwright, a real server with its
embedded worker): submit a hierarchy, follow it, see every level one over the other."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
from service_fixtures import square_mesh
from test_web_api import ALICE, BOB, app, finished_job  # noqa: F401 (app: a fixture)


def test_hierarchy_levels_json(app, tmp_path):  # noqa: F811
    client, settings = app
    square = square_mesh(tmp_path / "square.vtu", 12)
    job = finished_job(
        client,
        settings,
        square,
        model="rtree",
        mode="kway",
        k=72,
        options={"hierarchy": True, "ratio": 4, "coarsest": 4},
    )
    zf = zipfile.ZipFile(io.BytesIO(client.get(f"/v1/jobs/{job['id']}/hierarchy", headers=ALICE).content))
    index = json.loads(zf.read("hierarchy.json"))
    r = client.get(f"/v1/jobs/{job['id']}/hierarchy/levels", headers=ALICE)
    assert r.status_code == 200, r.text
    levels = r.json()
    assert levels["model"] == "rtree" and levels["ratio"] == 4 and levels["dim"] == 2 and levels["nested"]
    assert [lv["elements"] for lv in levels["levels"]] == [lv["elements"] for lv in index["levels"]]
    # the finest level is the job's agglomeration (k = 72), the coarser ones agglomerate it: 72, 18, 5, 2
    assert len(levels["levels"]) >= 3 and levels["levels"][-1]["elements"] == 72 == job["result"]["elements"]
    for lv in levels["levels"]:
        assert "circle_ratio" in lv["summary"] and lv["coverage"] >= 1.0

    fine_labels = [np.asarray(json.loads(zf.read(lv["labels"]))) for lv in index["levels"]]
    for L, lv in enumerate(index["levels"]):
        r = client.get(f"/v1/jobs/{job['id']}/hierarchy/levels/{L}", headers=ALICE)
        assert r.status_code == 200, r.text
        poly = r.json()
        n = lv["elements"]
        assert poly["level"] == L and len(poly["offsets"]) == n + 1
        # the polygons are in label order: element e holds exactly the fine cells labelled e
        assert poly["cell_data"]["n_fine_cells"] == np.bincount(fine_labels[L], minlength=n).tolist()
        root = np.asarray(poly["root"])
        assert np.array_equal(root[fine_labels[L]], fine_labels[0])
        if L == 0:
            assert "parent" not in poly and root.tolist() == list(range(n))
        else:
            assert np.array_equal(np.asarray(poly["parent"])[fine_labels[L]], fine_labels[L - 1])
    assert (
        client.get(f"/v1/jobs/{job['id']}/hierarchy/levels/{len(index['levels'])}", headers=ALICE).status_code
        == 404
    )
    assert client.get(f"/v1/jobs/{job['id']}/hierarchy/levels", headers=BOB).status_code == 404

    # the fine mesh under the levels: the upload's own cells
    fine = client.get(f"/v1/meshes/{job['mesh_id']}/polygons", headers=ALICE)
    assert fine.status_code == 200, fine.text
    fine = fine.json()
    assert len(fine["offsets"]) == 288 + 1 and len(fine["connectivity"]) == 3 * 288
    assert len(fine["points"]) == 13 * 13 and max(max(p) for p in fine["points"]) == 1.0
    assert client.get(f"/v1/meshes/{job['mesh_id']}/polygons", headers=BOB).status_code == 404

    # a job without the option: 404 that says how to get one
    plain = finished_job(client, settings, square, model="metis", mode="kway", k=4)
    r = client.get(f"/v1/jobs/{plain['id']}/hierarchy/levels", headers=ALICE)
    assert r.status_code == 404 and "options.hierarchy" in r.text
    # the levels a recursive mode records (no ratio): the same JSON
    rec = finished_job(
        client, settings, square, model="metis", mode="nref", nref=3, options={"hierarchy": True}
    )
    levels = client.get(f"/v1/jobs/{rec['id']}/hierarchy/levels", headers=ALICE).json()
    assert [lv["elements"] for lv in levels["levels"]] == [1, 2, 4, 8] and levels["nested"]
    poly = client.get(f"/v1/jobs/{rec['id']}/hierarchy/levels/3", headers=ALICE).json()
    assert len(poly["offsets"]) == 9 and sorted(set(poly["parent"])) == [0, 1, 2, 3]


def test_hierarchy_level_pictures_of_a_3d_job(app, tmp_path):  # noqa: F811
    import meshio
    from meshes import tets

    client, settings = app
    points, cells = tets(6)[:2]
    path = tmp_path / "cube.vtu"
    meshio.write(path, meshio.Mesh(points, [("tetra", cells)]))
    job = finished_job(
        client,
        settings,
        path,
        model="rtree",
        mode="kway",
        k=8,
        options={"hierarchy": True, "ratio": 8, "coarsest": 4},
    )
    levels = client.get(f"/v1/jobs/{job['id']}/hierarchy/levels", headers=ALICE).json()
    assert levels["dim"] == 3 and len(levels["levels"]) >= 2
    # 3D levels are not polygons: a picture each (the exploded view, as a 3D job's preview.png)
    assert client.get(f"/v1/jobs/{job['id']}/hierarchy/levels/0", headers=ALICE).status_code == 404
    n = len(levels["levels"])
    first = None
    for L in range(n - 1):  # every level but the finest: drawn now
        r = client.get(f"/v1/jobs/{job['id']}/hierarchy/levels/{L}/preview.png", headers=ALICE)
        assert r.status_code == 200, r.text
        assert r.headers["content-type"] == "image/png" and r.content[:8] == b"\x89PNG\r\n\x1a\n"
        first = first or r.content
    (tmp_path / "level0.png").write_bytes(first)
    again = client.get(f"/v1/jobs/{job['id']}/hierarchy/levels/0/preview.png", headers=ALICE)
    assert again.content == first  # drawn once, then kept with the results
    bad = client.get(f"/v1/jobs/{job['id']}/hierarchy/levels/{n}/preview.png", headers=ALICE)
    assert bad.status_code == 404
    assert client.get(f"/v1/jobs/{job['id']}/hierarchy/levels/0/preview.png", headers=BOB).status_code == 404
    assert client.get(f"/v1/meshes/{job['mesh_id']}/polygons", headers=ALICE).status_code == 404  # 3D
    # the upload deleted: the pictures drawn stay, a level not drawn yet cannot be (404 that says why)
    assert client.delete(f"/v1/meshes/{job['mesh_id']}", headers=ALICE).status_code == 204
    assert client.get(f"/v1/jobs/{job['id']}/hierarchy/levels/0/preview.png", headers=ALICE).content == first
    r = client.get(f"/v1/jobs/{job['id']}/hierarchy/levels/{n - 1}/preview.png", headers=ALICE)
    assert r.status_code == 404 and "deleted" in r.text

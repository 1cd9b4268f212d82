"""Boundary groups through the service: an uploaded gmsh mesh keeps its physical curves, the upload
summary lists them (tags and names), and the job's lymph structs carry them as bc_tag; the same from
the Matlab/Octave wrapper (job.mesh.boundary.groups maps names to tags). A live embedded server."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from service_fixtures import ROOT, service_env, start_api, wait_until, workers_online

TOKEN = "boundary-key"
SQUARE = ROOT / "tests" / "data" / "square_sides.msh"
SIDES = {2: (1, 0.0), 3: (0, 1.0), 4: (1, 1.0), 5: (0, 0.0)}

sys.path.insert(0, str(ROOT / "client"))
from magnet_client import Client  # noqa: E402


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("boundary-server")
    env = service_env(tmp / "data", api_keys=f"tester:{TOKEN}")
    proc, url = start_api(env, tmp, embedded_worker=True)
    try:
        wait_until(lambda: workers_online(url, TOKEN) >= 1, 60, 0.2, "the embedded worker")
        yield url
    finally:
        proc.stop()


def sides_of(region: dict) -> np.ndarray:
    coord = np.asarray(region["coord"], dtype=float)
    bc = np.asarray(region["connectivity_bc"]) - 1
    mid = 0.5 * (coord[bc[:, 0]] + coord[bc[:, 1]])
    out = np.full(len(mid), -1)
    for t, (axis, v) in SIDES.items():
        out[np.abs(mid[:, axis] - v) < 1e-12] = t
    return out


def test_upload_summary_and_job_lymph_carry_the_groups(server, tmp_path):
    c = Client(server, token=TOKEN)
    mesh = c.upload(SQUARE)
    assert mesh["boundary_groups"] == [2, 3, 4, 5]
    groups = mesh["boundary"]["groups"]
    assert {g["name"]: g["tag"] for g in groups} == {"bottom": 2, "right": 3, "top": 4, "left": 5}
    assert all(g["on_boundary"] == 13 and g["interior"] == 0 for g in groups)
    assert mesh["boundary"]["untagged_boundary_facets"] == 0
    job = c.agglomerate(
        SQUARE,
        tmp_path / "o.vtu",
        metrics=str(tmp_path / "m.json"),
        progress=False,
        model="metis",
        mode="kway",
        k=8,
        boundary_tag=9,
    )
    region = c.download_lymph(job["id"])["region"]
    assert region["bc_tag"] == sides_of(region).tolist() and 9 not in region["bc_tag"]
    rep = json.loads((tmp_path / "m.json").read_text())["boundary"]
    assert {k: v["measure_after"] for k, v in rep["groups"].items()} == pytest.approx(
        {str(t): 1.0 for t in SIDES}, rel=1e-12
    )
    assert job["params"]["options"]["boundary_tag"] == 9


OCTAVE = r"""
addpath('{matlab}');
[region, neighbor, job] = magnet_agglomerate('{mesh}', 'Server', '{url}', 'Token', '{token}', 'K', 8, ...
    'Verbose', false, 'Poll', 0.3);
g = job.mesh.boundary.groups;
names = {{g.name}};
out = struct('names', {{names}}, 'tags', [g.tag], 'bc', unique(region.bc_tag), 'nbc', numel(region.bc_tag));
fid = fopen('{result}', 'w'); fprintf(fid, '%s', jsonencode(out)); fclose(fid);
"""


@pytest.mark.octave
@pytest.mark.slow
def test_octave_wrapper_names_map_to_tags(server, tmp_path):
    octave = shutil.which("octave-cli")
    if octave is None:
        pytest.skip(
            "octave-cli not found: install GNU Octave (apt-get install -y --no-install-recommends octave)"
        )
    result = tmp_path / "r.json"
    script = tmp_path / "run.m"
    script.write_text(
        OCTAVE.format(matlab=ROOT / "client" / "matlab", mesh=SQUARE, url=server, token=TOKEN, result=result)
    )
    out = subprocess.run(
        [octave, "--no-gui", "--quiet", "--no-window-system", str(script)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.exists(), f"octave failed:\n{out.stdout}\n{out.stderr}"
    r = json.loads(result.read_text())
    assert dict(zip(r["names"], r["tags"], strict=True)) == {"bottom": 2, "right": 3, "top": 4, "left": 5}
    assert r["bc"] == [2, 3, 4, 5] and r["nbc"] == 52

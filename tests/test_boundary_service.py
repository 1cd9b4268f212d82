"""Boundary groups through the service: an uploaded gmsh mesh keeps its physical curves, the upload
summary lists them (tags and names), and the job's lymph structs carry them as bc_tag; the same from
the Matlab/Octave wrapper (job.mesh.boundary.groups maps names to tags). A live embedded server."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from service_fixtures import ROOT, embedded_server, run_octave

TOKEN = "boundary-key"
SQUARE = ROOT / "tests" / "data" / "square_sides.msh"
SIDES = {2: (1, 0.0), 3: (0, 1.0), 4: (1, 1.0), 5: (0, 0.0)}

sys.path.insert(0, str(ROOT / "client"))
from magnet_client import Client  # noqa: E402


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with embedded_server(tmp_path_factory.mktemp("boundary-server"), TOKEN) as url:
        yield url


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
    result = tmp_path / "r.json"
    text = OCTAVE.format(
        matlab=ROOT / "client" / "matlab", mesh=SQUARE, url=server, token=TOKEN, result=result
    )
    r = run_octave(tmp_path / "run.m", text, result)
    assert dict(zip(r["names"], r["tags"], strict=True)) == {"bottom": 2, "right": 3, "top": 4, "left": 5}
    assert r["bc"] == [2, 3, 4, 5] and r["nbc"] == 52

"""lymph boundary conditions from our .mat, in GNU Octave: the .mat that `magnet agglomerate --lymph`
writes for gmsh meshes with physical curves is loaded in octave-cli, and every boundary edge of every
element (neigh < 0) is marked the way lymph's MakeNeighborBoundary marks it (its bc_tag, found by the
edge's two vertices in connectivity_bc, mapped through Data.TagBc / Data.LabBc to -1 Dirichlet /
-2 Neumann). Our own Octave code, not lymph's. Counts per tag and per mark must match the mesh."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from service_fixtures import run_octave

pytestmark = [pytest.mark.octave]
ROOT = Path(__file__).parent.parent
DATA = ROOT / "tests" / "data"

SCRIPT = r"""
s = load('{mat}');
region = s.region; neighbor = s.neighbor;
TagBc = [2 3 4 5]; LabBc = 'DNDD';          % Data.TagBc = {{[2 3 4 5]}}; Data.LabBc = {{'DNDD'}}
bc = region.connectivity_bc;
nv = size(region.coord, 1);
bkey = min(bc, [], 2) * (nv + 1) + max(bc, [], 2);
tags = []; marks = []; unknown = 0; missing = 0; len = zeros(1, 6);
for i = 1:region.ne
  c = region.connectivity{{i}};
  n = numel(c);
  for j = 1:n
    if neighbor.neigh{{i}}(j) >= 0
      continue
    end
    a = c(j); b = c(mod(j, n) + 1);
    k = find(bkey == min(a, b) * (nv + 1) + max(a, b));
    if numel(k) ~= 1
      missing = missing + 1;
      continue
    end
    t = region.bc_tag(k);
    hit = find(TagBc == t);
    if isempty(hit)
      unknown = unknown + 1;
      continue
    end
    mark = -1 - (LabBc(hit) == 'N');
    neighbor.neigh{{i}}(j) = mark;
    tags(end + 1) = t; marks(end + 1) = mark;
    len(t) = len(t) + norm(region.coord(a, :) - region.coord(b, :));
  end
end
counts = arrayfun(@(t) sum(tags == t), TagBc);
ids = arrayfun(@(t) sum(region.id == t), [1 2]);
out = struct('counts', counts, 'dirichlet', sum(marks == -1), 'neumann', sum(marks == -2), ...
  'unknown', unknown, 'missing', missing, 'nbc', size(bc, 1), 'len', len(TagBc), 'ids', ids, 'ne', region.ne);
fid = fopen('{result}', 'w'); fprintf(fid, '%s', jsonencode(out)); fclose(fid);
"""


def marks_in_octave(tmp_path: Path, mat: Path) -> dict:
    result = tmp_path / "result.json"
    return run_octave(tmp_path / "marks.m", SCRIPT.format(mat=mat, result=result), result)


@pytest.mark.parametrize(
    ("mesh", "mode", "sides", "ids"),
    [
        ("square_sides.msh", ["--k", "16"], 13, None),
        ("square_inclusion.msh", ["--mode", "segregated", "--mult-factor", "0.3"], 15, True),
    ],
)
def test_octave_marks_boundary_edges_per_tag(tmp_path, mesh, mode, sides, ids):
    mat = tmp_path / "out.mat"
    cmd = [
        sys.executable,
        "-m",
        "models.cli",
        "agglomerate",
        str(DATA / mesh),
        "-o",
        str(tmp_path / "out.vtu"),
        "--lymph",
        str(mat),
        "--labels",
        str(tmp_path / "labels.json"),
        *mode,
    ]
    run = subprocess.run(
        cmd,
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "MPLBACKEND": "Agg"},
    )
    assert run.returncode == 0, run.stderr
    r = marks_in_octave(tmp_path, mat)
    assert r["missing"] == 0 and r["unknown"] == 0
    assert r["counts"] == [sides] * 4 and r["nbc"] == 4 * sides  # every fine boundary edge, on its side
    assert r["dirichlet"] == 3 * sides and r["neumann"] == sides  # 'DNDD': the right side (3) is Neumann
    assert all(abs(x - 1.0) < 1e-12 for x in r["len"])
    if ids:  # elements per material: matrix 1, inclusion 2, and every element is one of them
        assert sum(r["ids"]) == r["ne"] and min(r["ids"]) > 0

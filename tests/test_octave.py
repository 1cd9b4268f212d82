"""The Matlab/Octave wrapper, run in GNU Octave (octave-cli) against a live embedded server on the
brain mesh: the lymph structs come back with the right element count, 1-based connectivity and
areas summing to the domain's area; server errors arrive as Octave errors with the server's words."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
from scipy.io import loadmat
from service_fixtures import BRAIN, ROOT, embedded_server, octave_cli, run_octave

pytestmark = [pytest.mark.octave, pytest.mark.slow]
TOKEN = "octave-key"

SCRIPT = r"""
addpath('{matlab}');
[region, neighbor, job] = magnet_agglomerate('{mesh}', 'Server', '{url}', 'Token', '{token}', ...
    'Model', 'metis', 'K', 64, 'SaveAs', '{saved}', 'Verbose', false, 'Poll', 0.3);
conn = [region.connectivity{{:}}];
nb = [neighbor.neigh{{:}}];
try
  magnet_agglomerate('{mesh}', 'Server', '{url}', 'Token', '{token}', 'K', 100000, 'Verbose', false);
  err = '';
catch e
  err = e.message;
end
out = struct('ne', region.ne, 'ncells', numel(region.connectivity), 'nv', size(region.coord, 1), ...
  'cmin', min(conn), 'cmax', max(conn), 'area', sum(region.area), 'elements', job.result.elements, ...
  'nbmin', min(nb), 'nbmax', max(nb), 'nedges', numel(neighbor.nedges), 'tag', region.tag, 'err', err);
fid = fopen('{result}', 'w'); fprintf(fid, '%s', jsonencode(out)); fclose(fid);
"""


def domain_area(path) -> float:
    m = meshio.read(path)
    tri = m.cells_dict["triangle"]
    p = m.points[:, :2]
    u, v = p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]
    return float(np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).sum() / 2)


def test_octave_wrapper_returns_lymph_structs(tmp_path):
    octave_cli()  # skip before starting a server
    result, saved = tmp_path / "result.json", tmp_path / "brain64.mat"
    with embedded_server(tmp_path, TOKEN, user="matlab-user") as url:
        text = SCRIPT.format(
            matlab=ROOT / "client" / "matlab", mesh=BRAIN, url=url, token=TOKEN, saved=saved, result=result
        )
        r = run_octave(tmp_path / "run_magnet.m", text, result)
    assert r["ne"] == r["ncells"] == r["elements"] == r["nedges"] and r["ne"] >= 64
    assert r["cmin"] == 1 and r["cmax"] == r["nv"]  # 1-based, every vertex used
    assert r["area"] == pytest.approx(domain_area(BRAIN), rel=1e-9)
    assert r["nbmin"] == -1 and r["nbmax"] == r["ne"]  # -1 on the boundary, 1-based neighbours
    assert r["tag"] == "P"
    assert "HTTP 422" in r["err"] and "k = 100000" in r["err"]
    assert int(loadmat(saved)["region"]["ne"][0, 0].squeeze()) == r["ne"]


HIERARCHY_SCRIPT = r"""
addpath('{matlab}');
[region, neighbor, job, levels] = magnet_agglomerate('{mesh}', 'Server', '{url}', 'Token', '{token}', ...
    'Model', 'metis', 'Mode', 'multilevel', 'Nref', 3, 'Refiner', 'fm', 'Threshold', 100, ...
    'Hierarchy', true, 'Verbose', false, 'Poll', 0.3);
ne = cellfun(@(l) l.region.ne, levels);
ok = true;
for L = 2:numel(levels)
  par = levels{{L}}.parent;
  ok = ok && numel(par) == levels{{L}}.region.ne && max(par) == levels{{L - 1}}.region.ne && min(par) == 1;
  % exact nesting: the children's areas add up to their parent's
  ok = ok && max(abs(accumarray(par, levels{{L}}.region.area(:)) - levels{{L - 1}}.region.area(:))) < 1e-9;
end
out = struct('ne', ne, 'ok', ok, 'final', region.ne, 'refiner', job.params.refiner);
fid = fopen('{result}', 'w'); fprintf(fid, '%s', jsonencode(out)); fclose(fid);
"""


def test_octave_wrapper_returns_every_nested_level(tmp_path):
    octave_cli()  # skip before starting a server
    result = tmp_path / "levels.json"
    with embedded_server(tmp_path, TOKEN, user="matlab-user") as url:
        text = HIERARCHY_SCRIPT.format(
            matlab=ROOT / "client" / "matlab", mesh=BRAIN, url=url, token=TOKEN, result=result
        )
        r = run_octave(tmp_path / "run_levels.m", text, result)
    assert r["ne"] == [1, 2, 4, 8] and r["final"] == 8 and r["ok"] is True
    assert r["refiner"] == "fm"


RATIO_SCRIPT = r"""
addpath('{matlab}');
[region, neighbor, job, levels] = magnet_agglomerate('{mesh}', 'Server', '{url}', 'Token', '{token}', ...
    'Model', 'rtree', 'Mode', 'kway', 'K', 400, 'Hierarchy', true, 'Ratio', 8, 'Coarsest', 10, ...
    'Verbose', false, 'Poll', 0.3);
ne = cellfun(@(l) l.region.ne, levels);
ok = true;
for L = 1:numel(levels)
  P = levels{{L}}.P;
  ok = ok && size(P, 2) == levels{{L}}.region.ne && all(sum(P, 2) == 1);
end
cells = size(levels{{end}}.P, 1);
out = struct('ne', ne, 'ok', ok, 'cells', cells, 'final', region.ne);
fid = fopen('{result}', 'w'); fprintf(fid, '%s', jsonencode(out)); fclose(fid);
"""


def test_octave_wrapper_hierarchy_with_ratio_and_operators(tmp_path):
    """'Ratio' gives nested levels above the job's k elements (its finest level) with the aggregation operators."""
    octave_cli()  # skip before starting a server
    result = tmp_path / "ratio.json"
    with embedded_server(tmp_path, TOKEN, user="matlab-user") as url:
        text = RATIO_SCRIPT.format(
            matlab=ROOT / "client" / "matlab", mesh=BRAIN, url=url, token=TOKEN, result=result
        )
        r = run_octave(tmp_path / "run_ratio.m", text, result)
    from models.partition.rtree import level_counts

    # the brain has no hole: no step shorter than asked (stretch 0) above the job's 400 elements
    assert (
        r["ne"] == [*level_counts(400, 8, 10, stretch=0), 400]
        and r["ok"] is True
        and r["cells"] == 14372
        and r["final"] == 400
    )

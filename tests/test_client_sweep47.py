"""Sweep 47 on the clients: magnet-client, the Matlab/Octave wrapper and the web page say what is
wrong with bad input in one sentence of ours (never a traceback or Python's raw OS text) and refuse
what they can know before a job runs; the page and the wrapper can follow the advice the server
gives (fill a closed surface, allow extra elements, weld points); docs/hierarchy.md's client example
runs as written. Against a live embedded server."""

from __future__ import annotations

import re
import subprocess
import sys

import httpx
import meshio
import numpy as np
import pytest
from meshes import tets
from service_fixtures import ROOT, embedded_server, square_mesh
from test_client import CLIENT, client_env

TOKEN = "sweep47-key"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with embedded_server(tmp_path_factory.mktemp("sweep47-server"), TOKEN) as url:
        yield url


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep47-meshes")
    points, cells = tets(3)
    meshio.write(str(d / "box.vtu"), meshio.Mesh(np.asarray(points, float), [("tetra", np.asarray(cells))]))
    return {"square": square_mesh(d / "square.vtu", 8), "box": d / "box.vtu", "dir": d}


def client_cli(server, *args, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "magnet_client.cli", "--server", server, "--token", TOKEN, *map(str, args)],
        cwd=CLIENT,
        env=client_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def job_count(server) -> int:
    r = httpx.get(f"{server}/v1/jobs", headers={"Authorization": f"Bearer {TOKEN}"}, params={"limit": 100})
    return len(r.json()["items"])


def one_error(out, text: str):
    """Exit status 2 and one line on stderr, saying `text`; no traceback."""
    assert out.returncode == 2, (out.returncode, out.stderr)
    assert "Traceback" not in out.stderr, out.stderr
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, out.stderr
    assert text in lines[0], lines[0]
    assert "Errno" not in lines[0] and "\\x" not in lines[0], lines[0]


# --- 1. magnet-client: bad values are one sentence, as `magnet hierarchy` says them ------------------


def test_kappa_that_is_no_numbers_is_the_cli_sentence(server, meshes, tmp_path):
    base = ["agglomerate", meshes["square"], "-o", tmp_path / "p.vtu", "--k", "8", "--model", "rtree"]
    base += ["--hierarchy", tmp_path / "h", "--finest", "cuts"]
    out = client_cli(server, *base, "--kappa", "x,1")
    one_error(out, "--kappa must be comma-separated numbers kx,ky[,kz], got 'x,1'")
    out = client_cli(server, *base, "--kappa", "50")
    one_error(out, "--kappa must be two or three positive numbers kx,ky[,kz], got '50'")
    out = client_cli(server, *base, "--kappa", "1,2,3")  # the mesh's dimension: known after the upload
    one_error(out, "kappa has 3 values but the mesh square.vtu is 2D: give one per axis")


@pytest.mark.parametrize(
    "flags, text",
    [
        (["--weld", "inf"], "argument --weld: must be finite, got inf"),
        (["--mode", "target-size", "--target-size", "nan"], "argument --target-size: must be finite"),
        (["--absorb", "nan"], "argument --absorb: must be finite, got nan"),
        (["--fill-size=-inf"], "argument --fill-size: must be finite, got -inf"),
        (["--k", "x"], "argument -k/--k: invalid int value: 'x'"),
        (["--server", "http://[::"], "the server address 'http://[::' is not an http:// or https:// URL"),
        (["--server", "foo"], "the server address 'foo' is not an http:// or https:// URL"),
        (["--token", "clé"], "the API key must be printable ASCII text"),
        (["--server", "http://127.0.0.1:9"], "cannot reach the MAGNET server at http://127.0.0.1:9 ("),
    ],
)
def test_every_bad_flag_value_is_one_sentence(server, meshes, tmp_path, flags, text):
    out = client_cli(server, "agglomerate", meshes["square"], "-o", tmp_path / "x.vtu", "--k", "4", *flags)
    one_error(out, text)


def test_the_python_client_refuses_values_json_cannot_carry(server, meshes, tmp_path):
    sys.path.insert(0, str(CLIENT))
    try:
        from magnet_client import Client, InputError
    finally:
        sys.path.remove(str(CLIENT))
    with Client(server, TOKEN) as c:
        before = job_count(server)
        with pytest.raises(InputError, match="target_size must be finite, got nan"):
            c.agglomerate(meshes["square"], tmp_path / "x.vtu", mode="target-size", target_size=float("nan"))
        with pytest.raises(InputError, match="kappa must be comma-separated numbers"):
            c.agglomerate(meshes["square"], tmp_path / "x.vtu", k=4, kappa=["a", 1])
        assert job_count(server) == before


# --- 2. what the client can know is refused before the server is asked, in its words ---------------


def test_missing_input_file_is_our_sentence(server, tmp_path):
    missing = tmp_path / "nope.vtu"
    out = client_cli(server, "agglomerate", missing, "-o", tmp_path / "x.vtu", "--k", "8")
    one_error(out, f"cannot read {missing}: no such file")
    out = client_cli(server, "agglomerate", tmp_path, "-o", tmp_path / "x.vtu", "--k", "8")
    one_error(out, f"cannot read {tmp_path}: it is a folder, not a file")


def test_missing_subset_file_is_our_sentence(server, meshes, tmp_path):
    subset = tmp_path / "no-subset.txt"
    out = client_cli(
        server,
        "agglomerate",
        meshes["square"],
        "-o",
        tmp_path / "x.vtu",
        "--mode",
        "coarsen",
        "--subset",
        subset,
    )
    one_error(out, f"cannot read subset file {subset}: no such file")


def test_missing_output_folder_is_refused_before_the_job(server, meshes, tmp_path):
    before = job_count(server)
    out = client_cli(server, "agglomerate", meshes["square"], "-o", tmp_path / "no" / "x.vtu", "--k", "9")
    one_error(
        out,
        f"cannot write output mesh '{tmp_path / 'no' / 'x.vtu'}': folder '{tmp_path / 'no'}' does not exist",
    )
    out = client_cli(
        server, "agglomerate", meshes["square"], "-o", tmp_path / "x.vtu", "--k", "9",
        "--metrics", tmp_path / "no" / "m.json",
    )  # fmt: skip
    one_error(out, "cannot write metrics file")
    out = client_cli(
        server,
        "agglomerate",
        meshes["square"],
        "-o",
        tmp_path / "x.vtu",
        "--k",
        "9",
        "--hierarchy",
        meshes["square"],
    )
    one_error(out, "it is a file, not a folder")
    assert job_count(server) == before


def test_lymph_of_a_3d_mesh_is_refused_before_the_job(server, meshes, tmp_path):
    before = job_count(server)
    out = client_cli(
        server,
        "agglomerate",
        meshes["box"],
        "-o",
        tmp_path / "box.vtu",
        "--k",
        "4",
        "--lymph",
        tmp_path / "b.mat",
    )
    one_error(out, "lymph's region/neighbor structs are for 2D meshes only and box.vtu is 3D")
    assert job_count(server) == before
    assert not (tmp_path / "box.vtu").exists()


# --- 4. docs/hierarchy.md's client example runs as written -----------------------------------------


def test_docs_hierarchy_client_example_runs(server, meshes, tmp_path):
    text = (ROOT / "docs" / "hierarchy.md").read_text()
    m = re.search(r"`(magnet-client agglomerate [^`]*--finest cuts)`", text.replace("\n  ", " "))
    assert m, "docs/hierarchy.md lost its magnet-client example"
    words = m.group(1).split()[1:]
    subst = {
        "MESH": str(meshes["square"]),
        "OUT.vtu": str(tmp_path / "out.vtu"),
        "DIR": str(tmp_path / "levels"),
    }
    out = client_cli(server, *[subst.get(w, w) for w in words])
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "levels" / "hierarchy.json").exists()


# --- 3. the web page: ratios in 3 digits, the options its advice names are on the form -----------------

CHROMIUM = "/usr/bin/chromium"


@pytest.fixture(scope="module")
def page_of(server, tmp_path_factory):
    """A page of the live server in Debian's chromium (Playwright), with the API key entered."""
    import os
    import shutil

    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
    chromium = os.environ.get("MAGNET_TEST_CHROMIUM", CHROMIUM)
    if not (os.path.exists(chromium) or shutil.which(chromium)):
        pytest.skip(f"no chromium at {chromium} (apt-get install chromium; scripts/test.sh does)")
    from test_web_page import ARGS

    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=ARGS)

        def open_page():
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(server + "/")
            page.fill("#token", TOKEN)
            page.dispatch_event("#token", "change")
            return page, errors

        yield open_page
        browser.close()


def until(page, expression: str, timeout: float = 120):
    from service_fixtures import wait_until

    return wait_until(lambda: page.evaluate(expression), timeout, 0.1, expression)


def upload(page, path):
    page.set_input_files("#file", str(path))
    page.wait_for_selector("#mesh-summary")
    until(page, "!document.querySelector('#form').hidden")


def finished(page) -> str:
    until(
        page,
        "['succeeded', 'failed'].some((s) => document.querySelector('#progress-status').textContent.startsWith(s))",
    )
    return page.inner_text("#progress-status")


def test_web_hierarchy_ratio_has_at_most_3_digits(page_of, tmp_path):
    points, cells = tets(8)
    box = tmp_path / "box8.vtu"
    meshio.write(str(box), meshio.Mesh(np.asarray(points, float), [("tetra", np.asarray(cells))]))
    page, errors = page_of()
    upload(page, box)
    page.select_option("select[name=model]", "rtree")
    page.select_option("select[name=mode]", "kway")
    page.fill("input[name=k]", "4")
    page.check("input[name=hierarchy]")
    page.select_option("select[name=finest]", "aggregation")  # a ratio per step: [5.9..., 16] on this box
    page.click("button[type=submit]")
    assert finished(page) == "succeeded"
    until(page, "/ratio /.test(document.querySelector('#hierarchy-title').textContent)")
    title = page.inner_text("#hierarchy-title")
    ratio = re.search(r"ratio ([^·]+)·", title).group(1).strip()
    values = ratio.split(", ")
    assert len(values) >= 2, title
    for v in values:
        assert len(v.replace(".", "").lstrip("0")) <= 3, title
    assert errors == []


def test_web_form_has_the_options_a_failed_coarsen_job_names(page_of, meshes):
    page, errors = page_of()
    upload(page, meshes["square"])
    page.select_option("select[name=model]", "metis")
    page.select_option("select[name=mode]", "coarsen")
    page.fill("textarea[name=subset]", "0 127")  # two cells far apart: two pieces
    page.fill("input[name=k]", "1")
    for name in ("nref", "target_size", "mult_factor"):
        page.fill(f"input[name={name}]", "")
    page.click("button[type=submit]")
    status = finished(page)
    assert status.startswith("failed"), status
    # the advice names the form's own fields, which are there to tick and fill
    assert "“Allow extra elements” under Options" in status and "options.allow_extra" not in status, status
    assert "“Weld points closer than” under Options" in status, status
    page.evaluate("document.querySelector('#form details').open = true")
    page.check("input[name=allow_extra]")
    page.fill("input[name=weld]", "1e-12")
    page.click("button[type=submit]")
    until(
        page,
        "document.querySelector('#progress-status').textContent === 'queued' || document.querySelector('#progress-status').textContent === 'running' || document.querySelector('#progress-status').textContent === 'succeeded'",
    )
    assert finished(page) == "succeeded"
    jobs = httpx.get(f"{page.url}v1/jobs", headers={"Authorization": f"Bearer {TOKEN}"}).json()["items"]
    options = jobs[0]["params"]["options"]
    assert options.get("allow_extra") is True and options.get("weld") == 1e-12, options
    assert errors == []


def test_web_fill_checkbox_for_closed_surfaces(page_of, meshes, tmp_path):
    from surfaces import surface_of

    points, tris = surface_of(lambda occ: occ.addSphere(0, 0, 0, 1), 0.5)
    ball = tmp_path / "ball.stl"
    meshio.write(str(ball), meshio.Mesh(points, [("triangle", tris)]))
    page, errors = page_of()
    upload(page, meshes["square"])
    assert page.is_hidden(".field[data-field=fill]")  # not a surface: no fill
    upload(page, ball)
    assert page.is_visible(".field[data-field=fill]") and page.is_checked("input[name=fill]")
    page.select_option("select[name=model]", "metis")
    page.select_option("select[name=mode]", "kway")
    page.fill("input[name=k]", "8")
    page.uncheck("input[name=fill]")  # without it the server refuses, naming the checkbox
    page.click("button[type=submit]")
    until(
        page,
        "document.querySelector('.field[data-field=fill]').classList.contains('invalid') || document.querySelector('#form-error').textContent",
    )
    said = page.inner_text(".field[data-field=fill] .error") or page.inner_text("#form-error")
    assert "Fill the closed surface" in said, said
    page.check("input[name=fill]")
    page.click("button[type=submit]")
    assert finished(page) == "succeeded"
    assert errors == []


# --- 2 and 3. the Matlab/Octave wrapper: refusals up front, Fill, connect errors, 429 retried ----------

OCTAVE_TRY = r"""
addpath('{matlab}');
function r = tryit(f)
  try
    f();
    r = struct('id', 'ok', 'msg', '');
  catch err
    r = struct('id', err.identifier, 'msg', err.message);
  end
end
"""


def octave(tmp_path, body: str, **fmt) -> dict:
    from service_fixtures import run_octave

    result = tmp_path / "result.json"
    text = OCTAVE_TRY.format(matlab=ROOT / "client" / "matlab") + body.format(result=result, **fmt)
    return run_octave(tmp_path / "run_sweep47.m", text, result)


@pytest.mark.octave
def test_octave_refuses_up_front_fills_and_names_the_server(server, meshes, tmp_path):
    from service_fixtures import free_port, octave_cli
    from surfaces import surface_of

    octave_cli()
    points, tris = surface_of(lambda occ: occ.addSphere(0, 0, 0, 1), 0.5)
    ball = tmp_path / "ball.stl"
    meshio.write(str(ball), meshio.Mesh(points, [("triangle", tris)]))
    before = job_count(server)
    body = r"""
o = {{'Server', '{url}', 'Token', '{token}', 'Verbose', false, 'Poll', 0.2}};
r.missing = tryit(@() magnet_agglomerate('{missing}', 'K', 8, o{{:}}));
r.box = tryit(@() magnet_agglomerate('{box}', 'K', 4, o{{:}}));
r.fill_no_output = tryit(@() magnet_agglomerate('{ball}', 'K', 4, 'Fill', true, o{{:}}));
r.surface = tryit(@() magnet_agglomerate('{ball}', 'K', 4, o{{:}}));
r.down = tryit(@() magnet_agglomerate('{square}', 'K', 4, 'Server', '{down}', 'Verbose', false));
[region, neighbor, job] = magnet_agglomerate('{ball}', 'K', 4, 'Fill', true, 'Output', '{out}', o{{:}});
r.filled = struct('region', isempty(region), 'elements', job.result.elements, 'fill', job.params.options.fill);
fid = fopen('{result}', 'w'); fprintf(fid, '%s', jsonencode(r)); fclose(fid);
"""
    down = f"http://127.0.0.1:{free_port()}"
    r = octave(
        tmp_path, body, url=server, token=TOKEN, missing=tmp_path / "nope.vtu", box=meshes["box"],
        ball=ball, square=meshes["square"], down=down, out=tmp_path / "ball4.vtu",
    )  # fmt: skip
    assert r["missing"] == {"id": "magnet:file", "msg": f"cannot read {tmp_path / 'nope.vtu'}: no such file"}
    assert r["box"]["id"] == "magnet:dim" and "2D meshes only and box.vtu is 3D" in r["box"]["msg"], r["box"]
    assert r["fill_no_output"]["id"] == "magnet:dim", r["fill_no_output"]
    # the server's advice, in the wrapper's own option names
    said = r["surface"]["msg"]
    assert "'Fill', true" in said and "set options.fill" not in said, said
    assert (
        r["down"]["id"] == "magnet:connect"
        and f"cannot reach the MAGNET server at {down}" in r["down"]["msg"]
    )
    assert r["filled"] == {"region": True, "elements": 4, "fill": True}
    assert meshio.read(tmp_path / "ball4.vtu").cells
    assert job_count(server) == before + 1  # the 3D job was taken back; the filled one ran


@pytest.mark.octave
def test_octave_retries_a_full_queue(tmp_path):
    from service_fixtures import octave_cli, service_env, start_api

    octave_cli()
    mesh = square_mesh(tmp_path / "sq.vtu", 6)
    env = service_env(tmp_path / "data", api_keys=f"o:{TOKEN}", max_queued_jobs_per_user=1)
    proc, url = start_api(env, tmp_path)  # no worker: a job stays queued and fills the queue
    try:
        auth = {"Authorization": f"Bearer {TOKEN}"}
        mesh_id = httpx.post(
            f"{url}/v1/meshes", params={"filename": "sq.vtu"}, content=mesh.read_bytes(), headers=auth
        ).json()["id"]
        first = httpx.post(f"{url}/v1/jobs", json={"mesh_id": mesh_id, "k": 4}, headers=auth).json()
        body = r"""
r = tryit(@() magnet_agglomerate('{mesh}', 'K', 4, 'Server', '{url}', 'Token', '{token}', 'Verbose', false, ...
          'Timeout', 2, 'Poll', 0.2));
fid = fopen('{result}', 'w'); fprintf(fid, '%s', jsonencode(r)); fclose(fid);
"""
        import threading
        import time

        def free_the_queue():
            time.sleep(4)  # Octave got its 429 and waits
            httpx.delete(f"{url}/v1/jobs/{first['id']}", params={"purge": "true"}, headers=auth)

        threading.Thread(target=free_the_queue, daemon=True).start()
        t0 = time.monotonic()
        r = octave(tmp_path, body, mesh=mesh, url=url, token=TOKEN)
        # submitted after the retry: the job then waits in the queue (no worker) until the Timeout
        assert r["id"] == "magnet:timeout", r
        assert time.monotonic() - t0 > 4
    finally:
        proc.stop()

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

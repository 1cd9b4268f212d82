"""The Python client: installs alone (no torch, no server code), and its CLI `magnet-client
agglomerate` with the flags of `magnet agglomerate` gives the same result as the local command,
against a live embedded server."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from service_fixtures import ROOT, embedded_server, square_mesh

from models.cli.main import main as magnet

CLIENT = ROOT / "client"
TOKEN = "client-test-key"


def client_env() -> dict:
    """Only the client package on the path: the repository's packages are not importable from it."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MAGNET_", "PYTHONPATH"))}
    env["PYTHONPATH"] = str(CLIENT)
    return env


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with embedded_server(tmp_path_factory.mktemp("client-server"), TOKEN) as url:
        yield url


def test_client_imports_no_torch_and_no_server_code():
    code = (
        "import sys, magnet_client, magnet_client.cli; "
        "bad = [m for m in ('torch', 'service', 'worker', 'models', 'fastapi', 'celery', 'sqlalchemy') "
        "if m in sys.modules]; print(bad)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=CLIENT, env=client_env(), capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"


def test_client_wheel_holds_only_the_client(tmp_path):
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(CLIENT),
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    (wheel,) = tmp_path.glob("magnet_client-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert all(n.startswith(("magnet_client/", "magnet_client-")) for n in names), names
    meta = next(n for n in names if n.endswith("METADATA"))
    requires = [
        line
        for line in zipfile.ZipFile(wheel).read(meta).decode().splitlines()
        if line.startswith("Requires-Dist")
    ]
    assert sorted(r.split()[1].split(">")[0] for r in requires) == ["httpx", "tqdm"]


def test_cli_same_flags_same_result_as_local(server, tmp_path, capsys):
    mesh = square_mesh(tmp_path / "square.vtu", 12)
    subset = tmp_path / "subset.txt"
    subset.write_text(" ".join(str(i) for i in range(0, 288, 2)))
    flags = ["--model", "metis", "--mode", "coarsen", "--k", "6", "--subset", str(subset), "--seed", "2"]
    remote, local = tmp_path / "remote", tmp_path / "local"
    remote.mkdir()
    local.mkdir()

    def outputs(d):
        return [
            "-o",
            str(d / "out.vtu"),
            "--metrics",
            str(d / "m.json"),
            "--labels",
            str(d / "l.json"),
            "--lymph",
            str(d / "lymph.mat"),
            "--plot",
            str(d / "p.png"),
        ]

    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "magnet_client.cli",
            "agglomerate",
            str(mesh),
            "--server",  # the form: flags after the sub-command
            server,
            "--token",
            TOKEN,
            *outputs(remote),
            *flags,
        ],
        cwd=CLIENT,
        env=client_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert "elements from 288 cells" in out.stdout
    capsys.readouterr()
    assert magnet(["agglomerate", str(mesh), *outputs(local), *flags]) == 0
    # the same one-line summary (elements, parts split, fragments absorbed; then timings and total)
    local_line = capsys.readouterr().out.strip().splitlines()[-1]
    remote_line = out.stdout.strip().splitlines()[-1]
    assert remote_line.split(" | ")[0] == local_line.split(" | ")[0], (remote_line, local_line)
    assert " | job: read " in remote_line and " | client wall time " in remote_line
    assert remote_line.count("total") == 1 and remote_line.endswith(f"| job {remote_line.rsplit(' ', 1)[-1]}")
    assert json.loads((remote / "l.json").read_text()) == json.loads((local / "l.json").read_text())
    assert (
        json.loads((remote / "m.json").read_text())["summary"]
        == json.loads((local / "m.json").read_text())["summary"]
    )
    assert (remote / "lymph.mat").read_bytes()[:6] == b"MATLAB"
    assert (remote / "p.png").read_bytes()[:4] == b"\x89PNG"
    assert (remote / "out.vtu").stat().st_size > 0


def test_cli_weld_and_size_measure_as_local(server, tmp_path, capsys):
    """--weld and --size-measure reach the server and give the local CLI's labels."""
    mesh = square_mesh(tmp_path / "square.vtu", 12)
    flags = [
        "--model",
        "metis",
        "--mode",
        "mult-factor",
        "--mult-factor",
        "0.3",
        "--size-measure",
        "vertices",
        "--weld",
        "1e-9",
    ]
    remote, local = tmp_path / "remote.json", tmp_path / "local.json"
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "magnet_client.cli",
            "agglomerate",
            str(mesh),
            "--server",
            server,
            "--token",
            TOKEN,
            "-o",
            str(tmp_path / "r.vtu"),
            "--labels",
            str(remote),
            *flags,
        ],
        cwd=CLIENT,
        env=client_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert (
        magnet(["agglomerate", str(mesh), "-o", str(tmp_path / "l.vtu"), "--labels", str(local), *flags]) == 0
    )
    labels = json.loads(remote.read_text())
    assert labels == json.loads(local.read_text())
    centroids = magnet(
        [
            "agglomerate",
            str(mesh),
            "-o",
            str(tmp_path / "c.vtu"),
            "--labels",
            str(tmp_path / "c.json"),
            *flags[:-4],
            "--weld",
            "1e-9",
        ]
    )  # the default measure (centroids) gives fewer, larger elements here
    assert centroids == 0 and max(json.loads((tmp_path / "c.json").read_text())) < max(labels)
    # --weld joins a mesh split along a seam of duplicate points: one element for k=1 instead of two
    seam = Path(__file__).parent / "data" / "defects" / "duplicate_seam.vtu"
    for weld, elements in ((["--weld", "1e-9"], 1), (["--allow-extra"], 2)):
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "magnet_client.cli",
                "agglomerate",
                str(seam),
                "--server",
                server,
                "--token",
                TOKEN,
                "-o",
                str(tmp_path / "seam.vtu"),
                "--k",
                "1",
                *weld,
            ],
            cwd=CLIENT,
            env=client_env(),
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert out.returncode == 0 and out.stdout.startswith(f"{elements} elements"), (
            weld,
            out.stdout,
            out.stderr,
        )


def test_cli_clear_errors(server, tmp_path):
    mesh = square_mesh(tmp_path / "square.vtu", 4)

    def run(*args):
        return subprocess.run(
            [sys.executable, "-m", "magnet_client.cli", "--server", server, *args],
            cwd=CLIENT,
            env=client_env(),
            capture_output=True,
            text=True,
            timeout=120,
        )

    out = run("--token", TOKEN, "agglomerate", str(mesh), "-o", str(tmp_path / "o.vtu"), "--k", "1000")
    assert out.returncode == 2 and "HTTP 422" in out.stderr and "k = 1000" in out.stderr
    out = run("--token", "wrong", "agglomerate", str(mesh), "-o", str(tmp_path / "o.vtu"), "--k", "3")
    assert out.returncode == 2 and "HTTP 401" in out.stderr
    out = subprocess.run(
        [sys.executable, "-m", "magnet_client.cli", "--server", "http://127.0.0.1:9", "models"],
        cwd=CLIENT,
        env=client_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2 and "cannot reach" in out.stderr


def test_python_api(server, tmp_path):
    sys.path.insert(0, str(CLIENT))
    try:
        from magnet_client import Client, MagnetHTTPError
    finally:
        sys.path.remove(str(CLIENT))
    mesh = square_mesh(tmp_path / "square.vtu", 6)
    with Client(server, TOKEN) as client:
        assert {"metis", "kmeans"} <= {m["name"] for m in client.models()}
        job = client.agglomerate(
            mesh,
            tmp_path / "out.vtu",
            model="kmeans",
            k=5,
            seed=1,
            progress=False,
            labels=str(tmp_path / "labels.json"),
        )
        assert job["status"] == "succeeded" and job["params"]["options"]["seed"] == 1
        assert len(client.download_labels(job["id"])) == 72
        assert client.download_metrics(job["id"])["elements"] == job["result"]["elements"]
        assert "region" in client.download_lymph(job["id"])
        with pytest.raises(MagnetHTTPError) as err:
            client.job("0" * 32)
        assert err.value.status == 404


def test_progress_bar_and_event_stream(server, tmp_path):
    """`magnet-client --progress` draws the job's stages and percentage (from the event stream) as a
    tqdm bar; Client.events yields the records the page shows, the last one final."""
    mesh = square_mesh(tmp_path / "square.vtu", 60)
    out = subprocess.run(
        [sys.executable, "-m", "magnet_client.cli", "--server", server, "--token", TOKEN, "agglomerate",
         str(mesh), "-o", str(tmp_path / "out.vtu"), "--k", "150", "--seed", "7", "--progress"],
        cwd=CLIENT, env=client_env(), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    frames = [f.strip() for f in out.stderr.replace("\r", "\n").split("\n") if "%" in f]
    assert any(" 100% " in f for f in frames), frames
    assert len({f.split()[0] for f in frames}) >= 2, frames  # several stages shown, not just the end
    sys.path.insert(0, str(CLIENT))
    try:
        from magnet_client import Client, MagnetHTTPError
    finally:
        sys.path.remove(str(CLIENT))
    with Client(server, TOKEN) as client:
        job = client.submit(client.upload(mesh)["id"], k=150, seed=8)
        records = list(client.events(job["id"]))
        assert records[-1]["status"] == "succeeded" and records[-1]["progress"] == 1.0
        assert [r["progress"] for r in records] == sorted(r["progress"] for r in records)
        assert list(client.events(job["id"])) == [records[-1]]  # a finished job: its final record at once
        assert client.wait(job["id"], progress=False) == records[-1]
        with pytest.raises(MagnetHTTPError) as err:  # the stream's 404 falls back to the job: 404 too
            list(client.follow("0" * 32))
        assert err.value.status == 404


def test_client_knows_exactly_the_api_fields():
    """The client keeps its own lists of job fields (it imports nothing from the server side): they
    must name exactly the API's parameters and options, so a new option is not silently dropped."""
    from magnet_client.client import OPTION_NAMES, PARAM_NAMES

    from service.schemas import JobOptions, JobParams

    assert set(OPTION_NAMES) == set(JobOptions.model_fields)
    assert set(PARAM_NAMES) == set(JobParams.model_fields) - {"options"}


def test_client_command_line_takes_every_flag_of_magnet_agglomerate(server, tmp_path, monkeypatch):
    """`magnet-client agglomerate` takes the flags of `magnet agglomerate` (the README says so), and
    they reach the job: a closed surface filled and agglomerated on the server with --fill."""
    monkeypatch.syspath_prepend(str(Path(ROOT) / "client"))
    import meshio
    from magnet_client.cli import build_parser as client_parser
    from surfaces import surface_of

    from models.cli.main import build_parser

    def flags(parser, name):
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        return {o for a in sub.choices[name]._actions for o in a.option_strings}

    local, remote = flags(build_parser(["agglomerate"]), "agglomerate"), flags(client_parser(), "agglomerate")
    assert local <= remote, sorted(local - remote)
    pytest.importorskip("gmsh")
    points, tris = surface_of(lambda occ: occ.addSphere(0, 0, 0, 1), 0.25)
    shell = tmp_path / "ball.stl"
    meshio.write(str(shell), meshio.Mesh(points, [("triangle", tris)]))
    out = subprocess.run(
        [sys.executable, "-m", "magnet_client.cli", "agglomerate", str(shell), "--server", server]
        + ["--token", TOKEN, "-o", str(tmp_path / "ball.vtu"), "-k", "8", "--fill", "--max-cells", "100000"],
        cwd=CLIENT,
        env=client_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0 and out.stdout.startswith("8 elements"), (out.stdout, out.stderr)
    assert meshio.read(tmp_path / "ball.vtu").points.shape[1] == 3


def test_summary_line_labels_job_stages_and_client_time(monkeypatch):
    monkeypatch.syspath_prepend(str(Path(ROOT) / "client"))
    from magnet_client.cli import summary_line

    job = {
        "id": "abc",
        "mesh": {"cells": 288},
        "result": {"elements": 16, "timings": {"read": 0.1, "write": 0.38, "total": 0.43}},
    }
    line = summary_line(job, 0.55)
    assert line == (
        "16 elements from 288 cells | job: read 0.10s write 0.38s total 0.43s | client wall time 0.55s | job abc"
    )

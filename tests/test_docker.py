"""Docker files, checked without a Docker engine: the compose file parses, has the redis, api and
worker services on one shared data volume, a GPU reservation for the GPU worker, and every
`magnet ...` command in it (and the image's CMD) parses with the real sub-command parsers."""

from __future__ import annotations

import argparse
import json
import re
import tomllib

import pytest
import yaml
from service_fixtures import ROOT

from service.cli import register_serve
from worker.cli import register_worker


@pytest.fixture(scope="module")
def compose():
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def magnet_parser() -> argparse.ArgumentParser:
    """The `magnet` sub-commands the server side registers through the magnet.commands entry points."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    commands = pyproject["project"]["entry-points"]["magnet.commands"]
    assert commands == {
        "serve": "service.cli:register_serve",
        "keys": "service.cli:register_keys",
        "worker": "worker.cli:register_worker",
    }
    assert pyproject["project"]["scripts"]["magnet"] == "models.cli.main:main"
    parser = argparse.ArgumentParser(prog="magnet", exit_on_error=False)
    sub = parser.add_subparsers(dest="command", required=True)
    register_serve(sub)
    register_worker(sub)
    return parser


def check_command(argv: list[str]) -> argparse.Namespace:
    assert argv[0] == "magnet", argv
    args = magnet_parser().parse_args(argv[1:])
    assert callable(args.func)
    return args


def test_compose_services_and_shared_volume(compose):
    services = compose["services"]
    assert {"redis", "api", "worker"} <= set(services)
    assert services["redis"]["image"].startswith("redis")
    for name in ("api", "worker", "worker-gpu"):
        svc = services[name]
        env = svc["environment"]
        assert env["MAGNET_BROKER_URL"] == "redis://redis:6379/0"
        assert "magnet-data:" + env["MAGNET_DATA_DIR"] in svc["volumes"]
        assert "redis" in svc["depends_on"]
    assert "magnet-data" in compose["volumes"]
    assert "MAGNET_API_KEYS" in services["api"]["environment"]  # bound to 0.0.0.0: keys required


def test_compose_commands_exist(compose):
    assert check_command(compose["services"]["api"]["command"]).command == "serve"
    worker = check_command(compose["services"]["worker"]["command"])
    assert worker.command == "worker" and worker.queues == "cpu"
    gpu = check_command(compose["services"]["worker-gpu"]["command"])
    assert gpu.command == "worker" and "gpu" in gpu.queues.split(",") and gpu.concurrency == 1


def test_gpu_worker_reserves_a_gpu(compose):
    gpu = compose["services"]["worker-gpu"]
    devices = gpu["deploy"]["resources"]["reservations"]["devices"]
    assert devices[0]["capabilities"] == ["gpu"] and devices[0]["count"] == 1
    assert "cuda" in gpu["build"]["args"]["BASE_IMAGE"]


def test_dockerfile_cpu_default_cuda_argument_and_cmd():
    text = (ROOT / "Dockerfile").read_text()
    assert re.search(r"^ARG BASE_IMAGE=python:3\.1\d", text, re.M)
    assert re.search(r"^FROM \$\{BASE_IMAGE\}", text, re.M)
    assert "download.pytorch.org/whl/cpu" in text
    for src in re.findall(r"^COPY (\S+) ", text, re.M):
        assert (ROOT / src).exists(), src
    cmd = json.loads(re.search(r"^CMD (\[.*\])$", text, re.M).group(1))
    assert check_command(cmd).command == "serve"

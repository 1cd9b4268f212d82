"""Schemathesis fuzzes every operation of the OpenAPI schema (bounded examples): no 5xx, ever."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

schemathesis = pytest.importorskip("schemathesis")

from schemathesis.checks import not_a_server_error  # noqa: E402

from jobqueue.settings import Settings  # noqa: E402
from service.app import create_app  # noqa: E402

TOKEN = "fuzz-key"
_data = Path(tempfile.mkdtemp(prefix="magnet-fuzz-"))
app = create_app(
    Settings(data_dir=_data, api_keys=f"fuzzer:{TOKEN}", max_upload_bytes=200_000, parse_timeout_s=20)
)
schema = schemathesis.openapi.from_asgi("/openapi.json", app)


@schema.parametrize()
@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
def test_no_server_errors(case):
    headers = {"Authorization": f"Bearer {TOKEN}"}
    if case.path == "/readyz":  # 503 "not ready" is its documented answer when no worker runs
        status = case.call(headers=headers).status_code
        assert status < 500 or status == 503
        return
    case.call_and_validate(headers=headers, checks=[not_a_server_error])

"""Property-based API fuzzing with schemathesis, from the app's own OpenAPI schema: no
generated request (valid or not: random multipart bodies, ids, cursors, headers) may cause
a server error, and every response must match the documented status codes and schemas."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    response_schema_conformance,
    status_code_conformance,
)

from jobs.config import Settings
from service.main import create_app

_DATA = Path(tempfile.mkdtemp(prefix="prt-schemathesis-"))
app = create_app(Settings(data_dir=_DATA, max_upload_bytes=1 << 20))
schema = schemathesis.openapi.from_asgi("/openapi.json", app)


@pytest.fixture(scope="module", autouse=True)
def _lifespan():
    """Open the store and queue (the app's lifespan) for the whole module."""
    import shutil

    from fastapi.testclient import TestClient

    with TestClient(app):
        yield
    shutil.rmtree(_DATA, ignore_errors=True)


@schema.parametrize()
@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                                 HealthCheck.function_scoped_fixture])
def test_no_server_error(case):
    case.call_and_validate(checks=[not_a_server_error, status_code_conformance,
                                   response_schema_conformance])

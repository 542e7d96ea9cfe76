"""Property-based fuzzing of every operation of the OpenAPI schema (schemathesis): never a 5xx.

Bounded so that it stays fast: a few examples per operation, no deadline, jobs never run (idle runner).
Every answer is checked: a status below 500, documented for the operation in the OpenAPI document, and
every error is problem+json with its status.

The app is built at import because schemathesis reads the schema when the module is collected
(``schemathesis.pytest.from_fixture`` fails under pytest 9); its data folder is removed afterwards.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings

from api.app import create_app
from api.auth import create_key
from tests.api.conftest import IdleRunner, make_settings

_DATA = tempfile.TemporaryDirectory(prefix="cabinplan-fuzz-")
APP = create_app(make_settings(Path(_DATA.name), max_upload_bytes=64 * 1024), runner=IdleRunner())
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)
KEY: dict[str, str] = {}


@pytest.fixture(scope="module", autouse=True)
def _lifespan() -> Iterator[None]:
    with TestClient(APP):  # creates the tables and starts the (idle) runner
        KEY["alpha"] = create_key(APP.state.ctx, "alpha", "fuzz")[1]
        yield
    _DATA.cleanup()


#: Operations that compute for seconds per call (the pprs6 workspace search and pose-path profiles) get
#: fewer examples, so the whole fuzz stays bounded; every operation is fuzzed.
HEAVY_TAG = "pprs6"


@schema.exclude(tag=HEAVY_TAG).parametrize()
@settings(max_examples=6, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
def test_no_server_errors(case: schemathesis.Case) -> None:
    _check(case)


@schema.include(tag=HEAVY_TAG).parametrize()
@settings(max_examples=2, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
def test_no_server_errors_heavy_operations(case: schemathesis.Case) -> None:
    _check(case)


def _check(case: schemathesis.Case) -> None:
    response = case.call(headers={"X-API-Key": KEY["alpha"]})
    assert response.status_code < 500, f"{case.method} {case.formatted_path}: {response.text[:500]}"
    if case.method.upper() == case.operation.method.upper():  # (not the unsupported-method probes: 405)
        documented = set(case.operation.definition.raw["responses"])
        assert str(response.status_code) in documented, (
            case.method,
            case.formatted_path,
            response.status_code,
        )
    if response.status_code >= 400:
        content_type = response.headers.get("content-type", [""])[0]
        assert content_type.startswith("application/problem+json"), (
            response.status_code,
            response.text[:200],
        )
        body = response.json()
        assert body["status"] == response.status_code and "Traceback" not in response.text

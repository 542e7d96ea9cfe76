"""Property-based fuzzing of every operation of the OpenAPI schema (schemathesis): never a 5xx.

Bounded so that it stays fast: a few examples per operation, no deadline, jobs never run (idle runner).
Every answer is checked: a status below 500, documented for the operation in the OpenAPI document, and
every error is problem+json with its status.

Phases: the schema's examples and random bodies (fuzzing) for every operation; the coverage phase (every
boundary value, missing and unexpected parameters) for the operations whose enumeration the contract test
leaves out (``tests/api/test_contract.py``: the large bodies and the pprs6 tools) -- it enumerates every
other operation with every check, these assertions included.

Run through schemathesis' engine (its pytest plugin gives every operation's test the same node id, which
pytest-xdist runs once instead of once per operation), in parts that ``make test``'s two workers share:
the examples and fuzzing of every operation, and the coverage phase of each large body (1 400-2 700 cases
each).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import schemathesis
from fastapi.testclient import TestClient
from schemathesis.config import SchemathesisConfig
from schemathesis.engine import events, from_schema

from api.app import create_app
from api.auth import create_key
from tests.api.conftest import IdleRunner, make_settings
from tests.api.test_contract import HEAVY_TAG, LARGE_BODIES

#: Examples per operation in the fuzzing phase; the pprs6 tools compute for seconds a call: fewer.
MAX_EXAMPLES = 6
HEAVY_MAX_EXAMPLES = 2


#: The parts of the run: None, every operation's examples and random bodies (and the pprs6 tools' coverage
#: phase); a large body's path, its coverage phase alone.
PARTS = [None, *sorted({path for _, path in LARGE_BODIES})]


def _config(key: str, part: str | None) -> SchemathesisConfig:
    if part is None:
        operations: list[dict[str, Any]] = [
            {"include-tag": HEAVY_TAG, "generation": {"max-examples": HEAVY_MAX_EXAMPLES}},
            {  # enumerated by the contract test, or by a part of its own
                "exclude-tag": HEAVY_TAG,
                "phases": {"coverage": {"enabled": False}},
            },
        ]
    else:
        operations = [
            {
                "include-path": part,
                "phases": {"examples": {"enabled": False}, "fuzzing": {"enabled": False}},
            },
            {"exclude-path": part, "enabled": False},
        ]
    config = SchemathesisConfig.from_dict(
        {
            "seed": 1,
            "headers": {"X-API-Key": key},
            "generation": {"max-examples": MAX_EXAMPLES, "deterministic": True},
            "phases": {"stateful": {"enabled": False}},
            "operations": operations,
        }
    )
    config.projects.override.checks.update(included_check_names=["not_a_server_error"])
    return config


def _problems(case: schemathesis.Case, status: int, content_type: str, body: bytes) -> list[str]:
    """What is wrong with one answer: a 5xx, an undocumented status, an error that is not problem+json."""
    label = f"{case.method.upper()} {case.formatted_path} -> {status}"
    if status >= 500:
        return [f"{label}: {body[:500]!r}"]
    out = []
    if case.method.upper() == case.operation.method.upper():  # (not the unsupported-method probes: 405)
        if str(status) not in case.operation.definition.raw["responses"]:
            out.append(f"{label}: not documented for the operation")
    if status >= 400:
        import json

        if not content_type.startswith("application/problem+json"):
            out.append(f"{label}: content type {content_type!r}, not problem+json")
        elif json.loads(body).get("status") != status or b"Traceback" in body:
            out.append(f"{label}: problem status differs or a traceback: {body[:200]!r}")
    return out


@pytest.mark.parametrize(
    "part",
    [pytest.param(p, marks=pytest.mark.xdist_group(f"fuzz {p}"), id=p or "fuzzing") for p in PARTS],
)
def test_no_server_errors(part: str | None, tmp_path: Path) -> None:
    app = create_app(make_settings(tmp_path, max_upload_bytes=64 * 1024), runner=IdleRunner())
    with TestClient(app):  # creates the tables and starts the (idle) runner
        key = create_key(app.state.ctx, "alpha", "fuzz")[1]
        schema = schemathesis.openapi.from_asgi("/openapi.json", app, config=_config(key, part))
        answers, operations, problems, errors = 0, set(), [], []
        for event in from_schema(schema).execute():
            if isinstance(event, events.ScenarioFinished):
                for case_id, interaction in event.recorder.interactions.items():
                    response = interaction.response
                    assert response is not None, event.recorder.label
                    case = event.recorder.cases[case_id].value
                    answers += 1
                    operations.add(event.recorder.label)
                    content_type = (response.headers.get("content-type") or [""])[0]
                    problems += _problems(case, response.status_code, content_type, response.content)
            elif isinstance(event, events.NonFatalError):  # pragma: no cover - the run could not test
                errors.append(str(event.info)[:600])
    print(f"schemathesis: {answers} answers from {len(operations)} operations")  # noqa: T201
    if part is None:
        n_operations = sum(len(methods) for methods in app.openapi()["paths"].values())
        assert len(operations) == n_operations, sorted(operations)  # every operation fuzzed
    else:
        assert len(operations) >= 1 and answers >= 200, (operations, answers)  # its enumeration ran
    assert not errors, errors
    assert not problems, "\n".join(sorted(set(problems))[:40])

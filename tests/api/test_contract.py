"""The published OpenAPI document says exactly what the server accepts and answers (schemathesis, all checks).

Every operation, every phase but the stateful one (examples, coverage: boundary values, missing and
unexpected parameters, undeclared methods; fuzzing), every check schemathesis has (``--checks all``):
status codes, content types, response schemas and headers, schema-valid data accepted and invalid data
refused, 405 with an ``Allow`` header listing the path's methods. Jobs never run (idle runner).

Where acceptance depends on physics or on stored state no schema can state, a schema-valid body may be
refused with 422 (the exceptions below, one reason each); for the kinematics and stiffness tools only with
a physical reason (:func:`physics_refusal`), so a refusal of the body's *shape* still fails the test.

Bounded for CI: five examples per operation in the fuzzing phase (``tests/api/test_fuzz.py`` draws six
more of every operation), the coverage phase's enumeration for every operation but the largest bodies
(LARGE_BODIES): 465 cases, 18 s alone on the 2-core machine (ten examples: 675 cases, 27 s).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import schemathesis
from fastapi.testclient import TestClient
from schemathesis.config import SchemathesisConfig
from schemathesis.engine import Status, events, from_schema

from api.app import create_app
from api.auth import create_key
from tests.api.conftest import IdleRunner, make_settings

#: Operations whose schema-valid bodies the server may refuse with 422, and why.
SEMANTIC_422: dict[tuple[str, str], str] = {
    ("POST", "/api/v1/cabins"): "the file must be a mesh the loaders read (bytes a schema cannot check)",
    ("POST", "/api/v1/plans"): "a scenario's start, goal and cabin must be admissible (limits, collisions)",
    ("POST", "/api/v1/plans:validate"): "the scenario and the profile must belong together",
    ("POST", "/api/v1/sweeps"): "the base scenario and the expanded plans must be admissible",
    ("POST", "/api/v1/cycles"): "a cycle's units, dock, bay and meshes must be admissible (overlaps)",
    ("POST", "/api/v1/campaigns"): "a campaign's units must be installable (overlaps, docks, stored meshes)",
    ("POST", "/api/v1/robots/pprs6/profiles"): "the pose path must stay in pprs6's workspace",
    ("POST", "/api/v1/robots/pprs6/scene"): "the pose path must stay in pprs6's workspace",
    ("POST", "/api/v1/kinematics/fk"): "the mechanism must assemble",
    ("POST", "/api/v1/kinematics/ik"): "the pose must be in reach",
    ("POST", "/api/v1/stiffness"): "the mechanism must assemble within its limits",
}
#: What a refusal of a body's shape says (pydantic's and the planner's wording): the kinematics and stiffness
#: tools' schemas are exact, so none of these may refuse a schema-valid body there.
SHAPE_REFUSALS = (
    "unknown field",
    "required field is missing",
    "unknown name",
    "missing [",
    "should be a valid",
    "Extra inputs",
    "give exactly one",
)
#: Value constraints a JSON schema cannot state (a unit quaternion's norm within 1e-3 of 1): the refusal
#: names the value, though a union's parse lists its other branches' shape errors beside it.
VALUE_REFUSALS = ("quaternion norm",)
#: The pprs6 tools compute for seconds a call (workspace searches): their examples only, no coverage or
#: fuzzing phase (the rest of the suite fuzzes them: tests/api/test_fuzz.py).
HEAVY_TAG = "pprs6"
#: Bodies whose coverage phase alone is 200-1 500 requests (every boundary of every field of a scenario,
#: a sweep, a stiffness request): fuzzed (examples and random bodies), not enumerated, to keep the run
#: to a few hundred requests. Their fields' bounds are pydantic's own (tests/test_scenario.py and
#: tests/api/test_routes.py check the refusals).
LARGE_BODIES = (
    ("POST", "/api/v1/plans"),
    ("POST", "/api/v1/sweeps"),
    ("POST", "/api/v1/cycles"),
    ("POST", "/api/v1/campaigns"),
    ("POST", "/api/v1/stiffness"),
    ("POST", "/api/v1/kinematics/fk"),
    ("POST", "/api/v1/kinematics/ik"),
)
PHYSICS_OPERATIONS = frozenset(
    {"POST /api/v1/kinematics/fk", "POST /api/v1/kinematics/ik", "POST /api/v1/stiffness"}
)


@schemathesis.check
def physics_refusal(ctx: Any, response: Any, case: schemathesis.Case) -> bool | None:
    """A kinematics or stiffness tool refuses schema-valid data only for a physical reason."""
    label = f"{case.method.upper()} {case.operation.path}"
    positive = case.meta is not None and case.meta.generation.mode.is_positive
    if label in PHYSICS_OPERATIONS and positive and response.status_code == 422:
        problem = response.json()
        said = " ".join(
            [str(problem.get("detail", ""))] + [str(e.get("reason")) for e in problem.get("errors", [])]
        )
        shape = [p for p in SHAPE_REFUSALS if p in said and not any(v in said for v in VALUE_REFUSALS)]
        assert not shape, f"{label}: a schema-valid body refused for its shape: {said}"
    return None


def _config(key: str) -> SchemathesisConfig:
    operations = [
        {
            "include-method": method,
            "include-path": path,
            "checks": {
                "positive_data_acceptance": {
                    "expected-statuses": ["2xx", "401", "403", "404", "409", "422", "429"]
                }
            },
        }
        for (method, path) in SEMANTIC_422
    ]
    operations.append(
        {"include-tag": HEAVY_TAG, "phases": {"coverage": {"enabled": False}, "fuzzing": {"enabled": False}}}
    )
    for method, path in LARGE_BODIES:
        operations.append(
            {"include-method": method, "include-path": path, "phases": {"coverage": {"enabled": False}}}
        )
    config = SchemathesisConfig.from_dict(
        {
            "seed": 1,
            "headers": {"X-API-Key": key},
            "generation": {"max-examples": 5, "deterministic": True},
            "phases": {
                "stateful": {"enabled": False},
                "coverage": {"unexpected-methods": ["OPTIONS", "PATCH"]},
            },
            "operations": operations,
        }
    )
    config.projects.override.checks.update(included_check_names=["all"])
    return config


def test_the_openapi_document_says_exactly_what_the_server_accepts_and_answers(tmp_path: Path) -> None:
    app = create_app(make_settings(tmp_path, max_upload_bytes=64 * 1024), runner=IdleRunner())
    with TestClient(app):
        key = create_key(app.state.ctx, "alpha", "contract")[1]
        schema = schemathesis.openapi.from_asgi("/openapi.json", app, config=_config(key))
        cases, failures, errors = 0, [], []
        for event in from_schema(schema).execute():
            if isinstance(event, events.ScenarioFinished):
                cases += len(event.recorder.cases)
                for checks in event.recorder.checks.values():
                    for check in checks:
                        if check.status == Status.FAILURE and check.failure_info is not None:
                            failure = check.failure_info.failure
                            failures.append(
                                f"{event.recorder.label}: {check.name}: {failure.title}\n"
                                f"{failure.message}\n{check.failure_info.code_sample[:600]}"
                            )
            elif isinstance(event, events.NonFatalError):  # pragma: no cover - the run could not test
                errors.append(str(event.info)[:600])
    print(f"schemathesis: {cases} cases, {len(failures)} failures")  # noqa: T201 - the figure the README cites
    assert cases >= 250, cases  # every operation reached, not a run that stopped early
    assert not errors, errors
    assert not failures, "\n\n".join(sorted(set(failures)))

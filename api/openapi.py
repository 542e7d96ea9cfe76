"""The OpenAPI document: the scenario schema published, every problem status documented.

FastAPI's generated document is completed once, when first asked for:

* ``components.schemas.Scenario`` (and its parts, prefixed ``scenario.``) is the pydantic model of
  :class:`planner.scenario.Scenario`, the body of ``POST /plans`` in ``application/json`` and
  ``application/yaml``;
* ``components.schemas.Cycle`` and ``components.schemas.Campaign`` (parts prefixed ``cycle.`` and
  ``campaign.``): the bodies of ``POST /cycles`` and ``POST /campaigns``
  (:class:`planner.task.schema.Cycle`, :class:`planner.task.campaign_schema.Campaign`);
* ``components.schemas.Problem`` is the RFC 9457 body of every error; each operation lists the statuses
  it can answer with, all as ``application/problem+json``: 422 always (replacing FastAPI's
  ``application/json`` validation error), 401 and 429 (rate limit) when it takes an API key, 404 when
  its path has a parameter, 400/408/413/415 when it takes a body, 500 always.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from api.problems import PROBLEM_JSON, PROBLEM_SCHEMA, problem_responses
from planner.scenario import Scenario

#: Media types a scenario body may have (``POST /plans``).
SCENARIO_MEDIA_TYPES = ("application/json", "application/yaml")
#: Component-name prefix of the scenario's nested models.
SCENARIO_PREFIX = "scenario."


def scenario_schemas() -> dict[str, Any]:
    """``{name: schema}`` of the scenario model and its nested models, for ``components.schemas``."""
    schema = Scenario.model_json_schema(ref_template=f"#/components/schemas/{SCENARIO_PREFIX}{{model}}")
    defs = schema.pop("$defs", {})
    out = {f"{SCENARIO_PREFIX}{name}": value for name, value in defs.items()}
    out["Scenario"] = schema
    return out


def model_schemas(model: Any, name: str, prefix: str) -> dict[str, Any]:
    """``{name: schema}`` of a pydantic model and its nested models (``prefix`` + their names)."""
    schema = model.model_json_schema(ref_template=f"#/components/schemas/{prefix}{{model}}")
    defs = schema.pop("$defs", {})
    out = {f"{prefix}{key}": value for key, value in defs.items()}
    out[name] = schema
    return out


def task_schemas() -> dict[str, Any]:
    """The cycle and campaign documents' schemas (``Cycle``, ``Campaign`` and their parts)."""
    from planner.task.campaign_schema import Campaign
    from planner.task.schema import Cycle

    return {**model_schemas(Cycle, "Cycle", "cycle."), **model_schemas(Campaign, "Campaign", "campaign.")}


def scenario_request_body(description: str, example: dict[str, Any] | None = None) -> dict[str, Any]:
    """``requestBody`` of an operation whose body is a scenario (JSON or YAML)."""
    ref = {"$ref": "#/components/schemas/Scenario"}
    content: dict[str, Any] = {}
    for media in SCENARIO_MEDIA_TYPES:
        content[media] = {"schema": ref}
        if example is not None:
            content[media]["example"] = example
    return {"required": True, "description": description, "content": content}


def _complete(op: dict[str, Any], path: str) -> None:
    responses: dict[str, Any] = op.setdefault("responses", {})
    wanted = [422, 500]
    if op.get("security"):
        wanted += [401, 429]
    if "{" in path:
        wanted.append(404)
    if "requestBody" in op:
        wanted += [400, 408, 413, 415]
    for status, entry in problem_responses(*wanted).items():
        key = str(status)
        if key == "422" or key not in responses:
            responses[key] = entry
    for key, entry in responses.items():
        if key.startswith(("4", "5")):  # every error is a problem document
            entry["content"] = {PROBLEM_JSON: {"schema": {"$ref": "#/components/schemas/Problem"}}}


def install_openapi(app: FastAPI) -> None:
    """Replace ``app.openapi`` by the completed document (built once, then cached)."""

    def build() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        doc = get_openapi(
            title=app.title, version=app.version, description=app.description, routes=app.routes
        )
        schemas = doc.setdefault("components", {}).setdefault("schemas", {})
        schemas.update(scenario_schemas())
        schemas.update(task_schemas())
        schemas["Problem"] = PROBLEM_SCHEMA
        for name in ("HTTPValidationError", "ValidationError"):
            schemas.pop(name, None)
        for path, item in doc.get("paths", {}).items():
            for method, op in item.items():
                if method in ("get", "post", "put", "patch", "delete"):
                    _complete(op, path)
        app.openapi_schema = doc
        return doc

    app.openapi = build  # type: ignore[method-assign]


__all__ = [
    "SCENARIO_MEDIA_TYPES",
    "install_openapi",
    "model_schemas",
    "scenario_request_body",
    "scenario_schemas",
    "task_schemas",
]

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

from collections.abc import Callable, Sequence
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


#: Component-name prefix of the sweep description's nested models.
SWEEP_PREFIX = "sweep."
#: Operation key naming the component that is the JSON body's exact schema (see :func:`_complete`).
BODY_SCHEMA_KEY = "x-cabinplan-body-schema"


def sweep_schemas() -> dict[str, Any]:
    """``{name: schema}`` of the service's sweep description (``POST /sweeps``), for ``components``.

    The CLI's :class:`~planner.sweep.spec.SweepSpec` as the service takes it: ``base`` is the scenario
    inline (the service reads no files), ``bays.manifest`` is absent (bays come from the reference
    cabins' manifest), ``axes`` and ``plans`` are not both given (``axes`` may be empty with ``plans``).
    """
    from planner.sweep.spec import SweepSpec

    schema = SweepSpec.model_json_schema(ref_template=f"#/components/schemas/{SWEEP_PREFIX}{{model}}")
    defs = schema.pop("$defs", {})
    schema["properties"]["base"] = {
        "$ref": "#/components/schemas/Scenario",
        "description": "The base scenario, inline.",
    }
    bays = defs["BaySource"]
    bays["properties"].pop("manifest", None)
    schema["allOf"] = [
        {
            "if": {"required": ["plans"], "properties": {"plans": {"type": "array"}}},
            "then": {"properties": {"axes": {"maxProperties": 0}}},
        }
    ]
    out = {f"{SWEEP_PREFIX}{name}": value for name, value in defs.items()}
    out["Sweep"] = schema
    return out


def scenario_request_body(description: str, example: dict[str, Any] | None = None) -> dict[str, Any]:
    """``requestBody`` of an operation whose body is a scenario (JSON or YAML)."""
    ref = {"$ref": "#/components/schemas/Scenario"}
    content: dict[str, Any] = {}
    for media in SCENARIO_MEDIA_TYPES:
        content[media] = {"schema": ref}
        if example is not None:
            content[media]["example"] = example
    return {"required": True, "description": description, "content": content}


def drive_map_schema(names: Sequence[str], lower: Any = None, upper: Any = None) -> dict[str, Any]:
    """Schema of a map naming every one of ``names`` once (numbers; in ``[lower, upper]`` when given).

    ``lower`` and ``upper``: sequences (arrays) of the bounds of each name, in order.
    """
    props: dict[str, Any] = {}
    for k, name in enumerate(names):
        prop: dict[str, Any] = {"type": "number"}
        if lower is not None and upper is not None:
            prop.update(minimum=float(lower[k]), maximum=float(upper[k]))
        props[name] = prop
    return {"type": "object", "properties": props, "required": list(names), "additionalProperties": False}


def exact_variants(
    variants: Callable[[dict[str, Any]], list[dict[str, Any]]],
) -> Callable[[dict[str, Any]], None]:
    """A pydantic ``json_schema_extra`` that publishes a model's body as ``oneOf`` its exact variants.

    A request model that takes several shapes (one robot's drive names or another's, ``drives`` or
    ``joints``) parses them with one permissive model and checks the rest in the planner, naming the
    field; its generated schema would then promise more than the server accepts. ``variants(properties)``
    builds the exact shapes from the generated property schemas (their ``$ref`` to nested models kept);
    each variant lists only its own properties (``additionalProperties: false``), so exactly one
    matches any body the server accepts.
    """

    def replace(schema: dict[str, Any]) -> None:
        properties = dict(schema.get("properties", {}))
        keep: dict[str, Any] = {k: schema[k] for k in ("title", "description", "$defs") if k in schema}
        schema.clear()
        schema.update(keep)
        schema["oneOf"] = variants(properties)

    return replace


def _complete(op: dict[str, Any], path: str) -> None:
    exact = op.pop(BODY_SCHEMA_KEY, None)
    if exact is not None:  # the body is parsed as a mapping; its published schema is the exact one
        media = op["requestBody"]["content"]["application/json"]
        examples = media["schema"].get("examples")
        media["schema"] = {"$ref": f"#/components/schemas/{exact}"}
        if examples:
            media["example"] = examples[0]
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
        schemas.update(sweep_schemas())
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
    "BODY_SCHEMA_KEY",
    "SCENARIO_MEDIA_TYPES",
    "drive_map_schema",
    "exact_variants",
    "install_openapi",
    "model_schemas",
    "scenario_request_body",
    "scenario_schemas",
    "sweep_schemas",
    "task_schemas",
]

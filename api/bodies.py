"""Request bodies of scenarios: JSON or YAML (the CLI's formats), parsed safely.

``POST /plans`` takes ``application/json`` or ``application/yaml`` (also ``application/x-yaml``,
``text/yaml``); a missing Content-Type is read as JSON. YAML is read with the scenario loader of the
CLI (safe, duplicate keys refused, ``1e-3`` read as a number) and refuses anchors and aliases: a
scenario needs none, and aliases would let a small body expand into an exponentially large document.
A body that cannot be parsed is 400 ``malformed_body``; another Content-Type is 415.
"""

from __future__ import annotations

import json
from typing import Any

import yaml

from api.problems import Problem, malformed_body
from planner.scenario.files import ScenarioYamlLoader, unique_json_object  # the CLI's parsers, reused

YAML_MEDIA_TYPES = ("application/yaml", "application/x-yaml", "text/yaml", "text/x-yaml")
JSON_MEDIA_TYPES = ("application/json",)


def _refuse_aliases(text: str) -> None:
    """Raise a YAML error at the first alias of ``text`` (events only: libyaml's parser, nothing built)."""
    for event in yaml.parse(text, Loader=ScenarioYamlLoader):
        if isinstance(event, yaml.AliasEvent):
            mark = event.start_mark  # libyaml's Mark: the same line and column as PyYAML's
            raise yaml.composer.ComposerError(
                None,
                None,
                "aliases are not accepted in a scenario body",
                mark,  # type: ignore[arg-type]
            )


def media_type(content_type: str | None) -> str:
    """The bare media type of a Content-Type header, lower case (``""`` when absent)."""
    return (content_type or "").split(";", 1)[0].strip().lower()


def parse_body(raw: bytes, content_type: str | None) -> Any:
    """The parsed document of a JSON or YAML request body.

    Raises:
        Problem: 400 ``malformed_body`` (not UTF-8, a syntax error with its position, a duplicate key,
            an alias), 415 ``unsupported_media_type`` (another Content-Type).
    """
    media = media_type(content_type)
    is_yaml = media in YAML_MEDIA_TYPES
    if not is_yaml and media not in ("", *JSON_MEDIA_TYPES) and not media.endswith("+json"):
        raise Problem(
            415,
            "unsupported_media_type",
            f"Content-Type {media!r}: send application/json or application/yaml",
            errors=[{"field": "Content-Type", "reason": "unsupported media type"}],
        )
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise malformed_body(f"request body: not UTF-8 text (invalid byte at offset {exc.start})") from None
    try:
        if is_yaml:
            _refuse_aliases(text)
            return yaml.load(text, Loader=ScenarioYamlLoader)  # a safe loader
        return json.loads(text, object_pairs_hook=unique_json_object)
    except json.JSONDecodeError as exc:
        raise malformed_body(
            f"request body: invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        why = " ".join(str(exc.problem or exc.context or "syntax error").split())
        raise malformed_body(f"request body: invalid YAML{where}: {why}") from None
    except yaml.YAMLError as exc:
        raise malformed_body(f"request body: invalid YAML: {' '.join(str(exc).split())}") from None
    except RecursionError:
        raise malformed_body("request body: the document is nested too deeply") from None
    except ValueError as exc:  # a duplicate JSON key
        raise malformed_body(f"request body: invalid JSON: {exc}") from None


__all__ = ["JSON_MEDIA_TYPES", "YAML_MEDIA_TYPES", "media_type", "parse_body"]

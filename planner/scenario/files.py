"""Scenario files: YAML or JSON, at most 1 MiB, read safely into a validated scenario.

Duplicate keys and YAML tags are refused; the content goes through
:func:`~planner.scenario.schema.scenario_from_dict`.
"""

from __future__ import annotations

import json
import logging
import re
import stat
from collections.abc import Hashable
from pathlib import Path
from typing import Any

import yaml

from planner.core.exceptions import InvalidInput
from planner.scenario.schema import Scenario, scenario_from_dict

log = logging.getLogger(__name__)


#: Largest accepted scenario file [bytes] (1 MiB), checked before the file is read.
MAX_SCENARIO_BYTES = 1 << 20

#: File extensions :func:`load_scenario_file` accepts (lower case, with the dot).
SCENARIO_EXTENSIONS: tuple[str, ...] = (".yaml", ".yml", ".json")


#: libyaml's parser where PyYAML was built with it (the wheels are): 6-7x faster than the pure-Python one
#: on a scenario-sized document; the constructor and resolver (duplicate keys, floats) stay Python's.
_SAFE_LOADER: type[yaml.SafeLoader] = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class ScenarioYamlLoader(_SAFE_LOADER):  # type: ignore[valid-type,misc]
    """Safe YAML loader that refuses duplicate keys and reads YAML 1.2 floats such as ``1e-3``."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Hashable, Any]:  # noqa: D102
        seen: set[Any] = set()
        for key_node, _ in node.value:
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=False)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    "while constructing a mapping",
                    node.start_mark,
                    f"found duplicate key {key!r}",
                    key_node.start_mark,
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


# PyYAML implements YAML 1.1, where 1e-3 (no dot) is a string; accept it as the number users mean.
ScenarioYamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def unique_json_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json`` object hook that refuses a key given twice (the last would silently win)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}")
        out[key] = value
    return out


def load_scenario_file(path: Path) -> Scenario:
    """Read and validate a scenario file (``.yaml``/``.yml`` or ``.json``, at most 1 MiB).

    Relative mesh paths in the scenario refer to the file's folder: pass ``path.parent`` as ``base_dir``
    to :func:`resolve_scenario` (or use :func:`load_scenario`).

    Args:
        path: The scenario file.

    Returns:
        The validated scenario.

    Raises:
        InvalidInput: wrong extension, missing/unreadable/oversized file, not UTF-8, a syntax error (the
            message gives line and column) or a duplicate key, or a schema violation (see
            :func:`scenario_from_dict`). ``details['field']`` is ``"scenario"`` for file-level problems.
    """
    path = Path(path)
    return scenario_from_dict(read_document(path), source=str(path))


def read_document(path: Path, what: str = "scenario") -> object:
    """The parsed content of a YAML or JSON input file (a scenario, a sweep description), not yet validated.

    Args:
        path: The file (``.yaml``/``.yml`` or ``.json``, at most 1 MiB, UTF-8).
        what: What the file holds: the prefix of every message and ``details['field']``.

    Raises:
        InvalidInput: wrong extension, missing/unreadable/oversized file, not UTF-8, a syntax error (the
            message gives line and column) or a duplicate key.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in SCENARIO_EXTENSIONS:
        raise InvalidInput(
            f"{what}: unsupported file extension {ext or '(none)'!r} of {path.name!r}; "
            f"expected one of {', '.join(SCENARIO_EXTENSIONS)}",
            field=what,
            file=str(path),
        )
    text = read_text(path, what)
    try:
        if ext == ".json":
            return json.loads(text, object_pairs_hook=unique_json_object)
        return yaml.load(text, Loader=ScenarioYamlLoader)  # a safe loader
    except json.JSONDecodeError as exc:
        why = f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        raise _file_error(path, why, what) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        why = " ".join(str(exc.problem or exc.context or "syntax error").split())
        raise _file_error(path, f"invalid YAML{where}: {why}", what) from None
    except yaml.YAMLError as exc:
        raise _file_error(path, f"invalid YAML: {' '.join(str(exc).split())}", what) from None
    except RecursionError:
        raise _file_error(path, "the document is nested too deeply", what) from None
    except ValueError as exc:  # duplicate JSON key
        raise _file_error(path, f"invalid JSON: {exc}", what) from None


def _file_error(path: Path, why: str, what: str = "scenario") -> InvalidInput:
    return InvalidInput(f"{what}: {path.name}: {why}", field=what, file=str(path))


def read_text(path: Path, what: str = "scenario") -> str:
    """The file's text (UTF-8), refusing missing, non-regular and oversized files before reading.

    ``what`` (the file's kind) prefixes the messages and is ``details['field']``.
    """
    try:
        info = path.stat()
    except FileNotFoundError:
        raise _file_error(path, f"file not found ({path})", what) from None
    except OSError as exc:
        raise _file_error(path, f"cannot read the file: {exc.strerror or exc}", what) from None
    if not stat.S_ISREG(info.st_mode):
        raise _file_error(path, "not a regular file", what)
    if info.st_size > MAX_SCENARIO_BYTES:
        cap = f"{info.st_size} bytes exceeds the {what} size cap of {MAX_SCENARIO_BYTES} bytes (1 MiB)"
        raise _file_error(path, cap, what)
    try:
        with path.open("rb") as fh:
            raw = fh.read(MAX_SCENARIO_BYTES + 1)
    except OSError as exc:
        raise _file_error(path, f"cannot read the file: {exc.strerror or exc}", what) from None
    if len(raw) > MAX_SCENARIO_BYTES:  # the file grew between stat and read
        raise _file_error(path, f"more than {MAX_SCENARIO_BYTES} bytes (1 MiB)", what)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise _file_error(path, f"not UTF-8 text (invalid byte at offset {exc.start})", what) from None

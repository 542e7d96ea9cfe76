"""What blocks a refused cycle: the installed units its refusal's evidence names, with their figures.

A cycle's refusal document carries the planner's evidence (``details``): records of the bodies furthest
short of their required distance (``{"cause": "clearance", "bodies": [body, other], "distance_m",
"required_m", "where"}``, :func:`planner.plan.goals.collision_evidence`), contacts of a state
(``{"kind", "bodies", "detail"}``) and messages. Installed units are obstacles of the collision world named
``"unit <id>"`` (:mod:`planner.collision.obstacles`), so the units that block a cycle are read from those
records: no second planner run, no guess.

Pure functions over plain JSON data (the refusal's ``details`` and message).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

__all__ = ["UNIT_PREFIX", "Mention", "mentions", "nearest", "obstacle_name", "unit_of"]

#: How the collision world names an installed unit: ``"unit <id>"``.
UNIT_PREFIX = "unit "
_UNIT_RE = re.compile(r"\bunit ([A-Za-z0-9._-]+)")


def obstacle_name(unit_id: str) -> str:
    """The collision world's name of an installed unit."""
    return f"{UNIT_PREFIX}{unit_id}"


def unit_of(name: str) -> str | None:
    """The unit id of an obstacle name (``"unit B3"`` -> ``"B3"``), or None for any other body."""
    return name[len(UNIT_PREFIX) :] if name.startswith(UNIT_PREFIX) else None


@dataclass(frozen=True)
class Mention:
    """One installed unit named by a refusal's evidence.

    Attributes:
        unit: The unit's id.
        body: The robot body (or ``payload``) it is measured against, when the record names one.
        distance_m: The exact distance of that record [m] (<= 0: contact), when it has one.
        required_m: The distance the planner required there [m], when the record has one.
        where: Where the record was found (its ``where``: ``"at the goal"``), when it says.
        leg: The cycle's leg it was found in (the nearest enclosing ``leg``), when known.
    """

    unit: str
    body: str | None = None
    distance_m: float | None = None
    required_m: float | None = None
    where: str | None = None
    leg: str | None = None


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and math.isfinite(float(value)) else None


def _walk(node: Any, leg: str | None, out: list[Mention], units: frozenset[str]) -> None:
    if isinstance(node, dict):
        leg = str(node["leg"]) if isinstance(node.get("leg"), str) else leg
        where = str(node["where"]) if isinstance(node.get("where"), str) else None
        bodies = node.get("bodies")
        if isinstance(bodies, list) and all(isinstance(b, str) for b in bodies):
            for k, name in enumerate(bodies):
                unit = unit_of(name)
                if unit is None or unit not in units:
                    continue
                others = [b for j, b in enumerate(bodies) if j != k]
                out.append(
                    Mention(
                        unit,
                        others[0] if others else None,
                        _number(node.get("distance_m")),
                        _number(node.get("required_m")),
                        where,
                        leg,
                    )
                )
        for key, value in node.items():
            if key != "bodies":
                _walk(value, leg, out, units)
    elif isinstance(node, list):
        for value in node:
            _walk(value, leg, out, units)
    elif isinstance(node, str):
        for unit in _UNIT_RE.findall(node):
            if unit in units:
                out.append(Mention(unit, leg=leg))


def mentions(
    details: Any, message: str | None, installed: Iterable[str], leg: str | None = None
) -> list[Mention]:
    """Every mention of an installed unit in a refusal's evidence (records first, then message text).

    Args:
        details: The refusal's ``details`` (any JSON value).
        message: The refusal's message (units named in its text count too).
        installed: Ids of the units installed when the cycle was planned (only these can block it).
        leg: The leg the refusal names at its top level, if the details do not carry it.
    """
    units = frozenset(installed)
    out: list[Mention] = []
    _walk(details, leg, out, units)
    if message:
        _walk(message, leg, out, units)
    return out


def nearest(found: list[Mention]) -> dict[str, Mention]:
    """Per unit, its most telling mention: the smallest distance, else the first with a body or place."""

    def rank(m: Mention) -> tuple[float, int]:
        return (
            m.distance_m if m.distance_m is not None else math.inf,
            0 if m.body or m.where or m.leg else 1,
        )

    out: dict[str, Mention] = {}
    for m in found:
        if m.unit not in out or rank(m) < rank(out[m.unit]):
            out[m.unit] = m
    return out

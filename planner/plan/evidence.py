"""The evidence of a refusal: what blocks a configuration (bodies and distances, a drive's force, a limit).

Each record is a dict ``{"cause": "clearance" | "force" | "limit", "where", ...the figures..., "q"}``
(:func:`collision_evidence`, :func:`force_evidence`, :func:`limit_evidence`); :func:`describe` makes one
readable line of it and :func:`dominant` picks the record closest to passing, which the refusals of the goal
stage (:mod:`planner.plan.targets`) and of the compensation (:mod:`planner.plan.compensate`) name.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from planner.collision.world import CollisionWorld
from planner.core.types import Array
from planner.dynamics.holding import StaticForceCheck


def collision_evidence(
    world: CollisionWorld, q: Array, required_m: float, where: str, margin_m: float = 0.0
) -> dict[str, Any]:
    """What blocks configuration q: the bodies furthest short of their required distance, with figures.

    A body and the cabin must keep ``required_m`` + ``margin_m`` (``required_m``: the clearance the
    planner certifies there, the requested clearance and its slack; ``margin_m``: for a motion, the
    certified walk's smallest margin); a pair of robot bodies the world's self-clearance + ``margin_m``.
    The record is that of the kind with the smaller spare distance (exact FCL distances), so a robot pair
    that passes never hides a cabin distance that fails, nor the other way round.
    """
    cabin_required = float(required_m) + margin_m
    pair_required = world.self_clearance + margin_m
    closest = world.min_distance(q)  # the smallest distance of either kind
    if world.is_environment(closest.bodies[1]):
        records = [(closest, cabin_required)]
        # Every pair is at least that far: it can be further short only of a larger requirement.
        if pair_required > cabin_required:
            records.append((world.min_distance(q, include_cabin=False), pair_required))
    else:
        records = [(closest, pair_required)]
        if world.cabin is not None or world.obstacles is not None:
            records.append((world.min_distance(q, include_self=False), cabin_required))
    d, required = min(records, key=lambda r: r[0].distance_m - r[1])
    return {
        "cause": "clearance",
        "where": where,
        "bodies": list(d.bodies),
        "distance_m": float(d.distance_m),
        "required_m": float(required),
        "q": [float(v) for v in q],
    }


def force_evidence(forces: StaticForceCheck, q: Array, where: str) -> dict[str, Any]:
    """The drive that cannot hold the payload at q, and its static force as a fraction of its limit."""
    tau = forces.dynamics.static_forces_batch(np.atleast_2d(q), forces.payload)[0]
    ratios = np.abs(tau) / forces.dynamics.robot.limits.effort_max
    j = int(np.argmax(ratios))
    return {
        "cause": "force",
        "where": where,
        "drive": forces.dynamics.robot.drive_names[j],
        "force_ratio": float(ratios[j]),
        "allowed_ratio": float(forces.fraction),
        "q": [float(v) for v in q],
    }


def limit_evidence(violations: list[dict[str, Any]], q: Array, where: str) -> dict[str, Any]:
    """The limit or margin configuration q is furthest outside (of ``robot.violations(q)``), and by how much.

    ``excess`` is the distance outside the bound in the limit's own unit (m or rad; None for a value that
    is not finite), ``span`` the width of the admissible range (for ranking records of different limits).
    """

    def excess(v: dict[str, Any]) -> float:
        value, lo, hi = v["value"], v["lower"], v["upper"]
        if not isinstance(value, float) or lo is None or hi is None or not np.isfinite(value):
            return float("inf")
        return float(max(lo - value, value - hi))

    worst = max(violations, key=lambda v: excess(v) / _span(v))
    over = excess(worst)
    return {
        "cause": "limit",
        "where": where,
        "limit": worst["name"],
        "value": worst["value"],
        "lower": worst["lower"],
        "upper": worst["upper"],
        "excess": over if np.isfinite(over) else None,
        "span": _span(worst),
        "q": [float(v) for v in q],
    }


def _span(v: dict[str, Any]) -> float:
    lo, hi = v["lower"], v["upper"]
    if lo is None or hi is None or not np.isfinite(hi - lo) or hi <= lo:
        return 1.0
    return float(hi - lo)


def describe(evidence: dict[str, Any]) -> str:
    """One readable line of an evidence record.

    The records of :func:`collision_evidence`, :func:`force_evidence` and :func:`limit_evidence`.
    """
    if evidence["cause"] == "limit":
        if evidence["excess"] is None:
            return f"{evidence['limit']} is not finite {evidence['where']}"
        return (
            f"{evidence['limit']} = {evidence['value']:.4g} outside [{evidence['lower']:.4g}, "
            f"{evidence['upper']:.4g}] by {evidence['excess']:.3g} {evidence['where']}"
        )
    if evidence["cause"] == "force":
        return (
            f"{evidence['drive']} needs {100 * evidence['force_ratio']:.0f}% of its force limit "
            f"{evidence['where']} ({100 * evidence['allowed_ratio']:.0f}% allowed)"
        )
    a, b = evidence["bodies"]
    other = "the cabin" if b == "cabin" else b
    if evidence["distance_m"] <= 0.0:  # FCL reports penetration as a distance <= 0
        return (
            f"{a} in contact with {other} {evidence['where']}, {1e3 * evidence['required_m']:.1f} mm required"
        )
    distance_mm, required_mm = 1e3 * evidence["distance_m"], 1e3 * evidence["required_m"]
    digits = 1
    while digits < 4 and f"{distance_mm:.{digits}f}" == f"{required_mm:.{digits}f}":
        digits += 1  # as many decimals as it takes to tell the two apart
    return (
        f"{a} {distance_mm:.{digits}f} mm from {other} {evidence['where']}, "
        f"{required_mm:.{digits}f} mm required"
    )


def dominant(evidence: list[dict[str, Any]], cause: str | None = None) -> dict[str, Any] | None:
    """The record closest to passing (of ``cause`` only, when given): the smallest relative shortfall."""
    evidence = [e for e in evidence if cause is None or e["cause"] == cause]

    def shortfall(e: dict[str, Any]) -> float:
        if e["cause"] == "force":
            return e["force_ratio"] / e["allowed_ratio"] - 1.0
        if e["cause"] == "limit":
            return math.inf if e["excess"] is None else e["excess"] / e["span"]
        return (e["required_m"] - e["distance_m"]) / max(e["required_m"], 1e-6)

    return min(evidence, key=shortfall) if evidence else None

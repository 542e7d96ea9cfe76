"""The evidence of a refusal: what blocks a configuration (bodies and distances, a drive's force, a limit).

Each record is a dict ``{"cause": "clearance" | "force" | "limit", "where", ...the figures..., "q"}``
(:func:`collision_evidence`, :func:`force_evidence`, :func:`limit_evidence`); :func:`describe` makes one
readable line of it and :func:`dominant` picks the record closest to passing, which the refusals of the goal
stage (:mod:`planner.plan.targets`) and of the compensation (:mod:`planner.plan.compensate`) name.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.collision.world import CollisionWorld
from planner.core.types import Array
from planner.dynamics.holding import StaticForceCheck
from planner.plan.motion import MIN_MARGIN_M, AdaptiveMotion


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


def state_evidence(
    world: CollisionWorld,
    q: Array,
    required_m: float,
    where: str,
    forces: StaticForceCheck | None = None,
    margin_m: float = 0.0,
) -> dict[str, Any] | None:
    """Why configuration q fails a planner state check: the measurement that fails, never one that passes.

    A state check (:meth:`CollisionWorld.is_valid` and, with ``forces``, the static hold) fails on a limit
    or margin of the mechanism, on a distance short of its requirement, or on a drive that cannot hold the
    load; the record is the first of those that fails at q, in that order: :func:`limit_evidence` (the
    limit furthest outside), :func:`collision_evidence` only when its distance is below its requirement
    (``required_m`` + ``margin_m`` for the cabin and obstacles), :func:`force_evidence`. None when every
    one passes at q (nothing true to report there).
    """
    violations = world.robot.violations(q)
    if violations:
        return limit_evidence(violations, q, where)
    ev = collision_evidence(world, q, required_m, where, margin_m)
    if ev["distance_m"] < ev["required_m"]:
        return ev
    if forces is not None and not forces.ok(q):
        return force_evidence(forces, q, where)
    return None


def motion_evidence(
    world: CollisionWorld,
    q_a: Array,
    q_b: Array,
    motion: AdaptiveMotion,
    required_m: float,
    where: Callable[[float], str],
) -> dict[str, Any] | None:
    """Why the certified motion q_a -> q_b (the refused ``motion`` of :func:`certify_motion`) failed.

    At the walk's failing fraction t (q = q_a + t (q_b - q_a)): a limit or margin contact gives
    :func:`limit_evidence` there; a clearance failure the bodies short of ``required_m`` + the adaptive
    walk's smallest margin (:data:`MIN_MARGIN_M`: the walk halves its margin down to it before it refuses a
    state), the requirement the walk failed on. Only a failing measurement is returned: None when the walk
    gives no failing state or the state measures clear (``where(t)`` names the place).
    """
    rep = motion.report
    if rep.valid or rep.t_fail is None:
        return None
    t = float(rep.t_fail)
    q_at = np.asarray(q_a, dtype=float) + t * (np.asarray(q_b, dtype=float) - q_a)
    if any(c.kind == "limit" for c in rep.contacts):
        violations = world.robot.violations(q_at)
        return limit_evidence(violations, q_at, where(t)) if violations else None
    ev = collision_evidence(world, q_at, required_m, where(t), margin_m=MIN_MARGIN_M)
    return ev if ev["distance_m"] < ev["required_m"] else None


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

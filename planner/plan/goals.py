"""Goal configurations and the straight-line approach, using the two redundant DOF.

For a pose goal the redundancy of cabin8 is the explicit family q(gamma, d5)
(:mod:`planner.kinematics.closed_form`). :func:`goal_configurations` grids that family, keeps the
admissible points, polishes each to an exact solution, and keeps those that are collision-free with the
requested clearance and can hold the payload statically within the drive force limits. Candidates are
ranked by their normalised limit/singularity margin and diversified (distinct (gamma, d5)), so the global
planner gets several good goals to connect to.

With an approach, :func:`track_approach` follows the payload frame backwards along the line from each goal
candidate with the differential IK of :func:`planner.redundancy.ik.track_pose` (posture continuity and
margins as secondary objectives, exact pose at every step), certifies every step with the collision
layer, and the candidate whose line keeps the largest clearance (measured at a few states along it) wins.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.collision.world import CollisionWorld
from planner.core.types import Array
from planner.dynamics.holding import (  # StaticForceCheck: also imported from here by planner.generate
    SEGMENT_STEP,
    StaticForceCheck,
)
from planner.kinematics.closed_form import redundant_family
from planner.plan.evidence import force_evidence, motion_evidence, state_evidence
from planner.plan.motion import certify_motion
from planner.redundancy.ik import (
    IKOptions,
    comfort_margins,
    family_candidates,
    normalised_margin,
    polish_pose,
    track_pose,
)
from planner.robots.cabin8 import Cabin8

log = logging.getLogger(__name__)


#: Most grid points of the redundant family polished into exact goal configurations per pose goal.
MAX_GOAL_POLISH = 24


@dataclass(frozen=True)
class GoalCandidate:
    """A goal configuration (and, with an approach, its tracked line back to the pre-insertion state)."""

    q: Array = field(repr=False)
    min_margin: float
    line: Array | None = field(default=None, repr=False)  # (K, 8) from pre-insertion to goal
    line_s: Array | None = field(default=None, repr=False)  # (K,) distance along the line [m]
    clearance_m: float = float("nan")


def goal_configurations(
    world: CollisionWorld,
    T_base_tool: Array,
    clearance: float,
    forces: StaticForceCheck,
    u_ref: Array,
    max_candidates: int = 6,
    evidence: list[dict[str, Any]] | None = None,
) -> tuple[list[GoalCandidate], dict[str, int]]:
    """Valid, diverse exact IK solutions for a tool pose, best margin first.

    Returns the candidates and counts of why the others were dropped (for a clear refusal); each dropped
    candidate's evidence is appended to ``evidence`` when given.
    """
    robot = world.robot
    opts = IKOptions(grid_gamma=15, grid_d5=15)
    good, _ = family_candidates(robot, T_base_tool, u_ref, 0.3, opts)
    # The grid points already clear (a state check, ~50 us) are polished first, best score first within
    # each group, and the diversity rule keeps the accepted candidates apart only: a rejected one (a grid
    # point whose polished solution touches the cabin) must not hide its neighbours (a shelf goal whose
    # clear postures are the fourth-best grid row, and a bay goal whose one clear posture neighbours a
    # clear grid point that polishes into the cabin, were refused as goal_in_collision that way). At most
    # MAX_GOAL_POLISH points are polished. Within each group, the points that hold the payload where they
    # stand come first (one batched force evaluation): the polish budget spent on best-scored points that
    # cannot hold it hid the four that can (gen-box-section-0-003: 24 polished, all 1.7-3.1 times over
    # x3's limit, and the goal refused as "no configuration reaching it can hold the payload").
    clear = [world.is_valid(cand.q, clearance) for cand in good]
    holds = (forces.ratios(np.array([c.q for c in good])) <= forces.fraction).tolist() if good else []
    ranked = sorted(zip(clear, holds, good, strict=True), key=lambda x: (not x[0], not x[1]))
    good = [cand for _, _, cand in ranked]
    stats = {"family_points": len(good), "not_converged": 0, "collision": 0, "force": 0}
    out: list[GoalCandidate] = []
    used: list[Array] = []
    polished = 0
    for cand in good:
        if len(out) >= max_candidates or polished >= MAX_GOAL_POLISH:
            break
        key = cand.q[[3, 6]]
        if any(np.all(np.abs(key - u) < np.array([0.05, 0.06])) for u in used):
            continue
        polished += 1
        sol = track_pose(robot, cand.q, T_base_tool, cand.q, opts)
        if sol is not None and not world.is_valid(sol.q, clearance) and world.is_valid(cand.q, clearance):
            # The refinement moved a clear family point into the cabin (towards its margins and posture):
            # the point itself, polished where it stands, is an exact solution that keeps the clearance
            # (gen-end-bay-12-004: both clear grid points refined to 10.1 mm, where they keep 15.8 mm).
            sol = polish_pose(robot, cand.q, T_base_tool, opts) or sol
        if sol is None:
            stats["not_converged"] += 1
            continue
        if not world.is_valid(sol.q, clearance):
            stats["collision"] += 1
            if evidence is not None:
                _record(evidence, state_evidence(world, sol.q, clearance, "at the goal"))
            continue
        if not forces.ok(sol.q):
            stats["force"] += 1
            if evidence is not None:
                evidence.append(force_evidence(forces, sol.q, "at the goal"))
            continue
        used.append(key)
        out.append(GoalCandidate(sol.q, normalised_margin(robot, sol.q)))
    out.sort(key=lambda c: -c.min_margin)
    return out, stats


def approach_lines(
    world: CollisionWorld,
    T_base_tool_goal: Array,
    direction: Array,
    distance_m: float,
    clearance: float,
    motion_margin: float,
    forces: StaticForceCheck,
    max_lines: int = 3,
    grid: int = 21,
    evidence: list[dict[str, Any]] | None = None,
    hold: StaticForceCheck | None = None,
) -> tuple[list[GoalCandidate], dict[str, int]]:
    """Straight approach lines with the redundancy fixed along each line, best margin first.

    For a pure translation of the tool pose with fixed orientation, the closed-form family
    q(gamma, d5) keeps theta3, theta4, theta6 (they depend on the orientation only) and shifts (d1, x, y)
    by the translation: with (gamma, d5) held, the line of the payload frame is a *straight segment in
    joint space*. Each (gamma, d5) of a grid is scored by its smallest normalised limit/singularity margin
    over the whole line (vectorised), lines that cannot hold the payload statically are dropped, and the
    best lines, diverse in (gamma, d5), are certified collision-free with the motion check of the
    collision layer. The redundancy is thus chosen once for the whole insertion, exactly (the line is
    followed to rounding error), rather than drifting step by step.

    ``hold``: a static check the goal configuration must also pass (a grasp, where the load is taken at
    the goal: the approach itself is checked with ``forces``). Every admissible grid point is checked
    (vectorised) before any is certified, so a goal that cannot hold never takes a line's place nor hides
    a neighbour that can; ``stats["hold"]`` counts the admissible points that cannot hold. When none can,
    the one closest to holding (smallest largest force ratio) is the only evidence appended (a
    :func:`force_evidence` record "at the goal"): the cause is the load, whatever the clearances.
    """
    robot = world.robot
    ps = robot.desc.parallel_stage
    gammas = np.linspace(-ps.gamma_max, ps.gamma_max, grid)
    d5s = np.linspace(robot.limits.lower[6], robot.limits.upper[6], grid)
    gg, dd = np.meshgrid(gammas, d5s, indexing="ij")
    Q = redundant_family(robot.desc.serial_chain, T_base_tool_goal, gg.ravel(), dd.ravel())
    shift = line_shift(direction, distance_m)
    n_along = 11
    taus = np.linspace(0.0, 1.0, n_along)
    along = Q[None, :, :] + taus[:, None, None] * shift[None, None, :]  # (n_along, K, 8)
    c = robot.constraint_values_batch(along.reshape(-1, 8)).reshape(n_along, len(Q), -1)
    margins = np.minimum(c - robot.c_lower, robot.c_upper - c) / comfort_margins(robot)
    worst = np.min(np.where(np.isnan(margins), -np.inf, margins), axis=(0, 2))
    stats = {"grid_points": len(Q), "admissible": int(np.sum(worst >= 0)), "force": 0, "collision": 0}
    order = [int(i) for i in np.argsort(-worst) if worst[i] >= 0]
    if hold is not None:
        ratios = hold.ratios(Q[order]) if order else np.zeros(0)
        held = ratios <= hold.fraction
        stats["hold"] = int(np.sum(~held))
        if order and not np.any(held) and evidence is not None:
            best = order[int(np.argmin(np.where(np.isnan(ratios), np.inf, ratios)))]
            evidence.append(force_evidence(hold, Q[best], "at the goal"))
        order = [i for i, ok in zip(order, held.tolist(), strict=True) if ok]
    # The static forces along every admissible line at once, before any line is certified: a line that
    # cannot hold never takes a diversity slot, so it cannot hide a neighbour that can (a line 25 mm of
    # arm further out fails on force where the witness between two grid points holds at 87%).
    line_worst = _line_force_ratios(forces, Q[order], shift) if order else np.zeros(0)
    holds = line_worst <= forces.fraction
    stats["force"] = int(np.sum(~holds))
    if order and not np.any(holds) and evidence is not None:
        best = order[int(np.argmin(np.where(np.isnan(line_worst), np.inf, line_worst)))]
        q_goal, q_pre = Q[best], Q[best] + shift
        k_worst = int(np.argmax(forces.ratios(np.linspace(q_pre, q_goal, 11))))
        frac = 1.0 - k_worst / 10.0
        evidence.append(force_evidence(forces, q_pre + (1.0 - frac) * (q_goal - q_pre), _along(frac)))
    order = [i for i, ok in zip(order, holds.tolist(), strict=True) if ok]
    out: list[GoalCandidate] = []
    used: list[Array] = []
    for i in order:
        if len(out) >= max_lines:
            break
        key = Q[i, [3, 6]]
        if any(np.all(np.abs(key - u) < np.array([0.05, 0.06])) for u in used):
            continue
        used.append(key)
        q_goal, q_pre = Q[i], Q[i] + shift
        if not world.is_valid(q_goal, clearance):
            stats["collision"] += 1
            if evidence is not None:
                _record(evidence, state_evidence(world, q_goal, clearance, "at the goal"))
            continue
        motion = certify_motion(world, q_pre, q_goal, clearance, motion_margin)
        if not motion.valid:
            stats["collision"] += 1
            if evidence is not None:
                ev = motion_evidence(world, q_pre, q_goal, motion, clearance, lambda t: _along(1.0 - t))
                _record(evidence, ev)
            continue
        line = np.stack([q_pre, q_goal])
        out.append(GoalCandidate(q_goal, float(worst[i]), line, np.array([0.0, distance_m])))
    return out, stats


def line_shift(direction: Array, distance_m: float) -> Array:
    """The joint change (8,) from a goal configuration to its pre-insertion one, redundancy held.

    With (gamma, d5) fixed, a translation of the tool by ``-distance_m * direction`` (base frame) moves
    only the rail and the platform: d1 by its z part, the platform's x and y by its x and y parts.
    """
    shift = np.zeros(8)
    shift[[0, 1, 2]] = -distance_m * np.array([direction[2], direction[0], direction[1]])
    return shift


def _line_force_ratios(forces: StaticForceCheck, goals: Array, shift: Array) -> Array:
    """The largest static force ratio along each approach line (K,): from ``goals + shift`` to ``goals``.

    The points :meth:`StaticForceCheck.segment_ok` checks on each line (one every :data:`SEGMENT_STEP` of
    the largest joint change), the same arithmetic row by row, all lines' in one batched evaluation: a
    line holds exactly when ``segment_ok(q_pre, q_goal)`` says so.
    """
    q_pre = goals + shift
    dq = goals - q_pre
    steps = np.maximum(1, np.ceil(np.max(np.abs(dq), axis=1) / SEGMENT_STEP)).astype(np.int64)
    worst = np.empty(len(goals))
    for n in np.unique(steps).tolist():  # one group in practice: every line has the same shift
        rows = np.flatnonzero(steps == n)
        t = np.linspace(0.0, 1.0, n + 1)[:, None, None]
        pts = q_pre[None, rows] + t * dq[None, rows]  # (n + 1, k, 8)
        worst[rows] = forces.ratios(pts.reshape(-1, goals.shape[1])).reshape(n + 1, len(rows)).max(axis=0)
    return worst


def _record(evidence: list[dict[str, Any]], record: dict[str, Any] | None) -> None:
    """Append a failing measurement (None: the check failed on nothing that can be measured there)."""
    if record is not None:
        evidence.append(record)


def _along(remaining: float) -> str:
    """Where on the insertion line: the goal, or how far before it (fraction of the line)."""
    if remaining <= 1e-9:
        return "at the goal"
    if remaining >= 1.0 - 1e-9:
        return "at the start of the insertion line"
    return f"{100 * remaining:.0f}% of the insertion line before the goal"


def track_approach(
    world: CollisionWorld,
    goal: GoalCandidate,
    T_base_tool_goal: Array,
    direction: Array,
    distance_m: float,
    step_m: float,
    clearance: float,
    motion_margin: float,
    forces: StaticForceCheck,
    cancelled: Callable[[], bool] = lambda: False,
    evidence: list[dict[str, Any]] | None = None,
) -> GoalCandidate | None:
    """Track the straight approach backwards from the goal; None if any step fails.

    The tool moves along ``-direction`` with fixed orientation; the payload frame moves the same way
    (it is rigidly attached). Every step is an exact IK solution seeded by the previous one, admissible,
    collision-free with ``clearance`` (certified motion between steps) and within the static force limits.
    A step that fails on clearance or force appends its evidence to ``evidence`` when given (the closest
    bodies against the clearance a motion needs, ``clearance`` + the adaptive walk's smallest margin).
    """
    robot = world.robot
    n = int(np.ceil(distance_m / step_m))
    s = np.linspace(0.0, distance_m, n + 1)
    qs = [goal.q]
    opts = IKOptions(refine_iterations=3)
    for k in range(1, n + 1):
        if cancelled():
            return None
        T = T_base_tool_goal.copy()
        T[:3, 3] -= s[k] * direction
        sol = track_pose(robot, qs[-1], T, qs[-1], opts)
        if sol is None:
            return None
        q = sol.q
        # One continuous branch: a step of a few millimetres never moves a joint far.
        if float(np.max(np.abs(q - qs[-1]))) > 20 * step_m + 0.05:
            return None
        motion = certify_motion(world, qs[-1], q, clearance, motion_margin)
        if not motion.valid:
            if evidence is not None:
                # What blocks the step: the limit there, or the closest bodies against the clearance a
                # motion needs there.
                def where(t: float, k: int = k) -> str:
                    back_m = s[k - 1] + t * (s[k] - s[k - 1])
                    if back_m < 5e-4:
                        return "at the goal"
                    return f"{1e3 * back_m:.0f} mm before the goal on the insertion line"

                _record(evidence, motion_evidence(world, qs[-1], q, motion, clearance, where))
            return None
        if not forces.segment_ok(qs[-1], q):
            if evidence is not None:
                evidence.append(
                    force_evidence(forces, q, f"{1e3 * s[k]:.0f} mm before the goal on the insertion line")
                )
            return None
        qs.append(q)
    line = np.array(qs[::-1])
    probe = line[:: max(1, len(line) // 6)]
    c = float(np.min(world.clearance_profile(probe))) if world.cabin is not None else float("inf")
    return GoalCandidate(goal.q, goal.min_margin, line, distance_m - s[::-1], c)


@dataclass(frozen=True)
class LineSpeedBound:
    """Fastest motions along an insertion line within the drive velocity limits, per configuration."""

    line_m_s: Array  #: (N,) largest payload speed along the line (orientation fixed) [m/s]
    rail_m_s: Array  #: (N,) largest |rail speed| while the payload moves along the line [m/s]


def line_speed_bounds(robot: Cabin8, qs: Array, T_tool_payload: Array, direction: Array) -> LineSpeedBound:
    """Linear programs over the drive velocity box at configurations on an insertion line.

    With the payload frame's twist constrained to (v d, 0) (moving along the unit direction d at speed
    v >= 0, orientation fixed), |G q_dot| <= v_max for the drives: the largest v, and the largest rail
    speed |d1_dot| such a motion allows. A lower bound on the time of any insertion through these
    configurations is the line's length over the largest v; a rail speed of 0 means the rail cannot move
    while the payload is on the line.
    """
    from scipy.optimize import linprog

    d = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    line, rail = [], []
    for q in np.atleast_2d(qs):
        T = robot.fk(q)
        r = (T @ T_tool_payload)[:3, 3] - T[:3, 3]
        shift = np.eye(6)  # the payload point's velocity: v_tool + omega x r = v_tool - [r]x omega
        shift[:3, 3:] = -np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
        J = shift @ robot.jacobian(q)
        G, _ = robot.drive_map_jacobian(q)
        # Variables (q_dot (8), v): J q_dot - v (d, 0) = 0, -v_max <= G q_dot <= v_max, v >= 0.
        A_eq = np.hstack([J, -np.concatenate([d, np.zeros(3)])[:, None]])
        A_ub = np.vstack([np.hstack([G, np.zeros((8, 1))]), np.hstack([-G, np.zeros((8, 1))])])
        b_ub = np.concatenate([robot.limits.v_max, robot.limits.v_max])
        bounds = [(None, None)] * 8 + [(0.0, None)]
        best = []
        for c in (np.r_[np.zeros(8), -1.0], np.r_[-1.0, np.zeros(8)], np.r_[1.0, np.zeros(8)]):
            res = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=np.zeros(6), bounds=bounds, method="highs")
            best.append(-float(res.fun) if res.status == 0 else float("nan"))
        line.append(best[0])
        rail.append(max(0.0, best[1], best[2]))
    return LineSpeedBound(np.array(line), np.array(rail))

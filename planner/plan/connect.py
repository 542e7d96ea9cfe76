"""Connections: OMPL attempts, straight connections onto and off a transit ride, the greedy shortcut.

:func:`ompl_attempt` runs the sampling planner (:mod:`planner.plan.ompl_adapter`, the only module that
imports OMPL) with a motion-check budget and the time left; :func:`via_transit` plans start -> transit
ride -> target, joining and leaving the ride while the rail moves where a straight connection is certified
(:func:`ride_connections`), else with OMPL as a local problem first (:func:`connect`); :func:`via_relay`
plans start -> one ride -> a change of posture -> another ride -> target where no single posture rides.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from planner.collision.world import CollisionWorld
from planner.core.types import Array
from planner.kinematics import chain
from planner.plan.context import PlanContext
from planner.plan.ompl_adapter import plan_joint_path
from planner.plan.shortcut import segment_times
from planner.plan.transit import Transit, find_transit

#: A connection onto or off a transit ride is first planned with the rail within this of its ends [m].
CONNECT_RAIL_WINDOW_M = 0.3
#: Fractions of the transit ride at which a straight connection may join or leave it (see
#: :func:`ride_connections`), and the most certified checks spent looking for such a pair.
RIDE_FRACTIONS = (0.0, 0.15, 0.3, 0.45, 0.6, 0.75, 0.9, 1.0)
RIDE_MAX_CHECKS = 12
RIDE_SIDE_CHECKS = 4
#: Rail offsets [m] of the intermediate configuration of a detour connection (:func:`detour`), and how far
#: it is along the posture change (0: the first posture, 1: the second).
DETOUR_RAIL_M = (0.1, -0.1, 0.2, -0.2, 0.35, -0.35, 0.5, -0.5)
DETOUR_BLEND = (1.0, 0.5, 0.0)
#: Most certified motion checks a detour search spends (each ~1-3 ms; an OMPL connection needs hundreds).
DETOUR_MAX_CHECKS = 24
#: Where a relay (:func:`via_relay`) may change the riding posture: fractions of the rail move, the
#: middle first.
RELAY_SPLITS = (0.5, 0.25, 0.75)
#: Postures of the seeded pool the relay's second ride is searched among: all of them (a pinch that few
#: postures pass is rarely among the most compact, which the transit search sweeps).
RELAY_SWEEP = 4000


def joint_box(world: CollisionWorld) -> tuple[Array, Array]:
    """The sampling planner's joint box (8,), (8,): drive ranges, the stage's x, y and gamma ranges."""
    robot = world.robot
    ps = robot.desc.parallel_stage
    lo, hi = robot.limits.lower.copy(), robot.limits.upper.copy()
    half = 0.5 * (max(robot.limits.upper[1:4]) - min(robot.limits.lower[1:4]))
    lo[1:4] = [-half, ps.y_range[0], -ps.gamma_max]
    hi[1:4] = [half, ps.y_range[1], ps.gamma_max]
    return lo, hi


def ompl_attempt(
    ctx: PlanContext,
    q_start: Array,
    targets: list[Array],
    max_checks: int,
    simplify: bool = True,
    rail_window_m: float | None = None,
) -> tuple[Array, int] | None:
    """OMPL from ``q_start`` to any of ``targets`` within ``max_checks`` motion checks and the time left.

    ``rail_window_m`` makes it a local problem: the rail kept within that of the ends. None when no path
    was found (the attempt is recorded in the report).
    """
    budget = ctx.remaining()
    if budget <= 0:
        return None
    ctx.motion_checks_granted += max_checks
    lo, hi = joint_box(ctx.world)
    if rail_window_m is not None:  # a local problem: the rail kept near its two ends
        d1s = [float(q_start[chain.D1]), *(float(q[chain.D1]) for q in targets)]
        lo[chain.D1] = max(lo[chain.D1], min(d1s) - rail_window_m)
        hi[chain.D1] = min(hi[chain.D1], max(d1s) + rail_window_m)
    res = plan_joint_path(
        ctx.world,
        q_start,
        targets,
        clearance=ctx.clearances.planner_m,
        motion_margin=ctx.clearances.motion_margin_m,
        time_limit_s=budget,
        seed=ctx.opts.seed,
        planner=ctx.opts.planner,
        simplify=simplify and ctx.simplify,
        joint_lower=lo,
        joint_upper=hi,
        state_ok=ctx.search_state_ok,
        motion_ok=ctx.search_motion_ok,
        max_motion_checks=max_checks,
        planner_range=ctx.preset.planner_range,
    )
    if res is None:
        ctx.report.setdefault("search_attempts", []).append({"method": "ompl", "max_checks": max_checks})
        return None
    ctx.out_of_time()  # the clock may have cut the path's simplification short
    ctx.report["search"] = {
        "method": "ompl",
        "planner": res.planner,
        "planning_time_s": round(res.planning_time_s, 4),
        "simplify_time_s": round(res.simplify_time_s, 4),
        "raw_waypoints": res.raw_waypoints,
        "waypoints": len(res.waypoints),
        "motion_checks": res.motion_checks,
    }
    return res.waypoints, res.goal_index


def connect(
    ctx: PlanContext, q_a: Array, targets: list[Array], local_only: bool = False
) -> tuple[Array, int] | None:
    """``q_a`` to any target: straight where certified, else OMPL as a local problem, a rail detour, OMPL.

    None when not found. ``local_only``: no OMPL attempt in the whole joint box (a relay's connections:
    when they fail, the search's own full attempt follows).
    """
    for k, q in enumerate(targets):
        if np.allclose(q, q_a, rtol=0.0, atol=1e-12):
            return np.array([q_a, q]), k
        if ctx.motion_ok(q_a, q):
            return np.array([q_a, q]), k
    # Not simplified here: the caller shortcuts and simplifies the whole path it is part of. First as a
    # local problem (the rail near the connection's ends: a posture change at the end of a rail move
    # needs no rail detour), then two straight motions through a configuration off the rail position
    # (a few checks), then in the whole joint box.
    preset = ctx.preset
    local = ompl_attempt(
        ctx,
        q_a,
        targets,
        max_checks=preset.quick_motion_checks,
        simplify=False,
        rail_window_m=CONNECT_RAIL_WINDOW_M,
    )
    if local is not None:
        return local
    via = detour(ctx, q_a, targets[0])
    if via is not None:
        return via, 0
    if local_only:
        return None
    return ompl_attempt(ctx, q_a, targets, max_checks=preset.full_motion_checks, simplify=False)


def detour(ctx: PlanContext, q_a: Array, q_b: Array) -> Array | None:
    """Two certified straight motions ``q_a`` -> m -> ``q_b`` through a configuration m off the rail position.

    A posture change that is blocked where it starts (a ring frame, a bracket or a bay's rack beside the
    payload) is often clear a few decimetres along the rail: m takes the posture ``q_a + lam (q_b - q_a)``
    (the whole change, half of it or none, :data:`DETOUR_BLEND`) at the rail position of ``q_a`` or
    ``q_b`` (whichever the posture is nearer) shifted by :data:`DETOUR_RAIL_M`. These are the paths the
    sampling planner found for such connections (posture change during a short rail move, then the rail
    back), at a few motion checks instead of hundreds. The candidates are tried in order of estimated time
    (each motion's slowest drive at its velocity limit); at most :data:`DETOUR_MAX_CHECKS` are spent.
    Returns the waypoints (3, 8), or None.
    """
    lo, hi = ctx.robot.limits.lower[chain.D1], ctx.robot.limits.upper[chain.D1]
    q_a, q_b = np.asarray(q_a, dtype=float), np.asarray(q_b, dtype=float)
    candidates: list[tuple[float, float, float, Array]] = []
    for lam in DETOUR_BLEND:
        base = float(q_b[chain.D1] if lam >= 0.5 else q_a[chain.D1])
        for offset in DETOUR_RAIL_M:
            m = q_a + lam * (q_b - q_a)
            m[chain.D1] = base + offset
            if lo <= m[chain.D1] <= hi:
                t = float(segment_times(ctx.robot, q_a, q_a, m)[0] + segment_times(ctx.robot, m, m, q_b)[0])
                candidates.append((t, offset, lam, m))
    candidates.sort(key=lambda c: c[0])  # least estimated time first (stable: the listed order on ties)
    checks = 0
    for _, offset, lam, m in candidates:
        if checks >= DETOUR_MAX_CHECKS:
            break
        if not ctx.state_ok(m):
            continue
        checks += 1
        if not ctx.motion_ok(q_a, m):
            continue
        checks += 1
        if ctx.motion_ok(m, q_b):
            ctx.report.setdefault("search_attempts", []).append(
                {"method": "detour", "checks": checks, "rail_offset_m": offset, "blend": lam}
            )
            return np.array([q_a, m, q_b])
    ctx.report.setdefault("search_attempts", []).append({"method": "detour", "checks": checks})
    return None


def greedy_shortcut(ctx: PlanContext, waypoints: Array) -> Array:
    """Greedy, deterministic shortcut.

    From each kept waypoint, jump to the farthest one reachable by a certified straight motion.
    """
    keep = [0]
    i = 0
    n = len(waypoints)
    while i < n - 1:
        j = n - 1
        while j > i + 1 and not ctx.motion_ok(waypoints[i], waypoints[j]):
            j -= 1
        keep.append(j)
        i = j
    return waypoints[keep]


def _find_ride(
    ctx: PlanContext,
    q_a: Array,
    q_b: Array,
    segment_ok: Callable[[Array, Array], bool] | None = None,
    **sweep: int,
) -> Transit | None:
    """:func:`find_transit` from ``q_a``'s d1 to ``q_b``'s under the plan's clearances, checks and seed.

    ``segment_ok``: the ride's extra condition (default: the static forces along it); ``sweep``:
    ``n_sweep`` and ``n_riders`` where they differ from the transit search's.
    """
    c = ctx.clearances
    return find_transit(
        ctx.world,
        q_a,
        q_b,
        c.planner_m,
        c.motion_margin_m,
        ctx.search_state_ok,
        ctx.search_motion_ok if segment_ok is None else segment_ok,
        ctx.opts.seed,
        deadline=ctx.out_of_time,
        states_ok=ctx.search_states_ok,
        **sweep,
    )


def via_transit(ctx: PlanContext, q_start: Array, targets: list[Array]) -> tuple[Array, int] | None:
    """Start -> transit ride -> a target (waypoints, target index), or None when no transit is found."""
    transit = _find_ride(ctx, q_start, targets[0])
    ctx.report.setdefault("search_attempts", []).append({"method": "transit", "found": transit is not None})
    if transit is None:
        return None
    head, tail = ride_connections(ctx, q_start, targets, transit.q_a, transit.q_b)
    if head is None:
        joined = connect(ctx, q_start, [transit.q_a])
        if joined is None:
            return None
        head = joined[0]
    if tail is None:
        tail = connect(ctx, transit.q_b, targets)
        if tail is None:
            return None
    # Along the ride from where the head joins it to where the tail leaves it (at most one rail move).
    ride = [tail[0][0]] if not np.allclose(head[-1], tail[0][0], rtol=0.0, atol=1e-12) else []
    # Shortcut here; the caller then cuts the corners for time (OMPL's length-based simplifier, tried
    # here as well, gave the same durations after corner cutting, at 30-50 ms a plan).
    waypoints = greedy_shortcut(ctx, np.vstack([head, *ride, tail[0][1:]]))
    ctx.report["search"] = {
        "method": "transit",
        "transit_candidates": transit.candidates_tried,
        "transit_state_checks": transit.state_checks,
        "waypoints": len(waypoints),
    }
    return waypoints, tail[1]


def via_relay(ctx: PlanContext, q_start: Array, targets: list[Array]) -> tuple[Array, int] | None:
    """Start -> a first ride -> a change of posture -> a second ride -> a target; None when none is found.

    Where no single posture rides the whole rail move (the transit search found none), two may: a cabin
    can pinch the robot twice, each pinch passable only by postures the other stops (a hatch, then a
    shelf beside the rail). At a split m of the rail move (:data:`RELAY_SPLITS`, in turn):

    1. the second ride: a posture that rides from m to the first target's d1, searched in the whole
       seeded pool (:data:`RELAY_SWEEP`, most compact first; the first one certified is taken);
    2. the first ride: the transit search from the start to that posture at m, its riders held to one
       more condition: the straight change of posture at m, from the ride's end onto the second ride,
       certified;
    3. the connections onto the first ride (and off it, while the rail moves, where that is certified)
       and from the second ride's end to a target, straight or as local problems only
       (:func:`connect`'s ``local_only``).

    Every motion is certified as in any search; the caller shortcuts the path and cuts its corners.
    """
    q_goal = np.asarray(targets[0], dtype=float)
    d1_a, d1_b = float(q_start[chain.D1]), float(q_goal[chain.D1])
    for frac in RELAY_SPLITS:
        q_m = q_goal.copy()
        q_m[chain.D1] = d1_a + frac * (d1_b - d1_a)
        second = _find_ride(ctx, q_m, q_goal, n_sweep=RELAY_SWEEP, n_riders=1)
        if second is None:
            continue
        onto = second.q_a

        def ride_then_change(q_a: Array, q_b: Array, onto: Array = onto) -> bool:
            return ctx.search_motion_ok(q_a, q_b) and ctx.motion_ok(q_b, onto)

        first = _find_ride(ctx, q_start, onto, ride_then_change)
        if first is None:
            continue
        head, leave = ride_connections(ctx, q_start, [onto], first.q_a, first.q_b)
        if head is None:
            joined = connect(ctx, q_start, [first.q_a], local_only=True)
            if joined is None:
                continue
            head = joined[0]
        change = leave[0] if leave is not None else np.array([first.q_b, onto])
        tail = connect(ctx, second.q_b, targets, local_only=True)
        if tail is None:
            continue
        rows = [*head, *change, *tail[0]]  # head ends and change starts on the first ride
        keep = [0] + [i for i in range(1, len(rows)) if not np.array_equal(rows[i], rows[i - 1])]
        waypoints = greedy_shortcut(ctx, np.array(rows)[keep])
        ctx.report["search"] = {
            "method": "relay",
            "split_fraction": frac,
            "first_ride_candidates": first.candidates_tried,
            "second_ride_candidates": second.candidates_tried,
            "state_checks": first.state_checks + second.state_checks,
            "waypoints": len(waypoints),
        }
        return waypoints, tail[1]
    ctx.report.setdefault("search_attempts", []).append({"method": "relay", "found": False})
    return None


def ride_connections(
    ctx: PlanContext, q_start: Array, targets: list[Array], ride_a: Array, ride_b: Array
) -> tuple[Array | None, tuple[Array, int] | None]:
    """Straight connections onto and off the transit ride, changing posture while the rail moves.

    The ride is the transit posture moving along the rail from ``ride_a`` (the start's d1) to ``ride_b``
    (the goal's). Joining it at a fraction f_in of the way and leaving it at 1 - f_out lets the posture
    changes overlap the rail move instead of happening at a standstill. The pairs (f_in, f_out) with
    f_in + f_out <= 1 are tried in order of estimated time (slowest drive at v_max per segment), each
    straight connection certified, at most :data:`RIDE_MAX_CHECKS` checks in all. A side without a
    certified connection is None: the caller joins the ride at its start, or leaves it at its end,
    with the planner.

    Returns:
        (start -> join waypoints or None, (leave -> target waypoints, target index) or None).
    """
    ride = ride_b - ride_a
    t_ride = float(segment_times(ctx.robot, ride_a, ride_a, ride_b)[0])

    def on_ride(f: float) -> Array:
        return ride_a + f * ride

    t_in = {f: float(segment_times(ctx.robot, q_start, q_start, on_ride(f))[0]) for f in RIDE_FRACTIONS}
    combos: list[tuple[float, float, float, int]] = []
    for k, q_t in enumerate(targets):
        for f_out in RIDE_FRACTIONS:
            t_out = float(segment_times(ctx.robot, q_t, on_ride(1.0 - f_out), q_t)[0])
            for f_in in RIDE_FRACTIONS:
                if f_in + f_out <= 1.0 + 1e-12:
                    combos.append((t_in[f_in] + (1.0 - f_in - f_out) * t_ride + t_out, f_in, f_out, k))
    combos.sort()
    verdict: dict[tuple[str, float, int], bool] = {}

    def ok(side: str, f: float, k: int, budget: int) -> bool:
        """The side's connection certified; False, unchecked, once ``budget`` checks are spent."""
        key = (side, f, k if side == "out" else 0)
        if key not in verdict:
            if len(verdict) >= budget:
                return False
            a, b = (q_start, on_ride(f)) if side == "in" else (on_ride(1.0 - f), targets[k])
            verdict[key] = ctx.motion_ok(a, b)
        return verdict[key]

    # A side whose plain connection at the ride's end is not clear rarely has a longer diagonal that is
    # (it crosses the same obstacle while the rail moves too): such sides are not tried further.
    open_in = ok("in", 0.0, 0, RIDE_MAX_CHECKS)
    open_out = {k for k in range(len(targets)) if ok("out", 0.0, k, RIDE_MAX_CHECKS)}
    combos = [c for c in combos if (open_in or c[1] == 0.0) and (c[3] in open_out or c[2] == 0.0)]
    join: float | None = None
    out: tuple[float, int] | None = None
    pair = next(
        (
            (a, b, k)
            for _, a, b, k in combos
            if ok("in", a, k, RIDE_MAX_CHECKS) and ok("out", b, k, RIDE_MAX_CHECKS)
        ),
        None,
    )
    if pair is not None:
        join, out = pair[0], (pair[1], pair[2])
    else:
        # No pair within the budget: one side alone, the other at the ride's end (f = 0), the side's
        # fractions in order of their own estimate, with a few more checks.
        budget = len(verdict) + RIDE_SIDE_CHECKS
        join = next((a for _, a, b, k in combos if b == 0.0 and ok("in", a, k, budget)), None)
        if join is None:
            budget = len(verdict) + RIDE_SIDE_CHECKS
            out = next(((b, k) for _, a, b, k in combos if a == 0.0 and ok("out", b, k, budget)), None)
    ctx.report.setdefault("search_attempts", []).append(
        {
            "method": "ride_connections",
            "checks": len(verdict),
            "join_fraction": join,
            "leave_fraction": None if out is None else 1.0 - out[0],
        }
    )
    head = None if join is None else np.array([q_start, on_ride(join)])
    tail = None if out is None else (np.array([on_ride(1.0 - out[0]), targets[out[1]]]), out[1])
    return head, tail

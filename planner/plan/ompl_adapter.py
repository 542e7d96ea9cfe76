"""The only module that imports OMPL: a joint-space planning problem on the certified collision world.

OMPL plans in *scaled* joint coordinates z = q / w, where w_i is roughly the speed joint i reaches when its
slowest drive runs at its velocity limit, so that OMPL's Euclidean distance approximates motion time [s]
and its nearest-neighbour, range and shortcut decisions favour fast paths. States are checked with
:meth:`CollisionWorld.is_valid` and motions with the certified :meth:`CollisionWorld.check_motion`
(a straight joint-space segment passes only if no point of it comes within the clearance): there is no
fixed-resolution sampling anywhere.

Pitfalls of the OMPL 2.0 nanobind bindings handled here: ``setup()`` only after start and goal are set,
a ``timedPlannerTerminationCondition`` rather than ``solve(seconds)`` (which starts a timer thread), and
the global RNG seeded before any planner or sampler is allocated.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from planner.collision.world import CollisionWorld
from planner.core.types import Array
from planner.plan.motion import motion_clear

log = logging.getLogger(__name__)

ou.setLogLevel(ou.LOG_WARN)

#: Upper bound on shortcutting rounds (each round stops early when it changes nothing); more rounds cost
#: about 0.3 s a plan on the reference bay insertions and gave no shorter trajectories there.
SIMPLIFY_ROUNDS = 3

#: Planners offered by name; each is exercised by the test suite, and each is reproducible for a given
#: seed under a motion-check budget. Not offered: planners that need OMPL's "last valid state" motion
#: check (KPIECE family; the Python bindings cannot override it) and those that grow their roadmap in a
#: second thread (PRM, PRM*: not reproducible).
PLANNERS: dict[str, Callable[[ob.SpaceInformation], ob.Planner]] = {
    "RRTConnect": og.RRTConnect,
    "RRT": og.RRT,
    "RRTstar": og.RRTstar,
    "AORRTC": og.AORRTC,
}


@dataclass(frozen=True)
class SearchResult:
    """A certified joint-space polyline from the start to one of the goals.

    Attributes:
        waypoints: (N, 8) joint vectors; every straight segment between neighbours passed the certified
            motion check.
        goal_index: Which of the goal configurations was reached.
        planner: The planner's name.
        planning_time_s: Time spent in the planner (excluding simplification).
        simplify_time_s: Time spent shortcutting.
        raw_waypoints: Number of waypoints before simplification.
        motion_checks: Certified motion checks performed.
    """

    waypoints: Array
    goal_index: int
    planner: str
    planning_time_s: float
    simplify_time_s: float
    raw_waypoints: int
    motion_checks: int


class _Validator(ob.MotionValidator):
    def __init__(self, si: ob.SpaceInformation, check: Callable[[Array, Array], bool], scale: Array) -> None:
        super().__init__(si)
        self._check = check
        self._scale = scale
        self.calls = 0

    def checkMotion(self, s1: ob.State, s2: ob.State) -> bool:  # noqa: N802 (OMPL's name)
        self.calls += 1
        return self._check(_to_q(s1, self._scale), _to_q(s2, self._scale))


def _to_q(state: ob.State, scale: Array) -> Array:
    return np.array([state[i] for i in range(len(scale))]) * scale


def _set(state: ob.State, q: Array, scale: Array) -> None:
    z = np.asarray(q) / scale
    for i in range(len(scale)):
        state[i] = float(z[i])


def joint_scale(world: CollisionWorld) -> Array:
    """Per-joint speed scale w [m/s or rad/s]: how fast each joint moves with its drives at v_max.

    d1, theta3, theta4, d5, theta6 are drives themselves. The platform pose (x, y, gamma) moves the three
    sliders through the stage Jacobian; at the home posture each platform coordinate's speed is limited
    by the slider that it moves fastest (the largest |du_i/dq_j|).
    """
    robot = world.robot
    v = robot.limits.v_max
    G, _ = robot.drive_map_jacobian(robot.joints_from_drives(robot.home_drives))
    w = np.empty(8)
    for j in range(8):
        col = np.abs(G[:, j])
        w[j] = float(np.min(v[col > 1e-9] / col[col > 1e-9]))
    return w


def _problem(
    world: CollisionWorld,
    clearance: float,
    motion_margin: float,
    seed: int,
    joint_lower: Array,
    joint_upper: Array,
    state_ok: Callable[[Array], bool] | None,
    motion_ok: Callable[[Array, Array], bool] | None,
) -> tuple[ob.RealVectorStateSpace, og.SimpleSetup, ob.SpaceInformation, _Validator, Array]:
    """The seeded OMPL problem: scaled state space, state validity and certified motion validator."""
    # OMPL treats seed 0 as "pick one at random". Re-seeding resets its seed generator (it logs an error
    # that determinism is lost once seeds were handed out, which is not so: every planner and sampler
    # allocated after this call draws its seed from the reset generator).
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)
    ou.RNG.setSeed(int(seed) + 1)
    ou.setLogLevel(level)
    scale = joint_scale(world)
    space = ob.RealVectorStateSpace(8)
    bounds = ob.RealVectorBounds(8)
    lo, hi = np.asarray(joint_lower) / scale, np.asarray(joint_upper) / scale
    for i in range(8):
        bounds.setLow(i, float(lo[i]))
        bounds.setHigh(i, float(hi[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    si = ss.getSpaceInformation()
    extra_state = state_ok or (lambda q: True)
    extra_motion = motion_ok or (lambda q_a, q_b: True)

    def valid(state: ob.State) -> bool:
        q = _to_q(state, scale)
        # The caller's check first: it also ticks the search's progress, also on invalid states.
        return extra_state(q) and world.is_valid(q, clearance)

    ss.setStateValidityChecker(valid)

    def motion(q_a: Array, q_b: Array) -> bool:
        return motion_clear(world, q_a, q_b, clearance, motion_margin) and extra_motion(q_a, q_b)

    validator = _Validator(si, motion, scale)
    si.setMotionValidator(validator)
    return space, ss, si, validator, scale


def _simplify(simplifier: og.PathSimplifier, path: og.PathGeometric, deadline: float) -> None:
    """Deterministic shortcutting, cut short only by the deadline.

    Rounds of vertex reduction and partial shortcuts (random choices drawn from OMPL's seeded RNG) until a
    round changes nothing.
    """
    for _ in range(SIMPLIFY_ROUNDS):
        changed = simplifier.reduceVertices(path, 0, 0, 0.33)
        changed = simplifier.partialShortcutPath(path, 0, 0, 0.33, 0.005) or changed
        changed = simplifier.collapseCloseVertices(path, 0, 0) or changed
        if not changed or time.perf_counter() > deadline:
            break


def plan_joint_path(
    world: CollisionWorld,
    q_start: Array,
    q_goals: Sequence[Array],
    *,
    clearance: float,
    motion_margin: float,
    time_limit_s: float,
    seed: int,
    planner: str = "RRTConnect",
    simplify: bool = True,
    joint_lower: Array,
    joint_upper: Array,
    state_ok: Callable[[Array], bool] | None = None,
    motion_ok: Callable[[Array, Array], bool] | None = None,
    max_motion_checks: int | None = None,
    planner_range: float | None = None,
) -> SearchResult | None:
    """Plan a certified joint-space path from ``q_start`` to any of ``q_goals``.

    Args:
        world: The collision world (robot, payload and cabin).
        q_start: (8,) start joints, already checked valid.
        q_goals: Goal joint vectors (each already checked valid); the planner may reach any.
        clearance: Cabin clearance [m] every state and motion keeps.
        motion_margin: Certification margin of the motion check [m].
        time_limit_s: Wall-clock budget for planning and simplification together.
        seed: OMPL's RNG seed: the same seed and inputs give the same path.
        planner: One of :data:`PLANNERS`.
        simplify: Shortcut the path (OMPL's path simplifier, with the same certified motion check).
        joint_lower: (8,) sampling box lower bounds (joint coordinates).
        joint_upper: (8,) sampling box upper bounds.
        state_ok: Extra state condition (e.g. static drive forces), checked after the world's.
        motion_ok: Extra motion condition, checked after the certified motion check.
        planner_range: The planner's step length in scaled joint space (None: OMPL's default).
        max_motion_checks: Stop the planner after this many motion checks: a budget that does not
            depend on the machine's speed, so the outcome is reproducible (the time limit still applies).

    Returns:
        The path, or ``None`` when no path was found within the time limit.
    """
    t0 = time.perf_counter()
    space, ss, si, validator, scale = _problem(
        world, clearance, motion_margin, seed, joint_lower, joint_upper, state_ok, motion_ok
    )
    start = space.allocState()
    _set(start, q_start, scale)
    ss.setStartState(start)
    goals = ob.GoalStates(si)
    goal_states = []
    for q in q_goals:
        g = space.allocState()
        _set(g, q, scale)
        goals.addState(g)
        goal_states.append(g)
    ss.setGoal(goals)
    pl = PLANNERS[planner](si)
    if planner_range is not None and hasattr(pl, "setRange"):
        pl.setRange(float(planner_range))
    ss.setPlanner(pl)
    ss.setup()
    remaining = time_limit_s - (time.perf_counter() - t0)
    if remaining <= 0:
        return None
    ptc = ob.timedPlannerTerminationCondition(remaining)
    if max_motion_checks is not None:
        budget = int(max_motion_checks)
        ptc = ob.plannerOrTerminationCondition(
            ptc, ob.PlannerTerminationCondition(lambda: validator.calls >= budget)
        )
    status = ss.solve(ptc)
    t_plan = time.perf_counter() - t0
    if not ss.haveExactSolutionPath() or str(status) != "Exact solution":
        log.info("planner %s: %s after %.3f s", planner, status, t_plan)
        return None
    path = ss.getSolutionPath()
    raw = path.getStateCount()
    t1 = time.perf_counter()
    if simplify:
        _simplify(og.PathSimplifier(si), path, t0 + time_limit_s)
    qs = np.array([_to_q(s, scale) for s in path.getStates()])
    end = qs[-1]
    goal_index = int(np.argmin([np.linalg.norm((end - np.asarray(g)) / scale) for g in q_goals]))
    qs[-1] = np.asarray(q_goals[goal_index], dtype=float)  # exact goal (the state holds it up to rounding)
    qs[0] = np.asarray(q_start, dtype=float)
    return SearchResult(
        waypoints=qs,
        goal_index=goal_index,
        planner=planner,
        planning_time_s=t_plan,
        simplify_time_s=time.perf_counter() - t1,
        raw_waypoints=raw,
        motion_checks=validator.calls,
    )

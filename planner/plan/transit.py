"""Transit postures: how cabin8 passes narrow sections of the cabin (a bulkhead hatch) along its rail.

A long move along the rail through a narrow opening is a narrow passage in the 8-D joint space: only a
small set of compact postures fits through (about one random admissible posture in a thousand for the
reference hatch), and a sampling planner rarely finds it. But the structure is simple: the rail (d1)
moves everything rigidly, so the question is which *posture* (the other seven joints) can ride the rail
from the start's d1 to the goal's d1. This module answers it directly:

1. draw admissible postures (seeded), plus the start's and the goal's own;
2. rank them by compactness: the lateral and vertical extent of the robot's sphere cover, the quantity a
   hatch opening constrains (vectorised over all candidates);
3. sweep the best ones along the rail with cheap state checks at a few d1 values, the d1 values that
   rejected most earlier candidates first (a pinch is found after one or two checks), until a few
   postures survive (``n_riders``);
4. rank the survivors by the posture change they need: the estimated time from the start's posture and
   to the goal's (slowest drive at its velocity limit) beyond what fits in the rail move before the
   start's posture meets the narrow section and after the goal's leaves it (the planner changes posture
   while the rail moves): the most compact posture is rarely the one the robot reaches quickest;
5. certify the survivors' rail motion, in that order, with the motion check and the static force check.

The planner then connects start -> transit at the start's d1 and transit at the goal's d1 -> goal
(short, local problems), with the certified rail motion in between.
"""

from __future__ import annotations

import logging
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from planner.collision.world import CollisionWorld
from planner.core.lru import BoundedLRU
from planner.core.types import Array
from planner.kinematics import chain
from planner.plan.motion import motion_clear
from planner.plan.shortcut import segment_times
from planner.redundancy.ik import random_admissible_joints

if TYPE_CHECKING:
    from planner.robots.cabin8 import Cabin8

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Transit:
    """A posture that rides the rail between two d1 values: ``q_a`` at the first, ``q_b`` at the second."""

    q_a: Array
    q_b: Array
    candidates_tried: int
    state_checks: int


def compactness(world: CollisionWorld, qs: Array) -> Array:
    """Extent of the robot above the carriage: max |x| + max y of the fine sphere cover, per posture (N,).

    Each sphere's |x| + r and y + r, their maxima over the cover (:meth:`CollisionWorld.cover_extents`,
    compiled: 4 000 postures in 4.4 ms with their poses, where the centres and numpy's maxima took 7 ms).
    """
    extents = world.cover_extents(qs)
    return extents[:, 0] + 0.5 * extents[:, 1]


#: Each robot's seeded draws of admissible postures, ``(seed, n_candidates)`` -> (N, 8), read-only: the
#: draw depends on the robot alone (its limits and stage), so every world of a process (a service's worker,
#: a sweep) draws it once (4-5 ms) and ranks it for its own payload; the last :data:`DRAWS_KEPT` per robot.
_DRAWS: weakref.WeakKeyDictionary[object, BoundedLRU[tuple[int, int], Array]] = weakref.WeakKeyDictionary()
DRAWS_KEPT = 4
#: Each robot's ranked pools by payload: ``(seed, n_candidates, geometry)`` -> (N, 8), read-only. The ranking
#: depends on the robot and what it carries (the tool-to-payload transform and the sphere cover), never
#: on the cabin: a plan's transit search and a relay's two rides, a sweep's plans (one payload, many cabins
#: or goals) and a worker's repeated scenarios rank a draw once (4-5 ms a transit plan); the last
#: :data:`DRAWS_KEPT` per robot.
_RANKED: weakref.WeakKeyDictionary[object, BoundedLRU[tuple[int, int, str], Array]] = (
    weakref.WeakKeyDictionary()
)


def ranked_pool(world: CollisionWorld, seed: int, n_candidates: int) -> Array:
    """The world's seeded pool of ``n_candidates`` admissible postures, most compact first (read-only).

    :func:`random_admissible_joints` from ``default_rng(seed)``, sorted by :func:`compactness` (stable):
    the same rows whichever search asks first (tests/plan/test_transit.py).
    """
    ranked = _RANKED.get(world.robot)
    if ranked is None:
        ranked = _RANKED.setdefault(world.robot, BoundedLRU(DRAWS_KEPT))
    key = (int(seed), int(n_candidates), world.cover_digest())
    pool = ranked.get(key)
    if pool is None:
        drawn = seeded_draw(world.robot, *key[:2])
        pool = drawn[np.argsort(compactness(world, drawn), kind="stable")] if len(drawn) else drawn.copy()
        pool.flags.writeable = False
        ranked.put(key, pool)
    return pool


def seeded_draw(robot: Cabin8, seed: int, n_candidates: int) -> Array:
    """:func:`random_admissible_joints` from ``default_rng(seed)`` (at most 4 n tries), kept per robot.

    Read-only; the same rows for the same robot, seed and size in every call (tests/plan/test_transit.py).
    """
    draws = _DRAWS.get(robot)
    if draws is None:
        draws = _DRAWS.setdefault(robot, BoundedLRU(DRAWS_KEPT))
    key = (int(seed), int(n_candidates))
    drawn = draws.get(key)
    if drawn is None:
        rng = np.random.default_rng(seed)
        drawn = random_admissible_joints(robot, rng, n_candidates, max_tries=4 * n_candidates)
        drawn.flags.writeable = False
        draws.put(key, drawn)
    return drawn


def find_transit(
    world: CollisionWorld,
    q_start: Array,
    q_goal: Array,
    clearance: float,
    motion_margin: float,
    state_ok: Callable[[Array], bool],
    segment_ok: Callable[[Array, Array], bool],
    seed: int,
    n_candidates: int = 4000,
    n_sweep: int = 400,
    d1_step: float = 0.05,
    deadline: Callable[[], bool] = lambda: False,
    n_riders: int = 8,
    states_ok: Callable[[Array], NDArray[np.bool_]] | None = None,
) -> Transit | None:
    """A posture that can ride the rail from ``q_start[0]`` to ``q_goal[0]`` (see the module docstring).

    Args:
        world: The collision world.
        q_start: Start joints; the ride starts at its d1.
        q_goal: Goal (or pre-insertion) joints; the ride ends at its d1.
        clearance: Clearance every state and the ride keep [m].
        motion_margin: Certification margin of the ride's motion check [m].
        state_ok: An extra condition on the posture, which must not depend on the rail position d1 (it is
            evaluated once per posture): the static force check is such, as gravity is normal to the rail
            and no drive force changes along it (tested).
        segment_ok: An extra condition on the ride (the static forces along it), evaluated before the
            ride's certified motion check (the cheaper of the two; a relay's change of posture rejects
            most riders). It must be pure: the rider taken is the first that passes both, in either order.
        seed: Seed of the candidate pool.
        n_candidates: Postures drawn for the pool.
        n_sweep: Most postures swept along the rail.
        d1_step: Spacing of the sweep's rail positions [m].
        deadline: Returns True when the caller's time is up (then None).
        n_riders: Postures that survive the sweep before they are ranked (1: the most compact one).
        states_ok: ``state_ok`` of many postures (N, 8) at once, (N,) verdicts: evaluated once on the
            swept part of the pool instead of posture by posture (the static forces, batched: 10 ms of
            a cluttered cabin's plan). ``None``: ``state_ok`` each.
    """
    robot = world.robot
    d1_a, d1_b = float(q_start[chain.D1]), float(q_goal[chain.D1])
    n_d1 = int(max(2, np.ceil(abs(d1_b - d1_a) / d1_step) + 1))
    d1s = np.linspace(d1_a, d1_b, n_d1)
    kills = np.zeros(n_d1)
    checks = 0

    def candidates() -> Iterator[tuple[Array, bool | None]]:
        # The start's and goal's own postures first (no reconfiguration needed); only when neither rides
        # the rail, the seeded pool, most compact first (drawn and ranked once per world: ranked_pool),
        # each with its posture condition when ``states_ok`` gives them all at once (None: ``state_ok``).
        yield q_start, None
        yield q_goal, None
        pool = ranked_pool(world, seed, n_candidates)
        if len(pool):
            swept = pool[: n_sweep - 2]
            if states_ok is None:
                yield from ((posture, None) for posture in swept)
            else:
                yield from zip(swept, np.asarray(states_ok(swept), dtype=bool).tolist(), strict=True)

    def free_run(posture: Array, order: NDArray[np.intp]) -> float:
        """How far [m] the posture rides from the first d1 of ``order`` before it meets the cabin."""
        bad, _ = world.first_invalid_on_axis(posture, chain.D1, d1s[order], clearance)
        return abs(d1_b - d1_a) if bad < 0 else abs(float(d1s[order[bad]] - d1s[order[0]]))

    # The rail time before the start's posture meets the narrow section, and after the goal's leaves it:
    # a posture change that fits in these windows overlaps the rail move (the planner connects onto
    # and off the ride while the rail moves); what does not fit costs a standstill.
    v_rail = float(robot.limits.v_max[0])
    window_in = free_run(q_start, np.arange(n_d1)) / v_rail
    window_out = free_run(q_goal, np.arange(n_d1)[::-1]) / v_rail

    def change_time(posture: Array) -> float:
        """Estimated standstill the posture changes from the start and to the goal need (then their sum)."""
        q_a, q_b = posture.copy(), posture.copy()
        q_a[chain.D1], q_b[chain.D1] = d1_a, d1_b
        t_in = float(segment_times(robot, q_start, q_start, q_a)[0])
        t_out = float(segment_times(robot, q_goal, q_b, q_goal)[0])
        return max(0.0, t_in - window_in) + max(0.0, t_out - window_out) + 1e-3 * (t_in + t_out)

    def rides(posture: Array, holdable: bool | None = None) -> bool:
        """The posture is valid at every sweep position (the ones that rejected most postures first).

        ``holdable``: the posture condition when it is known already (``None``: ``state_ok`` decides).
        """
        nonlocal checks
        # The posture condition once: it does not depend on the rail position (see Args).
        q = posture.copy()
        q[chain.D1] = d1_a
        if not (state_ok(q) if holdable is None else holdable):
            return False
        # The sweep positions in that order, up to the first the posture fails at (one compiled call).
        order = np.argsort(-kills, kind="stable")
        bad, checked = world.first_invalid_on_axis(posture, chain.D1, d1s[order], clearance)
        checks += checked
        if bad >= 0:
            kills[order[bad]] += 1
            return False
        return True

    lo6, hi6 = robot.limits.lower[chain.THETA6], robot.limits.upper[chain.THETA6]
    middle = 0.5 * (np.asarray(q_start, dtype=float) + np.asarray(q_goal, dtype=float))

    def certified(batch: list[tuple[float, int, bool, Array]]) -> Transit | None:
        """The batch's best rider (least estimated standstill) whose ride is certified, if any."""
        for _, _, swept, posture in sorted(batch, key=lambda r: (r[0], r[1], not r[2])):
            if deadline():
                return None
            if not swept and not rides(posture):
                continue
            q_a, q_b = posture.copy(), posture.copy()
            q_a[chain.D1], q_b[chain.D1] = d1_a, d1_b
            # The extra condition first: it is the cheaper one (the static forces; a relay's change of
            # posture, a short motion that rejects most of its riders), the rail's certification the dear one.
            if segment_ok(q_a, q_b) and motion_clear(world, q_a, q_b, clearance, motion_margin):
                log.info("transit posture found after %d candidates, %d state checks", tried, checks)
                return Transit(q_a, q_b, tried, checks)
        return None

    # Riders in batches: (estimated standstill, rank, swept already, posture). A batch is judged when it
    # holds the start's or goal's own posture (no change on that side: the best there is) or n_riders pool
    # postures; when none of its rides is certified (the sweep samples the rail, the certification proves
    # it), the pool sweep goes on.
    batch: list[tuple[float, int, bool, Array]] = []
    tried = found = 0
    for tried, (posture, holdable) in enumerate(candidates(), start=1):
        if deadline():
            return None
        if not rides(posture, holdable):
            continue
        batch.append((change_time(posture), tried, True, posture))
        if tried > 2:
            # Variants nearer the start's and goal's postures (a random posture is compact for some joints
            # and needlessly far off in others), and its twins with the wrist turned half a turn (a payload
            # symmetric about the tool axis fits alike): swept only when their turn comes.
            batch += [(change_time(v), tried, False, v) for v in _variants(posture, middle, lo6, hi6)]
            found += 1
        if tried <= 2 or found >= n_riders:
            result = certified(batch)
            if result is not None or deadline():
                return result
            batch, found = [], 0
    return certified(batch) if batch else None


#: How far a rider's variants move toward the start's and goal's mean posture (all joints but the rail).
VARIANT_STEPS = (0.75, 0.5, 0.25)


def _variants(posture: Array, middle: Array, lo6: float, hi6: float) -> Iterator[Array]:
    """Postures near a rider: toward ``middle`` (all joints, then the wrist alone), and wrist half-turns."""
    for lam in VARIANT_STEPS:
        v = posture + lam * (middle - posture)
        v[chain.D1] = posture[chain.D1]
        yield v
    for lam in (1.0, 0.5):
        v = posture.copy()
        v[chain.THETA6] += lam * (middle[chain.THETA6] - posture[chain.THETA6])
        yield v
    for turn in (-np.pi, np.pi):
        v = posture.copy()
        v[chain.THETA6] += turn
        if lo6 <= v[chain.THETA6] <= hi6:
            yield v

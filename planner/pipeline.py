"""The planning pipeline: resolved scenario in, validated drive profile out (or a clear refusal).

Stages (each reported through the ``progress`` callback):

1. ``check_start`` / ``goals``: the start must be admissible, collision-free with the requested clearance
   and statically holdable within the drive force limits; a pose goal becomes several good exact goal
   configurations (:mod:`planner.planning.goals`); with an approach each is tracked back along the
   insertion line and the best line (largest clearance) gives the pre-insertion configurations.
2. ``search``: the straight joint-space motion when it is certified clear; for a long rail move a transit
   posture (:mod:`planner.planning.transit`) joined and left while the rail moves; else OMPL
   (:mod:`planner.planning.ompl_adapter`) to any of the pre-insertion / goal configurations; shortcut,
   then corners cut for time (:mod:`planner.planning.shortcut`).
3. ``smooth``: corners become certified quadratic blends (shrunk, or left sharp with a stop, where a
   blend would not be clear).
4. ``timing``: TOPP-RA per leg (rest to rest; legs split at sharp corners and before the approach).
5. ``sample`` and ``validate``: sampled at the controller period and passed through the gate
   (:mod:`planner.validate`); a gate failure on a limit re-times with tighter limits, any other failure
   refuses.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from planner.collision.world import CollisionWorld
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.payload import RigidPayload
from planner.dynamics.stiffness import Compensation, StaticDeflection, compensate_goals, stiffness_model
from planner.exceptions import (
    ApproachInfeasible,
    GoalInCollision,
    GoalUnreachable,
    InvalidInput,
    NoPathFound,
    NoPathWithinBudget,
    PlannerError,
    StartInvalid,
    ValidationFailed,
)
from planner.kinematics import chain
from planner.planning.goals import (
    GoalCandidate,
    StaticForceCheck,
    approach_lines,
    goal_configurations,
    track_approach,
)
from planner.planning.motion import motion_clear
from planner.planning.ompl_adapter import plan_joint_path
from planner.planning.shortcut import cut_corners, segment_times
from planner.planning.transit import find_transit

if TYPE_CHECKING:
    from planner.scenario import ResolvedScenario
from planner.timing.path import JointPath, LinePiece, SplinePiece, blended_polyline, segment_time_length
from planner.timing.profile import DriveProfile, sample_legs
from planner.timing.stage import TimedPath, TimingStage, ToppraStage
from planner.validate import GateReport, GateRequirements, validate_profile

Array = NDArray[np.float64]
log = logging.getLogger(__name__)

Progress = Callable[[str, float], None]

#: Blend half-length as a fraction of the shorter neighbouring segment, then the shrink sequence.
BLEND_FRACTIONS = (0.45, 0.2, 0.08, 0.03, 0.01, 0.0)
#: Largest extra clearance of a certified run along a blend [m] (see CollisionWorld.check_path).
BLEND_MAX_EXTRA_M = 0.01
#: Limit scalings tried when the gate finds a limit exceeded on the sampled profile.
SAFETY_LEVELS = ((0.995, 0.97, 0.97), (0.98, 0.92, 0.92), (0.95, 0.85, 0.85))
LIMIT_CHECKS = {"velocity", "acceleration", "effort", "consistency"}
#: Motion checks of the first, reproducible planner attempt.
QUICK_MOTION_CHECKS = 1500
#: Motion-check budget of the full attempt. The search is bounded by these work budgets, so the same
#: scenario and seed give the same plan on any machine; the time limit is only the hard stop, and when it
#: ends the search the plan is refused (``no_path_within_time_limit``), never finished differently.
FULL_MOTION_CHECKS = 40_000
#: A connection onto or off a transit ride is first planned with the rail within this of its ends [m].
CONNECT_RAIL_WINDOW_M = 0.3
#: Rail moves at least this long may use a transit posture [m].
TRANSIT_MIN_RAIL_M = 0.5
#: Fractions of the transit ride at which a straight connection may join or leave it (see
#: Planner._ride_connections), and the most certified checks spent looking for such a pair.
RIDE_FRACTIONS = (0.0, 0.15, 0.3, 0.45, 0.6, 0.75, 0.9, 1.0)
RIDE_MAX_CHECKS = 12
RIDE_SIDE_CHECKS = 4
#: Planner step length in OMPL's scaled joint space (about seconds of motion at full drive speed):
#: measured on the reference bay insertions, 1.0 halves the median search time against OMPL's default.
PLANNER_RANGE = 1.0
#: Certification margin of the gate's collision check [m].
GATE_MOTION_MARGIN_M = 0.001
#: Extra clearance the planner keeps beyond the requested one [m] (see Planner.__init__).
GATE_SLACK_M = 0.003
#: Samples of a profile at which the deflection is predicted for the report (interpolated in between).
DEFLECTION_SAMPLES = 300
#: Fraction of the time limit kept for timing and validation.
TIME_RESERVE = 0.15


@dataclass(frozen=True)
class PlanResult:
    """A validated drive profile and everything that explains it."""

    profile: DriveProfile
    gate: GateReport
    report: dict[str, Any] = field(repr=False)
    waypoints: Array = field(repr=False)
    #: Predicted static deflection of the payload frame at every sample (N, 6), or None (no stiffness data).
    deflection: Array | None = field(default=None, repr=False)


def single_drive_lower_bound(robot: Any, u0: Array, u1: Array) -> float:
    """Rest-to-rest time of the slowest drive moving alone from u0 to u1 (v_max, a_max), a lower bound."""
    d = np.abs(np.asarray(u1) - np.asarray(u0))
    v, a = robot.limits.v_max, robot.limits.a_max
    t = np.where(d > v * v / a, d / v + v / a, 2.0 * np.sqrt(d / a))
    return float(np.max(t))


def compensates_deflection(sc: ResolvedScenario) -> bool:
    """Whether a scenario's pose goal is deflection-compensated (option, default: with a payload).

    Raises:
        InvalidInput: compensation asked for explicitly on a robot without stiffness data.
    """
    option = sc.options.compensate_deflection
    if option and sc.robot.desc.stiffness is None:
        raise InvalidInput(
            f"options.compensate_deflection: robot {sc.robot.name!r} has no stiffness data",
            field="options.compensate_deflection",
        )
    if sc.T_base_payload_goal is None or sc.robot.desc.stiffness is None:
        return False
    return sc.payload is not None if option is None else bool(option)


def gate_requirements(
    sc: ResolvedScenario, payload: RigidPayload | None, T_base_payload_commanded: Array | None = None
) -> GateRequirements:
    """What the validation gate demands of any trajectory for this scenario.

    ``T_base_payload_commanded`` is the planner's compensated command of a pose goal (the gate
    recomputes it from the final sample when it is not given).
    """
    return GateRequirements(
        start_u=sc.start_u,
        clearance_m=sc.options.clearance_m,
        motion_margin_m=GATE_MOTION_MARGIN_M,
        goal_u=sc.goal_u,
        T_base_payload_goal=sc.T_base_payload_goal,
        T_tool_payload=sc.payload.T_tool_payload if sc.payload is not None else np.eye(4),
        approach_direction=sc.approach_direction,
        approach_distance_m=sc.approach_distance_m,
        payload=payload,
        compensate_deflection=compensates_deflection(sc),
        T_base_payload_commanded=T_base_payload_commanded,
        sample_period_s=sc.options.sample_period_s,
        deflection_check=sc.payload is not None and sc.robot.desc.stiffness is not None,
    )


def _joint_box(world: CollisionWorld) -> tuple[Array, Array]:
    robot = world.robot
    ps = robot.desc.parallel_stage
    lo, hi = robot.limits.lower.copy(), robot.limits.upper.copy()
    g = robot.geometry
    half = 0.5 * (max(robot.limits.upper[1:4]) - min(robot.limits.lower[1:4]))
    lo[1:4] = [-half, ps.y_range[0], -ps.gamma_max]
    hi[1:4] = [half, ps.y_range[1], ps.gamma_max]
    del g
    return lo, hi


class Planner:
    """Plans one resolved scenario (see the module docstring). Construct, then call :meth:`plan`.

    Args:
        scenario: The resolved scenario.
        progress: Called with (stage name, fraction done) as the stages start.
        timing: Factory of the timing stage, ``(robot, payload, safety) -> TimingStage`` (default:
            :class:`~planner.timing.stage.ToppraStage`): the timing stage is pluggable.
        naive: The benchmark's baseline: OMPL with OMPL's defaults, no straight-line, transit or
            shortcut steps, no corner blends (the robot stops at every waypoint); the gate still decides.
    """

    def __init__(
        self,
        scenario: ResolvedScenario,
        progress: Progress | None = None,
        timing: Callable[[Any, Any, tuple[float, float, float]], TimingStage] | None = None,
        naive: bool = False,
    ) -> None:
        self.sc = scenario
        self.naive = naive
        self.robot = scenario.robot
        self.opts = scenario.options
        self.progress = progress or (lambda stage, fraction: None)
        self.payload = scenario.payload.rigid_payload() if scenario.payload is not None else None
        self.world = CollisionWorld(self.robot, scenario.cabin, scenario.payload)
        self.dynamics = Cabin8Dynamics.of(self.robot)
        self.forces = StaticForceCheck(self.dynamics, self.payload)
        # The planner keeps GATE_SLACK_M more than the requested clearance, so that the gate's own
        # certification (which must prove a margin at the samples it starts from) passes on its path.
        self.plan_clearance = self.opts.clearance_m + GATE_SLACK_M
        self._timing_factory = timing or (lambda robot, payload, safety: ToppraStage(robot, payload, safety))
        self._warm_up(scenario.start_q)
        self.t0 = time.perf_counter()
        self._last_tick = self.t0
        self.report: dict[str, Any] = {"stages_s": {}}

    # ----------------------------------------------------------------- helpers
    def _warm_up(self, q: Array) -> None:
        """Run one state and one motion check before the clock starts (results unused).

        The collision kernels are compiled by numba on first use and cached on disk; in a process that
        finds no cache (a fresh install) that takes tens of seconds, which must not count against the
        scenario's planning time limit. Once compiled, this costs well under a millisecond.
        """
        q_b = np.array(q, dtype=float)
        q_b[chain.THETA6] += 1e-3
        self.world.is_valid(q, self.plan_clearance)
        self.world.check_motion(q, q_b, self.plan_clearance, self.opts.motion_margin_m)

    def _elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def _stage(self, name: str, t_start: float) -> None:
        self.report["stages_s"][name] = round(time.perf_counter() - t_start, 6)

    def _state_ok(self, q: Array) -> bool:
        return self.world.is_valid(q, self.plan_clearance) and self.forces.ok(q)

    def _search_state_ok(self, q: Array) -> bool:
        """The planner's extra state check (static forces), ticking the search progress."""
        self._tick()
        return self.forces.ok(q)

    def _tick(self) -> None:
        """Report the search's progress at most twice a second: elapsed share of its time budget."""
        now = time.perf_counter()
        if now - self._last_tick >= 0.5:
            self._last_tick = now
            budget = self.opts.time_limit_s * (1.0 - TIME_RESERVE)
            self.progress("search", 0.15 + 0.55 * min(1.0, self._elapsed() / budget))

    def _out_of_time(self) -> bool:
        """Deadline of the search's steps: raises the time-limit refusal once the time is up.

        A step cut short by the clock would give a result that depends on the machine's speed, so the
        wall-clock limit stops the plan instead of shortening it.
        """
        if self._remaining() <= 0:
            raise self._no_path()
        return False

    def _no_path(self) -> NoPathFound:
        """The refusal of a search without a path, saying whether the clock or the work budget ended it."""
        elapsed = round(self._elapsed(), 3)
        if self._remaining() <= 0:
            return NoPathFound(
                f"the wall-clock time limit ({self.opts.time_limit_s:g} s) stopped the search after "
                f"{elapsed:g} s, before its work budget was spent (the machine was slower or busier than "
                f"it needs): retry, or raise options.time_limit_s",
                ended_by="time_limit",
                time_limit_s=self.opts.time_limit_s,
                elapsed_s=elapsed,
                planner=self.opts.planner,
            )
        return NoPathWithinBudget(
            f"no collision-free path found within the search's work budget "
            f"({QUICK_MOTION_CHECKS} + {FULL_MOTION_CHECKS} motion checks, planner {self.opts.planner}); "
            f"the same seed ends the same way on any machine: try another options.seed or scenario",
            ended_by="work_budget",
            motion_check_budget=QUICK_MOTION_CHECKS + FULL_MOTION_CHECKS,
            time_limit_s=self.opts.time_limit_s,
            elapsed_s=elapsed,
            planner=self.opts.planner,
        )

    def _motion_ok(self, q_a: Array, q_b: Array) -> bool:
        self._tick()
        return motion_clear(
            self.world, q_a, q_b, self.plan_clearance, self.opts.motion_margin_m
        ) and self.forces.segment_ok(q_a, q_b)

    def _check_configuration(self, q: Array, what: str) -> None:
        rep = self.world.check_state(q, self.opts.clearance_m, all_contacts=True)
        limits = [c for c in rep.contacts if c.kind == "limit"]
        contacts = [c.to_dict() for c in rep.contacts]
        if what == "start":
            if limits:
                raise StartInvalid(
                    f"start violates {', '.join(c.detail for c in limits)}", limits=True, contacts=contacts
                )
            if rep.contacts:
                raise StartInvalid(f"start: {rep.contacts[0].detail}", contacts=contacts)
        else:
            if limits:
                raise GoalUnreachable(
                    f"goal violates {', '.join(c.detail for c in limits)}", contacts=contacts
                )
            if rep.contacts:
                raise GoalInCollision(f"goal: {rep.contacts[0].detail}", contacts=contacts)
        # Every motion is certified with GATE_SLACK_M beyond the requested clearance: an end state inside
        # that band can never be left or reached, so say so now rather than search until the time limit.
        slack = self.world.check_state(q, self.plan_clearance)
        if not slack.valid:
            msg = (
                f"{what}: {slack.contacts[0].detail}: the planner keeps {1e3 * GATE_SLACK_M:.0f} mm beyond "
                f"the requested {self.opts.clearance_m} m so that the gate can certify the motion; "
                f"ask for a smaller clearance or move the {what}"
            )
            if what == "start":
                raise StartInvalid(msg, contacts=[c.to_dict() for c in slack.contacts])
            raise GoalInCollision(msg, contacts=[c.to_dict() for c in slack.contacts])
        ratio = float(self.forces.ratios(q)[0])
        if ratio > self.forces.fraction:
            msg = (
                f"{what}: holding the payload there needs {100 * ratio:.0f}% of a drive's force limit "
                f"(at most {100 * self.forces.fraction:.0f}% allowed)"
            )
            if what == "start":
                raise StartInvalid(msg, limits=True, static_force_ratio=ratio)
            raise GoalUnreachable(msg, static_force_ratio=ratio)

    # ------------------------------------------------------------------ stages
    def goals(self) -> tuple[list[Array], list[GoalCandidate | None]]:
        """Configurations the global search must reach, and for each its approach line (or None)."""
        sc = self.sc
        if sc.goal_q is not None:
            self._check_configuration(sc.goal_q, "goal")
            return [sc.goal_q], [None]
        assert sc.T_base_tool_goal is not None
        if sc.approach_direction is not None:
            lines, line_stats = approach_lines(
                self.world,
                sc.T_base_tool_goal,
                sc.approach_direction,
                sc.approach_distance_m,
                self.plan_clearance,
                self.opts.motion_margin_m,
                self.forces,
            )
            self.report["approach"] = {"method": "fixed_redundancy", "lines": len(lines), **line_stats}
            lines = [c for c in lines if c.line is not None]  # targets and their lines stay aligned
            if lines:
                return [c.line[0] for c in lines if c.line is not None], list(lines)
        cands, stats = goal_configurations(
            self.world, sc.T_base_tool_goal, self.plan_clearance, self.forces, self.sc.start_u
        )
        self.report["goal_candidates"] = {"found": len(cands), **stats}
        if not cands:
            if stats["family_points"] == 0:
                raise GoalUnreachable(
                    "goal pose: no admissible configuration of the robot reaches it", **stats
                )
            if stats["collision"] >= max(stats["force"], 1):
                raise GoalInCollision(
                    "goal pose: every configuration reaching it comes within the clearance of the cabin "
                    "or of itself",
                    **stats,
                )
            raise GoalUnreachable(
                "goal pose: no configuration reaching it can hold the payload within the drive force limits",
                **stats,
            )
        if sc.approach_direction is None:
            return [c.q for c in cands], [None] * len(cands)
        # Fallback: let the redundancy vary along the line (QP differential IK, step by step).
        tracked: list[GoalCandidate] = []
        for cand in cands[:4]:
            tr = track_approach(
                self.world,
                cand,
                sc.T_base_tool_goal,
                sc.approach_direction,
                sc.approach_distance_m,
                self.opts.approach_step_m,
                self.plan_clearance,
                self.opts.motion_margin_m,
                self.forces,
            )
            if tr is not None:
                tracked.append(tr)
        if not tracked:
            raise ApproachInfeasible(
                f"approach: no goal configuration can be tracked {sc.approach_distance_m} m back along the "
                "line within limits, margins, force limits and clearance",
                candidates=len(cands[:4]),
            )
        tracked.sort(key=lambda c: -c.clearance_m)
        self.report["approach"].update(
            method="tracked",
            candidates_tracked=len(tracked),
            line_clearance_m=[round(c.clearance_m, 4) for c in tracked],
        )
        return [c.line[0] for c in tracked if c.line is not None], list(tracked)

    def search(self, q_start: Array, targets: list[Array]) -> tuple[Array, int]:
        """Certified waypoints from the start to one of the targets (and which), corners cut for time."""
        waypoints, k = self._search(q_start, targets)
        if len(waypoints) > 2 and self.opts.simplify and not self.naive:
            waypoints, stats = cut_corners(self.robot, waypoints, self._motion_ok, deadline=self._out_of_time)
            self.report.setdefault("search", {})["corner_cuts"] = {
                "cuts": stats.cuts,
                "checks": stats.checks,
                "estimated_saving_s": round(stats.saved_s, 3),
            }
        return waypoints, k

    def _search(self, q_start: Array, targets: list[Array]) -> tuple[Array, int]:
        for k, q in enumerate(targets):
            if np.allclose(q, q_start, rtol=0.0, atol=1e-12):
                return np.array([q_start, q]), k
        if self.naive:  # the benchmark's baseline: the plain planner, its raw path
            res = self._ompl(q_start, targets, max_checks=FULL_MOTION_CHECKS)
            if res is None:
                raise self._no_path()
            return res
        # The straight motion first: free when it is clear.
        for k, q in enumerate(targets):
            if self._motion_ok(q_start, q):
                self.report["search"] = {"method": "straight"}
                return np.array([q_start, q]), k
        # A long rail move first tries a transit posture (cheap, and it solves narrow passages such as a
        # hatch), then the sampling planner with a budget counted in motion checks (reproducible), then
        # the planner again with the rest of the time.
        if self.opts.simplify and abs(float(targets[0][0] - q_start[0])) >= TRANSIT_MIN_RAIL_M:
            via = self._via_transit(q_start, targets)
            if via is not None:
                return via
        res = self._ompl(q_start, targets, max_checks=QUICK_MOTION_CHECKS)
        if res is not None:
            return res
        res = self._ompl(q_start, targets, max_checks=FULL_MOTION_CHECKS)
        if res is not None:
            return res
        raise self._no_path()

    def _remaining(self) -> float:
        """Time left for search, keeping a reserve for timing and validation."""
        return self.opts.time_limit_s * (1.0 - TIME_RESERVE) - self._elapsed()

    def _ompl(
        self,
        q_start: Array,
        targets: list[Array],
        max_checks: int,
        simplify: bool = True,
        rail_window_m: float | None = None,
    ) -> tuple[Array, int] | None:
        budget = self._remaining()
        if budget <= 0:
            return None
        lo, hi = _joint_box(self.world)
        if rail_window_m is not None:  # a local problem: the rail kept near its two ends
            d1s = [float(q_start[chain.D1]), *(float(q[chain.D1]) for q in targets)]
            lo[chain.D1] = max(lo[chain.D1], min(d1s) - rail_window_m)
            hi[chain.D1] = min(hi[chain.D1], max(d1s) + rail_window_m)
        res = plan_joint_path(
            self.world,
            q_start,
            targets,
            clearance=self.plan_clearance,
            motion_margin=self.opts.motion_margin_m,
            time_limit_s=budget,
            seed=self.opts.seed,
            planner=self.opts.planner,
            simplify=simplify and self.opts.simplify and not self.naive,
            joint_lower=lo,
            joint_upper=hi,
            state_ok=self._search_state_ok,
            motion_ok=self.forces.segment_ok,
            max_motion_checks=max_checks,
            planner_range=None if self.naive else PLANNER_RANGE,
        )
        if res is None:
            self.report.setdefault("search_attempts", []).append({"method": "ompl", "max_checks": max_checks})
            return None
        self._out_of_time()  # the clock may have cut the path's simplification short
        self.report["search"] = {
            "method": "ompl",
            "planner": res.planner,
            "planning_time_s": round(res.planning_time_s, 4),
            "simplify_time_s": round(res.simplify_time_s, 4),
            "raw_waypoints": res.raw_waypoints,
            "waypoints": len(res.waypoints),
            "motion_checks": res.motion_checks,
        }
        return res.waypoints, res.goal_index

    def _connect(self, q_a: Array, targets: list[Array]) -> tuple[Array, int] | None:
        for k, q in enumerate(targets):
            if np.allclose(q, q_a, rtol=0.0, atol=1e-12):
                return np.array([q_a, q]), k
            if self._motion_ok(q_a, q):
                return np.array([q_a, q]), k
        # Not simplified here: the caller shortcuts and simplifies the whole path it is part of. First as a
        # local problem (the rail near the connection's ends: a posture change at the end of a rail move
        # needs no rail detour), then in the whole joint box.
        local = self._ompl(
            q_a, targets, max_checks=QUICK_MOTION_CHECKS, simplify=False, rail_window_m=CONNECT_RAIL_WINDOW_M
        )
        return local or self._ompl(q_a, targets, max_checks=FULL_MOTION_CHECKS, simplify=False)

    def _shortcut(self, waypoints: Array) -> Array:
        """Greedy, deterministic shortcut.

        From each kept waypoint, jump to the farthest one reachable by a certified straight motion.
        """
        keep = [0]
        i = 0
        n = len(waypoints)
        while i < n - 1:
            j = n - 1
            while j > i + 1 and not self._motion_ok(waypoints[i], waypoints[j]):
                j -= 1
            keep.append(j)
            i = j
        return waypoints[keep]

    def _via_transit(self, q_start: Array, targets: list[Array]) -> tuple[Array, int] | None:
        transit = find_transit(
            self.world,
            q_start,
            targets[0],
            self.plan_clearance,
            self.opts.motion_margin_m,
            self.forces.ok,
            self.forces.segment_ok,
            self.opts.seed,
            deadline=self._out_of_time,
        )
        self.report.setdefault("search_attempts", []).append(
            {"method": "transit", "found": transit is not None}
        )
        if transit is None:
            return None
        head, tail = self._ride_connections(q_start, targets, transit.q_a, transit.q_b)
        if head is None:
            joined = self._connect(q_start, [transit.q_a])
            if joined is None:
                return None
            head = joined[0]
        if tail is None:
            tail = self._connect(transit.q_b, targets)
            if tail is None:
                return None
        # Along the ride from where the head joins it to where the tail leaves it (at most one rail move).
        ride = [tail[0][0]] if not np.allclose(head[-1], tail[0][0], rtol=0.0, atol=1e-12) else []
        # Shortcut here; the caller then cuts the corners for time (OMPL's length-based simplifier, tried
        # here as well, gave the same durations after corner cutting, at 30-50 ms a plan).
        waypoints = self._shortcut(np.vstack([head, *ride, tail[0][1:]]))
        self.report["search"] = {
            "method": "transit",
            "transit_candidates": transit.candidates_tried,
            "transit_state_checks": transit.state_checks,
            "waypoints": len(waypoints),
        }
        return waypoints, tail[1]

    def _ride_connections(
        self, q_start: Array, targets: list[Array], ride_a: Array, ride_b: Array
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
        t_ride = float(segment_times(self.robot, ride_a, ride_a, ride_b)[0])

        def on_ride(f: float) -> Array:
            return ride_a + f * ride

        t_in = {f: float(segment_times(self.robot, q_start, q_start, on_ride(f))[0]) for f in RIDE_FRACTIONS}
        combos: list[tuple[float, float, float, int]] = []
        for k, q_t in enumerate(targets):
            for f_out in RIDE_FRACTIONS:
                t_out = float(segment_times(self.robot, q_t, on_ride(1.0 - f_out), q_t)[0])
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
                verdict[key] = self._motion_ok(a, b)
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
        self.report.setdefault("search_attempts", []).append(
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

    def smooth(self, waypoints: Array) -> list[JointPath]:
        """Blend corners where the blend is certified clear; split into legs at the remaining corners."""
        n_corners = len(waypoints) - 2
        if n_corners <= 0 or not self.opts.simplify or self.naive:
            return [
                JointPath((LinePiece(a, b, segment_time_length(self.robot, a, b)),))
                for a, b in zip(waypoints[:-1], waypoints[1:], strict=True)
            ]
        level = np.zeros(n_corners, dtype=int)
        # A corner's blend depends on its own fraction only (a blend takes at most 0.45 of each neighbouring
        # segment, so two never meet): a verdict holds while the other corners shrink.
        verdicts: dict[tuple[int, int], bool] = {}
        while True:
            frac = np.array([BLEND_FRACTIONS[k] for k in level])
            path, blend_index = blended_polyline(self.robot, waypoints, frac)
            failed = False
            for c, idx in enumerate(blend_index):
                if idx < 0:
                    continue
                if verdicts.get((c, int(level[c]))):
                    continue
                piece = path.pieces[idx]
                s = np.linspace(0.0, piece.length, 17)
                qs = piece.evaluate(s)[0]
                ok = bool(np.all(self.robot.admissible_batch(qs)))
                ok = ok and bool(np.all(self.forces.ratios(qs) <= self.forces.fraction))
                # A curved run deviates from its chord: runs with up to BLEND_MAX_EXTRA_M of extra
                # clearance (halved where that fails) take a few checks rather than one per piece.
                ok = (
                    ok
                    and self.world.check_path(
                        qs,
                        self.plan_clearance + 0.001,
                        self.opts.motion_margin_m,
                        max_extra_m=BLEND_MAX_EXTRA_M,
                    ).valid
                )
                verdicts[c, int(level[c])] = ok
                if not ok:
                    level[c] = min(level[c] + 1, len(BLEND_FRACTIONS) - 1)
                    failed = True
            if not failed:
                break
        self.report["smoothing"] = {
            "corners": n_corners,
            "blended": int(np.sum(frac > 0)),
            "sharp": int(np.sum(frac == 0)),
        }
        # Split at sharp corners (the robot stops there): corner c is waypoint c + 1.
        legs: list[JointPath] = []
        start = 0
        for c in range(n_corners):
            if frac[c] == 0:
                legs.append(blended_polyline(self.robot, waypoints[start : c + 2], frac[start:c])[0])
                start = c + 1
        legs.append(blended_polyline(self.robot, waypoints[start:], frac[start:])[0])
        return legs

    def time_and_validate(
        self, legs: list[JointPath], req: GateRequirements
    ) -> tuple[DriveProfile, GateReport, list[TimedPath]]:
        """Time every leg, sample and gate; re-time with tighter limits when only a limit check fails.

        Only the limits that failed are tightened (velocity, acceleration, force: the next of
        :data:`SAFETY_LEVELS` for each; a consistency failure tightens the acceleration): the others keep
        their margin, so a drive holding a heavy payload near its force limit is not refused because an
        acceleration peak had to come down.
        """
        last: GateReport | None = None
        level = [0, 0, 0]  # velocity, acceleration, force
        for attempt in range(len(SAFETY_LEVELS)):
            safety = (
                SAFETY_LEVELS[level[0]][0],
                SAFETY_LEVELS[level[1]][1],
                SAFETY_LEVELS[level[2]][2],
            )
            stage = self._timing_factory(self.robot, self.payload, safety)
            t1 = time.perf_counter()
            timed = [stage.time_path(leg) for leg in legs]
            self._stage(f"timing_{attempt}", t1)
            self.progress("sample", 0.85)
            profile, _ = sample_legs(
                self.robot, timed, self.opts.sample_period_s, self.payload, self.dynamics
            )
            self.progress("validate", 0.9)
            t2 = time.perf_counter()
            gate = validate_profile(profile, self.robot, self.world, req, self.dynamics)
            self._stage(f"validate_{attempt}", t2)
            if gate.passed:
                return profile, gate, timed
            last = gate
            failed = {c.name for c in gate.failures}
            if not failed <= LIMIT_CHECKS:
                break
            for name, k in (("velocity", 0), ("acceleration", 1), ("consistency", 1), ("effort", 2)):
                if name in failed:
                    level[k] = min(level[k] + 1, len(SAFETY_LEVELS) - 1)
            self.report.setdefault("retimed", []).append({"failed": sorted(failed), "safety": list(safety)})
        assert last is not None
        raise ValidationFailed(f"validation gate: {last.summary()}", report=last.to_dict())

    # -------------------------------------------------------------------- main
    def plan(self) -> PlanResult:
        """Run every stage; returns the validated result or raises the refusal."""
        sc = self.sc
        t = time.perf_counter()
        self.progress("check_start", 0.0)
        self._check_configuration(sc.start_q, "start")
        self._stage("check_start", t)
        t = time.perf_counter()
        self.progress("goals", 0.05)
        targets, lines = self.goals()
        compensations = self._compensate(targets, lines)
        self._stage("goals", t)
        t = time.perf_counter()
        self.progress("search", 0.15)
        waypoints, k = self.search(sc.start_q, targets)
        self._stage("search", t)
        t = time.perf_counter()
        self.progress("smooth", 0.7)
        legs = self.smooth(waypoints)
        line = lines[k]
        if line is not None and line.line is not None and line.line_s is not None:
            if len(line.line) == 2:
                a, b = line.line
                legs.append(JointPath((LinePiece(a, b, segment_time_length(self.robot, a, b)),)))
            else:
                legs.append(JointPath((SplinePiece.through(line.line_s, line.line),)))
            waypoints = np.vstack([waypoints, line.line[1:]])
        self._stage("smooth", t)
        commanded = compensations[k].T_base_frame_commanded if compensations else None
        req = gate_requirements(sc, self.payload, commanded)
        self.progress("timing", 0.75)
        profile, gate, timed = self.time_and_validate(legs, req)
        deflection = self._deflection_report(profile, compensations[k] if compensations else None)
        bound = single_drive_lower_bound(self.robot, profile.position[0], profile.position[-1])
        self.report.update(
            legs=len(legs),
            leg_durations_s=[round(tp.duration, 4) for tp in timed],
            duration_s=profile.duration_s,
            single_drive_lower_bound_s=bound,
            duration_ratio=profile.duration_s / bound if bound > 0 else 1.0,
            planning_time_s=self._elapsed(),
        )
        if line is not None and line.line is not None:
            # With an insertion the robot stops at the pre-insertion pose, so no trajectory of this shape
            # beats the single-drive bound to it plus the one along the line.
            u_pre = self.robot.drives_from_joints(line.line[0])
            staged = single_drive_lower_bound(
                self.robot, profile.position[0], u_pre
            ) + single_drive_lower_bound(self.robot, u_pre, profile.position[-1])
            self.report.update(
                staged_lower_bound_s=staged,
                staged_duration_ratio=profile.duration_s / staged if staged > 0 else 1.0,
            )
        self.progress("done", 1.0)
        return PlanResult(profile, gate, self.report, waypoints, deflection)

    def _compensate(self, targets: list[Array], lines: list[GoalCandidate | None]) -> list[Compensation]:
        """Move pose-goal targets onto their deflection-compensated commands (in place); [] when off."""
        sc = self.sc
        if not compensates_deflection(sc) or sc.goal_q is not None:
            return []
        assert sc.T_base_payload_goal is not None

        def accept(path: Array) -> bool:
            if len(path) == 1:
                return self._state_ok(path[0])
            if any(self.robot.violations(qi) for qi in path):
                return False
            if len(path) == 2:
                return self._state_ok(path[0]) and self._state_ok(path[1]) and self._motion_ok(*path)
            return self.world.check_path(path, self.plan_clearance, self.opts.motion_margin_m).valid

        T_tool_payload = sc.payload.T_tool_payload if sc.payload is not None else np.eye(4)
        res = compensate_goals(
            stiffness_model(self.robot),
            targets,
            lines,
            sc.T_base_payload_goal,
            self.payload,
            T_tool_payload,
            accept,
        )
        targets[:], lines[:] = res.targets, res.lines
        self.report["compensation"] = {"candidates": len(res.targets), "rejected": res.rejected}
        return res.compensations

    def _deflection_report(self, profile: DriveProfile, comp: Compensation | None) -> Array | None:
        """Predicted payload-frame deflection along the profile into the report; (N, 6) or None."""
        if self.robot.desc.stiffness is None:
            return None
        sc = self.sc
        T_tool_payload = sc.payload.T_tool_payload if sc.payload is not None else np.eye(4)
        # The deflection is a smooth function of the configuration: predicted at up to DEFLECTION_SAMPLES
        # evenly spaced samples (and the last) and interpolated in between, for the report and the plot.
        n = len(profile.joints)
        idx = np.unique(np.concatenate([np.arange(0, n, max(1, n // DEFLECTION_SAMPLES)), [n - 1]]))
        x_at = stiffness_model(self.robot).deflection_along(profile.joints[idx], self.payload, T_tool_payload)
        x = np.column_stack([np.interp(np.arange(n), idx, x_at[:, j]) for j in range(6)])
        tr, rot = np.linalg.norm(x[:, :3], axis=1), np.linalg.norm(x[:, 3:], axis=1)
        every = -(-len(idx) // 100)  # at most 100 points of the series in the report
        self.report["deflection"] = {
            "frame": "payload" if sc.payload is not None else "tool",
            "max_translation_m": float(tr.max()),
            "max_rotation_rad": float(rot.max()),
            "at_goal": StaticDeflection(x[-1, :3], x[-1, 3:]).to_dict(),
            "compensated": comp is not None,
            # The predicted deflection along the trajectory, at up to 100 evenly spaced samples.
            "along": {
                "t_s": profile.t[idx[::every]].round(4).tolist(),
                "translation_m": x_at[::every, :3].tolist(),
                "rotation_rad": x_at[::every, 3:].tolist(),
            },
        }
        if comp is not None:
            doc = comp.to_dict()
            self.report["goal"] = {
                "nominal": doc["nominal"],
                "compensated": doc["compensated"],
                "residual_m": comp.residual_m,
                "residual_rad": comp.residual_rad,
                "iterations": doc["iterations"],
            }
        return x


def plan(
    scenario: ResolvedScenario,
    progress: Progress | None = None,
) -> PlanResult:
    """Plan a resolved scenario; raises a :class:`~planner.exceptions.PlanRefused` (or GoalUnreachable)."""
    return Planner(scenario, progress).plan()


def refusal(exc: PlannerError) -> dict[str, Any]:
    """The machine-readable refusal body: ``{"status": "failed", "reason", "message", "details"}``."""
    return {"status": "failed", **exc.to_dict()}

"""Planning an assembly cycle: every leg an ordinary plan, one continuous profile, one gate over it all.

The legs (:mod:`planner.task.legs`) are planned in order, each from where the previous one ended:

1. the grasp line first (:func:`~planner.plan.goals.approach_lines` onto the grasp pose in the dock scene,
   the gripper allowed near the unit), keeping a line whose grasp configuration can hold the unit, whose
   lift-off line is clear with the unit held, and whose ends are clear where the neighbouring legs need;
2. ``pre_grasp``: the pipeline (:func:`~planner.plan.pipeline.plan_scenario`) from the park posture to the
   grasp line's start;
3. ``grasp_line`` and ``lift_off``: straight joint segments, timed and gated by the pipeline's timing stage
   (:func:`~planner.plan.retime.time_and_validate`) in their own worlds;
4. ``transit`` + ``insertion``: the pipeline from the end of the lift-off to the bay pose with its
   insertion line, the unit held (deflection-compensated as any payload pose goal);
5. ``retract``: a straight segment from the release configuration; ``park``: the pipeline back to the park
   posture, the unit now an obstacle in its bay.

At the grasp and the release the drives rest while the load changes; the tool jumps by the change of its
static deflection (:func:`~planner.dynamics.load_change.load_change`). Both sides of each jump and the
straight motion between them are certified (:func:`planner.gate.cycle.jump_check`); a release whose
spring-back brings the gripper or the robot within the clearance of anything but the released unit is
refused (:class:`~planner.core.exceptions.ReleaseInCollision`), and so is a unit the robot cannot hold at
its dock (:class:`~planner.core.exceptions.UnitNotHoldable`).

The legs' profiles are joined into one timeline (:func:`join_legs`, dwells at rest at the controller
period), and :func:`planner.gate.cycle.validate_cycle` certifies the whole of it.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from planner.core.exceptions import (
    ApproachInfeasible,
    PlannerError,
    UnitNotHoldable,
    ValidationFailed,
)
from planner.core.types import Array, IntArray
from planner.dynamics.holding import StaticForceCheck
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.gate.checks import GateReport
from planner.gate.cycle import CycleLeg, CycleRequirements, validate_cycle
from planner.gate.requirements import compensates_deflection, requirements_for
from planner.plan.context import PLANNER_SELF_CLEARANCE_M, PRODUCT, PlanContext, Progress, SearchPreset
from planner.plan.evidence import (
    collision_evidence,
    describe,
    dominant,
    force_evidence,
    motion_evidence,
    state_evidence,
)
from planner.plan.goals import approach_lines
from planner.plan.motion import certify_motion
from planner.plan.pipeline import PlanResult, plan_scenario
from planner.plan.retime import time_and_validate
from planner.scenario.resolve import ResolvedScenario
from planner.task.legs import (
    LEGS,
    LegState,
    allowed_label,
    body_label,
    leg,
    leg_scenario,
    leg_world,
    line_joints,
    payload_inertia,
)
from planner.task.resolve import ResolvedCycle
from planner.timing import stages
from planner.timing.path import JointPath, LinePiece, segment_time_length
from planner.timing.profile import DriveProfile
from planner.timing.stage import TimingFactory


@dataclass(frozen=True)
class LegTiming:
    """Where one leg lies on the cycle's timeline (the contract's ``legs`` entries).

    ``sample_end`` is exclusive; a leg starts where the previous one ended (``t_start_s`` is the time of
    the previous leg's last sample: a motion leaves from there, a dwell rests from there).
    """

    name: str
    kind: str
    payload: str | None
    t_start_s: float
    t_end_s: float
    sample_start: int
    sample_end: int

    def to_dict(self) -> dict[str, Any]:
        """The contract's leg entry (the fields, in order)."""
        return asdict(self)


@dataclass(frozen=True)
class CycleEvent:
    """An attach or a detach: when, which unit, in which leg, and the tool's jump [m]."""

    kind: str
    t_s: float
    unit: str
    leg: str
    springback_m: float
    rotation_rad: float

    def to_dict(self) -> dict[str, Any]:
        """The contract's event entry (plus the jump's rotation): the fields, in order."""
        return asdict(self)


@dataclass(frozen=True)
class CycleResult:
    """A planned, certified cycle: one profile, its legs and events, and the gate's report over it all.

    Attributes:
        profile: The whole cycle's drive profile (N samples).
        leg_of: The leg index (into ``legs``) of every sample (N,).
        legs: The legs in order, on the timeline.
        events: The attach and detach events.
        gate: The whole-cycle gate report (:func:`planner.gate.cycle.validate_cycle`).
        report: What the planning did (per-leg reports, timings, allowed pairs), JSON-able.
    """

    profile: DriveProfile
    leg_of: IntArray = field(repr=False)
    legs: tuple[LegTiming, ...]
    events: tuple[CycleEvent, ...]
    gate: GateReport
    report: dict[str, Any] = field(repr=False)


@contextmanager
def _in_leg(name: str) -> Iterator[None]:
    """Name the leg in any refusal raised inside (message prefix, ``details['leg']``)."""
    try:
        yield
    except PlannerError as exc:
        if "leg" not in exc.details:
            exc.message = f"{name}: {exc.message}"
            exc.args = (exc.message,)
            exc.details = {**exc.details, "leg": name}
        raise


@dataclass
class _Piece:
    """One planned leg before joining: its profile (motion) or its rest configuration (dwell)."""

    state: LegState
    q_end: Array
    profile: DriveProfile | None = None
    dwell_s: float = 0.0
    report: dict[str, Any] = field(default_factory=dict)


def plan_cycle(
    cyc: ResolvedCycle,
    progress: Progress | None = None,
    timing: TimingFactory | None = None,
    preset: SearchPreset = PRODUCT,
) -> CycleResult:
    """Plan, time and certify a whole assembly cycle (see the module docstring).

    Args:
        cyc: The resolved cycle.
        progress: Called with (leg name, fraction of the cycle done) as the legs start.
        timing: The timing stage factory (default: each leg's scenario's, as for a plan).
        preset: The search preset of the pipeline legs.

    Returns:
        The certified :class:`CycleResult`.

    Raises:
        UnitNotHoldable: no grasp of the unit on its dock can be held within the drive force limits (the
            drive and its force ratio).
        ReleaseInCollision: the spring-back at the release brings a body within the clearance (the bodies
            and distances).
        PlanRefused: a leg's refusal (its reason, ``details['leg']`` naming the leg).
        ValidationFailed: the whole-cycle gate refused the joined profile.
    """
    t0 = time.perf_counter()
    report_progress = progress or (lambda stage, fraction: None)
    robot = cyc.robot
    dynamics = Cabin8Dynamics.of(robot)
    pieces: list[_Piece] = []

    report_progress("grasp_line", 0.0)
    with _in_leg("grasp_line"):
        q_pre, q_grasp, grasp_ctx = _grasp_line(cyc, dynamics, progress, timing, preset)
    q_lift = line_joints(q_grasp, cyc.lift_line.offset)

    report_progress("pre_grasp", 0.1)
    with _in_leg("pre_grasp"):
        res = plan_scenario(
            _leg_of_cycle(cyc, leg("pre_grasp"), cyc.park_q, goal_q=q_pre), None, timing, preset
        )
    pieces.append(_Piece(leg("pre_grasp"), q_pre, res.profile, report=_leg_report(res)))

    with _in_leg("grasp_line"):
        line_ctx = PlanContext.build(
            _leg_of_cycle(cyc, leg("grasp_line"), q_pre, goal_q=q_grasp), None, timing, preset
        )
        line_ctx.report["grasp"] = grasp_ctx.report.get("grasp", {})
        pieces.append(_line_leg(line_ctx, leg("grasp_line"), q_pre, q_grasp))
    pieces.append(_Piece(leg("grasp"), q_grasp, dwell_s=cyc.grasp_dwell_s))

    report_progress("lift_off", 0.3)
    with _in_leg("lift_off"):
        lift_ctx = PlanContext.build(
            _leg_of_cycle(cyc, leg("lift_off"), q_grasp, goal_q=q_lift), None, timing, preset
        )
        pieces.append(_line_leg(lift_ctx, leg("lift_off"), q_grasp, q_lift))

    report_progress("transit", 0.4)
    with _in_leg("transit"):
        sc = _leg_of_cycle(
            cyc, leg("transit"), q_lift, T_base_unit_goal=cyc.T_base_unit_bay, approach=cyc.insertion_line
        )
        res = plan_scenario(sc, None, timing, preset)
    transit, insertion = _split_insertion(res)
    q_release = insertion.joints[-1]
    pieces.append(_Piece(leg("transit"), transit.joints[-1], transit, report=_leg_report(res)))
    pieces.append(
        _Piece(leg("insertion"), q_release, insertion, report={"compensated": compensates_deflection(sc)})
    )
    pieces.append(_Piece(leg("release"), q_release, dwell_s=cyc.release_dwell_s))

    report_progress("retract", 0.7)
    q_retract = line_joints(q_release, cyc.retract_line.offset)
    with _in_leg("retract"):
        retract_ctx = PlanContext.build(
            _leg_of_cycle(cyc, leg("retract"), q_release, goal_q=q_retract), None, timing, preset
        )
        _check_release(cyc, retract_ctx, q_release)
        _check_line_end(cyc, leg("park"), q_retract, "retract", "retract.distance")
        pieces.append(_line_leg(retract_ctx, leg("retract"), q_release, q_retract))

    report_progress("park", 0.8)
    with _in_leg("park"):
        res = plan_scenario(
            _leg_of_cycle(cyc, leg("park"), q_retract, goal_q=cyc.park_q), None, timing, preset
        )
    pieces.append(_Piece(leg("park"), cyc.park_q, res.profile, report=_leg_report(res)))

    report_progress("validate", 0.9)
    profile, leg_of, legs = join_legs(cyc, pieces, dynamics)
    req = cycle_requirements(cyc, legs)
    gate = validate_cycle(profile, robot, req, dynamics)
    if not gate.passed:
        raise ValidationFailed(f"validation gate (cycle): {gate.summary()}", report=gate.to_dict())
    events = cycle_events(cyc, profile, legs)
    report = {
        "planning_time_s": round(time.perf_counter() - t0, 4),
        "duration_s": profile.duration_s,
        "legs": {p.state.name: p.report for p in pieces if p.report},
        "allowed_pairs": allowed_pairs_report(cyc, legs),
        "gate": gate.to_dict(),
    }
    report_progress("done", 1.0)
    return CycleResult(profile, leg_of, legs, events, gate, report)


# ------------------------------------------------------------------------------------------------ legs
def _leg_of_cycle(cyc: ResolvedCycle, state: LegState, start_q: Array, **goal: Any) -> ResolvedScenario:
    """:func:`leg_scenario` for planning inside this cycle: its gate leaves the clearance to the cycle gate.

    The cycle gate (:func:`~planner.gate.cycle.validate_cycle`) certifies every leg's samples -- the very
    samples of the leg's plan, joined unchanged -- in the same world (:func:`leg_world`: the leg's payload,
    obstacles and allowed pair), with the same clearance and margin, rigid and sagging; the leg's own gate
    would certify them twice. A leg that fails there fails the cycle (never a weaker certificate).
    """
    return dataclasses.replace(
        leg_scenario(cyc, state, start_q, **goal), gate_collision=False, deflection_series=False
    )


def _leg_report(res: PlanResult) -> dict[str, Any]:
    keep = ("planning_time_s", "legs", "leg_durations_s", "approach", "compensation", "duration")
    return {k: v for k, v in res.report.items() if k in keep}


def _grasp_line(
    cyc: ResolvedCycle,
    dynamics: Cabin8Dynamics,
    progress: Progress | None,
    timing: TimingFactory | None,
    preset: SearchPreset,
) -> tuple[Array, Array, PlanContext]:
    """The grasp line (pre-grasp and grasp configurations) and its leg's context.

    Lines of fixed redundancy onto the grasp pose (:func:`approach_lines`, in the grasp line's world: the
    gripper may come near the unit). Every admissible grasp configuration of the grid is first held to
    the static forces of the *loaded* tool (``hold``): only those that can hold the unit are certified as
    lines, so a grasp that cannot hold never takes the place of one that can. Of the lines found, the
    first whose pre-grasp is clear without the allowed pair and whose lift-off line is clear with the unit
    held (and ends clear of the fixture).

    Raises:
        UnitNotHoldable: no admissible grasp configuration holds the unit (the drive and force ratio of
            the one closest to holding it).
        ApproachInfeasible: no holdable line is clear (the failing measurement closest to passing: bodies
            and distance below its requirement, a limit, or a drive, with the place).
    """
    T_tool_grasp = cyc.T_base_unit_dock @ np.linalg.inv(cyc.T_tool_unit)
    state = leg("grasp_line")
    sc = leg_scenario(cyc, state, cyc.park_q, goal_q=cyc.park_q)
    ctx = PlanContext.build(sc, progress, timing, preset)
    c = ctx.clearances
    loaded = StaticForceCheck(dynamics, cyc.unit_payload)
    evidence: list[dict[str, Any]] = []
    line = cyc.grasp_line
    lines, stats = approach_lines(
        ctx.world,
        T_tool_grasp,
        line.direction,
        line.distance_m,
        c.planner_m,
        c.motion_margin_m,
        ctx.forces,
        max_lines=6,
        evidence=evidence,
        hold=loaded,
    )
    for e in evidence:  # approach_lines speaks of an insertion line and its goal: here the grasp line
        e["where"] = (
            str(e.get("where", ""))
            .replace("insertion line", "grasp line")
            .replace("at the goal", "at the grasp")
        )
    if stats["admissible"] > 0 and stats["hold"] == stats["admissible"]:
        best = min((e for e in evidence if e["cause"] == "force"), key=lambda e: e["force_ratio"])
        raise UnitNotHoldable(
            f"{cyc.unit_name} ({cyc.unit_payload.mass:g} kg) cannot be held at its dock: {describe(best)} "
            f"(the best of {stats['admissible']} admissible grasp configurations)",
            drive=best["drive"],
            force_ratio=best["force_ratio"],
            allowed_ratio=best["allowed_ratio"],
            best=best,
            **stats,
        )
    lines = [x for x in lines if x.line is not None]
    pre_ctx = PlanContext.build(
        leg_scenario(cyc, leg("pre_grasp"), cyc.park_q, goal_q=cyc.park_q), None, timing, preset
    )
    lift_ctx = PlanContext.build(
        leg_scenario(cyc, leg("lift_off"), cyc.park_q, goal_q=cyc.park_q), None, timing, preset
    )
    carry_world = leg_world(cyc, leg("transit"), PLANNER_SELF_CLEARANCE_M)
    for cand in lines:
        assert cand.line is not None
        q_pre, q_grasp = cand.line[0], cand.line[-1]
        q_lift = line_joints(q_grasp, cyc.lift_line.offset)
        if not pre_ctx.state_ok(q_pre):
            _record(
                evidence,
                state_evidence(pre_ctx.world, q_pre, c.planner_m, "at the pre-grasp", pre_ctx.forces),
            )
            continue
        if not (lift_ctx.state_ok(q_lift) and lift_ctx.motion_ok(q_grasp, q_lift)):
            _record(evidence, _line_evidence(lift_ctx, q_grasp, q_lift, "lift-off"))
            continue
        if not carry_world.is_valid(q_lift, c.planner_m):
            where = "at the end of the lift-off (dock.lift.distance)"
            _record(evidence, state_evidence(carry_world, q_lift, c.planner_m, where))
            continue
        ctx.report["grasp"] = {"lines": len(lines), **stats}
        return q_pre, q_grasp, ctx
    closest = dominant(evidence)
    cause = f"; closest: {describe(closest)}" if closest is not None else ""
    raise ApproachInfeasible(
        f"no clear grasp line onto {cyc.unit_name} on its dock ({len(lines)} lines of fixed redundancy "
        f"that hold the unit tried){cause}",
        **stats,
        best=closest,
        candidates=evidence,
    )


def _record(evidence: list[dict[str, Any]], record: dict[str, Any] | None) -> None:
    """Append a failing measurement (None: nothing measured there fails)."""
    if record is not None:
        evidence.append(record)


def _line_evidence(ctx: PlanContext, q_a: Array, q_b: Array, what: str) -> dict[str, Any] | None:
    """Why the straight line q_a -> q_b fails the leg's planner checks: the failing measurement, where.

    In the order of the checks: the ends (:func:`state_evidence`: a limit, bodies short of the planner's
    clearance, a drive that cannot hold), the static forces along the line (the worst sample), then the
    certified walk (:func:`motion_evidence`: a limit, or bodies short of the clearance plus the walk's
    margin, at the fraction of the line where it failed). None when every check passes.
    """
    c = ctx.clearances
    for q, where in ((q_a, f"at the start of the {what} line"), (q_b, f"at the end of the {what} line")):
        ev = state_evidence(ctx.world, q, c.planner_m, where, ctx.forces)
        if ev is not None:
            return ev
    if not ctx.forces.segment_ok(q_a, q_b):
        # The samples segment_ok checks (every 0.02 m or rad of the largest joint change): one fails.
        ts = np.linspace(0.0, 1.0, int(max(1, np.ceil(float(np.max(np.abs(q_b - q_a))) / 0.02))) + 1)
        qs = q_a + ts[:, None] * (q_b - q_a)
        k = int(np.argmax(ctx.forces.ratios(qs)))
        return force_evidence(ctx.forces, qs[k], f"{100 * ts[k]:.0f}% along the {what} line")
    motion = certify_motion(ctx.world, q_a, q_b, c.planner_m, c.motion_margin_m)
    return motion_evidence(
        ctx.world, q_a, q_b, motion, c.planner_m, lambda t: f"{100 * t:.0f}% along the {what} line"
    )


def _line_leg(ctx: PlanContext, state: LegState, q_a: Array, q_b: Array) -> _Piece:
    """A straight leg q_a -> q_b: certified by the planner's clearance, then timed and gated.

    Raises:
        ApproachInfeasible: the segment is not clear (the failing measurement: bodies and distance below
            its requirement, a limit, or a drive, and where).
    """
    c = ctx.clearances
    motion = certify_motion(ctx.world, q_a, q_b, c.planner_m, c.motion_margin_m)
    if not (motion.valid and ctx.state_ok(q_a) and ctx.state_ok(q_b) and ctx.forces.segment_ok(q_a, q_b)):
        what = state.name.replace("_", "-")
        ev = _line_evidence(ctx, q_a, q_b, what)
        cause = describe(ev) if ev is not None else "its certified walk failed"
        raise ApproachInfeasible(
            f"the straight {state.name} line is not clear: {cause}", **({"best": ev} if ev else {})
        )
    path = JointPath((LinePiece(q_a, q_b, segment_time_length(ctx.robot, q_a, q_b)),))
    profile, gate, _ = time_and_validate(ctx, [path], requirements_for(ctx.sc, ctx.payload))
    return _Piece(state, np.asarray(q_b, dtype=float), profile, report={"gate_checks": len(gate.checks)})


def _split_insertion(res: PlanResult) -> tuple[DriveProfile, DriveProfile]:
    """The transit and insertion parts of a plan whose last leg is the insertion line (sharing a sample)."""
    assert res.leg_of is not None
    k = int(np.flatnonzero(res.leg_of == res.leg_of[-1])[0])  # the insertion's first sample (at rest)
    return _slice(res.profile, 0, k + 1), _slice(res.profile, k, len(res.profile.t))


def _slice(p: DriveProfile, a: int, b: int) -> DriveProfile:
    """Samples a..b-1 of a profile, its clock restarted at 0."""
    return DriveProfile(
        p.drive_names,
        p.drive_units,
        p.joint_names,
        p.sample_period_s,
        p.t[a:b] - p.t[a],
        p.position[a:b],
        p.velocity[a:b],
        p.acceleration[a:b],
        None if p.effort is None else p.effort[a:b],
        p.joints[a:b],
    )


def _check_release(cyc: ResolvedCycle, ctx: PlanContext, q_release: Array) -> None:
    """Refuse a release whose spring-back leaves a body within the clearance (see :func:`jump_check`)."""
    from planner.core.exceptions import ReleaseInCollision
    from planner.gate.cycle import jump_check

    chk = jump_check(
        ctx.robot,
        ctx.world,
        q_release,
        cyc.unit_payload,
        None,
        cyc.T_tool_unit,
        ctx.clearances.requested_m,
        "release",
    )
    if not chk.passed:
        raise ReleaseInCollision(
            f"the release's spring-back: {chk.detail}", springback_m=chk.worst, sample=None
        )


def _check_line_end(cyc: ResolvedCycle, next_state: LegState, q: Array, what: str, field_name: str) -> None:
    """Refuse a line whose end is within the planner's clearance of anything in the next leg's world."""
    world = leg_world(cyc, next_state, PLANNER_SELF_CLEARANCE_M)
    sc = leg_scenario(cyc, next_state, q, goal_q=q)
    from planner.plan.context import Clearances

    c = Clearances.of(sc.options)
    if not world.is_valid(q, c.planner_m):
        where = f"at the end of the {what} line"
        ev = state_evidence(world, q, c.planner_m, where)
        if ev is None:
            # The state check's grown bodies refuse what the exact distances keep (near a box's corners a
            # grown box overstates the clearance): say so, the closest bodies apart from the evidence.
            near = collision_evidence(world, q, c.planner_m, where)
            raise ApproachInfeasible(
                f"the {what} line ends where the state check cannot certify {1e3 * c.planner_m:.1f} mm of "
                f"clearance (the exact distances keep it: {describe(near)}; lengthen or turn {field_name})",
                closest=near,
                field=field_name,
            )
        if "bodies" in ev:
            a, b = ev["bodies"]
            ev["bodies"] = [body_label(cyc, next_state, a), b]
        raise ApproachInfeasible(
            f"the {what} line ends where the next leg cannot start: {describe(ev)} (lengthen {field_name})",
            best=ev,
            field=field_name,
        )


# ---------------------------------------------------------------------------------------- the timeline
def join_legs(
    cyc: ResolvedCycle, pieces: list[_Piece], dynamics: Cabin8Dynamics
) -> tuple[DriveProfile, IntArray, tuple[LegTiming, ...]]:
    """Join the legs into one profile at the controller period (sample k at k * period).

    A motion leg's first sample is the previous leg's last (both at rest there: checked to 1e-9) and is
    not repeated; a dwell adds ceil(dwell / period) samples at rest (zero velocity and acceleration) with
    the forces that hold the dwell's load. Every sample belongs to one leg (its forces computed with that
    leg's payload).
    """
    robot = cyc.robot
    period = float(cyc.spec.options.sample_period_s)
    u_parts: list[Array] = []
    v_parts: list[Array] = []
    a_parts: list[Array] = []
    e_parts: list[Array] = []
    q_parts: list[Array] = []
    counts: list[int] = []
    last_q: Array | None = None
    for k, p in enumerate(pieces):
        if p.profile is not None:
            prof = p.profile
            skip = 0 if k == 0 else 1
            if last_q is not None and float(np.max(np.abs(prof.joints[0] - last_q))) > 1e-9:
                raise AssertionError(f"leg {p.state.name} does not start where the previous leg ended")
            assert prof.effort is not None
            u_parts.append(prof.position[skip:])
            v_parts.append(prof.velocity[skip:])
            a_parts.append(prof.acceleration[skip:])
            e_parts.append(prof.effort[skip:])
            q_parts.append(prof.joints[skip:])
            counts.append(len(prof.t) - skip)
            last_q = prof.joints[-1]
        else:
            assert last_q is not None
            n = int(np.ceil(p.dwell_s / period - 1e-9)) if p.dwell_s > 0 else 0
            q = np.repeat(last_q[None, :], n, axis=0)
            u = robot.drives_from_joints(last_q)
            u_parts.append(np.repeat(u[None, :], n, axis=0))
            v_parts.append(np.zeros((n, robot.n_drives)))
            a_parts.append(np.zeros((n, robot.n_drives)))
            tau = dynamics.drive_forces_batch(
                q, np.zeros_like(q), np.zeros_like(q), payload_inertia(cyc, p.state)
            )
            e_parts.append(np.asarray(tau).reshape(n, robot.n_drives))
            q_parts.append(q)
            counts.append(n)
    position = np.vstack(u_parts)
    n_total = len(position)
    t = np.arange(n_total, dtype=float) * period
    profile = DriveProfile(
        robot.drive_names,
        robot.drive_units,
        robot.joint_names,
        period,
        t,
        position,
        np.vstack(v_parts),
        np.vstack(a_parts),
        np.vstack(e_parts),
        np.vstack(q_parts),
    )
    bounds = np.concatenate([[0], np.cumsum(counts)]).astype(int)
    leg_of = np.repeat(np.arange(len(pieces)), counts).astype(np.int64)
    legs = []
    for k, p in enumerate(pieces):
        s, e = int(bounds[k]), int(bounds[k + 1])
        t_start = float(t[s - 1]) if s > 0 else 0.0
        t_end = float(t[e - 1]) if e > s else t_start
        legs.append(
            LegTiming(
                p.state.name,
                p.state.kind,
                cyc.spec.unit.id if p.state.held else None,
                t_start,
                t_end,
                s,
                e,
            )
        )
    return profile, leg_of, tuple(legs)


def cycle_requirements(cyc: ResolvedCycle, legs: tuple[LegTiming, ...]) -> CycleRequirements:
    """What the whole-cycle gate demands: each leg's world, load and line, the grasp, bay and park goals."""
    robot = cyc.robot
    sc_bay = leg_scenario(cyc, leg("insertion"), cyc.park_q, T_base_unit_goal=cyc.T_base_unit_bay)
    out = []
    for timing_ in legs:
        state = leg(timing_.name)
        line = {
            "grasp_line": cyc.grasp_line,
            "lift_off": cyc.lift_line,
            "insertion": cyc.insertion_line,
            "retract": cyc.retract_line,
        }.get(state.name)
        out.append(
            CycleLeg(
                name=state.name,
                kind=state.kind,
                sample_start=timing_.sample_start,
                sample_end=timing_.sample_end,
                world=leg_world(cyc, state),
                payload=payload_inertia(cyc, state),
                line_direction=None if line is None else line.direction,
                line_distance_m=0.0 if line is None else line.distance_m,
                labels={"payload": body_label(cyc, state, "payload")},
                allowed=allowed_label(cyc, state.allowed),
            )
        )
    return CycleRequirements(
        start_u=cyc.park_u,
        park_u=cyc.park_u,
        clearance_m=float(cyc.spec.options.clearance_m),
        sample_period_s=float(cyc.spec.options.sample_period_s),
        jerk_limited=stages.select(cyc.base.options.timing, cyc.base.robot).binds_jerk,
        legs=tuple(out),
        T_tool_unit=cyc.T_tool_unit,
        T_base_unit_dock=cyc.T_base_unit_dock,
        T_base_unit_bay=cyc.T_base_unit_bay,
        unit_payload=cyc.unit_payload,
        unit_name=cyc.unit_name,
        compensate_bay=compensates_deflection(sc_bay),
        stiffness=robot.desc.stiffness is not None,
    )


def cycle_events(
    cyc: ResolvedCycle, profile: DriveProfile, legs: tuple[LegTiming, ...]
) -> tuple[CycleEvent, ...]:
    """The attach (start of the grasp dwell) and detach (start of the release dwell) events.

    Each with the tool's jump at the unit frame (:func:`~planner.dynamics.load_change.load_change`).
    """
    from planner.dynamics.load_change import load_change

    out = []
    for kind, name, before, after in (
        ("attach", "grasp", None, cyc.unit_payload),
        ("detach", "release", cyc.unit_payload, None),
    ):
        lt = next(x for x in legs if x.name == name)
        q = profile.joints[lt.sample_start - 1]
        change = load_change(cyc.robot, q, before, after, cyc.T_tool_unit)
        out.append(
            CycleEvent(kind, lt.t_start_s, cyc.spec.unit.id, name, change.springback_m, change.rotation_rad)
        )
    return tuple(out)


def allowed_pairs_report(cyc: ResolvedCycle, legs: tuple[LegTiming, ...]) -> list[dict[str, Any]]:
    """The explicitly allowed pairs: the bodies and the legs on which each may come within the clearance."""
    out: dict[tuple[str, str], list[str]] = {}
    for lt in legs:
        pair = allowed_label(cyc, leg(lt.name).allowed)
        if pair is not None:
            out.setdefault(pair, []).append(lt.name)
    return [{"bodies": list(p), "legs": names} for p, names in out.items()]


def plan_cycle_scenarios(cyc: ResolvedCycle) -> dict[str, ResolvedScenario]:
    """Every leg's world-defining scenario (start and goal at the park posture): for inspection and tests."""
    return {s.name: leg_scenario(cyc, s, cyc.park_q, goal_q=cyc.park_q) for s in LEGS}

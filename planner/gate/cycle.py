"""The validation gate over a whole assembly cycle: one report for the joined timeline of its legs.

The gate trusts nothing the planner computed. From the sampled drive profile, the legs' sample ranges and
what each leg is (its collision world: cabin, obstacles, allowed pair; its load; its straight line) it
re-derives and checks:

``finite`` ... ``consistency``  the drive checks of a plan (:func:`~planner.gate.drive_checks.drive_checks`)
                                over every sample: start at the park posture at rest, time, position,
                                velocity, acceleration, jerk, integration, at rest at the end;
``legs``          the legs cover the samples in order, without gaps;
``workspace``     the parallel stage assembles with every margin at every sample;
``effort``        the forces recomputed from the inverse dynamics *with each leg's load* match the reported
                  ones and are within the limits;
``dwell``         the robot rests at every dwell sample: positions held, velocity and acceleration zero;
``collision``     each leg's polyline (from the previous leg's last sample) is certified against that leg's
                  world: rigid in one batched pass (:meth:`CollisionWorld.along`, obstacles included), and
                  sagging under that leg's load (:func:`~planner.gate.checks.deflected_joints`);
``line``          each straight leg keeps the unit frame within 1 mm of its line with a constant
                  orientation (0.1 deg), never stepping back, for the line's full length;
``grasp`` / ``bay`` / ``park``  the unit frame at the grasp is the dock pose (1 mm / 0.1 deg); at the end of
                  the insertion the unit's predicted deflected pose is the bay pose (compensated: 0.01 mm /
                  1e-5 rad; else its rigid pose within 1 mm / 0.1 deg); the last sample is the park posture;
``springback_grasp`` / ``springback_release``  at each load change the tool jumps by the change of its
                  static deflection (:func:`~planner.dynamics.load_change.load_change`, reported in mm,
                  in metres in ``worst``); the sagging robot before and after and the straight motion
                  between them keep the clearance in the event's world (:func:`jump_check`);
``allowed_pair``  (informational) the closest the explicitly allowed pair comes on the legs that allow it
                  (exact over every sample of those legs).

``min_clearance_m``: the smallest exact FCL distance over *every* sample of the cycle, each leg's samples
(from the previous leg's last) measured in the leg's own world -- its payload state, the installed units,
the fixture, the unit where it rests; allowed pairs apart, reported by ``allowed_pair`` -- found by the
legs' batched passes (:mod:`planner.collision.along`, to within ``min_clearance_at.tolerance_m``);
``min_clearance_bound_m`` a certified lower bound of it along every leg's polyline, between samples
included; ``min_clearance_at`` the sample, time, leg and bodies (as reports name them: ``unit A3`` for the
carried unit, ``gripper``, ``unit A2`` for an installed unit, ``cabin``) of the exact figure.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.collision.along import CLEARANCE_TOL_M, AlongPath, ClearanceAlong
from planner.collision.world import DEFAULT_SELF_CLEARANCE_M, CollisionWorld
from planner.core.exceptions import OutsideWorkspace
from planner.core.so3 import rotation_angles, rotation_log
from planner.core.types import Array
from planner.dynamics.load_change import load_change
from planner.dynamics.models import DriveDynamics, drive_dynamics
from planner.dynamics.payload import RigidPayload
from planner.dynamics.stiffness import COMPENSATION_TOL_M, COMPENSATION_TOL_RAD
from planner.gate.checks import deflected_joints, deflected_joints_of, sagging_certificate
from planner.gate.drive_checks import Check, GateReport, drive_checks, ratio_check
from planner.gate.requirements import (
    GATE_MOTION_MARGIN_M,
    GOAL_ANGLE_TOL_RAD,
    GOAL_POSITION_TOL_M,
    LIMIT_TOLERANCE,
    LINE_TOL_M,
)
from planner.robots.cabin8 import Cabin8
from planner.timing.profile import DriveProfile


@dataclass(frozen=True)
class CycleLeg:
    """What one leg of a cycle must satisfy.

    Attributes:
        name: The leg's name (``transit``).
        kind: ``motion`` or ``dwell``.
        sample_start, sample_end: Its samples [start, end).
        world: Its collision world (cabin, obstacles, allowed pair, tool body).
        payload: The tool's load on the leg (None: none).
        line_direction: A straight leg's unit direction (3,) in the base frame, else None.
        line_distance_m: Its length [m].
        labels: World body names -> report names (``payload`` -> ``unit A3`` or ``gripper``).
        allowed: The leg's allowed pair as reports name it, or None.
    """

    name: str
    kind: str
    sample_start: int
    sample_end: int
    world: CollisionWorld = field(repr=False)
    payload: RigidPayload | None = None
    line_direction: Array | None = field(default=None, repr=False)
    line_distance_m: float = 0.0
    labels: dict[str, str] = field(default_factory=dict)
    allowed: tuple[str, str] | None = None

    def rows(self) -> slice:
        """Its samples from the previous leg's last (where its motion or rest begins)."""
        return slice(max(0, self.sample_start - 1), self.sample_end)


@dataclass(frozen=True)
class CycleRequirements:
    """What a cycle's profile must do (built by :func:`planner.task.cycle.cycle_requirements`)."""

    start_u: Array = field(repr=False)
    park_u: Array = field(repr=False)
    clearance_m: float
    sample_period_s: float
    jerk_limited: bool
    legs: tuple[CycleLeg, ...]
    T_tool_unit: Array = field(repr=False)
    T_base_unit_dock: Array = field(repr=False)
    T_base_unit_bay: Array = field(repr=False)
    unit_payload: RigidPayload
    unit_name: str
    compensate_bay: bool
    stiffness: bool


def validate_cycle(
    profile: DriveProfile, robot: Cabin8, req: CycleRequirements, dynamics: DriveDynamics | None = None
) -> GateReport:
    """Run every check of the cycle gate (module docstring) on a cycle's joined profile."""
    checks, peaks = drive_checks(profile, robot, req.start_u, req.sample_period_s, req.jerk_limited)
    n = len(profile.t)
    if not checks[0].passed:
        return GateReport(tuple(checks), n, float("nan"), {})
    checks.append(_legs_check(req, n))
    if not checks[-1].passed:
        return GateReport(tuple(checks), n, float("nan"), peaks)
    u, ud, udd = profile.position, profile.velocity, profile.acceleration
    try:
        q = robot.joints_from_drives(u)
    except OutsideWorkspace as exc:
        checks.append(Check("workspace", False, exc.message, None, exc.details.get("index")))
        return GateReport(tuple(checks), n, float("nan"), peaks)
    admissibility = req.legs[0].world.model.admissibility
    bad = ~admissibility.admissible_batch(q)
    if bad.any():
        i = int(np.argmax(bad))
        names = ", ".join(v["name"] for v in admissibility.violations(q[i]))
        checks.append(Check("workspace", False, f"sample {i} violates {names}", None, i))
    else:
        checks.append(
            Check("workspace", True, "stage on its working branch with every margin at every sample")
        )
    # Forces, each leg with its own load.
    dyn = dynamics or drive_dynamics(robot)
    assert dyn is not None, "the cycle gate needs the robot's force model"
    qd, qdd = dyn.joint_rates_batch(q, ud, udd)
    tau = np.empty_like(u)
    for leg in req.legs:
        s, e = leg.sample_start, leg.sample_end
        if e > s:
            tau[s:e] = dyn.drive_forces_batch(q[s:e], qd[s:e], qdd[s:e], leg.payload)
    chk, peaks["effort"] = ratio_check("effort", tau, robot.limits.effort_max, robot, "N or N m", n)
    if profile.effort is None:
        checks.append(Check("effort", False, "the profile carries no forces", chk.worst, chk.sample))
    else:
        mismatch = float(np.max(np.abs(tau - profile.effort) / robot.limits.effort_max[None, :]))
        checks.append(
            Check(
                "effort",
                chk.passed and mismatch <= LIMIT_TOLERANCE,
                chk.detail
                + f"; reported vs recomputed (each leg's load) differ by {100 * mismatch:.2f}% of the limit",
                chk.worst,
                chk.sample,
            )
        )
    checks.append(_dwell_check(req, u, ud, udd))
    T_unit = robot.fk_batch(q) @ req.T_tool_unit
    collision, figure, allowed = _collision_checks(robot, q, req)
    checks.extend(collision)
    checks.append(_line_check(T_unit, req))
    checks.extend(_goal_checks(robot, q, T_unit, u, req))
    for name, before, after in (("grasp", None, req.unit_payload), ("release", req.unit_payload, None)):
        leg = next(x for x in req.legs if x.name == name)
        q_event = q[max(0, leg.sample_start - 1)]
        checks.append(
            jump_check(
                robot, leg.world, q_event, before, after, req.T_tool_unit, req.clearance_m, name, leg.labels
            )
        )
    checks.extend(_allowed_checks(allowed))
    if figure is None:  # a leg failed its certificate: the failure says where, no figure is claimed
        return GateReport(tuple(checks), n, float("nan"), peaks)
    where = {
        "t_s": float(profile.t[figure.sample]),
        "sample": figure.sample,
        "bodies": list(figure.bodies),
        "tolerance_m": figure.tolerance_m,
        "leg": figure.leg,
    }
    return GateReport(tuple(checks), n, figure.distance_m, peaks, figure.bound_m, where)


@dataclass(frozen=True)
class CycleClearance:
    """The smallest distance over a whole cycle, each leg's samples measured in the leg's own world.

    Attributes:
        distance_m: Exact FCL distance at ``sample`` between ``bodies`` (in the leg's world): no sample of
            any leg has an exact distance (any body to the cabin, an obstacle, or another checked body;
            allowed pairs apart) below it by more than ``tolerance_m``.
        bound_m: Certified lower bound of every such distance along every leg's polyline (between samples).
        sample: The cycle's sample of ``distance_m``.
        bodies: The two bodies as reports name them (``unit A3``, ``gripper``, ``unit A2``, ``cabin`` ...).
        leg: The leg of ``sample``.
        tolerance_m: What the branch and bound proved (see :class:`~planner.collision.along.ClearanceAlong`).
    """

    distance_m: float
    bound_m: float
    sample: int
    bodies: tuple[str, str]
    leg: str
    tolerance_m: float


@dataclass(frozen=True)
class _LegPass:
    """One leg's certified batched pass: the leg, its first cycle sample and the pass."""

    leg: CycleLeg
    first: int
    last: int
    along: AlongPath


def _legs_check(req: CycleRequirements, n: int) -> Check:
    ends = [0]
    for leg in req.legs:
        if leg.sample_start != ends[-1] or leg.sample_end < leg.sample_start:
            return Check("legs", False, f"leg {leg.name} starts at sample {leg.sample_start}, not {ends[-1]}")
        ends.append(leg.sample_end)
    if ends[-1] != n:
        return Check("legs", False, f"the legs cover {ends[-1]} samples, the profile has {n}")
    return Check("legs", True, f"{len(req.legs)} legs cover the {n} samples in order")


def _dwell_check(req: CycleRequirements, u: Array, ud: Array, udd: Array) -> Check:
    worst, where = 0.0, ""
    count = 0
    for leg in req.legs:
        if leg.kind != "dwell":
            continue
        s, e = max(0, leg.sample_start - 1), leg.sample_end
        count += e - s
        dev = max(
            float(np.max(np.abs(u[s:e] - u[s]), initial=0.0)),
            float(np.max(np.abs(ud[s:e]), initial=0.0)),
            float(np.max(np.abs(udd[s:e]), initial=0.0)),
        )
        if dev > worst:
            worst, where = dev, leg.name
    ok = worst == 0.0
    detail = (
        f"at rest on every dwell sample ({count} samples, positions held, velocity and acceleration zero)"
        if ok
        else f"the {where} dwell moves: largest position change, velocity or acceleration {worst:.3g}"
    )
    return Check("dwell", ok, detail, worst)


def _label(leg: CycleLeg, detail: str) -> str:
    for name, label in leg.labels.items():
        if name != label:
            detail = detail.replace(f"{name} within", f"{label} within").replace(f"of {name}", f"of {label}")
    return detail


def _collision_checks(
    robot: Cabin8, q: Array, req: CycleRequirements
) -> tuple[list[Check], CycleClearance | None, list[tuple[CycleLeg, ClearanceAlong]]]:
    """Each leg's samples certified in its world, rigid and sagging under its load; the cycle's figure.

    The rigid robot: each leg's polyline (from the previous leg's last sample) in one batched pass of its
    world (:meth:`CollisionWorld.along`: cabin, robot pairs, installed units, fixture, the unit where it
    rests), which also gives the leg's exact minimum over its samples; the legs' figures combine into the
    cycle's (:func:`_cycle_clearance`). The sagging robot under each leg's load: the certified walk.
    Returns (checks, the cycle's figure or None after a failure, each allowed pair's figure per leg).
    """
    failures: list[Check] = []
    passes: list[_LegPass] = []
    worst_sag, exact, walked = 0.0, 0, 0
    sagging = _sagging_legs(robot, q, req) if req.stiffness else {}
    for k, leg in enumerate(req.legs):
        sl = leg.rows()
        rows = q[sl]
        first = sl.start
        # A leg of one sample (an empty leg at the start): its sample twice, a path at rest.
        along = leg.world.along(rows if len(rows) >= 2 else np.vstack([rows, rows]))
        rep = along.certify(req.clearance_m, DEFAULT_SELF_CLEARANCE_M, GATE_MOTION_MARGIN_M)
        exact += rep.exact_queries
        walked += rep.walked
        if not rep.valid:
            what = "; ".join(_label(leg, c.detail) for c in rep.contacts) or "not certified"
            bad = None if rep.first_bad is None else first + rep.first_bad
            failures.append(Check("collision", False, f"{leg.name}: from sample {bad}: {what}", None, bad))
            continue
        passes.append(_LegPass(leg, first, sl.stop - 1, along))
        if not req.stiffness:
            continue
        q_def, sag = sagging[k]
        worst_sag = max(worst_sag, sag)
        rep_def = sagging_certificate(leg.world, q_def, req.clearance_m, GATE_MOTION_MARGIN_M, along)
        exact += rep_def.exact_queries
        walked += rep_def.walked
        if not rep_def.valid:
            what = "; ".join(_label(leg, c.detail) for c in rep_def.contacts) or "not certified"
            bad = None if rep_def.first_bad is None else first + rep_def.first_bad
            failures.append(
                Check(
                    "collision",
                    False,
                    f"{leg.name}, sagging ({1e3 * sag:.2f} mm): from sample {bad}: {what}",
                    None,
                    bad,
                )
            )
    allowed = [(p.leg, c) for p in passes if (c := p.along.allowed_clearance()) is not None]
    if failures:
        return failures, None, allowed
    figure = _cycle_clearance(passes)
    return (
        [
            Check(
                "collision",
                True,
                f"certified clearance >= {req.clearance_m} m along every leg's polyline in its world "
                f"(installed units, fixture, the unit where it rests), rigid and sagging (up to "
                f"{1e3 * worst_sag:.2f} mm) alike ({exact} exact distances, {walked} pieces walked)",
            )
        ],
        figure,
        allowed,
    )


def _sagging_legs(robot: Cabin8, q: Array, req: CycleRequirements) -> dict[int, tuple[Array, float]]:
    """Each leg's sagging configurations under its load (:func:`deflected_joints`), by leg index.

    The legs of one load share one evaluation of the stiffness model (:func:`deflected_joints_of`).
    """
    loads: list[RigidPayload | None] = []
    for leg in req.legs:
        if not any(leg.payload is x for x in loads):
            loads.append(leg.payload)
    out: dict[int, tuple[Array, float]] = {}
    for load in loads:
        ks = [k for k, leg in enumerate(req.legs) if leg.payload is load]
        paths = [q[req.legs[k].rows()] for k in ks]
        out.update(zip(ks, deflected_joints_of(robot, paths, load, req.T_tool_unit), strict=True))
    return out


def _cycle_clearance(passes: list[_LegPass]) -> CycleClearance | None:
    """The cycle's smallest distance: each leg's exact minimum over its samples, the smallest of them.

    The legs are searched in the order of their smallest bound, each with the smallest figure found so far
    as its cap (a leg need not resolve distances above it); the tolerance is what every leg proved: no
    sample of leg l is below min(best_l - tol, its smallest open bound), so none of the cycle is below the
    smallest of those.
    """
    if not passes:
        return None

    def key(p: _LegPass) -> float:
        a = p.along
        return float(np.min(a.lower[:, : a.n_checked])) if a.n_checked else np.inf

    best: tuple[ClearanceAlong, _LegPass] | None = None
    proven, bound = np.inf, np.inf
    for p in sorted(passes, key=key):
        cap = best[0].distance_m if best is not None else np.inf
        c = p.along.clearance(cap_m=cap)
        proven = min(proven, c.distance_m - c.tolerance_m)
        bound = min(bound, c.bound_m)
        if best is None or c.distance_m < best[0].distance_m:
            best = (c, p)
    assert best is not None
    c, p = best
    if not np.isfinite(c.distance_m):
        return None
    sample = min(p.first + c.sample, p.last)  # a one-sample leg's path repeats its sample
    bodies = (p.leg.labels.get(c.bodies[0], c.bodies[0]), p.leg.labels.get(c.bodies[1], c.bodies[1]))
    tolerance = max(CLEARANCE_TOL_M, c.distance_m - proven)
    return CycleClearance(c.distance_m, min(bound, c.distance_m), sample, bodies, p.leg.name, tolerance)


def _line_check(T_unit: Array, req: CycleRequirements) -> Check:
    """Every straight leg: the unit frame on its line, constant orientation, monotone, full length."""
    worst_off, worst_ang, details = 0.0, 0.0, []
    ok = True
    for leg in req.legs:
        if leg.line_direction is None:
            continue
        T = T_unit[leg.rows()]
        d = leg.line_direction
        rel = T[:, :3, 3] - T[0, :3, 3]
        along = rel @ d
        off = float(np.max(np.linalg.norm(rel - np.outer(along, d), axis=1)))
        ang = float(np.max(rotation_angles(T[0, :3, :3].T[None] @ T[:, :3, :3])))
        back = float(max(0.0, -float(np.min(np.diff(along), initial=0.0))))
        short = abs(float(along[-1]) - leg.line_distance_m)
        good = off <= LINE_TOL_M and ang <= GOAL_ANGLE_TOL_RAD and back <= 1e-9 and short <= LINE_TOL_M
        ok = ok and good
        worst_off, worst_ang = max(worst_off, off), max(worst_ang, ang)
        details.append(
            f"{leg.name} {1e3 * float(along[-1]):.1f} mm ({1e3 * off:.4f} mm off, {np.rad2deg(ang):.4f} deg"
            f"{', steps back' if back > 1e-9 else ''})"
        )
    return Check("line", ok, "straight legs: " + "; ".join(details), worst_off)


def _pose_error(T: Array, T_goal: Array) -> tuple[float, float]:
    dp = float(np.linalg.norm(T[:3, 3] - T_goal[:3, 3]))
    da = float(np.linalg.norm(rotation_log(T_goal[:3, :3].T @ T[:3, :3])))
    return dp, da


def _goal_checks(robot: Cabin8, q: Array, T_unit: Array, u: Array, req: CycleRequirements) -> list[Check]:
    out = []
    grasp_end = next(x for x in req.legs if x.name == "grasp_line").sample_end - 1
    dp, da = _pose_error(T_unit[grasp_end], req.T_base_unit_dock)
    out.append(
        Check(
            "grasp",
            dp <= GOAL_POSITION_TOL_M and da <= GOAL_ANGLE_TOL_RAD,
            f"at the grasp the unit frame is off the dock pose by {1e3 * dp:.3f} mm, "
            f"{np.rad2deg(da):.4f} deg",
            dp,
            grasp_end,
        )
    )
    bay_end = next(x for x in req.legs if x.name == "insertion").sample_end - 1
    if req.compensate_bay:
        from planner.dynamics.stiffness import deflected_pose, stiffness_model

        x = stiffness_model(robot).deflection(q[bay_end], req.unit_payload, req.T_tool_unit).twist
        dp, da = _pose_error(deflected_pose(T_unit[bay_end], x), req.T_base_unit_bay)
        ok = dp <= COMPENSATION_TOL_M and da <= COMPENSATION_TOL_RAD
        detail = (
            f"the unit's predicted deflected pose ({1e3 * float(np.linalg.norm(x[:3])):.3f} mm sag) is off "
            f"the bay pose by {1e3 * dp:.4f} mm, {da:.2e} rad"
        )
    else:
        dp, da = _pose_error(T_unit[bay_end], req.T_base_unit_bay)
        ok = dp <= GOAL_POSITION_TOL_M and da <= GOAL_ANGLE_TOL_RAD
        detail = (
            f"the unit frame is off the bay pose by {1e3 * dp:.3f} mm, {np.rad2deg(da):.4f} deg "
            "(not compensated)"
        )
    out.append(Check("bay", ok, detail, dp, bay_end))
    e = float(np.max(np.abs(u[-1] - req.park_u)))
    out.append(Check("park", e <= 1e-6, f"final drives off the park posture by {e:.3g}", e, len(u) - 1))
    return out


def jump_check(
    robot: Cabin8,
    world: CollisionWorld,
    q: Array,
    before: RigidPayload | None,
    after: RigidPayload | None,
    T_tool_frame: Array,
    clearance_m: float,
    what: str,
    labels: dict[str, str] | None = None,
) -> Check:
    """The load change at ``q``.

    the tool's jump, and the sagging robot before and after it and the straight motion between them
    certified to keep ``clearance_m`` in ``world`` (the gate's margin).

    ``worst`` is the jump of the ``T_tool_frame`` origin [m]
    (:func:`~planner.dynamics.load_change.load_change`).
    A failure names the bodies and their exact distance after the jump.
    """
    change = load_change(robot, q, before, after, T_tool_frame)
    q2 = np.atleast_2d(np.asarray(q, dtype=float))
    q_before = deflected_joints(robot, q2, before, T_tool_frame)[0][0]
    q_after = deflected_joints(robot, q2, after, T_tool_frame)[0][0]
    rep = world.check_motion(q_before, q_after, clearance_m, GATE_MOTION_MARGIN_M)
    size = f"{1e3 * change.springback_m:.3f} mm, {1e3 * change.rotation_rad:.3f} mrad"
    name = f"springback_{what}"
    if rep.valid:
        return Check(
            name,
            True,
            f"at the {what} the tool jumps {size} (load change); both sides and the motion between them keep "
            f"{clearance_m} m",
            change.springback_m,
        )
    d = world.min_distance(q_after)
    a, b = (labels or {}).get(d.bodies[0], d.bodies[0]), (labels or {}).get(d.bodies[1], d.bodies[1])
    other = "the cabin" if b == "cabin" else b
    return Check(
        name,
        False,
        f"at the {what} the tool jumps {size} (load change) and {a} comes {1e3 * d.distance_m:.2f} mm from "
        f"{other} ({1e3 * clearance_m:.1f} mm required)",
        change.springback_m,
    )


def _allowed_checks(allowed: list[tuple[CycleLeg, ClearanceAlong]]) -> list[Check]:
    """The allowed pair's closest approach on the legs that allow it (informational).

    Exact over every sample of those legs (:meth:`~planner.collision.along.AlongPath.allowed_clearance`).
    """
    out: dict[tuple[str, str], tuple[float, list[str]]] = {}
    for leg, c in allowed:
        if leg.allowed is None:
            continue
        best, legs = out.get(leg.allowed, (np.inf, []))
        out[leg.allowed] = (min(best, c.distance_m), [*legs, leg.name])
    return [
        Check(
            "allowed_pair",
            True,
            f"{a} ~ {b} allowed within the clearance on {', '.join(legs)} only; closest {1e3 * d:.2f} mm "
            "(exact over every sample)",
            d,
        )
        for (a, b), (d, legs) in out.items()
    ]

"""The validation gate: every trajectory passes it before it leaves the program.

The gate trusts nothing the planner computed. From the sampled drive profile alone (plus the scenario) it
re-derives and checks:

``finite``          every value is a finite number, arrays have the right shapes;
``time``            t starts at 0 and strictly increases with the sample period;
``start``           the first sample is the scenario's start (1e-9), at rest;
``end_at_rest``     the last sample is at rest;
``goal``            the final pose is the goal (payload frame within 1 mm / 0.1 deg; drives goal: 1e-6);
                    with deflection compensation the final pose is the *commanded* pose (1 mm / 0.1 deg)
                    and the deflected pose predicted there by the stiffness model is the requested pose
                    within 0.01 mm / 1e-5 rad (:mod:`planner.dynamics.stiffness`);
``position``        every drive within its travel (1e-9);
``velocity``        |u_dot| <= v_max (1% tolerance);
``acceleration``    |u_ddot| <= a_max (1%);
``jerk``            (with jerk limits) |a_{k+1} - a_k| / dt <= j_max (1%), from the sampled accelerations;
                    reported but not binding for ``options.timing: acceleration_limited``;
``on_path``         (when the certified path is given, as the planner does) every sample's joints lie on
                    it within 1e-6 (:mod:`planner.gate.path_check`);
``effort``          the forces recomputed here from the inverse dynamics (payload included) match the
                    reported ones and are within effort_max (1%);
``consistency``     the positions integrate the velocities and the velocities the accelerations
                    (trapezoid rule, 1% of the limit per sample step), so the profile is executable;
``workspace``       the parallel stage assembles on its working branch with every margin
                    (limits, slider gaps, singularity margins) at every sample;
``approach``        (with an approach) the payload frame stays within 1 mm of the insertion line, with
                    the goal orientation (0.1 deg), from the pre-insertion pose to the goal;
``collision``       the polyline through the samples is certified to keep the requested clearance from the
                    cabin and the world's obstacles (and the self-clearance between bodies): between
                    consecutive samples, not only at them (:meth:`CollisionWorld.along`,
                    rigid and sagging alike).

After the drive checks (:mod:`planner.gate.drive_checks`), the checks are :data:`CABIN8_CHECKS`, an ordered
list of functions of (profile, context) -> Check. A failed check never stops the others: the report lists
every failure with its worst value and where.

The report's ``min_clearance_m`` is the smallest exact FCL distance of any body (payload included) to the
cabin or an obstacle (installed units, fixtures; allowed pairs apart), or between two checked bodies, over
*every* sample of the rigid robot (found by branch and bound on certified bounds and swept hulls, to within
:data:`~planner.collision.along.CLEARANCE_TOL_M`; the value itself is the exact distance at
``min_clearance_at``), and ``min_clearance_bound_m`` a certified lower bound of it along the
whole joint-space polyline, between samples included (:mod:`planner.collision.along`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from planner.collision.along import AlongPath, AlongReport, ClearanceAlong
from planner.collision.world import DEFAULT_SELF_CLEARANCE_M, CollisionWorld
from planner.core.exceptions import DeflectionNotCompensated, OutsideWorkspace
from planner.core.so3 import rotation_angles, rotation_log
from planner.core.types import Array, IntArray
from planner.dynamics.models import DriveDynamics, drive_dynamics
from planner.dynamics.payload import RigidPayload
from planner.dynamics.stiffness import (
    COMPENSATION_TOL_M,
    COMPENSATION_TOL_RAD,
    compensate_goal,
    deflected_pose,
    stiffness_model,
)
from planner.gate.drive_checks import Check, GateReport, drive_checks, ratio_check
from planner.gate.path_check import path_deviation
from planner.gate.requirements import (
    APPROACH_BACKOUT_TOL_M,
    GOAL_ANGLE_TOL_RAD,
    GOAL_POSITION_TOL_M,
    LIMIT_TOLERANCE,
    LINE_TOL_M,
    PATH_DEVIATION_TOL,
    GateRequirements,
    deflection_sample_indices,
)
from planner.robots.cabin8 import Cabin8
from planner.timing.profile import DriveProfile


@dataclass
class GateContext:
    """What cabin8's checks share for one profile: the inputs, and what one check derives for the next.

    ``q`` (N, 8) are the joints of every sample (None when the parallel stage does not assemble somewhere:
    ``workspace`` then fails and the checks that need joints fail as not evaluated); ``T_pay`` (N, 4, 4)
    the payload frames; ``T_line_goal`` the goal of the insertion line (the commanded pose with deflection
    compensation); ``clearance`` the smallest distance along the path (set by ``collision``).
    """

    robot: Cabin8
    world: CollisionWorld
    req: GateRequirements
    dynamics: DriveDynamics | None
    n: int
    q: Array | None = None
    workspace_error: OutsideWorkspace | None = None
    T_pay: Array | None = None
    T_line_goal: Array | None = None
    clearance: ClearanceAlong | None = None
    peaks: dict[str, float] = field(default_factory=dict)
    #: The predicted payload-frame deflection the sagging certificate used: (sample indices, twists (K, 6))
    #: (set by ``collision``).
    deflection: tuple[IntArray, Array] | None = None


#: A check of the gate: a function of the profile and the shared context, giving its outcome (None: the
#: check does not apply to this scenario).
CheckFn = Callable[[DriveProfile, GateContext], Check | None]

NOT_ASSEMBLED = "not evaluated: the parallel stage does not assemble"


def workspace_check(profile: DriveProfile, ctx: GateContext) -> Check:
    """``workspace``: every sample assembles on the working branch with every margin (limits, gaps)."""
    if ctx.q is None:
        exc = ctx.workspace_error
        assert exc is not None
        return Check("workspace", False, exc.message, None, exc.details.get("index"))
    admissibility = ctx.world.model.admissibility  # the robot's constraints, as the world checks them
    bad = ~admissibility.admissible_batch(ctx.q)
    if bad.any():
        i = int(np.argmax(bad))
        names = ", ".join(v["name"] for v in admissibility.violations(ctx.q[i]))
        return Check("workspace", False, f"sample {i} violates {names}", None, i)
    return Check("workspace", True, "stage on its working branch with every margin at every sample")


def on_path_check(profile: DriveProfile, ctx: GateContext) -> Check | None:
    """``on_path``: every sample lies on the certified geometric path (when the planner gives it)."""
    if ctx.q is None or ctx.req.path_legs is None:
        return None
    dev = path_deviation(ctx.q, ctx.req.path_legs, ctx.req.path_leg_of, ctx.req.path_s)
    k = int(np.argmax(dev))
    return Check(
        "on_path",
        float(dev[k]) <= PATH_DEVIATION_TOL,
        f"samples off the certified path by at most {dev[k]:.3g} (joint space, sample {k})",
        float(dev[k]),
        k,
    )


def effort_check(profile: DriveProfile, ctx: GateContext) -> Check:
    """``effort``: forces recomputed from the inverse dynamics match the reported ones, within limits."""
    if ctx.q is None:
        return Check("effort", False, NOT_ASSEMBLED)
    robot, lim = ctx.robot, ctx.robot.limits
    dyn = ctx.dynamics or drive_dynamics(robot)
    assert dyn is not None, "this gate needs the robot's force model"
    # q_dot = G^-1 u_dot, q_ddot = G^-1 (u_ddot - G_dot q_dot), exact (CasADi AD of the drive map).
    qd, qdd = dyn.joint_rates_batch(ctx.q, profile.velocity, profile.acceleration)
    tau = dyn.drive_forces_batch(ctx.q, qd, qdd, ctx.req.payload)
    chk, ctx.peaks["effort"] = ratio_check("effort", tau, lim.effort_max, robot, "N or N m", ctx.n)
    if profile.effort is None:
        return Check("effort", False, "the profile carries no forces", chk.worst, chk.sample)
    mismatch = float(np.max(np.abs(tau - profile.effort) / lim.effort_max[None, :]))
    return Check(
        "effort",
        chk.passed and mismatch <= LIMIT_TOLERANCE,
        chk.detail + f"; reported vs recomputed differ by {100 * mismatch:.2f}% of the limit",
        chk.worst,
        chk.sample,
    )


def goal_check(profile: DriveProfile, ctx: GateContext) -> Check | None:
    """``goal``: the final pose is the goal (compensated: the commanded pose, and its sag the request)."""
    req, n = ctx.req, ctx.n
    if ctx.q is None:
        return Check("goal", False, NOT_ASSEMBLED)
    ctx.T_pay = ctx.robot.fk_batch(ctx.q) @ req.T_tool_payload
    T_pay = ctx.T_pay
    ctx.T_line_goal = req.T_base_payload_goal
    if req.T_base_payload_goal is not None and req.compensate_deflection:
        chk, ctx.T_line_goal = _compensated_goal_check(ctx.q[-1], T_pay[-1], ctx.robot, req, n)
        return chk
    if req.T_base_payload_goal is not None:
        Tg = req.T_base_payload_goal
        dp = float(np.linalg.norm(T_pay[-1][:3, 3] - Tg[:3, 3]))
        da = float(np.linalg.norm(rotation_log(Tg[:3, :3].T @ T_pay[-1][:3, :3])))
        return Check(
            "goal",
            dp <= GOAL_POSITION_TOL_M and da <= GOAL_ANGLE_TOL_RAD,
            f"final payload pose off by {1e3 * dp:.3f} mm, {np.rad2deg(da):.4f} deg",
            dp,
            n - 1,
        )
    if req.goal_u is not None:
        e = float(np.max(np.abs(profile.position[-1] - req.goal_u)))
        return Check("goal", e <= 1e-6, f"final drives off by {e:.3g}", e, n - 1)
    return None


def approach_check(profile: DriveProfile, ctx: GateContext) -> Check | None:
    """``approach``: on the insertion line, with the goal orientation, from the pre-insertion pose on."""
    req = ctx.req
    if req.approach_direction is None or req.T_base_payload_goal is None:
        return None
    if ctx.T_pay is None:
        return Check("approach", False, NOT_ASSEMBLED)
    return _approach_check(ctx.T_pay, req, ctx.T_line_goal)


def collision_check(profile: DriveProfile, ctx: GateContext) -> Check | None:
    """``collision``: the polyline through the samples keeps the clearance, rigid and sagging.

    The rigid robot's polyline is certified in one batched pass (:meth:`CollisionWorld.along`: the cabin,
    the robot's pairs and the world's obstacles; pieces the bounds cannot cover are walked by the certified
    motion check), which also gives the report's smallest distance (exact over every sample, certified
    between them, obstacles included); with a payload and stiffness
    data, the robot sagging under its predicted static deflection likewise (:func:`sagging_certificate`).
    Not applicable (None) where the requirements defer it (``req.collision``: a cycle's legs, which the
    cycle gate certifies in the same worlds).
    """
    if not ctx.req.collision:  # a cycle's leg: the cycle gate certifies these samples in this world
        return None
    if ctx.q is None:
        return Check("collision", False, NOT_ASSEMBLED)
    req, world, robot = ctx.req, ctx.world, ctx.robot
    along = world.along(ctx.q)
    rep = along.certify(req.clearance_m, req.self_clearance_m, req.motion_margin_m)
    if world.cabin is not None or world.obstacles is not None:
        ctx.clearance = along.clearance()
    if not rep.valid:
        what = "; ".join(c.detail for c in rep.contacts) or "not certified"
        return Check(
            "collision", False, f"between samples {rep.first_bad} and later: {what}", None, rep.first_bad
        )
    done = (
        f"certified clearance >= {req.clearance_m} m along the whole polyline ({rep.exact_queries} exact "
        f"distances, {rep.walked} pieces walked)"
    )
    if not (req.deflection_check and robot.desc.stiffness is not None):
        return Check("collision", True, done)
    q_def, sag, idx, x = _deflections(robot, [ctx.q], req.payload, req.T_tool_payload)[0]
    ctx.deflection = (idx, x)
    rep_def = sagging_certificate(
        world, q_def, req.clearance_m, req.motion_margin_m, along, req.self_clearance_m
    )
    if rep_def.valid:
        return Check(
            "collision",
            True,
            f"{done}, and sagging (up to {1e3 * sag:.2f} mm; {rep_def.exact_queries} exact distances, "
            f"{rep_def.walked} pieces walked)",
        )
    what = "; ".join(c.detail for c in rep_def.contacts) or "not certified"
    return Check(
        "collision",
        False,
        f"with the predicted sag (up to {1e3 * sag:.2f} mm), between samples {rep_def.first_bad} and "
        f"later: {what}",
        None,
        rep_def.first_bad,
    )


def sagging_certificate(
    world: CollisionWorld,
    q_def: Array,
    clearance_m: float,
    margin_m: float,
    rigid: AlongPath | None = None,
    self_clearance_m: float = DEFAULT_SELF_CLEARANCE_M,
) -> AlongReport:
    """The polyline through the sagging robot's configurations (N, 8) certified in one batched pass.

    :meth:`CollisionWorld.along` on ``q_def`` (:func:`deflected_joints`): as strict as the certified walk
    (:meth:`CollisionWorld.check_path`), the world's obstacles included; ``rigid``, the rigid robot's pass
    over the same samples, seeds its bounds (:meth:`AlongPath.seed_from`: what the rigid pass proved, less
    how far the sag moves each body). A single configuration (a leg at rest) is its own path of two samples.
    Pairs of bodies keep ``self_clearance_m`` (the requested one, not the world's setting).
    """
    q_def = np.ascontiguousarray(q_def if len(q_def) >= 2 else np.vstack([q_def, q_def]))
    along = world.along(q_def)
    if rigid is not None and rigid.n == along.n:
        along.seed_from(rigid)
    return along.certify(clearance_m, self_clearance_m, margin_m)


#: cabin8's checks after the drive checks, in order (each a function of the profile and the context).
CABIN8_CHECKS: tuple[CheckFn, ...] = (
    workspace_check,
    on_path_check,
    effort_check,
    goal_check,
    approach_check,
    collision_check,
)


def validate_profile(
    profile: DriveProfile,
    robot: Cabin8,
    world: CollisionWorld,
    req: GateRequirements,
    dynamics: DriveDynamics | None = None,
) -> GateReport:
    """Run every check of the gate on a sampled profile (see the module docstring).

    The robot-independent drive checks (:func:`~planner.gate.drive_checks.drive_checks`), then
    :data:`CABIN8_CHECKS` in order. The report's ``min_clearance_m`` is the exact smallest distance over
    every sample (to within :data:`~planner.collision.along.CLEARANCE_TOL_M`), ``min_clearance_bound_m``
    the certified lower bound along the polyline between samples, ``min_clearance_at`` where and between
    which bodies (infinite, None without a cabin).
    """
    checks, peaks = drive_checks(profile, robot, req.start_u, req.sample_period_s, req.jerk_limited)
    n = len(profile.t)
    if not checks[0].passed:  # not finite: nothing else can be evaluated
        return GateReport(tuple(checks), n, float("nan"), {})
    ctx = GateContext(robot, world, req, dynamics, n, peaks=peaks)
    try:
        ctx.q = robot.joints_from_drives(profile.position)
    except OutsideWorkspace as exc:
        ctx.workspace_error = exc
    for check in CABIN8_CHECKS:
        result = check(profile, ctx)
        if result is not None:
            checks.append(result)
    c = ctx.clearance
    if c is None:  # no cabin nor obstacle (inf), or no figure measured here (nan)
        measured = ctx.q is not None and req.collision
        return GateReport(
            tuple(checks), n, float("inf") if measured else float("nan"), peaks, deflection=ctx.deflection
        )
    where = {
        "t_s": float(profile.t[c.sample]),
        "sample": c.sample,
        "bodies": list(c.bodies),
        "tolerance_m": c.tolerance_m,
    }
    return GateReport(tuple(checks), n, c.distance_m, peaks, c.bound_m, where, ctx.deflection)


def clearance_probe_indices(n: int) -> IntArray:
    """Every ``n // 40``-th sample and the last one (sorted, unique): a thinned set of samples.

    The report's ``min_clearance_m`` was measured on these before it became the minimum over every sample;
    the operator viewer still includes them among its frames.
    """
    return np.unique(np.concatenate([np.arange(0, n, max(1, n // 40)), [n - 1]])).astype(np.int64)


def _compensated_goal_check(
    q_end: Array, T_end: Array, robot: Cabin8, req: GateRequirements, n: int
) -> tuple[Check, Array]:
    """Goal check of a deflection-compensated pose goal; also returns the commanded pose."""
    assert req.T_base_payload_goal is not None
    model = stiffness_model(robot)
    T_cmd = req.T_base_payload_commanded
    if T_cmd is None:
        try:
            T_cmd = compensate_goal(
                model, req.T_base_payload_goal, q_end, req.payload, req.T_tool_payload
            ).T_base_frame_commanded
        except DeflectionNotCompensated as exc:
            return Check("goal", False, f"no compensated command: {exc.message}", None, n - 1), T_end
    dp = float(np.linalg.norm(T_end[:3, 3] - T_cmd[:3, 3]))
    da = float(np.linalg.norm(rotation_log(T_cmd[:3, :3].T @ T_end[:3, :3])))
    x = model.deflection(q_end, req.payload, req.T_tool_payload).twist
    T_def = deflected_pose(T_end, x)
    Tg = req.T_base_payload_goal
    ep = float(np.linalg.norm(T_def[:3, 3] - Tg[:3, 3]))
    ea = float(np.linalg.norm(rotation_log(Tg[:3, :3].T @ T_def[:3, :3])))
    ok = dp <= GOAL_POSITION_TOL_M and da <= GOAL_ANGLE_TOL_RAD
    ok = ok and ep <= COMPENSATION_TOL_M and ea <= COMPENSATION_TOL_RAD
    detail = (
        f"final payload pose off the commanded pose by {1e3 * dp:.3f} mm, {np.rad2deg(da):.4f} deg; "
        f"predicted deflected pose ({1e3 * float(np.linalg.norm(x[:3])):.3f} mm sag) off the request by "
        f"{1e3 * ep:.4f} mm, {ea:.2e} rad"
    )
    return Check("goal", ok, detail, max(dp, ep), n - 1), T_cmd


def _approach_check(T_pay: Array, req: GateRequirements, T_goal: Array | None = None) -> Check:
    """The insertion line check; ``T_goal`` is the line's goal pose (default: the requested goal)."""
    assert req.approach_direction is not None and req.T_base_payload_goal is not None
    T_goal = req.T_base_payload_goal if T_goal is None else T_goal
    d = req.approach_direction / np.linalg.norm(req.approach_direction)
    goal_p = T_goal[:3, 3]
    rel = T_pay[:, :3, 3] - goal_p[None, :]
    along = -(rel @ d)  # distance back from the goal along the line
    reached = np.flatnonzero(along >= req.approach_distance_m - LINE_TOL_M)
    if len(reached) == 0:
        return Check(
            "approach", False, "the payload never reaches the pre-insertion pose on the approach line"
        )
    k = int(reached[-1])
    seg = rel[k:]
    off = np.linalg.norm(seg - np.outer(seg @ d, d), axis=1)
    Rg = T_goal[:3, :3]
    ang = rotation_angles(Rg.T[None] @ T_pay[k:, :3, :3])
    worst_off, worst_ang = float(off.max()), float(ang.max())
    # Along the line the payload only moves in: never past the goal, never back out.
    overshoot = float(max(0.0, -float(along[k:].min())))
    backout = float(max(0.0, float(np.max(np.diff(along[k:]), initial=0.0))))
    ok = (
        worst_off <= LINE_TOL_M
        and worst_ang <= GOAL_ANGLE_TOL_RAD
        and overshoot <= LINE_TOL_M
        and backout <= APPROACH_BACKOUT_TOL_M
    )
    return Check(
        "approach",
        ok,
        f"from sample {k}: {1e3 * worst_off:.3f} mm off the line, "
        f"{np.rad2deg(worst_ang):.4f} deg off the goal orientation, {1e3 * overshoot:.3f} mm past the goal, "
        f"{1e3 * backout:.4f} mm back out in one step",
        worst_off,
        k,
    )


def deflected_joints(
    robot: Cabin8, q: Array, payload: RigidPayload | None, T_tool_payload: Array
) -> tuple[Array, float]:
    """Configurations (N, 8) of the rigid robot whose payload frame sits where the real one sags to.

    At the samples of :func:`deflection_sample_indices` (where the robot moves) the static gravity deflection
    of the payload frame (stiffness model, payload and links) displaces its pose; the closed-form
    redundant family on the sample's own (gamma, d5) gives the configuration that reaches the displaced
    pose, and the correction q' - q (smooth and millimetre-sized) is interpolated in between. The bodies
    of the rigid robot at q' stand for the sagging robot: exact for the payload and the tool, an
    approximation for the links (which sag less the nearer they are to the rail).

    Returns:
        (q', the largest predicted payload-frame translation [m]).
    """
    return deflected_joints_of(robot, [q], payload, T_tool_payload)[0]


def deflected_joints_of(
    robot: Cabin8, paths: Sequence[Array], payload: RigidPayload | None, T_tool_payload: Array
) -> list[tuple[Array, float]]:
    """:func:`deflected_joints` of several joint paths under the same load, the model evaluated once.

    The stiffness model costs about as much for one configuration as for a hundred (numpy's per-call
    overhead): a cycle's legs of the same load share one evaluation. Each path's result is the same as
    its own :func:`deflected_joints` (the model is evaluated row by row).
    """
    return [(q, sag) for q, sag, _, _ in _deflections(robot, paths, payload, T_tool_payload)]


def _deflections(
    robot: Cabin8, paths: Sequence[Array], payload: RigidPayload | None, T_tool_payload: Array
) -> list[tuple[Array, float, IntArray, Array]]:
    """(q', the largest translation, the sample indices, the payload-frame twists (K, 6) there) per path."""
    from scipy.spatial.transform import Rotation

    from planner.dynamics.stiffness import stiffness_model
    from planner.kinematics import chain
    from planner.kinematics.closed_form import redundant_family

    if not paths:
        return []
    idxs = [deflection_sample_indices(q) for q in paths]
    # Each distinct configuration once (a dwell repeats one): the same inputs give the same deflection.
    picked = np.vstack([q[idx] for q, idx in zip(paths, idxs, strict=True)])
    distinct, back = np.unique(picked, axis=0, return_inverse=True)
    x_all = stiffness_model(robot).deflection_along(distinct, payload, T_tool_payload)[back.ravel()]
    T_pay = robot.fk_batch(picked) @ T_tool_payload
    T_payload_tool = np.linalg.inv(T_tool_payload)
    T_def = T_pay.copy()  # the payload frames displaced by their small twists (as deflected_pose, batched)
    T_def[:, :3, :3] = Rotation.from_rotvec(x_all[:, 3:]).as_matrix() @ T_pay[:, :3, :3]
    T_def[:, :3, 3] += x_all[:, :3]
    T_tool = T_def @ T_payload_tool
    dq_all = redundant_family(robot.desc.serial_chain, T_tool, picked[:, chain.GAMMA], picked[:, chain.D5])
    dq_all -= picked
    dq_all[:, chain.THETA6] = np.arctan2(np.sin(dq_all[:, chain.THETA6]), np.cos(dq_all[:, chain.THETA6]))
    out = []
    start = 0
    for q, idx in zip(paths, idxs, strict=True):
        stop = start + len(idx)
        dq, x = dq_all[start:stop], x_all[start:stop]
        start = stop
        steps = np.arange(len(q))
        correction = np.column_stack([np.interp(steps, idx, dq[:, j]) for j in range(8)])
        out.append((q + correction, float(np.linalg.norm(x[:, :3], axis=1).max()), idx, x))
    return out

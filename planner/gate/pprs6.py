"""pprs6's gate: the drive checks of every profile, then the platform's own, as an ordered list.

The robot-independent drive checks (:func:`~planner.gate.drive_checks.drive_checks`: finite, time, start,
end at rest, position, velocity, acceleration with the executed dv/dt, jerk, consistency), then
:data:`PPRS6_CHECKS`, each a function of (profile, context) -> Check:

``pose_path_followed``   the forward kinematics (Newton, from the previous samples' pose) of every sample
                         lies on its leg of the pose path within :data:`POSE_PATH_TOL` (m, and rad weighted by
                         the platform radius r);
``start_and_end_poses``  the first and last poses are the path's ends within 1e-9;
``singularity``          the singularity measure (condition number) stays below the path's bound.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from planner.core.types import Array, IntArray
from planner.gate.drive_checks import Check, GateReport, drive_checks
from planner.kinematics import pprs6 as kin
from planner.robots.pprs6 import Pprs6
from planner.timing.profile import DriveProfile

#: How far the forward kinematics of a sample may lie off its leg of the pose path (m, weighted rad).
POSE_PATH_TOL = 1e-6


class PoseLegs(Protocol):
    """What the gate reads of a pose path (:class:`planner.plan.pose_path.PosePath`)."""

    @property
    def waypoints(self) -> Array:
        """(K, 6) poses [m, rad] in the order travelled."""
        ...

    @property
    def max_condition(self) -> float:
        """Largest singularity measure admitted along the path."""
        ...

    @property
    def n_legs(self) -> int:
        """Number of straight legs (K - 1)."""
        ...


@dataclass
class Pprs6Context:
    """What pprs6's checks share: the path, each sample's leg (N,) and the tracked poses (N, 6)."""

    robot: Pprs6
    path: PoseLegs
    leg: IntArray
    poses: Array


#: A check of pprs6's gate: a function of the profile and the shared context.
Pprs6CheckFn = Callable[[DriveProfile, Pprs6Context], Check]


def pose_path_check(profile: DriveProfile, ctx: Pprs6Context) -> Check:
    """``pose_path_followed``: every sample's pose on its leg (weighted pose metric, rad times r)."""
    g = ctx.robot.geometry
    weights = np.array([1.0, 1.0, 1.0, g.r, g.r, g.r])
    w = ctx.path.waypoints
    dev = np.zeros(len(ctx.poses))
    for k in range(ctx.path.n_legs):
        m = ctx.leg == k
        dev[m] = _segment_distance(ctx.poses[m], w[k], w[k + 1], weights)
    worst = float(np.max(dev))
    return Check(
        "pose_path_followed",
        worst <= POSE_PATH_TOL,
        f"forward kinematics off the pose path by at most {worst:.3g} (m, weighted rad)",
        worst,
        int(np.argmax(dev)),
    )


def end_poses_check(profile: DriveProfile, ctx: Pprs6Context) -> Check:
    """``start_and_end_poses``: the first and last poses are the path's ends (1e-9)."""
    w = ctx.path.waypoints
    ends = max(float(np.max(np.abs(ctx.poses[0] - w[0]))), float(np.max(np.abs(ctx.poses[-1] - w[-1]))))
    return Check("start_and_end_poses", ends <= 1e-9, f"end poses off by {ends:.3g}", ends)


def singularity_check(profile: DriveProfile, ctx: Pprs6Context) -> Check:
    """``singularity``: the condition number of every sample's pose below the path's bound."""
    cond = ctx.robot.condition_number(ctx.poses)
    bound = ctx.path.max_condition
    return Check(
        "singularity",
        float(np.max(cond)) <= bound,
        f"condition number at most {float(np.max(cond)):.3g} (bound {bound:.3g})",
        float(np.max(cond)),
        int(np.argmax(cond)),
    )


#: pprs6's checks after the drive checks, in order.
PPRS6_CHECKS: tuple[Pprs6CheckFn, ...] = (pose_path_check, end_poses_check, singularity_check)


def validate(
    robot: Pprs6, path: PoseLegs, profile: DriveProfile, leg: IntArray, period_s: float
) -> tuple[GateReport, Array]:
    """The validation gate of a sampled pprs6 profile (see the module docstring); returns (report, poses).

    Args:
        robot: The platform.
        path: The pose path the profile follows.
        profile: The sampled profile (N samples, 6 drives).
        leg: (N,) the leg of each sample.
        period_s: The controller period the profile must be sampled at [s].

    Returns:
        The report (no clearance figure: the platform has no collision world, ``min_clearance_m`` NaN) and
        the forward kinematics (N, 6) of the samples (empty when the arrays are not finite).
    """
    start_u = robot.ik(path.waypoints[0])
    checks, peaks = drive_checks(profile, robot, start_u, period_s)
    n = len(profile.t)
    if not checks[0].passed:
        return GateReport(tuple(checks), n, float("nan"), peaks), np.zeros((0, 6))
    # Forward kinematics of every sample, each leg tracked from its start waypoint, sample after sample.
    ctx = Pprs6Context(robot, path, leg, _track_fk(robot, path, profile.position))
    checks.extend(check(profile, ctx) for check in PPRS6_CHECKS)
    return GateReport(tuple(checks), n, float("nan"), peaks), ctx.poses


def _segment_distance(x: Array, a: Array, b: Array, weights: Array) -> Array:
    """Distance of poses x (N, 6) from the segment a-b, in the weighted pose metric."""
    d = (b - a) * weights
    rel = (x - a) * weights
    t = np.clip(rel @ d / float(d @ d), 0.0, 1.0)
    return np.asarray(np.linalg.norm(rel - t[:, None] * d, axis=1))


def _track_fk(robot: Pprs6, path: PoseLegs, u: Array) -> Array:
    """FK of every sample (N, 6 drives), Newton started from the pose of the sample before its batch of 25."""
    out = np.empty_like(u)
    stride = 25  # samples solved together from the same start (within a few mm of each other)
    guess = path.waypoints[0]
    for i0 in range(0, len(u), stride):
        block = u[i0 : i0 + stride]
        out[i0 : i0 + stride] = kin.forward_or_raise(robot.geometry, block, [guess])
        guess = out[min(i0 + stride, len(u)) - 1]
    return out

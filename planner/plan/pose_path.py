"""Drive profiles of the pprs6 platform along a pose path, and their validation gate.

A pose path is a polyline of platform poses (the paper's closed path E -> F -> G -> H -> E of Fig. 6 by
default). Each straight leg ``x(s) = x_a + s (x_b - x_a)``, s in [0, 1], becomes a drive path through the
closed-form inverse kinematics:

    u(s) = IK(x(s)),   u'(s) = J(x(s)) dx,   u''(s) = d/ds [J(x(s))] dx

(J the analytic drive Jacobian; its derivative along the leg by a central difference of J with step
1e-4 in s, an O(1e-8) relative error). Corners are sharp, so the platform stops at every waypoint: each
leg is timed rest to rest by :func:`planner.timing.drive_path.time_drive_path` (TOPP-RA under the drive
velocity and acceleration limits of the description) and the legs are sampled one after the other at the
controller period.

The gate (:func:`validate`) re-derives everything from the sampled drives, trusting nothing the timing
computed: finite values; time from 0 in steps of the period; positions within the drive ranges; |v| and
|a| (reported, and executed between samples dv/dt) within 1% of the limits; positions integrate the
velocities; at rest at both ends; the forward kinematics (Newton, from the previous sample's pose) of
every sample on its leg of the pose path within 1e-6 (m, rad); and the singularity measure (condition
number) below the path's bound at every sample.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.core.exceptions import InvalidInput, OutsideWorkspace, ValidationFailed
from planner.core.types import Array
from planner.kinematics import pprs6 as kin
from planner.robots.pprs6 import Pprs6
from planner.timing.drive_path import DrivePath, SampledLegs, sample_legs, time_drive_path

#: The paper's closed path E -> F -> G -> H (Fig. 6 shows only its shape): a saddle-shaped spatial
#: quadrilateral of 40 mm x 40 mm x 20 mm around the centre of the level workspace, at a yaw of 0.2 rad
#: (the unyawed level platform sits on a type-II singularity; see the README).
PAPER_PATH: dict[str, Any] = {
    "name": "paper-EFGHE",
    "closed": True,
    "waypoints": [
        {"name": "E", "x": -0.05, "y": -0.05, "z": 0.18, "phi": 0.2, "theta": 0.0, "psi": 0.0},
        {"name": "F", "x": -0.01, "y": -0.05, "z": 0.20, "phi": 0.2, "theta": 0.0, "psi": 0.0},
        {"name": "G", "x": -0.01, "y": -0.01, "z": 0.18, "phi": 0.2, "theta": 0.0, "psi": 0.0},
        {"name": "H", "x": -0.05, "y": -0.01, "z": 0.20, "phi": 0.2, "theta": 0.0, "psi": 0.0},
    ],
}

_FD_STEP = 1e-4


@dataclass(frozen=True)
class PosePath:
    """A polyline of platform poses, (K, 6) waypoints in the order travelled (closed: back to the first).

    Attributes:
        name: Label.
        waypoints: (K, 6) poses [m, rad], the last equal to the first for a closed path.
        labels: Waypoint names (K,).
        max_condition: Largest singularity measure admitted along the path.
    """

    name: str
    waypoints: Array = field(repr=False)
    labels: tuple[str, ...]
    max_condition: float = 1000.0

    @property
    def n_legs(self) -> int:
        """Number of straight legs."""
        return len(self.waypoints) - 1


def pose_path_from_spec(spec: Mapping[str, Any]) -> PosePath:
    """Validate a pose-path document: ``{"name"?, "closed"?, "max_condition"?, "waypoints": [pose, ...]}``.

    Every waypoint is ``{"x","y","z","phi","theta","psi"}`` (m, rad) with an optional ``"name"``.

    Raises:
        InvalidInput: the field at fault is named (``waypoints.2.z``, ...).
    """
    if not isinstance(spec, Mapping):
        raise InvalidInput("path: expected an object with 'waypoints'", field="path")
    unknown = sorted(set(spec) - {"name", "closed", "waypoints", "max_condition"})
    if unknown:
        raise InvalidInput(f"path: unknown field(s) {unknown}", field=f"path.{unknown[0]}")
    wps = spec.get("waypoints")
    if not isinstance(wps, Sequence) or isinstance(wps, str) or len(wps) < 2:
        raise InvalidInput("waypoints: expected a list of at least 2 poses", field="waypoints")
    closed = spec.get("closed", False)
    if not isinstance(closed, bool):
        raise InvalidInput("closed: expected true or false", field="closed")
    max_cond = spec.get("max_condition", 1000.0)
    if isinstance(max_cond, bool) or not isinstance(max_cond, int | float) or not 1 < max_cond <= 1e6:
        raise InvalidInput("max_condition: expected a finite number in (1, 1e6]", field="max_condition")
    poses, labels = [], []
    for k, wp in enumerate(wps):
        if not isinstance(wp, Mapping):
            raise InvalidInput(f"waypoints.{k}: expected a pose object", field=f"waypoints.{k}")
        rest = {n: v for n, v in wp.items() if n != "name"}
        poses.append(pose_from_mapping(rest, field=f"waypoints.{k}"))
        labels.append(str(wp.get("name", f"P{k}")))
    if closed:
        poses.append(poses[0])
        labels.append(labels[0])
    W = np.array(poses)
    if np.any(np.max(np.abs(np.diff(W, axis=0)), axis=1) < 1e-9):
        raise InvalidInput("waypoints: two consecutive waypoints are equal", field="waypoints")
    name = str(spec.get("name", "path"))
    return PosePath(name, W, tuple(labels), float(max_cond))


def pose_from_mapping(values: Mapping[str, Any], field: str = "pose") -> Array:
    """Pose vector (6,) from ``{"x","y","z","phi","theta","psi"}``; every coordinate, nothing else.

    Raises:
        InvalidInput: unknown/missing coordinate or a non-finite value (the field is named).
    """
    if not isinstance(values, Mapping):
        raise InvalidInput(f"{field}: expected an object with {list(kin.POSE)}", field=field)
    unknown = sorted(set(values) - set(kin.POSE))
    if unknown:
        raise InvalidInput(f"{field}: unknown name(s) {unknown}; expected {list(kin.POSE)}", field=field)
    missing = [n for n in kin.POSE if n not in values]
    if missing:
        raise InvalidInput(f"{field}: missing {missing}", field=field)
    out = np.empty(6)
    for i, n in enumerate(kin.POSE):
        v = values[n]
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
            raise InvalidInput(f"{field}.{n}: expected a finite number, got {v!r}", field=f"{field}.{n}")
        out[i] = float(v)
    return out


def leg_drive_path(robot: Pprs6, a: Array, b: Array) -> DrivePath:
    """The drive path of the straight pose leg a -> b (s in [0, 1]); see the module docstring."""
    dx = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    geom = robot.geometry

    def evaluate(s: Array) -> tuple[Array, Array, Array]:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        x = a + s[:, None] * dx
        u = kin.inverse(geom, x).drives
        du = kin.drive_jacobian(geom, x) @ dx
        J_p = kin.drive_jacobian(geom, x + _FD_STEP * dx)
        J_m = kin.drive_jacobian(geom, x - _FD_STEP * dx)
        ddu = ((J_p - J_m) @ dx) / (2.0 * _FD_STEP)
        return u, du, ddu

    return DrivePath(evaluate, 1.0, 6)


def check_path(robot: Pprs6, path: PosePath, samples_per_leg: int = 400) -> None:
    """Refuse a path that leaves the workspace or comes near a singularity anywhere along a leg.

    Raises:
        OutsideWorkspace: ``details`` name the leg, its fraction and the chain/drive (or the condition).
    """
    s = np.linspace(0.0, 1.0, samples_per_leg + 1)[:, None]
    for k in range(path.n_legs):
        a, b = path.waypoints[k], path.waypoints[k + 1]
        X = a + s * (b - a)
        leg = f"{path.labels[k]}->{path.labels[k + 1]}"
        try:
            robot.ik(X)
        except OutsideWorkspace as exc:
            i = int(exc.details.get("index", 0))
            raise OutsideWorkspace(
                f"leg {leg} at {100 * s[i, 0]:.1f}%: {exc.message}",
                **{**dict(exc.details), "leg": leg, "fraction": float(s[i, 0])},
            ) from None
        cond = robot.condition_number(X)
        if np.max(cond) > path.max_condition:
            i = int(np.argmax(cond))
            raise OutsideWorkspace(
                f"leg {leg} at {100 * s[i, 0]:.1f}% comes near a singularity (condition number "
                f"{cond[i]:.3g} > {path.max_condition:.3g})",
                condition="singularity",
                leg=leg,
                fraction=float(s[i, 0]),
                condition_number=float(cond[i]),
                limit=path.max_condition,
            )


@dataclass(frozen=True)
class Pprs6Profile:
    """A sampled drive profile of the platform, arrays (N samples, 6 drives), SI units."""

    path: PosePath
    sample_period_s: float
    samples: SampledLegs = field(repr=False)
    poses: Array = field(repr=False)  # (N, 6) forward kinematics of the sampled drives

    @property
    def duration_s(self) -> float:
        """Time of the last sample [s]."""
        return float(self.samples.t[-1])


def build_profile(
    robot: Pprs6, path: PosePath, period_s: float | None = None, grid_points: int = 300
) -> Pprs6Profile:
    """Time the pose path leg by leg and sample it; returns the validated :class:`Pprs6Profile`.

    Raises:
        OutsideWorkspace: the path leaves the workspace or nears a singularity.
        RetimingFailed: TOPP-RA found no time law.
        ValidationFailed: the gate rejected the samples (``details['report']``).
    """
    period = robot.sample_period_s if period_s is None else float(period_s)
    if not (np.isfinite(period) and 0.0005 <= period <= 0.1):
        raise InvalidInput(
            f"sample_period_s: must be in [0.0005, 0.1] s, got {period}", field="sample_period_s"
        )
    check_path(robot, path)
    lim = robot.limits
    paths = [leg_drive_path(robot, path.waypoints[k], path.waypoints[k + 1]) for k in range(path.n_legs)]
    laws = [time_drive_path(p, lim.v_max, lim.a_max, period, grid_points) for p in paths]
    samples = sample_legs(paths, laws, period)
    report, poses = validate(robot, path, samples, period)
    if not report["passed"]:
        failed = [c["name"] for c in report["checks"] if not c["passed"]]
        raise ValidationFailed(f"the drive profile failed the gate: {', '.join(failed)}", report=report)
    return Pprs6Profile(path, period, samples, poses)


def _segment_distance(x: Array, a: Array, b: Array, weights: Array) -> Array:
    """Distance of poses x (N, 6) from the segment a-b, in the weighted pose metric."""
    d = (b - a) * weights
    rel = (x - a) * weights
    t = np.clip(rel @ d / float(d @ d), 0.0, 1.0)
    return np.asarray(np.linalg.norm(rel - t[:, None] * d, axis=1))


def validate(robot: Pprs6, path: PosePath, s: SampledLegs, period_s: float) -> tuple[dict[str, Any], Array]:
    """The validation gate of a sampled profile (see the module docstring); returns (report, poses)."""
    lim = robot.limits
    checks: list[dict[str, Any]] = []

    def check(name: str, passed: bool, **evidence: Any) -> None:
        checks.append({"name": name, "passed": bool(passed), **evidence})

    arrays = (s.t, s.position, s.velocity, s.acceleration)
    finite = all(np.all(np.isfinite(a)) for a in arrays)
    check("finite", finite)
    if not finite:
        return {"passed": False, "checks": checks}, np.zeros((0, 6))
    dt = np.diff(s.t)
    check("time", bool(s.t[0] == 0.0) and bool(np.all(np.abs(dt - period_s) <= 1e-9)), period_s=period_s)
    lo_ok = s.position >= lim.lower - 1e-12
    hi_ok = s.position <= lim.upper + 1e-12
    check("position_range", bool(np.all(lo_ok & hi_ok)))
    v_frac = np.max(np.abs(s.velocity) / lim.v_max)
    a_frac = np.max(np.abs(s.acceleration) / lim.a_max)
    exec_a = np.max(np.abs(np.diff(s.velocity, axis=0)) / dt[:, None] / lim.a_max) if len(dt) else 0.0
    check("velocity", bool(v_frac <= 1.01), max_fraction=float(v_frac))
    check("acceleration", bool(a_frac <= 1.01), max_fraction=float(a_frac))
    check("executed_acceleration", bool(exec_a <= 1.01), max_fraction=float(exec_a))
    integ = np.abs(np.diff(s.position, axis=0) - 0.5 * (s.velocity[1:] + s.velocity[:-1]) * dt[:, None])
    integ_frac = float(np.max(integ / (lim.v_max * period_s))) if len(dt) else 0.0
    check("integrates_velocity", integ_frac <= 0.01, max_fraction_of_limit_step=integ_frac)
    rest = max(
        float(np.max(np.abs(s.velocity[0]) / lim.v_max)), float(np.max(np.abs(s.velocity[-1]) / lim.v_max))
    )
    check("at_rest_at_ends", rest <= 1e-9, max_velocity_fraction=rest)
    # Forward kinematics of every sample, each leg tracked from its start waypoint, sample after sample.
    poses = _track_fk(robot, path, s)
    weights = np.array([1.0, 1.0, 1.0, robot.geometry.r, robot.geometry.r, robot.geometry.r])
    dev = np.zeros(len(s.t))
    for k in range(path.n_legs):
        m = s.leg == k
        dev[m] = _segment_distance(poses[m], path.waypoints[k], path.waypoints[k + 1], weights)
    check("pose_path_followed", float(np.max(dev)) <= 1e-6, max_deviation_m=float(np.max(dev)))
    ends = max(
        float(np.max(np.abs(poses[0] - path.waypoints[0]))),
        float(np.max(np.abs(poses[-1] - path.waypoints[-1]))),
    )
    check("start_and_end_poses", ends <= 1e-9, max_error=ends)
    cond = robot.condition_number(poses)
    check("singularity", float(np.max(cond)) <= path.max_condition, max_condition_number=float(np.max(cond)))
    return {"passed": all(c["passed"] for c in checks), "checks": checks}, poses


def _track_fk(robot: Pprs6, path: PosePath, s: SampledLegs) -> Array:
    """FK of every sample, Newton started from the pose of the sample before its batch of 25."""
    u = s.position
    out = np.empty_like(u)
    stride = 25  # samples solved together from the same start (within a few mm of each other)
    guess = path.waypoints[0]
    for i0 in range(0, len(u), stride):
        block = u[i0 : i0 + stride]
        out[i0 : i0 + stride] = kin.forward_or_raise(robot.geometry, block, [guess])
        guess = out[min(i0 + stride, len(u)) - 1]
    return out

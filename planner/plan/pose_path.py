"""Drive profiles of the pprs6 platform along a pose path, through the shared timing stage and gate.

A pose path is a polyline of platform poses (the paper's closed path E -> F -> G -> H -> E of Fig. 6 by
default). Each straight leg ``x(s) = x_a + s (x_b - x_a)``, s in [0, 1], is a one-piece
:class:`~planner.timing.path.JointPath` in pose coordinates (the platform pose is pprs6's joint vector);
the robot model maps it to the drive path (:meth:`planner.robots.pprs6.Pprs6.drive_path`: closed-form IK,
analytic Jacobian, its derivative along the leg by a central difference). Corners are sharp, so the
platform stops at every waypoint: each leg is timed rest to rest by the robot's default timing stage
(:func:`planner.timing.stages.default_stage`: the jerk-limited LP over drive velocity, acceleration and
jerk limits, pprs6 having no force model; TOPP-RA alone for a description without jerk limits) on a
uniform grid of 300 intervals, and the legs are sampled one after the other at the controller period by the
shared sampler (:func:`~planner.timing.profile.sample_legs`).

The gate is pprs6's room of the one gate (:func:`planner.gate.pprs6.validate`, re-exported here): the
robot-independent drive checks of every profile, then the pose path followed within 1e-6 (m, rad), start
and end poses within 1e-9, and the singularity measure below the path's bound.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.core.exceptions import InvalidInput, OutsideWorkspace, ValidationFailed
from planner.core.types import Array, IntArray
from planner.gate.drive_checks import GateReport
from planner.gate.pprs6 import validate
from planner.kinematics import pprs6 as kin
from planner.robots.pprs6 import Pprs6
from planner.timing import stages
from planner.timing.path import JointPath, LinePiece
from planner.timing.profile import DriveProfile, sample_legs

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


def leg_paths(path: PosePath) -> list[JointPath]:
    """The straight legs of a pose path as one-piece joint paths in pose coordinates (s in [0, 1])."""
    w = path.waypoints
    return [JointPath((LinePiece(w[k], w[k + 1], 1.0),)) for k in range(path.n_legs)]


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
    """A validated drive profile of the platform along a pose path.

    Attributes:
        path: The pose path.
        profile: The sampled drive profile, arrays (N samples, 6 drives); its ``joints`` are the poses of
            the path at the samples; no forces.
        leg: (N,) the leg of each sample (a corner sample belongs to the leg it starts).
        poses: (N, 6) forward kinematics of the sampled drives.
        gate: The gate's report.
    """

    path: PosePath
    profile: DriveProfile = field(repr=False)
    leg: IntArray = field(repr=False)
    poses: Array = field(repr=False)
    gate: GateReport = field(repr=False)

    @property
    def sample_period_s(self) -> float:
        """The controller period [s]."""
        return self.profile.sample_period_s

    @property
    def duration_s(self) -> float:
        """Time of the last sample [s]."""
        return self.profile.duration_s


#: Grid intervals of each leg's timing problem (uniform in s).
GRID_POINTS = 300


def build_profile(
    robot: Pprs6, path: PosePath, period_s: float | None = None, grid_points: int = GRID_POINTS
) -> Pprs6Profile:
    """Time the pose path leg by leg and sample it; returns the validated :class:`Pprs6Profile`.

    Raises:
        OutsideWorkspace: the path leaves the workspace or nears a singularity.
        RetimingFailed: no time law (jerk-limited with the description's jerk limits, else TOPP-RA).
        ValidationFailed: the gate rejected the samples (``details['report']``).
    """
    period = robot.sample_period_s if period_s is None else float(period_s)
    if not (np.isfinite(period) and 0.0005 <= period <= 0.1):
        raise InvalidInput(
            f"sample_period_s: must be in [0.0005, 0.1] s, got {period}", field="sample_period_s"
        )
    check_path(robot, path)
    entry = stages.default_stage(robot)
    stage = entry.build(robot, None, sample_period_s=period, grid_points=grid_points)
    timed = [stage.time_path(leg) for leg in leg_paths(path)]
    profile, leg, _ = sample_legs(robot, timed, period, None)
    gate, poses = validate(robot, path, profile, leg, period)
    if not gate.passed:
        raise ValidationFailed(f"the drive profile failed the gate: {gate.summary()}", report=gate.to_dict())
    return Pprs6Profile(path, profile, leg, poses, gate)

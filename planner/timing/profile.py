"""Drive profiles: the product's output, sampled at the controller period.

A profile holds, for N samples at t_k = k * period, the positions, velocities, accelerations and efforts
(forces / torques) of the 8 drives, and the joint positions. It is built from one or more
:class:`~planner.timing.stage.TimedPath` legs executed one after the other (each at rest at its ends);
after the last leg ends the robot holds the goal at rest until the next sample.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.core.exceptions import InvalidInput, OutsideWorkspace
from planner.core.types import Array, IntArray
from planner.dynamics.models import DriveDynamics, drive_dynamics
from planner.dynamics.payload import RigidPayload
from planner.robots.base import RobotModel
from planner.timing.stage import TimedPath


@dataclass(frozen=True)
class DriveProfile:
    """Sampled drive trajectory, arrays (N samples, n drives) in drive order, SI units.

    ``effort`` is None for a robot without a dynamics model (its profile carries no forces); ``joints``
    (N, n joints) are the path coordinates the planner certified (cabin8: joints; pprs6: platform pose).
    """

    drive_names: tuple[str, ...]
    drive_units: tuple[str, ...]
    joint_names: tuple[str, ...]
    sample_period_s: float
    t: Array = field(repr=False)
    position: Array = field(repr=False)
    velocity: Array = field(repr=False)
    acceleration: Array = field(repr=False)
    effort: Array | None = field(repr=False)
    joints: Array = field(repr=False)

    @property
    def duration_s(self) -> float:
        """Time of the last sample [s]."""
        return float(self.t[-1])

    @property
    def jerk(self) -> Array:
        """Drive jerk (N, n drives): row k is (a_{k+1} - a_k) / (t_{k+1} - t_k), the last row 0.

        The jerk a controller executes ramping the acceleration linearly from sample to sample (what the
        gate checks); after the last sample the robot rests.
        """
        dt = np.diff(self.t)[:, None]
        out = np.zeros_like(self.acceleration)
        out[:-1] = np.diff(self.acceleration, axis=0) / dt
        return out

    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """The profile's fields of the JSON output contract (no ``effort`` without forces).

        Args:
            arrays: The samples as the numpy arrays themselves (for a serializer that writes arrays,
                :func:`planner.documents.output.document_bytes`), else as lists of Python floats.
        """
        out = np.ascontiguousarray if arrays else (lambda a: a.tolist())
        names = list(zip(self.drive_names, self.drive_units, strict=True))
        units: dict[str, Any] = {
            "t": "s",
            "position": dict(names),
            "velocity": {n: f"{u}/s" for n, u in names},
            "acceleration": {n: f"{u}/s^2" for n, u in names},
            "jerk": {n: f"{u}/s^3" for n, u in names},
        }
        doc: dict[str, Any] = {
            "drives": list(self.drive_names),
            "units": units,
            "sample_period_s": self.sample_period_s,
            "t": out(self.t),
            "position": out(self.position),
            "velocity": out(self.velocity),
            "acceleration": out(self.acceleration),
            "jerk": out(self.jerk),
        }
        if self.effort is not None:
            units["effort"] = {n: ("N" if u == "m" else "N m") for n, u in names}
            doc["effort"] = out(self.effort)
        doc["joints"] = {"names": list(self.joint_names), "position": out(self.joints)}
        doc["duration_s"] = self.duration_s
        return doc

    @classmethod
    def from_dict(cls, data: dict[str, Any], robot: RobotModel) -> DriveProfile:
        """Read a profile written by :meth:`to_dict` (e.g. for ``cabinplan check``); validates shapes.

        Joint positions are recomputed from the drive positions (the drives are what a controller runs);
        a ``jerk`` array in the document is not read: the jerk is the change of the accelerations.
        Forces are required of a robot with a dynamics model (the gate checks them).
        """
        arrays: dict[str, Array] = {}
        series = ["t", "position", "velocity", "acceleration"]
        if drive_dynamics(robot) is not None or "effort" in data:
            series.append("effort")
        m = robot.n_drives
        for key in ("drives", "sample_period_s", *series):
            if key not in data:
                raise InvalidInput(f"profile.{key}: missing", field=f"profile.{key}")
        try:
            names = tuple(data["drives"])
        except TypeError:
            msg = "profile.drives: must be a list of drive names"
            raise InvalidInput(msg, field="profile.drives") from None
        try:
            period = float(data["sample_period_s"])
        except (TypeError, ValueError, OverflowError):
            raise InvalidInput(
                "profile.sample_period_s: must be a number [s]", field="profile.sample_period_s"
            ) from None
        for key in series:
            try:
                arrays[key] = np.asarray(data[key], dtype=float)
            except (TypeError, ValueError, OverflowError):
                shape = "list of numbers" if key == "t" else f"list of rows of {m} numbers"
                raise InvalidInput(
                    f"profile.{key}: must be a {shape} (ragged or non-numeric)",
                    field=f"profile.{key}",
                ) from None
        if names != robot.drive_names:
            raise InvalidInput(
                f"profile.drives: expected {list(robot.drive_names)}, got {list(names)}",
                field="profile.drives",
            )
        n = arrays["t"].shape
        if len(n) != 1 or n[0] < 2:
            raise InvalidInput("profile.t: need a 1-D list of at least 2 times", field="profile.t")
        for k in series[1:]:
            if arrays[k].shape != (n[0], m):
                raise InvalidInput(
                    f"profile.{k}: expected {n[0]} rows of {m} values, got shape {arrays[k].shape}",
                    field=f"profile.{k}",
                )
        try:
            joints = robot.joints_from_drives(arrays["position"])
        except OutsideWorkspace:  # off the stage workspace: the gate reports it sample by sample
            joints = np.full((n[0], len(robot.joint_names)), np.nan)
        arrays.setdefault("effort", None)  # type: ignore[arg-type]
        return cls(robot.drive_names, robot.drive_units, robot.joint_names, period, joints=joints, **arrays)

    def to_csv(self) -> str:
        """One row per sample: t, then position, velocity, acceleration, jerk, effort of each drive."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        header = ["t_s"]
        for kind, suffix in (("pos", ""), ("vel", "/s"), ("acc", "/s2"), ("jerk", "/s3")):
            header += [
                f"{n}_{kind}_{u}{suffix}" for n, u in zip(self.drive_names, self.drive_units, strict=True)
            ]
        columns = [self.t, self.position, self.velocity, self.acceleration, self.jerk]
        if self.effort is not None:
            header += [
                f"{n}_effort_{'N' if u == 'm' else 'Nm'}"
                for n, u in zip(self.drive_names, self.drive_units, strict=True)
            ]
            columns.append(self.effort)
        w.writerow(header)
        data = np.column_stack(columns)
        for row in data:
            w.writerow([f"{v:.9g}" for v in row])
        return buf.getvalue()


def sample_legs(
    robot: RobotModel,
    legs: Sequence[TimedPath],
    period_s: float,
    payload: RigidPayload | None,
    dynamics: DriveDynamics | None = None,
) -> tuple[DriveProfile, IntArray, Array]:
    """Sample consecutive legs at t_k = k * period; also each sample's leg index (N,) and path parameter (N,).

    Sample k is its leg's path at the parameter ``s[k]`` (the gate's witness that it lies on the path).

    Forces come from the robot's dynamics model (``dynamics``, else
    :func:`~planner.dynamics.models.drive_dynamics`); a robot without one gives a profile without forces.
    """
    dynamics = dynamics or drive_dynamics(robot)
    # Each leg is slowed uniformly (by at most one period) so that it lasts a whole number of periods:
    # its boundaries fall on samples, the last sample is exactly the goal at rest, and velocities and
    # accelerations only shrink (by k and k^2, k <= 1).
    steps = [max(1, int(np.ceil(leg.duration / period_s - 1e-9))) for leg in legs]
    first = np.concatenate([[0], np.cumsum(steps)])
    n = int(first[-1]) + 1
    t = np.arange(n, dtype=float) * period_s
    leg_of = np.full(n, -1)
    s_of = np.zeros(n)
    q = np.empty((n, len(legs[0].path.start)))
    qd = np.zeros_like(q)
    qdd = np.zeros_like(q)
    u = np.empty((n, robot.n_drives))
    ud = np.zeros_like(u)
    udd = np.zeros_like(u)
    for k, leg in enumerate(legs):
        idx = np.arange(first[k], first[k + 1] + 1)
        scale = leg.duration / (steps[k] * period_s)
        s, sd, sdd = leg.state((idx - first[k]) * period_s * scale, 2)
        sd, sdd = sd * scale, sdd * scale**2
        sd[-1] = 0.0  # the leg ends at rest (the time law's last grid velocity is 0)
        pq, pdq, pddq = leg.path.evaluate(s)
        pu, pdu, pddu = robot.drive_path(pq, pdq, pddq)
        q[idx], u[idx] = pq, pu
        qd[idx] = pdq * sd[:, None]
        qdd[idx] = pdq * sdd[:, None] + pddq * (sd**2)[:, None]
        ud[idx] = pdu * sd[:, None]
        udd[idx] = pdu * sdd[:, None] + pddu * (sd**2)[:, None]
        leg_of[idx] = k
        s_of[idx] = s
    # Exact end points: the first sample is the path's start, the last the path's end, both at rest.
    q[0], u[0] = legs[0].path.start, robot.drives_from_joints(legs[0].path.start)
    q[-1], u[-1] = legs[-1].path.end, robot.drives_from_joints(legs[-1].path.end)
    s_of[0], s_of[-1] = 0.0, legs[-1].path.length
    qd[[0, -1]] = ud[[0, -1]] = 0.0
    qdd[-1] = udd[-1] = 0.0
    effort = dynamics.drive_forces_batch(q, qd, qdd, payload) if dynamics is not None else None
    profile = DriveProfile(
        robot.drive_names, robot.drive_units, robot.joint_names, float(period_s), t, u, ud, udd, effort, q
    )
    return profile, leg_of, s_of

"""Controller and tool exports of a succeeded plan or cycle document: ROS 2 trajectory goals and rosbag2/MCAP.

An export reads a profile document (:mod:`planner.documents.output`'s success shape, or a cycle document
with ``leg``, ``legs`` and ``events``) and writes a format with the library made for it:

* :func:`follow_joint_trajectory_goal`: a ``control_msgs/action/FollowJointTrajectory`` goal as a
  mapping with the message's own field names (``trajectory.joint_names`` = the drives in drive order,
  ``points[].time_from_start`` as ``{sec, nanosec}``, ``path_tolerance``, ``goal_tolerance``,
  ``goal_time_tolerance``), written as JSON (:func:`goal_json`) or YAML (:func:`goal_yaml`);
* :func:`write_rosbag`: a rosbag2 folder in MCAP storage (``metadata.yaml`` + ``.mcap``, what ``ros2 bag
  info`` and Foxglove open), written with ``rosbags``: ``/joint_states`` (``sensor_msgs/JointState`` of the
  drives at every exported sample), ``/joint_trajectory`` (``trajectory_msgs/JointTrajectory``, the
  points of the goal), ``/cabinplan/clearance`` (``std_msgs/Float64``: the exact clearance at each frame,
  when given), ``/cabinplan/min_clearance`` (the certified minimum, once) and ``/cabinplan/events``
  (``std_msgs/String``: each leg's start and each attach/detach event of a cycle, as JSON).

**Points and thinning.** By default every sample is a point (the controller period). With a spacing the
points are thinned (every ``round(spacing_s / period)``-th sample and the last), each keeping its sample's
position, velocity and acceleration, so the controller's quintic interpolation between two points (the
polynomial matching position, velocity and acceleration at both ends, as ``joint_trajectory_controller``
interpolates when all three are given) starts and ends on the profile. Between points the quintic is
evaluated at every original sample and must keep (:func:`thin_points`):

* position within ``max_deviation`` of the sample (default 1e-5 m or rad: the gate certified the
  clearance along the sampled path, not along another one);
* velocity, acceleration and jerk within the drive limits (with the gate's 1% tolerance,
  :data:`~planner.gate.requirements.LIMIT_TOLERANCE`).

A segment that does not is split at its middle sample, recursively, so thinning adds points where it must
and never exceeds a limit silently (at the limit, every sample is a point again).

**Tolerances** come from the gate's requirements (:mod:`planner.gate.requirements`): a prismatic drive's
path and goal position tolerance is ``GOAL_POSITION_TOL_M``, a revolute drive's ``GOAL_ANGLE_TOL_RAD``;
velocity and acceleration tolerances are 0 ("unspecified", the controller's default, as the message
defines); ``goal_time_tolerance`` is one controller period.

Times are nanoseconds from the profile's start, ``round(t * 1e9)``; bag timestamps add ``start_ns``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.core.exceptions import InvalidInput
from planner.core.types import Array, IntArray
from planner.gate.requirements import GOAL_ANGLE_TOL_RAD, GOAL_POSITION_TOL_M, LIMIT_TOLERANCE

if TYPE_CHECKING:
    from planner.scenario.resolve import ResolvedScenario

#: Largest distance [m or rad] between a thinned trajectory's quintic and any original sample.
DEFAULT_MAX_DEVIATION = 1e-5
#: Export formats of the CLI and the service.
FORMATS = ("ros2-json", "ros2-yaml", "mcap")


@dataclass(frozen=True)
class DriveBounds:
    """What interpolated motion must respect: velocity, acceleration and jerk limits per drive, (D,) each."""

    v_max: Array
    a_max: Array
    j_max: Array | None


@dataclass(frozen=True)
class Profile:
    """The samples of a document as arrays: t (N,) [s], position/velocity/acceleration/effort (N, D)."""

    drives: tuple[str, ...]
    units: tuple[str, ...]
    period_s: float
    t: Array
    position: Array
    velocity: Array
    acceleration: Array
    effort: Array | None


def profile_of(doc: Mapping[str, Any]) -> Profile:
    """The arrays of a succeeded plan or cycle document, checked for shape and finiteness.

    Raises:
        InvalidInput: the document is not a succeeded profile (``field`` names what is wrong).
    """
    if doc.get("status") != "succeeded":
        raise InvalidInput(
            f"document: status is {doc.get('status')!r}; only a succeeded plan or cycle can be exported",
            field="status",
        )
    try:
        drives = tuple(str(d) for d in doc["drives"])
        units = tuple(str(doc["units"]["position"][d]) for d in drives)
        period = float(doc["sample_period_s"])
        t = np.asarray(doc["t"], dtype=np.float64)
        arrays = {k: np.asarray(doc[k], dtype=np.float64) for k in ("position", "velocity", "acceleration")}
        effort = np.asarray(doc["effort"], dtype=np.float64) if doc.get("effort") is not None else None
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInput(
            f"document: not a plan profile ({type(exc).__name__}: {exc})", field="document"
        ) from exc
    n, d = len(t), len(drives)
    for name, a in {**arrays, **({"effort": effort} if effort is not None else {})}.items():
        if a.shape != (n, d) or not np.isfinite(a).all():
            raise InvalidInput(f"document.{name}: must be finite, shape ({n}, {d})", field=name)
    if n < 2 or not np.isfinite(t).all() or not (np.diff(t) > 0).all() or not period > 0:
        raise InvalidInput("document.t: at least 2 finite, increasing sample times", field="t")
    return Profile(
        drives, units, period, t, arrays["position"], arrays["velocity"], arrays["acceleration"], effort
    )


def bounds_for(robot_name: str) -> DriveBounds:
    """The drive limits of a registered robot (the document's ``robot``)."""
    from planner.robots import load_robot

    limits = load_robot(robot_name).limits
    return DriveBounds(limits.v_max, limits.a_max, limits.j_max)


def quintic(
    t0: float, t1: float, p0: Array, v0: Array, a0: Array, p1: Array, v1: Array, a1: Array, t: Array
) -> tuple[Array, Array, Array, Array]:
    """The quintic matching (p, v, a) at t0 and t1, evaluated at times t (K,): (p, v, a, jerk), each (K, D).

    With h = t1 - t0, s = (t - t0) / h and dp = p1 - p0 the coefficients of p(s) = sum c_i s^i are
    c0 = p0, c1 = v0 h, c2 = a0 h^2 / 2, c3 = 10 dp - (6 v0 + 4 v1) h - (3 a0 - a1) h^2 / 2,
    c4 = -15 dp + (8 v0 + 7 v1) h + (3 a0 - 2 a1) h^2 / 2, c5 = 6 dp - 3 (v0 + v1) h - (a0 - a1) h^2 / 2;
    time derivatives divide the s-derivatives by h, h^2, h^3.
    """
    h = t1 - t0
    dp = p1 - p0
    c = np.array(
        [
            p0,
            v0 * h,
            a0 * h * h / 2,
            10 * dp - (6 * v0 + 4 * v1) * h - (3 * a0 - a1) * h * h / 2,
            -15 * dp + (8 * v0 + 7 * v1) * h + (3 * a0 - 2 * a1) * h * h / 2,
            6 * dp - 3 * (v0 + v1) * h - (a0 - a1) * h * h / 2,
        ]
    )  # (6, D)
    s = ((np.asarray(t) - t0) / h)[:, None]
    p = c[0] + s * (c[1] + s * (c[2] + s * (c[3] + s * (c[4] + s * c[5]))))
    v = (c[1] + s * (2 * c[2] + s * (3 * c[3] + s * (4 * c[4] + s * 5 * c[5])))) / h
    a = (2 * c[2] + s * (6 * c[3] + s * (12 * c[4] + s * 20 * c[5]))) / h**2
    j = (6 * c[3] + s * (24 * c[4] + s * 60 * c[5])) / h**3
    return p, v, a, j


def _segment_ok(prof: Profile, i: int, k: int, bounds: DriveBounds | None, max_deviation: float) -> bool:
    """Whether the quintic from sample i to k keeps every sample between within deviation and limits."""
    if k - i < 2:
        return True
    inner = np.arange(i + 1, k)
    p, v, a, j = quintic(
        prof.t[i],
        prof.t[k],
        prof.position[i],
        prof.velocity[i],
        prof.acceleration[i],
        prof.position[k],
        prof.velocity[k],
        prof.acceleration[k],
        prof.t[inner],
    )
    if np.abs(p - prof.position[inner]).max() > max_deviation:
        return False
    if bounds is None:
        return True
    scale = 1.0 + LIMIT_TOLERANCE
    if (np.abs(v) > bounds.v_max * scale).any() or (np.abs(a) > bounds.a_max * scale).any():
        return False
    return bounds.j_max is None or not (np.abs(j) > bounds.j_max * scale).any()


def thin_points(
    prof: Profile,
    spacing_s: float | None,
    bounds: DriveBounds | None,
    max_deviation: float = DEFAULT_MAX_DEVIATION,
) -> IntArray:
    """Sample indices (M,) of the trajectory points: every sample, or thinned to ``spacing_s`` where safe.

    Args:
        prof: The profile.
        spacing_s: Wanted spacing of the points [s] (``None``: every sample, the controller period).
        bounds: Drive limits the quintic between points must keep at every original sample.
        max_deviation: Largest distance of the quintic from any original sample [m or rad].

    Returns:
        Increasing indices, first 0 and last N - 1; a segment the quintic would not keep safe is split at
        its middle sample until it is (at worst every sample is a point).

    Raises:
        InvalidInput: a spacing that is not finite and positive.
    """
    n = len(prof.t)
    if spacing_s is None:
        return np.arange(n)
    if not (np.isfinite(spacing_s) and spacing_s > 0):
        raise InvalidInput(
            f"spacing_s: must be a positive number of seconds, got {spacing_s!r}", field="spacing_s"
        )
    step = max(1, round(spacing_s / prof.period_s))
    wanted = np.unique(np.concatenate([np.arange(0, n, step), [n - 1]]))
    out: list[int] = [int(wanted[0])]
    for i, k in zip(wanted[:-1], wanted[1:], strict=True):
        stack = [(int(i), int(k))]
        while stack:  # depth-first, left before right: points come out in order
            a, b = stack.pop()
            if _segment_ok(prof, a, b, bounds, max_deviation):
                out.append(b)
            else:
                m = (a + b) // 2
                stack.extend([(m, b), (a, m)])
    return np.asarray(out, dtype=np.int64)


def _duration(ns: int) -> dict[str, int]:
    """``builtin_interfaces/Duration`` of a non-negative number of nanoseconds."""
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def times_ns(t: Array) -> list[int]:
    """Sample times as whole nanoseconds, ``round(t * 1e9)``."""
    return [round(float(x) * 1e9) for x in t]


def tolerances(prof: Profile) -> list[dict[str, Any]]:
    """``control_msgs/JointTolerance`` per drive from the gate's goal tolerances (module docstring)."""
    out = []
    for name, unit in zip(prof.drives, prof.units, strict=True):
        position = GOAL_ANGLE_TOL_RAD if unit == "rad" else GOAL_POSITION_TOL_M
        out.append({"name": name, "position": float(position), "velocity": 0.0, "acceleration": 0.0})
    return out


def follow_joint_trajectory_goal(
    doc: Mapping[str, Any],
    spacing_s: float | None = None,
    bounds: DriveBounds | None = None,
    max_deviation: float = DEFAULT_MAX_DEVIATION,
) -> dict[str, Any]:
    """The ``control_msgs/action/FollowJointTrajectory`` goal of a plan or cycle document.

    Args:
        doc: A succeeded plan or cycle document.
        spacing_s: Thin the points to this spacing [s] (:func:`thin_points`); ``None``: every sample.
        bounds: Drive limits for thinning; default the limits of the document's robot.
        max_deviation: Largest deviation of a thinned trajectory from the samples [m or rad].

    Returns:
        The goal with the message's field names (JSON-serialisable; numbers are the document's floats).
    """
    prof = profile_of(doc)
    if bounds is None and spacing_s is not None:
        bounds = bounds_for(str(doc.get("robot")))
    idx = thin_points(prof, spacing_s, bounds, max_deviation)
    ns = times_ns(prof.t[idx] - prof.t[0])
    points = []
    for row, k in enumerate(idx):
        points.append(
            {
                "positions": prof.position[k].tolist(),
                "velocities": prof.velocity[k].tolist(),
                "accelerations": prof.acceleration[k].tolist(),
                "effort": prof.effort[k].tolist() if prof.effort is not None else [],
                "time_from_start": _duration(ns[row]),
            }
        )
    tol = tolerances(prof)
    empty_header = {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
    return {
        "trajectory": {"header": empty_header, "joint_names": list(prof.drives), "points": points},
        "multi_dof_trajectory": {"header": empty_header, "joint_names": [], "points": []},
        "path_tolerance": tol,
        "component_path_tolerance": [],
        "goal_tolerance": tol,
        "component_goal_tolerance": [],
        "goal_time_tolerance": _duration(round(prof.period_s * 1e9)),
    }


def goal_json(goal: Mapping[str, Any]) -> bytes:
    """The goal as JSON (shortest round-trip floats: every number reads back bit-identical)."""
    return json.dumps(goal, separators=(",", ":")).encode()


def goal_yaml(goal: Mapping[str, Any]) -> str:
    """The goal as YAML (``ros2 action send_goal``'s syntax; floats as ``repr``, read back exactly)."""
    import yaml

    base: Any = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml's emitter: 10x faster

    class _Plain(base):
        def ignore_aliases(self, data: Any) -> bool:  # the two headers are equal, not one anchored node
            return True

    return yaml.dump(dict(goal), Dumper=_Plain, sort_keys=False, default_flow_style=None, width=1 << 16)


@dataclass(frozen=True)
class ClearanceSeries:
    """The exact clearance at some samples: times t_s (K,) [s] and distances distance_m (K,) [m]."""

    t_s: Array
    distance_m: Array


def clearance_series(sc: ResolvedScenario, doc: Mapping[str, Any], max_frames: int = 600) -> ClearanceSeries:
    """The exact clearance at the viewer's frames of a document, for the bag's ``/cabinplan/clearance``.

    The FCL distance of the robot and payload to the cabin and between non-adjacent bodies, at
    :func:`planner.documents.scene.frame_indices` (evenly strided samples, the gate's clearance probes
    and the last).
    """
    from planner.collision.world import CollisionWorld
    from planner.documents.scene import frame_indices

    joints = np.asarray(doc["joints"]["position"], dtype=np.float64)
    t = np.asarray(doc["t"], dtype=np.float64)
    world = CollisionWorld(sc.robot, sc.cabin, sc.payload)
    idx = frame_indices(len(t), max_frames)
    dist = np.array([world.min_distance(np.ascontiguousarray(joints[k])).distance_m for k in idx])
    return ClearanceSeries(t_s=t[idx], distance_m=dist)


def write_rosbag(
    doc: Mapping[str, Any],
    out: Path,
    *,
    spacing_s: float | None = None,
    bounds: DriveBounds | None = None,
    clearance: ClearanceSeries | None = None,
    start_ns: int = 0,
) -> Path:
    """Write a rosbag2 folder in MCAP storage (``out/metadata.yaml``, ``out/<name>.mcap``) with ``rosbags``.

    Args:
        doc: A succeeded plan or cycle document.
        out: The bag's folder (must not exist; rosbag2 bags are folders).
        spacing_s: Thinning of ``/joint_trajectory``'s points (``/joint_states`` has every sample).
        bounds: Drive limits for thinning; default the document robot's.
        clearance: The exact clearance per frame for ``/cabinplan/clearance`` (none: topic left out).
        start_ns: Timestamp of the profile's first sample [ns].

    Returns:
        The bag folder.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    prof = profile_of(doc)
    goal = follow_joint_trajectory_goal(doc, spacing_s, bounds)
    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Duration = T["builtin_interfaces/msg/Duration"]
    JointState, JointTrajectory = T["sensor_msgs/msg/JointState"], T["trajectory_msgs/msg/JointTrajectory"]
    Point, Float64, String = (
        T["trajectory_msgs/msg/JointTrajectoryPoint"],
        T["std_msgs/msg/Float64"],
        T["std_msgs/msg/String"],
    )

    def stamp(ns: int) -> Any:
        return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    names = list(prof.drives)
    ns = [start_ns + x for x in times_ns(prof.t - prof.t[0])]
    empty = np.zeros(0)
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as bag:
        states = bag.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        traj = bag.add_connection("/joint_trajectory", JointTrajectory.__msgtype__, typestore=store)
        minimum = bag.add_connection("/cabinplan/min_clearance", Float64.__msgtype__, typestore=store)
        events = bag.add_connection("/cabinplan/events", String.__msgtype__, typestore=store)
        pts = [
            Point(
                positions=np.asarray(p["positions"], dtype=np.float64),
                velocities=np.asarray(p["velocities"], dtype=np.float64),
                accelerations=np.asarray(p["accelerations"], dtype=np.float64),
                effort=np.asarray(p["effort"], dtype=np.float64),
                time_from_start=Duration(**p["time_from_start"]),
            )
            for p in goal["trajectory"]["points"]
        ]
        msg = JointTrajectory(header=Header(stamp=stamp(ns[0]), frame_id=""), joint_names=names, points=pts)
        bag.write(traj, ns[0], store.serialize_cdr(msg, JointTrajectory.__msgtype__))
        if doc.get("min_clearance_m") is not None:
            value = Float64(data=float(doc["min_clearance_m"]))
            bag.write(minimum, ns[0], store.serialize_cdr(value, Float64.__msgtype__))
        for k, when in enumerate(ns):
            state = JointState(
                header=Header(stamp=stamp(when), frame_id=""),
                name=names,
                position=prof.position[k],
                velocity=prof.velocity[k],
                effort=prof.effort[k] if prof.effort is not None else empty,
            )
            bag.write(states, when, store.serialize_cdr(state, JointState.__msgtype__))
        if clearance is not None:
            conn = bag.add_connection("/cabinplan/clearance", Float64.__msgtype__, typestore=store)
            for t_s, d in zip(clearance.t_s, clearance.distance_m, strict=True):
                when = start_ns + round((float(t_s) - float(prof.t[0])) * 1e9)
                bag.write(conn, when, store.serialize_cdr(Float64(data=float(d)), Float64.__msgtype__))
        for t_s, text in timeline_events(doc):
            when = start_ns + round((t_s - float(prof.t[0])) * 1e9)
            bag.write(events, when, store.serialize_cdr(String(data=text), String.__msgtype__))
    return out


def timeline_events(doc: Mapping[str, Any]) -> list[tuple[float, str]]:
    """(t [s], JSON text) of each leg's start and each event of a cycle document, in time order.

    A plan document has none. Legs: ``{"kind": "leg", "name", "leg_kind", "payload", "t_start_s",
    "t_end_s"}``; events are the document's own (``{"kind": "attach"|"detach", "t_s", "unit", "leg",
    "springback_m"}``).
    """
    out: list[tuple[float, str]] = []
    legs: Sequence[Mapping[str, Any]] = doc.get("legs") or []
    for leg in legs:
        item = {
            "kind": "leg",
            "name": leg["name"],
            "leg_kind": leg["kind"],
            "payload": leg.get("payload"),
            "t_start_s": leg["t_start_s"],
            "t_end_s": leg["t_end_s"],
        }
        out.append((float(leg["t_start_s"]), json.dumps(item)))
    for event in doc.get("events") or []:
        out.append((float(event["t_s"]), json.dumps(dict(event))))
    out.sort(key=lambda e: e[0])
    return out


def export_bytes(
    doc: Mapping[str, Any],
    fmt: str,
    *,
    spacing_s: float | None = None,
    clearance: ClearanceSeries | None = None,
    scratch: Path | None = None,
) -> tuple[bytes, str]:
    """One export as bytes and its media type (the service's route; the CLI writes the same bytes).

    ``mcap`` returns the bag's ``.mcap`` file (a rosbag2 MCAP file carries its own schemas; ``ros2 bag
    info`` also reads the folder's ``metadata.yaml``, which the CLI writes beside it).

    Raises:
        InvalidInput: an unknown format, a document that is not a succeeded profile, a bad spacing.
    """
    if fmt not in FORMATS:
        raise InvalidInput(f"format: must be one of {', '.join(FORMATS)}, got {fmt!r}", field="format")
    if fmt == "mcap":
        import tempfile

        with tempfile.TemporaryDirectory(dir=scratch) as tmp:
            folder = write_rosbag(doc, Path(tmp) / "bag", spacing_s=spacing_s, clearance=clearance)
            (mcap,) = folder.glob("*.mcap")
            return mcap.read_bytes(), "application/x-mcap"
    goal = follow_joint_trajectory_goal(doc, spacing_s)
    if fmt == "ros2-json":
        return goal_json(goal), "application/json"
    return goal_yaml(goal).encode(), "application/yaml"

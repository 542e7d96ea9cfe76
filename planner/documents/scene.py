"""Scene documents for the operator viewer: what the robot's bodies do over a plan, computed by its model.

The web page (``api/viewer``) draws these documents and computes no kinematics of its own: every pose it
shows comes from the same model the planner and the validation gate use.

* :func:`plan_scene` (cabin8): the collision bodies of :class:`~planner.collision.world.CollisionWorld`
  (carriage, stage links, platform, column, arm, slide, payload) posed at a set of *frames* -- samples of
  the drive profile -- with the closest pair of bodies (or body and cabin) and its distance at each frame
  (exact FCL distances, :meth:`~planner.collision.world.CollisionWorld.min_distance`); the start and goal
  payload poses, the approach line, and the drive limits. The frames include the sample where the report's
  ``min_clearance_m`` (the exact minimum over every sample) lies when the caller names it
  (``extra_samples``), so the curve reaches the report's figure there, and never goes below it by more
  than the gate's tolerance elsewhere.
* :func:`refusal_scene` (cabin8): the configuration a refusal is about -- the start for ``start_*``
  reasons, the goal configuration for a joint goal, else the planner's IK solution of the goal pose -- with
  every contact the state check finds there (the offending pairs) and the closest pair.
* :func:`pprs6_scene`: the pprs6 platform along a validated pose-path profile (sphere centres C_i, slider
  points B_i and link ends D_i of each chain per frame, from the closed-form inverse kinematics) and its
  reachable workspace at the path's first orientation as a boundary point cloud.

Conventions: arrays are nested lists, (frames, bodies, ...) in the order of ``bodies``; rotations are
row-major 3x3 (``R[i][j]``, body axes in the base frame as columns), positions in metres, SI throughout.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from planner.collision.world import CollisionWorld
from planner.core.exceptions import PlannerError

if TYPE_CHECKING:
    from planner.robots.cabin8 import Cabin8
    from planner.robots.pprs6 import Pprs6
    from planner.scenario import ResolvedScenario

Array = NDArray[np.float64]

#: Largest number of frames of a scene (a 16 s profile at 4 ms has 4000 samples; 400 frames keep the
#: document near 1 MB and the distance queries near a second).
MAX_FRAMES = 400


def frame_indices(
    n_samples: int, max_frames: int = MAX_FRAMES, extra_samples: tuple[int, ...] = ()
) -> NDArray[np.int64]:
    """Sample indices of the frames: evenly strided, the thinned probes, the extra samples and the last one.

    Args:
        n_samples: Samples of the profile (>= 1).
        max_frames: Target number of strided frames (the probes, at most 41, come on top).
        extra_samples: Samples shown in any case (the report's closest sample); those out of range ignored.

    Returns:
        Sorted unique indices, shape (F,), first 0 and last ``n_samples - 1``.
    """
    from planner.gate.checks import clearance_probe_indices

    stride = max(1, int(np.ceil(n_samples / max_frames)))
    probes = clearance_probe_indices(n_samples)
    extra = [k for k in extra_samples if 0 <= k < n_samples]
    idx = np.concatenate([np.arange(0, n_samples, stride), probes, extra, [n_samples - 1]])
    return np.unique(idx.astype(np.int64))


def _payload_frame(robot: Cabin8, sc: ResolvedScenario, q: Array) -> Array:
    """Payload frame (tool frame without a payload) in the base frame for joints q (8,), (4, 4)."""
    T = robot.fk(q)
    if sc.payload is not None:
        T = T @ sc.payload.T_tool_payload
    return np.asarray(T, dtype=float)


def _pose(T: Array) -> dict[str, Any]:
    return {"position": T[:3, 3].tolist(), "rotation": T[:3, :3].tolist()}


def _bodies(world: CollisionWorld) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for name, shape in zip(world.names, world.bodies.shapes, strict=True):
        if shape.kind == "box":
            out.append({"name": name, "kind": "box", "size_m": list(shape.size)})
        else:
            out.append({"name": name, "kind": "capsule", "radius_m": shape.radius})
    return out


def _posed(world: CollisionWorld, q: Array) -> dict[str, Any]:
    """Body poses of joint rows q (F, 8): ``R`` (F, B, 3, 3), ``p`` (F, B, 3), capsule ``length`` (F, B)."""
    R, p, length = world.poses(np.ascontiguousarray(q))
    return {"R": R.tolist(), "p_m": p.tolist(), "length_m": length.tolist()}


def _closest(world: CollisionWorld, q: Array) -> dict[str, Any]:
    d = world.min_distance(np.ascontiguousarray(q, dtype=float))
    finite = bool(np.isfinite(d.distance_m))
    return {
        "distance_m": float(d.distance_m) if finite else None,
        "pair": list(d.bodies) if finite else None,
        "point_a_m": d.point_a.tolist() if finite else None,
        "point_b_m": d.point_b.tolist() if finite else None,
    }


def _limits(robot: Cabin8) -> dict[str, Any]:
    lim = robot.limits
    doc = {
        "lower": np.asarray(lim.lower).tolist(),
        "upper": np.asarray(lim.upper).tolist(),
        "v_max": np.asarray(lim.v_max).tolist(),
        "a_max": np.asarray(lim.a_max).tolist(),
        "effort_max": np.asarray(lim.effort_max).tolist(),
    }
    j_max = getattr(lim, "j_max", None)
    if j_max is not None:
        doc["j_max"] = np.asarray(j_max).tolist()
    return doc


def _context(sc: ResolvedScenario, world: CollisionWorld) -> dict[str, Any]:
    """What every cabin8 scene carries: bodies, limits, start / goal payload poses, approach line."""
    robot = sc.robot
    T_start = _payload_frame(robot, sc, sc.start_q)
    if sc.T_base_payload_goal is not None:
        T_goal: Array | None = np.asarray(sc.T_base_payload_goal, dtype=float)
    elif sc.goal_q is not None:
        T_goal = _payload_frame(robot, sc, sc.goal_q)
    else:
        T_goal = None
    approach = None
    if sc.approach_direction is not None and T_goal is not None:
        end = T_goal[:3, 3]
        begin = end - sc.approach_distance_m * np.asarray(sc.approach_direction, dtype=float)
        approach = {"from_m": begin.tolist(), "to_m": end.tolist(), "distance_m": sc.approach_distance_m}
    return {
        "robot": robot.name,
        "drives": list(robot.drive_names),
        "drive_units": list(robot.drive_units),
        "limits": _limits(robot),
        "bodies": _bodies(world),
        "has_cabin": sc.cabin is not None,
        "payload_body": "payload" if "payload" in world.names else None,
        # What the scenario asked for; the gate certified it plus the STEP tessellation's deviation
        # (``certified_clearance_m``, equal without a STEP mesh) against the loaded triangles.
        "clearance_m": float(sc.requested_clearance_m),
        "certified_clearance_m": float(sc.options.clearance_m),
        "start": _pose(T_start),
        "goal": None if T_goal is None else _pose(T_goal),
        "approach": approach,
    }


def plan_scene(
    sc: ResolvedScenario,
    joints: Array,
    t: Array,
    max_frames: int = MAX_FRAMES,
    extra_samples: tuple[int, ...] = (),
) -> dict[str, Any]:
    """The scene of a validated cabin8 plan.

    Args:
        sc: The resolved scenario the plan solves.
        joints: Joint positions of every sample, (N, 8) [m, rad] (the profile's, recomputed from drives).
        t: Sample times (N,) [s].
        max_frames: See :func:`frame_indices`.
        extra_samples: Samples shown in any case (the report's ``min_clearance_at.sample``).

    Returns:
        ``{"kind": "plan", bodies, limits, start, goal, approach, "frames": {"sample", "t_s", "R", "p_m",
        "length_m", "payload_frame": {"position", "rotation"} per frame}, "clearance": {"t_s",
        "distance_m", "pair"} per frame, "min_clearance_m" over the frames}``.
    """
    q = np.asarray(joints, dtype=float)
    t = np.asarray(t, dtype=float)
    if q.ndim != 2 or q.shape[1] != 8 or t.shape != (q.shape[0],) or q.shape[0] < 1:
        raise ValueError(f"joints (N, 8) and t (N,) expected, got {q.shape} and {t.shape}")
    world = CollisionWorld(sc.robot, sc.cabin, sc.payload)
    idx = frame_indices(q.shape[0], max_frames, extra_samples)
    qf = np.ascontiguousarray(q[idx])
    doc = _context(sc, world)
    frames = {"sample": idx.tolist(), "t_s": t[idx].tolist(), **_posed(world, qf)}
    frames["payload_frame"] = [_pose(_payload_frame(sc.robot, sc, row)) for row in qf]
    closest = [_closest(world, row) for row in qf]
    distances = [c["distance_m"] for c in closest]
    finite = [d for d in distances if d is not None]
    doc.update(
        kind="plan",
        frames=frames,
        clearance={
            "t_s": frames["t_s"],
            "distance_m": distances,
            "pair": [c["pair"] for c in closest],
            "point_a_m": [c["point_a_m"] for c in closest],
            "point_b_m": [c["point_b_m"] for c in closest],
        },
        min_clearance_m=min(finite) if finite else None,
    )
    return doc


def refusal_configuration(
    sc: ResolvedScenario, reason: str, details: Mapping[str, Any]
) -> tuple[Array | None, str]:
    """The configuration a refusal is about, and where it comes from (for the page's caption).

    In order: joints named in the refusal's evidence (``details.q`` or ``details.joints``); the start for
    ``start_*`` reasons; the goal joints of a drives/joints goal; the planner's IK solution nearest the start
    for a pose goal (``goal_*`` reasons; a pose that IK cannot reach has no configuration to show).
    """
    for key in ("q", "joints"):
        value = details.get(key)
        if isinstance(value, list) and len(value) == 8:
            try:
                return np.asarray(value, dtype=float), f"the refusal's evidence ({key})"
            except (TypeError, ValueError):
                pass
    if reason.startswith("start"):
        return np.asarray(sc.start_q, dtype=float), "the start configuration"
    if reason.startswith("goal"):
        if sc.goal_q is not None:
            return np.asarray(sc.goal_q, dtype=float), "the goal configuration"
        if sc.T_base_tool_goal is not None:
            from planner.redundancy.ik import solve_pose_ik

            try:
                sol = solve_pose_ik(sc.robot, sc.T_base_tool_goal, near_drives=sc.start_u)
            except PlannerError:
                return None, "no configuration reaches the goal pose"
            return np.asarray(sol.q, dtype=float), "the planner's IK solution of the goal pose"
    return None, "this refusal names no configuration"


def refusal_scene(sc: ResolvedScenario, reason: str, details: Mapping[str, Any]) -> dict[str, Any]:
    """The scene of a refusal: its configuration (if any) with the contacts and the closest pair there.

    Returns:
        ``{"kind": "refusal", bodies, limits, start, goal, approach, "configuration": {"source", "joints",
        "contacts": [{"kind", "bodies", "detail"}], "closest": {...}} or null, "frames": one frame}``.
    """
    world = CollisionWorld(sc.robot, sc.cabin, sc.payload)
    doc = _context(sc, world)
    q, source = refusal_configuration(sc, reason, details)
    doc["kind"] = "refusal"
    doc["configuration"] = None
    doc["configuration_source"] = source
    if q is None:
        doc["frames"] = None
        return doc
    q = np.ascontiguousarray(q)
    report = world.check_state(q, sc.options.clearance_m, all_contacts=True)
    doc["configuration"] = {
        "joints": q.tolist(),
        "valid": bool(report.valid),
        "contacts": [c.to_dict() for c in report.contacts],
        "closest": _closest(world, q),
    }
    doc["frames"] = {
        "sample": [0],
        "t_s": [0.0],
        **_posed(world, q[None, :]),
        "payload_frame": [_pose(_payload_frame(sc.robot, sc, q))],
    }
    return doc


# ------------------------------------------------------------------------------------------------ pprs6
def pprs6_chain_points(robot: Pprs6, poses: Array, drives: Array) -> dict[str, Array]:
    """Joint points of the three chains for poses (N, 6) and their drives (N, 6): each (N, 3 chains, 3).

    ``C``: sphere centres on the platform (paper eq. 6-7). ``B``: slider points on the base -- ``w_i u_i``
    for chains 1, 2, the pivot ``R u_3`` of chain 3. ``D``: the link's lower end -- ``w_i u_i + s_i z`` for
    chains 1, 2 (the link D_i C_i stays in the plane ``x . u_i = w_i``), and for chain 3 the point ``s_3``
    along the column tilted by beta from the pivot, ``R u_3 + s_3 (-cos(beta) u_3 + sin(beta) z)``.
    Each link has its length: ``|C_i - D_i| = L_i`` (the tests hold it to 1e-9 m).
    """
    from planner.kinematics.pprs6 import platform_points

    g = robot.geometry
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    drives = np.atleast_2d(np.asarray(drives, dtype=float))
    C = platform_points(g, poses).C
    n = poses.shape[0]
    z = np.array([0.0, 0.0, 1.0])
    B = np.empty((n, 3, 3))
    D = np.empty((n, 3, 3))
    for i in (0, 1):
        B[:, i] = drives[:, i, None] * g.u[i]
        D[:, i] = B[:, i] + drives[:, 3 + i, None] * z
    beta, s3 = drives[:, 2], drives[:, 5]
    B[:, 2] = g.R * g.u[2]
    axis = -np.cos(beta)[:, None] * g.u[2] + np.sin(beta)[:, None] * z
    D[:, 2] = B[:, 2] + s3[:, None] * axis
    return {"C": C, "B": B, "D": D}


def pprs6_scene(
    robot: Pprs6,
    profile: Mapping[str, Any],
    workspace_points: Array,
    max_frames: int = MAX_FRAMES,
    max_points: int = 6000,
) -> dict[str, Any]:
    """The scene of a validated pprs6 pose-path profile (:func:`planner.tools.pprs6.profile_document`).

    Args:
        robot: The pprs6 model.
        profile: The profile document (``t``, ``pose`` (N, 6), ``position`` (N, 6) drives).
        workspace_points: Boundary points of the reachable workspace (M, 3) [m].
        max_frames: Evenly strided frames (plus the last sample).
        max_points: Workspace points kept (evenly strided).
    """
    t = np.asarray(profile["t"], dtype=float)
    poses = np.asarray(profile["pose"], dtype=float)
    drives = np.asarray(profile["position"], dtype=float)
    n = t.shape[0]
    stride = max(1, int(np.ceil(n / max_frames)))
    idx = np.unique(np.concatenate([np.arange(0, n, stride), [n - 1]])).astype(np.int64)
    pts = pprs6_chain_points(robot, poses[idx], drives[idx])
    from planner.kinematics.pprs6 import rotation

    R = rotation(poses[idx, 3:6])
    ws = np.asarray(workspace_points, dtype=float).reshape(-1, 3)
    if len(ws) > max_points:
        ws = ws[:: int(np.ceil(len(ws) / max_points))]
    g = robot.geometry
    return {
        "kind": "pprs6",
        "robot": robot.name,
        "drives": list(robot.drive_names),
        "geometry": {"R_m": float(g.R), "r_m": float(g.r), "L_m": np.asarray(g.L, dtype=float).tolist()},
        "frames": {
            "sample": idx.tolist(),
            "t_s": t[idx].tolist(),
            "pose": poses[idx].tolist(),
            "platform_rotation": R.tolist(),
            "C_m": pts["C"].tolist(),
            "B_m": pts["B"].tolist(),
            "D_m": pts["D"].tolist(),
        },
        "workspace": {"points_m": ws.tolist(), "count": int(len(ws))},
        "path": profile.get("path"),
        "duration_s": profile.get("duration_s"),
    }


def workspace_boundary_points(inside: NDArray[np.bool_], axes: tuple[Array, Array, Array]) -> Array:
    """Grid points inside the workspace with at least one outside (or off-grid) neighbour, (M, 3) [m]."""
    pad = np.pad(inside, 1, constant_values=False)
    interior = inside.copy()
    for axis in range(3):
        for shift in (-1, 1):
            interior &= np.roll(pad, shift, axis=axis)[1:-1, 1:-1, 1:-1]
    boundary = inside & ~interior
    ii = np.nonzero(boundary)
    return np.column_stack([axes[0][ii[0]], axes[1][ii[1]], axes[2][ii[2]]])


__all__ = [
    "MAX_FRAMES",
    "frame_indices",
    "plan_scene",
    "pprs6_chain_points",
    "pprs6_scene",
    "refusal_configuration",
    "refusal_scene",
    "workspace_boundary_points",
]

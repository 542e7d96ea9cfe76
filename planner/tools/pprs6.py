"""JSON-able documents of the pprs6 platform, shared by the CLI and the HTTP API.

Each function validates its input (raising `InvalidInput` with the field named),
calls the model, and returns plain dicts / bytes. Units: m, rad, s; the pose is
``{"x","y","z","phi","theta","psi"}`` of the platform centre O1 in the fixed frame.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from planner.core.exceptions import InvalidInput
from planner.kinematics import pprs6 as kin
from planner.kinematics.pprs6_modes import assembly_modes
from planner.kinematics.workspace import Workspace, two_pass_search
from planner.plan.pose_path import (
    PAPER_PATH,
    Pprs6Profile,
    build_profile,
    pose_from_mapping,
    pose_path_from_spec,
)
from planner.robots.pprs6 import Pprs6


def _robot() -> Pprs6:
    from planner.robots import load_robot

    model = load_robot("pprs6")
    assert isinstance(model, Pprs6)
    return model


def _drives(values: Mapping[str, Any], field: str) -> np.ndarray:
    robot = _robot()
    if not isinstance(values, Mapping):
        raise InvalidInput(f"{field}: expected an object mapping drive names to numbers", field=field)
    return robot.drives_from_dict(dict(values), field=field)


def fk_document(drives: Mapping[str, float], guess: Mapping[str, float] | None = None) -> dict[str, Any]:
    """Forward kinematics: drives -> pose, every assembly mode found, closure residual, singularity measure.

    The forward problem has several solutions for one set of drives (assembly modes, e.g. yaws of
    opposite sign about the level platform). ``pose`` is the mode nearest ``guess`` when one is given, else
    the mode connected to the home pose (what Newton reaches from home); ``assembly_modes`` lists every
    mode found (:func:`~planner.kinematics.pprs6_modes.assembly_modes`: Newton from many starts), each
    marked ``connected_to_home`` / ``nearest_guess``, and ``warning`` says when there is more than one.

    Args:
        drives: ``{"w1","w2","beta","s1","s2","s3"}`` [m, rad].
        guess: Optional pose to start Newton from (the mode nearest it is returned).

    Raises:
        InvalidInput: unknown/missing drive names, non-finite values.
        OutsideWorkspace: a drive out of range, or no assembly (ForwardKinematicsFailed).
    """
    robot = _robot()
    u = _drives(drives, "drives")
    x0 = None if guess is None else pose_from_mapping(guess, field="guess")
    x = robot.fk(u, guess=x0)  # raises when no start converges
    modes = assembly_modes(robot.geometry, u, robot.home_pose, x0)
    poses = modes.poses if len(modes.poses) else x[None]
    chosen = modes.nearest_guess if x0 is not None else modes.home
    if chosen is None:  # the modes search missed Newton's own answer: list it too
        poses = np.vstack([x[None], poses])
        chosen = 0
    x = poses[chosen]
    res = kin.closure(robot.geometry, u, x)[0]
    conds = robot.condition_number(poses)
    out: dict[str, Any] = {
        "robot": robot.name,
        "drives": robot.drives_dict(u),
        "pose": robot.pose_dict(x),
        "closure_residual_m": float(np.max(np.abs(res))),
        "condition_number": float(conds[chosen]),
        "selected": "nearest_guess" if x0 is not None else "connected_to_home",
        "assembly_modes": [
            {
                "pose": robot.pose_dict(p),
                "connected_to_home": modes.home is not None and i == modes.home,
                "nearest_guess": modes.nearest_guess is not None and i == modes.nearest_guess,
                "condition_number": float(conds[i]),
            }
            for i, p in enumerate(poses)
        ],
    }
    if len(poses) > 1:
        out["warning"] = (
            f"{len(poses)} assembly modes reproduce these drives (found from {modes.starts} starts); "
            f"'pose' is the one {out['selected'].replace('_', ' ')}"
            + ("" if x0 is not None else "; pass --guess (e.g. the previous pose) to choose another")
        )
    return out


def ik_document(pose: Mapping[str, float]) -> dict[str, Any]:
    """Closed-form inverse kinematics: pose -> drives, with the closure residual and singularity measure.

    Raises:
        InvalidInput: unknown/missing pose names, non-finite values.
        OutsideWorkspace: a chain cannot close or a drive leaves its range (the chain/drive is named).
    """
    robot = _robot()
    x = pose_from_mapping(pose, field="pose")
    u = robot.ik(x)
    res = kin.closure(robot.geometry, u, x)[0]
    return {
        "robot": robot.name,
        "pose": robot.pose_dict(x),
        "drives": robot.drives_dict(u),
        "residual_m": float(np.max(np.abs(res))),
        "condition_number": float(robot.condition_number(x)[0]),
    }


def search_workspace(orientation: Mapping[str, float] | None, step_m: float) -> tuple[Workspace, np.ndarray]:
    """The reachable positions of the platform centre at a fixed orientation (two-pass boundary search).

    Args:
        orientation: ``{"phi","theta","psi"}`` [rad] (default: all zero, as in the paper's Fig. 5).
        step_m: Grid step of the fine pass [m], in [0.001, 0.02].

    Returns:
        (the workspace grid, the orientation angles (3,) [rad]).
    """
    robot = _robot()
    angles = np.zeros(3)
    if orientation is not None:
        if not isinstance(orientation, Mapping):
            raise InvalidInput("orientation: expected {phi, theta, psi}", field="orientation")
        names = ("phi", "theta", "psi")
        unknown = sorted(set(orientation) - set(names))
        if unknown:
            raise InvalidInput(
                f"orientation: unknown name(s) {unknown}; expected {list(names)}", field="orientation"
            )
        for i, n in enumerate(names):
            v = orientation.get(n, 0.0)
            if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
                raise InvalidInput(
                    f"orientation.{n}: expected a finite number, got {v!r}", field=f"orientation.{n}"
                )
            angles[i] = float(v)
    if isinstance(step_m, bool) or not isinstance(step_m, int | float) or not 0.001 <= step_m <= 0.02:
        raise InvalidInput(f"step_m: must be in [0.001, 0.02] m, got {step_m!r}", field="step_m")

    def admissible(p: np.ndarray) -> np.ndarray:
        x = np.empty((len(p), 6))
        x[:, :3], x[:, 3:] = p, angles
        return np.asarray(robot.admissible(x))

    g = robot.geometry
    reach = g.R + g.r + max(g.L)
    z_top = float(robot.limits.upper[3:].max() + max(g.L) + g.r)
    bounds = np.array([[-reach, reach], [-reach, reach], [-g.r - max(g.L), z_top]])
    ws = two_pass_search(admissible, bounds, float(step_m), coarse_step_m=max(4 * float(step_m), 0.01))
    return ws, angles


def workspace_document(
    orientation: Mapping[str, float] | None = None,
    step_m: float = 0.005,
    png: bool = True,
) -> tuple[dict[str, Any], bytes]:
    """Reachable positions at a fixed orientation (boundary search), figures and the three-view PNG.

    Args:
        orientation: ``{"phi","theta","psi"}`` [rad] (default: all zero, as in the paper's Fig. 5).
        step_m: Grid step of the fine pass [m], in [0.001, 0.02].
        png: Also draw the views (else the bytes are empty).

    Returns:
        (figures: volume, extents, sizes, condition numbers over the inside grid points; PNG bytes).
    """
    robot = _robot()
    ws, angles = search_workspace(orientation, step_m)
    doc: dict[str, Any] = {
        "robot": robot.name,
        "orientation": dict(zip(("phi", "theta", "psi"), angles.tolist(), strict=True)),
        **ws.to_dict(),
    }
    if ws.n_inside:
        P = np.stack(np.meshgrid(*ws.axes, indexing="ij"), axis=-1)[ws.inside]
        X = np.empty((len(P), 6))
        X[:, :3], X[:, 3:] = P, angles
        cond = robot.condition_number(X)
        doc["condition_number"] = {
            "median": float(np.median(cond)),
            "p90": float(np.percentile(cond, 90)),
            "fraction_above_1000": float(np.mean(cond > 1000)),
        }
    image = b""
    if png:
        from planner.documents.pprs6_plot import workspace_png

        deg = np.degrees(angles)
        image = workspace_png(
            ws,
            title=f"pprs6 workspace at phi={deg[0]:.1f}, theta={deg[1]:.1f}, psi={deg[2]:.1f} deg: "
            f"{1e6 * ws.volume_m3:.0f} cm^3",
        )
    return doc, image


def _profile(path_spec: Mapping[str, Any] | None) -> Pprs6Profile:
    robot = _robot()
    spec = dict(PAPER_PATH if path_spec is None else path_spec)
    period = spec.pop("sample_period_s", None)
    if period is not None and (isinstance(period, bool) or not isinstance(period, int | float)):
        raise InvalidInput("sample_period_s: expected a number [s]", field="sample_period_s")
    return build_profile(robot, pose_path_from_spec(spec), period_s=period)


def profile_document(path_spec: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Validated drive profile along a pose path (default: the paper's closed path E-F-G-H-E).

    ``path_spec``: ``{"name"?, "closed"?, "max_condition"?, "sample_period_s"?, "waypoints": [pose...]}``.

    Raises:
        InvalidInput: a malformed path (the field is named).
        OutsideWorkspace: the path leaves the workspace or nears a singularity.
        RetimingFailed, ValidationFailed: no admissible time law / the gate refused the samples.
    """
    return _document(_profile(path_spec))


def _document(prof: Pprs6Profile) -> dict[str, Any]:
    robot = _robot()
    s = prof.profile
    units = dict(zip(robot.drive_names, robot.drive_units, strict=True))
    return {
        "robot": robot.name,
        "status": "succeeded",
        "path": {
            "name": prof.path.name,
            "waypoints": [
                {"name": n, **robot.pose_dict(w)}
                for n, w in zip(prof.path.labels, prof.path.waypoints, strict=True)
            ],
        },
        "drives": list(robot.drive_names),
        "units": {
            "t": "s",
            "position": units,
            "velocity": {n: f"{u}/s" for n, u in units.items()},
            "acceleration": {n: f"{u}/s^2" for n, u in units.items()},
            "jerk": {n: f"{u}/s^3" for n, u in units.items()},
        },
        "limits": {
            "v_max": robot.drives_dict(robot.limits.v_max),
            "a_max": robot.drives_dict(robot.limits.a_max),
            **({} if robot.limits.j_max is None else {"j_max": robot.drives_dict(robot.limits.j_max)}),
        },
        "sample_period_s": prof.sample_period_s,
        "duration_s": prof.duration_s,
        "t": s.t.tolist(),
        "position": s.position.tolist(),
        "velocity": s.velocity.tolist(),
        "acceleration": s.acceleration.tolist(),
        "jerk": s.jerk.tolist(),
        "leg": prof.leg.tolist(),
        "pose": prof.poses.tolist(),
        "provenance": {"robot_description_sha256": robot.description_sha256},
    }


def profile_png(document: Mapping[str, Any]) -> bytes:
    """PNG of the six drive displacements against time (paper Fig. 7) from a :func:`profile_document`."""
    from planner.documents.pprs6_plot import drives_png

    t = np.asarray(document["t"], dtype=float)
    pos = np.asarray(document["position"], dtype=float)
    name = document.get("path", {}).get("name", "")
    return drives_png(t, pos, tuple(document["drives"]), title=f"pprs6 {name}: {float(t[-1]):.2f} s")


def fk(
    robot_name: str,
    drives: Mapping[str, Any] | None,
    joints: Mapping[str, Any] | None,
    guess: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """:class:`~planner.robots.base.KinematicsTools` forward kinematics (see :func:`fk_document`)."""
    if joints is not None:
        raise InvalidInput("joints: pprs6 takes drives (w1, w2, beta, s1, s2, s3)", field="joints")
    if drives is None:
        raise InvalidInput(
            "drives: pprs6 forward kinematics needs drives (w1, w2, beta, s1, s2, s3)", field="drives"
        )
    return fk_document(drives, guess)


def ik(robot_name: str, pose: Any, near: Mapping[str, Any] | None, seed: int) -> dict[str, Any]:
    """:class:`~planner.robots.base.KinematicsTools` inverse kinematics of a platform pose."""
    if near is not None or seed != 0:
        raise InvalidInput(
            "near: pprs6's inverse kinematics has one solution (closed form); omit near and seed",
            field="near",
        )
    if not isinstance(pose, Mapping):
        raise InvalidInput("pose: expected {x, y, z, phi, theta, psi} (m, rad)", field="pose")
    return ik_document(pose)

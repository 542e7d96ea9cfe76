"""The stiffness document of one configuration (``cabinplan stiffness``, ``POST /api/v1/stiffness``).

The boundary around :mod:`planner.dynamics.stiffness` (which stays pure math): the payload as it is given
at the CLI / API (:class:`PayloadInput`, pydantic), the external wrench, and the JSON document of the
stiffness, compliance and deflections at the tool or payload frame.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from planner.core.exceptions import InvalidInput
from planner.core.schemas import Finite, Pose
from planner.core.types import Array
from planner.dynamics.payload import RigidPayload, box_inertia
from planner.dynamics.stiffness import LoadCase, StaticDeflection, stiffness_model

#: Input bounds of :func:`stiffness_document` (beyond them the linear model means nothing and overflows).
MAX_PAYLOAD_KG = 1e5
MAX_WRENCH = 1e9


class PayloadInput(BaseModel):
    """A payload at the boundary (CLI / API): mass, centre of mass and inertia in the payload frame, grasp.

    ``inertia`` is about the centre of mass [kg m^2]; without it, ``box`` (sizes [m]) gives a uniform solid
    box, and without either the payload is a point mass. ``grasp`` is the payload frame in the tool frame.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    mass: Finite = Field(ge=0, le=MAX_PAYLOAD_KG, description="kg")
    com: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)
    inertia: (
        tuple[tuple[Finite, Finite, Finite], tuple[Finite, Finite, Finite], tuple[Finite, Finite, Finite]]
        | None
    ) = None
    box: tuple[Finite, Finite, Finite] | None = None
    grasp: Pose = Pose(position=(0.0, 0.0, 0.0))

    def rigid_payload(self) -> RigidPayload:
        """The payload's inertial data in the tool frame."""
        if self.inertia is not None:
            inertia = np.array(self.inertia, dtype=float)
        elif self.box is not None:
            inertia = box_inertia(self.mass, self.box)
        else:
            inertia = np.zeros((3, 3))
        return RigidPayload.from_grasp(self.mass, np.array(self.com), inertia, self.grasp.matrix())


def _wrench_vector(wrench: Any) -> Array:
    if isinstance(wrench, Mapping):
        extra = set(wrench) - {"force", "moment"}
        if extra:
            raise InvalidInput(f"wrench: unknown fields {sorted(extra)} (force, moment)", field="wrench")
        w = [*wrench.get("force", (0.0, 0.0, 0.0)), *wrench.get("moment", (0.0, 0.0, 0.0))]
    else:
        w = list(wrench)
    try:
        out = np.array(w, dtype=float)
    except (TypeError, ValueError):
        out = np.full(1, np.nan)
    if out.shape != (6,) or not np.all(np.isfinite(out)) or np.any(np.abs(out) > MAX_WRENCH):
        raise InvalidInput(
            "wrench: expected [fx, fy, fz, mx, my, mz] or {force: [3], moment: [3]} of finite numbers "
            f"(N, N m) of magnitude at most {MAX_WRENCH:g}",
            field="wrench",
        )
    return out


def stiffness_document(
    robot_name: str,
    drives: Mapping[str, Any] | None = None,
    joints: Mapping[str, Any] | None = None,
    wrench: Sequence[float] | Mapping[str, Any] | None = None,
    payload: Mapping[str, Any] | None = None,
    frame: str = "tool",
) -> dict[str, Any]:
    """Stiffness report of one configuration (``cabinplan stiffness``, ``POST /api/v1/stiffness``).

    Args:
        robot_name: Registry name of a cabin8-type robot.
        drives: Drive name -> position [m, rad]; exactly one of ``drives`` and ``joints``.
        joints: Joint name -> value [m, rad].
        wrench: External wrench at the frame origin, base axes: ``[fx, fy, fz, mx, my, mz]`` or
            ``{"force": [3], "moment": [3]}`` [N, N m]; optional.
        payload: ``{"mass", "com"?, "inertia"? | "box"?, "grasp"?}`` (:class:`PayloadInput`); its weight
            adds to the gravity deflection, and its grasp defines the payload frame.
        frame: ``"tool"`` or ``"payload"`` (the payload frame needs ``payload``): where K, C and the
            deflections are given (at the frame origin, base axes).

    Returns:
        ``{"robot", "stiffness_source", "frame", "joints", "drives", "T_base_frame", "stiffness",
        "compliance", "units",
        "deflection": {"gravity", "wrench"?, "total"}}``; matrices are 6x6 row-major lists, deflections
        ``{"translation_m", "rotation_rad", "translation_norm_m", "rotation_norm_rad"}``.

    Raises:
        InvalidInput: bad names, shapes, frame, wrench or payload (``details['field']`` names it).
        LimitViolation / OutsideWorkspace: the configuration is not admissible or does not assemble.
    """
    from planner.robots.registry import tool_pose_robot

    robot = tool_pose_robot(robot_name)
    if frame not in ("tool", "payload"):
        raise InvalidInput(f"frame: must be 'tool' or 'payload', got {frame!r}", field="frame")
    if (drives is None) == (joints is None):
        raise InvalidInput("stiffness: give exactly one of drives or joints", field="drives")
    if drives is not None:
        q = robot.joints_from_drives(robot.drives_from_dict(dict(drives), field="drives"))
    else:
        q = robot.joints_from_dict(dict(joints or {}), field="joints")
    pay: PayloadInput | None = None
    if payload is not None:
        try:
            pay = PayloadInput.model_validate(payload)
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(["payload", *(str(p) for p in first["loc"])])
            raise InvalidInput(f"{where}: {first['msg']}", field=where) from exc
        except ArithmeticError as exc:  # e.g. a quaternion whose squared norm overflows
            raise InvalidInput(f"payload: out of range ({exc})", field="payload") from exc
    if frame == "payload" and pay is None:
        raise InvalidInput("frame: 'payload' needs a payload (its grasp is the frame)", field="frame")
    w = None if wrench is None else _wrench_vector(wrench)
    robot.check_admissible(q)
    T_tf = pay.grasp.matrix() if (pay is not None and frame == "payload") else np.eye(4)
    rigid = pay.rigid_payload() if pay is not None else None
    model = stiffness_model(robot)
    C = model.compliance(q, T_tf)
    K = model.stiffness(q, T_tf)
    T = robot.fk(q) @ T_tf
    grav = model.deflection(q, rigid, T_tf)
    out: dict[str, Any] = {
        "robot": robot.name,
        "stiffness_source": model.spec.source,
        "frame": frame,
        "joints": robot.joints_dict(q),
        "drives": robot.drives_dict(robot.drives_from_joints(q)),
        "T_base_frame": [float(v) for v in T.reshape(-1)],
        "stiffness": K.tolist(),
        "compliance": C.tolist(),
        "units": {
            "twist": ["m", "m", "m", "rad", "rad", "rad"],
            "wrench": ["N", "N", "N", "N*m", "N*m", "N*m"],
            "stiffness": "wrench per twist component; compliance its inverse",
            "axes": "base frame; wrench and twist at the frame origin",
        },
        "deflection": {"gravity": grav.to_dict()},
    }
    total = grav.twist
    if w is not None:
        dw = model.static_deflection(q, LoadCase(None, T_tf, w, gravity=False))
        out["deflection"]["wrench"] = dw.to_dict()
        total = total + dw.twist
    out["deflection"]["total"] = StaticDeflection(total[:3], total[3:]).to_dict()
    return out

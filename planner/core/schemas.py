"""Boundary value types shared by scenario files, the CLI and the HTTP API (pydantic, SI units)."""

from __future__ import annotations

import math
from typing import Annotated

import numpy as np
from pydantic import AfterValidator, AllowInfNan, BaseModel, ConfigDict, Field, Strict, model_validator

from planner.core.so3 import matrix_to_quat_wxyz, quat_wxyz_to_matrix
from planner.core.types import Array


def _finite(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError("must be a finite number")
    return v


#: A finite real number: ints and floats only (a numeric string or a boolean is refused, as the published
#: OpenAPI document's ``number`` says), checked for NaN/inf after any bound: poses and wrenches of the CLI
#: and the HTTP API.
Finite = Annotated[float, Strict(), AfterValidator(_finite)]

#: A finite real number, strict: ints and floats only (no numeric strings, no booleans, no NaN/inf),
#: checked *before* any bound, so ``.nan`` is reported as "not finite" rather than as "not <= 0.2"; bounds
#: added to it also land in the JSON schema as standard ``exclusiveMinimum``/``maximum`` keys. Scenario
#: files use it.
StrictFinite = Annotated[float, Strict(), AllowInfNan(False)]


class Quaternion(BaseModel):
    """Unit quaternion {w, x, y, z}; accepted within 1e-3 of unit norm and normalised."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    w: Finite
    x: Finite
    y: Finite
    z: Finite

    @model_validator(mode="after")
    def _unit(self) -> Quaternion:
        n = math.hypot(self.w, self.x, self.y, self.z)  # no overflow for huge components (inf)
        if abs(n - 1.0) > 1e-3:
            raise ValueError(f"quaternion norm is {n:.6g}; a rotation needs a unit quaternion (w, x, y, z)")
        return self

    def matrix(self) -> Array:
        """3x3 rotation matrix."""
        return quat_wxyz_to_matrix((self.w, self.x, self.y, self.z))


IDENTITY = Quaternion(w=1.0, x=0.0, y=0.0, z=0.0)


class Pose(BaseModel):
    """A rigid pose: position [m] and orientation, of a frame in its parent frame."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: tuple[Finite, Finite, Finite] = Field(description="[x, y, z] in metres")
    orientation: Quaternion = IDENTITY

    def matrix(self) -> Array:
        """4x4 homogeneous transform."""
        T = np.eye(4)
        T[:3, :3] = self.orientation.matrix()
        T[:3, 3] = self.position
        return T

    @classmethod
    def from_matrix(cls, T: Array) -> Pose:
        """Pose of a 4x4 homogeneous transform."""
        w, x, y, z = matrix_to_quat_wxyz(np.asarray(T)[:3, :3])
        p = np.asarray(T)[:3, 3]
        return cls(
            position=(float(p[0]), float(p[1]), float(p[2])),
            orientation=Quaternion(w=float(w), x=float(x), y=float(y), z=float(z)),
        )


class Limits(BaseModel):
    """Wall-clock limits of each plan process of a sweep or a campaign (beyond ``options.time_limit_s``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    grace_s: StrictFinite = Field(
        15.0,
        ge=0.0,
        le=600.0,
        description="Wall-clock grace beyond a plan's time_limit_s before it is killed.",
    )
    wall_time_limit_s: StrictFinite | None = Field(
        None,
        gt=0.0,
        le=3600.0,
        description="If set, every plan is killed after this many seconds of wall clock, whatever its "
        "time_limit_s + grace_s.",
    )

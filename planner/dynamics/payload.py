"""The payload's inertial parameters, expressed in the tool frame."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from planner.core.exceptions import InvalidInput
from planner.core.types import Array


def box_inertia(mass: float, size: Array | tuple[float, float, float]) -> Array:
    """Inertia [kg m^2] of a uniform solid box of ``size`` (sx, sy, sz) [m] about its centre, box axes."""
    sx, sy, sz = (float(s) for s in size)
    return mass / 12.0 * np.diag([sy**2 + sz**2, sx**2 + sz**2, sx**2 + sy**2])


@dataclass(frozen=True)
class RigidPayload:
    """A rigid payload: mass [kg], centre of mass [m] and inertia about it [kg m^2], in the tool frame.

    Validated on construction: finite values, mass >= 0, inertia symmetric, positive semi-definite and
    satisfying the triangle inequalities of its principal moments (physically realisable).
    """

    mass: float = 0.0
    com_tool: Array = field(default_factory=lambda: np.zeros(3))
    inertia_tool: Array = field(default_factory=lambda: np.zeros((3, 3)))

    def __post_init__(self) -> None:
        com = np.asarray(self.com_tool, dtype=float).reshape(3)
        inertia = np.asarray(self.inertia_tool, dtype=float).reshape(3, 3)
        object.__setattr__(self, "com_tool", com)
        object.__setattr__(self, "inertia_tool", inertia)
        if not np.isfinite(self.mass) or self.mass < 0:
            raise InvalidInput(
                f"payload.mass: must be a finite mass >= 0 kg, got {self.mass}", field="payload.mass"
            )
        if not np.all(np.isfinite(com)):
            raise InvalidInput("payload.com: must be finite", field="payload.com")
        if not np.all(np.isfinite(inertia)) or not np.allclose(inertia, inertia.T, atol=1e-9):
            raise InvalidInput(
                "payload.inertia: must be a finite symmetric 3x3 matrix", field="payload.inertia"
            )
        eig = np.linalg.eigvalsh(inertia)
        tol = 1e-9 * max(1.0, float(np.abs(eig).max()))
        if eig[0] < -tol or eig[2] > eig[0] + eig[1] + tol:
            raise InvalidInput(
                f"payload.inertia: principal moments {eig.tolist()} are not physically realisable "
                "(need non-negative values obeying the triangle inequality)",
                field="payload.inertia",
            )

    @classmethod
    def from_grasp(
        cls, mass: float, com_payload: Array, inertia_payload: Array, T_tool_payload: Array
    ) -> RigidPayload:
        """Express payload-frame inertial data in the tool frame through the grasp transform."""
        R = np.asarray(T_tool_payload, dtype=float)[:3, :3]
        p = np.asarray(T_tool_payload, dtype=float)[:3, 3]
        com_tool = p + R @ np.asarray(com_payload, dtype=float)
        inertia_tool = R @ np.asarray(inertia_payload, dtype=float) @ R.T
        return cls(float(mass), com_tool, inertia_tool)

    def params(self) -> Array:
        """The 10 inertial parameters (m, c_x, c_y, c_z, I_xx, I_yy, I_zz, I_xy, I_xz, I_yz) (read-only)."""
        return self._params

    @cached_property
    def _params(self) -> Array:
        inertia = self.inertia_tool
        out = np.array(
            [
                self.mass,
                *self.com_tool,
                inertia[0, 0],
                inertia[1, 1],
                inertia[2, 2],
                inertia[0, 1],
                inertia[0, 2],
                inertia[1, 2],
            ]
        )
        out.flags.writeable = False
        return out

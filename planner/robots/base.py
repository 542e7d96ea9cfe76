"""The generic robot-model interface every mechanism implements.

The planner, the CLI and the service talk to robots only through :class:`RobotModel`: drive names and
limits, the drive <-> joint maps, a summary, and the collision geometry with the admissibility constraints
(:meth:`RobotModel.collision_model`, the protocol of :mod:`planner.robots.geometry`). Mechanism-specific
capabilities (a tool frame for a serial-parallel arm, a platform pose for a parallel platform) live on the
concrete classes.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np

from planner.core.types import Array

if TYPE_CHECKING:
    from planner.robots.geometry import CollisionModel


@dataclass(frozen=True)
class DriveLimits:
    """Per-drive limits in drive order, each of shape (n_drives,), SI units."""

    lower: Array
    upper: Array
    v_max: Array
    a_max: Array
    effort_max: Array
    #: Jerk limits [m/s^3] or [rad/s^3]; None for a robot whose description gives none.
    j_max: Array | None = None

    def __post_init__(self) -> None:
        n = self.lower.shape
        for name in ("upper", "v_max", "a_max", "effort_max", "j_max"):
            value = getattr(self, name)
            if value is not None and value.shape != n:
                raise ValueError(f"DriveLimits.{name} has shape {value.shape}, expected {n}")
        if np.any(self.lower >= self.upper):
            raise ValueError("DriveLimits: every lower limit must be below its upper limit")
        if self.j_max is not None and not np.all(np.isfinite(self.j_max) & (self.j_max > 0)):
            raise ValueError("DriveLimits.j_max: every jerk limit must be finite and > 0")
        for arr in (self.lower, self.upper, self.v_max, self.a_max, self.effort_max, self.j_max):
            if arr is not None:
                arr.setflags(write=False)


class RobotModel(ABC):
    """A mechanism: named drives with limits, and maps between drive and joint coordinates."""

    name: str
    kind: str
    drive_names: tuple[str, ...]
    drive_units: tuple[str, ...]
    joint_names: tuple[str, ...]
    limits: DriveLimits
    description_sha256: str

    @property
    def n_drives(self) -> int:
        """Number of actuated drives."""
        return len(self.drive_names)

    @abstractmethod
    def drives_from_joints(self, q: Array) -> Array:
        """Drive positions for joint coordinates, (N, n) -> (N, n_drives) or (n,) -> (n_drives,)."""

    @abstractmethod
    def joints_from_drives(self, u: Array) -> Array:
        """Joint coordinates for drive positions (the mechanism's forward map of its closed loops)."""

    @abstractmethod
    def drive_path(self, q: Array, dq: Array, ddq: Array) -> tuple[Array, Array, Array]:
        """Drive-space derivatives of a path given in joint coordinates (the path the planner certifies).

        Args:
            q: (N, n_joints) path values q(s).
            dq: (N, n_joints) first derivatives q'(s).
            ddq: (N, n_joints) second derivatives q''(s).

        Returns:
            (N, n_drives) u(s), u'(s) = G q', u''(s) = G q'' + (dG/ds) q' (G = du/dq).
        """

    @abstractmethod
    def summary(self) -> dict[str, Any]:
        """JSON-serialisable description: drives, units, limits, geometry."""

    def collision_model(self) -> CollisionModel:
        """The robot's collision geometry and admissibility (:mod:`planner.robots.geometry`).

        Raises:
            InvalidInput: the robot has no collision geometry (it cannot be checked against a cabin).
        """
        from planner.core.exceptions import InvalidInput

        raise InvalidInput(f"robot {self.name!r} has no collision geometry", field="robot", robot=self.name)

    def drives_dict(self, u: Array) -> dict[str, float]:
        """Name -> value mapping of one drive vector."""
        return {n: float(v) for n, v in zip(self.drive_names, np.asarray(u, dtype=float), strict=True)}

    def joints_dict(self, q: Array) -> dict[str, float]:
        """Name -> value mapping of one joint vector."""
        return {n: float(v) for n, v in zip(self.joint_names, np.asarray(q, dtype=float), strict=True)}

    def drives_from_dict(self, values: dict[str, float], field: str = "drives") -> Array:
        """Drive vector from a name -> value mapping; every drive must be given, nothing else.

        Raises:
            InvalidInput: a drive is missing, unknown, or not a finite number (the message names it).
        """
        return _vector_from_dict(values, self.drive_names, field)

    def joints_from_dict(self, values: dict[str, float], field: str = "joints") -> Array:
        """Joint vector from a name -> value mapping; every joint must be given, nothing else."""
        return _vector_from_dict(values, self.joint_names, field)


def _vector_from_dict(values: dict[str, float], names: tuple[str, ...], field: str) -> Array:
    from planner.core.exceptions import InvalidInput

    if not isinstance(values, dict):
        raise InvalidInput(f"{field}: expected an object mapping names to numbers", field=field)
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise InvalidInput(f"{field}: unknown name(s) {unknown}; expected {list(names)}", field=field)
    missing = [n for n in names if n not in values]
    if missing:
        raise InvalidInput(f"{field}: missing {missing}", field=field)
    out = np.empty(len(names))
    for i, n in enumerate(names):
        v = values[n]
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
            raise InvalidInput(f"{field}.{n}: expected a finite number, got {v!r}", field=f"{field}.{n}")
        out[i] = float(v)
    return out


#: The payload type a force model takes (:class:`planner.dynamics.payload.RigidPayload`, a room above).
PayloadT = TypeVar("PayloadT", contravariant=True)


class DriveDynamics(Protocol[PayloadT]):
    """Inverse dynamics in drive space, batched over (N, n) arrays, SI units: a robot's force model.

    Generic in the payload type (the dynamics room's :class:`~planner.dynamics.payload.RigidPayload`:
    :data:`planner.dynamics.models.DriveDynamics` is this protocol bound to it), so that the robot registry
    can hold force models without importing the room that builds them.
    """

    def drive_forces_batch(self, q: Array, qd: Array, qdd: Array, payload: PayloadT | None = None) -> Array:
        """Drive forces / torques (N, n_drives) of the joint motion (q, q', q'')."""
        ...

    def static_forces_batch(self, q: Array, payload: PayloadT | None = None) -> Array:
        """Drive forces (N, n_drives) that hold the configurations at rest."""
        ...

    def joint_rates_batch(self, q: Array, ud: Array, udd: Array) -> tuple[Array, Array]:
        """Joint velocities and accelerations (N, n) of drive velocities and accelerations at q."""
        ...


class KinematicsTools(Protocol):
    """Single-shot kinematics documents of one kind of robot (CLI ``fk`` / ``ik``, API ``/kinematics``).

    A module with these two functions, registered beside the robot's model (``planner.robots``).

    Both take parsed JSON (mappings) and raise :class:`~planner.core.exceptions.InvalidInput` naming the field
    for anything the robot does not take (joints, a guess, a nearby solution, a pose of another form).
    """

    def fk(
        self,
        robot_name: str,
        drives: Mapping[str, Any] | None,
        joints: Mapping[str, Any] | None,
        guess: Mapping[str, Any] | None,
    ) -> dict[str, Any]:
        """Forward kinematics document."""
        ...

    def ik(self, robot_name: str, pose: Any, near: Mapping[str, Any] | None, seed: int) -> dict[str, Any]:
        """Inverse kinematics document."""
        ...

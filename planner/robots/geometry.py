"""What a robot model gives the collision world: its bodies, their shapes and motion, its admissibility.

The collision world (:mod:`planner.collision`) knows no robot by name. It asks the model for a
:class:`CollisionModel` (:meth:`planner.robots.base.RobotModel.collision_model`) and builds everything from
it: the bodies and their primitive :class:`Shape`, the pairs never checked against each other (adjacent),
the joints that move pairs rigidly together, the reach bounds of the certified motion walk, the body poses
(numpy, CasADi and the compiled kernel of :mod:`planner.robots.kernels`), and the admissibility vector
c(q) with its bounds. A payload, when carried, is one more body named :data:`PAYLOAD`, fixed to the tool.

A second robot plans through the same collision world by implementing this protocol (and registering its
compiled pose kernel in :mod:`planner.robots.kernels`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from planner.core.types import Array

if TYPE_CHECKING:
    import casadi as ca

    from planner.kinematics.compiled import FastFunction

#: The name of the carried payload's body (the last body of a world that has one).
#: A box's 8 corners as signs of its half extents (8, 3), x slowest and z fastest (read-only): the corners
#: of a box of half extents h are ``BOX_CORNER_SIGNS * h`` in its frame.
BOX_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
BOX_CORNER_SIGNS.flags.writeable = False

PAYLOAD = "payload"


@dataclass(frozen=True)
class Shape:
    """A primitive in its body frame: ``box`` (size) or ``capsule`` (radius, length along body z)."""

    kind: Literal["box", "capsule"]
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.0
    length: float = 0.0

    def inflated(self, margin: float) -> Shape:
        """The shape grown by ``margin`` [m] on every side (its Minkowski sum with a ball)."""
        if self.kind == "box":
            return Shape("box", tuple(s + 2 * margin for s in self.size))  # type: ignore[arg-type]
        return Shape("capsule", radius=self.radius + margin, length=self.length)

    def sphere_cover(self, cell: float = 0.10) -> tuple[Array, Array]:
        """(centres (S, 3), radii (S,)) in the body frame; their union contains the shape.

        For a capsule the centres' z is a *fraction* in [-1/2, 1/2] of the actual length, so one cover
        serves every length up to ``length`` (a capsule between two frames may stretch with a joint): with
        n + 1 spheres the spacing is at most length / n and the radius sqrt(r^2 + (length / 2n)^2) covers
        the swept disc between. A box is split into cells of at most ``cell`` [m] per side, one sphere
        around each. Computed once per shape and cell (every collision world asks); the arrays are
        read-only.
        """
        return _sphere_cover(self, float(cell))

    def _cover_of_cells(self, cell: float) -> tuple[Array, Array]:
        if self.kind == "capsule":
            n = max(1, int(np.ceil(self.length / max(self.radius, 1e-3))))
            t = np.linspace(-0.5, 0.5, n + 1)
            r = float(np.sqrt(self.radius**2 + (self.length / (2 * n)) ** 2))
            return np.column_stack([np.zeros_like(t), np.zeros_like(t), t]), np.full(len(t), r)
        size = np.asarray(self.size)
        counts = np.maximum(1, np.ceil(size / cell)).astype(int)
        cells = size / counts
        axes = [(-s / 2 + c * (np.arange(n) + 0.5)) for s, c, n in zip(size, cells, counts, strict=True)]
        gx, gy, gz = np.meshgrid(*axes, indexing="ij")
        centres = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
        return centres, np.full(len(centres), 0.5 * float(np.linalg.norm(cells)))

    @property
    def bounding_radius(self) -> float:
        """Radius of the smallest origin-centred sphere containing the shape."""
        if self.kind == "box":
            return 0.5 * float(np.linalg.norm(self.size))
        return self.radius + self.length / 2


@lru_cache(maxsize=1024)
def _sphere_cover(shape: Shape, cell: float) -> tuple[Array, Array]:
    centres, radii = shape._cover_of_cells(cell)
    centres.flags.writeable = False
    radii.flags.writeable = False
    return centres, radii


class Admissibility(Protocol):
    """The admissibility constraints of a robot: c(q) within [c_lower, c_upper] (limits and margins)."""

    c_lower: Array
    c_upper: Array

    def violations(self, q: Array, tol: float = 1e-9) -> list[dict[str, Any]]:
        """Every violated limit or margin at q: ``{"name", "value", "lower", "upper"}``; empty: admissible."""
        ...

    def constraint_values_batch(self, q: Array) -> Array:
        """c(q) for (N, n_joints) joints, shape (N, m); NaN where the mechanism cannot close."""
        ...

    def admissible_batch(self, qs: Array, tol: float = 1e-9) -> NDArray[np.bool_]:
        """For (N, n_joints) joints: True where every limit and margin holds."""
        ...


class CollisionModel(Protocol):
    """A robot's collision geometry and admissibility, as the collision world consumes them.

    Poses are rows of 13 values per body: R column-major (9), centre p (3), capsule length (a capsule's
    axis is its frame's z axis; boxes 0). Reach bounds rho (B, n_joints): no point of body b moves more
    than ``sum_j rho[b, j] |dq_j|`` along a straight joint-space step dq.
    """

    #: The robot's bodies, in pose order (the payload, when carried, comes last).
    body_names: tuple[str, ...]
    #: Joint-space dimension of the configurations the world checks.
    n_joints: int
    #: The admissibility constraints c(q) (the robot model itself, for cabin8).
    admissibility: Admissibility
    #: Code of the robot's compiled pose kernel in :mod:`planner.robots.kernels`, and its parameters.
    kernel: int
    kernel_params: Array
    #: Rows of c(q) that bound the slope of slope-dependent bodies (their largest value is the "ratio").
    ratio_rows: tuple[int, ...]
    #: Bodies whose reach bounds depend on that ratio (:meth:`segment_reach_bounds`).
    slope_bodies: tuple[str, ...]
    #: Half width h of the slope-dependent reach, ``rho[b, gamma] = h (1 + k)`` (0 without such bodies).
    slope_half_width: float
    #: A body moved by joint 0 alone, along the base z axis (its exact cabin clearance is tabulated along
    #: that joint's range ``rail_range``), or None.
    rail_body: str | None
    rail_range: tuple[float, float]

    def shapes(self, payload_size: tuple[float, float, float] | None) -> dict[str, Shape]:
        """Every body's shape by name (the payload's box when ``payload_size`` is given)."""
        ...

    def adjacent(self, a: str, b: str) -> bool:
        """True for a pair joined by a joint (or resting on one another by design): never checked."""
        ...

    def rigid(self, a: str, b: str, joint: int) -> bool:
        """True when ``joint`` moves bodies a and b rigidly together (no relative reach)."""
        ...

    def kind_code(self, name: str) -> int:
        """The code of body ``name`` in the compiled pose kernel."""
        ...

    def reach_bounds(
        self, names: tuple[str, ...], shapes: Mapping[str, Shape], payload_reach: float
    ) -> Array:
        """Reach bounds rho (B, n_joints) of the named bodies.

        ``payload_reach`` bounds the payload's distance to the tool axis (grasp offset plus the box's
        bounding radius).
        """
        ...

    def slope_bound(self, ratio: float) -> float:
        """The slope bound k of slope-dependent bodies for a ratio (``ratio_rows``) bounded by ``ratio``."""
        ...

    def slope_deviation(self, q_a: Array, q_b: Array) -> float:
        """How far the ratio can exceed the larger endpoint value along the segment q_a -> q_b."""
        ...

    def segment_reach_bounds(self, names: tuple[str, ...], rho: Array, ratio: float) -> Array:
        """Rho with the slope-dependent bodies' bounds for a segment whose ratio stays <= ``ratio``."""
        ...

    def body_poses(
        self, q: Array, names: tuple[str, ...], T_tool_box: Array | None
    ) -> tuple[Array, Array, Array]:
        """(R (N, B, 3, 3), p (N, B, 3), lengths (N, B)) of the named bodies, numpy (the reference)."""
        ...

    def pose_functions(self, names: tuple[str, ...]) -> tuple[ca.Function, FastFunction]:
        """The CasADi function (q, T_tool_box) -> (flat poses (13 B), c(q)) and its buffered wrapper."""
        ...

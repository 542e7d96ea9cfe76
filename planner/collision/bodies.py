"""The bodies of a collision world: the robot model's bodies plus the payload, with covers and reach bounds.

The robot model supplies its geometry through its :class:`~planner.robots.geometry.CollisionModel` (body
names, shapes, adjacency, rigid groups, reach bounds, poses); this module adds the payload
(:class:`PayloadGeometry`, a body fixed to the tool) and assembles the :class:`BodySet` a world checks.

Every body has a *sphere cover* (spheres in the body frame whose union contains the body), used to prune
exact checks: a body whose every sphere is certainly clear needs no FCL query. And every body has *reach
bounds* rho_j: no point of the body moves more than ``sum_j rho_j |dq_j|`` for a joint step dq along a
straight line in joint space -- the basis of the certified motion check.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.core.exceptions import InvalidInput
from planner.core.types import Array
from planner.dynamics.payload import RigidPayload, box_inertia
from planner.robots.base import RobotModel
from planner.robots.geometry import PAYLOAD, CollisionModel, Shape

__all__ = [
    "BodySet",
    "PayloadGeometry",
    "Shape",
    "body_poses",
    "pair_reach_bounds",
    "robot_bodies",
    "segment_reach_bounds",
]


@dataclass(frozen=True)
class PayloadGeometry:
    """The carried object: a box (or a mesh's oriented bounding box), its grasp and its inertia.

    Attributes:
        size: Box size (x, y, z) [m] in the box frame.
        T_payload_box: Box frame in the payload frame (identity for a box payload; the OBB pose for a mesh).
        T_tool_payload: The grasp: payload frame in the tool frame.
        mass: [kg].
        com_payload: Centre of mass in the payload frame [m].
        inertia_payload: Inertia about the centre of mass, payload axes [kg m^2].
        source: ``"box"`` or the mesh name (documentation and provenance).
    """

    size: tuple[float, float, float]
    T_tool_payload: Array = field(default_factory=lambda: np.eye(4))
    T_payload_box: Array = field(default_factory=lambda: np.eye(4))
    mass: float = 0.0
    com_payload: Array = field(default_factory=lambda: np.zeros(3))
    inertia_payload: Array | None = None
    source: str = "box"

    def __post_init__(self) -> None:
        size = tuple(float(s) for s in self.size)
        if len(size) != 3 or not all(np.isfinite(s) and s > 0 for s in size):
            raise InvalidInput(
                f"payload.box: three positive finite sizes [m] expected, got {self.size}", field="payload.box"
            )
        object.__setattr__(self, "size", size)
        for name in ("T_tool_payload", "T_payload_box"):
            T = np.asarray(getattr(self, name), dtype=float)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise InvalidInput(f"payload: {name} must be a finite 4x4 transform", field=f"payload.{name}")
            object.__setattr__(self, name, T)

    @property
    def T_tool_box(self) -> Array:
        """Box frame in the tool frame."""
        return self.T_tool_payload @ self.T_payload_box

    def rigid_payload(self) -> RigidPayload:
        """Inertial data in the tool frame (default inertia: a uniform solid box of the payload's size)."""
        inertia = self.inertia_payload
        if inertia is None:
            inertia = box_inertia(self.mass, self.size) if self.mass > 0 else np.zeros((3, 3))
            inertia = self.T_payload_box[:3, :3] @ inertia @ self.T_payload_box[:3, :3].T
        return RigidPayload.from_grasp(self.mass, self.com_payload, inertia, self.T_tool_payload)

    @classmethod
    def from_mesh_vertices(cls, vertices_payload: Array, **kwargs: object) -> PayloadGeometry:
        """The oriented bounding box of mesh vertices given in the payload frame (conservative cover)."""
        import trimesh

        T_obb, extents = trimesh.bounds.oriented_bounds(np.asarray(vertices_payload, dtype=float))
        # trimesh returns the transform taking points to the OBB frame; invert for the box pose.
        return cls(size=tuple(float(e) for e in extents), T_payload_box=np.linalg.inv(T_obb), **kwargs)  # type: ignore[arg-type]


@dataclass(frozen=True)
class BodySet:
    """The bodies of one robot + payload: shapes, sphere covers, reach bounds, checked pairs."""

    names: tuple[str, ...]
    shapes: tuple[Shape, ...]
    pairs: tuple[tuple[int, int], ...]
    rho: Array  # (n_bodies, n_joints) reach bounds [m per m or m per rad]
    pair_rho: Array  # (n_pairs, n_joints) relative reach bounds of each checked pair
    pair_rigid: Array  # (n_pairs, n_joints) bool: joint j moves both bodies of the pair rigidly together
    sphere_centres: tuple[Array, ...]  # fine cover (cabin bounds)
    sphere_radii: tuple[Array, ...]
    coarse_centres: tuple[Array, ...]  # coarse cover (self-collision bounds)
    coarse_radii: tuple[Array, ...]


def robot_bodies(model: CollisionModel, payload: PayloadGeometry | None) -> BodySet:
    """Shapes, covers, self-collision pairs and reach bounds of a robot's bodies and an optional payload."""
    shapes = model.shapes(payload.size if payload is not None else None)
    names = list(model.body_names)
    payload_reach = 0.0
    if payload is not None:
        names.append(PAYLOAD)
        T = payload.T_tool_box
        payload_reach = float(np.linalg.norm(T[:3, 3])) + shapes[PAYLOAD].bounding_radius
    ordered = tuple(shapes[n] for n in names)
    pairs = tuple(
        (i, j)
        for i in range(len(names))
        for j in range(i + 1, len(names))
        if not model.adjacent(names[i], names[j])
    )
    covers = [s.sphere_cover(0.10) for s in ordered]
    coarse = [
        s.sphere_cover(max(0.10, min(s.size))) if s.kind == "box" else s.sphere_cover() for s in ordered
    ]
    rho = model.reach_bounds(tuple(names), shapes, payload_reach)
    n_joints = model.n_joints
    pair_rigid = np.array(
        [[model.rigid(names[a], names[b], j) for j in range(n_joints)] for a, b in pairs], dtype=bool
    ).reshape(len(pairs), n_joints)
    pair_rho = pair_reach_bounds(rho, pairs, pair_rigid)
    return BodySet(
        tuple(names),
        ordered,
        pairs,
        rho,
        pair_rho,
        pair_rigid,
        tuple(c for c, _ in covers),
        tuple(r for _, r in covers),
        tuple(c for c, _ in coarse),
        tuple(r for _, r in coarse),
    )


def pair_reach_bounds(rho: Array, pairs: tuple[tuple[int, int], ...], rigid: Array) -> Array:
    """Relative reach bounds of body pairs: rho_a + rho_b, except 0 for joints moving both rigidly."""
    if not pairs:
        return np.zeros((0, rho.shape[1]))
    a = np.array([p[0] for p in pairs])
    b = np.array([p[1] for p in pairs])
    return np.where(rigid, 0.0, rho[a] + rho[b])


def segment_reach_bounds(model: CollisionModel, bodies: BodySet, ratio_bound: float) -> tuple[Array, Array]:
    """Reach bounds (bodies, pairs) for a segment along which the model's slope ratio stays <= ratio_bound.

    The static bounds assume the worst admissible slope of the slope-dependent bodies (cabin8: the stage
    links); a segment far from the singular heights can use its own, much smaller one.
    """
    rho = model.segment_reach_bounds(bodies.names, bodies.rho, ratio_bound)
    return rho, pair_reach_bounds(rho, bodies.pairs, bodies.pair_rigid)


def body_poses(
    robot: RobotModel, bodies: BodySet, q: Array, payload: PayloadGeometry | None
) -> tuple[Array, Array, Array]:
    """Poses of every body for N configurations, by the robot model's numpy route (the tests' reference).

    Returns:
        (R (N, B, 3, 3), p (N, B, 3), lengths (N, B)): rotation and centre of each body frame in the base
        frame, and the actual length of each capsule (boxes: 0). A capsule's axis is its frame's z axis.
    """
    T_tool_box = payload.T_tool_box if payload is not None else None
    return robot.collision_model().body_poses(q, bodies.names, T_tool_box)

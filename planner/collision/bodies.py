"""Coarse, conservative collision geometry of cabin8 and its payload, posed in batch.

Bodies (issue 3; all in the frames of the robot model):

========  ======================================================================================
carriage  box 1.70 x 0.12 x 0.40 m (x, y, z) centred at (0, -0.06, d1), axis-aligned
link_ab   capsule r 0.03 m between the joint centres A and B (in the plane z = d1)
link_cd   capsule r 0.03 m between C and D
link_ef   capsule r 0.03 m between E and F
platform  box 0.36 x 0.08 x 0.25 m (along BC, normal to BC in the plane, along z), on the platform
column    capsule r 0.07 m from the frame-2 origin to the frame-3 origin
arm       capsule r 0.07 m from frame 3 to frame 4
slide     capsule r 0.06 m from frame 4 to frame 6
payload   box (or a mesh's oriented bounding box, conservative) at T_tool_payload
========  ======================================================================================

Every body also has a *sphere cover* (spheres in the body frame whose union contains the body), used to
prune exact checks: a body whose every sphere is certainly clear needs no FCL query. And every body has
*reach bounds* rho_j: no point of the body moves more than ``sum_j rho_j |dq_j|`` for a joint step dq along
a straight line in joint space -- the basis of the certified motion check.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from planner.core.exceptions import InvalidInput
from planner.core.types import Array
from planner.dynamics.payload import RigidPayload, box_inertia
from planner.kinematics import chain, parallel
from planner.robots.cabin8 import Cabin8

BODY_NAMES = ("carriage", "link_ab", "link_cd", "link_ef", "platform", "column", "arm", "slide", "payload")
#: Pairs joined by a joint (or resting on one another by design): never checked against each other.
ADJACENT = frozenset(
    frozenset(p)
    for p in (
        ("carriage", "link_ab"),
        ("carriage", "link_cd"),
        ("carriage", "link_ef"),
        ("link_ab", "platform"),
        ("link_ab", "link_ef"),
        ("link_cd", "platform"),
        ("platform", "column"),
        ("column", "arm"),
        ("arm", "slide"),
        ("slide", "payload"),
    )
)


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
        serves every length up to ``length`` (the slide's varies with d5): with n + 1 spheres the spacing
        is at most length / n and the radius sqrt(r^2 + (length / 2n)^2) covers the swept disc between.
        A box is split into cells of at most ``cell`` [m] per side, one sphere around each.
        """
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


#: For each joint, the bodies it moves rigidly together (a rigid motion of both bodies of a pair does not
#: change their relative position, so it does not count towards their relative reach).
RIGID_GROUPS: tuple[frozenset[str], ...] = (
    frozenset(BODY_NAMES),  # d1 translates everything
    frozenset({"platform", "column", "arm", "slide", "payload"}),  # x
    frozenset({"platform", "column", "arm", "slide", "payload"}),  # y
    frozenset({"platform", "column", "arm", "slide", "payload"}),  # gamma
    frozenset({"arm", "slide", "payload"}),  # theta3
    frozenset({"slide", "payload"}),  # theta4 (the slide capsule spans frame 4 -> 6, rigid in theta4)
    frozenset({"payload"}),  # d5 (the slide capsule stretches: not rigid)
    frozenset({"payload"}),  # theta6
)


@dataclass(frozen=True)
class BodySet:
    """The bodies of one robot + payload: shapes, sphere covers, reach bounds, checked pairs."""

    names: tuple[str, ...]
    shapes: tuple[Shape, ...]
    pairs: tuple[tuple[int, int], ...]
    rho: Array  # (n_bodies, 8) reach bounds [m per m or m per rad]
    pair_rho: Array  # (n_pairs, 8) relative reach bounds of each checked pair
    pair_rigid: Array  # (n_pairs, 8) bool: joint j moves both bodies of the pair rigidly together
    sphere_centres: tuple[Array, ...]  # fine cover (cabin bounds)
    sphere_radii: tuple[Array, ...]
    coarse_centres: tuple[Array, ...]  # coarse cover (self-collision bounds)
    coarse_radii: tuple[Array, ...]


def cabin8_bodies(robot: Cabin8, payload: PayloadGeometry | None) -> BodySet:
    """Shapes, covers, self-collision pairs and reach bounds for cabin8 with an optional payload."""
    g = robot.geometry
    shapes: dict[str, Shape] = {
        "carriage": Shape("box", (1.70, 0.12, 0.40)),
        "link_ab": Shape("capsule", radius=0.03, length=g.L1),
        "link_cd": Shape("capsule", radius=0.03, length=g.L3),
        "link_ef": Shape("capsule", radius=0.03, length=g.L4),
        "platform": Shape("box", (0.36, 0.08, 0.25)),
        "column": Shape("capsule", radius=0.07, length=_column_length(robot)),
        "arm": Shape("capsule", radius=0.07, length=_arm_length(robot)),
    }
    # The slide spans frame 4 -> frame 6, whose length varies with d5: the capsule is posed per state with
    # its actual length; the cover and reach bounds use the longest extension.
    slide_max = _slide_length_max(robot)
    shapes["slide"] = Shape("capsule", radius=0.06, length=slide_max)
    names = [n for n in BODY_NAMES if n != "payload"]
    payload_reach = 0.0
    if payload is not None:
        shapes["payload"] = Shape("box", payload.size)
        names.append("payload")
        T = payload.T_tool_box
        payload_reach = float(np.linalg.norm(T[:3, 3])) + shapes["payload"].bounding_radius
    ordered = tuple(shapes[n] for n in names)
    pairs = tuple(
        (i, j)
        for i in range(len(names))
        for j in range(i + 1, len(names))
        if frozenset((names[i], names[j])) not in ADJACENT
    )
    covers = [s.sphere_cover(0.10) for s in ordered]
    coarse = [
        s.sphere_cover(max(0.10, min(s.size))) if s.kind == "box" else s.sphere_cover() for s in ordered
    ]
    rho = _reach_bounds(robot, names, shapes, payload_reach)
    pair_rigid = np.array(
        [[{names[a], names[b]} <= RIGID_GROUPS[j] for j in range(8)] for a, b in pairs], dtype=bool
    ).reshape(len(pairs), 8)
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
        return np.zeros((0, 8))
    a = np.array([p[0] for p in pairs])
    b = np.array([p[1] for p in pairs])
    return np.where(rigid, 0.0, rho[a] + rho[b])


def link_slope_bound(ratio: float) -> float:
    """Bound of |d x_slider / d y_joint| = y / sqrt(L^2 - y^2) for a link-height ratio y / L <= ratio."""
    ratio = min(max(ratio, 0.0), 0.99)
    return ratio / float(np.sqrt(1.0 - ratio**2))


def segment_reach_bounds(robot: Cabin8, bodies: BodySet, ratio_bound: float) -> tuple[Array, Array]:
    """Reach bounds (bodies, pairs) for a segment along which every link-height ratio stays <= ratio_bound.

    The stage links' bounds grow with the slope of the links (``link_slope_bound``); the static bounds use
    the worst admissible slope, a segment far from the singular heights can use its own, much smaller one.
    """
    k = link_slope_bound(ratio_bound)
    h = 0.5 * robot.geometry.L2
    rho = bodies.rho.copy()
    for name in ("link_ab", "link_cd", "link_ef"):
        if name in bodies.names:
            b = bodies.names.index(name)
            rho[b, chain.Y] = max(1.0, k)
            rho[b, chain.GAMMA] = h * (1.0 + k)
    return rho, pair_reach_bounds(rho, bodies.pairs, bodies.pair_rigid)


def _reach_bounds(robot: Cabin8, names: list[str], shapes: dict[str, Shape], payload_reach: float) -> Array:
    """rho[b, j]: max displacement of any point of body b per unit step of joint j.

    Prismatic joints move every downstream point 1:1. A revolute joint moves a point by at most the angle
    times its distance from the axis, bounded by the summed lengths from the joint to the body's far end
    (plus the body's radius). The stage links move with their joint centres; their slider ends move by
    ``dx_slider = dx_B + (y_B / sqrt(L^2 - y_B^2)) dy_B``, bounded with the link-height ratio 0.99 -- above
    the admissible 0.95, which covers the few millimetres the motion check lets a link move between checked
    states.
    """
    g = robot.geometry
    h = 0.5 * g.L2
    k = link_slope_bound(0.99)  # |d x_slider / d y_joint| bound
    column, arm, slide = _column_length(robot), _arm_length(robot), _slide_length_max(robot)
    r = {n: (s.radius if s.kind == "capsule" else s.bounding_radius) for n, s in shapes.items()}
    platform_half = shapes["platform"].bounding_radius
    # Distance bounds from each axis to the far end of each body, radius included.
    far_from_platform_axis = {
        "platform": platform_half,
        "column": column + r["column"],
        "arm": column + arm + r["arm"],
        "slide": column + arm + slide + r["slide"],
        "payload": column + arm + slide + payload_reach,
    }
    rho = np.zeros((len(names), 8))
    for b, name in enumerate(names):
        rho[b, chain.D1] = 1.0
        if name == "carriage":
            continue
        if name in ("link_ab", "link_cd", "link_ef"):
            # Points of a link move no more than its ends. Joint end B: |dB| <= |dx| + |dy| + h |dgamma|;
            # slider end A: |dx1| <= |dx_B| + k |dy_B| <= |dx| + k |dy| + h (1 + k) |dgamma| (C, D alike);
            # E = (A + B)/2 and F (|dy_E| = |dy_B|/2) reach the same bound. The capsule radius rides along.
            rho[b, chain.X] = 1.0
            rho[b, chain.Y] = max(1.0, k)
            rho[b, chain.GAMMA] = h * (1.0 + k)
            continue
        rho[b, chain.X] = rho[b, chain.Y] = 1.0
        rho[b, chain.GAMMA] = far_from_platform_axis[name]
        if name in ("arm", "slide", "payload"):
            rho[b, chain.THETA3] = far_from_platform_axis[name] - column
        if name in ("slide", "payload"):
            rho[b, chain.THETA4] = far_from_platform_axis[name] - column - arm
            rho[b, chain.D5] = 1.0
        if name == "payload":
            rho[b, chain.THETA6] = payload_reach
    return rho


def body_poses(
    robot: Cabin8, bodies: BodySet, q: Array, payload: PayloadGeometry | None
) -> tuple[Array, Array, Array]:
    """Poses of every body for N configurations.

    Returns:
        (R (N, B, 3, 3), p (N, B, 3), lengths (N, B)): rotation and centre of each body frame in the base
        frame, and the actual length of each capsule (boxes: 0). A capsule's axis is its frame's z axis.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    frames = robot.frames(q)
    with np.errstate(invalid="ignore"):
        pts = parallel.stage_points(robot.geometry, q[:, chain.X], q[:, chain.Y], q[:, chain.GAMMA])
    z = q[:, chain.D1]

    def p3(pt: tuple[Array, Array]) -> Array:
        return np.column_stack([pt[0], pt[1], z])

    nb = len(bodies.names)
    R = np.empty((n, nb, 3, 3))
    P = np.empty((n, nb, 3))
    lengths = np.zeros((n, nb))
    for b, name in enumerate(bodies.names):
        if name == "carriage":
            R[:, b] = np.eye(3)
            P[:, b] = np.column_stack([np.zeros(n), np.full(n, -0.06), z])
        elif name == "platform":
            R[:, b] = frames[:, 2, :3, :3]
            P[:, b] = frames[:, 2, :3, 3]
        elif name == "payload":
            assert payload is not None
            T = frames[:, 6] @ payload.T_tool_box
            R[:, b], P[:, b] = T[:, :3, :3], T[:, :3, 3]
        else:
            a, c = {
                "link_ab": (p3(pts.A), p3(pts.B)),
                "link_cd": (p3(pts.C), p3(pts.D)),
                "link_ef": (p3(pts.E), p3(pts.F)),
                "column": (frames[:, 2, :3, 3], frames[:, 3, :3, 3]),
                "arm": (frames[:, 3, :3, 3], frames[:, 4, :3, 3]),
                "slide": (frames[:, 4, :3, 3], frames[:, 6, :3, 3]),
            }[name]
            R[:, b], P[:, b], lengths[:, b] = _segment_frames(a, c)
    return R, P, lengths


def _segment_frames(a: Array, b: Array) -> tuple[Array, Array, Array]:
    """Frames whose z axis runs from a to b, centred at the midpoint; (R (N,3,3), p (N,3), length (N,))."""
    d = b - a
    length = np.linalg.norm(d, axis=1)
    zax = d / np.where(length > 1e-12, length, 1.0)[:, None]
    zax[length <= 1e-12] = [0.0, 0.0, 1.0]
    helper = np.where(np.abs(zax[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    xax = np.cross(helper, zax)
    xax /= np.linalg.norm(xax, axis=1)[:, None]
    yax = np.cross(zax, xax)
    R = np.stack([xax, yax, zax], axis=2)
    return R, 0.5 * (a + b), length


# Link lengths from the description (not from the reference numbers): the origin of MDH(alpha, a, theta, d)
# lies at (a, -sin(alpha) d, cos(alpha) d) in the previous frame, at distance sqrt(a^2 + d^2) whatever theta.
def _column_length(robot: Cabin8) -> float:
    """|frame 3 - frame 2| [m] (constant)."""
    link = robot.desc.serial_chain[0]
    return float(np.hypot(link.a, link.d))


def _arm_length(robot: Cabin8) -> float:
    """|frame 4 - frame 3| [m] (constant)."""
    link = robot.desc.serial_chain[1]
    return float(np.hypot(link.a, link.d))


def _slide_length_max(robot: Cabin8) -> float:
    """Upper bound of |frame 6 - frame 4| [m] over the d5 range (triangle inequality through frame 5)."""
    l2, l3 = robot.desc.serial_chain[2], robot.desc.serial_chain[3]
    d_max = max(abs(l2.d + robot.limits.lower[6]), abs(l2.d + robot.limits.upper[6]))
    return float(np.hypot(l2.a, d_max) + np.hypot(l3.a, l3.d))

"""cabin8's collision geometry: bodies, shapes, adjacency, reach bounds and poses (its CollisionModel).

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

Reach bounds rho_j: no point of a body moves more than ``sum_j rho_j |dq_j|`` for a joint step dq along a
straight line in joint space -- the basis of the certified motion check. The stage links' bounds grow with
the links' slope, bounded by the link-height ratios y_B/L1, y_C/L3, y_E/L4 (the last three rows of c(q)).

Poses three ways, held to each other by the tests: numpy (:meth:`Cabin8CollisionModel.body_poses`, the
reference), CasADi (:func:`pose_function`, with c(q)) and the compiled kernel
(:mod:`planner.robots.cabin8_kernels`, reached through :mod:`planner.robots.kernels`).
"""

from __future__ import annotations

import weakref
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from planner.core.types import Array
from planner.kinematics import chain, parallel
from planner.kinematics.compiled import FastFunction, dense_function
from planner.robots.geometry import PAYLOAD, Admissibility, Shape
from planner.robots.kernel_codes import CABIN8, CABIN8_KIND_CODES, CABIN8_PARAMS

if TYPE_CHECKING:  # the model imports its geometry, never the other way round at run time
    from planner.robots.cabin8 import Cabin8, Cabin8Kinematics

#: cabin8's bodies in pose order, the payload last (when carried).
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


#: The constraints that bound the stage links' slopes (``Cabin8.constraint_specs`` names).
_LINK_RATIOS = ("yB_over_L1", "yC_over_L3", "yE_over_L4")


class Cabin8CollisionModel:
    """cabin8's :class:`~planner.robots.geometry.CollisionModel` (one per model: ``Cabin8.collision_model``).

    Args:
        robot: The cabin8 model (its description's stage, chain and limits size the bodies).
    """

    body_names: tuple[str, ...] = tuple(n for n in BODY_NAMES if n != PAYLOAD)
    n_joints: int = 8
    kernel: int = CABIN8
    slope_bodies: tuple[str, ...] = ("link_ab", "link_cd", "link_ef")
    rail_body: str | None = "carriage"

    def __init__(self, robot: Cabin8) -> None:
        self.robot = robot
        self.admissibility: Admissibility = robot
        #: The link-height ratios y_B/L1, y_C/L3, y_E/L4 in c(q) (:attr:`Cabin8.constraint_specs`).
        self.ratio_rows: tuple[int, ...] = tuple(
            i for i, spec in enumerate(robot.constraint_specs) if spec.name in _LINK_RATIOS
        )
        g = robot.geometry
        self.slope_half_width = 0.5 * g.L2
        self.rail_range = (float(robot.limits.lower[0]), float(robot.limits.upper[0]))
        mdh = np.array(
            [
                [link.alpha, link.a, link.theta, link.d, float(j), 1.0 if revolute else 0.0]
                for link, (j, revolute) in zip(robot.desc.serial_chain, chain.LINK_VARIABLES, strict=True)
            ]
        )
        self.kernel_params = np.concatenate([mdh.ravel(), [g.L1, g.L2, g.L3, g.L4]])
        assert self.kernel_params.shape == (CABIN8_PARAMS,)

    def shapes(self, payload_size: tuple[float, float, float] | None) -> dict[str, Shape]:
        """Every body's shape; the slide's cover and reach bounds use its longest extension over d5."""
        robot, g = self.robot, self.robot.geometry
        shapes: dict[str, Shape] = {
            "carriage": Shape("box", (1.70, 0.12, 0.40)),
            "link_ab": Shape("capsule", radius=0.03, length=g.L1),
            "link_cd": Shape("capsule", radius=0.03, length=g.L3),
            "link_ef": Shape("capsule", radius=0.03, length=g.L4),
            "platform": Shape("box", (0.36, 0.08, 0.25)),
            "column": Shape("capsule", radius=0.07, length=_column_length(robot)),
            "arm": Shape("capsule", radius=0.07, length=_arm_length(robot)),
            # The slide spans frame 4 -> frame 6, whose length varies with d5: the capsule is posed per state
            # with its actual length.
            "slide": Shape("capsule", radius=0.06, length=_slide_length_max(robot)),
        }
        if payload_size is not None:
            shapes[PAYLOAD] = Shape("box", payload_size)
        return shapes

    def adjacent(self, a: str, b: str) -> bool:
        """True for a pair in :data:`ADJACENT`."""
        return frozenset((a, b)) in ADJACENT

    def rigid(self, a: str, b: str, joint: int) -> bool:
        """True when ``joint`` moves both bodies rigidly together (:data:`RIGID_GROUPS`)."""
        return {a, b} <= RIGID_GROUPS[joint]

    def kind_code(self, name: str) -> int:
        """The body's code in :func:`planner.robots.cabin8_kernels.body_poses`."""
        return CABIN8_KIND_CODES[name]

    def reach_bounds(
        self, names: tuple[str, ...], shapes: Mapping[str, Shape], payload_reach: float
    ) -> Array:
        """Rho (B, 8) of the named bodies (:func:`reach_bounds`)."""
        return reach_bounds(self.robot, names, shapes, payload_reach)

    def slope_bound(self, ratio: float) -> float:
        """|d x_slider / d y_joint| bound of the stage links for link-height ratios <= ``ratio``."""
        return link_slope_bound(ratio)

    def slope_deviation(self, q_a: Array, q_b: Array) -> float:
        """How far the link-height ratios can exceed the larger endpoint value along the segment.

        The ratios y_B/L1, y_C/L3, y_E/L4 are affine in y and in sin(gamma); along the segment they exceed
        the larger endpoint value by at most (L2/2) dgamma^2 / 8 over the shortest length (the sine's
        deviation from its chord), which bounds the links' slopes.
        """
        g = self.robot.geometry
        return 0.5 * g.L2 * (q_b[chain.GAMMA] - q_a[chain.GAMMA]) ** 2 / 8.0 / min(g.L1, g.L3, 2.0 * g.L4)

    def segment_reach_bounds(self, names: tuple[str, ...], rho: Array, ratio: float) -> Array:
        """Rho for a segment along which every link-height ratio stays <= ``ratio``.

        The stage links' bounds grow with the slope of the links (:func:`link_slope_bound`); the static
        bounds use the worst admissible slope, a segment far from the singular heights can use its own, much
        smaller one.
        """
        k = link_slope_bound(ratio)
        rho = rho.copy()
        for name in self.slope_bodies:
            if name in names:
                b = names.index(name)
                rho[b, chain.Y] = max(1.0, k)
                rho[b, chain.GAMMA] = self.slope_half_width * (1.0 + k)
        return rho

    def body_poses(
        self, q: Array, names: tuple[str, ...], T_tool_box: Array | None
    ) -> tuple[Array, Array, Array]:
        """Poses of the named bodies for N configurations, numpy (:func:`body_poses`)."""
        return body_poses(self.robot, names, q, T_tool_box)

    def pose_functions(self, names: tuple[str, ...]) -> tuple[ca.Function, FastFunction]:
        """The CasADi pose function of the named bodies and its wrapper, built once per model."""
        return pose_functions(self.robot.kin, names)


def link_slope_bound(ratio: float) -> float:
    """Bound of |d x_slider / d y_joint| = y / sqrt(L^2 - y^2) for a link-height ratio y / L <= ratio."""
    ratio = min(max(ratio, 0.0), 0.99)
    return ratio / float(np.sqrt(1.0 - ratio**2))


def reach_bounds(
    robot: Cabin8, names: Sequence[str], shapes: Mapping[str, Shape], payload_reach: float
) -> Array:
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
    robot: Cabin8, names: tuple[str, ...], q: Array, T_tool_box: Array | None
) -> tuple[Array, Array, Array]:
    """Poses of the named bodies for N configurations (numpy; ``T_tool_box``: the payload box in the tool).

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

    nb = len(names)
    R = np.empty((n, nb, 3, 3))
    P = np.empty((n, nb, 3))
    lengths = np.zeros((n, nb))
    for b, name in enumerate(names):
        if name == "carriage":
            R[:, b] = np.eye(3)
            P[:, b] = np.column_stack([np.zeros(n), np.full(n, -0.06), z])
        elif name == "platform":
            R[:, b] = frames[:, 2, :3, :3]
            P[:, b] = frames[:, 2, :3, 3]
        elif name == PAYLOAD:
            assert T_tool_box is not None
            T = frames[:, 6] @ T_tool_box
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


def pose_function(kin: Cabin8Kinematics, names: tuple[str, ...]) -> ca.Function:
    """Compiled (q, T_tool_box) -> body poses and the admissibility vector c(q) of the named bodies.

    Body poses: R column-major, p, capsule length -- 13 values per body.
    """
    q = kin.q_sx
    T_tb = ca.SX.sym("T_tool_box", 4, 4)
    frames = kin.frames_sx
    pts = parallel.stage_points(kin.geometry, q[chain.X], q[chain.Y], q[chain.GAMMA], xp=ca)

    def p3(pt: tuple[ca.SX, ca.SX]) -> ca.SX:
        return ca.vertcat(pt[0], pt[1], q[chain.D1])

    def seg(a: ca.SX, b: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        d = b - a
        length = ca.norm_2(d)
        z = d / length
        # Any unit vector normal to z completes the frame (a capsule is symmetric about its axis).
        helper = ca.if_else(ca.fabs(z[0]) < 0.9, ca.DM([1, 0, 0]), ca.DM([0, 1, 0]))
        x = ca.cross(helper, z)
        x = x / ca.norm_2(x)
        y = ca.cross(z, x)
        return ca.horzcat(x, y, z), 0.5 * (a + b), length

    outs: list[ca.SX] = []
    for name in names:
        if name == "carriage":
            R, p, length = ca.SX.eye(3), ca.vertcat(0, -0.06, q[chain.D1]), ca.SX(0)
        elif name == "platform":
            R, p, length = frames[2][0:3, 0:3], frames[2][0:3, 3], ca.SX(0)
        elif name == "payload":
            T = ca.mtimes(frames[6], T_tb)
            R, p, length = T[0:3, 0:3], T[0:3, 3], ca.SX(0)
        else:
            a, b = {
                "link_ab": (p3(pts.A), p3(pts.B)),
                "link_cd": (p3(pts.C), p3(pts.D)),
                "link_ef": (p3(pts.E), p3(pts.F)),
                "column": (frames[2][0:3, 3], frames[3][0:3, 3]),
                "arm": (frames[3][0:3, 3], frames[4][0:3, 3]),
                "slide": (frames[4][0:3, 3], frames[6][0:3, 3]),
            }[name]
            R, p, length = seg(a, b)
        outs.append(ca.vertcat(ca.vec(R), p, length))
    return dense_function(
        "body_poses",
        [q, T_tb],
        [ca.vertcat(*outs), kin.constraints_sx(q)],
        {"cse": True},
    )


#: Compiled pose functions by kinematic model and body list (building one takes ~10 ms).
_POSE_FUNCTIONS: weakref.WeakKeyDictionary[
    Cabin8Kinematics, dict[tuple[str, ...], tuple[ca.Function, FastFunction]]
]
_POSE_FUNCTIONS = weakref.WeakKeyDictionary()


def pose_functions(kin: Cabin8Kinematics, names: tuple[str, ...]) -> tuple[ca.Function, FastFunction]:
    """The pose function of :func:`pose_function` and its buffered wrapper, built once per model."""
    by_names = _POSE_FUNCTIONS.setdefault(kin, {})
    key = tuple(names)
    entry = by_names.get(key)
    if entry is None:
        fn = pose_function(kin, key)
        entry = by_names[key] = (fn, FastFunction(fn))
    return entry

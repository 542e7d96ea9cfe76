"""The body poses as a CasADi function of (q, T_tool_box): the symbolic model the compiled poses follow.

Poses are rows of 13 values per body: R column-major (9), centre p (3), capsule length (a capsule's axis is
its frame's z axis). The function also returns the admissibility vector c(q). The world evaluates it for
single configurations (:meth:`~planner.collision.world.CollisionWorld.poses`); the reference route
(:mod:`planner.collision.reference`) for everything, and the tests hold the closed-form kernels
(:mod:`planner.collision.kernels.poses`) to it to 1e-12.
"""

from __future__ import annotations

import weakref

import casadi as ca

from planner.kinematics import chain, parallel
from planner.kinematics.compiled import FastFunction, dense_function
from planner.robots.cabin8 import Cabin8Kinematics


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

"""Collision world: cabin, payload and robot geometry; certified state, motion and path checks.

What callers use: :class:`CollisionWorld` (the state / path API), its reports (:class:`StateReport`,
:class:`MotionReport`, :class:`PathReport`, :class:`Contact`, :class:`Distance`) and the payload's
geometry (:class:`PayloadGeometry`). The rooms behind it are listed in :mod:`planner.collision.world`;
mesh files are read by :mod:`planner.meshio`, outside this package.
"""

from planner.collision.bodies import PayloadGeometry
from planner.collision.reports import Contact, Distance, MotionReport, PathReport, StateReport
from planner.collision.world import (
    DEFAULT_CLEARANCE_M,
    DEFAULT_MOTION_MARGIN_M,
    DEFAULT_SELF_CLEARANCE_M,
    CollisionWorld,
)

__all__ = [
    "DEFAULT_CLEARANCE_M",
    "DEFAULT_MOTION_MARGIN_M",
    "DEFAULT_SELF_CLEARANCE_M",
    "CollisionWorld",
    "Contact",
    "Distance",
    "MotionReport",
    "PathReport",
    "PayloadGeometry",
    "StateReport",
]

"""Values the collision world returns and passes around: contacts, state/motion/path reports, distances.

All frozen: a report compares equal field for field, which is how the tests hold the compiled route to
the reference route (:mod:`planner.collision.oracle`). :class:`BodyState` is the internal value of one
evaluated configuration (poses and certified bounds) that the FCL probes read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from planner.core.types import Array
from planner.robots.geometry import Admissibility


@dataclass(frozen=True)
class Contact:
    """Why a state is invalid: a limit, a body against the cabin, or a pair of bodies."""

    kind: str  # "limit" | "cabin" | "self"
    bodies: tuple[str, ...]
    detail: str

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"kind": self.kind, "bodies": list(self.bodies), "detail": self.detail}


@dataclass(frozen=True)
class StateReport:
    """Result of a state check: ``valid`` and, when not, every contact found."""

    valid: bool
    contacts: tuple[Contact, ...] = ()


#: The report of a state the bounds prove clear (shared: reports are immutable).
VALID = StateReport(True)


@dataclass(frozen=True)
class MotionReport:
    """Result of a certified motion check."""

    valid: bool
    #: States evaluated along the segment (limit samples when a limit failed first).
    states_checked: int
    #: Collision queries the check needed (probes on grown bodies: FCL's, and the walk's own for boxes
    #: against the cabin, :mod:`planner.collision.kernels.mesh`, the same queries).
    fcl_queries: int
    #: Segment parameter t in [0, 1] of the state that failed (None if valid).
    t_fail: float | None = None
    contacts: tuple[Contact, ...] = ()
    #: The smallest margin the walk stepped with [m]: the one asked for, or less where an adaptive walk
    #: (``min_margin``) met a tight state (None: no walk, e.g. a limit failed first).
    smallest_margin_m: float | None = None


@dataclass(frozen=True)
class PathReport:
    """Result of :meth:`~planner.collision.world.CollisionWorld.check_path`."""

    valid: bool
    #: Motion checks run (runs of samples certified together, halved where they failed).
    motion_checks: int
    #: The last sample certified (index into the path).
    last_checked: int
    #: The sample starting the first piece that failed (None if valid).
    first_bad: int | None
    contacts: tuple[Contact, ...] = ()


@dataclass(frozen=True)
class Distance:
    """Minimum distance between the robot (with payload) and the cabin or itself, with witnesses."""

    distance_m: float
    bodies: tuple[str, str]
    point_a: Array = field(repr=False)
    point_b: Array = field(repr=False)


@dataclass(frozen=True)
class BodyState:
    """Body poses (flat: R column-major, p, length per body) and certified bounds at one configuration."""

    flat: Array
    cabin_lb: Array
    pair_lb: Array
    admissible: bool = True

    def R(self, b: int) -> Array:
        """Rotation of body b."""
        return self.flat[b, :9].reshape(3, 3).T

    def p(self, b: int) -> Array:
        """Centre of body b."""
        return self.flat[b, 9:12]

    def length(self, b: int) -> float:
        """Capsule length of body b (0 for boxes)."""
        return float(self.flat[b, 12])


def limit_contacts(robot: Admissibility, q: Array) -> list[Contact]:
    """One ``limit`` contact per violated limit or margin of the robot at q."""
    return [
        Contact(
            "limit",
            (v["name"],),
            f"{v['name']}={v['value']:.6g} outside [{v['lower']:.6g}, {v['upper']:.6g}]"
            if isinstance(v["value"], float)
            else "non-finite configuration",
        )
        for v in robot.violations(q)
    ]


def body_contact(
    names: tuple[str, ...], pairs: tuple[tuple[int, int], ...], is_cabin: bool, idx: int, margin: float
) -> Contact:
    """The contact of body ``idx`` with the cabin, or of checked pair ``idx``, within ``margin`` [m]."""
    if is_cabin:
        return Contact("cabin", (names[idx],), f"{names[idx]} within {margin:.4g} m of the cabin")
    a, b = pairs[idx]
    return Contact("self", (names[a], names[b]), f"{names[a]} within {margin:.4g} m of {names[b]}")


@dataclass(frozen=True)
class AlongReport:
    """Result of :meth:`~planner.collision.along.AlongPath.certify`: the polyline keeps the clearance or not.

    Attributes:
        valid: Every piece certified (limits at every sample and every ``LIMIT_STEP`` within pieces).
        exact_queries: FCL distance queries the certificate needed.
        walked: Pieces the bounds could not cover, handed to the certified motion walk.
        first_bad: The sample starting the first piece that failed (None if valid).
        contacts: Why it failed.
    """

    valid: bool
    exact_queries: int
    walked: int
    first_bad: int | None = None
    contacts: tuple[Contact, ...] = ()


@dataclass(frozen=True)
class ClearanceAlong:
    """The smallest distance of a path: exact over every sample, certified between samples.

    Attributes:
        distance_m: Exact FCL distance at ``sample`` for ``bodies``: no sample's exact distance of any
            body to the cabin, or between two checked bodies, is below it by more than ``tolerance_m``.
        bound_m: Certified lower bound of every distance along the polyline through the samples (between
            samples included), <= ``distance_m``.
        sample: The sample of ``distance_m``.
        bodies: The body and ``"cabin"``, or the two bodies, of ``distance_m``.
        bound_sample: The sample starting the piece where ``bound_m`` is smallest.
        exact_queries: FCL distance queries the search needed.
        tolerance_m: No sample's exact distance is below ``distance_m`` by more than this (the requested
            tolerance, or what the query budget reached where the distances are flat over many samples).
    """

    distance_m: float
    bound_m: float
    sample: int
    bodies: tuple[str, str]
    bound_sample: int
    exact_queries: int
    tolerance_m: float

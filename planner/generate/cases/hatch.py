"""A bulkhead hatch between the start and the goal, passable in the tucked posture with this payload.

The hatch's stepped opening (carriage, parallel stage, arm) is sized from the payload box at the tucked
posture plus a drawn margin (70-110 mm), then widened 20 mm at a time until the straight rail motion through
the bulkhead in that posture is certified with the requested clearance + 10 mm.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from planner.collision.world import CollisionWorld
from planner.generate.cases.common import Draw
from planner.generate.reach import tucked
from planner.meshes.generate import Bulkhead, OpeningStep
from planner.plan.goals import StaticForceCheck
from planner.robots.geometry import BOX_CORNER_SIGNS

HatchWorld = Callable[[Bulkhead], tuple[CollisionWorld, StaticForceCheck]]


def _payload_extent(d: Draw, z_bh: float) -> tuple[float, float]:
    """Largest |x| and y [m] of the payload box's corners at the tucked posture at ``z_bh``."""
    T = d.robot.fk(tucked(z_bh)) @ d.payload.T_tool_box
    half = np.array(d.payload.size) / 2
    corners = BOX_CORNER_SIGNS * half
    pts = corners @ T[:3, :3].T + T[:3, 3]
    return float(abs(pts[:, 0]).max()), float(pts[:, 1].max())


def hatch(d: Draw, world_of: HatchWorld, z_bh: float, clearance: float) -> Bulkhead | None:
    """A bulkhead at ``z_bh`` whose stepped opening passes the tucked posture with this payload.

    Returns:
        The bulkhead, or ``None`` if no opening within six widenings is certified (or the tucked
        posture cannot hold the payload).
    """
    q = tucked(z_bh)
    x_max, y_max = _payload_extent(d, z_bh)
    margin = float(d.rng.uniform(0.07, 0.11))
    x_half = float(max(x_max + margin, 0.25))
    y_top = float(max(y_max + margin, 0.9))
    for _ in range(6):
        steps = (
            OpeningStep("carriage", -0.90, 0.90, d.section.shell.deck_top_y_m, 0.08),
            OpeningStep("stage", -0.60, 0.60, 0.08, 0.40),
            OpeningStep("arm", -x_half, x_half, 0.40, y_top),
        )
        spec = Bulkhead(z_m=float(np.round(z_bh, 3)), thickness_m=0.05, steps=steps)
        world, forces = world_of(spec)
        if not forces.ok(q):
            return None
        a, b = tucked(z_bh - 1.0), tucked(z_bh + 0.7)
        if world.check_motion(a, b, clearance + 0.01).valid:
            return spec
        x_half, y_top = x_half + 0.02, y_top + 0.02
    return None


__all__ = ["HatchWorld", "hatch"]

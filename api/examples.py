"""Example scenario pieces shared by the OpenAPI examples and the job warm-up (data only).

The docked posture and the aisle cabin's bay goal appear in the plan and sweep request examples and
in the forkserver's warm-up plan; they are written once here.
"""

from __future__ import annotations

from typing import Any


def docked(d1: float = 1.0) -> dict[str, Any]:
    """A start or goal given by drive positions: the arm folded, at ``d1`` [m] on the rail (a fresh copy)."""
    return {
        "drives": {
            "d1": d1,
            "x1": -0.46,
            "x2": 0.46,
            "x3": -0.09,
            "theta3": 1.2,
            "theta4": -0.8,
            "d5": -0.25,
            "theta6": 0.0,
        }
    }


def aisle_bay_goal() -> dict[str, Any]:
    """A bay of the reference aisle cabin as a pose goal with its straight 0.48 m insertion (a fresh copy)."""
    return {
        "pose": {
            "position": [0.885, 0.675, 2.7],
            "orientation": {"w": 0.70710678, "x": 0, "y": 0.70710678, "z": 0},
        },
        "approach": {"direction": [1, 0, 0], "distance": 0.48},
    }

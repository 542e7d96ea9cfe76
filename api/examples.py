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


def _pose(position: list[float], w: float = 0.70710678, y: float = 0.70710678) -> dict[str, Any]:
    return {"position": position, "orientation": {"w": w, "x": 0, "y": y, "z": 0}}


def aisle_unit(
    unit_id: str, bay_z: float, box: list[float] | None = None, mass: float = 60.0
) -> dict[str, Any]:
    """A unit of the aisle cabin's rack (x 0.885 m) at ``bay_z``, taken from the dock near the entrance.

    The dock, fixture and lines are the reference cycle's (README, "Assembly cycles"): the unit rests on a
    shelf at z = 0.6 m, grasped from -x, lifted 30 mm, inserted 0.48 m along +x.
    """
    return {
        "unit": {
            "id": unit_id,
            "box": box or [0.45, 0.35, 0.24],
            "mass": mass,
            "grasp": {"position": [0, 0, 0.20], "orientation": {"w": 1, "x": 0, "y": 0, "z": 0}},
        },
        "dock": {
            "pose": _pose([0.70, 0.675, 0.60]),
            "fixture": {"box": [0.30, 0.4475, 0.45], "pose": _pose([0.70, 0.27375, 0.60], 1.0, 0.0)},
            "approach": {"direction": [1, 0, 0], "distance": 0.10},
            "lift": {"direction": [0, 1, 0], "distance": 0.03},
        },
        "bay": {"pose": _pose([0.885, 0.675, bay_z]), "approach": {"direction": [1, 0, 0], "distance": 0.48}},
        "retract": {"direction": [-1, 0, 0], "distance": 0.10},
    }


def aisle_cycle() -> dict[str, Any]:
    """The reference cycle: a 60 kg unit into rack bay A3 of the aisle cabin, A2 and A4 installed."""
    installed = [
        {"id": "A2", "box": [0.24, 0.35, 0.45], "pose": _pose([0.885, 0.675, 2.1], 1.0, 0.0)},
        {"id": "A4", "box": [0.24, 0.35, 0.45], "pose": _pose([0.885, 0.675, 3.3], 1.0, 0.0)},
    ]
    return {
        "name": "aisle-install-A3",
        "robot": "cabin8",
        "cabin": {"mesh": "cabin-aisle"},
        "installed": installed,
        **aisle_unit("A3", 2.7),
        "park": docked(),
        "dwell": {"grasp_s": 0.5, "release_s": 0.5},
        "gripper": {
            "box": [0.20, 0.20, 0.02],
            "pose": {"position": [0, 0, 0.07], "orientation": {"w": 1, "x": 0, "y": 0, "z": 0}},
        },
        "options": {"clearance_m": 0.01, "seed": 1},
    }


def aisle_campaign() -> dict[str, Any]:
    """Two units of the aisle cabin's rack, bays A3 then A5, installed in the given order."""
    cycle = aisle_cycle()
    return {
        "name": "aisle-A3-A5",
        "robot": "cabin8",
        "cabin": cycle["cabin"],
        "installed": cycle["installed"],
        "park": cycle["park"],
        "units": [aisle_unit("A3", 2.7), aisle_unit("A5", 3.9)],
        "order": "given",
        "gripper": cycle["gripper"],
        "options": cycle["options"],
    }

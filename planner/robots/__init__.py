"""Robot models (cabin8, pprs6), their description files and the registry that names them.

What a model gives the collision world is the protocol of :mod:`planner.robots.geometry` (bodies, shapes,
reach bounds, pose kernels, admissibility).
"""

from planner.robots.base import DriveLimits, KinematicsTools, RobotModel
from planner.robots.registry import available_robots, load_robot

__all__ = ["DriveLimits", "KinematicsTools", "RobotModel", "available_robots", "load_robot"]

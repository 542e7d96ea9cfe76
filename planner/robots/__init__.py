"""Robot models (cabin8, pprs6), their description files and the registry that names them."""

from planner.robots.base import DriveLimits, KinematicsTools, RobotModel
from planner.robots.registry import available_robots, load_robot

__all__ = ["DriveLimits", "KinematicsTools", "RobotModel", "available_robots", "load_robot"]

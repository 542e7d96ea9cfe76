"""Rigid-body dynamics: inverse dynamics in joint and drive space, energies, payload inertia."""

from planner.dynamics.payload import RigidPayload

__all__ = ["RigidPayload"]

"""Kinematics: planar parallel stage, serial chain, closed-form redundant IK, compiled CasADi maps."""

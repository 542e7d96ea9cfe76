"""Benchmarks: run as modules (``python -m bench.kinematics``); they print figures, they are not tests."""

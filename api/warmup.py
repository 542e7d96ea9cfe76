"""Preloaded by the job forkserver: imports the planner and plans one tiny scenario, once.

Every job process is forked from the forkserver, so it inherits what this warm-up loaded (compiled
CasADi functions, numba kernels from their cache, the reference cabin's clearance grid, matplotlib's
font cache) and starts planning at once instead of spending seconds warming up. Importing this module
has that side effect on purpose; nothing else imports it.
"""

from __future__ import annotations

import logging
import time

from api.worker import plan_job

_LOG = logging.getLogger(__name__)

_HOME = {"x1": -0.46, "x2": 0.46, "x3": -0.09, "theta3": 1.2, "theta4": -0.8, "d5": -0.25, "theta6": 0.0}

#: A 0.2 m rail move in the reference aisle cabin without payload.
WARMUP_SCENARIO = {
    "name": "warmup",
    "robot": "cabin8",
    "cabin": {"mesh": "cabin-aisle", "units": "m"},
    "start": {"drives": {"d1": 1.0, **_HOME}},
    "goal": {"drives": {"d1": 1.2, **_HOME}},
    "options": {"seed": 0, "time_limit_s": 30},
}


def warm_up() -> float:
    """Plan :data:`WARMUP_SCENARIO` (result discarded); returns the time it took [s]."""
    t0 = time.perf_counter()
    try:
        plan_job(
            {"id": "warmup", "scenario": WARMUP_SCENARIO, "meshes": {}, "empty_dir": "/nonexistent"}, _ignore
        )
    except Exception:  # a warm-up failure must not stop the forkserver: jobs then just start cold
        _LOG.exception("job warm-up failed")
    return time.perf_counter() - t0


def _ignore(_stage: str, _fraction: float) -> None:
    return None


warm_up()
